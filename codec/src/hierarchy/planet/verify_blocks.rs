//! The exact verifier of a planet, block by block: every reconstructed vertex of every level
//! against the lattice, as [`super::verify_planet`] compares them, with never more than the
//! apex's last refinements, one block's diamonds and one block's tiles of the lattice held.
//!
//! The levels above a cut (the *apex*) are decoded over the whole planet as the whole walk
//! ([`crate::hierarchy::walk_all_with_validity`]) decodes them, each batch of diamonds compared
//! with the lattice tiles under it read from the apex view ([`ApexView`], thinned to the
//! level's vertices); the refinements of the level above the cut are kept. Then each block of
//! tiles ([`TileGroup`], as the block-wise encode groups them) decodes, level by level from the
//! cut, the diamonds the whole walk visits whose centres its tiles own (as the encode's blocks
//! own them) and, where asked, those of the finest level's parity whose squares meet its tiles
//! (what a reconstruction of its tiles writes), with all their ancestors down to the cut. A
//! diamond's grid depends on its parents' refinements and its own record only (α = 1), so each
//! is decoded exactly as the whole walk decodes it; every diamond the whole walk visits is
//! owned by one block, so the per-level counts and maxima are the whole verifier's.

use std::collections::{BTreeSet, HashMap};
use std::sync::Arc;

use rayon::prelude::*;

use super::apex_finest::{ApexFinest, FinestVisit};
use super::apex_grids::{ApexRefinements, RefinedSpill, refinement_bytes};
use super::apex_view::ApexView;
use super::block_groups::TileGroup;
use super::blocks::SET_BYTES_PER_ID;
use super::grid::tiles_across;
use super::outline::PlanetOutline;
use super::tile_source::{PlanetTiles, Rect, held_planet, tiles_under, union};
use super::{PlanetGrid, PlanetTile};
use crate::CodecError;
use crate::geometry::{DiamondId, DomainKind, Layout};
use crate::hierarchy::CodecParams;
use crate::hierarchy::decode::walk_level;
use crate::hierarchy::decode::{Decoder, LevelRecords, LevelReport, Visit, records_by_level};
use crate::hierarchy::decode_pool::GridPool;
use crate::hierarchy::refine::{RefineScratch, Refined};
use crate::lifting::Alpha;

/// A planet hierarchy verified block by block (see the module documentation): built with the
/// apex decoded and compared; [`PlanetBlockVerify::verify_block`] then does any block.
pub struct PlanetBlockVerify<'a> {
    decoder: Decoder,
    outline: &'a PlanetOutline,
    levels: Vec<LevelRecords<'a>>,
    /// Per level from the cut, in id order: the diamonds the whole walk visits.
    visited: Vec<Vec<DiamondId>>,
    /// Refinements of the recorded diamonds of the level above the cut (spilled, read back a
    /// block's at a time).
    apex: ApexRefinements,
    /// The visited apex diamonds of the finest level's parity, their grids and validity (what
    /// a reconstruction writes before the blocks' levels; spilled).
    apex_finest: ApexFinest,
    cut: u8,
}

