//! Encoding a planet block by block, its tiles read as each block needs them: the same records,
//! byte for byte, as [`super::encode_planet`] over the whole planet, with never more than an
//! apex view and one block's tiles of the lattice held.
//!
//! A planet's face is cut into tiles ([`PlanetGrid::tile_rects`]); a block is one tile
//! ([`PlanetBlocks::new`]) or a rectangle of tiles of one face grouped by memory
//! ([`PlanetBlocks::with_block_bytes`], [`BlockGroups`]). The encode runs in three parts:
//!
//! 1. An [`PlanetOutline`], gathered one tile at a time: the leaves each tile's points make
//!    (the stored diamonds are the leaves and their ancestors, as the whole encoder finds them),
//!    whether some point is a hole (the nodata mask) and whether any has data.
//! 2. The **apex** ([`super::apex`]): the root field and the levels above a cut level, over the
//!    whole planet, each level in runs of diamonds reading only the tiles under them, thinned to
//!    the points that level reads. The apex spills each of its diamonds' grids and the last
//!    level's refinements; its object errors are measured by the blocks.
//! 3. The **blocks**: the stored diamonds from the cut down whose centres lie in the block's
//!    tiles (the block *owns* them; a tile owns its first row and column, its last only on
//!    the face's far side) and their ancestors down to the cut, each gathered from its parents
//!    as the whole encoder does — a diamond's refinement depends on its parents' and its own
//!    points only (α = 1), so it is the same wherever it is computed. The block reads the tiles
//!    under those diamonds (across face edges and cube corners through the cube's
//!    `locate`/`representations`), records the diamonds it owns with their object errors, and
//!    measures its own tile's share of the apex diamonds' errors: a planet diamond's error is the
//!    largest over the tiles under it (on each face it lies on), so the largest over the blocks
//!    is the whole encoder's.

use std::collections::{BTreeSet, HashMap};

use rayon::prelude::*;

use super::apex::PlanetApex;
use super::apex_view::{ApexView, ApexViewWriter};
use super::block_groups::{BlockGroups, TileGroup};
use super::finished::{BYTES_PER_RECORD, BYTES_PER_STORED, FinishedRecords};
use super::grid::{tiles_across, tiles_meeting};
use super::outline::PlanetOutline;
use super::tile_source::{PlanetTiles, Rect, held_planet, tiles_under, union};
use super::{
    PlanetGrid, TiledError, grid_from_parents, planet_params, planet_surface_error, refine_diamond,
    views,
};
use crate::CodecError;
use crate::geometry::{DiamondId, Domain};
use crate::hierarchy::blocks::{BlockJournal, BlockOutput};
use crate::hierarchy::encode::EncodeOptions;
use crate::hierarchy::refine::Refined;
use crate::hierarchy::resolution::with_parents;
use crate::hierarchy::{Encoded, Record};
use crate::quant::Quantizer;

/// Bytes an id takes in a set of ids built in order (a B-tree's full leaves of 11 ids of 12
/// bytes and their headers, 13.1 bytes an id) with room for its inner nodes and half-full leaves.
pub(super) const SET_BYTES_PER_ID: u64 = 16;

/// The deepest cut [`default_cut`] takes: a block's tile this many of the cut level's radii
/// across (the blocks' margins, the ancestors of the diamonds they own, about 2 radii each
/// side), as for planar blocks ([`crate::hierarchy::BlockPlan`]).
const TILE_IN_CUT_RADII: i64 = 32;

/// The apex reads the lattice at least `2^APEX_MIN_SHIFT` steps apart (a 64th of the points at
/// most), so that it stays small beside the blocks.
const APEX_MIN_SHIFT: u32 = 3;

/// How many blocks ahead a neighbour's tile may be encoded in and still be painted whole when
/// a block reaches into it (kept in the tiles' cache until its own block asks for it), rather
/// than only the strip the block reaches: a block is mostly one tile, and in the blocks' order
/// (quarters in turn) a tile's eastern, southern and south-eastern neighbours in its quarter
/// come within three.
const NEIGHBOURS_AHEAD: usize = 3;

