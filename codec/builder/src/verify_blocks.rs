//! `cbdam verify` of a multi-input build in bounded memory: the hierarchy decoded block by block
//! ([`BlockWalk`]) while the inputs are composed block of rows by block of rows, as the build
//! reads them.
//!
//! The whole-hierarchy comparison holds the reconstruction, the nodata states and a level's
//! refinements for every lattice point at once (26 bytes a point: 7 GB at 16385²). Here the
//! apex's refinements, one row of blocks' reconstruction (5 bytes a point of the row) and each
//! worker's block refinements are held; the lattice's classes and quantized heights stay in the
//! mosaic's storage (mapped files above the memory limit), read by window. The comparison is the
//! whole one's ([`super::compare_tiles_whole`]): [`BlockWalk`] visits exactly the diamonds the
//! whole walk visits and leaves every point as it does.

use std::ops::Range;

use cbdam_codec::geometry::{DiamondId, Layout};
use cbdam_codec::hierarchy::blocks::Block;
use cbdam_codec::hierarchy::{BlockPlan, BlockWalk, CodecParams, LevelReport, Reached};
use cbdam_codec::quant::HeightGrid;
use rayon::prelude::*;

use crate::error::{Result, bail};

/// Bytes per lattice point of a walk's refinements while the level above the finest is
/// decoded: each diamond's refinement is a `(2N−1)²` half-step grid of 4-byte heights and, with
/// a nodata mask, 1-byte validities; a level has `2^l` diamonds per root of `(N−1)²·2^finest`
/// lattice points, so that level's refinements take 10 bytes a lattice point and the level
/// above's, held while it is decoded, 5. Each level up halves both.
const REFINED_BYTES: u64 = 15;
/// Bytes per lattice point of a row of blocks' reconstruction: the value and its [`Reached`].
const POINT_BYTES: u64 = 5;

/// Bytes a block-wise comparison under `plan` holds at once: the apex's refinements, one row of
/// blocks' reconstruction `width` points across, and per worker one block's refinements (at
/// the level where they are most, each level holding half the points of the next) and its
/// window of the quantized heights.
pub(crate) fn decode_bytes(layout: &Layout, plan: &BlockPlan, width: usize, workers: usize) -> u64 {
    let finest = layout.finest_level();
    let (ex, ey) = layout.face_extent();
    // Refinements held while level `l + 1` is decoded, over a square of side `s`.
    let refined = |l: u8, s: i64| {
        (REFINED_BYTES * (s.max(0) as u64).pow(2)) >> (finest - l.min(finest - 1) - 1)
    };
    let apex = match plan.cut_level {
        0 => 0,
        cut => refined(cut - 1, ex.max(ey) + 1),
    };
    let side = plan.block_side + 1;
    let block = (plan.cut_level..finest)
        .map(|l| {
            let margin = BlockWalk::reach(layout, plan, l) + layout.radius(l);
            refined(l, side + 2 * margin)
        })
        .max()
        .unwrap_or(0);
    let window =
        HeightGrid::BYTES_PER_POINT * ((side + 2 * layout.radius(plan.cut_level)) as u64).pow(2);
    let row = width as u64 * side as u64 * POINT_BYTES;
    apex + row + workers as u64 * (block + window)
}

/// The plan with the largest blocks, cut as deep as it can, whose decode takes at most `budget`
/// bytes ([`decode_bytes`]).
pub(crate) fn decode_plan(
    layout: &Layout,
    width: usize,
    workers: usize,
    budget: u64,
) -> Result<BlockPlan> {
    let bytes = |plan: &BlockPlan| decode_bytes(layout, plan, width, workers);
    if let Some(plan) = BlockPlan::first_fitting(layout, i64::MAX, |p| bytes(p) <= budget) {
        return Ok(plan);
    }
    // Over budget: say what the cheapest plan would need.
    let least = std::cell::Cell::new(None::<u64>);
    BlockPlan::first_fitting(layout, i64::MAX, |p| {
        least.set(Some(least.get().map_or(bytes(p), |b| b.min(bytes(p)))));
        false
    });
    match least.get() {
        Some(least) => bail!(
            "decoding this repository block by block needs more than the {} MiB the memory \
             limit leaves it (the smallest blocks need about {} MiB): raise --memory-limit",
            budget >> 20,
            least.div_ceil(1 << 20)
        ),
        None => bail!("this hierarchy has too few levels to decode block by block"),
    }
}

