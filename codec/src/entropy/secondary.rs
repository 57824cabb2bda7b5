//! Secondary prediction of a band's quantizer indices from what the decoder already has: the
//! indices decoded beside them in the same band (left `L`, top `T`, top-left, top-right; 0
//! outside the band) and, for a diamond's cells, the diamond's grid ([`GridHints`]: how far
//! another cell predictor on the grid lands from the codec's own, in quantizer steps). Coding
//! `v − p` instead of `v` is lossless on the indices, so it changes neither the reconstruction
//! nor the error bound, only what the entropy coder sees.
//!
//! Every prediction is clamped to `±`[`PREDICTION_LIMIT`], and neighbours beyond it switch the
//! neighbour terms off, so `|p| ≤ PREDICTION_LIMIT` whatever the bytes.

use crate::entropy::ParentGrid;
use crate::lifting::cell_uses_order4;

/// Largest magnitude of a prediction.
pub const PREDICTION_LIMIT: i32 = 1 << 16;

/// How a band's indices are predicted.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum InBand {
    /// No prediction: the indices are coded as they are.
    None,
    /// `⌊(L + T) / 4⌉`.
    HalfMean,
    /// `−⌊(L + T) / 4⌉`.
    NegHalfMean,
    /// The median of 0, `L` and `T`.
    MedianZero,
    /// The cell's flatter diagonal's mean instead of the codec's prediction (exact at step 1,
    /// in whole steps above).
    Flatter,
    /// Half-way from the codec's prediction to the flatter diagonal's mean.
    HalfFlatter,
    /// The median of the codec's prediction and the two diagonals' means.
    Median,
    /// Half-way from the codec's prediction to the four corners' mean.
    HalfBilinear,
    /// Per cell, whichever of none, [`InBand::Flatter`], [`InBand::HalfFlatter`] and
    /// [`InBand::Median`] would have predicted the decoded neighbours `L`, `T`, `TL`, `TR`
    /// best (least absolute error summed; ties to the first).
    LocalBest,
}

impl InBand {
    /// Every predictor, for measurement.
    pub const ALL: [InBand; 9] = [
        InBand::None,
        InBand::HalfMean,
        InBand::NegHalfMean,
        InBand::MedianZero,
        InBand::Flatter,
        InBand::HalfFlatter,
        InBand::Median,
        InBand::HalfBilinear,
        InBand::LocalBest,
    ];

    /// A short name for tables.
    pub fn name(self) -> &'static str {
        match self {
            Self::None => "none",
            Self::HalfMean => "(L + T) / 4",
            Self::NegHalfMean => "−(L + T) / 4",
            Self::MedianZero => "median(0, L, T)",
            Self::Flatter => "grid: flatter diagonal",
            Self::HalfFlatter => "grid: half-way to the flatter diagonal",
            Self::Median => "grid: median of codec and diagonals",
            Self::HalfBilinear => "grid: half-way to bilinear",
            Self::LocalBest => "grid: per cell, the best on the neighbours",
        }
    }

    /// The prediction from the neighbours `[L, T, TL, TR]` and the cell's grid hints.
    #[inline]
    fn predict(self, [l, t, _, _]: [i32; 4], hint: CellHint) -> i32 {
        let lim = PREDICTION_LIMIT;
        let near = [l, t].iter().all(|v| (-lim..=lim).contains(v));
        match self {
            Self::None => 0,
            Self::HalfMean if near => round(i64::from(l + t), 4) as i32,
            Self::NegHalfMean if near => -round(i64::from(l + t), 4) as i32,
            Self::MedianZero if near => l.min(t).max(0.min(l.max(t))),
            Self::HalfMean | Self::NegHalfMean | Self::MedianZero => 0,
            Self::Flatter => hint[FLATTER],
            Self::HalfFlatter => hint[HALF_FLATTER],
            Self::Median => hint[MEDIAN],
            Self::HalfBilinear => hint[HALF_BILINEAR],
            // Needs the neighbours' hints: `predict_at` does it.
            Self::LocalBest => 0,
        }
    }
}

/// `num / den` rounded to nearest, halves away from zero (`den > 0`); 32-bit division where
/// the operands fit, which gives the same quotient.
#[inline]
fn round(num: i64, den: i64) -> i64 {
    let num = num + num.signum() * (den / 2);
    match (i32::try_from(num), i32::try_from(den)) {
        (Ok(n), Ok(d)) => i64::from(n / d),
        _ => num / den,
    }
}

/// One cell's grid predictions less the codec's, in quantizer steps, rounded and clamped to
/// `±PREDICTION_LIMIT`: indexed by [`FLATTER`], [`HALF_FLATTER`], [`MEDIAN`],
/// [`HALF_BILINEAR`].
type CellHint = [i32; 4];
const FLATTER: usize = 0;
const HALF_FLATTER: usize = 1;
const MEDIAN: usize = 2;
const HALF_BILINEAR: usize = 3;

const NO_HINT: CellHint = [0; 4];

/// For each cell of a diamond's grid, how far other predictors on the grid land from the
/// codec's own (order-4 Neville where it fits, `lifting::predict_cell`'s formula in 64 bits),
/// in quantizer steps ([`CellHint`]). Kept between bands so that decoding does not allocate.
#[derive(Debug, Default)]
pub struct GridHints {
    cells: Vec<CellHint>,
}