impl<'a> PlanetBlockVerify<'a> {
    /// Decodes the levels above `cut` (clamped to the finest level) over the whole planet that
    /// `outline` outlines and compares each visited diamond's vertices with the lattice as
    /// `view` (written for the same cut) holds it: the apex's levels of the report. Each level
    /// is decoded in runs of diamonds whose refinements, with their parents', take about
    /// `run_bytes`; the refinements of a level wait for the next in a temporary file, as the
    /// grids the finest level's reconstruction takes from the apex do (held whole, they grow
    /// with the planet's land).
    pub fn new(
        params: CodecParams,
        roots: &[u8],
        records: impl IntoIterator<Item = (DiamondId, &'a [u8])>,
        (outline, view): (&'a PlanetOutline, &ApexView),
        cut: u8,
        run_bytes: u64,
    ) -> Result<(Self, Vec<LevelReport>), CodecError> {
        if params.domain.kind() != DomainKind::CubeSphere || params.alpha != Alpha::One {
            return Err(CodecError::unsupported(
                "only a planet with α = 1 is verified block by block",
            ));
        }
        if params.domain != outline.domain {
            return Err(CodecError::invalid(
                "the planet's lattice (N, K) differs from the hierarchy's",
            ));
        }
        let finest = params.layout().finest_level();
        let cut = cut.min(finest);
        let decoder = Decoder::new(params, roots)?;
        let levels = records_by_level(&params, records)?;
        let mut report = LevelReport::empty(&params);
        let n = params.layout().n();
        let mut apex_finest = ApexFinest::new(n);
        let mut prev = ApexRefinements::none(n);
        let mut scratch = RefineScratch::default();
        let pool = GridPool::default();
        // A refinement and the two parents' it gathers from.
        let run = usize::try_from(run_bytes / (3 * refinement_bytes(n) as u64))
            .unwrap_or(usize::MAX)
            .max(1);
        for level in 0..cut {
            let walk = ApexLevel {
                decoder: &decoder,
                records: &levels[usize::from(level)],
                outline,
                view,
                stride: params
                    .layout()
                    .k()
                    .saturating_sub(u32::from(level).div_ceil(2)),
                run,
                pool: &pool,
            };
            let ids = visited_on(&params, &levels, level);
            let grids = (level % 2 == finest % 2).then_some(&mut apex_finest);
            let out = &mut report[usize::from(level)];
            prev = walk.walk(&ids, &prev, out, grids, &mut scratch)?;
        }
        let visited = (cut..=finest)
            .map(|l| visited_on(&params, &levels, l))
            .collect();
        let walk = Self {
            decoder,
            outline,
            levels,
            visited,
            apex: prev,
            apex_finest: apex_finest.finish()?,
            cut,
        };
        Ok((walk, report))
    }

    /// Bytes the verifier holds for the planet's diamonds whatever its blocks: the records' ids
    /// and places, the visited diamonds' ids and the outline's leaves. A memory plan takes them
    /// from what its blocks and caches may hold.
    pub fn diamond_bytes(&self) -> u64 {
        let id = std::mem::size_of::<DiamondId>() as u64;
        let place = std::mem::size_of::<&[u8]>() as u64;
        let records: u64 = self.levels.iter().map(|l| l.ids.len() as u64).sum();
        let visited: u64 = self.visited.iter().map(|v| v.len() as u64).sum();
        let leaves: u64 = self.outline.leaves.iter().map(|l| l.len() as u64).sum();
        records * (id + place) + visited * id + leaves * SET_BYTES_PER_ID
    }

    /// The level the blocks start at.
    pub fn cut(&self) -> u8 {
        self.cut
    }

    /// Decodes block `group` from the cut down and adds to `report` (one entry per level) the
    /// comparison of the diamonds it owns with the lattice `tiles` hands out (its own tiles
    /// whole, of the others the parts its diamonds reach). With `finest`, also hands it, in the
    /// whole walk's order, every visited diamond of the finest level's parity on the group's
    /// face whose square meets the group's tiles (what a reconstruction of them writes).
    pub fn verify_block(
        &self,
        group: &TileGroup,
        tiles: &dyn PlanetTiles,
        report: &mut [LevelReport],
        mut finest: Option<&mut FinestVisit<'_>>,
    ) -> Result<(), CodecError> {
        let params = self.decoder.params();
        let layout = params.layout();
        let last = layout.finest_level();
        let face = group.face;
        let (side, log2) = (self.side(), self.outline.tile_log2);
        let (xs, ys) = group.owned_span(side, log2);
        let rect = group_rect(group, side, log2);
        let owns = |id: &DiamondId| {
            let (x, y) = (i64::from(id.x), i64::from(id.y));
            id.face == face && xs.0 <= x && x <= xs.1 && ys.0 <= y && y <= ys.1
        };
        let reconstructs = finest.is_some();
        let writes = |id: &DiamondId| {
            let b = layout.bounds(*id);
            reconstructs
                && id.level % 2 == last % 2
                && id.face == face
                && b.0 <= rect.2
                && rect.0 <= b.2
                && b.1 <= rect.3
                && rect.1 <= b.3
        };
        if let Some(f) = finest.as_mut() {
            self.apex_writes(face, (rect.0, rect.2), &writes, &mut **f)?;
        }
        let needed = self.needed(face, (xs.0, rect.2), &|id| owns(id) || writes(id));
        let view = self.lattice_view(group, tiles, &needed, &owns)?;
        let mut scratch = RefineScratch::default();
        let pool = GridPool::default();
        let domain = &params.domain;
        let at_cut = needed.first().into_iter().flatten();
        let apex = self
            .apex
            .load(at_cut.flat_map(|&id| domain.parents(id)).flatten())?;
        let mut own: HashMap<DiamondId, Refined> = HashMap::new();
        for (ids, level) in needed.iter().zip(self.cut..=last) {
            let prev = if level == self.cut { &apex } else { &own };
            let out = &mut report[usize::from(level)];
            let next = walk_level(
                &self.decoder,
                ids,
                &self.levels[usize::from(level)],
                prev,
                &mut scratch,
                &pool,
                &mut |batch: &[Visit<'_>]| {
                    let mine: Vec<&Visit<'_>> = batch.iter().filter(|v| owns(&v.id)).collect();
                    compare_batch(layout, &view, &mine, out);
                    if let Some(f) = finest.as_mut() {
                        for v in batch.iter().filter(|v| writes(&v.id)) {
                            f(v.id, v.grid, v.valid);
                        }
                    }
                },
            )?;
            pool.give_refinements(std::mem::replace(&mut own, next).into_values());
        }
        pool.give_refinements(apex.into_values());
        Ok(())
    }

    /// Hands `finest`, in the whole walk's order, the apex diamonds of `face` with centres in
    /// columns `xs` (widened by the level's radius) that `writes` takes.
    fn apex_writes(
        &self,
        face: u8,
        xs: (i64, i64),
        writes: &dyn Fn(&DiamondId) -> bool,
        finest: &mut FinestVisit<'_>,
    ) -> Result<(), CodecError> {
        let layout = self.outline.domain.layout();
        self.apex_finest
            .visit((face, xs), &|level| layout.radius(level), writes, finest)
    }

    fn side(&self) -> i64 {
        self.outline.domain.cube().expect("a cube-sphere").side()
    }

    /// Per level from the cut, in id order: the visited diamonds of `face` with centres in
    /// columns `xs` (widened by the level's radius) that `keep` takes, and their ancestors
    /// down to the cut.
    fn needed(
        &self,
        face: u8,
        xs: (i64, i64),
        keep: &dyn Fn(&DiamondId) -> bool,
    ) -> Vec<Vec<DiamondId>> {
        let domain = &self.outline.domain;
        let layout = domain.layout();
        let last = layout.finest_level();
        let mut needed = Vec::new();
        let mut below: Vec<DiamondId> = Vec::new();
        for level in (self.cut..=last).rev() {
            let ids = &self.visited[usize::from(level - self.cut)];
            let r = layout.radius(level);
            let at = |id: &DiamondId| (id.face, i64::from(id.x));
            let (a, b) = (
                ids.partition_point(|id| at(id) < (face, xs.0 - r)),
                ids.partition_point(|id| at(id) <= (face, xs.1 + r)),
            );
            let mut set: BTreeSet<DiamondId> = ids[a..b].iter().copied().filter(keep).collect();
            set.extend(below.iter().flat_map(|&d| domain.parents(d)).flatten());
            below = set.into_iter().collect();
            needed.push(below.clone());
        }
        needed.reverse();
        needed
    }

    /// The lattice the block's owned diamonds are compared with: its own tiles whole, of the
    /// others the parts under those diamonds.
    fn lattice_view(
        &self,
        group: &TileGroup,
        tiles: &dyn PlanetTiles,
        needed: &[Vec<DiamondId>],
        owns: &(dyn Fn(&DiamondId) -> bool + Sync),
    ) -> Result<PlanetGrid, CodecError> {
        let domain = &self.outline.domain;
        let across = tiles_across(self.side(), self.outline.tile_log2);
        let mut wanted: HashMap<(u8, usize), Option<Rect>> = group
            .tiles(across)
            .map(|i| ((group.face, i), None))
            .collect();
        for id in needed.iter().flatten().filter(|id| owns(id)) {
            for (f, i, r) in tiles_under(domain, self.outline.tile_log2, *id) {
                wanted
                    .entry((f, i))
                    .and_modify(|w| *w = w.map(|w| union(w, r)))
                    .or_insert(Some(r));
            }
        }
        let held = wanted
            .into_par_iter()
            .map(|((f, i), part)| {
                let tile = match part {
                    Some(part) => tiles.tile_part(f, i, part)?,
                    None => tiles.tile(f, i, 0)?,
                };
                Ok(((f, i), tile))
            })
            .collect::<Result<HashMap<_, _>, CodecError>>()?;
        held_planet(self.outline, held)
    }
}

/// One level above the cut, decoded over the whole planet in runs of diamonds
/// ([`PlanetBlockVerify::new`]).
struct ApexLevel<'w, 'a> {
    decoder: &'w Decoder,
    records: &'w LevelRecords<'a>,
    outline: &'w PlanetOutline,
    view: &'w ApexView,
    /// `log2` of the steps between the level's vertices.
    stride: u32,
    /// Diamonds decoded at once.
    run: usize,
    pool: &'w GridPool,
}

impl ApexLevel<'_, '_> {
    /// Decodes the visited diamonds `ids`, a run at a time, each run's parents' refinements read
    /// back from `prev`; compares them with the lattice into `out` and hands their grids to
    /// `grids` where given: the level's refinements, spilled.
    fn walk(
        &self,
        ids: &[DiamondId],
        prev: &ApexRefinements,
        out: &mut LevelReport,
        mut grids: Option<&mut ApexFinest>,
        scratch: &mut RefineScratch,
    ) -> Result<ApexRefinements, CodecError> {
        let domain = &self.decoder.params().domain;
        let mut spill = RefinedSpill::new(domain.n());
        let mut failed = None;
        for ids in ids.chunks(self.run) {
            let above = prev.load(ids.iter().flat_map(|&id| domain.parents(id)).flatten())?;
            let next = walk_level(
                self.decoder,
                ids,
                self.records,
                &above,
                scratch,
                self.pool,
                &mut |batch: &[Visit<'_>]| {
                    if failed.is_some() {
                        return;
                    }
                    let compared =
                        compare_apex_batch(self.outline, self.view, self.stride, batch, out);
                    let put = grids.as_mut().map_or(Ok(()), |g| g.put_all(batch));
                    failed = compared.and(put).err();
                },
            )?;
            if let Some(e) = failed {
                return Err(e);
            }
            let mut next: Vec<(DiamondId, Refined)> = next.into_iter().collect();
            next.sort_unstable_by_key(|&(id, _)| id);
            for (id, refined) in &next {
                spill.put(*id, refined)?;
            }
            self.pool.give_refinements(next.into_iter().map(|(_, r)| r));
            self.pool.give_refinements(above.into_values());
        }
        spill.finish()
    }
}

/// The lattice points `(x0, y0, x1, y1)` (inclusive) of `group`'s tiles.
pub fn group_rect(group: &TileGroup, side: i64, tile_log2: u32) -> Rect {
    let t = 1i64 << tile_log2;
    let lo = |a: usize| (a as i64 * t).min(side);
    let hi = |b: usize| ((b as i64 + 1) * t).min(side);
    (
        lo(group.first.0),
        lo(group.first.1),
        hi(group.last.0),
        hi(group.last.1),
    )
}

/// The diamonds the whole walk visits on `level`, in id order: the recorded ones and, below
/// the roots, the children of the level above's recorded ones whose existing parents all are.
fn visited_on(params: &CodecParams, levels: &[LevelRecords<'_>], level: u8) -> Vec<DiamondId> {
    let stored = &levels[usize::from(level)];
    if level == 0 {
        return stored.ids.clone();
    }
    let domain = &params.domain;
    let above = &levels[usize::from(level) - 1];
    let mut ids: Vec<DiamondId> = above
        .ids
        .iter()
        .flat_map(|&p| domain.children(p))
        .flatten()
        .filter(|&c| {
            domain
                .parents(c)
                .into_iter()
                .flatten()
                .all(|p| above.get(p).is_some())
        })
        .collect();
    ids.extend_from_slice(&stored.ids);
    ids.sort_unstable();
    ids.dedup();
    ids
}

/// Compares an apex batch with the lattice: the tiles under its diamonds read from `view` on
/// multiples of `2^stride` (the level's vertices lie there).
fn compare_apex_batch(
    outline: &PlanetOutline,
    view: &ApexView,
    stride: u32,
    batch: &[Visit<'_>],
    report: &mut LevelReport,
) -> Result<(), CodecError> {
    let domain = &outline.domain;
    let wanted: BTreeSet<(u8, usize)> = batch
        .iter()
        .flat_map(|v| tiles_under(domain, outline.tile_log2, v.id))
        .map(|(f, i, _)| (f, i))
        .collect();
    let held: HashMap<(u8, usize), Arc<PlanetTile>> = view.tiles(&wanted, stride)?;
    let planet = held_planet(outline, held)?;
    let all: Vec<&Visit<'_>> = batch.iter().collect();
    compare_batch(domain.layout(), &planet, &all, report);
    Ok(())
}

/// Adds `batch`'s diamonds to `report`: every vertex where `planet` has data compared with it
/// (as [`super::verify_planet`] does).
fn compare_batch(
    layout: &Layout,
    planet: &PlanetGrid,
    batch: &[&Visit<'_>],
    report: &mut LevelReport,
) {
    let n = layout.n();
    let (max, vertices) = batch
        .par_iter()
        .map(|v| {
            let g = layout.grid(v.id);
            let (mut max, mut count) = (0u32, 0u64);
            for j in 0..n {
                for i in 0..n {
                    let (x, y) = g.point(i as i64, j as i64);
                    let Some(want) = planet.get(v.id.face, x, y) else {
                        continue;
                    };
                    let e = (i64::from(v.grid[j * n + i]) - i64::from(want)).unsigned_abs();
                    max = max.max(u32::try_from(e).unwrap_or(u32::MAX));
                    count += 1;
                }
            }
            (max, count)
        })
        .reduce(|| (0, 0), |a, b| (a.0.max(b.0), a.1 + b.1));
    report.diamonds += batch.len();
    report.vertices += vertices;
    report.max_error = report.max_error.max(max);
}
