//! Quincunx Neville prediction on one diamond's grid (paper eqs. 1–4, Fig. 3).
//!
//! A diamond's `N × N` vertex grid `P` (row-major, `P[j·N + i]`) predicts its `(N−1)²` cell
//! centres `C` (cell `(i, j)` lies between vertices `i, i+1` and `j, j+1`), and the cell centres
//! predict the inner vertices. Order 4 (10/32 on the 4 nearest, −1/32 on the 8 next) is used where
//! the whole support lies in the diamond's own grid, order 2 (¼ on the 4 nearest) elsewhere, so a
//! diamond never reads outside itself and every record decodes on its own.
//!
//! All filters are integer with exactly one rounding, by floor: order 2 is scaled by 8 so both
//! orders round as `(num + 16) >> 5`. Encoder and decoder therefore agree bit for bit. Inputs
//! must satisfy `|value| ≤` [`MAX_ABS_HEIGHT`] so that numerators (at most 48 times a value)
//! fit an `i32`.

/// Largest magnitude of any reconstructed height, in the repository's integer unit. Filter
/// numerators reach 48 times this, which must stay below 2^31.
pub const MAX_ABS_HEIGHT: i32 = 44_000_000;

/// Predictions are clamped to `±PREDICTION_LIMIT` before a residual is added. Where residuals
/// are "don't care" (outside the data, nodata) a reconstruction *is* its prediction, and
/// order-4 overshoot (up to 50 % of a step) compounds level after level; the clamp bounds every
/// reconstruction by `PREDICTION_LIMIT + k ≤ MAX_ABS_HEIGHT`, so numerators always fit `i32`.
/// Encoder and decoder clamp identically, so reconstruction stays bit-exact.
pub const PREDICTION_LIMIT: i32 = 40_000_000;

/// Clamps a prediction to `±PREDICTION_LIMIT`.
#[inline]
pub fn clamp_prediction(v: i64) -> i64 {
    v.clamp(-i64::from(PREDICTION_LIMIT), i64::from(PREDICTION_LIMIT))
}

/// Whether cell `(i, j)` of an `N`-grid is predicted with order 4 (its 12-point support, one
/// vertex beyond the cell on each side, lies inside the grid).
#[inline]
pub fn cell_uses_order4(n: usize, i: usize, j: usize) -> bool {
    (1..=n.wrapping_sub(3)).contains(&i) && (1..=n.wrapping_sub(3)).contains(&j)
}

/// Whether inner vertex `(i, j)` is predicted with order 4 from the cell centres.
#[inline]
pub fn vertex_uses_order4(n: usize, i: usize, j: usize) -> bool {
    (2..=n.wrapping_sub(3)).contains(&i) && (2..=n.wrapping_sub(3)).contains(&j)
}

/// Prediction of cell `(i, j)` from the vertex grid `p`.
#[inline]
pub fn predict_cell(p: &[i32], n: usize, i: usize, j: usize) -> i32 {
    let at = |x: usize, y: usize| p[y * n + x];
    let s4 = at(i, j) + at(i + 1, j) + at(i, j + 1) + at(i + 1, j + 1);
    if cell_uses_order4(n, i, j) {
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
    }
}

/// Which compilation of the decoder's vector loops runs: the portable one, the reference (on
/// AArch64 it is NEON, part of the baseline; on wasm32 `simd128` where the build enables it),
/// or one compiled for a wider vector unit the CPU was found to have at run time. Every kind
/// gives the same integers: the same source, only the instructions differ.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VectorKernels {
    /// The target's baseline instructions (SSE2 on x86-64).
    Portable,
    /// AVX2 (x86-64, detected at run time).
    #[cfg(target_arch = "x86_64")]
    Avx2,
}

impl VectorKernels {
    /// The fastest kind this CPU runs.
    #[inline]
    pub fn detected() -> Self {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            return Self::Avx2;
        }
        Self::Portable
    }

    /// Every kind this CPU runs, the portable one first.
    pub fn available() -> Vec<Self> {
        let mut kinds = vec![Self::Portable];
        if Self::detected() != Self::Portable {
            kinds.push(Self::detected());
        }
        kinds
    }
}

/// Predictions of all `(N−1)²` cells, row-major into `out`.
///
/// The hot path of decoding: borders use [`predict_cell`], the interior runs a branch-free loop
/// over rows so the compiler can vectorise it ([`VectorKernels::Portable`]).
pub fn predict_cells(p: &[i32], n: usize, out: &mut [i32]) {
    predict_cells_inline(p, n, out);
}