impl GridHints {
    /// Fills the hints of `grid`'s `(n − 1)²` cells.
    pub fn fill(&mut self, grid: &ParentGrid<'_>) {
        let (p, n) = (grid.values, grid.n);
        let m = n.saturating_sub(1);
        let step = i64::from(grid.step.max(1));
        let lim = i64::from(PREDICTION_LIMIT);
        // Whole steps and half steps; at step 1 without a division.
        let steps = |d: i64| if step == 1 { d } else { round(d, step) };
        let half_steps = |d: i64| {
            if step == 1 {
                round(d, 2)
            } else {
                round(d, 2 * step)
            }
        };
        self.cells.clear();
        let at = |x: usize, y: usize| i64::from(p[y * n + x]);
        for j in 0..m {
            for i in 0..m {
                let (tl, tr, bl, br) = (at(i, j), at(i + 1, j), at(i, j + 1), at(i + 1, j + 1));
                let s4 = tl + tr + bl + br;
                let own = if cell_uses_order4(n, i, j) {
                    let s8 = at(i - 1, j)
                        + at(i - 1, j + 1)
                        + at(i + 2, j)
                        + at(i + 2, j + 1)
                        + at(i, j - 1)
                        + at(i + 1, j - 1)
                        + at(i, j + 2)
                        + at(i + 1, j + 2);
                    (10 * s4 - s8 + 16) >> 5
                } else {
                    (8 * s4 + 16) >> 5
                };
                let (main, anti) = ((tl + br).div_euclid(2), (tr + bl).div_euclid(2));
                let flatter = if (tl - br).abs() <= (tr - bl).abs() {
                    main
                } else {
                    anti
                };
                let median = own.max(main.min(anti)).min(main.max(anti));
                let bilinear = (s4 + 2).div_euclid(4);
                let hint = [
                    steps(flatter - own),
                    half_steps(flatter - own),
                    steps(median - own),
                    half_steps(bilinear - own),
                ];
                self.cells.push(hint.map(|v| v.clamp(-lim, lim) as i32));
            }
        }
    }

    fn at(&self, i: usize) -> CellHint {
        self.cells[i]
    }
}

/// The neighbours `[L, T, TL, TR]` of `(x, y)` in a `w`-wide row-major band (0 outside).
#[inline]
fn neighbours(v: &[i32], w: usize, x: usize, y: usize) -> [i32; 4] {
    let at = |x: usize, y: usize| v[y * w + x];
    let l = if x > 0 { at(x - 1, y) } else { 0 };
    if y == 0 {
        return [l, 0, 0, 0];
    }
    let tl = if x > 0 { at(x - 1, y - 1) } else { 0 };
    let tr = if x + 1 < w { at(x + 1, y - 1) } else { 0 };
    [l, at(x, y - 1), tl, tr]
}

/// The hint of cell `i`: `hints`' when given (a diamond's cells), none otherwise.
#[inline]
fn hint_of(hints: Option<&GridHints>, i: usize) -> CellHint {
    hints.map_or(NO_HINT, |h| h.at(i))
}

/// `predictor`'s prediction of `(x, y)` in a `w`-wide band whose earlier values (raster order)
/// are decoded.
#[inline]
fn predict_at(
    predictor: InBand,
    values: &[i32],
    w: usize,
    x: usize,
    y: usize,
    hints: Option<&GridHints>,
) -> i32 {
    let near = neighbours(values, w, x, y);
    let i = y * w + x;
    if predictor != InBand::LocalBest {
        return predictor.predict(near, hint_of(hints, i));
    }
    let Some(hints) = hints else {
        return 0;
    };
    // The neighbours inside the band, by index.
    let mut around = [None; 4];
    if x > 0 {
        around[0] = Some(i - 1);
    }
    if y > 0 {
        around[1] = Some(i - w);
        around[2] = (x > 0).then(|| i - w - 1);
        around[3] = (x + 1 < w).then(|| i - w + 1);
    }
    // The candidates of [`InBand::LocalBest`], and the error of each summed on the neighbours.
    let candidates = |h: CellHint| [0, h[FLATTER], h[HALF_FLATTER], h[MEDIAN]];
    let mut errors = [0i64; 4];
    for &k in around.iter().flatten() {
        let v = i64::from(values[k]);
        for (e, c) in errors.iter_mut().zip(candidates(hints.at(k))) {
            *e += (v - i64::from(c)).abs();
        }
    }
    // The first of the least.
    let best = (1..4).fold(0, |b, c| if errors[c] < errors[b] { c } else { b });
    candidates(hints.at(i))[best]
}

/// The coded values of a `w × h` band of indices `values` under `predictor`, into `out`:
/// `v − p`. 64-bit, since `v − p` may leave `i32`'s range near its ends; the caller checks it
/// against its coder's limit. `hints`, when given, are the band's cells' ([`GridHints::fill`]).
pub fn forward(
    predictor: InBand,
    values: &[i32],
    w: usize,
    h: usize,
    hints: Option<&GridHints>,
    out: &mut Vec<i64>,
) {
    assert_eq!(values.len(), w * h, "band size mismatch");
    out.clear();
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let p = predict_at(predictor, values, w, x, y, hints);
            out.push(i64::from(values[i]) - i64::from(p));
        }
    }
}

/// Undoes [`forward`] in place: `values` holds the coded values, and gets the indices back,
/// in raster order so that every prediction sees decoded neighbours. Sums that leave `i32`
/// saturate (a valid record never has them; the caller checks the result's range).
pub fn inverse(
    predictor: InBand,
    values: &mut [i32],
    w: usize,
    h: usize,
    hints: Option<&GridHints>,
) {
    assert_eq!(values.len(), w * h, "band size mismatch");
    if predictor == InBand::None {
        return;
    }
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let p = predict_at(predictor, values, w, x, y, hints);
            values[i] = values[i].saturating_add(p);
        }
    }
}
