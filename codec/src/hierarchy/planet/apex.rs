//! The apex of a planet's block-wise encode ([`PlanetApex`]): the root field and the levels above
//! the cut, over the whole planet, encoded out of core.
//!
//! Level by level, as the whole encoder does, but never the whole planet at once: a level's
//! stored diamonds (in id order: by face, then column) are cut into runs whose reads fit a
//! budget of bytes, and each run reads only the tiles under its recorded diamonds, thinned to
//! the points that level reads (the next level's vertices, `2^(K − ⌈(l + 1)/2⌉)` apart: a coarse
//! level reads a few points a tile), from the view written as the tiles were painted
//! ([`ApexView`]: the apex itself paints nothing). Each level's refinements, which the next
//! level gathers its grids from, are spilled ([`RefinedSpill`]) and read back a run's parents
//! at a time; each diamond's grid is spilled for the blocks ([`ApexGrids`]). A diamond's
//! refinement depends on its parents' and the points it reads only, so the records are the
//! whole encoder's, in the same order.

use std::collections::{BTreeSet, HashMap};

use rayon::prelude::*;

use super::apex_grids::{ApexGrids, ApexRefinements, GridSpill, RefinedSpill};
use super::apex_view::ApexView;
use super::block_groups::TileGroup;
use super::grid::{tile_of, tiles_across, tiles_meeting};
use super::outline::PlanetOutline;
use super::tile_source::{held_planet, tiles_under};
use super::{refine_diamond, views};
use crate::CodecError;
use crate::geometry::{DiamondId, Domain};
use crate::hierarchy::encode::grid_from_parents;
use crate::hierarchy::roots::encode_roots;
use crate::hierarchy::{CodecParams, Record};

/// The levels above the cut, encoded over the whole planet.
#[derive(Clone, Debug, PartialEq)]
pub struct PlanetApex {
    /// The root field's values.
    pub root_field: Vec<i32>,
    /// The coded root field.
    pub roots: Vec<u8>,
    /// Records of the apex levels (object errors not yet saturated).
    pub records: Vec<Record>,
    /// Every stored apex diamond's grid, for the blocks to measure its error on their tiles
    /// (spilled, read back as a block needs one).
    pub grids: ApexGrids,
    /// Refinements of the recorded diamonds of the level above the cut (spilled, read back as
    /// a block needs them).
    pub last: ApexRefinements,
    /// Each apex diamond's views ([`views`]): the face, the tiles meeting it there (first
    /// and last column and row) and the diamond.
    seen: Vec<(u8, TileSpan, DiamondId)>,
}

/// Columns and rows of a rectangle of a face's tiles: `((first column, first row), (last
/// column, last row))`, inclusive.
type TileSpan = ((usize, usize), (usize, usize));

impl PlanetApex {
    /// The apex of the planet `outline` outlines from its parts as an earlier
    /// [`super::PlanetBlocks::apex`] held them.
    pub fn from_parts(
        outline: &PlanetOutline,
        root_field: Vec<i32>,
        roots: Vec<u8>,
        records: Vec<Record>,
        grids: ApexGrids,
        last: ApexRefinements,
    ) -> Self {
        let seen = seen(&outline.domain, outline.tile_log2, &grids);
        Self {
            root_field,
            roots,
            records,
            grids,
            last,
            seen,
        }
    }

    /// The apex diamonds with a view on `group`'s face meeting one of its tiles.
    pub(super) fn meeting(&self, group: &TileGroup) -> BTreeSet<DiamondId> {
        let (first, last) = (group.first, group.last);
        self.seen
            .iter()
            .filter(|&&(face, (a, b), _)| {
                face == group.face
                    && a.0 <= last.0
                    && first.0 <= b.0
                    && a.1 <= last.1
                    && first.1 <= b.1
            })
            .map(|&(_, _, id)| id)
            .collect()
    }