/// [`predict_cells`], inlined into its caller so that a caller compiled for wider vectors
/// ([`VectorKernels`]) vectorises it with them.
#[inline(always)]
pub(crate) fn predict_cells_inline(p: &[i32], n: usize, out: &mut [i32]) {
    // `p` is only a stand-in for the per-cell operand, which the identity ignores (its loads
    // are dead and compiled out); it is long enough: N² ≥ (N−1)².
    predict_cells_then(p, n, out, p, |prediction, _| prediction);
}

/// Every cell's prediction `c`, with cell `k`'s `operand[k]`, through `finish(c, operand[k])`,
/// row-major into `out`: the decoder finishes a cell (clamp, residual) in the pass that predicts
/// it. `operand` must hold at least `(N−1)²` values.
#[inline(always)]
pub(crate) fn predict_cells_then(
    p: &[i32],
    n: usize,
    out: &mut [i32],
    operand: &[i32],
    finish: impl Fn(i32, i32) -> i32,
) {
    let m = n - 1;
    assert!(p.len() == n * n && out.len() == m * m && operand.len() >= m * m);
    // Order 2 from the four nearest vertices (`predict_cell` outside the order-4 region).
    let order2 = |s4: i32| (8 * s4 + 16) >> 5;
    for j in 0..m {
        if m < 4 {
            for i in 0..m {
                let k = j * m + i;
                out[k] = finish(predict_cell(p, n, i, j), operand[k]);
            }
            continue;
        }
        let (r0, r1) = (&p[j * n..][..n], &p[(j + 1) * n..][..n]);
        if !cell_uses_order4(n, 1, j) {
            // The first and last rows: order 2 everywhere, as slices (no bounds checks).
            let (a, b, c, d) = (&r0[..m], &r0[1..], &r1[..m], &r1[1..]);
            let row = &mut out[j * m..][..m];
            let ops = &operand[j * m..][..m];
            for i in 0..m {
                row[i] = finish(order2(a[i] + b[i] + c[i] + d[i]), ops[i]);
            }
            continue;
        }
        // The row's first and last cells are order 2.
        for i in [0, m - 1] {
            let k = j * m + i;
            out[k] = finish(order2(r0[i] + r0[i + 1] + r1[i] + r1[i + 1]), operand[k]);
        }
        // The interior cells i = 1..=m−2 (w of them) read the four rows at columns i−1..=i+2:
        // slices of exactly w values, so the loop has no bounds checks and vectorises.
        let w = m - 2;
        let cols = |r: usize| -> [&[i32]; 4] {
            let row = &p[r * n..(r + 1) * n];
            std::array::from_fn(|c| &row[c..c + w])
        };
        let ([_, up1, up2, _], [r0a, r0b, r0c, r0d], [r1a, r1b, r1c, r1d], [_, dn1, dn2, _]) =
            (cols(j - 1), cols(j), cols(j + 1), cols(j + 2));
        let row = &mut out[j * m + 1..][..w];
        let ops = &operand[j * m + 1..][..w];
        for k in 0..w {
            let s4 = r0b[k] + r0c[k] + r1b[k] + r1c[k];
            let s8 = r0a[k] + r1a[k] + r0d[k] + r1d[k] + up1[k] + up2[k] + dn1[k] + dn2[k];
            row[k] = finish((10 * s4 - s8 + 16) >> 5, ops[k]);
        }
    }
}

