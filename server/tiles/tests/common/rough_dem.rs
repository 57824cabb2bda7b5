//! The rough test DEM that both the tiles crate's tests (`window_tiles.rs`) and the server's
//! (`server/tests/tiles.rs`, through `#[path]`) cut into tiles: a wave, a slope and hashed
//! noise, with a nodata hole, built into a repository within [`EPSILON`].

use cbdam_codec::hierarchy::{EncodeOptions, Encoder};
use cbdam_codec::quant::{HeightGrid, QuantPlan};
use cbdam_codec::repository::{GeoRef, Repository, serialize};

/// The DEM's nodata value.
pub const NODATA: f64 = -9999.0;
/// The repositories' ε, metres.
pub const EPSILON: f64 = 0.25;

/// Rough terrain with a nodata hole, `w × h` samples, row by row from the north.
pub fn rough_metres(w: usize, h: usize) -> Vec<f64> {
    (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as f64, (i / w) as f64);
            if (x - 0.7 * w as f64).hypot(y - 0.3 * h as f64) < 3.0 {
                return NODATA;
            }
            let noise = ((i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 58) as f64 / 8.0;
            300.0 + 40.0 * (x / 6.0).sin() * (y / 9.0).cos() + 0.3 * x + noise
        })
        .collect()
}

/// The repository of `metres` (`w × h`) within [`EPSILON`], georeferenced by `georef`.
pub fn repository(w: usize, h: usize, metres: &[f64], georef: &GeoRef) -> Repository {
    repository_between(w, h, metres, georef, (200.0, 400.0))
}

/// [`repository`] of heights within `lo…hi` metres.
pub fn repository_between(
    w: usize,
    h: usize,
    metres: &[f64],
    georef: &GeoRef,
    (lo, hi): (f64, f64),
) -> Repository {
    let plan = QuantPlan::new(EPSILON, None, lo, hi).unwrap();
    let grid = HeightGrid::from_metres(w, h, metres, Some(NODATA), &plan).unwrap();
    let opts = EncodeOptions {
        n: 9,
        ..EncodeOptions::default()
    };
    let enc = Encoder::new(&grid, plan.quantizer, &opts).encode().unwrap();
    let bytes = serialize(&enc, &plan, Some(georef), Some(NODATA)).unwrap();
    Repository::from_bytes(bytes).unwrap()
}
