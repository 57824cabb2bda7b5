//! The value quantum of a DEM: the spacing of the lattice its heights were rounded to.
//!
//! Most DEMs store whole metres or decimetres even when the file type is float; knowing that
//! lets the encoder treat a tolerance below the quantum as lossless instead of spending bits on
//! the float noise between lattice points.

use super::{Dem, SampleType};

/// Candidate quanta for float data, largest first, as `(u, k)` with `u = 1 / k` exactly in
/// decimal; dividing by the integer `k` rounds once, where multiplying by the double nearest to
/// `u` would not (3 * 0.1 != 0.3).
const CANDIDATES: [(f64, f64); 7] = [
    (1.0, 1.0),
    (0.5, 2.0),
    (0.25, 4.0),
    (0.2, 5.0),
    (0.1, 10.0),
    (0.05, 20.0),
    (0.01, 100.0),
];

/// Above this, `n` is no longer an exact integer in `f64` and the test below means nothing.
const MAX_STEPS: f64 = 9_007_199_254_740_992.0; // 2^53

/// The quantum `u` such that every valid sample is a multiple of `u`, if there is one.
///
/// Integer samples give the gcd of their magnitudes, at least 1; a constant field gives 1 (its
/// only value says nothing about a lattice). Float samples try 1, 0.5, 0.25, 0.2, 0.1, 0.05 and
/// 0.01 in that order and return the first `u` for which every valid sample `v` is the value of
/// its own type nearest to `round(v / u) * u`. `None` when no candidate fits (lidar, resampled
/// data) or when no sample is valid.
pub fn detect_quantum(dem: &Dem) -> Option<f64> {
    let mut valid = (0..dem.values.len())
        .filter(|&i| dem.is_valid(i))
        .map(|i| dem.values[i]);
    let first = valid.next()?;
    let valid = std::iter::once(first).chain(valid);
    if dem.sample_type.is_integer() {
        return Some(integer_quantum(first, valid));
    }
    CANDIDATES
        .iter()
        .find(|&&(_, k)| {
            let valid = (0..dem.values.len())
                .filter(|&i| dem.is_valid(i))
                .map(|i| dem.values[i]);
            fits(valid, k, dem.sample_type)
        })
        .map(|&(u, _)| u)
}

fn integer_quantum(first: f64, valid: impl Iterator<Item = f64>) -> f64 {
    let mut g = 0u64;
    let mut constant = true;
    for v in valid {
        constant &= v == first;
        // Integer sample types hold at most 32 bits, so the cast is exact.
        g = gcd(g, v.abs() as u64);
        if g == 1 {
            return 1.0;
        }
    }
    if constant || g == 0 { 1.0 } else { g as f64 }
}

fn gcd(mut a: u64, mut b: u64) -> u64 {
    while b != 0 {
        (a, b) = (b, a % b);
    }
    a
}

/// Whether every value is the nearest value of `ty` to some `n / k`; stops at the first miss.
fn fits(mut values: impl Iterator<Item = f64>, k: f64, ty: SampleType) -> bool {
    let single = ty == SampleType::F32;
    values.all(|v| {
        let n = (v * k).round();
        if n.is_nan() || n.abs() >= MAX_STEPS {
            return false;
        }
        let q = n / k;
        if single { q as f32 == v as f32 } else { q == v }
    })
}
