//! Encoding the fine levels block by block: the unit of work of out-of-core, resumable and
//! sharded builds.
//!
//! With α = 1 a diamond's refinement depends only on the reconstructed values at its own grid
//! points, which its ancestors wrote (see [`super::field`]). An ancestor at level `l` of a
//! diamond lies within [`BlockPlan::reach`]`(l)` of it (L∞, lattice units): the sum of the radii
//! of the levels between, since a parent's centre is within the parent's radius of its child's.
//! So the levels from a cut level down can be encoded one square block of the domain at a time:
//! an *apex* field holds the points of the levels above the cut (all on a lattice of spacing
//! `2^`[`BlockPlan::apex_shift`]), and each block encodes, level by level, the diamonds whose
//! centre lies within the reach of its square, in a field of its own seeded from the apex. The
//! diamonds whose centre is in the square are the block's: their records and errors are exactly
//! what the whole-domain encoder gives. The others are its margin, encoded again by each
//! neighbour that needs them and recorded by the block that owns them. The margin's cost is
//! about `4 · reach / side` of the fine levels' work.

use super::Record;
use super::field::{ReconField, TempStorage};
use crate::CodecError;
use crate::geometry::{DiamondId, Layout};

/// What one block of a [`BlockPlan`] produced: the records of the diamonds it owns (object
/// errors not yet saturated: that happens once all blocks are in) and their own object errors.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct BlockOutput {
    /// Records of the block's refined diamonds, object errors 0.
    pub records: Vec<Record>,
    /// Own (unsaturated) object error of every stored diamond the block owns.
    pub own_errors: Vec<(DiamondId, u32)>,
}

/// Keeps finished blocks, so that an encode that was interrupted continues where it stopped
/// (`cbdam build`'s journal). The encoder asks for each block before encoding it and hands over
/// each block it finished.
pub trait BlockJournal: Sync {
    /// The output of block `index` from an earlier run of the same encode, if it finished.
    fn load(&self, index: usize) -> Result<Option<BlockOutput>, CodecError>;
    /// Keeps block `index`'s output; when this returns, a later run may rely on it.
    fn save(&self, index: usize, output: &BlockOutput) -> Result<(), CodecError>;
}

/// Keeps nothing: every block is encoded.
pub struct NoJournal;

impl BlockJournal for NoJournal {
    fn load(&self, _index: usize) -> Result<Option<BlockOutput>, CodecError> {
        Ok(None)
    }
    fn save(&self, _index: usize, _output: &BlockOutput) -> Result<(), CodecError> {
        Ok(())
    }
}

/// Bytes a block holds besides its reconstruction field, for a field of `rows` rows of
/// `row_len` points: the window of an input in mapped files it reads
/// ([`crate::quant::HeightGrid::window_bytes`]), or nothing ([`NO_WINDOW`]). Asked also with
/// the apex field's size, for the apex's copy of its points of such an input (an upper bound:
/// that copy is compact).
pub type WindowBytes<'a> = dyn Fn(usize, usize) -> u64 + Sync + 'a;

/// An input read in place: no window.
pub const NO_WINDOW: fn(usize, usize) -> u64 = |_, _| 0;

/// How the encoder splits the levels into an apex and blocks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BlockPlan {
    /// The first level encoded in blocks; the levels above it make the apex.
    pub cut_level: u8,
    /// Side of a block's square, lattice units (the last block of a row or column takes the
    /// rest of the domain).
    pub block_side: i64,
}

/// The deepest cut tried for a block side: the cut level's radius this many times smaller than
/// the side, and two levels above the finest at most (a deeper cut leaves the apex nearly the
/// whole field). Its margin (about 5 radii each side) then costs about a third of the cut
/// level's work and next to nothing at the finest levels; shallower cuts shrink the apex and
/// grow the margin. Measured on 4097² and 8193² synthetic terrain (`cbdam build
/// --block-plan`): this choice encodes as fast as the whole field (CPU ratio 0.99–1.02) with a
/// quarter less peak memory.
const SIDE_IN_CUT_RADII: i64 = 32;
/// The shallowest cut tried: a block 4 of its cut level's radii across.
const MIN_SIDE_IN_CUT_RADII: i64 = 4;

