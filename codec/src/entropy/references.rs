//! Entropy references for the coders' rate: what an ideal static coder would spend on the
//! symbols a coder codes, with no context, with the coder's own contexts, and — for comparison
//! with JPEG-LS — on the residuals of its MED predictor over the same quantized lattice, with
//! and without its 365 gradient contexts. `cbdam bench entropy` prints these beside the bits
//! the coder actually spent, per level and band kind, so that a rate gap can be laid at the
//! door of the prediction, the context model or the coder's fixed costs.
//!
//! Every figure is an empirical entropy in bits (a total, so that levels add up): the counts
//! are taken over everything measured and the code is the one that knows them in advance, so
//! it is a lower bound for any coder with those contexts, not reachable by an adaptive one
//! (which learns the counts as it goes) nor by a static one (which must send them).

use std::collections::HashMap;

use super::adaptive::class_of;
use crate::lifting::median_edge as med;

/// Counts of `(context, symbol)` pairs: enough for the zero-order and the context-conditioned
/// empirical entropy.
#[derive(Clone, Debug, Default)]
pub struct SymbolStats {
    joint: HashMap<(u32, i32), u64>,
    by_context: HashMap<u32, u64>,
    by_symbol: HashMap<i32, u64>,
    total: u64,
}

impl SymbolStats {
    /// Counts one `symbol` seen in `context`.
    pub fn add(&mut self, context: u32, symbol: i32) {
        *self.joint.entry((context, symbol)).or_default() += 1;
        *self.by_context.entry(context).or_default() += 1;
        *self.by_symbol.entry(symbol).or_default() += 1;
        self.total += 1;
    }

    /// Symbols counted.
    pub fn count(&self) -> u64 {
        self.total
    }

    /// Distinct contexts seen.
    pub fn contexts(&self) -> usize {
        self.by_context.len()
    }

    /// Total bits of the zero-order code: `−Σ n(s) log2(n(s) / N)`.
    pub fn zero_order_bits(&self) -> f64 {
        let n = self.total as f64;
        self.by_symbol.values().map(|&c| bits_of(c, n)).sum()
    }

    /// Total bits of the code conditioned on the context: `−Σ n(c, s) log2(n(c, s) / n(c))`.
    pub fn conditional_bits(&self) -> f64 {
        self.joint
            .iter()
            .map(|(&(ctx, _), &c)| bits_of(c, self.by_context[&ctx] as f64))
            .sum()
    }

    /// Total bits of coding only `|symbol|` conditioned on the context, plus one raw bit for
    /// the sign of each non-zero symbol: what a coder whose signs are raw bits can reach.
    pub fn conditional_bits_raw_sign(&self) -> f64 {
        let mut magnitudes: HashMap<(u32, u32), u64> = HashMap::new();
        let mut signs = 0u64;
        for (&(ctx, s), &c) in &self.joint {
            *magnitudes.entry((ctx, s.unsigned_abs())).or_default() += c;
            if s != 0 {
                signs += c;
            }
        }
        let magnitude_bits: f64 = magnitudes
            .iter()
            .map(|(&(ctx, _), &c)| bits_of(c, self.by_context[&ctx] as f64))
            .sum();
        magnitude_bits + signs as f64
    }

    /// Adds `other`'s counts to these.
    pub fn merge(&mut self, other: &SymbolStats) {
        for (&k, &c) in &other.joint {
            *self.joint.entry(k).or_default() += c;
        }
        for (&k, &c) in &other.by_context {
            *self.by_context.entry(k).or_default() += c;
        }
        for (&k, &c) in &other.by_symbol {
            *self.by_symbol.entry(k).or_default() += c;
        }
        self.total += other.total;
    }
}

/// `−c · log2(c / n)`, the bits of `c` occurrences of a symbol of probability `c / n`.
fn bits_of(c: u64, n: f64) -> f64 {
    let c = c as f64;
    -c * (c / n).log2()
}

