//! Tests of the entropy references: the entropies against hand-computed figures, the coder's
//! context against the class table worked by hand, and the MED residuals by decoding them back.

use super::*;

#[test]
fn entropies_of_known_distributions() {
    let mut s = SymbolStats::default();
    // Four equiprobable symbols, each fixed by its context.
    for (ctx, sym) in [(0, 1), (1, -1), (2, 2), (3, -2)] {
        s.add(ctx, sym);
    }
    assert_eq!(s.count(), 4);
    assert_eq!(s.contexts(), 4);
    assert!((s.zero_order_bits() - 8.0).abs() < 1e-12);
    assert!(s.conditional_bits().abs() < 1e-12);
    // Magnitudes known from the context, signs raw: one bit each.
    assert!((s.conditional_bits_raw_sign() - 4.0).abs() < 1e-12);

    // One context, symbols 0 ×2, 1, −1: H = 1.5 bits each; magnitudes {0, 0, 1, 1} 1 bit each
    // plus two raw signs.
    let mut t = SymbolStats::default();
    for sym in [0, 0, 1, -1] {
        t.add(7, sym);
    }
    assert!((t.zero_order_bits() - 6.0).abs() < 1e-12);
    assert!((t.conditional_bits() - 6.0).abs() < 1e-12);
    assert!((t.conditional_bits_raw_sign() - 6.0).abs() < 1e-12);

    let mut both = s.clone();
    both.merge(&t);
    let mut direct = SymbolStats::default();
    for (ctx, sym) in [
        (0, 1),
        (1, -1),
        (2, 2),
        (3, -2),
        (7, 0),
        (7, 0),
        (7, 1),
        (7, -1),
    ] {
        direct.add(ctx, sym);
    }
    assert_eq!(both.count(), direct.count());
    assert!((both.zero_order_bits() - direct.zero_order_bits()).abs() < 1e-9);
    assert!((both.conditional_bits() - direct.conditional_bits()).abs() < 1e-9);
}

#[test]
fn the_coder_context_is_the_class_of_the_weighted_neighbourhood() {
    let (w, h) = (6, 6);
    let mut band = vec![0i32; w * h];
    // Around (3, 3): left 1, top −2, top-left 3, top-right −4: sum 2·(1 + 2) + 3 + 4 = 13, the
    // top of class 6 (bounds 0, 1, 2, 4, 6, 9, 13, …), away from the border.
    band[3 * w + 2] = 1;
    band[2 * w + 3] = -2;
    band[2 * w + 2] = 3;
    band[2 * w + 4] = -4;
    band[3 * w + 3] = 9;
    let mut seen = Vec::new();
    coder_contexts(&band, w, h, |ctx, v| seen.push((ctx, v)));
    assert_eq!(seen.len(), w * h);
    assert_eq!(seen[3 * w + 3], (12, 9));
    // The corner has no neighbours and is on the border: class 0, border 1.
    assert_eq!(seen[0], (1, 0));
    // (4, 3): left 9, top −4, top-left −2: 2·(9 + 4) + 2 = 28, class 9, on the right border.
    assert_eq!(seen[3 * w + 4], (19, 0));
}

#[test]
fn jpeg_ls_default_thresholds() {
    // T.87's defaults: 8-bit 3/7/21, 12-bit 18/67/276, and NEAR widening them.
    let q8 = GradientQuantizer::new(255, 0);
    assert_eq!((q8.t1, q8.t2, q8.t3), (3, 7, 21));
    let q12 = GradientQuantizer::new(4095, 0);
    assert_eq!((q12.t1, q12.t2, q12.t3), (18, 67, 276));
    let q8n = GradientQuantizer::new(255, 1);
    assert_eq!((q8n.t1, q8n.t2, q8n.t3), (6, 12, 28));
    assert_eq!(
        [-21, -7, -3, -1, 0, 1, 2, 3, 6, 7, 20, 21].map(|d| q8.quantize(d)),
        [-4, -3, -2, -1, 0, 1, 1, 2, 2, 3, 3, 4]
    );
}

