//! The L∞ guarantee, checked exactly (in integer units) on every level, on adversarial fields.

use crate::util::Rng;
use cbdam_codec::entropy::CoderKind;
use cbdam_codec::hierarchy::{EncodeOptions, Encoder, verify};
use cbdam_codec::lifting::Alpha;
use cbdam_codec::quant::{HeightGrid, QuantPlan};
use proptest::prelude::*;

#[derive(Clone, Copy, Debug)]
enum Field {
    Random,
    Fractal,
    Cliffs,
    Spikes,
    Constant,
    Checkerboard,
}

/// Heights in metres.
fn make(field: Field, w: usize, h: usize, seed: u64) -> Vec<f64> {
    let mut rng = Rng(seed | 1);
    match field {
        Field::Random => (0..w * h).map(|_| rng.unit() * 4000.0 - 500.0).collect(),
        Field::Fractal => {
            // Sum of octaves of random sinusoids: spectrum like real terrain, 1/f amplitude.
            let waves: Vec<(f64, f64, f64, f64)> = (0..24)
                .map(|o| {
                    let f = 0.01 * 1.35f64.powi(o);
                    let a = 1500.0 / (1.0 + f * 60.0);
                    (
                        f,
                        rng.unit() * std::f64::consts::TAU,
                        a,
                        rng.unit() * std::f64::consts::TAU,
                    )
                })
                .collect();
            (0..w * h)
                .map(|k| {
                    let (x, y) = ((k % w) as f64, (k / w) as f64);
                    waves
                        .iter()
                        .map(|&(f, ph, a, ang)| {
                            a * (f * (x * ang.cos() + y * ang.sin()) + ph).sin()
                        })
                        .sum::<f64>()
                        + 1000.0
                })
                .collect()
        }
        Field::Cliffs => (0..w * h)
            .map(|k| {
                let (x, y) = (k % w, k / w);
                let step = if (x + y / 3) % 17 < 8 { 2500.0 } else { -300.0 };
                step + (x as f64 * 0.7).round()
            })
            .collect(),
        Field::Spikes => {
            let mut v = vec![200.0; w * h];
            for _ in 0..(w * h / 40).max(2) {
                let k = rng.next() as usize % (w * h);
                v[k] = if rng.next().is_multiple_of(2) {
                    10_000.0
                } else {
                    -10_000.0
                };
            }
            v
        }
        Field::Constant => vec![-42.0; w * h],
        Field::Checkerboard => (0..w * h)
            .map(|k| {
                if (k % w + k / w).is_multiple_of(2) {
                    900.0
                } else {
                    -900.0
                }
            })
            .collect(),
    }
}

fn check(
    field: Field,
    w: usize,
    h: usize,
    seed: u64,
    eps: f64,
    quantum: Option<f64>,
    opts: EncodeOptions,
) {
    let metres = make(field, w, h, seed);
    let metres: Vec<f64> = match quantum {
        Some(u) => metres.iter().map(|v| (v / u).round() * u).collect(),
        None => metres,
    };
    let (lo, hi) = metres
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), &v| (a.min(v), b.max(v)));
    let plan = match QuantPlan::new(eps, quantum, lo, hi) {
        Ok(plan) => plan,
        Err(e) => {
            // Only a tolerance too fine for the relief may be refused, and it must say so.
            assert!(e.to_string().contains("too fine"), "{e}");
            assert!((hi - lo) / eps > 1e6, "refused ε={eps} for range {lo}…{hi}");
            return;
        }
    };
    let grid = HeightGrid::from_metres(w, h, &metres, None, &plan).unwrap();
    let enc = Encoder::new(&grid, plan.quantizer, &opts).encode().unwrap();
    let report = verify(&enc, &grid).unwrap();
    assert!(
        report.within_bound(),
        "{field:?} {w}x{h} ε={eps} {opts:?}: max error {} > bound {} units; per level {:?}",
        report.max_error(),
        report.bound,
        report.levels
    );
    // The bound in metres, including pre-quantization for float input, is within ε in exact
    // arithmetic; the stated one adds at most the float rounding term. It covers every level.
    assert!(plan.quantization_error() <= eps * (1.0 + 1e-9));
    assert!(plan.max_error() <= (eps * (1.0 + 1e-9) + plan.rounding_error()).next_up());
    assert_eq!(
        report.levels.len(),
        enc.params.layout().finest_level() as usize + 1
    );
    // Every valid sample is a vertex of some finest diamond, so the finest level checked all.
    assert!(
        report.levels.last().unwrap().vertices as usize
            >= grid.valid.iter().filter(|&&v| v).count()
    );
    assert!(
        enc.leaf_error <= report.bound,
        "leaf object error {} > {}",
        enc.leaf_error,
        report.bound
    );
}