impl BlockPlan {
    /// The plan with the largest blocks whose fields (the apex's and one block's,
    /// [`BlockPlan::field_bytes`]) take at most `budget` bytes, with the deepest cut that fits
    /// (the least work in margins); `None` when no plan fits. Blocks are a root's side halved
    /// `j` times, at least 8 finest radii across.
    pub fn fitting(layout: &Layout, budget: u64) -> Option<BlockPlan> {
        Self::fitting_at_most(layout, budget, layout.root_side(), &NO_WINDOW)
    }

    /// [`BlockPlan::fitting`] with blocks at most `max_side` across (rounded down to a root's
    /// side halved `j` times): for a build that wants several blocks (units of work to resume
    /// from) even when one would fit; and with a block's `window` of the input counted
    /// besides its field.
    pub fn fitting_at_most(
        layout: &Layout,
        budget: u64,
        max_side: i64,
        window: &WindowBytes<'_>,
    ) -> Option<BlockPlan> {
        Self::first_fitting(layout, max_side, |plan| {
            plan.field_bytes(layout, window) <= budget
        })
    }

    /// The first plan that `fits` accepts, trying the largest blocks first (a root's side halved
    /// `j` times, at most `max_side` and at least 8 finest radii across) and for each side the
    /// deepest cut first (the least work in margins; see [`SIDE_IN_CUT_RADII`]).
    pub fn first_fitting(
        layout: &Layout,
        max_side: i64,
        fits: impl Fn(&BlockPlan) -> bool,
    ) -> Option<BlockPlan> {
        let finest = layout.finest_level();
        let smallest = (8 * layout.radius(finest)).min(layout.root_side());
        let mut side = layout.root_side();
        while side > max_side.max(smallest) {
            side /= 2;
        }
        while side >= smallest && side > 0 {
            let deepest = (0..=finest)
                .find(|&l| layout.radius(l) * SIDE_IN_CUT_RADII <= side)
                .unwrap_or(finest)
                .min(finest.saturating_sub(2));
            for cut_level in (0..=deepest).rev() {
                if layout.radius(cut_level) * MIN_SIDE_IN_CUT_RADII > side {
                    break;
                }
                let plan = BlockPlan {
                    cut_level,
                    block_side: side,
                };
                if fits(&plan) {
                    return Some(plan);
                }
            }
            side /= 2;
        }
        None
    }

    /// Bytes of the fields a block encode holds at once: the apex's and one block's (the
    /// largest), with the block's `window` of the input; or, while the apex is encoded, the
    /// apex's field and its `window` of the input.
    pub fn field_bytes(&self, layout: &Layout, window: &WindowBytes<'_>) -> u64 {
        let shift = self.apex_shift(layout);
        let (ex, ey) = layout.face_extent();
        let (aw, ah) = ((ex >> shift) as usize + 1, (ey >> shift) as usize + 1);
        let apex = (aw * ah) as u64;
        let block = self
            .blocks(layout)
            .iter()
            .map(|b| {
                let (x0, y0, x1, y1) = b.field_rect;
                let (w, h) = ((x1 - x0 + 1) as usize, (y1 - y0 + 1) as usize);
                4 * (w as u64) * (h as u64) + window(h, w)
            })
            .max()
            .unwrap_or(0);
        4 * apex + block.max(window(ah, aw))
    }

    /// How far (L∞, lattice units) a diamond's ancestors at `level` or finer can lie from it.
    pub fn reach(&self, layout: &Layout, level: u8) -> i64 {
        (level..layout.finest_level())
            .map(|l| layout.radius(l))
            .sum()
    }

