//! Object-space error of a diamond: how far its drawn surface is from the input samples under it.
//!
//! The surface of a diamond is the piecewise-linear interpolant of its reconstructed grid, cells
//! split parallel to the split diagonal exactly as they are drawn. Grid spacings are powers of
//! two in lattice units, so the interpolant at an input sample is a rational with that
//! denominator: it is evaluated exactly in integers, and the maximum rounded up.

use rayon::prelude::*;

use crate::geometry::{Diagonal, DiamondId, Layout};
use crate::lifting::MAX_ABS_HEIGHT;
use crate::quant::HeightGrid;

/// Diamonds whose grid rows span at least this many lattice units have their rows scanned in
/// parallel.
const PARALLEL_ROWS_FROM: i64 = 512;

/// Bytes of an odd-level batch of surface rows (see [`Scan::rows`]): small enough to stay in
/// a core's L2 cache.
const ODD_BATCH_BYTES: usize = 256 << 10;

/// Fewest odd-level surface rows compared with the input at a time: the batch's width along
/// each input row it meets, and so how much of each input cache line is used before it leaves.
const ODD_BATCH_MIN: usize = 32;

/// Rows of an odd-level batch over `rows` surface rows `len` long: as many as the byte budget
/// allows, and at least [`ODD_BATCH_MIN`].
fn odd_batch_rows<T>(rows: usize, len: usize) -> usize {
    let mut b = rows.max(1);
    while b > ODD_BATCH_MIN
        && (len.div_ceil(2) + b) * b * std::mem::size_of::<T>() > ODD_BATCH_BYTES
    {
        b = b.div_ceil(2);
    }
    b
}

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

/// Integer lanes of the scan. Arithmetic wraps: exact for valid samples (the caller picks a
/// lane wide enough), and nodata samples, whose values are arbitrary, are masked out afterwards.
trait Lane: Copy + Ord + Default + Send {
    fn of(v: i64) -> Self;
    fn add(self, o: Self) -> Self;
    fn sub(self, o: Self) -> Self;
    fn mul(self, o: Self) -> Self;
    fn shl(self, k: u32) -> Self;
    fn widen(self) -> i64;
}

macro_rules! lane {
    ($t:ty) => {
        impl Lane for $t {
            #[inline(always)]
            fn of(v: i64) -> Self {
                v as $t
            }
            #[inline(always)]
            fn add(self, o: Self) -> Self {
                self.wrapping_add(o)
            }
            #[inline(always)]
            fn sub(self, o: Self) -> Self {
                self.wrapping_sub(o)
            }
            #[inline(always)]
            fn mul(self, o: Self) -> Self {
                self.wrapping_mul(o)
            }
            #[inline(always)]
            fn shl(self, k: u32) -> Self {
                self.wrapping_shl(k)
            }
            #[inline(always)]
            fn widen(self) -> i64 {
                self as i64
            }
        }
    };
}
lane!(i32);
lane!(i64);

/// The extremes of `surface − value·2^shift` over the valid samples of a row, starting from
/// `(hi, lo)`: `valid` is `None` when every sample is. Nodata contributes 0, neutral for both.
/// Straight, so it vectorises.
#[inline(always)]
fn extremes<T: Lane>(
    surface: &[T],
    values: &[i32],
    valid: Option<&[bool]>,
    shift: u32,
    mut hi: T,
    mut lo: T,
) -> (T, T) {
    let diff = |s: T, v: i32| s.sub(T::of(i64::from(v)).shl(shift));
    match valid {
        Some(valid) => {
            for ((&s, &v), &ok) in surface.iter().zip(values).zip(valid) {
                let d = if ok { diff(s, v) } else { T::default() };
                hi = hi.max(d);
                lo = lo.min(d);
            }
        }
        None => {
            for (&s, &v) in surface.iter().zip(values) {
                let d = diff(s, v);
                hi = hi.max(d);
                lo = lo.min(d);
            }
        }
    }
    (hi, lo)
}

/// Input rows ahead of the one being compared whose samples are prefetched: a diamond's row
/// of samples is short (a few cache lines), too short for the hardware prefetcher to follow
/// the jump to the next input row, so each row would wait on memory.
const PREFETCH_ROWS: i64 = 4;

