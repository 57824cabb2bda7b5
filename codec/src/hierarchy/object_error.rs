//! Object-space error of a diamond: how far its drawn surface is from the input samples under it.
//!
//! The surface of a diamond is the piecewise-linear interpolant of its reconstructed grid, cells
//! split parallel to the split diagonal exactly as they are drawn. Grid spacings are powers of
//! two in lattice units, so the interpolant at an input sample is a rational with that
//! denominator: it is evaluated exactly in integers, and the maximum rounded up.
//!
//! This file holds the entry points and the finest level (every sample a grid vertex); `scan.rs`
//! walks the coarser levels' surfaces, over the integer lanes of `lanes.rs`.

use crate::geometry::{Diagonal, DiamondId, Layout};
use crate::lifting::MAX_ABS_HEIGHT;
use crate::quant::HeightGrid;

mod lanes;
mod scan;
#[cfg(test)]
mod tests;
mod walk;

use lanes::{Lane, PREFETCH_ROWS, extremes, prefetch};
use scan::Scan;

/// Diamonds whose grid rows span at least this many lattice units have their rows scanned in
/// parallel.
const PARALLEL_ROWS_FROM: i64 = 512;

/// The input samples the errors are measured against, with a bound on their magnitude (computed
/// once per encode) that lets most diamonds be scanned in 32-bit lanes.
#[derive(Clone, Copy)]
pub(crate) struct ErrorInput<'a> {
    grid: &'a HeightGrid,
    /// The largest `|value|` of a valid sample.
    max_abs: i64,
    /// No nodata: the scans need not read the validity mask.
    all_valid: bool,
    /// The samples measured: `(x0, y0, x1, y1)`, inclusive; the whole grid but for
    /// [`ErrorInput::clipped`].
    clip: (i64, i64, i64, i64),
    /// The lattice point of the grid's first sample: `(0, 0)` but for
    /// [`ErrorInput::placed_at`].
    offset: (i64, i64),
}

impl<'a> ErrorInput<'a> {
    pub(crate) fn new(grid: &'a HeightGrid) -> Self {
        let max_abs = grid
            .range()
            .map_or(0, |(lo, hi)| i64::from(lo).abs().max(i64::from(hi).abs()));
        Self::with_bounds(grid, max_abs, !grid.has_invalid())
    }

    /// [`ErrorInput::new`] with the largest `|value|` of a valid sample and whether every
    /// sample is valid given (as [`ErrorInput::bounds`] measured them), so that nothing scans
    /// the grid here.
    pub(crate) fn with_bounds(grid: &'a HeightGrid, max_abs: i64, all_valid: bool) -> Self {
        Self {
            grid,
            max_abs,
            all_valid,
            clip: (0, 0, grid.width as i64 - 1, grid.height as i64 - 1),
            offset: (0, 0),
        }
    }

    /// The same input with its first sample at lattice point `offset`: a window of the
    /// lattice (a planet's tile).
    pub(crate) fn placed_at(self, offset: (i64, i64)) -> Self {
        Self { offset, ..self }
    }

    /// The same input with only the samples in the rectangle `(x0, y0, x1, y1)` (inclusive)
    /// measured: the error of a diamond over rectangles that cover the grid is the largest of
    /// its errors over each (a sharded encode measures the apex's errors block by block).
    pub(crate) fn clipped(self, (x0, y0, x1, y1): (i64, i64, i64, i64)) -> Self {
        let (a0, b0, a1, b1) = self.clip;
        Self {
            clip: (x0.max(a0), y0.max(b0), x1.min(a1), y1.min(b1)),
            ..self
        }
    }

    /// The largest `|value|` of a valid sample, and whether every sample is valid.
    pub(crate) fn bounds(&self) -> (i64, bool) {
        (self.max_abs, self.all_valid)
    }

    /// Whether only part of the grid is measured.
    fn is_clipped(&self) -> bool {
        self.clip
            != (
                0,
                0,
                self.grid.width as i64 - 1,
                self.grid.height as i64 - 1,
            )
    }
}

/// The largest distance, in units rounded up, between the surface of diamond `id` with grid `p`
/// and the valid input samples under it (0 if there are none).
///
/// Exact, in integers scaled by the grid spacing `sp` (a power of two). Works row by row in the
/// diamond's scaled grid coordinates `(s, t)`; for even levels a row is an input row, for odd
/// levels (s = Δx + Δy, t = Δx − Δy) an input diagonal. See [`surface_error_scan`].
pub(crate) fn surface_error(layout: &Layout, id: DiamondId, p: &[i32], input: &ErrorInput) -> u32 {
    surface_error_of(layout, id, p, grid_abs(p), input)
}

/// The largest `|value|` of a diamond's grid, what [`surface_error_of`] takes.
pub(crate) fn grid_abs(p: &[i32]) -> i64 {
    p.iter().map(|&v| i64::from(v).abs()).max().unwrap_or(0)
}

/// [`surface_error`] with the largest `|value|` of `p` given ([`grid_abs`]): a diamond measured
/// against many inputs (a planet's tiles) computes it once.
pub(crate) fn surface_error_of(
    layout: &Layout,
    id: DiamondId,
    p: &[i32],
    p_abs: i64,
    input: &ErrorInput,
) -> u32 {
    let g = layout.grid(id);
    if id.is_even() && g.u.0 == 1 && !input.is_clipped() {
        let origin = (g.origin.0 - input.offset.0, g.origin.1 - input.offset.1);
        let e = finest_error_fast(layout.n(), origin, p, p_abs, input);
        input.grid.touched_rows(layout.n(), layout.n());
        return e;
    }
    let parallel = layout.radius(id.level) * 2 >= PARALLEL_ROWS_FROM;
    surface_error_scan(layout, id, p, p_abs, input, parallel)
}