/// [`predict_vertex`] of all `(N−2)²` inner vertices, row-major into `out`: the α = ½ decode's
/// counterpart of [`predict_cells`], with the interior of each row in a branch-free loop.
///
/// `c` must satisfy `|value| ≤` [`MAX_ABS_HEIGHT`] (numerators are computed in `i32`).
pub fn predict_inner_vertices(c: &[i32], n: usize, out: &mut [i32]) {
    let m = n - 1;
    let k = n.saturating_sub(2);
    assert!(c.len() == m * m && out.len() == k * k);
    for j in 1..n - 1 {
        let row = &mut out[(j - 1) * k..j * k];
        if !vertex_uses_order4(n, 2, j) || n < 7 {
            for (o, i) in row.iter_mut().zip(1..) {
                *o = predict_vertex(c, n, i, j);
            }
            continue;
        }
        let (first, last) = (predict_vertex(c, n, 1, j), predict_vertex(c, n, n - 2, j));
        row[0] = first;
        row[k - 1] = last;
        let r_m2 = &c[(j - 2) * m..(j - 1) * m];
        let r_m1 = &c[(j - 1) * m..j * m];
        let r0 = &c[j * m..(j + 1) * m];
        let r1 = &c[(j + 1) * m..(j + 2) * m];
        // Vertex i (2 ≤ i ≤ N−3) sits at out index i − 1.
        for (o, i) in row[1..k - 1].iter_mut().zip(2..) {
            let s4 = r_m1[i - 1] + r_m1[i] + r0[i - 1] + r0[i];
            let s8 = r_m1[i - 2]
                + r0[i - 2]
                + r_m1[i + 1]
                + r0[i + 1]
                + r_m2[i - 1]
                + r_m2[i]
                + r1[i - 1]
                + r1[i];
            *o = (10 * s4 - s8 + 16) >> 5;
        }
    }
}

/// Prediction of inner vertex `(i, j)` (`1 ≤ i, j ≤ N−2`) from the cell grid `c`.
#[inline]
pub fn predict_vertex(c: &[i32], n: usize, i: usize, j: usize) -> i32 {
    let m = n - 1;
    let num = predict_vertex_numerator(|x, y| i64::from(c[y * m + x]), n, i, j);
    ((num + 16) >> 5) as i32
}

/// The unrounded numerator of [`predict_vertex`] scaled by 32 (`10·s4 − s8` or `8·s4`), for the
/// α = ½ analysis, which averages `V` with the exact prediction and rounds once.
#[inline]
pub fn predict_vertex_numerator(
    c: impl Fn(usize, usize) -> i64,
    n: usize,
    i: usize,
    j: usize,
) -> i64 {
    let s4 = c(i - 1, j - 1) + c(i, j - 1) + c(i - 1, j) + c(i, j);
    if vertex_uses_order4(n, i, j) {
        let s8 = c(i - 2, j - 1)
            + c(i - 2, j)
            + c(i + 1, j - 1)
            + c(i + 1, j)
            + c(i - 1, j - 2)
            + c(i, j - 2)
            + c(i - 1, j + 1)
            + c(i, j + 1);
        10 * s4 - s8
    } else {
        8 * s4
    }
}

/// The lifting weight α of inner vertices (always 1 on a diamond's sides).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Alpha {
    /// Predict-only lifting: coarse vertices are subsamples, records hold ΔC only. The default
    /// (docs/DESIGN.md: α = ½'s ΔV is mostly quantization noise and costs ≈ 2 bits/sample).
    One,
    /// The paper's smoothing: `P = (V + Pred_V(C)) / 2` on inner vertices; records add ΔV.
    Half,
}

impl Alpha {
    /// The byte stored in a repository header.
    pub fn to_byte(self) -> u8 {
        match self {
            Alpha::One => 0,
            Alpha::Half => 1,
        }
    }
    /// Parses the header byte.
    pub fn from_byte(b: u8) -> Option<Self> {
        match b {
            0 => Some(Alpha::One),
            1 => Some(Alpha::Half),
            _ => None,
        }
    }
}

/// One level of analysis on a single diamond (eqs. 1–2), with integer rounding: from the finer
/// level's vertex values `v` (`N²`) and cell values `c` (`(N−1)²`) compute the coarse vertices
/// `p` and the details `h = C − Pred_C(P)`.
///
/// With α = ½ the rounding makes the step lose up to one bit per inner vertex; the remainder
/// `r = V − (2P − Pred_V(C))` is returned so that [`synthesis`] can invert it exactly (the codec
/// carries it, quantized, in ΔV).
pub fn analysis(
    alpha: Alpha,
    n: usize,
    v: &[i32],
    c: &[i32],
    p: &mut [i32],
    h: &mut [i32],
    r: &mut [i32],
) {
    let m = n - 1;
    p.copy_from_slice(v);
    if alpha == Alpha::Half {
        for j in 1..n - 1 {
            for i in 1..n - 1 {
                let num = predict_vertex_numerator(|x, y| i64::from(c[y * m + x]), n, i, j);
                let vv = i64::from(v[j * n + i]);
                p[j * n + i] = ((32 * vv + num + 32) >> 6) as i32;
            }
        }
    }
    predict_cells(p, n, h);
    for (hk, ck) in h.iter_mut().zip(c) {
        *hk = ck - *hk;
    }
    r.fill(0);
    if alpha == Alpha::Half {
        for j in 1..n - 1 {
            for i in 1..n - 1 {
                let pv = predict_vertex(c, n, i, j);
                r[(j - 1) * (n - 2) + (i - 1)] = v[j * n + i] - (2 * p[j * n + i] - pv);
            }
        }
    }
}