    /// Log2 of the spacing of the lattice that holds every point of the levels above the cut:
    /// the vertices of the cut level's diamonds, `2^(K − ⌈cut/2⌉)` apart.
    pub fn apex_shift(&self, layout: &Layout) -> u32 {
        layout.k() - u32::from(self.cut_level.min(layout.finest_level())).div_ceil(2)
    }

    /// The apex's field: the whole domain at [`BlockPlan::apex_shift`].
    pub(crate) fn apex_field(
        &self,
        layout: &Layout,
        storage: &TempStorage,
    ) -> Result<ReconField, CodecError> {
        let shift = self.apex_shift(layout);
        let (ex, ey) = layout.face_extent();
        ReconField::window(
            (0, 0),
            shift,
            (ex >> shift) as usize + 1,
            (ey >> shift) as usize + 1,
            storage,
        )
    }

    /// The blocks, row by row.
    pub fn blocks(&self, layout: &Layout) -> Vec<Block> {
        let (ex, ey) = layout.face_extent();
        let side = self.block_side.max(1);
        let count = |e: i64| ((e + side - 1) / side).max(1);
        let span = |i: i64, e: i64| {
            (
                i * side,
                if i == count(e) - 1 {
                    e
                } else {
                    (i + 1) * side - 1
                },
            )
        };
        let cut = self.cut_level.min(layout.finest_level());
        let margin = self.reach(layout, cut) + layout.radius(cut);
        let apex_shift = self.apex_shift(layout);
        let mut out = Vec::new();
        for j in 0..count(ey) {
            for i in 0..count(ex) {
                let (x0, x1) = span(i, ex);
                let (y0, y1) = span(j, ey);
                out.push(Block {
                    owned: (x0, y0, x1, y1),
                    field_rect: (
                        (x0 - margin).max(0),
                        (y0 - margin).max(0),
                        (x1 + margin).min(ex),
                        (y1 + margin).min(ey),
                    ),
                    apex_shift,
                });
            }
        }
        out
    }
}

/// One block of a [`BlockPlan`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Block {
    /// The lattice rectangle `(x0, y0, x1, y1)`, inclusive, whose diamonds (by centre) the block
    /// records.
    pub owned: (i64, i64, i64, i64),
    /// The rectangle its field covers: the owned one grown by the reach of the cut level and
    /// its radius, clipped to the domain.
    pub field_rect: (i64, i64, i64, i64),
    /// The apex field's spacing, log2.
    pub apex_shift: u32,
}

impl Block {
    /// Whether the block records `id`.
    pub fn owns(&self, id: DiamondId) -> bool {
        self.within(id, 0)
    }

    /// Whether `id`'s centre lies within `reach` of the owned rectangle.
    pub fn within(&self, id: DiamondId, reach: i64) -> bool {
        let (x0, y0, x1, y1) = self.owned;
        let (x, y) = (i64::from(id.x), i64::from(id.y));
        x >= x0 - reach && x <= x1 + reach && y >= y0 - reach && y <= y1 + reach
    }

    /// The diamonds of `ids` (one level's, in id order) within `reach` of the owned rectangle:
    /// the runs of each column in range found by binary search, so that a level's diamonds are
    /// not all visited by every block.
    pub fn select(&self, ids: &[DiamondId], reach: i64) -> Vec<DiamondId> {
        let (x0, y0, x1, y1) = self.owned;
        let (xa, xb, ya, yb) = (x0 - reach, x1 + reach, y0 - reach, y1 + reach);
        let sorted_one_face =
            ids.is_sorted() && ids.first().map(|f| f.face) == ids.last().map(|l| l.face);
        if !sorted_one_face {
            return ids
                .iter()
                .copied()
                .filter(|&id| self.within(id, reach))
                .collect();
        }
        let x = |id: &DiamondId| i64::from(id.x);
        let y = |id: &DiamondId| i64::from(id.y);
        let (start, end) = (
            ids.partition_point(|id| x(id) < xa),
            ids.partition_point(|id| x(id) <= xb),
        );
        let mut out = Vec::new();
        let mut i = start;
        while i < end {
            let column = ids[i].x;
            let run_end = i + ids[i..end].partition_point(|id| id.x == column);
            let run = &ids[i..run_end];
            let (a, b) = (
                run.partition_point(|id| y(id) < ya),
                run.partition_point(|id| y(id) <= yb),
            );
            out.extend_from_slice(&run[a..b]);
            i = run_end;
        }
        out
    }

