//! `cbdam extract`: back to a grid within the bound, windows and levels, nodata and CRS kept,
//! bad arguments refused without output.

use std::path::Path;

use cbdam_builder::input::{Format, ReadOptions, read_dem};
use cbdam_codec::repository::{Repository, Section};
use cbdam_codec::samples::Dem;

use super::write_asc;
use crate::util::*;

fn read(path: &Path) -> Dem {
    read_dem(path, &ReadOptions::default()).unwrap()
}

/// Half a float32 ulp of `v`: what rounding a decoded f64 height to f32 may add.
fn half_ulp_f32(v: f64) -> f64 {
    let f = v as f32;
    f64::from(f32::from_bits(f.abs().to_bits() + 1) - f.abs()) / 2.0
}

/// Largest |a − b| over the samples `b` holds (its nodata and NaN samples skipped), failing
/// when any exceeds `eps` plus the f32 rounding allowance of the value.
fn max_abs_diff(a: &Dem, b: &Dem, eps: f64, f32_out: bool) -> f64 {
    assert_eq!((a.width, a.height), (b.width, b.height));
    let mut worst = 0f64;
    for i in 0..b.values.len() {
        if !b.is_valid(i) {
            continue;
        }
        let e = (a.values[i] - b.values[i]).abs();
        let allowance = if f32_out {
            half_ulp_f32(a.values[i])
        } else {
            0.0
        };
        assert!(
            e <= eps + allowance,
            "sample {i} (column {}, row {}): extract {} vs {} is off by {e}",
            i % b.width,
            i / b.width,
            a.values[i],
            b.values[i]
        );
        worst = worst.max(e);
    }
    worst
}

fn extract_ok(args: &[&str]) {
    let mut all = vec!["extract", "--quiet"];
    all.extend_from_slice(args);
    let o = cbdam(&all);
    assert!(o.status.success(), "{all:?}: {}", stderr(&o));
}

/// Build → extract the whole extent → read back: the input's grid and georeferencing, every
/// sample within ε (plus the float32 rounding when written as float32; exactly ε with
/// --float64).
fn extract_round_trip(name: &str, max_error: &str) {
    let dir = tempfile::tempdir().unwrap();
    let repo = dir.path().join("t.cbdam");
    let input = data(name);
    build_quiet(&input, &repo, max_error);
    let eps: f64 = max_error.parse().unwrap();
    let orig = read(Path::new(&input));

    let tif = dir.path().join("x.tif");
    extract_ok(&[&s(&repo), "-o", &s(&tif)]);
    let got = read(&tif);
    assert_eq!(got.georef, orig.georef);
    let worst = max_abs_diff(&got, &orig, eps, true);
    eprintln!("{name} at ε = {eps} m: float32 extract max |extract − input| = {worst} m");
    assert!(
        worst > 0.0,
        "a lossy build that reproduces {name} exactly is suspicious"
    );

    let tif64 = dir.path().join("x64.tif");
    extract_ok(&[&s(&repo), "-o", &s(&tif64), "--float64"]);
    let got64 = read(&tif64);
    assert_eq!(got64.georef, orig.georef);
    let worst64 = max_abs_diff(&got64, &orig, eps, false);
    eprintln!("{name} at ε = {eps} m: float64 extract max |extract − input| = {worst64} m");

    // Raw: the same samples, and a sidecar that says how to read them.
    let raw = dir.path().join("x.f32");
    extract_ok(&[&s(&repo), "-o", &s(&raw), "--format", "raw"]);
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("x.json")).unwrap()).unwrap();
    assert_eq!(meta["width"], orig.width);
    assert_eq!(meta["height"], orig.height);
    assert_eq!(meta["unit"], "m");
    assert_eq!(meta["max_error_m"], eps);
    assert_eq!(
        meta["georef"]["origin_x"],
        orig.georef.as_ref().unwrap().origin_x
    );
    let r = read_dem(
        &raw,
        &ReadOptions {
            format: Some(Format::RawF32 {
                width: orig.width,
                height: orig.height,
            }),
            ..ReadOptions::default()
        },
    )
    .unwrap();
    assert_eq!(r.values, got.values);
}

#[test]
fn extract_jacksboro_within_bound() {
    extract_round_trip("jacksboro_mpl.tif", "1");
}