    /// Encodes the levels above `cut` of the planet `outline` outlines (`stored` and `recorded`
    /// its sets) from its tiles as `view` holds them, each run of a level reading at most about
    /// `view_bytes` of tiles.
    pub(super) fn encode(
        outline: &PlanetOutline,
        view: &ApexView,
        params: &CodecParams,
        (stored, recorded): (&[Vec<DiamondId>], &[BTreeSet<DiamondId>]),
        cut: u8,
        view_bytes: u64,
    ) -> Result<Self, CodecError> {
        let domain = &params.domain;
        let n = domain.n();
        let (root_field, roots) = {
            let k = domain.layout().k();
            let wanted = root_tiles(domain, outline.tile_log2);
            let view = held_planet(outline, view.tiles(&wanted, k)?)?;
            encode_roots(
                params,
                |f, x, y| view.get(f, x, y),
                |f, x, y| view.drawn(f, x, y) == Some(true),
            )?
        };
        let grids = GridSpill::new(n * n);
        let mut index = HashMap::new();
        let mut records = Vec::new();
        let mut prev = ApexRefinements::none(n);
        for level in 0..cut {
            let level_sets = (
                &stored[usize::from(level)][..],
                &recorded[usize::from(level)],
            );
            let mut next = RefinedSpill::new(n);
            for run in level_runs(outline, level, level_sets, view_bytes) {
                let encoded = encode_run(outline, view, params, &root_field, &prev, &run, &grids)?;
                for (id, refined, at) in encoded {
                    index.insert(id, at);
                    if let Some((refined, record)) = refined {
                        next.put(id, &refined)?;
                        records.push(record);
                    }
                }
            }
            prev = next.finish()?;
        }
        let grids = grids.finish(index)?;
        Ok(Self::from_parts(
            outline, root_field, roots, records, grids, prev,
        ))
    }
}

/// One apex diamond encoded: its refinement and record (recorded diamonds), and where its grid
/// went.
type RunOutput = (DiamondId, Option<(super::Refined, Record)>, u64);

/// Encodes the diamonds of `run` (one level's) from their parents' refinements `prev`, reading
/// only the tiles under them: each one's refinement and record if it is recorded, its grid put
/// in `grids`.
fn encode_run(
    outline: &PlanetOutline,
    tiles: &ApexView,
    params: &CodecParams,
    root_field: &[i32],
    prev: &ApexRefinements,
    run: &Run,
    grids: &GridSpill,
) -> Result<Vec<RunOutput>, CodecError> {
    let domain = &params.domain;
    let view = held_planet(outline, tiles.tiles(&run.tiles, run.stride)?)?;
    let parents = prev.load(run.ids().flat_map(|id| domain.parents(id)).flatten())?;
    run.ids
        .par_iter()
        .map(|&(id, is_recorded)| {
            let p = grid_from_parents(domain, root_field, id, &parents);
            let refined = match is_recorded {
                true => Some(refine_diamond(params, &view, id, &p)?),
                false => None,
            };
            Ok((id, refined, grids.put(&p)?))
        })
        .collect()
}

/// A run of one level's stored diamonds encoded together (each with whether it is recorded),
/// and the tiles its recorded diamonds read, thinned to `2^stride`.
struct Run {
    ids: Vec<(DiamondId, bool)>,
    tiles: BTreeSet<(u8, usize)>,
    stride: u32,
}

impl Run {
    fn ids(&self) -> impl Iterator<Item = DiamondId> + '_ {
        self.ids.iter().map(|&(id, _)| id)
    }
}

/// Bytes a tile of the view takes besides its points: the tile, its grid's and classes'
/// buffers and its entry in the view.
const TILE_OVERHEAD_BYTES: u64 = 256;

/// Bytes a point of a tile takes in the view and the lattice's tile cache: height, validity,
/// class and the input it took its height from.
const POINT_BYTES: u64 = 8;

/// Bytes a refinement of a grid of side `n` takes in memory: its vertices and cells, and a
/// validity for each half-step point (the most it carries).
pub(super) fn refinement_bytes(n: usize) -> u64 {
    let (n, m) = (n as u64, n.saturating_sub(1) as u64);
    (n * n + m * m) * 4 + (n + m) * (n + m)
}

/// Level `level`'s stored diamonds (`sets`: the level's stored ids, in order, and those
/// recorded), in runs of consecutive ids whose reads fit about `view_bytes` (at least one
/// diamond a run): the tiles its recorded diamonds read, its diamonds' parents' refinements
/// read back from the level above, and its recorded diamonds' own refinements, held until the
/// run is spilled. The level reads the next level's vertices: `2^(K − ⌈(level + 1)/2⌉)` apart.
fn level_runs(
    outline: &PlanetOutline,
    level: u8,
    (ids, recorded): (&[DiamondId], &BTreeSet<DiamondId>),
    view_bytes: u64,
) -> Vec<Run> {
    let domain = &outline.domain;
    let tile_log2 = outline.tile_log2;
    let stride = domain.layout().k() - (u32::from(level) + 1).div_ceil(2);
    let s = stride.min(tile_log2);
    let side = ((1u64 << tile_log2) >> s) + 1;
    let tile_bytes = side * side * POINT_BYTES + TILE_OVERHEAD_BYTES;
    let refined_bytes = refinement_bytes(domain.n());
    let mut runs = Vec::new();
    let mut run = RunBudget::new(stride);
    for &id in ids {
        let is_recorded = recorded.contains(&id);
        let under: BTreeSet<(u8, usize)> = match is_recorded {
            true => tiles_under(domain, tile_log2, id)
                .into_iter()
                .map(|(f, i, _)| (f, i))
                .collect(),
            false => BTreeSet::new(),
        };
        let parents: Vec<DiamondId> = domain.parents(id).into_iter().flatten().collect();
        let (tiles, refinements) = run.with(&under, &parents, is_recorded);
        let full = tiles * tile_bytes + refinements * refined_bytes > view_bytes;
        if full && !run.run.ids.is_empty() {
            runs.push(std::mem::replace(&mut run, RunBudget::new(stride)).run);
        }
        run.add(id, is_recorded, under, parents);
    }
    if !run.run.ids.is_empty() {
        runs.push(run.run);
    }
    debug_assert!(runs.iter().flat_map(Run::ids).eq(ids.iter().copied()));
    runs
}