/// The cut level for tiles of `2^tile_log2` steps: the deepest level whose radius fits
/// [`TILE_IN_CUT_RADII`] times in a tile, two levels above the finest at most, and no deeper
/// than lets the apex read every `2^`[`APEX_MIN_SHIFT`]-th point.
pub fn default_cut(domain: &Domain, tile_log2: u32) -> u8 {
    let layout = domain.layout();
    let finest = layout.finest_level();
    let apex = 2 * layout.k().saturating_sub(APEX_MIN_SHIFT);
    (0..=finest)
        .find(|&l| layout.radius(l) * TILE_IN_CUT_RADII <= 1i64 << tile_log2)
        .unwrap_or(finest)
        .min(finest.saturating_sub(2))
        .min(u8::try_from(apex).unwrap_or(u8::MAX))
}

/// Encodes the planet that `outline` outlines and `tiles` hands out, block by block (see the
/// module documentation), cut at level `cut` (clamped to the finest level;
/// [`default_cut`] is a good one): the same [`Encoded`] as [`super::encode_planet`] of the
/// whole planet. Blocks `journal` kept are not encoded again (block `i` is tile
/// `i % tiles_per_face` of face `i / tiles_per_face`); `spill`: finished records' bytes wait
/// in a temporary file.
pub fn encode_planet_in_blocks(
    outline: &PlanetOutline,
    tiles: &dyn PlanetTiles,
    quantizer: Quantizer,
    opts: &EncodeOptions,
    cut: u8,
    journal: &dyn BlockJournal,
    spill: bool,
) -> Result<Encoded, CodecError> {
    PlanetBlocks::new(
        outline,
        tiles,
        quantizer,
        opts,
        cut,
        Apex::Encode(APEX_VIEW_BYTES),
    )?
    .finish(journal, spill)
}

/// The bytes of tiles a run of the apex reads at once when the caller names no budget
/// ([`encode_planet_in_blocks`]).
pub const APEX_VIEW_BYTES: u64 = 64 << 20;

/// Where a block-wise encode's apex comes from.
#[derive(Debug)]
pub enum Apex {
    /// Encoded from the tiles, each run of an apex level reading at most about this many bytes
    /// of tiles ([`super::apex`]): the same apex whatever the budget. The tiles are first
    /// asked for once each, thinned to what the apex reads ([`ApexViewWriter::put_all`]).
    Encode(u64),
    /// Encoded as [`Apex::Encode`] from a view of the tiles written as they were painted
    /// ([`ApexViewWriter::put`], for the same planet and cut): no tile is asked for again.
    EncodeFrom(u64, ApexView),
    /// As [`PlanetBlocks::apex`] gave it for the same planet and cut.
    Given(Box<PlanetApex>),
}

/// The blocks [`PlanetBlocks::with_block_bytes`] makes of the planet `outline` outlines, cut
/// at `cut`: for a plan that needs their count before any is encoded.
pub fn planet_block_groups(
    outline: &PlanetOutline,
    cut: u8,
    strides: &[Vec<u32>],
    budget: (u64, usize),
) -> Result<BlockGroups, CodecError> {
    let domain = outline.domain;
    let sets = with_parents(&domain, &outline.leaves);
    let cut = cut.min(domain.finest_level());
    BlockGroups::within(
        &domain,
        outline.tile_log2,
        strides,
        &sets.stored,
        cut,
        budget,
    )
}

/// A planet's block-wise encode split at its seams, for builds whose blocks run in other
/// processes (sharded builds): the apex (encoded, or handed over as an earlier process
/// encoded it), any block on its own, and the merge of every block's output.
pub struct PlanetBlocks<'a> {
    outline: &'a PlanetOutline,
    tiles: &'a dyn PlanetTiles,
    params: crate::hierarchy::CodecParams,
    stored: Vec<Vec<DiamondId>>,
    recorded: Vec<BTreeSet<DiamondId>>,
    apex: PlanetApex,
    cut: u8,
    groups: BlockGroups,
}