#[test]
fn extract_lidar_within_bound() {
    extract_round_trip("lidar1m_mn.tif", "0.5");
}

#[test]
fn extract_bbox_and_level() {
    let dir = tempfile::tempdir().unwrap();
    let repo = dir.path().join("t.cbdam");
    let input = data("jacksboro_mpl.tif");
    build_quiet(&input, &repo, "1");
    let full = dir.path().join("full.tif");
    extract_ok(&[&s(&repo), "-o", &s(&full)]);
    let full = read(&full);
    let g = full.georef.clone().unwrap();

    // Cell edges of columns 100 … 199 and rows 50 … 149: sample centres lie half a pixel
    // inside, so no rounding decides membership.
    let bbox = format!(
        "{},{},{},{}",
        g.origin_x + 100.0 * g.pixel_x,
        g.origin_y - 150.0 * g.pixel_y,
        g.origin_x + 200.0 * g.pixel_x,
        g.origin_y - 50.0 * g.pixel_y
    );
    let win = dir.path().join("win.tif");
    extract_ok(&[&s(&repo), "-o", &s(&win), "--bbox", &bbox]);
    let win = read(&win);
    let want = full.crop(100, 50, 100, 100).unwrap();
    assert_eq!((win.width, win.height), (100, 100));
    assert_eq!(win.values, want.values);
    let (a, b) = (win.georef.unwrap(), want.georef.unwrap());
    assert!((a.origin_x - b.origin_x).abs() < 1e-9 && (a.origin_y - b.origin_y).abs() < 1e-9);
    assert_eq!(
        (a.pixel_x, a.pixel_y, a.epsg),
        (b.pixel_x, b.pixel_y, b.epsg)
    );

    // A box reaching past the data is clipped to it.
    let big = dir.path().join("big.tif");
    extract_ok(&[&s(&repo), "-o", &s(&big), "--bbox", "-100,-100,100,100"]);
    assert_eq!(read(&big).values, full.values);

    // Level 4 of 6 (K = 3): every second sample, each within ε of the input (α = 1 keeps the
    // coarse levels subsamples of the input, and the bound holds on every level).
    let orig = read(Path::new(&input));
    let l4 = dir.path().join("l4.tif");
    extract_ok(&[&s(&repo), "-o", &s(&l4), "--level", "4"]);
    let l4 = read(&l4);
    assert_eq!((l4.width, l4.height), (202, 172));
    let sub = Dem {
        width: 202,
        height: 172,
        values: (0..172)
            .flat_map(|r| (0..202).map(move |c| (r, c)))
            .map(|(r, c)| orig.values[2 * r * orig.width + 2 * c])
            .collect(),
        ..orig.clone()
    };
    max_abs_diff(&l4, &sub, 1.0, true);
    let lg = l4.georef.unwrap();
    assert_eq!(lg.pixel_x, 2.0 * g.pixel_x);
    // PixelIsArea: the coarse cell is centred on input sample (0, 0).
    let centre = g.origin_x + 0.5 * g.pixel_x;
    assert!((lg.origin_x + 0.5 * lg.pixel_x - centre).abs() < 1e-9);
    // Level 0: one root of 65 × 65 covering the 403 × 344 data at spacing 8.
    let l0 = dir.path().join("l0.tif");
    extract_ok(&[&s(&repo), "-o", &s(&l0), "--level", "0"]);
    let l0 = read(&l0);
    assert_eq!((l0.width, l0.height), (51, 43));
}

/// Runs an extract that must fail with `message` and leave `dir` as it was.
fn extract_fails(dir: &Path, args: &[&str], message: &str) {
    let mut all = vec!["extract"];
    all.extend_from_slice(args);
    run_refused_leaving(dir, &all, &[message]);
}