    /// A field over the block's rectangle.
    pub(crate) fn field(&self, storage: &TempStorage) -> Result<ReconField, CodecError> {
        let (x0, y0, x1, y1) = self.field_rect;
        ReconField::window(
            (x0, y0),
            0,
            (x1 - x0 + 1) as usize,
            (y1 - y0 + 1) as usize,
            storage,
        )
    }

    /// The points of the apex lattice in the block's field rectangle.
    pub(crate) fn apex_points(&self) -> impl Iterator<Item = (i64, i64)> {
        let (x0, y0, x1, y1) = self.field_rect;
        let g = 1i64 << self.apex_shift;
        let first = move |a: i64| (a + g - 1) / g * g;
        (first(y0)..=y1)
            .step_by(g as usize)
            .flat_map(move |y| (first(x0)..=x1).step_by(g as usize).map(move |x| (x, y)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocks_tile_the_domain_and_fields_cover_their_margins() {
        let layout = Layout::new(65, 5, 3, 2).unwrap();
        let (ex, ey) = layout.face_extent();
        for plan in [
            BlockPlan {
                cut_level: 4,
                block_side: 1000,
            },
            BlockPlan {
                cut_level: 7,
                block_side: 512,
            },
            BlockPlan {
                cut_level: 30,
                block_side: 4096,
            },
        ] {
            let blocks = plan.blocks(&layout);
            // Every lattice point's diamond centre is owned by exactly one block.
            for (x, y) in [
                (0, 0),
                (ex, ey),
                (ex, 0),
                (999, 1000),
                (1000, 999),
                (ex / 2, ey / 2),
            ] {
                let id = DiamondId::new(layout.finest_level(), x as u32, y as u32);
                assert_eq!(
                    blocks.iter().filter(|b| b.owns(id)).count(),
                    1,
                    "{plan:?} ({x}, {y})"
                );
            }
            let cut = plan.cut_level.min(layout.finest_level());
            for b in &blocks {
                for level in cut..=layout.finest_level() {
                    for id in layout
                        .level(level)
                        .filter(|&id| b.within(id, plan.reach(&layout, level)))
                    {
                        // A diamond the block encodes lies in its field (clipped to the domain).
                        let (x0, y0, x1, y1) = layout.bounds(id);
                        let (f0, g0, f1, g1) = b.field_rect;
                        assert!(
                            x0.max(0) >= f0
                                && y0.max(0) >= g0
                                && x1.min(ex) <= f1
                                && y1.min(ey) <= g1,
                            "{plan:?}: {id} outside {:?}",
                            b.field_rect
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn fitting_plans_fit_and_prefer_large_blocks() {
        let layout = Layout::new(65, 8, 1, 1).unwrap();
        let (ex, ey) = layout.face_extent();
        let whole = 4 * (ex as u64 + 1) * (ey as u64 + 1);
        // About a tenth of the whole field is the floor with one level of blocks: the apex
        // must hold the points down to a cut fine enough for the blocks' margins.
        for budget in [whole / 2, whole / 4, whole / 8] {
            let plan = BlockPlan::fitting(&layout, budget).expect("a plan fits");
            assert!(
                plan.field_bytes(&layout, &NO_WINDOW) <= budget,
                "{plan:?} over {budget}"
            );
        }
        let big = BlockPlan::fitting(&layout, whole / 2).unwrap();
        let small = BlockPlan::fitting(&layout, whole / 8).unwrap();
        assert!(big.block_side >= small.block_side, "{big:?} vs {small:?}");
        assert_eq!(BlockPlan::fitting(&layout, 1000), None);
    }
}