/// Asks for `values[k..k + count]` and `valid[k..k + count]` (clipped to the slices) to be
/// brought into the cache. A hint only: no effect on results.
#[inline(always)]
fn prefetch(values: &[i32], valid: Option<&[bool]>, k: usize, count: usize) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        let end = (k + count).min(values.len());
        if k >= end {
            return;
        }
        // SAFETY: SSE is part of the x86-64 baseline, and a prefetch neither reads into the
        // program nor faults.
        let hint = |p: *const i8| unsafe { _mm_prefetch::<_MM_HINT_T0>(p) };
        for line in values[k..end].chunks(16) {
            hint(line.as_ptr().cast());
        }
        if let Some(valid) = valid {
            for line in valid[k..end].chunks(64) {
                hint(line.as_ptr().cast());
            }
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (values, valid, k, count);
}

/// One diamond's scan: its grid, spacing and placement over the input.
struct Scan<'a> {
    p: &'a [i32],
    n: usize,
    input: &'a HeightGrid,
    /// The validity mask, `None` when every sample is valid.
    valid: Option<&'a [bool]>,
    odd: bool,
    /// Grid spacing in `(s, t)` units, a power of two, and its log.
    sp: i64,
    shift: u32,
    /// Last row / column of `(s, t)`: `sp·(N − 1)`.
    side: i64,
    origin: (i64, i64),
    /// The samples measured ([`ErrorInput::clipped`]).
    clip: (i64, i64, i64, i64),
}

impl<'a> Scan<'a> {
    fn new(layout: &Layout, id: DiamondId, p: &'a [i32], error_input: &ErrorInput<'a>) -> Self {
        let input = error_input.grid;
        let n = layout.n();
        let g = layout.grid(id);
        let odd = !id.is_even();
        let sp = if odd { 2 * g.u.0 } else { g.u.0 };
        debug_assert!(sp.count_ones() == 1, "grid spacings are powers of two");
        Self {
            p,
            n,
            input,
            valid: (!error_input.all_valid).then_some(&input.valid[..]),
            odd,
            sp,
            shift: sp.trailing_zeros(),
            side: sp * (n as i64 - 1),
            origin: (
                g.origin.0 - error_input.offset.0,
                g.origin.1 - error_input.offset.1,
            ),
            clip: error_input.clip,
        }
    }

    /// Row `t`'s samples that lie in the data: `s` in `[lo, hi]` (odd levels: `s ≡ t` mod 2).
    #[inline]
    fn data_range(&self, t: i64) -> Option<(i64, i64)> {
        let (ox, oy) = self.origin;
        let (x0, y0, x1, y1) = self.clip;
        let (mut lo, mut hi) = if self.odd {
            (
                (2 * (x0 - ox) - t).max(t + 2 * (y0 - oy)).max(0),
                (2 * (x1 - ox) - t).min(2 * (y1 - oy) + t).min(self.side),
            )
        } else {
            if oy + t < y0 || oy + t > y1 {
                return None;
            }
            ((x0 - ox).max(0), (x1 - ox).min(self.side))
        };
        if self.odd {
            lo += (lo - t).rem_euclid(2);
            hi -= (hi - t).rem_euclid(2);
        }
        (lo <= hi).then_some((lo, hi))
    }

    /// The rows `t` that can hold data, a range containing every row [`Scan::data_range`]
    /// accepts (a diamond much larger than its input, a planet's tile, meets few of its rows).
    #[inline]
    fn data_rows(&self) -> (i64, i64) {
        let (ox, oy) = self.origin;
        let (x0, y0, x1, y1) = self.clip;
        let (lo, hi) = if self.odd {
            // s ≥ 2(x0 − ox) − t and s ≤ t + 2(y1 − oy) meet only for t ≥ (x0 − ox) − (y1 −
            // oy); likewise s ≥ t + 2(y0 − oy) and s ≤ 2(x1 − ox) − t for t ≤ (x1 − ox) − (y0
            // − oy).
            ((x0 - ox) - (y1 - oy), (x1 - ox) - (y0 - oy))
        } else {
            (y0 - oy, y1 - oy)
        };
        (lo.max(0), hi.min(self.side))
    }

