//! The L∞ guarantee on every real DEM in `data/`, end to end: every level checked exactly in
//! integer units by `verify`, and the finest reconstruction checked in metres against the
//! file's own sample values — an independent check of the whole chain (quantum detection, unit
//! plan, offset, quantizer, hierarchy), since the sample values never went through the codec.

use std::path::Path;
use std::time::Instant;

use cbdam_builder::input::{ReadOptions, read_dem};
use cbdam_codec::entropy::CoderKind;
use cbdam_codec::hierarchy::{EncodeOptions, Encoder, reconstruct_finest, verify};
use cbdam_codec::lifting::Alpha;
use cbdam_codec::quant::{HeightGrid, QuantPlan};
use cbdam_codec::samples::Dem;

fn read(name: &str) -> Dem {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../data")
        .join(name);
    read_dem(&path, &ReadOptions::default()).unwrap_or_else(|e| panic!("{name}: {e}"))
}

/// Encodes `dem` at `eps` and checks both bounds; returns the largest sample error, metres.
fn check(name: &str, dem: &Dem, eps: f64, alpha: Alpha, coder: CoderKind) -> f64 {
    let t = Instant::now();
    let what = format!("{name} ε={eps} {alpha:?} {}", coder.name());
    let plan = QuantPlan::for_dem(dem, eps, None).unwrap_or_else(|e| panic!("{what}: {e}"));
    let grid = HeightGrid::from_dem(dem, &plan).unwrap();
    let opts = EncodeOptions {
        alpha,
        coder,
        ..EncodeOptions::default()
    };
    let enc = Encoder::new(&grid, plan.quantizer, &opts)
        .encode()
        .unwrap_or_else(|e| panic!("{what}: {e}"));
    let report = verify(&enc, &grid).unwrap();
    assert!(
        report.within_bound(),
        "{what}: max error {} > bound {} units; per level {:?}",
        report.max_error(),
        report.bound,
        report.levels
    );
    let finest = reconstruct_finest(&enc).unwrap();
    assert_eq!(finest.len(), dem.values.len());
    let mut max_err = 0f64;
    let mut checked = 0usize;
    for (i, &n) in finest.iter().enumerate() {
        // Validity from the file (nodata / NaN), not from the codec's own grid.
        if !dem.is_valid(i) {
            continue;
        }
        checked += 1;
        let e = (plan.metres(n) - dem.values[i]).abs();
        // f64 evaluation of `offset + n·u` is good to ~1e-16 relative; anything beyond that
        // is a real violation of the tolerance.
        assert!(
            e <= eps * (1.0 + 1e-12),
            "{what}: sample {i} (col {}, row {}) is {} m, decoded {} m: error {e} m",
            i % dem.width,
            i / dem.width,
            dem.values[i],
            plan.metres(n)
        );
        max_err = max_err.max(e);
    }
    assert_eq!(checked, dem.valid_count(), "{what}");
    eprintln!(
        "{what}: {} records, {:.3} bits/valid sample, max error {max_err:.4} m, {:.1} s",
        enc.records.len(),
        enc.payload_bytes() as f64 * 8.0 / checked as f64,
        t.elapsed().as_secs_f64()
    );
    max_err
}

/// ε = 0.1, 1 and 10 m with the default adaptive coder and α = 1; then, at 1 m, the other
/// coder and α = ½.
fn full(name: &str) {
    let dem = read(name);
    let mut errs = Vec::new();
    for eps in [0.1, 1.0, 10.0] {
        errs.push(check(name, &dem, eps, Alpha::One, CoderKind::Adaptive));
    }
    // The coarse tolerance must actually be used: a codec that stored everything losslessly
    // would pass the bound checks while failing its purpose.
    assert!(errs[2] > 1.0, "{name}: ε = 10 m gave max error {}", errs[2]);
    for coder in CoderKind::ALL {
        for alpha in [Alpha::One, Alpha::Half] {
            if (coder, alpha) != (CoderKind::Adaptive, Alpha::One) {
                check(name, &dem, 1.0, alpha, coder);
            }
        }
    }
}

#[test]
fn srtm3_demcompare() {
    full("srtm3_demcompare.tif");
}

#[test]
fn fuji_terrainrgb() {
    full("fuji_terrainrgb.tif");
}

#[test]
fn jacksboro_mpl() {
    full("jacksboro_mpl.tif");
}

#[test]
fn lidar1m_mn() {
    full("lidar1m_mn.tif");
}

#[test]
fn rhine_nodata() {
    // 48 % nodata: the stored set, don't-care residuals and the finest walk over holes.
    full("rhine_nodata.tif");
}

#[test]
fn etopo5_global() {
    // 9.3 M samples, bathymetry included.
    let name = "etopo5_global.tif";
    let dem = read(name);
    for eps in [0.1, 1.0, 10.0] {
        check(name, &dem, eps, Alpha::One, CoderKind::Adaptive);
    }
}