/// Hands `visit(context, value)` every value of a `w × h` band (row-major) with the context
/// the adaptive coders give it: the class of the neighbourhood sum `2|L| + 2|T| + |TL| + |TR|`
/// (neighbours outside the band are 0) times 2, plus 1 on the two-sample border where the
/// residuals come from a lower-order predictor. Values in all-zero leaf blocks get the context
/// too (their zero neighbourhoods give the quietest class), as a coder without the quadtree
/// would see them.
pub fn coder_contexts(values: &[i32], w: usize, h: usize, mut visit: impl FnMut(u32, i32)) {
    assert_eq!(values.len(), w * h, "band size mismatch");
    // Magnitudes above 1024 all fall in the last class; clamping keeps the sum in range.
    let mag = |x: usize, y: usize| values[y * w + x].unsigned_abs().min(1024);
    for y in 0..h {
        for x in 0..w {
            let left = if x > 0 { mag(x - 1, y) } else { 0 };
            let (top, top_left, top_right) = if y > 0 {
                (
                    mag(x, y - 1),
                    if x > 0 { mag(x - 1, y - 1) } else { 0 },
                    if x + 1 < w { mag(x + 1, y - 1) } else { 0 },
                )
            } else {
                (0, 0, 0)
            };
            let sum = 2 * (left + top) + top_left + top_right;
            let border = (y < 2 || y + 2 >= h || x < 2 || x + 2 >= w) as u32;
            visit(class_of(sum) as u32 * 2 + border, values[y * w + x]);
        }
    }
}

/// Contexts of JPEG-LS (ITU-T T.87): three local gradients, each quantized to −4 … 4 by the
/// default thresholds for the lattice's range and `near`, the triple's sign merged into the
/// residual's, so 365 contexts (0 is the flat one, where JPEG-LS would switch to run mode).
#[derive(Clone, Copy, Debug)]
struct GradientQuantizer {
    t1: i64,
    t2: i64,
    t3: i64,
    near: i64,
}

impl GradientQuantizer {
    /// The default thresholds of T.87 §C.2.4.1.1 for `MAXVAL = max_value` (≥ 128 assumed, as
    /// for any DEM lattice; smaller ranges get the same formula, clamped).
    fn new(max_value: i64, near: i64) -> Self {
        let max_value = max_value.max(1);
        let factor = (max_value.min(4095) + 128) >> 8;
        let clamp = |v: i64, lo: i64| if v > max_value || v < lo { lo } else { v };
        // T.87's BASIC_T1..3 = 3, 7, 21.
        let t1 = clamp(factor + 2 + 3 * near, near + 1);
        let t2 = clamp(factor * 4 + 3 + 5 * near, t1);
        let t3 = clamp(factor * 17 + 4 + 7 * near, t2);
        Self { t1, t2, t3, near }
    }

    fn quantize(&self, d: i64) -> i64 {
        let magnitude = |d: i64| {
            if d >= self.t3 {
                4
            } else if d >= self.t2 {
                3
            } else if d >= self.t1 {
                2
            } else if d > self.near {
                1
            } else {
                0
            }
        };
        if d < 0 { -magnitude(-d) } else { magnitude(d) }
    }
}

/// One sample of [`med_residuals`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MedSample {
    /// JPEG-LS's context, 0 … 364, the gradients' sign merged.
    pub context: u32,
    /// The quantized residual with the context's sign merged in, as JPEG-LS codes it.
    pub index: i32,
}

/// The MED (LOCO-I / JPEG-LS) predictor run over a `w × h` integer lattice in closed loop with
/// JPEG-LS's near-lossless quantizer (step `2·near + 1`, residual indices rounded to nearest,
/// each sample reconstructed before the next is predicted), handing `visit` every sample's
/// context and index. Outside the lattice: the row above the first is 0, the left neighbour of
/// the first column is the sample above it, and the top-left and top-right neighbours off the
/// edge repeat the sample above. JPEG-LS's bias correction, run mode and modular reduction are
/// left out: per-context counts already hold each context's bias, so they would change the
/// entropy little. Samples where `valid` is false are taken to be their prediction (index 0).
pub fn med_residuals(
    values: &[i32],
    valid: Option<&[bool]>,
    w: usize,
    h: usize,
    near: i32,
    mut visit: impl FnMut(MedSample),
) {
    assert_eq!(values.len(), w * h, "lattice size mismatch");
    if w == 0 || h == 0 {
        return;
    }
    let (lo, hi) = values.iter().fold((i64::MAX, i64::MIN), |(lo, hi), &v| {
        (lo.min(v.into()), hi.max(v.into()))
    });
    let quantizer = GradientQuantizer::new(hi - lo, near.into());
    let step = 2 * i64::from(near) + 1;
    let mut above = vec![0i64; w];
    let mut row = vec![0i64; w];
    for y in 0..h {
        for x in 0..w {
            let b = above[x];
            let a = if x > 0 { row[x - 1] } else { b };
            let c = if x > 0 { above[x - 1] } else { b };
            let d = if x + 1 < w { above[x + 1] } else { b };
            let prediction = med(a, b, c);
            let q = [d - b, b - c, c - a].map(|g| quantizer.quantize(g));
            let mut context = 81 * q[0] + 9 * q[1] + q[2];
            let sign = if context < 0 { -1 } else { 1 };
            context *= sign;
            let i = y * w + x;
            let is_valid = valid.is_none_or(|v| v[i]);
            let error = if is_valid {
                sign * (i64::from(values[i]) - prediction)
            } else {
                0
            };
            let index = if error >= 0 {
                (error + i64::from(near)) / step
            } else {
                -((i64::from(near) - error) / step)
            };
            row[x] = prediction + sign * index * step;
            visit(MedSample {
                context: context as u32,
                index: index as i32,
            });
        }
        std::mem::swap(&mut above, &mut row);
    }
}