#[test]
fn extract_bad_inputs_fail_without_output() {
    let dir = tempfile::tempdir().unwrap();
    let repo = jacksboro_at("1");
    let r = s(&repo);
    let out = s(&dir.path().join("out.tif"));
    // Jacksboro lies around 84.2° W, 36.6° N.
    extract_fails(
        dir.path(),
        &[&r, "-o", &out, "--bbox", "10,10,11,11"],
        "holds no sample",
    );
    extract_fails(
        dir.path(),
        &[&r, "-o", &out, "--bbox", "-84.1,36.5,-84.3,36.6"],
        "inverted",
    );
    extract_fails(dir.path(), &[&r, "-o", &out, "--bbox", "1,2,3"], "four");
    extract_fails(dir.path(), &[&r, "-o", &out, "--level", "3"], "even");
    extract_fails(dir.path(), &[&r, "-o", &out, "--level", "8"], "finest is 6");
    let sub = dir.path().join("sub");
    std::fs::create_dir(&sub).unwrap();
    extract_fails(dir.path(), &[&r, "-o", &s(&sub)], "is a directory");
    extract_fails(
        dir.path(),
        &[&r, "-o", &s(&dir.path().join("x.json")), "--format", "raw"],
        "sidecar",
    );
    extract_fails(
        dir.path(),
        &[&r, "-o", &s(&dir.path().join("no").join("x.tif"))],
        "writing",
    );

    // A damaged record: named, and nothing written.
    let bad = dir.path().join("bad.cbdam");
    let rp = Repository::open(&repo).unwrap();
    let records = rp.head().section_len(Section::Records) as usize;
    let victim = (0..rp.head().entries().len())
        .max_by_key(|&i| rp.head().entries()[i].length)
        .unwrap();
    let e = rp.head().entries()[victim];
    drop(rp);
    let mut bytes = std::fs::read(&repo).unwrap();
    let at = bytes.len() - records + e.offset as usize + e.length as usize / 2;
    bytes[at] ^= 0x10;
    std::fs::write(&bad, &bytes).unwrap();
    extract_fails(
        dir.path(),
        &[&s(&bad), "-o", &out],
        &format!("record {victim}"),
    );
    extract_fails(
        dir.path(),
        &[&s(&dir.path().join("missing.cbdam")), "-o", &out],
        "missing.cbdam",
    );
}

/// Without georeferencing, --bbox is in column / row indices (row 0 = north), inclusive.
#[test]
fn extract_bbox_in_pixels_without_georef() {
    let dir = tempfile::tempdir().unwrap();
    let repo = dir.path().join("f.cbdam");
    let input = data("fuji_terrainrgb.png");
    build_quiet(&input, &repo, "2");
    let full = dir.path().join("full.tif");
    extract_ok(&[&s(&repo), "-o", &s(&full)]);
    let full = read(&full);
    assert!(full.georef.is_none());
    let orig = read(Path::new(&input));
    max_abs_diff(&full, &orig, 2.0, true);

    let win = dir.path().join("win.tif");
    extract_ok(&[&s(&repo), "-o", &s(&win), "--bbox", "10,20,59,99"]);
    let win = read(&win);
    assert_eq!((win.width, win.height), (50, 80));
    assert_eq!(win.values, full.crop(10, 20, 50, 80).unwrap().values);
}

/// An input with nodata: its value is carried to GDAL_NODATA, valid samples keep the bound.
#[test]
fn extract_keeps_the_nodata_value() {
    let dir = tempfile::tempdir().unwrap();
    let repo = dir.path().join("r.cbdam");
    let input = data("rhine_nodata.tif");
    build_quiet(&input, &repo, "1");
    let orig = read(Path::new(&input));
    assert_eq!(orig.nodata, Some(-9999.0));
    let tif = dir.path().join("r.tif");
    extract_ok(&[&s(&repo), "-o", &s(&tif)]);
    let got = read(&tif);
    assert_eq!(got.nodata, orig.nodata);
    assert_eq!(got.georef, orig.georef);
    max_abs_diff(&got, &orig, 1.0, true);
    // The repository's nodata mask comes back exactly: nodata where the input had none, data
    // everywhere else.
    let written_nodata = (0..got.values.len()).filter(|&i| !got.is_valid(i)).count();
    let input_nodata = (0..orig.values.len())
        .filter(|&i| !orig.is_valid(i))
        .count();
    assert!(input_nodata > orig.values.len() / 3, "{input_nodata}");
    let differ: Vec<usize> = (0..orig.values.len())
        .filter(|&i| got.is_valid(i) != orig.is_valid(i))
        .collect();
    assert!(
        differ.is_empty(),
        "{} of {input_nodata} nodata samples differ ({written_nodata} written), first at {:?}",
        differ.len(),
        &differ[..differ.len().min(5)]
    );
    // A coarser level keeps the mask on its own samples (every 2nd sample of every 2nd row).
    let coarse = dir.path().join("c.tif");
    let finest = cbdam(&["inspect", "--json", &s(&repo)]);
    let meta: serde_json::Value = serde_json::from_slice(&finest.stdout).unwrap();
    let level = meta["finest_level"].as_u64().unwrap() - 2;
    extract_ok(&[&s(&repo), "-o", &s(&coarse), "--level", &level.to_string()]);
    let c = read(&coarse);
    for y in 0..c.height {
        for x in 0..c.width {
            let i = 2 * y * orig.width + 2 * x;
            assert_eq!(c.is_valid(y * c.width + x), orig.is_valid(i), "({x}, {y})");
        }
    }

    // inspect reports the share of samples without data, from the mask.
    assert!(
        (meta["nodata_fraction"].as_f64().unwrap()
            - input_nodata as f64 / orig.values.len() as f64)
            .abs()
            < 1e-12,
        "{}",
        meta["nodata_fraction"]
    );
    let text = stdout(&cbdam(&["inspect", &s(&repo)]));
    assert!(
        text.contains(&format!("{input_nodata} of")) && text.contains("mask stored"),
        "{text}"
    );
}