fn both_coders_and_alphas(n: usize) -> Vec<EncodeOptions> {
    let mut v = Vec::new();
    for coder in CoderKind::ALL {
        for alpha in [Alpha::One, Alpha::Half] {
            v.push(EncodeOptions {
                n,
                alpha,
                coder,
                extra_level_pairs: 0,
            });
        }
    }
    v
}

#[test]
fn twelve_levels_deep_on_every_adversarial_field() {
    // N = 3 on 129×129 gives K = 6: levels 0…12.
    for field in [
        Field::Fractal,
        Field::Cliffs,
        Field::Spikes,
        Field::Constant,
        Field::Checkerboard,
        Field::Random,
    ] {
        for opts in both_coders_and_alphas(3) {
            check(field, 129, 129, 7, 0.5, Some(1.0), opts);
            check(field, 129, 129, 7, 0.0025, None, opts);
        }
    }
}

#[test]
fn planet_relief_at_the_smallest_accepted_tolerance_does_not_overflow() {
    // Heights spanning −11 000 … +9 000 m (trench to summit) with cliffs between them.
    let (w, h) = (97, 61);
    let metres: Vec<f64> = make(Field::Fractal, w, h, 11)
        .iter()
        .enumerate()
        .map(|(k, v)| {
            if (k % w) < w / 2 {
                -11_000.0 + v.abs() % 500.0
            } else {
                9_000.0 - v.abs() % 500.0
            }
        })
        .collect();
    // The smallest ε the plan accepts, to 1 %: refused just below it, accepted at it.
    let (mut lo, mut hi) = (1e-5f64, 1.0f64);
    while hi / lo > 1.01 {
        let mid = (lo * hi).sqrt();
        if QuantPlan::new(mid, None, -11_000.0, 9_000.0).is_ok() {
            hi = mid
        } else {
            lo = mid
        }
    }
    assert!(
        hi < 0.0026,
        "the format should hold planet relief at 2.5 mm, smallest is {hi}"
    );
    let err = QuantPlan::new(lo, None, -11_000.0, 9_000.0).unwrap_err();
    assert!(err.to_string().contains("smallest tolerance"), "{err}");
    let plan = QuantPlan::new(hi, None, -11_000.0, 9_000.0).unwrap();
    let grid = HeightGrid::from_metres(w, h, &metres, None, &plan).unwrap();
    for opts in both_coders_and_alphas(5) {
        let enc = Encoder::new(&grid, plan.quantizer, &opts).encode().unwrap();
        let report = verify(&enc, &grid).unwrap();
        assert!(report.within_bound(), "{opts:?}: {report:?}");
    }
}

#[test]
fn lossless_when_the_tolerance_is_below_the_quantum() {
    for opts in both_coders_and_alphas(9) {
        let metres = make(Field::Fractal, 70, 50, 3);
        let metres: Vec<f64> = metres.iter().map(|v| v.round()).collect();
        let plan = QuantPlan::new(0.4, Some(1.0), -3000.0, 5000.0).unwrap();
        let grid = HeightGrid::from_metres(70, 50, &metres, None, &plan).unwrap();
        let enc = Encoder::new(&grid, plan.quantizer, &opts).encode().unwrap();
        let report = verify(&enc, &grid).unwrap();
        assert_eq!((report.bound, report.max_error()), (0, 0), "{opts:?}");
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]
    #[test]
    fn bound_holds_on_random_inputs(
        w in 1usize..90,
        h in 1usize..90,
        n_pow in 1u32..6,
        field in prop_oneof![Just(Field::Random), Just(Field::Fractal), Just(Field::Cliffs), Just(Field::Spikes), Just(Field::Constant), Just(Field::Checkerboard)],
        eps in prop_oneof![Just(0.001), Just(0.01), Just(0.1), Just(0.5), Just(1.0), Just(5.0), Just(10.0), Just(100.0)],
        lattice in any::<bool>(),
        half in any::<bool>(),
        coder in proptest::sample::select(CoderKind::ALL.to_vec()),
        seed in any::<u64>(),
        extra_level_pairs in 0u32..3,
    ) {
        let opts = EncodeOptions {
            n: (1 << n_pow) + 1,
            alpha: if half { Alpha::Half } else { Alpha::One },
            coder,
            extra_level_pairs,
        };
        check(field, w, h, seed, eps, lattice.then_some(1.0), opts);
    }
}