impl<'a> PlanetBlocks<'a> {
    /// The encode of the planet `outline` outlines, cut at `cut` (clamped to the finest
    /// level), its apex encoded or given ([`Apex`]).
    pub fn new(
        outline: &'a PlanetOutline,
        tiles: &'a dyn PlanetTiles,
        quantizer: Quantizer,
        opts: &EncodeOptions,
        cut: u8,
        apex: Apex,
    ) -> Result<Self, CodecError> {
        let domain = outline.domain;
        let params = planet_params(domain, quantizer, opts, outline.has_nodata)?;
        if !outline.has_data {
            return Err(CodecError::invalid("the planet has no valid sample"));
        }
        let sets = with_parents(&domain, &outline.leaves);
        let cut = cut.min(domain.finest_level());
        let apex = match apex {
            Apex::Given(apex) => *apex,
            Apex::Encode(view_bytes) => {
                let view = ApexViewWriter::new(&domain, outline.tile_log2, cut);
                view.put_all(tiles, domain.faces())?;
                let sets = (&sets.stored[..], &sets.recorded[..]);
                PlanetApex::encode(outline, &view.finish()?, &params, sets, cut, view_bytes)?
            }
            Apex::EncodeFrom(view_bytes, view) => {
                let sets = (&sets.stored[..], &sets.recorded[..]);
                PlanetApex::encode(outline, &view, &params, sets, cut, view_bytes)?
            }
        };
        Ok(Self {
            outline,
            tiles,
            params,
            stored: sets.stored,
            recorded: sets.recorded,
            apex,
            cut,
            groups: BlockGroups::one_per_tile(&domain, outline.tile_log2),
        })
    }

    /// The same encode with its tiles grouped into blocks of about `budget.0` bytes each, and
    /// at least `budget.1` blocks ([`BlockGroups::within`]; `strides`, per face, per tile:
    /// `log2` of the stride it holds its points at) instead of one block per tile: the same
    /// bytes, far fewer blocks where the planet is coarse.
    pub fn with_block_bytes(
        mut self,
        strides: &[Vec<u32>],
        budget: (u64, usize),
    ) -> Result<Self, CodecError> {
        self.groups = BlockGroups::within(
            &self.outline.domain,
            self.outline.tile_log2,
            strides,
            &self.stored,
            self.cut,
            budget,
        )?;
        Ok(self)
    }

    /// Bytes the encode holds for the planet's diamonds whatever its blocks, until it is
    /// finished: the outline's leaves, the stored and recorded sets, and what the finished
    /// records keep ([`FinishedRecords`]). A memory plan takes them from what its blocks may
    /// hold.
    pub fn diamond_bytes(&self) -> u64 {
        let count = |sets: &mut dyn Iterator<Item = usize>| sets.map(|n| n as u64).sum::<u64>();
        let leaves = count(&mut self.outline.leaves.iter().map(BTreeSet::len));
        let stored = count(&mut self.stored.iter().map(Vec::len));
        let recorded = count(&mut self.recorded.iter().map(BTreeSet::len));
        let id = std::mem::size_of::<DiamondId>() as u64;
        (leaves + recorded) * SET_BYTES_PER_ID
            + stored * (id + BYTES_PER_STORED)
            + recorded * BYTES_PER_RECORD
    }

    /// The apex: the levels above the cut.
    pub fn apex(&self) -> &PlanetApex {
        &self.apex
    }

    /// How many blocks: one per tile, or per group of tiles ([`Self::with_block_bytes`]).
    pub fn block_count(&self) -> usize {
        self.groups.len()
    }

