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
    let mut scan = QuantumScan::new(dem.sample_type);
    for i in 0..dem.values.len() {
        if dem.is_valid(i) {
            scan.push(dem.values[i]);
        }
    }
    scan.finish()
}

/// [`detect_quantum`] one valid sample at a time, for inputs streamed in blocks; scans of
/// consecutive parts combine with [`QuantumScan::merge`].
#[derive(Clone, Debug)]
pub struct QuantumScan {
    sample_type: SampleType,
    /// The first valid sample, and whether every later one equals it (integer types).
    first: Option<f64>,
    constant: bool,
    /// Gcd of the magnitudes so far (integer types).
    gcd: u64,
    /// Which float candidates every sample so far fits.
    alive: [bool; CANDIDATES.len()],
}

impl QuantumScan {
    /// An empty scan of samples stored as `sample_type`.
    pub fn new(sample_type: SampleType) -> Self {
        Self {
            sample_type,
            first: None,
            constant: true,
            gcd: 0,
            alive: [true; CANDIDATES.len()],
        }
    }

    /// Adds one valid sample.
    #[inline]
    pub fn push(&mut self, v: f64) {
        let first = *self.first.get_or_insert(v);
        if self.sample_type.is_integer() {
            self.constant &= v == first;
            if self.gcd != 1 {
                // Integer sample types hold at most 32 bits, so the cast is exact.
                self.gcd = gcd(self.gcd, v.abs() as u64);
            }
        } else {
            // A whole number of modest size is exactly n / k for every candidate k (v·k is an
            // exact integer, and dividing it by k gives v back), so it keeps every candidate
            // alive: skip the seven roundings for the whole-metre floats most DEMs hold.
            let i = v as i64;
            if i as f64 == v && i.unsigned_abs() < 1 << 40 {
                return;
            }
            for (alive, &(_, k)) in self.alive.iter_mut().zip(&CANDIDATES) {
                *alive = *alive && fits(v, k, self.sample_type);
            }
        }
    }

    /// The scan of `self`'s samples followed by `later`'s.
    pub fn merge(mut self, later: Self) -> Self {
        if let Some(f) = later.first {
            match self.first {
                None => return later,
                Some(first) => self.constant &= later.constant && f == first,
            }
        }
        self.gcd = gcd(self.gcd, later.gcd);
        for (a, b) in self.alive.iter_mut().zip(later.alive) {
            *a &= b;
        }
        self
    }

    /// The quantum, as [`detect_quantum`] defines it.
    pub fn finish(&self) -> Option<f64> {
        self.first?;
        if self.sample_type.is_integer() {
            return Some(if self.constant || self.gcd == 0 {
                1.0
            } else {
                self.gcd as f64
            });
        }
        CANDIDATES
            .iter()
            .zip(self.alive)
            .find(|(_, alive)| *alive)
            .map(|(&(u, _), _)| u)
    }
}

fn gcd(mut a: u64, mut b: u64) -> u64 {
    while b != 0 {
        (a, b) = (b, a % b);
    }
    a
}

/// Whether `v` is the nearest value of `ty` to some `n / k`.
#[inline]
fn fits(v: f64, k: f64, ty: SampleType) -> bool {
    let n = (v * k).round();
    if n.is_nan() || n.abs() >= MAX_STEPS {
        return false;
    }
    let q = n / k;
    if ty == SampleType::F32 {
        q as f32 == v as f32
    } else {
        q == v
    }
}