    /// The largest scaled error over the diamond, rows split across threads or not.
    fn run<const MAIN: bool, T: Lane>(&self, parallel: bool) -> u32 {
        let last = self.n as i64 - 2;
        let worst_h = if parallel {
            // The coarsest diamonds cover the whole dataset alone, and their level has too few
            // diamonds to keep every core busy: one task per row of cells.
            (0..=last)
                .into_par_iter()
                .map(|cj| {
                    let t0 = cj << self.shift;
                    let t1 = if cj == last {
                        self.side
                    } else {
                        t0 + self.sp - 1
                    };
                    self.rows_fast::<MAIN, T>(t0, t1)
                })
                .max()
                .unwrap_or(0)
        } else {
            self.rows_fast::<MAIN, T>(0, self.side)
        };
        let e = (worst_h + self.sp - 1) / self.sp;
        u32::try_from(e).unwrap_or(u32::MAX)
    }

    /// [`Scan::rows`] compiled for the widest vector unit the CPU has: the scan is a few
    /// integer operations per sample, and the baseline x86-64 target (SSE2) has no 32-bit
    /// min/max and half the lanes of AVX2.
    fn rows_fast<const MAIN: bool, T: Lane>(&self, t0: i64, t1: i64) -> i64 {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") && !tests::portable_only() {
            // SAFETY: the CPU has AVX2, checked just above.
            return unsafe { self.rows_avx2::<MAIN, T>(t0, t1) };
        }
        self.rows::<MAIN, T>(t0, t1)
    }

    /// [`Scan::rows`] with AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn rows_avx2<const MAIN: bool, T: Lane>(&self, t0: i64, t1: i64) -> i64 {
        self.rows::<MAIN, T>(t0, t1)
    }

    /// The largest scaled error over rows `t0..=t1`.
    ///
    /// The surface along the first row with data is filled exactly, cell by cell. Moving to the
    /// next row adds, at each `s`, the step of the triangle the unit segment between the two
    /// rows lies in: constant per cell except at the split diagonal, so a second buffer holds
    /// the steps and only one entry per cell changes from row to row (all of them at a new row
    /// of cells). Both loops over a row are straight and vectorise.
    ///
    /// Long on purpose: this is the encoder's hottest kernel (the object error of every
    /// diamond), compiled twice — here and inside [`Scan::rows_avx2`]'s `target_feature` — and
    /// kept as one body so that every loop of it is compiled for the wider vector unit there.
    #[inline(always)]
    fn rows<const MAIN: bool, T: Lane>(&self, t0: i64, t1: i64) -> i64 {
        let (lo, hi) = self.data_rows();
        let (t0, t1) = (t0.max(lo), t1.min(hi));
        let Some(ta) = (t0..=t1).find(|&t| self.data_range(t).is_some()) else {
            return 0;
        };
        let tb = (ta..=t1)
            .rev()
            .find(|&t| self.data_range(t).is_some())
            .unwrap_or(ta);
        // The columns any of these rows needs.
        let (mut ulo, mut uhi) = (i64::MAX, i64::MIN);
        if self.odd {
            for t in ta..=tb {
                if let Some((lo, hi)) = self.data_range(t) {
                    ulo = ulo.min(lo);
                    uhi = uhi.max(hi);
                }
            }
        } else if let Some((lo, hi)) = self.data_range(ta) {
            (ulo, uhi) = (lo, hi);
        }
        let (sp, shift, n) = (self.sp, self.shift, self.n);
        let last = n as i64 - 2;
        let len = (uhi - ulo + 1) as usize;
        let mut surface = vec![T::default(); len];
        let mut step = vec![T::default(); len];
        let (cl, ch) = ((ulo >> shift).min(last), (uhi >> shift).min(last));
        let p = self.p;
        let at = |k: usize| T::of(i64::from(p[k]));
        // The cells of row `t`: (index of cell (cl, cj) in `p`, offset ft of t in the row).
        let cell_row = |t: i64| {
            let cj = (t >> shift).min(last);
            (cj as usize * n, t - (cj << shift))
        };
        // Fills `buf` cell by cell with `value(cell index, fs)` over the columns kept.
        let for_cells = |buf: &mut [T], f: &mut dyn FnMut(usize, i64, &mut [T])| {
            for ci in cl..=ch {
                let s0 = ci << shift;
                let from = (ulo - s0).max(0);
                let to = (uhi - s0).min(sp);
                if from <= to {
                    let slots = &mut buf[(s0 + from - ulo) as usize..=(s0 + to - ulo) as usize];
                    f(ci as usize, from, slots);
                }
            }
        };
        // Exact surface along row ta: two linear pieces c0 + c1·fs per cell.
        {
            let (row, ft) = cell_row(ta);
            let spl = T::of(sp);
            let ftl = T::of(ft);
            for_cells(&mut surface, &mut |ci, from, slots| {
                let k = row + ci;
                let (v00, v10, v01, v11) = (at(k), at(k + 1), at(k + n), at(k + n + 1));
                // fs in [0, split] lies on the first piece, the rest on the second.
                let (split, first, second) = if MAIN {
                    (
                        ft - 1,
                        (v00.mul(spl).add(v01.sub(v00).mul(ftl)), v11.sub(v01)),
                        (v00.mul(spl).add(v11.sub(v10).mul(ftl)), v10.sub(v00)),
                    )
                } else {
                    (
                        sp - ft,
                        (v00.mul(spl).add(v01.sub(v00).mul(ftl)), v10.sub(v00)),
                        (
                            v01.mul(spl).add(v10.sub(v11).mul(T::of(sp - ft))),
                            v11.sub(v01),
                        ),
                    )
                };
                for (fs, slot) in (from..).zip(slots.iter_mut()) {
                    let (c0, c1) = if fs <= split { first } else { second };
                    *slot = c0.add(c1.mul(T::of(fs)));
                }
            });
        }
        // Steps from row t (offset ft in its row of cells) to t + 1. Main diagonal: the upper
        // triangle (fs ≤ ft) climbs like the cell's left edge, the lower one like its right
        // edge. Anti-diagonal: the lower-left one (fs < sp − ft) like the left edge, the
        // upper-right one like the right edge. `edge[i]`: the climb of vertex column i.
        let mut edge = vec![T::default(); n];
        let fill_edges = |edge: &mut [T], t: i64| {
            let (row, _) = cell_row(t);
            let (lower, upper) = (&p[row..row + n], &p[row + n..row + 2 * n]);
            for ((e, &a), &b) in edge.iter_mut().zip(lower).zip(upper) {
                *e = T::of(i64::from(b)).sub(T::of(i64::from(a)));
            }
        };
        let fill_steps = |step: &mut [T], edge: &[T], t: i64| {
            let (_, ft) = cell_row(t);
            let split = if MAIN { ft } else { sp - ft - 1 };
            for (s, slot) in (ulo..).zip(step.iter_mut()) {
                let right = usize::from((s & (sp - 1)) > split);
                *slot = edge[(s >> shift) as usize + right];
            }
        };
        if ta < tb {
            fill_edges(&mut edge, ta);
            fill_steps(&mut step, &edge, ta);
        }
        let (ox, oy) = self.origin;
        let w = self.input.width as i64;
        let (values, valid) = (&self.input.values[..], self.valid);
        let (mut hi_d, mut lo_d) = (T::default(), T::default());
        // Odd levels: a row is an input diagonal, and walking it touches one input row (and
        // memory page) per sample. So a batch of surface rows is kept, transposed: input row
        // Δy crosses batch row r at s = 2Δy + t0 + r, so the samples of one input row lie on
        // one diagonal s − r of the batch, and the batch is stored diagonal by diagonal, each
        // diagonal's rows adjacent. Then the batch is compared with the input in input-row
        // order, both sides contiguous. Only entries with s ≡ t (mod 2) are samples, so a
        // batch's diagonals share one parity and are kept at half resolution.
        let br = odd_batch_rows::<T>((tb - ta + 1) as usize, len);
        let mut batch = if self.odd {
            vec![T::default(); (len.div_ceil(2) + br) * br]
        } else {
            Vec::new()
        };
        let mut batch_from = ta;
        let mut t = ta;
        loop {
            if self.odd {
                let r = (t - batch_from) as usize;
                // The first sample column of row t, and its diagonal's slot.
                let s0 = ulo + (t - ulo).rem_euclid(2);
                if s0 <= uhi {
                    let d0 = odd_diagonal(s0 - r as i64, ulo, br);
                    let slots = batch[d0 * br + r..].iter_mut().step_by(br);
                    let row = surface[(s0 - ulo) as usize..].iter().step_by(2);
                    for (slot, &v) in slots.zip(row) {
                        *slot = v;
                    }
                }
                if r + 1 == br || t == tb {
                    let rows = (batch_from, t);
                    (hi_d, lo_d) = self.odd_batch(&batch, br, rows, ulo, uhi, (hi_d, lo_d));
                    batch_from = t + 1;
                }
            } else if let Some((lo, hi)) = self.data_range(t) {
                if let Some((lo, hi)) = self.data_range(t + PREFETCH_ROWS).filter(|_| t < tb) {
                    let k = ((oy + t + PREFETCH_ROWS) * w + ox + lo) as usize;
                    prefetch(values, valid, k, (hi - lo + 1) as usize);
                }
                let buf = &surface[(lo - ulo) as usize..=(hi - ulo) as usize];
                let k = ((oy + t) * w + ox + lo) as usize;
                let vals = &values[k..k + buf.len()];
                let oks = valid.map(|v| &v[k..k + buf.len()]);
                (hi_d, lo_d) = extremes(buf, vals, oks, shift, hi_d, lo_d);
                // A mapped input drops its resident pages every window read.
                self.input.touched_sparse_rows(1, buf.len());
            }
            if t == tb {
                break;
            }
            for (s, &d) in surface.iter_mut().zip(&step) {
                *s = s.add(d);
            }
            t += 1;
            if t == tb {
                // No step out of the last row.
            } else if t & (sp - 1) == 0 {
                fill_edges(&mut edge, t);
                fill_steps(&mut step, &edge, t);
            } else {
                // One entry per cell changes triangle: fs = ft to the left edge (main), or
                // fs = sp − ft to the right edge (anti).
                let (_, ft) = cell_row(t);
                let fs = if MAIN { ft } else { sp - ft };
                for ci in cl..=ch {
                    let s = (ci << shift) + fs;
                    if (ulo..=uhi).contains(&s) {
                        step[(s - ulo) as usize] = edge[ci as usize + usize::from(!MAIN)];
                    }
                }
            }
        }
        hi_d.widen().max(-lo_d.widen())
    }

    /// Folds into `(hi, lo)` the extremes of `surface − value·sp` over the valid samples of
    /// odd-level rows `t0..=t1`, whose surfaces (columns `ulo..=uhi`) are in `batch` of `br`
    /// rows, diagonal by diagonal (see [`Scan::rows`]). Walks the input row by row: along an input row, `s`
    /// and `t` both grow by one, so the batch row grows by one along a diagonal.
    #[inline(always)]
    fn odd_batch<T: Lane>(
        &self,
        batch: &[T],
        br: usize,
        (t0, t1): (i64, i64),
        ulo: i64,
        uhi: i64,
        (mut hi, mut lo): (T, T),
    ) -> (T, T) {
        let (ox, oy) = self.origin;
        let w = self.input.width as i64;
        let (x0, y0, x1, y1) = self.clip;
        // s − t = 2·Δy.
        let dy0 = (ulo - t1).div_euclid(2).max(y0 - oy);
        let dy1 = (uhi - t0).div_euclid(2).min(y1 - oy);
        for dy in dy0..=dy1 {
            // t = Δx − Δy in [t0, t1], s = Δx + Δy in [ulo, uhi], x in the data.
            let dx0 = (t0 + dy).max(ulo - dy).max(x0 - ox);
            let dx1 = (t1 + dy).min(uhi - dy).min(x1 - ox);
            if dx0 > dx1 {
                continue;
            }
            let (r0, r1) = (dx0 - dy - t0, dx1 - dy - t0);
            let base = odd_diagonal(2 * dy + t0, ulo, br) * br;
            let surface = &batch[base + r0 as usize..=base + r1 as usize];
            let k = ((oy + dy) * w + ox + dx0) as usize;
            let count = surface.len();
            // The row PREFETCH_ROWS below spans about as many samples, shifted by as many.
            prefetch(
                &self.input.values,
                self.valid,
                k + (PREFETCH_ROWS * w) as usize - PREFETCH_ROWS as usize,
                count + 2 * PREFETCH_ROWS as usize,
            );
            let vals = &self.input.values[k..k + count];
            let oks = self.valid.map(|v| &v[k..k + count]);
            (hi, lo) = extremes(surface, vals, oks, self.shift, hi, lo);
            // A mapped input drops its resident pages every window read.
            self.input.touched_sparse_rows(1, count);
        }
        (hi, lo)
    }
}