/// Inverse of [`analysis`] (eqs. 3–4): from `p`, `h` and the remainders `r` rebuild `v`, `c`.
pub fn synthesis(
    alpha: Alpha,
    n: usize,
    p: &[i32],
    h: &[i32],
    r: &[i32],
    v: &mut [i32],
    c: &mut [i32],
) {
    predict_cells(p, n, c);
    for (ck, hk) in c.iter_mut().zip(h) {
        *ck += hk;
    }
    v.copy_from_slice(p);
    if alpha == Alpha::Half {
        for j in 1..n - 1 {
            for i in 1..n - 1 {
                let pv = predict_vertex(c, n, i, j);
                v[j * n + i] = 2 * p[j * n + i] - pv + r[(j - 1) * (n - 2) + (i - 1)];
            }
        }
    }
}

/// The median edge detector of LOCO-I / JPEG-LS from the left (`a`), upper (`b`) and
/// upper-left (`c`) neighbours: `min(a, b)` above an edge, `max(a, b)` below, else `a + b − c`.
/// The root field's predictor, and the reference `cbdam bench entropy` measures against.
#[inline]
pub fn median_edge(a: i64, b: i64, c: i64) -> i64 {
    if c >= a.max(b) {
        a.min(b)
    } else if c <= a.min(b) {
        a.max(b)
    } else {
        a + b - c
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn row_wise_vertex_predictions_match_the_pointwise_ones() {
        // Extreme values too: the row loop computes numerators in i32.
        let mut state = 3u64;
        for n in [3, 5, 7, 9, 17, 65] {
            let m = n - 1;
            let c: Vec<i32> = (0..m * m)
                .map(|_| {
                    state = state
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    match (state >> 60) % 4 {
                        0 => MAX_ABS_HEIGHT,
                        1 => -MAX_ABS_HEIGHT,
                        _ => ((state >> 33) % 2001) as i32 - 1000,
                    }
                })
                .collect();
            let k = n - 2;
            let mut got = vec![0; k * k];
            predict_inner_vertices(&c, n, &mut got);
            for j in 1..n - 1 {
                for i in 1..n - 1 {
                    assert_eq!(
                        got[(j - 1) * k + i - 1],
                        predict_vertex(&c, n, i, j),
                        "n = {n}, vertex ({i},{j})"
                    );
                }
            }
        }
    }

    #[test]
    fn neville_predictions_are_exact_on_polynomials_and_round_by_floor() {
        // Order 4 reproduces cubics, order 2 planes. Fields are scaled by 64 so that every exact
        // prediction is an integer and rounding cannot hide an error.
        let n = 9;
        let f = |x: f64, y: f64| 64.0 * (x * x * x - 2.0 * x * x * y + y * y * y + x * y);
        let cubic: Vec<i32> = (0..n * n)
            .map(|k| f((k % n) as f64, (k / n) as f64) as i32)
            .collect();
        for j in 0..n - 1 {
            for i in 0..n - 1 {
                if cell_uses_order4(n, i, j) {
                    let want = f(i as f64 + 0.5, j as f64 + 0.5);
                    assert_eq!(
                        f64::from(predict_cell(&cubic, n, i, j)),
                        want,
                        "cell ({i},{j})"
                    );
                }
            }
        }
        let plane: Vec<i32> = (0..n * n)
            .map(|k| 32 * (3 * (k % n) as i32 - 5 * (k / n) as i32))
            .collect();
        for j in 0..n - 1 {
            for i in 0..n - 1 {
                // The plane at the cell centre (i+½, j+½), times 32.
                let want = 32 * 3 * i as i32 + 48 - 32 * 5 * j as i32 - 80;
                assert_eq!(predict_cell(&plane, n, i, j), want, "cell ({i},{j})");
            }
        }
        // Rounding is floor even for negative numerators: -1/4 rounds to -1 with order 2 and the
        // +16 offset rounds -0.5 up to 0 (round half up).
        let mut p = vec![0i32; n * n];
        p[0] = -1;
        assert_eq!(predict_cell(&p, n, 0, 0), 0);
        p[0] = -3;
        assert_eq!(predict_cell(&p, n, 0, 0), -1);
    }

    #[test]
    fn order_regions_match_the_design() {
        let n = 65;
        assert!(
            !cell_uses_order4(n, 0, 5) && cell_uses_order4(n, 1, 1) && cell_uses_order4(n, 62, 62)
        );
        assert!(!cell_uses_order4(n, 63, 5));
        assert!(
            !vertex_uses_order4(n, 1, 5)
                && vertex_uses_order4(n, 2, 2)
                && vertex_uses_order4(n, 62, 62)
        );
        assert!(!vertex_uses_order4(n, 63, 5));
        // The vectorised loop agrees with the scalar definition everywhere.
        let p: Vec<i32> = (0..n * n)
            .map(|k| ((k * 7919) % 2001) as i32 - 1000)
            .collect();
        let mut out = vec![0; 64 * 64];
        predict_cells(&p, n, &mut out);
        for j in 0..64 {
            for i in 0..64 {
                assert_eq!(out[j * 64 + i], predict_cell(&p, n, i, j));
            }
        }
    }

    /// The row-wise cell predictions (vectorised rows, order-2 edges) are the pointwise
    /// definition on every grid size, with heights anywhere in the range.
    #[test]
    fn row_wise_cell_predictions_match_the_pointwise_ones() {
        let mut state = 5u64;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            state >> 16
        };
        for round in 0..400 {
            let n = [3, 4, 5, 6, 7, 9, 17, 33, 65][round % 9];
            let p: Vec<i32> = (0..n * n)
                .map(|_| match next() % 4 {
                    0 => MAX_ABS_HEIGHT,
                    1 => -MAX_ABS_HEIGHT,
                    _ => (next() % (2 * MAX_ABS_HEIGHT as u64 + 1)) as i32 - MAX_ABS_HEIGHT,
                })
                .collect();
            let m = n - 1;
            let mut out = vec![0; m * m];
            predict_cells(&p, n, &mut out);
            for j in 0..m {
                for i in 0..m {
                    assert_eq!(
                        out[j * m + i],
                        predict_cell(&p, n, i, j),
                        "N {n} ({i}, {j})"
                    );
                }
            }
        }
    }

    proptest! {
        #[test]
        fn lifting_round_trip_is_exact(
            n_pow in 1u32..6,
            seed in any::<u64>(),
            amp in 1i32..MAX_ABS_HEIGHT / 2,
            half in any::<bool>(),
        ) {
            let n = (1usize << n_pow) + 1;
            let alpha = if half { Alpha::Half } else { Alpha::One };
            let mut s = seed | 1;
            let mut rnd = || { s ^= s << 13; s ^= s >> 7; s ^= s << 17; ((s % (2 * amp as u64 + 1)) as i64 - amp as i64) as i32 };
            let v: Vec<i32> = (0..n * n).map(|_| rnd() / 2).collect();
            let c: Vec<i32> = (0..(n - 1) * (n - 1)).map(|_| rnd() / 2).collect();
            let (mut p, mut h, mut r) = (vec![0; n * n], vec![0; (n - 1) * (n - 1)], vec![0; (n - 2) * (n - 2)]);
            analysis(alpha, n, &v, &c, &mut p, &mut h, &mut r);
            // The diamond's sides are never smoothed: α = 1 there.
            for k in 0..n {
                for (i, j) in [(k, 0), (k, n - 1), (0, k), (n - 1, k)] {
                    prop_assert_eq!(p[j * n + i], v[j * n + i]);
                }
            }
            if alpha == Alpha::Half {
                // 2P − Pred_V(C) differs from V by at most the two roundings: 1.5 → one unit.
                prop_assert!(r.iter().all(|&x| (-1..=1).contains(&x)));
            } else {
                prop_assert!(r.iter().all(|&x| x == 0));
            }
            let (mut v2, mut c2) = (vec![0; n * n], vec![0; (n - 1) * (n - 1)]);
            synthesis(alpha, n, &p, &h, &r, &mut v2, &mut c2);
            prop_assert_eq!(v2, v);
            prop_assert_eq!(c2, c);
        }
    }
}