    fn block_encode(&self) -> BlockEncode<'_> {
        let domain = self.outline.domain;
        let side = domain.cube().expect("a cube-sphere").side();
        BlockEncode {
            outline: self.outline,
            tiles: self.tiles,
            params: &self.params,
            stored: &self.stored,
            recorded: &self.recorded,
            apex: &self.apex,
            cut: self.cut,
            side,
            across: tiles_across(side, self.outline.tile_log2),
        }
    }

    /// Encodes block `index` (its tiles: [`Self::block_tiles`]).
    pub fn encode_block(&self, index: usize) -> Result<BlockOutput, CodecError> {
        let Some(group) = self.groups.get(index) else {
            return Err(CodecError::invalid(format!(
                "block {index} of a planet of {} blocks",
                self.block_count()
            )));
        };
        self.block_encode().encode(group, &|_, _| false)
    }

    /// The block of each tile in a block of fewer than 64 tiles ([`BlockGroups::block_of_tiles`]).
    pub fn block_of_tiles(&self) -> HashMap<(u8, usize), usize> {
        self.groups.block_of_tiles(self.block_encode().across)
    }

    /// The tiles of block `index`, if there is one.
    pub fn block_tiles(&self, index: usize) -> Option<&TileGroup> {
        self.groups.get(index)
    }

    /// Every block's output (from `journal`, else encoded and saved there) and the apex's put
    /// together: the planet's [`Encoded`].
    pub fn finish(&self, journal: &dyn BlockJournal, spill: bool) -> Result<Encoded, CodecError> {
        self.finish_with(journal, spill, &mut |_| Ok(()))
    }

    /// [`Self::finish`], calling `after_block` with each block's index once it is done (encoded
    /// or found in `journal`), in block order.
    pub fn finish_with(
        &self,
        journal: &dyn BlockJournal,
        spill: bool,
        after_block: &mut dyn FnMut(usize) -> Result<(), CodecError>,
    ) -> Result<Encoded, CodecError> {
        let domain = self.outline.domain;
        let recorded = self.recorded.iter().map(BTreeSet::len).sum();
        let mut finished = FinishedRecords::new(&self.stored, recorded, spill)?;
        finished.keep(&self.apex.records)?;
        for id in self.apex.grids.ids() {
            finished.measure(id, 0);
        }
        let block = self.block_encode();
        let block_of = self.groups.block_of_tiles(block.across);
        for index in 0..self.block_count() {
            let output = match journal.load(index)? {
                Some(output) => output,
                None => {
                    let group = self.groups.get(index).expect("a block of the planet");
                    // A neighbour's tile whose own block comes within the next few is painted
                    // whole (and kept in the tiles' cache for that block), not only its strip.
                    let soon = |f: u8, i: usize| {
                        block_of
                            .get(&(f, i))
                            .is_some_and(|&b| index < b && b <= index + NEIGHBOURS_AHEAD)
                    };
                    let output = block.encode(group, &soon)?;
                    journal.save(index, &output)?;
                    output
                }
            };
            finished.keep(&output.records)?;
            for (id, e) in output.own_errors {
                finished.measure(id, e);
            }
            after_block(index)?;
        }
        let (records, leaf_error) = finished.finish(&domain)?;
        Ok(Encoded {
            params: self.params,
            roots: self.apex.roots.clone(),
            records,
            leaf_error,
        })
    }
}

/// A planet holding only `wanted`'s tiles at their own strides: whole (`None`) or with at
/// least the points of a rectangle ([`PlanetTiles::tile_part`]).
fn view_of_parts(
    outline: &PlanetOutline,
    tiles: &dyn PlanetTiles,
    wanted: HashMap<(u8, usize), Option<Rect>>,
    whole: &(dyn Fn(u8, usize) -> bool + Sync),
) -> Result<PlanetGrid, CodecError> {
    let held = wanted
        .into_par_iter()
        .map(|((f, i), part)| {
            let tile = match part {
                Some(part) if !whole(f, i) => tiles.tile_part(f, i, part)?,
                _ => tiles.tile(f, i, 0)?,
            };
            Ok(((f, i), tile))
        })
        .collect::<Result<HashMap<_, _>, CodecError>>()?;
    held_planet(outline, held)
}

/// What every block's encode shares.
struct BlockEncode<'a> {
    outline: &'a PlanetOutline,
    tiles: &'a dyn PlanetTiles,
    params: &'a crate::hierarchy::CodecParams,
    stored: &'a [Vec<DiamondId>],
    recorded: &'a [BTreeSet<DiamondId>],
    apex: &'a PlanetApex,
    cut: u8,
    side: i64,
    /// Tiles across a face.
    across: usize,
}