/// The reconstruction at the apex lattice's points of the data rectangle.
pub(crate) struct ApexPoints {
    shift: u32,
    width: usize,
    values: Vec<i32>,
    state: Vec<Reached>,
}

impl ApexPoints {
    /// Nothing reached yet, over a `width × height` data rectangle.
    pub(crate) fn new(shift: u32, (width, height): (usize, usize)) -> Self {
        let cols = |len: usize| ((len.max(1) - 1) >> shift) + 1;
        let len = cols(width) * cols(height);
        Self {
            shift,
            width: cols(width),
            values: vec![0; len],
            state: vec![Reached::No; len],
        }
    }

    fn index(&self, x: i64, y: i64) -> usize {
        (y >> self.shift) as usize * self.width + (x >> self.shift) as usize
    }

    fn set(&mut self, x: i64, y: i64, v: i32, s: Reached) {
        let k = self.index(x, y);
        self.values[k] = v;
        self.state[k] = s;
    }
}

/// A row of blocks' reconstruction (or the apex's), and the errors of the diamonds it owns.
pub(crate) struct Visits {
    /// Per level: diamonds, vertices and the largest error against the quantized input.
    pub(crate) levels: Vec<LevelReport>,
}

impl Visits {
    pub(crate) fn new(params: &CodecParams) -> Self {
        Self {
            levels: LevelReport::empty(params),
        }
    }

    /// Counts a diamond's grid against the quantized heights `input` (valid samples only),
    /// which holds lattice point `(x, y)` at `(x >> shift, y >> shift)` ([`HeightGrid::strided`]).
    fn check(&mut self, layout: &Layout, id: DiamondId, p: &[i32], input: &HeightGrid, shift: u32) {
        let n = layout.n();
        let g = layout.grid(id);
        let report = &mut self.levels[id.level as usize];
        report.diamonds += 1;
        for j in 0..n {
            for i in 0..n {
                let (x, y) = g.point(i as i64, j as i64);
                debug_assert!(x & ((1 << shift) - 1) == 0 && y & ((1 << shift) - 1) == 0);
                let Some(want) = input.get(x >> shift, y >> shift) else {
                    continue;
                };
                let e = (i64::from(p[j * n + i]) - i64::from(want)).unsigned_abs();
                report.max_error = report.max_error.max(u32::try_from(e).unwrap_or(u32::MAX));
                report.vertices += 1;
            }
        }
    }

    /// Adds another's counts.
    pub(crate) fn merge(&mut self, other: &Visits) {
        for (a, b) in self.levels.iter_mut().zip(&other.levels) {
            a.diamonds += b.diamonds;
            a.vertices += b.vertices;
            a.max_error = a.max_error.max(b.max_error);
        }
    }
}

/// What a visit leaves at a grid point.
fn state_of(valid: Option<&[bool]>, k: usize) -> Reached {
    if valid.is_none_or(|v| v[k]) {
        Reached::Valid
    } else {
        Reached::Invalid
    }
}

/// Calls `f(x, y, k)` for every grid point `k` of `id` at lattice point `(x, y)` within the
/// inclusive rectangle `rect`.
fn grid_points_in(
    layout: &Layout,
    id: DiamondId,
    (x0, y0, x1, y1): (i64, i64, i64, i64),
    mut f: impl FnMut(i64, i64, usize),
) {
    let n = layout.n();
    let g = layout.grid(id);
    for j in 0..n {
        for i in 0..n {
            let (x, y) = g.point(i as i64, j as i64);
            if x >= x0 && x <= x1 && y >= y0 && y <= y1 {
                f(x, y, j * n + i);
            }
        }
    }
}