/// [`finest_error`] compiled for AVX2 where the CPU has it (see [`Scan::rows_fast`]).
fn finest_error_fast(
    n: usize,
    origin: (i64, i64),
    p: &[i32],
    p_abs: i64,
    input: &ErrorInput,
) -> u32 {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && !tests::portable_only() {
        // SAFETY: the CPU has AVX2, checked just above.
        return unsafe { finest_error_avx2(n, origin, p, p_abs, input) };
    }
    finest_error(n, origin, p, p_abs, input)
}

/// [`finest_error`] with AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn finest_error_avx2(
    n: usize,
    origin: (i64, i64),
    p: &[i32],
    p_abs: i64,
    input: &ErrorInput,
) -> u32 {
    finest_error(n, origin, p, p_abs, input)
}

/// [`surface_error`] at the finest level, grid origin `origin`: every sample is a grid vertex,
/// and grid rows are input rows. Differences of heights within `MAX_ABS_HEIGHT` fit 32-bit
/// lanes; larger grid values (never from the encoder) take 64-bit ones.
#[inline(always)]
fn finest_error(n: usize, origin: (i64, i64), p: &[i32], p_abs: i64, input: &ErrorInput) -> u32 {
    let narrow = p_abs <= MAX_ABS_HEIGHT as i64 && input.max_abs <= MAX_ABS_HEIGHT as i64;
    if narrow {
        finest_error_lanes::<i32>(n, origin, p, input)
    } else {
        finest_error_lanes::<i64>(n, origin, p, input)
    }
}

#[inline(always)]
fn finest_error_lanes<T: Lane>(n: usize, origin: (i64, i64), p: &[i32], input: &ErrorInput) -> u32 {
    let grid = input.grid;
    let valid = (!input.all_valid).then_some(&grid.valid[..]);
    let (n, w, h) = (n as i64, grid.width as i64, grid.height as i64);
    let (ox, oy) = origin;
    let (i0, i1) = ((-ox).max(0), (w - ox).min(n));
    let (j0, j1) = ((-oy).max(0), (h - oy).min(n));
    if i0 >= i1 {
        return 0;
    }
    let mut row_vals = vec![T::default(); (i1 - i0) as usize];
    let (mut hi, mut lo) = (T::default(), T::default());
    for j in j0..j1 {
        let k = ((oy + j) * w + ox + i0) as usize;
        if j + PREFETCH_ROWS < j1 {
            prefetch(
                &grid.values,
                valid,
                k + (PREFETCH_ROWS * w) as usize,
                row_vals.len(),
            );
        }
        let row = &p[(j * n + i0) as usize..(j * n + i1) as usize];
        for (o, &v) in row_vals.iter_mut().zip(row) {
            *o = T::of(i64::from(v));
        }
        let vals = &grid.values[k..k + row.len()];
        (hi, lo) = extremes(
            &row_vals,
            vals,
            valid.map(|v| &v[k..k + row.len()]),
            0,
            hi,
            lo,
        );
    }
    u32::try_from(hi.widen().max(-lo.widen())).unwrap_or(u32::MAX)
}

/// [`surface_error`] without the finest-level shortcut, rows scanned in parallel or not.
///
/// Scaled by `sp`, every value is an integer: 32-bit lanes are used when the heights and the
/// spacing keep every intermediate below 2³¹ (nearly always), 64-bit ones otherwise.
fn surface_error_scan(
    layout: &Layout,
    id: DiamondId,
    p: &[i32],
    p_abs: i64,
    input: &ErrorInput,
    parallel: bool,
) -> u32 {
    let sp = layout.grid(id).u.0 << u32::from(!id.is_even());
    // Lanes wrap, so only the results need to fit: surface values and differences, at most
    // 2·max|height|·sp (with a margin).
    let narrow = 4 * p_abs.max(input.max_abs) * sp < 1 << 31;
    surface_error_lanes(layout, id, p, input, parallel, narrow)
}

/// [`surface_error_scan`] in 32-bit lanes (`narrow`) or 64-bit ones.
fn surface_error_lanes(
    layout: &Layout,
    id: DiamondId,
    p: &[i32],
    input: &ErrorInput,
    parallel: bool,
    narrow: bool,
) -> u32 {
    let scan = Scan::new(layout, id, p, input);
    debug_assert!(!narrow || 2 * scan.sp * input.max_abs < 1 << 31);
    match (layout.diagonal(id), narrow) {
        (Diagonal::Main, true) => scan.run::<true, i32>(parallel),
        (Diagonal::Anti, true) => scan.run::<false, i32>(parallel),
        (Diagonal::Main, false) => scan.run::<true, i64>(parallel),
        (Diagonal::Anti, false) => scan.run::<false, i64>(parallel),
    }
}

#[cfg(not(test))]
mod tests {
    /// Outside tests the fastest kernels are always used (only x86-64 has a choice).
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    pub(super) fn portable_only() -> bool {
        false
    }
}