/// Cell predictors to weigh against the codec's own on a decoded grid: what the cells'
/// residuals would cost with another prediction, all else equal.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CellPredictor {
    /// The codec's prediction (`lifting::predict_cells`: order-4 Neville where it fits).
    Codec,
    /// The mean of the cell's four corners (order 2 everywhere).
    Bilinear,
    /// The mean of the two corners along the flatter diagonal (edge-directed).
    FlatterDiagonal,
    /// The median of the codec's prediction and the two diagonals' means.
    Median,
}

impl CellPredictor {
    /// Every predictor, the codec's first.
    pub const ALL: [CellPredictor; 4] = [
        CellPredictor::Codec,
        CellPredictor::Bilinear,
        CellPredictor::FlatterDiagonal,
        CellPredictor::Median,
    ];

    /// A short name for tables.
    pub fn name(self) -> &'static str {
        match self {
            Self::Codec => "codec (Neville)",
            Self::Bilinear => "bilinear (4 corners)",
            Self::FlatterDiagonal => "flatter diagonal",
            Self::Median => "median of codec and diagonals",
        }
    }
}

/// The four corners of cell `(i, j)` (column, row) of an `n × n` grid: top-left, top-right,
/// bottom-left, bottom-right.
fn corners(p: &[i32], n: usize, i: usize, j: usize) -> [i64; 4] {
    [
        p[j * n + i],
        p[j * n + i + 1],
        p[(j + 1) * n + i],
        p[(j + 1) * n + i + 1],
    ]
    .map(i64::from)
}

/// The quantizer indices of a diamond's `(n − 1)²` cells under `predictor`, into `out`: `p` is
/// the diamond's `n × n` grid, `codec` the codec's predictions of its cells and `cells` their
/// reconstructed heights; each residual is rounded to the nearest multiple of `step` (odd).
/// Exact where `step` is 1 (the grid and cells are then the input's); with a coarser step it
/// is an open-loop estimate, since a closed loop with another predictor would quantize other
/// values.
pub fn cell_indices(
    predictor: CellPredictor,
    p: &[i32],
    n: usize,
    codec: &[i32],
    cells: &[i32],
    step: i32,
    out: &mut Vec<i32>,
) {
    let m = n - 1;
    assert!(p.len() == n * n && codec.len() == m * m && cells.len() == m * m);
    let step = i64::from(step);
    let k = (step - 1) / 2;
    out.clear();
    for j in 0..m {
        for i in 0..m {
            let [tl, tr, bl, br] = corners(p, n, i, j);
            let own = i64::from(codec[j * m + i]);
            let (main, anti) = ((tl + br).div_euclid(2), (tr + bl).div_euclid(2));
            let prediction = match predictor {
                CellPredictor::Codec => own,
                CellPredictor::Bilinear => (tl + tr + bl + br + 2).div_euclid(4),
                CellPredictor::FlatterDiagonal if (tl - br).abs() <= (tr - bl).abs() => main,
                CellPredictor::FlatterDiagonal => anti,
                CellPredictor::Median => own.max(main.min(anti)).min(main.max(anti)),
            };
            let r = i64::from(cells[j * m + i]) - prediction;
            let index = r.signum() * ((r.abs() + k) / step);
            out.push(index as i32);
        }
    }
}

/// Bin 0 … 7 of the spread of cell `(i, j)`'s corners in quantizer steps:
/// `⌊log2(1 + (|TL − BR| + |TR − BL|) / step)⌋`, at most 7. Known to a decoder before the cell.
pub fn corner_activity(p: &[i32], n: usize, i: usize, j: usize, step: i32) -> u32 {
    let [tl, tr, bl, br] = corners(p, n, i, j);
    let spread = ((tl - br).abs() + (tr - bl).abs()) / i64::from(step.max(1));
    ((spread + 1).ilog2()).min(7)
}

#[cfg(test)]
#[path = "references_tests.rs"]
mod tests;