/// A [`Run`] being gathered, with what it will hold counted.
struct RunBudget {
    run: Run,
    /// The parents its diamonds gather from (their refinements are read back for the run).
    parents: BTreeSet<DiamondId>,
    /// Its recorded diamonds (each one's refinement is held until the run is spilled).
    recorded: u64,
}

impl RunBudget {
    fn new(stride: u32) -> Self {
        Self {
            run: Run {
                ids: Vec::new(),
                tiles: BTreeSet::new(),
                stride,
            },
            parents: BTreeSet::new(),
            recorded: 0,
        }
    }

    /// The tiles and refinements the run would hold with a diamond reading the tiles `under`,
    /// gathering from `parents`, recorded or not.
    fn with(
        &self,
        under: &BTreeSet<(u8, usize)>,
        parents: &[DiamondId],
        recorded: bool,
    ) -> (u64, u64) {
        let tiles = self.run.tiles.len() + under.difference(&self.run.tiles).count();
        let more_parents = parents.iter().filter(|p| !self.parents.contains(p)).count();
        let refinements = self.parents.len() + more_parents + self.recorded as usize;
        (tiles as u64, refinements as u64 + u64::from(recorded))
    }

    fn add(
        &mut self,
        id: DiamondId,
        recorded: bool,
        under: BTreeSet<(u8, usize)>,
        parents: Vec<DiamondId>,
    ) {
        self.run.ids.push((id, recorded));
        self.run.tiles.extend(under);
        self.parents.extend(parents);
        self.recorded += u64::from(recorded);
    }
}

/// The tiles holding the root field's points as [`PlanetGrid::get`] reads them (each point on
/// the tile of its canonical point).
fn root_tiles(domain: &Domain, tile_log2: u32) -> BTreeSet<(u8, usize)> {
    let side = domain.cube().expect("a cube-sphere").side();
    let rf = domain.root_field();
    let mut out = BTreeSet::new();
    for face in 0..domain.faces() {
        for y in 0..rf.height as i64 {
            for x in 0..rf.width as i64 {
                if let Some(c) = domain.canonical_point(face, x * rf.spacing, y * rf.spacing) {
                    out.insert((c.face, tile_of(side, tile_log2, c.x, c.y)));
                }
            }
        }
    }
    out
}

/// Each view of each diamond of `grids` ([`views`]): its face, the tiles meeting it there and
/// the diamond.
fn seen(domain: &Domain, tile_log2: u32, grids: &ApexGrids) -> Vec<(u8, TileSpan, DiamondId)> {
    let side = domain.cube().expect("a cube-sphere").side();
    // Where a diamond's views lie does not depend on its grid.
    let blank = vec![0; domain.n() * domain.n()];
    let mut out = Vec::new();
    for id in grids.ids() {
        for (view, _) in views(domain, id, &blank) {
            if let Some(span) = tile_span(side, tile_log2, domain.layout().bounds(view)) {
                out.push((view.face, span, id));
            }
        }
    }
    out
}

/// The columns and rows (`(first, last)`, inclusive) of the tiles [`tiles_meeting`] gives, a
/// rectangle of the face's tile grid: `None` when it gives none.
fn tile_span(
    side: i64,
    log2: u32,
    (x0, y0, x1, y1): (i64, i64, i64, i64),
) -> Option<((usize, usize), (usize, usize))> {
    let s: Vec<usize> = tiles_meeting(side, log2, (x0, y0, x1, y1)).collect();
    let across = tiles_across(side, log2);
    let (first, last) = (*s.first()?, *s.last()?);
    Some((
        (first % across, first / across),
        (last % across, last / across),
    ))
}