/// Slot of diagonal `d = s − r` of an odd-level batch of `br` rows (columns from `ulo`, so
/// `d > ulo − br`): one per two diagonals, as a batch uses one parity.
#[inline]
fn odd_diagonal(d: i64, ulo: i64, br: usize) -> usize {
    ((d - ulo + br as i64) >> 1) as usize
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Layout;

    std::thread_local! {
        /// Set while a test checks the portable kernels on a CPU that has faster ones.
        static PORTABLE: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
    }

    pub(super) fn portable_only() -> bool {
        PORTABLE.get()
    }

    /// `h ×` the piecewise-linear interpolant at `(is, js)` (grid coordinates times `h`), for a grid
    /// of spacing `h` split along `diag`.
    #[inline]
    fn interpolate_h(p: &[i32], n: usize, diag: Diagonal, h: i64, is: i64, js: i64) -> i64 {
        let ci = ((is / h) as usize).min(n - 2);
        let cj = ((js / h) as usize).min(n - 2);
        let (fx, fy) = (is - ci as i64 * h, js - cj as i64 * h);
        let at = |i: usize, j: usize| i64::from(p[j * n + i]);
        let (v00, v10, v01, v11) = (
            at(ci, cj),
            at(ci + 1, cj),
            at(ci, cj + 1),
            at(ci + 1, cj + 1),
        );
        match diag {
            Diagonal::Main if fx >= fy => v00 * h + (v10 - v00) * fx + (v11 - v10) * fy,
            Diagonal::Main => v00 * h + (v11 - v01) * fx + (v01 - v00) * fy,
            Diagonal::Anti if fx + fy <= h => v00 * h + (v10 - v00) * fx + (v01 - v00) * fy,
            Diagonal::Anti => v11 * h + (v01 - v11) * (h - fx) + (v10 - v11) * (h - fy),
        }
    }

    /// Reference: the surface at every sample of the diamond, located by division.
    fn brute_force(layout: &Layout, id: DiamondId, p: &[i32], input: &HeightGrid) -> u32 {
        let (n, diag, g) = (layout.n(), layout.diagonal(id), layout.grid(id));
        let r = layout.radius(id.level);
        let (cx, cy) = (i64::from(id.x), i64::from(id.y));
        let mut worst = 0f64;
        for y in cy - r..=cy + r {
            for x in cx - r..=cx + r {
                let Some(v) = input.get(x, y) else { continue };
                let (dx, dy) = (x - g.origin.0, y - g.origin.1);
                let (sp, s, t) = if id.is_even() {
                    (g.u.0, dx, dy)
                } else {
                    (2 * g.u.0, dx + dy, dx - dy)
                };
                if s < 0 || t < 0 || s > sp * (n as i64 - 1) || t > sp * (n as i64 - 1) {
                    continue; // outside a rotated diamond
                }
                let surf = interpolate_h(p, n, diag, sp, s, t) as f64 / sp as f64;
                worst = worst.max((surf - f64::from(v)).abs());
            }
        }
        worst.ceil() as u32
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig { cases: 64, ..Default::default() })]
        #[test]
        fn incremental_evaluation_matches_brute_force_on_every_level(
            n_pow in 1u32..4,
            k in 0u32..4,
            rx in 1u32..3,
            ry in 1u32..3,
            cut_w in 0usize..6,
            cut_h in 0usize..6,
            holes in proptest::collection::vec(proptest::prelude::any::<u16>(), 0..8),
            seed in proptest::prelude::any::<u64>(),
        ) {
            let layout = Layout::new((1 << n_pow) + 1, k, rx, ry).unwrap();
            let n = layout.n();
            let (ex, ey) = layout.face_extent();
            // Data narrower and shorter than the domain, or reaching its far edge.
            let w = (ex as usize + 1).saturating_sub(cut_w).max(1);
            let h = (ey as usize + 1).saturating_sub(cut_h).max(1);
            let mut seed = seed | 1;
            let mut rnd = |m: i64| {
                seed ^= seed << 13;
                seed ^= seed >> 7;
                seed ^= seed << 17;
                (seed % (2 * m as u64 + 1)) as i64 - m
            };
            let mut input = HeightGrid::all_valid(w, h, (0..w * h).map(|_| rnd(1000) as i32).collect());
            for hole in holes {
                input.valid[hole as usize % (w * h)] = false;
            }
            let mut frontier: Vec<DiamondId> = layout.roots().collect();
            let mut seen = std::collections::HashSet::new();
            while let Some(d) = frontier.pop() {
                if !seen.insert(d) {
                    continue;
                }
                frontier.extend(layout.children(d).into_iter().flatten());
                let p: Vec<i32> = (0..n * n).map(|_| rnd(1000) as i32).collect();
                let want = brute_force(&layout, d, &p, &input);
                proptest::prop_assert_eq!(surface_error(&layout, d, &p, &ErrorInput::new(&input)), want, "{}", d);
                // Clipped to a rectangle (possibly empty or beyond the grid): the samples
                // outside it are as if nodata.
                let mut corner = |len: usize| rnd(len as i64 + 1);
                let (xa, xb, ya, yb) = (corner(w), corner(w), corner(h), corner(h));
                let rect = (xa.min(xb), ya.min(yb), xa.max(xb) + rnd(1), ya.max(yb));
                let mut masked = input.clone();
                for y in 0..h {
                    for x in 0..w {
                        let (xi, yi) = (x as i64, y as i64);
                        if xi < rect.0 || xi > rect.2 || yi < rect.1 || yi > rect.3 {
                            masked.valid[y * w + x] = false;
                        }
                    }
                }
                let want_clipped = brute_force(&layout, d, &p, &masked);
                let clipped = ErrorInput::new(&input).clipped(rect);
                proptest::prop_assert_eq!(surface_error(&layout, d, &p, &clipped), want_clipped, "{} clipped to {:?}", d, rect);
                proptest::prop_assert_eq!(surface_error_scan(&layout, d, &p, grid_abs(&p), &clipped, true), want_clipped, "{} clipped to {:?}, parallel", d, rect);
                if d.level == layout.finest_level() && d.is_even() {
                    // The shortcut's other lanes and its portable kernel.
                    let origin = layout.grid(d).origin;
                    let wide = finest_error_lanes::<i64>(n, origin, &p, &ErrorInput::new(&input));
                    PORTABLE.set(true);
                    let portable = finest_error_fast(n, origin, &p, grid_abs(&p), &ErrorInput::new(&input));
                    PORTABLE.set(false);
                    proptest::prop_assert_eq!((wide, portable), (want, want), "{} finest", d);
                }
                if d.level < layout.finest_level() || !d.is_even() {
                    for parallel in [false, true] {
                        proptest::prop_assert_eq!(surface_error_scan(&layout, d, &p, grid_abs(&p), &ErrorInput::new(&input), parallel), want, "{} {}", d, parallel);
                        // The same in 64-bit lanes, which the small heights here never pick.
                        proptest::prop_assert_eq!(surface_error_lanes(&layout, d, &p, &ErrorInput::new(&input), parallel, false), want, "{} {} wide", d, parallel);
                    }
                    // The portable kernels, which a CPU with AVX2 never runs otherwise (one
                    // thread: the switch is per thread).
                    PORTABLE.set(true);
                    let got = [true, false].map(|narrow| surface_error_lanes(&layout, d, &p, &ErrorInput::new(&input), false, narrow));
                    PORTABLE.set(false);
                    proptest::prop_assert_eq!(got, [want; 2], "{} portable", d);
                }
            }
        }
    }

    #[test]
    fn extreme_heights_on_coarse_grids_take_wide_lanes_and_stay_exact() {
        // Spacing 2^7 at the root: 44·10⁶ · 2^7 does not fit 32 bits.
        let layout = Layout::new(5, 5, 1, 1).unwrap();
        let (ex, ey) = layout.face_extent();
        let (w, h) = (ex as usize + 1, ey as usize + 1 - 3);
        let big = crate::lifting::MAX_ABS_HEIGHT;
        let values = (0..w * h)
            .map(|k| {
                if (k * 7919) % 5 < 2 {
                    big
                } else {
                    -big + (k % 13) as i32
                }
            })
            .collect();
        let input = HeightGrid::all_valid(w, h, values);
        let n = layout.n();
        let mut frontier: Vec<DiamondId> = layout.roots().collect();
        let mut seen = std::collections::HashSet::new();
        while let Some(d) = frontier.pop() {
            if !seen.insert(d) || d.level > 3 {
                continue;
            }
            frontier.extend(layout.children(d).into_iter().flatten());
            let p: Vec<i32> = (0..n * n)
                .map(|k| if k % 3 == 0 { -big } else { big - k as i32 })
                .collect();
            let want = brute_force(&layout, d, &p, &input);
            assert!(want > 1 << 25, "{d}: the errors are large");
            assert_eq!(
                surface_error(&layout, d, &p, &ErrorInput::new(&input)),
                want,
                "{d}"
            );
        }
    }

    #[test]
    fn interpolation_hits_vertices_and_is_linear_on_triangles() {
        let n = 3;
        let p = [0, 10, 20, 5, 16, 30, 8, 20, 40];
        for diag in [Diagonal::Main, Diagonal::Anti] {
            let h = 4;
            for j in 0..n {
                for i in 0..n {
                    let got = interpolate_h(&p, n, diag, h, i as i64 * h, j as i64 * h);
                    assert_eq!(
                        got,
                        i64::from(p[j * n + i]) * h,
                        "{diag:?} vertex ({i},{j})"
                    );
                }
            }
        }
        // Midpoint of the split diagonal of cell (0,0): the mean of its two ends.
        assert_eq!(
            interpolate_h(&p, n, Diagonal::Main, 4, 2, 2),
            16 * 2,
            "(0 + 16) / 2, times h = 4"
        );
        assert_eq!(interpolate_h(&p, n, Diagonal::Anti, 4, 2, 2), (10 + 5) * 2);
    }

    #[test]
    fn error_of_an_exact_plane_is_zero_and_of_a_bump_is_its_height() {
        let layout = Layout::new(5, 1, 1, 1).unwrap(); // root side 8, finest spacing 1
        let root = layout.roots().next().unwrap();
        let plane = |x: i64, y: i64| (3 * x - 2 * y) as i32;
        let values: Vec<i32> = (0..81).map(|k| plane(k % 9, k / 9)).collect();
        let mut input = HeightGrid::all_valid(9, 9, values);
        let g = layout.grid(root);
        let p: Vec<i32> = (0..25)
            .map(|k| {
                let (x, y) = g.point(k % 5, k / 5);
                plane(x, y)
            })
            .collect();
        assert_eq!(
            surface_error(&layout, root, &p, &ErrorInput::new(&input)),
            0
        );
        input.values[4 * 9 + 3] += 7; // a sample between grid vertices
        assert_eq!(
            surface_error(&layout, root, &p, &ErrorInput::new(&input)),
            7
        );
        input.valid[4 * 9 + 3] = false; // nodata does not count
        assert_eq!(
            surface_error(&layout, root, &p, &ErrorInput::new(&input)),
            0
        );
    }
}
