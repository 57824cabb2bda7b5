//! One diamond's object-error scan away from the finest level: its surface walked row by row
//! in the diamond's scaled grid coordinates, compared with the input in vectorised loops
//! (odd levels in batches of rows kept transposed, so the input is read row by row).

use rayon::prelude::*;

use super::ErrorInput;
use super::lanes::{Lane, PREFETCH_ROWS, extremes, prefetch};
use super::walk::SurfaceWalk;
use crate::geometry::{DiamondId, Layout};
use crate::quant::HeightGrid;

/// Bytes of an odd-level batch of surface rows (see [`Scan::odd_rows`]): small enough to stay in
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

/// One diamond's scan: its grid, spacing and placement over the input.
pub(super) struct Scan<'a> {
    p: &'a [i32],
    n: usize,
    input: &'a HeightGrid,
    /// The validity mask, `None` when every sample is valid.
    valid: Option<&'a [bool]>,
    odd: bool,
    /// Grid spacing in `(s, t)` units, a power of two, and its log.
    pub(super) sp: i64,
    shift: u32,
    /// Last row / column of `(s, t)`: `sp·(N − 1)`.
    side: i64,
    origin: (i64, i64),
    /// The samples measured ([`ErrorInput::clipped`]).
    clip: (i64, i64, i64, i64),
}

