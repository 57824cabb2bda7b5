//! Heights at the edges of what the quantizer takes (docs/FORMAT.md, "Quantizer range"): every
//! case either builds and meets its bound exactly — every level in integer units, every valid
//! sample in metres — or is refused with an error that names the problem. Nothing overflows
//! silently and nothing panics.

use crate::util::Rng;
use cbdam_codec::hierarchy::{EncodeOptions, Encoder, reconstruct_finest, verify};
use cbdam_codec::quant::{HeightGrid, QuantPlan};
use cbdam_codec::samples::{Dem, SampleType};

/// A grid side with several levels of small diamonds.
const SIDE: usize = 97;

fn dem(values: Vec<f64>) -> Dem {
    assert_eq!(values.len(), SIDE * SIDE);
    Dem {
        width: SIDE,
        height: SIDE,
        values,
        sample_type: SampleType::F64,
        nodata: None,
        georef: None,
    }
}

/// What one case came to.
#[derive(Debug, PartialEq)]
enum Outcome {
    /// Built; the largest sample error in metres.
    Built(f64),
    /// Refused with this message.
    Refused(String),
}

/// Plans, quantizes, encodes and decodes `dem` at `eps` (with `quantum` when given), checking
/// the bound on every level in units and on every valid sample in metres.
fn run(what: &str, dem: &Dem, eps: f64, quantum: Option<f64>) -> Outcome {
    let what = format!("{what} at ε = {eps} m");
    let plan = match QuantPlan::for_dem(dem, eps, quantum) {
        Ok(p) => p,
        Err(e) => return Outcome::Refused(e.to_string()),
    };
    let grid = match HeightGrid::from_dem(dem, &plan) {
        Ok(g) => g,
        Err(e) => return Outcome::Refused(e.to_string()),
    };
    let opts = EncodeOptions {
        n: 9,
        ..EncodeOptions::default()
    };
    let enc = Encoder::new(&grid, plan.quantizer, &opts)
        .encode()
        .unwrap_or_else(|e| panic!("{what}: planned and quantized, then the encode failed: {e}"));
    let report = verify(&enc, &grid).unwrap();
    assert!(
        report.within_bound(),
        "{what}: {} units on some level, bound {}",
        report.max_error(),
        report.bound
    );
    let finest = reconstruct_finest(&enc).unwrap();
    let mut worst = 0f64;
    for (i, (&n, &v)) in finest.iter().zip(&dem.values).enumerate() {
        if v.is_nan() {
            continue;
        }
        let e = (plan.metres(n) - v).abs();
        // The stated bound holds as computed: the quantization's, at most ε, plus the f64
        // rounding of `offset + n·u` that the plan states with it.
        assert!(
            e <= plan.max_error() && plan.quantization_error() <= eps * (1.0 + 1e-9),
            "{what}: sample {i} ({v} m) decoded {} m, off by {e} m, guaranteed {} m",
            plan.metres(n),
            plan.max_error()
        );
        worst = worst.max(e);
    }
    Outcome::Built(worst)
}

/// The tolerances every case runs at: from the smallest positive to far beyond the relief.
const EPSILONS: [f64; 9] = [1e-9, 1e-4, 1e-3, 0.1, 0.5, 1.0, 16.0, 100.0, 1000.0];

fn random_field(seed: u64, f: impl Fn(&mut Rng, usize, usize) -> f64) -> Vec<f64> {
    let mut rng = Rng(seed);
    (0..SIDE * SIDE)
        .map(|i| f(&mut rng, i % SIDE, i / SIDE))
        .collect()
}

/// Builds or a clear refusal at every tolerance; returns how many built.
fn every_tolerance(what: &str, dem: &Dem, quantum: Option<f64>, refusal_words: &[&str]) -> usize {
    let mut built = 0;
    for eps in EPSILONS {
        match run(what, dem, eps, quantum) {
            Outcome::Built(_) => built += 1,
            Outcome::Refused(msg) => assert!(
                refusal_words.iter().any(|w| msg.contains(w)),
                "{what} at ε = {eps}: refused with an unexpected message: {msg}"
            ),
        }
    }
    built
}

