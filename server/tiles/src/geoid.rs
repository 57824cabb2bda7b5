//! The EGM96 geoid: its undulation N (height of the geoid above the WGS84 ellipsoid) anywhere,
//! by bilinear interpolation in a 1° grid shipped with the crate, to turn an orthometric
//! repository's heights into the ellipsoidal heights CesiumJS draws quantized-mesh tiles at
//! (`h_ellipsoid = H + N`).
//!
//! The grid (`data/egm96-60min.i16.gz`, 181 × 361 nodes, centimetres) was generated once by
//! `scripts/egm96-grid` from the `egm96` crate's spherical-harmonic synthesis (NGA's F477 to
//! degree 360, checked there against NGA's published test values); nothing is downloaded at
//! run time. [`ERROR_M`] bounds |interpolated − synthesis| as that script measured it.

use std::io::Read;
use std::sync::OnceLock;

/// Minutes between grid nodes.
const STEP_MIN: usize = 60;
/// Rows (90° N to 90° S) and columns (0° to 360° E, the last repeating the first).
const ROWS: usize = 180 * 60 / STEP_MIN + 1;
const COLS: usize = 360 * 60 / STEP_MIN + 1;

/// The grid, gzip-compressed little-endian i16 centimetres, row-major from the north-west.
static GRID_GZ: &[u8] = include_bytes!("../data/egm96-60min.i16.gz");

/// The error of [`undulation`] against EGM96's synthesis, metres, as stated in the bound of
/// converted tiles: the largest |bilinear − synthesis| `scripts/egm96-grid` measured at 20 000
/// random points (6.25 m, where the geoid bends most between nodes a degree apart; the
/// centimetre rounding of the nodes included), rounded up. A measurement, not a proof.
pub const ERROR_M: f64 = 6.5;

/// The undulations, metres.
fn grid() -> &'static [f32] {
    static GRID: OnceLock<Vec<f32>> = OnceLock::new();
    GRID.get_or_init(|| {
        let mut raw = Vec::with_capacity(ROWS * COLS * 2);
        flate2::read::GzDecoder::new(GRID_GZ)
            .read_to_end(&mut raw)
            .expect("the geoid grid compiled in is a valid gzip stream");
        assert_eq!(
            raw.len(),
            ROWS * COLS * 2,
            "the geoid grid compiled in is whole"
        );
        raw.chunks_exact(2)
            .map(|b| f32::from(i16::from_le_bytes([b[0], b[1]])) / 100.0)
            .collect()
    })
}

/// EGM96's undulation N at a geodetic point, metres (latitude clamped to ±90°, any
/// longitude); NaN for a NaN coordinate.
pub fn undulation(lat: f64, lon: f64) -> f64 {
    if !lat.is_finite() || !lon.is_finite() {
        return f64::NAN;
    }
    let step = STEP_MIN as f64 / 60.0;
    let y = (90.0 - lat.clamp(-90.0, 90.0)) / step;
    let x = lon.rem_euclid(360.0) / step;
    let (r, c) = ((y as usize).min(ROWS - 2), (x as usize).min(COLS - 2));
    let (ty, tx) = (y - r as f64, x - c as f64);
    let g = grid();
    let at = |r: usize, c: usize| f64::from(g[r * COLS + c]);
    (1.0 - ty) * ((1.0 - tx) * at(r, c) + tx * at(r, c + 1))
        + ty * ((1.0 - tx) * at(r + 1, c) + tx * at(r + 1, c + 1))
}

/// The smallest and largest undulation of the grid, metres.
pub fn range() -> (f64, f64) {
    let g = grid();
    let lo = g.iter().copied().fold(f32::INFINITY, f32::min);
    let hi = g.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    (f64::from(lo), f64::from(hi))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// NGA's published test values for EGM96 (F477's `outintpt.dat`): latitude, longitude
    /// (east, 0…360°), undulation in metres.
    const NGA_TESTS: [(f64, f64, f64); 6] = [
        (38.628_155, 269.779_155, -31.628),
        (-14.621_217, 305.021_114, -2.969),
        (46.874_319, 102.448_729, -43.575),
        (-23.617_446, 133.874_712, 15.871),
        (38.625_473, 359.999_500, 50.066),
        (-0.466_744, 0.002_300, 17.329),
    ];

    #[test]
    fn published_undulations_are_met_within_the_stated_error() {
        for (lat, lon, n) in NGA_TESTS {
            let got = undulation(lat, lon);
            assert!(
                (got - n).abs() <= ERROR_M,
                "{lat}, {lon}: {got} m, NGA {n} m"
            );
            // West longitudes are the same point.
            let west = undulation(lat, lon - 360.0);
            assert!((west - got).abs() < 1e-9);
        }
        let (lo, hi) = range();
        // EGM96's extremes: about −107 m south of India, +85 m over New Guinea.
        assert!(
            (-108.0..-104.0).contains(&lo) && (84.0..87.0).contains(&hi),
            "{lo} {hi}"
        );
        assert!(undulation(f64::NAN, 0.0).is_nan());
    }
}