impl<'a> Scan<'a> {
    pub(super) fn new(
        layout: &Layout,
        id: DiamondId,
        p: &'a [i32],
        error_input: &ErrorInput<'a>,
    ) -> Self {
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
    pub(super) fn run<const MAIN: bool, T: Lane>(&self, parallel: bool) -> u32 {
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
        if std::arch::is_x86_feature_detected!("avx2") && !super::tests::portable_only() {
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
    /// The surface is walked row by row ([`SurfaceWalk`]): filled exactly along the first row
    /// with data, then moved to each next row by per-column steps. Every loop is straight and
    /// vectorises; all of them are `#[inline(always)]`, so that [`Scan::rows_avx2`]'s
    /// `target_feature` compiles them for the wider vector unit.
    #[inline(always)]
    fn rows<const MAIN: bool, T: Lane>(&self, t0: i64, t1: i64) -> i64 {
        let Some((ta, tb, columns)) = self.span(t0, t1) else {
            return 0;
        };
        let sp = (self.sp, self.shift);
        let mut walk = SurfaceWalk::<MAIN, T>::new(self.p, self.n, sp, columns, (ta, tb));
        let (hi, lo) = if self.odd {
            self.odd_rows(&mut walk, (ta, tb), columns)
        } else {
            self.even_rows(&mut walk, (ta, tb), columns.0)
        };
        hi.widen().max(-lo.widen())
    }

    /// The first and last rows of `t0..=t1` with data, and the columns `(ulo, uhi)` any of
    /// them needs; `None` when no row has data.
    #[inline(always)]
    fn span(&self, t0: i64, t1: i64) -> Option<(i64, i64, (i64, i64))> {
        let (lo, hi) = self.data_rows();
        let (t0, t1) = (t0.max(lo), t1.min(hi));
        let ta = (t0..=t1).find(|&t| self.data_range(t).is_some())?;
        let tb = (ta..=t1)
            .rev()
            .find(|&t| self.data_range(t).is_some())
            .unwrap_or(ta);
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
        Some((ta, tb, (ulo, uhi)))
    }

    /// Even levels: the extremes over rows `ta..=tb`, each row an input row compared as the
    /// walk reaches it (columns from `ulo`).
    #[inline(always)]
    fn even_rows<const MAIN: bool, T: Lane>(
        &self,
        walk: &mut SurfaceWalk<'_, MAIN, T>,
        (ta, tb): (i64, i64),
        ulo: i64,
    ) -> (T, T) {
        let (ox, oy) = self.origin;
        let w = self.input.width as i64;
        let (values, valid) = (&self.input.values[..], self.valid);
        let (mut hi_d, mut lo_d) = (T::default(), T::default());
        let mut t = ta;
        loop {
            if let Some((lo, hi)) = self.data_range(t) {
                if let Some((lo, hi)) = self.data_range(t + PREFETCH_ROWS).filter(|_| t < tb) {
                    let k = ((oy + t + PREFETCH_ROWS) * w + ox + lo) as usize;
                    prefetch(values, valid, k, (hi - lo + 1) as usize);
                }
                let buf = &walk.surface()[(lo - ulo) as usize..=(hi - ulo) as usize];
                let k = ((oy + t) * w + ox + lo) as usize;
                let vals = &values[k..k + buf.len()];
                let oks = valid.map(|v| &v[k..k + buf.len()]);
                (hi_d, lo_d) = extremes(buf, vals, oks, self.shift, hi_d, lo_d);
                // A mapped input drops its resident pages every window read.
                self.input.touched_sparse_rows(1, buf.len());
            }
            if t == tb {
                return (hi_d, lo_d);
            }
            t += 1;
            walk.advance(t, tb);
        }
    }

    /// Odd levels: the extremes over rows `ta..=tb` (columns `ulo..=uhi`). A row is an input
    /// diagonal, and walking it touches one input row (and memory page) per sample. So a batch
    /// of surface rows is kept, transposed: input row Δy crosses batch row r at
    /// s = 2Δy + t0 + r, so the samples of one input row lie on one diagonal s − r of the
    /// batch, and the batch is stored diagonal by diagonal, each diagonal's rows adjacent.
    /// Then the batch is compared with the input in input-row order ([`Scan::odd_batch`]),
    /// both sides contiguous. Only entries with s ≡ t (mod 2) are samples, so a batch's
    /// diagonals share one parity and are kept at half resolution.
    #[inline(always)]
    fn odd_rows<const MAIN: bool, T: Lane>(
        &self,
        walk: &mut SurfaceWalk<'_, MAIN, T>,
        (ta, tb): (i64, i64),
        (ulo, uhi): (i64, i64),
    ) -> (T, T) {
        let len = (uhi - ulo + 1) as usize;
        let br = odd_batch_rows::<T>((tb - ta + 1) as usize, len);
        let mut batch = vec![T::default(); (len.div_ceil(2) + br) * br];
        let mut batch_from = ta;
        let (mut hi_d, mut lo_d) = (T::default(), T::default());
        let mut t = ta;
        loop {
            let r = (t - batch_from) as usize;
            // The first sample column of row t, and its diagonal's slot.
            let s0 = ulo + (t - ulo).rem_euclid(2);
            if s0 <= uhi {
                let d0 = odd_diagonal(s0 - r as i64, ulo, br);
                let slots = batch[d0 * br + r..].iter_mut().step_by(br);
                let row = walk.surface()[(s0 - ulo) as usize..].iter().step_by(2);
                for (slot, &v) in slots.zip(row) {
                    *slot = v;
                }
            }
            if r + 1 == br || t == tb {
                let rows = (batch_from, t);
                (hi_d, lo_d) = self.odd_batch(&batch, br, rows, ulo, uhi, (hi_d, lo_d));
                batch_from = t + 1;
            }
            if t == tb {
                return (hi_d, lo_d);
            }
            t += 1;
            walk.advance(t, tb);
        }
    }

    /// Folds into `(hi, lo)` the extremes of `surface − value·sp` over the valid samples of
    /// odd-level rows `t0..=t1`, whose surfaces (columns `ulo..=uhi`) are in `batch` of `br`
    /// rows, diagonal by diagonal (see [`Scan::odd_rows`]). Walks the input row by row: along an input row, `s`
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
pub(super) fn odd_diagonal(d: i64, ulo: i64, br: usize) -> usize {
    ((d - ulo + br as i64) >> 1) as usize
}