#[test]
fn twelve_kilometres_either_way_at_a_millimetre_quantum() {
    // Multiples of 1 mm across ±12 000 m: 24 million units, within the ±40 million the
    // quantizer takes; ε up to 1000 m is k = 10⁶, within its largest half-step.
    let values = random_field(1, |r, _, _| {
        (r.below(24_000_001) as f64 - 12_000_000.0) / 1000.0
    });
    let d = dem(values);
    let built = every_tolerance(
        "±12 000 m on 1 mm",
        &d,
        Some(0.001),
        &["tolerance", "below"],
    );
    assert!(built >= 6, "only {built} tolerances built");
    // Below the quantum the plan is lossless: every sample comes back exactly.
    // Exactly up to the f64 rounding of `n / 1000` and `offset + n·u`: an ulp at 12 000 m.
    match run("±12 000 m on 1 mm", &d, 0.0005, Some(0.001)) {
        Outcome::Built(worst) => assert!(worst < 1e-11, "lossless, yet off by {worst} m"),
        other => panic!("lossless 1 mm refused: {other:?}"),
    }
}

#[test]
fn a_million_metres_builds_coarse_and_refuses_fine_tolerances_by_name() {
    let values = random_field(2, |r, _, _| 1e6 * (2.0 * r.unit() - 1.0));
    let d = dem(values);
    let built = every_tolerance("±1e6 m float", &d, None, &["too fine", "overflow"]);
    assert!(built >= 3, "only {built} tolerances built");
    match run("±1e6 m float", &d, 1e-3, None) {
        Outcome::Refused(msg) => assert!(msg.contains("too fine"), "{msg}"),
        other => panic!("1 mm on ±1e6 m needs 2·10⁹ units, yet: {other:?}"),
    }
}

#[test]
fn one_nan_is_nodata_and_one_infinity_is_refused_by_name() {
    let base = random_field(3, |r, x, y| {
        300.0 + (x as f64 * 0.3).sin() * 50.0 + y as f64 + r.unit()
    });
    let mut with_nan = base.clone();
    with_nan[SIDE * 40 + 17] = f64::NAN;
    every_tolerance("one NaN", &dem(with_nan), None, &["tolerance"]);
    for inf in [f64::INFINITY, f64::NEG_INFINITY] {
        let mut v = base.clone();
        v[SIDE * 5 + 90] = inf;
        for eps in EPSILONS {
            match run("one infinity", &dem(v.clone()), eps, None) {
                Outcome::Refused(msg) => assert!(msg.contains("infinite"), "{inf}: {msg}"),
                other => panic!("{inf} at ε = {eps} built: {other:?}"),
            }
        }
    }
}

#[test]
fn denormal_and_constant_grids_meet_every_tolerance() {
    let tiny = f64::MIN_POSITIVE / 1024.0;
    let denormals = random_field(4, |r, _, _| tiny * r.below(1000) as f64);
    every_tolerance("denormals", &dem(denormals), None, &["tolerance"]);
    for c in [0.0, -10_911.0, 8_848.86, 1234.5] {
        let built = every_tolerance("constant", &dem(vec![c; SIDE * SIDE]), None, &["tolerance"]);
        assert_eq!(built, EPSILONS.len(), "constant {c}");
    }
}

#[test]
fn checkerboards_of_eight_kilometres_meet_every_tolerance() {
    let board = random_field(5, |_, x, y| if (x + y) % 2 == 0 { 8000.0 } else { -8000.0 });
    let built = every_tolerance(
        "±8000 m checkerboard",
        &dem(board.clone()),
        None,
        &["too fine"],
    );
    assert!(built >= 6, "only {built} tolerances built");
    // Whole metres: the lattice plan, lossless below 1 m.
    let built = every_tolerance("±8000 m on 1 m", &dem(board), Some(1.0), &["too fine"]);
    assert!(built >= 6, "only {built} tolerances built");
}

#[test]
fn single_sample_spikes_on_every_level_meet_every_tolerance() {
    // A spike of ±5000 m on a gentle slope at one lattice point of each level's spacing
    // (2^j samples apart, j = 0 … 6), where each level first predicts it.
    let mut v = random_field(6, |_, x, y| x as f64 * 0.5 - y as f64 * 0.25);
    for j in 0..7 {
        let s = 1usize << j;
        let (x, y) = ((3 * s) % SIDE, (5 * s) % SIDE);
        v[y * SIDE + x] += if j % 2 == 0 { 5000.0 } else { -5000.0 };
        // And an odd point next to it: a cell centre of the finest level.
        v[((y + 1) % SIDE) * SIDE + (x + 1) % SIDE] -= 2500.0;
    }
    let built = every_tolerance("spikes", &dem(v), None, &["too fine"]);
    assert!(built >= 6, "only {built} tolerances built");
}

#[test]
fn a_zero_or_negative_tolerance_is_refused_by_name() {
    let d = dem(vec![1.0; SIDE * SIDE]);
    for eps in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        match run("bad ε", &d, eps, None) {
            Outcome::Refused(msg) => assert!(msg.contains("positive"), "{eps}: {msg}"),
            other => panic!("ε = {eps} built: {other:?}"),
        }
    }
}