impl BlockEncode<'_> {
    /// The block of the tiles of `group`; of its neighbours' tiles, those `whole` names are
    /// asked for whole rather than their strips (the same bytes: a strip is the whole tile
    /// there).
    fn encode(
        &self,
        group: &TileGroup,
        whole: &(dyn Fn(u8, usize) -> bool + Sync),
    ) -> Result<BlockOutput, CodecError> {
        let domain = &self.params.domain;
        let finest = domain.finest_level();
        let face = group.face;
        let (xs, ys) = group.owned_span(self.side, self.outline.tile_log2);
        let owns = |id: &DiamondId| {
            let (x, y) = (i64::from(id.x), i64::from(id.y));
            id.face == face && xs.0 <= x && x <= xs.1 && ys.0 <= y && y <= ys.1
        };
        let needed = self.needed(face, xs, &owns);
        // Its own tiles whole, and of the others the strips its diamonds reach.
        let mut wanted: HashMap<(u8, usize), Option<Rect>> = group
            .tiles(self.across)
            .map(|i| ((face, i), None))
            .collect();
        for id in needed.iter().flatten() {
            for (f, i, r) in tiles_under(domain, self.outline.tile_log2, *id) {
                wanted
                    .entry((f, i))
                    .and_modify(|w| *w = w.map(|w| union(w, r)))
                    .or_insert(Some(r));
            }
        }
        let view = view_of_parts(self.outline, self.tiles, wanted, whole)?;
        let errors = TiledError::new(&view)?;
        let mut output = BlockOutput::default();
        // The cut level gathers from the apex's last refinements: those its diamonds' parents.
        let first = needed.first().into_iter().flatten();
        let mut prev: HashMap<DiamondId, Refined> = self
            .apex
            .last
            .load(first.flat_map(|&id| domain.parents(id)).flatten())?;
        for level in self.cut..=finest {
            type Output = (DiamondId, Option<(Refined, Record)>, Option<u32>);
            let parents = &prev;
            let results = needed[usize::from(level - self.cut)]
                .par_iter()
                .map(|&id| -> Result<Output, CodecError> {
                    let p = grid_from_parents(domain, &self.apex.root_field, id, parents);
                    let err = owns(&id).then(|| planet_surface_error(domain, id, &p, &errors));
                    let refined = match self.recorded[level as usize].contains(&id) {
                        true => Some(refine_diamond(self.params, &view, id, &p)?),
                        false => None,
                    };
                    Ok((id, refined, err))
                })
                .collect::<Result<Vec<_>, CodecError>>()?;
            let mut next = HashMap::new();
            for (id, refined, err) in results {
                if let Some(e) = err {
                    output.own_errors.push((id, e));
                }
                if let Some((refined, record)) = refined {
                    if owns(&id) {
                        output.records.push(record);
                    }
                    next.insert(id, refined);
                }
            }
            prev = next;
        }
        output.own_errors.extend(self.apex_shares(group, &errors)?);
        Ok(output)
    }

    /// Per level from the cut, in id order: the stored diamonds the block owns (centres in
    /// columns `xs`, found by bisection: a level's ids are sorted by face, then column) and
    /// their ancestors down to the cut.
    fn needed(
        &self,
        face: u8,
        xs: (i64, i64),
        owns: &dyn Fn(&DiamondId) -> bool,
    ) -> Vec<Vec<DiamondId>> {
        let domain = &self.params.domain;
        let finest = domain.finest_level();
        let mut needed: Vec<Vec<DiamondId>> = Vec::new();
        let mut below: Vec<DiamondId> = Vec::new();
        for level in (self.cut..=finest).rev() {
            let ids = &self.stored[level as usize];
            let at = |id: &DiamondId| (id.face, i64::from(id.x));
            let (a, b) = (
                ids.partition_point(|id| at(id) < (face, xs.0)),
                ids.partition_point(|id| at(id) <= (face, xs.1)),
            );
            let mut set: BTreeSet<DiamondId> = ids[a..b].iter().copied().filter(owns).collect();
            set.extend(below.iter().flat_map(|&d| domain.parents(d)).flatten());
            below = set.into_iter().collect();
            needed.push(below.clone());
        }
        needed.reverse();
        needed
    }

    /// The apex diamonds' errors measured on this block's tiles alone.
    fn apex_shares(
        &self,
        group: &TileGroup,
        errors: &TiledError,
    ) -> Result<Vec<(DiamondId, u32)>, CodecError> {
        let domain = &self.params.domain;
        let layout = domain.layout();
        let face = group.face;
        let ids = self.apex.meeting(group);
        ids.into_par_iter()
            .map(|id| {
                let grid = self.apex.grids.get(id)?.expect("an apex diamond's grid");
                let e = views(domain, id, &grid)
                    .into_iter()
                    .filter(|(seen, _)| seen.face == face)
                    .filter_map(|(seen, q)| {
                        let mine: Vec<usize> =
                            tiles_meeting(self.side, self.outline.tile_log2, layout.bounds(seen))
                                .filter(|&i| group.holds(i, self.across))
                                .collect();
                        (!mine.is_empty()).then(|| errors.face_error_over(seen, &q, mine))
                    })
                    .max()
                    .unwrap_or(0);
                Ok((id, e))
            })
            .collect()
    }
}