/// The apex's visitor: checks each diamond against `input` (the quantized heights at the apex
/// lattice's points, [`HeightGrid::strided`]) and keeps what it leaves at the points of the data
/// rectangle `(width, height)`.
pub(crate) fn visit_apex<'a>(
    layout: &'a Layout,
    input: &'a HeightGrid,
    (width, height): (usize, usize),
    points: &'a mut ApexPoints,
    visits: &'a mut Visits,
) -> impl FnMut(DiamondId, &[i32], Option<&[bool]>) + 'a {
    let data = (0, 0, width as i64 - 1, height as i64 - 1);
    move |id, p, valid| {
        // Every point of the levels above the cut is on the apex lattice.
        visits.check(layout, id, p, input, points.shift);
        grid_points_in(layout, id, data, |x, y, k| {
            points.set(x, y, p[k], state_of(valid, k));
        });
    }
}

/// One block's reconstruction over its owned rectangle clipped to the data rectangle.
pub(crate) struct BlockPoints {
    /// First column and row.
    pub(crate) x0: usize,
    pub(crate) y0: usize,
    /// Columns and rows.
    pub(crate) width: usize,
    pub(crate) height: usize,
    pub(crate) values: Vec<i32>,
    pub(crate) state: Vec<Reached>,
    /// The errors of the diamonds the block owns.
    pub(crate) visits: Visits,
}

impl BlockPoints {
    /// Columns `x0..x0 + width` of lattice row `y` (one of the block's).
    pub(crate) fn row(&self, y: usize) -> (&[i32], &[Reached]) {
        let k = (y - self.y0) * self.width;
        (
            &self.values[k..k + self.width],
            &self.state[k..k + self.width],
        )
    }
}

/// Decodes block `index` of `walk`: its owned diamonds checked against `input`, and the
/// reconstruction of its owned points of the data rectangle `(width, height)`, seeded with the
/// apex's.
pub(crate) fn decode_block(
    walk: &BlockWalk<'_>,
    index: usize,
    apex: &ApexPoints,
    input: &HeightGrid,
    (width, height): (usize, usize),
) -> Result<BlockPoints> {
    let layout = *walk.params().layout();
    let block: Block = walk.blocks()[index];
    let (bx0, by0, bx1, by1) = block.owned;
    let rect = (
        bx0,
        by0,
        bx1.min(width as i64 - 1),
        by1.min(height as i64 - 1),
    );
    let (bw, bh) = (
        (rect.2 - rect.0 + 1).max(0) as usize,
        (rect.3 - rect.1 + 1).max(0) as usize,
    );
    let mut values = vec![0i32; bw * bh];
    let mut state = vec![Reached::No; bw * bh];
    let at = |x: i64, y: i64| (y - rect.1) as usize * bw + (x - rect.0) as usize;
    // The apex's points first: it visited them before any level of the blocks.
    let g = 1i64 << apex.shift;
    let first = |a: i64| (a + g - 1) / g * g;
    for y in (first(rect.1)..=rect.3).step_by(g as usize) {
        for x in (first(rect.0)..=rect.2).step_by(g as usize) {
            let k = apex.index(x, y);
            values[at(x, y)] = apex.values[k];
            state[at(x, y)] = apex.state[k];
        }
    }
    // A mapped grid is read as a copy of the block's rectangle, not page by page in place.
    let window = if input.windows() {
        Some(input.window(block.field_rect)?)
    } else {
        None
    };
    let input = window.as_ref().unwrap_or(input);
    let mut visits = Visits::new(walk.params());
    walk.walk_block(index, |id, owned, p, valid| {
        if owned {
            visits.check(&layout, id, p, input, 0);
        }
        grid_points_in(&layout, id, rect, |x, y, k| {
            values[at(x, y)] = p[k];
            state[at(x, y)] = state_of(valid, k);
        });
    })?;
    Ok(BlockPoints {
        x0: rect.0 as usize,
        y0: rect.1 as usize,
        width: bw,
        height: bh,
        values,
        state,
        visits,
    })
}