/// A CRS known only as WKT (an ESRI `.prj` beside an ASCII grid) is kept: `inspect --json`
/// shows it, `extract` writes it back as a `.prj` beside the GeoTIFF and into the raw sidecar,
/// and a `.prj` that is not text stops the build with its name, writing nothing.
#[test]
fn a_prj_crs_definition_travels_from_input_to_extract() {
    let dir = tempfile::tempdir().unwrap();
    let rows: Vec<Vec<f64>> = (0..20)
        .map(|y| (0..24).map(|x| 100.0 + (x * 3 + y * 2) as f64).collect())
        .collect();
    let asc = dir.path().join("lcc.asc");
    write_asc(&asc, &rows, None);
    let wkt = r#"PROJCS["Custom_LCC",GEOGCS["GCS_WGS_1984",DATUM["D_WGS_1984",SPHEROID["WGS_1984",6378137.0,298.257223563]],PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]],PROJECTION["Lambert_Conformal_Conic"],PARAMETER["Central_Meridian",-96.0],PARAMETER["Standard_Parallel_1",33.0],PARAMETER["Standard_Parallel_2",45.0],PARAMETER["Latitude_Of_Origin",39.0],UNIT["Meter",1.0]]"#;
    std::fs::write(dir.path().join("lcc.prj"), format!("{wkt}\r\n")).unwrap();
    let repo = dir.path().join("lcc.cbdam");
    build_quiet(&s(&asc), &repo, "1");
    let o = cbdam(&["inspect", &s(&repo), "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["georef"]["wkt"], wkt);
    // The definition is longer than the usual first fetch of a remote reader.
    assert!(v["sections"]["header"]["length"].as_u64().unwrap() > 256);
    assert!(
        stdout(&cbdam(&["inspect", &s(&repo)])).contains("crs (wkt)       PROJCS[\"Custom_LCC\"")
    );
    let o = cbdam(&["verify", &s(&repo), "--against", &s(&asc)]);
    assert!(o.status.success(), "{}", stderr(&o));

    let tif = dir.path().join("out.tif");
    let o = cbdam(&["extract", &s(&repo), "-o", &s(&tif), "--quiet"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(
        std::fs::read_to_string(dir.path().join("out.prj")).unwrap(),
        format!("{wkt}\n")
    );
    let raw = dir.path().join("out.f32");
    let o = cbdam(&[
        "extract",
        &s(&repo),
        "-o",
        &s(&raw),
        "--format",
        "raw",
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("out.json")).unwrap())
            .unwrap();
    assert_eq!(meta["georef"]["wkt"], wkt);

    // Not text: refused, naming the file.
    let bad = dir.path().join("bad.asc");
    write_asc(&bad, &rows, None);
    std::fs::write(dir.path().join("bad.prj"), [0xFFu8, 0xFE, 0x00, 0x50]).unwrap();
    let out = dir.path().join("bad.cbdam");
    let o = cbdam(&["build", &s(&bad), "-o", &s(&out), "--max-error", "1"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains("bad.prj") && stderr(&o).contains("UTF-8"),
        "{}",
        stderr(&o)
    );
    assert!(!out.exists());
}