/// Decodes [`med_residuals`]' indices back, independently: the prediction and context from the
/// reconstructed neighbours, then the index times the step with the context's sign.
fn decode_med(samples: &[MedSample], w: usize, h: usize, near: i32, max_value: i64) -> Vec<i64> {
    let quantizer = GradientQuantizer::new(max_value, near.into());
    let step = 2 * i64::from(near) + 1;
    let mut out = vec![0i64; w * h];
    for y in 0..h {
        for x in 0..w {
            let at = |x: usize, y: usize| out[y * w + x];
            let b = if y > 0 { at(x, y - 1) } else { 0 };
            let a = if x > 0 { at(x - 1, y) } else { b };
            let c = if x > 0 && y > 0 { at(x - 1, y - 1) } else { b };
            let d = if x + 1 < w && y > 0 {
                at(x + 1, y - 1)
            } else {
                b
            };
            let q = [d - b, b - c, c - a].map(|g| quantizer.quantize(g));
            let context = 81 * q[0] + 9 * q[1] + q[2];
            let sample = samples[y * w + x];
            assert_eq!(i64::from(sample.context), context.abs());
            let sign = if context < 0 { -1 } else { 1 };
            out[y * w + x] = med(a, b, c) + sign * i64::from(sample.index) * step;
        }
    }
    out
}

fn rough_lattice(w: usize, h: usize) -> Vec<i32> {
    (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as i64, (i / w) as i64);
            (300 + 7 * x - 5 * y + (x * y * 37 + x * x * 11) % 23 - 2 * ((x + y) % 3)) as i32
        })
        .collect()
}

#[test]
fn med_residuals_decode_back_within_near() {
    let (w, h) = (17, 13);
    let lattice = rough_lattice(w, h);
    let (lo, hi) = (
        *lattice.iter().min().unwrap() as i64,
        *lattice.iter().max().unwrap() as i64,
    );
    for near in [0, 1, 3] {
        let mut samples = Vec::new();
        med_residuals(&lattice, None, w, h, near, |s| samples.push(s));
        assert_eq!(samples.len(), w * h);
        let back = decode_med(&samples, w, h, near, hi - lo);
        let worst = back
            .iter()
            .zip(&lattice)
            .map(|(&r, &v)| (r - i64::from(v)).abs())
            .max()
            .unwrap();
        assert!(worst <= i64::from(near), "near {near}: error {worst}");
        if near == 0 {
            assert_eq!(
                back,
                lattice.iter().map(|&v| i64::from(v)).collect::<Vec<_>>()
            );
        }
        assert!(samples.iter().all(|s| s.context < 365));
    }
}

#[test]
fn a_constant_lattice_costs_one_index() {
    let lattice = vec![7i32; 9 * 5];
    let mut samples = Vec::new();
    med_residuals(&lattice, None, 9, 5, 0, |s| samples.push(s));
    let non_zero: Vec<_> = samples.iter().filter(|s| s.index != 0).collect();
    assert_eq!(non_zero.len(), 1, "{samples:?}");
    assert_eq!(non_zero[0].index, 7);
}

#[test]
fn cell_predictors_on_a_hand_worked_cell() {
    // One cell (n = 2): corners TL 10, TR 20, BL 14, BR 11; the codec predicted 13 and the
    // cell is 16. Bilinear ⌊(55 + 2) / 4⌋ = 14; diagonals TL–BR 10.5 → 10 (|Δ| 1, flatter),
    // TR–BL 17; median(13, 10, 17) = 13.
    let p = [10, 20, 14, 11];
    let mut out = Vec::new();
    let expect = [
        (CellPredictor::Codec, 3),
        (CellPredictor::Bilinear, 2),
        (CellPredictor::FlatterDiagonal, 6),
        (CellPredictor::Median, 3),
    ];
    for (predictor, residual) in expect {
        cell_indices(predictor, &p, 2, &[13], &[16], 1, &mut out);
        assert_eq!(out, [residual], "{}", predictor.name());
    }
    // Step 3 (k = 1): residual 6 → 2, 2 → 1 (rounded to nearest), −2 → −1.
    cell_indices(
        CellPredictor::FlatterDiagonal,
        &p,
        2,
        &[13],
        &[16],
        3,
        &mut out,
    );
    assert_eq!(out, [2]);
    cell_indices(CellPredictor::Bilinear, &p, 2, &[13], &[16], 3, &mut out);
    assert_eq!(out, [1]);
    cell_indices(CellPredictor::Codec, &p, 2, &[13], &[11], 3, &mut out);
    assert_eq!(out, [-1]);
    // Spread |10 − 11| + |20 − 14| = 7: ⌊log2 8⌋ = 3; in steps of 3: ⌊7 / 3⌋ = 2, ⌊log2 3⌋ = 1.
    assert_eq!(corner_activity(&p, 2, 0, 0, 1), 3);
    assert_eq!(corner_activity(&p, 2, 0, 0, 3), 1);
}
