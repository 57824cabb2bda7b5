//! The readers against real DEMs, checked with sidecars written by an independent tool: size,
//! range, georeferencing and the SHA-256 of the grid as little-endian f32, row-major, north-up.

use std::path::{Path, PathBuf};

use cbdam_builder::input::{Format, ReadOptions, read_dem};
use cbdam_codec::samples::{Dem, SampleType, detect_quantum};
use serde_json::Value;
use sha2::{Digest, Sha256};

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../data")
        .join(name)
}

fn sidecar(stem: &str) -> Value {
    let text = std::fs::read_to_string(data(&format!("{stem}.json"))).unwrap();
    serde_json::from_str(&text).unwrap()
}

fn read(name: &str) -> Dem {
    read_dem(&data(name), &ReadOptions::default()).unwrap_or_else(|e| panic!("{name}: {e}"))
}

fn sha256_f32(dem: &Dem) -> String {
    let mut h = Sha256::new();
    for &v in &dem.values {
        h.update((v as f32).to_le_bytes());
    }
    h.finalize().iter().map(|b| format!("{b:02x}")).collect()
}

fn valid_range(dem: &Dem) -> (f64, f64) {
    (0..dem.values.len())
        .filter(|&i| dem.is_valid(i))
        .map(|i| dem.values[i])
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        })
}

/// Checks `dem` against the sidecar `<stem>.json`: everything the independent tool recorded.
fn check_against_sidecar(dem: &Dem, stem: &str) {
    let j = sidecar(stem);
    assert_eq!(
        dem.width as u64,
        j["width"].as_u64().unwrap(),
        "{stem} width"
    );
    assert_eq!(
        dem.height as u64,
        j["height"].as_u64().unwrap(),
        "{stem} height"
    );
    assert_eq!(dem.values.len(), dem.width * dem.height);

    let (lo, hi) = valid_range(dem);
    // The sidecar's range is of the f32 grid; compare as f32 so a float32 file's 13.7 matches.
    assert_eq!(lo as f32, j["min"].as_f64().unwrap() as f32, "{stem} min");
    assert_eq!(hi as f32, j["max"].as_f64().unwrap() as f32, "{stem} max");
    assert_eq!(
        sha256_f32(dem),
        j["sha256_f32"].as_str().unwrap(),
        "{stem} sha256_f32"
    );

    match j["nodata"].as_f64() {
        Some(nd) => assert_eq!(dem.nodata, Some(nd), "{stem} nodata"),
        // No nodata in the sidecar: whatever the file's tag says, no sample may be void.
        None => assert_eq!(dem.valid_count(), dem.values.len(), "{stem}: void samples"),
    }

    match j.get("georef") {
        Some(g) => {
            let r = dem
                .georef
                .as_ref()
                .unwrap_or_else(|| panic!("{stem}: no georef"));
            assert_eq!(r.epsg, g["epsg"].as_u64().map(|e| e as u32), "{stem} epsg");
            for (got, key) in [
                (r.origin_x, "origin_x"),
                (r.origin_y, "origin_y"),
                (r.pixel_x, "pixel_x"),
                (r.pixel_y, "pixel_y"),
            ] {
                let want = g[key].as_f64().unwrap();
                assert!(
                    (got - want).abs() <= 1e-9 * want.abs().max(1.0),
                    "{stem} {key}: {got} vs {want}"
                );
            }
            let area = g["pixel_is"].as_str().unwrap() == "area";
            assert_eq!(r.pixel_is_area, area, "{stem} pixel_is");
        }
        // The sidecar tool records georeferencing wherever the file has it.
        None => assert_eq!(dem.georef, None, "{stem}: unexpected georef"),
    }
}

#[test]
fn srtm3_int16() {
    let dem = read("srtm3_demcompare.tif");
    assert_eq!(dem.sample_type, SampleType::I16);
    check_against_sidecar(&dem, "srtm3_demcompare");
    assert_eq!(detect_quantum(&dem), Some(1.0));
}

#[test]
fn etopo5_deflate_floating_point_predictor() {
    let dem = read("etopo5_global.tif");
    assert_eq!(dem.sample_type, SampleType::F32);
    check_against_sidecar(&dem, "etopo5_global");
    assert_eq!(detect_quantum(&dem), Some(1.0));
}

#[test]
fn fuji_float32_tiff() {
    let dem = read("fuji_terrainrgb.tif");
    assert_eq!(dem.sample_type, SampleType::F32);
    check_against_sidecar(&dem, "fuji_terrainrgb");
    assert_eq!(detect_quantum(&dem), Some(0.1));
}

#[test]
fn fuji_terrain_rgb_png_matches_the_tiff() {
    // Detected from the header (8-bit RGB) and read with the format named: both must agree.
    let detected = read("fuji_terrainrgb.png");
    let named = read_dem(
        &data("fuji_terrainrgb.png"),
        &ReadOptions {
            format: Some(Format::TerrainRgb),
            ..ReadOptions::default()
        },
    )
    .unwrap();
    assert_eq!(detected.values, named.values);
    check_against_sidecar(&detected, "fuji_terrainrgb");
    assert_eq!(
        sha256_f32(&detected),
        sha256_f32(&read("fuji_terrainrgb.tif"))
    );
    assert_eq!(detect_quantum(&detected), Some(0.1));
    // Exactly-rounded decimals: the lowest point is the double nearest 13.7, not 13.700000000000001.
    assert_eq!(valid_range(&detected).0, 13.7);
}

#[test]
fn jacksboro_float32_with_georef() {
    let dem = read("jacksboro_mpl.tif");
    check_against_sidecar(&dem, "jacksboro_mpl");
    assert_eq!(detect_quantum(&dem), Some(1.0));
}

#[test]
fn lidar_tiled_float32() {
    let dem = read("lidar1m_mn.tif");
    assert_eq!(dem.sample_type, SampleType::F32);
    check_against_sidecar(&dem, "lidar1m_mn");
    assert_eq!(detect_quantum(&dem), None);
}

#[test]
fn rhine_nodata() {
    let dem = read("rhine_nodata.tif");
    assert_eq!(dem.nodata, Some(-9999.0));
    let void = dem.values.iter().filter(|&&v| v == -9999.0).count();
    let invalid = dem.values.len() - dem.valid_count();
    assert_eq!(void, invalid, "every invalid sample is the nodata value");
    let frac = void as f64 / dem.values.len() as f64;
    assert!((0.46..0.50).contains(&frac), "nodata fraction {frac}");
    let (lo, _) = valid_range(&dem);
    assert!(lo > -9999.0);
    // The nodata override replaces the file's value.
    let over = read_dem(
        &data("rhine_nodata.tif"),
        &ReadOptions {
            nodata: Some(0.0),
            ..ReadOptions::default()
        },
    )
    .unwrap();
    assert_eq!(over.nodata, Some(0.0));
    assert_eq!(over.values, dem.values);
}

#[test]
fn truncated_real_tiffs() {
    // GDAL writes the directory first, so a cut file keeps its tags and loses pixel data.
    let dir = tempfile::TempDir::new().unwrap();
    for name in [
        "srtm3_demcompare.tif",
        "etopo5_global.tif",
        "lidar1m_mn.tif",
    ] {
        let bytes = std::fs::read(data(name)).unwrap();
        let cut = dir.path().join(name);
        std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap();
        let e = read_dem(&cut, &ReadOptions::default()).unwrap_err();
        assert!(
            matches!(e, cbdam_codec::CodecError::Truncated(_)),
            "{name}: {e}"
        );
    }
}
