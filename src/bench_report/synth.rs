//! A deterministic fractal terrain: the benchmark's large input, the same on every machine.

use cbdam_codec::input::{Dem, SampleType};

/// SplitMix64: tiny, deterministic, good enough to place fractal noise.
struct SplitMix(u64);

impl SplitMix {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [−1, 1).
    fn signed(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }
}

/// Diamond–square terrain of `side × side` samples (`side` = 2^k + 1), roughness exponent
/// H = 0.8 (mountainous but not white noise), about 3 km of relief, stored as float32 values so
/// that float codecs see it exactly as written. Floats off any lattice exercise the codec's
/// pre-quantization path, which the bundled whole-metre DEMs do not.
pub fn fractal(side: usize, seed: u64) -> Dem {
    assert!(
        side >= 3 && (side - 1).is_power_of_two(),
        "side must be 2^k + 1"
    );
    let mut rng = SplitMix(seed);
    let mut h = vec![0f64; side * side];
    let at = |x: usize, y: usize| y * side + x;
    let mut amp = 1500.0;
    let roughness = 2f64.powf(-0.8);
    for &(x, y) in &[(0, 0), (side - 1, 0), (0, side - 1), (side - 1, side - 1)] {
        h[at(x, y)] = 1500.0 + amp * rng.signed();
    }
    let mut step = side - 1;
    while step > 1 {
        let half = step / 2;
        // Diamond step: centres of squares from their four corners.
        for y in (half..side).step_by(step) {
            for x in (half..side).step_by(step) {
                let m = (h[at(x - half, y - half)]
                    + h[at(x + half, y - half)]
                    + h[at(x - half, y + half)]
                    + h[at(x + half, y + half)])
                    / 4.0;
                h[at(x, y)] = m + amp * rng.signed();
            }
        }
        // Square step: edge midpoints from their (up to four) diamond neighbours.
        for y in (0..side).step_by(half) {
            let x0 = if (y / half).is_multiple_of(2) {
                half
            } else {
                0
            };
            for x in (x0..side).step_by(step) {
                let mut sum = 0.0;
                let mut n = 0.0;
                if x >= half {
                    sum += h[at(x - half, y)];
                    n += 1.0;
                }
                if x + half < side {
                    sum += h[at(x + half, y)];
                    n += 1.0;
                }
                if y >= half {
                    sum += h[at(x, y - half)];
                    n += 1.0;
                }
                if y + half < side {
                    sum += h[at(x, y + half)];
                    n += 1.0;
                }
                h[at(x, y)] = sum / n + amp * rng.signed();
            }
        }
        amp *= roughness;
        step = half;
    }
    Dem {
        width: side,
        height: side,
        values: h.into_iter().map(|v| f64::from(v as f32)).collect(),
        sample_type: SampleType::F32,
        nodata: None,
        georef: None,
    }
}

#[cfg(test)]
mod tests {
    use super::fractal;

    #[test]
    fn deterministic_and_rough() {
        let a = fractal(129, 7);
        assert_eq!(a.values, fractal(129, 7).values);
        assert_ne!(a.values, fractal(129, 8).values);
        let (lo, hi) = a.valid_range().unwrap();
        assert!(hi - lo > 500.0, "relief {lo}…{hi}");
        // Neighbours differ (not a constant or a plane) but far less than the relief.
        let d = (a.values[1] - a.values[0]).abs();
        assert!(d > 0.0 && d < hi - lo);
    }
}
