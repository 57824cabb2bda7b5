//! Generates the EGM96 geoid grid that cbdam's quantized-mesh tiles use to turn orthometric
//! heights into heights above the WGS84 ellipsoid (docs/WEB-MAPS.md, "Datum"), and measures
//! what bilinear interpolation in it costs.
//!
//! Source: the `egm96` crate 0.3.2 (zlib licence), a port of NGA's F477 program that sums the
//! EGM96 spherical harmonics to degree and order 360 with the height-anomaly-to-undulation
//! correction, against WGS84. It is checked here against NGA's published test values (F477's
//! `outintpt.dat`) before anything is written.
//!
//! Output (`OUT`, default `grid.i16`): a grid of `STEP_MIN`-minute nodes (1°: the synthesis
//! takes about a millisecond a point, and a 15′ grid's million nodes were too slow to make
//! on the machine at hand), rows from 90° N to
//! 90° S, columns from 0° E eastwards to 360° (the last column repeats the first), each the
//! undulation N in centimetres as little-endian i16. Then the largest |bilinear − synthesis| at
//! `SAMPLES` random points (plus the centimetre rounding) is printed: the interpolation error
//! the tiles add to their bound.
//!
//! Run: `cargo run --release -- OUT [MINUTES]`; then `gzip -9n OUT` and copy to
//! server/tiles/data/egm96-60min.i16.gz.

use std::io::Write;
use std::sync::atomic::{AtomicUsize, Ordering};

/// Minutes between nodes, unless the second argument says otherwise.
const STEP_MIN: usize = 60;
/// Random points at which the interpolation is measured.
const SAMPLES: usize = 20_000;

/// NGA's test points for F477: latitude, longitude (0…360° E), undulation in metres.
const NGA_TESTS: [(f64, f64, f64); 6] = [
    (38.628_155, 269.779_155, -31.628),
    (-14.621_217, 305.021_114, -2.969),
    (46.874_319, 102.448_729, -43.575),
    (-23.617_446, 133.874_712, 15.871),
    (38.625_473, 359.999_500, 50.066),
    (-0.466_744, 0.002_300, 17.329),
];

fn synthesis(lat: f64, lon: f64, scratch: &mut egm96::Egm96Scratch) -> f64 {
    egm96::egm96_compute_altitude_offset_with_scratch(lat, lon, scratch)
}

fn main() {
    let out = std::env::args().nth(1).unwrap_or_else(|| "grid.i16".into());
    let step_min: usize = std::env::args()
        .nth(2)
        .map_or(STEP_MIN, |s| s.parse().expect("minutes between nodes"));
    let mut scratch = egm96::Egm96Scratch::new();
    for (lat, lon, n) in NGA_TESTS {
        let got = synthesis(lat, lon, &mut scratch);
        println!("NGA test {lat} {lon}: {got:.3} m, published {n} m");
        assert!((got - n).abs() < 0.01, "the synthesis misses NGA's test value by 1 cm or more");
    }
    let rows = 180 * 60 / step_min + 1;
    let cols = 360 * 60 / step_min + 1;
    let step = step_min as f64 / 60.0;
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let next = AtomicUsize::new(0);
    let mut grid = vec![0i16; rows * cols];
    let started = std::time::Instant::now();
    std::thread::scope(|s| {
        let chunks: Vec<_> = (0..threads)
            .map(|_| {
                s.spawn(|| {
                    let mut scratch = egm96::Egm96Scratch::new();
                    let mut done = Vec::new();
                    loop {
                        let r = next.fetch_add(1, Ordering::Relaxed);
                        if r >= rows {
                            return done;
                        }
                        let lat = 90.0 - r as f64 * step;
                        let row: Vec<i16> = (0..cols)
                            .map(|c| {
                                let n = synthesis(lat, c as f64 * step, &mut scratch);
                                (n * 100.0).round() as i16
                            })
                            .collect();
                        done.push((r, row));
                    }
                })
            })
            .collect();
        for h in chunks {
            for (r, row) in h.join().unwrap() {
                grid[r * cols..(r + 1) * cols].copy_from_slice(&row);
            }
        }
    });
    println!(
        "{rows} × {cols} nodes in {:.1} s",
        started.elapsed().as_secs_f64()
    );
    let bytes: Vec<u8> = grid.iter().flat_map(|v| v.to_le_bytes()).collect();
    std::fs::File::create(&out).unwrap().write_all(&bytes).unwrap();
    // Interpolation error at pseudo-random points (a fixed sequence: reproducible).
    let at = |r: usize, c: usize| f64::from(grid[r * cols + c]) / 100.0;
    let mut worst = 0.0f64;
    let mut state = 0x9E37_79B9_7F4A_7C15u64;
    let mut uniform = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    for _ in 0..SAMPLES {
        let lat = (2.0 * uniform() - 1.0).asin().to_degrees();
        let lon = 360.0 * uniform();
        let (y, x) = ((90.0 - lat) / step, lon / step);
        let (r, c) = ((y as usize).min(rows - 2), (x as usize).min(cols - 2));
        let (ty, tx) = (y - r as f64, x - c as f64);
        let bilinear = (1.0 - ty) * ((1.0 - tx) * at(r, c) + tx * at(r, c + 1))
            + ty * ((1.0 - tx) * at(r + 1, c) + tx * at(r + 1, c + 1));
        worst = worst.max((bilinear - synthesis(lat, lon, &mut scratch)).abs());
    }
    println!("largest |bilinear − synthesis| at {SAMPLES} random points: {worst:.4} m");
}