/// The blocks of `blocks` (row by row) grouped in rows: index ranges of equal first row.
fn rows_of_blocks(blocks: &[Block]) -> Vec<Range<usize>> {
    let mut rows: Vec<Range<usize>> = Vec::new();
    for (i, b) in blocks.iter().enumerate() {
        match rows.last_mut() {
            Some(r) if blocks[r.start].owned.1 == b.owned.1 => r.end = i + 1,
            _ => rows.push(i..i + 1),
        }
    }
    rows
}

/// Decodes the blocks `range` (one row of blocks) in parallel.
fn decode_row(
    walk: &BlockWalk<'_>,
    range: Range<usize>,
    apex: &ApexPoints,
    input: &HeightGrid,
    data: (usize, usize),
) -> Result<Vec<BlockPoints>> {
    range
        .into_par_iter()
        .map(|b| decode_block(walk, b, apex, input, data))
        .collect()
}

/// The rows of blocks of a [`BlockWalk`], decoded one row at a time as the lattice rows are
/// compared top to bottom: one row of blocks in memory, not two.
pub(crate) struct DecodedRows<'a> {
    walk: &'a BlockWalk<'a>,
    apex: &'a ApexPoints,
    input: &'a HeightGrid,
    data: (usize, usize),
    rows: Vec<Range<usize>>,
    next: usize,
    row: Vec<BlockPoints>,
}

impl<'a> DecodedRows<'a> {
    pub(crate) fn new(
        walk: &'a BlockWalk<'a>,
        apex: &'a ApexPoints,
        input: &'a HeightGrid,
        data: (usize, usize),
    ) -> Self {
        DecodedRows {
            walk,
            apex,
            input,
            data,
            rows: rows_of_blocks(walk.blocks()),
            next: 0,
            row: Vec::new(),
        }
    }

    /// The row of blocks holding lattice row `y` (rows asked for in order), decoding the rows
    /// of blocks up to it; each decoded row's visits are merged into `levels` and `released`
    /// is called after each decode (to drop the mapped pages it read).
    pub(crate) fn at(
        &mut self,
        y: usize,
        levels: &mut Visits,
        released: &dyn Fn(),
    ) -> Result<&[BlockPoints]> {
        while self.row.first().is_none_or(|b| y >= b.y0 + b.height) {
            let Some(range) = self.rows.get(self.next).cloned() else {
                bail!("lattice row {y} lies in no block of {:?}", self.walk.plan());
            };
            self.next += 1;
            // The finished row goes before the next is decoded.
            self.row = Vec::new();
            self.row = decode_row(self.walk, range, self.apex, self.input, self.data)?;
            released();
            for b in &self.row {
                levels.merge(&b.visits);
            }
        }
        Ok(&self.row)
    }

    /// Decodes the rows of blocks below the last asked for (blocks below the data rectangle
    /// own diamonds too: their grids may reach into it), merging their visits into `levels`.
    pub(crate) fn finish(self, levels: &mut Visits) -> Result<()> {
        for range in &self.rows[self.next..] {
            for b in decode_row(self.walk, range.clone(), self.apex, self.input, self.data)? {
                levels.merge(&b.visits);
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decode_plans_fit_their_budget_and_grow_with_it() {
        // 65537² as one root of N = 65 (issue 20's 4.3 G-sample benchmark), and a small lattice.
        for (layout, width) in [
            (Layout::new(65, 10, 1, 1).unwrap(), 65537),
            (Layout::new(17, 5, 3, 2).unwrap(), 1500),
        ] {
            let mut last: Option<BlockPlan> = None;
            for budget in [64u64 << 20, 256 << 20, 1280 << 20, 4 << 30, 64 << 30] {
                let Ok(plan) = decode_plan(&layout, width, 2, budget) else {
                    assert!(last.is_none(), "{budget} refused after {last:?} fitted");
                    continue;
                };
                assert!(decode_bytes(&layout, &plan, width, 2) <= budget, "{plan:?}");
                assert!(plan.cut_level < layout.finest_level(), "{plan:?}");
                if let Some(last) = last {
                    assert!(plan.block_side >= last.block_side, "{last:?} then {plan:?}");
                }
                last = Some(plan);
            }
            assert!(last.is_some(), "no budget fits {layout:?}");
        }
    }
}
