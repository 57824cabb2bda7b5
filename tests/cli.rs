//! The `cbdam` binary end to end: build → inspect → verify on real DEMs, bad inputs that must
//! fail cleanly without leaving files behind, and damaged repositories that `verify` must catch.

mod common;

use std::path::Path;
use std::process::{Command, Output};

use cbdam_codec::repository::{Repository, Section};
use common::*;

/// An ESRI ASCII grid of `rows` (north first).
fn write_asc(path: &Path, rows: &[Vec<f64>], nodata: Option<f64>) {
    let mut t = format!(
        "ncols {}\nnrows {}\nxllcorner 0\nyllcorner 0\ncellsize 1\n",
        rows[0].len(),
        rows.len()
    );
    if let Some(nd) = nodata {
        t += &format!("NODATA_value {nd}\n");
    }
    for r in rows {
        t += &r
            .iter()
            .map(|v| v.to_string())
            .collect::<Vec<_>>()
            .join(" ");
        t += "\n";
    }
    std::fs::write(path, t).unwrap();
}

fn round_trip(name: &str, max_error: &str, extra: &[&str]) {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("t.cbdam");
    let out_s = s(&out);
    let input = data(name);
    let mut args = vec!["build", &input, "-o", &out_s, "--max-error", max_error];
    args.extend_from_slice(extra);
    let o = cbdam(&args);
    assert!(o.status.success(), "build {name}: {}", stderr(&o));
    assert!(stdout(&o).contains("bits/sample"), "{}", stdout(&o));
    assert_eq!(listing(dir.path()), vec![out.clone()]);

    let o = cbdam(&["inspect", &out_s]);
    assert!(o.status.success(), "inspect: {}", stderr(&o));
    assert!(stdout(&o).contains("bits/sample"), "{}", stdout(&o));

    let o = cbdam(&["inspect", &out_s, "--json"]);
    assert!(o.status.success(), "inspect --json: {}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let file_bytes = std::fs::metadata(&out).unwrap().len();
    assert_eq!(v["file_bytes"], file_bytes);
    assert_eq!(
        v["max_error_requested_m"],
        max_error.parse::<f64>().unwrap()
    );
    let levels = v["levels"].as_array().unwrap();
    let records: u64 = levels.iter().map(|l| l["records"].as_u64().unwrap()).sum();
    assert_eq!(v["records"], records);
    // Header and checksum table: the compact header (format version 3) plus 4 bytes per
    // non-empty record; the root field starts right after the header.
    let empty = v["empty_records"].as_u64().unwrap();
    let header = v["sections"]["header"]["length"].as_u64().unwrap();
    assert!((16..128).contains(&header), "{header}-byte header");
    assert_eq!(v["sections"]["roots"]["offset"], header);
    assert_eq!(
        v["container_overhead_bytes"],
        header + 4 * (records - empty)
    );
    let meta: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(data(&name.replace(".tif", ".json"))).unwrap(),
    )
    .unwrap();
    assert_eq!(v["data_width"], meta["width"]);
    assert_eq!(v["data_height"], meta["height"]);
    assert_eq!(v["georef"]["epsg"], meta["georef"]["epsg"]);

    let o = cbdam(&["verify", &out_s, "--against", &input]);
    assert!(o.status.success(), "verify {name}: {}", stderr(&o));
    assert!(stdout(&o).ends_with("OK\n"), "{}", stdout(&o));
}

#[test]
fn jacksboro_round_trip() {
    round_trip("jacksboro_mpl.tif", "1", &[]);
    round_trip(
        "jacksboro_mpl.tif",
        "2.5",
        &["--alpha", "0.5", "--coder", "elias-gamma", "--threads", "1"],
    );
}

#[test]
fn lidar_round_trip() {
    round_trip("lidar1m_mn.tif", "0.5", &["--diamond-size", "33"]);
}

#[test]
fn quiet_prints_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out = s(&dir.path().join("q.cbdam"));
    let input = data("jacksboro_mpl.tif");
    let o = cbdam(&["build", &input, "-o", &out, "--max-error", "4", "--quiet"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(o.stdout.is_empty() && o.stderr.is_empty());
}

#[test]
fn progress_is_logged_when_stderr_is_not_a_terminal() {
    let dir = tempfile::tempdir().unwrap();
    let out = s(&dir.path().join("p.cbdam"));
    let o = cbdam(&[
        "build",
        &data("jacksboro_mpl.tif"),
        "-o",
        &out,
        "--max-error",
        "4",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let log = stderr(&o);
    // One line per quarter, in order, ending at 100 %, and no terminal control codes.
    let quarters: Vec<&str> = log
        .lines()
        .filter(|l| l.starts_with("encoding: "))
        .collect();
    assert_eq!(
        quarters,
        [
            "encoding: 25% done",
            "encoding: 50% done",
            "encoding: 75% done",
            "encoding: 100% done"
        ],
        "{log}"
    );
    assert!(!log.contains('\u{1b}'), "{log}");
}

/// Runs a build that must fail with `message` and leave `dir` as it was.
fn build_fails(dir: &Path, input: &str, out: &Path, extra: &[&str], message: &str) {
    let before = listing(dir);
    let out_s = s(out);
    let mut args = vec!["build", input, "-o", &out_s];
    args.extend_from_slice(extra);
    let o = cbdam(&args);
    assert!(!o.status.success(), "{args:?} succeeded");
    let err = stderr(&o);
    assert!(
        err.contains(message),
        "{args:?}: expected {message:?} in {err:?}"
    );
    assert_eq!(listing(dir), before, "{args:?} left files behind");
}

#[test]
fn bad_inputs_fail_without_output() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.cbdam");
    let jb = data("jacksboro_mpl.tif");
    for (e, msg) in [
        ("0", "positive"),
        ("-1", "positive"),
        ("NaN", "positive"),
        ("inf", "positive"),
        // Jacksboro spans 236…1076 m.
        ("900", "height range"),
    ] {
        build_fails(dir.path(), &jb, &out, &[&format!("--max-error={e}")], msg);
    }
    // Every sample nodata.
    let asc = dir.path().join("nodata.asc");
    write_asc(&asc, &vec![vec![-9999.0; 5]; 4], Some(-9999.0));
    build_fails(
        dir.path(),
        &s(&asc),
        &out,
        &["--max-error", "1"],
        "no valid sample",
    );
    // The same file becomes valid once its nodata value is overridden, so --nodata is honoured.
    let o = cbdam(&[
        "build",
        &s(&asc),
        "-o",
        &s(&out),
        "--max-error",
        "1",
        "--nodata",
        "-1",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    std::fs::remove_file(&out).unwrap();
    // --nodata can also make every sample invalid.
    let flat = dir.path().join("flat.asc");
    write_asc(&flat, &vec![vec![7.0; 5]; 4], None);
    build_fails(
        dir.path(),
        &s(&flat),
        &out,
        &["--max-error", "1", "--nodata", "7"],
        "no valid sample",
    );
    // Unreadable inputs.
    let missing = s(&dir.path().join("missing.tif"));
    build_fails(
        dir.path(),
        &missing,
        &out,
        &["--max-error", "1"],
        "missing.tif",
    );
    let garbage = dir.path().join("garbage.tif");
    std::fs::write(&garbage, b"this is not a tiff at all").unwrap();
    build_fails(
        dir.path(),
        &s(&garbage),
        &out,
        &["--max-error", "1"],
        "garbage.tif",
    );
    // Output is a directory.
    let sub = dir.path().join("sub");
    std::fs::create_dir(&sub).unwrap();
    build_fails(
        dir.path(),
        &jb,
        &sub,
        &["--max-error", "1"],
        "is a directory",
    );
    assert!(listing(&sub).is_empty());
    // Output directory missing: an error, nothing created.
    let deep = dir.path().join("no").join("such").join("out.cbdam");
    build_fails(dir.path(), &jb, &deep, &["--max-error", "1"], "writing");
}

#[test]
fn verify_catches_a_damaged_record_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("t.cbdam");
    let input = data("jacksboro_mpl.tif");
    let o = cbdam(&[
        "build",
        &input,
        "-o",
        &s(&out),
        "--max-error",
        "1",
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let repo = Repository::open(&out).unwrap();
    let records = repo.section_len(Section::Records) as usize;
    // The longest record (some records are empty: all residuals zero).
    let victim = (0..repo.entries().len())
        .max_by_key(|&i| repo.entries()[i].length)
        .unwrap();
    let e = repo.entries()[victim];
    drop(repo);
    let mut bytes = std::fs::read(&out).unwrap();
    let at = bytes.len() - records + e.offset as usize + e.length as usize / 2;
    bytes[at] ^= 0x01;
    std::fs::write(&out, &bytes).unwrap();
    let o = cbdam(&["verify", &s(&out), "--against", &input]);
    assert!(!o.status.success());
    let err = stderr(&o);
    assert!(err.contains(&format!("record {victim}")), "{err}");
    assert!(err.contains(&format!("level {}", e.id.level)), "{err}");
    // Inspect reads only the header and index, which are intact.
    assert!(cbdam(&["inspect", &s(&out)]).status.success());

    // A truncated file fails to open, in both commands.
    std::fs::write(&out, &bytes[..bytes.len() - 1]).unwrap();
    let out_s = s(&out);
    for args in [
        vec!["inspect", &out_s],
        vec!["verify", &out_s, "--against", &input],
    ] {
        let o = cbdam(&args);
        assert!(!o.status.success(), "{args:?}");
        assert!(stderr(&o).contains("truncated"), "{}", stderr(&o));
    }
}

#[test]
fn verify_rejects_the_wrong_input() {
    let dir = tempfile::tempdir().unwrap();
    let rows: Vec<Vec<f64>> = (0..20)
        .map(|y| (0..30).map(|x| f64::from(x * 3 + (y * 2) % 7)).collect())
        .collect();
    let asc = dir.path().join("a.asc");
    write_asc(&asc, &rows, None);
    let out = s(&dir.path().join("a.cbdam"));
    let o = cbdam(&["build", &s(&asc), "-o", &out, "--max-error", "2", "--quiet"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        cbdam(&["verify", &out, "--against", &s(&asc)])
            .status
            .success()
    );

    // One sample moved by far more than the tolerance.
    let mut moved = rows.clone();
    moved[11][17] += 10.0;
    let bad = dir.path().join("moved.asc");
    write_asc(&bad, &moved, None);
    let o = cbdam(&["verify", &out, "--against", &s(&bad)]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("violated"), "{}", stderr(&o));

    // A different grid size.
    let o = cbdam(&["verify", &out, "--against", &data("jacksboro_mpl.tif")]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("403×344"), "{}", stderr(&o));
}

#[test]
fn upgrade_rewrites_version_1_as_the_build_of_today() {
    let dir = tempfile::tempdir().unwrap();
    let v1 = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/codec/tests/data/v1/lidar1m_eps1.cbdam"
    );
    let copy = dir.path().join("old.cbdam");
    std::fs::copy(v1, &copy).unwrap();
    let copy_s = s(&copy);
    assert!(stdout(&cbdam(&["inspect", &copy_s])).contains("format          version 1"));

    // In place: the input is replaced atomically, nothing else is left behind.
    let o = cbdam(&["upgrade", &copy_s, "-o", &copy_s]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stdout(&o).contains("format version 1 → 3, 1318 → "),
        "{}",
        stdout(&o)
    );
    assert_eq!(listing(dir.path()), vec![copy.clone()]);
    assert!(stdout(&cbdam(&["inspect", &copy_s])).contains("format          version 3"));
    let o = cbdam(&["verify", &copy_s, "--against", &data("lidar1m_mn.tif")]);
    assert!(o.status.success(), "{}", stderr(&o));

    // The same bytes as building the same input today with the fixture's options (the
    // defaults of its day: the upgrade keeps the records, so the coder stays the bitwise one).
    let fresh = dir.path().join("fresh.cbdam");
    let o = cbdam(&[
        "build",
        &data("lidar1m_mn.tif"),
        "-o",
        &s(&fresh),
        "--max-error",
        "1",
        "--coder",
        "adaptive",
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(
        std::fs::read(&copy).unwrap(),
        std::fs::read(&fresh).unwrap()
    );

    // Not a repository: exit 1, the problem named, no output.
    let junk = dir.path().join("junk.cbdam");
    std::fs::write(&junk, b"not a repository").unwrap();
    let out = dir.path().join("out.cbdam");
    let o = cbdam(&["upgrade", &s(&junk), "-o", &s(&out)]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("bad magic"), "{}", stderr(&o));
    assert!(!out.exists());
}

#[test]
fn a_closed_stdout_ends_inspect_quietly() {
    let repo = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/codec/tests/data/v1/lidar1m_eps1.cbdam"
    );
    let mut child = Command::new(env!("CARGO_BIN_EXE_cbdam"))
        .args(["inspect", repo])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // As `| head -0` does: the reader goes away before anything is read.
    drop(child.stdout.take());
    let o = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!err.contains("panicked"), "{err}");
    assert_ne!(o.status.code(), Some(101), "{err}");
}

// ---- extract ----------------------------------------------------------------------------------

use cbdam_codec::input::{Dem, Format, ReadOptions, read_dem};

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

fn build_quiet(input: &str, out: &Path, max_error: &str) {
    let o = cbdam(&[
        "build",
        input,
        "-o",
        &s(out),
        "--max-error",
        max_error,
        "--quiet",
    ]);
    assert!(o.status.success(), "build {input}: {}", stderr(&o));
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
    let before = listing(dir);
    let mut all = vec!["extract"];
    all.extend_from_slice(args);
    let o = cbdam(&all);
    assert!(!o.status.success(), "{all:?} succeeded");
    assert_eq!(o.status.code(), Some(1), "{all:?}");
    let err = stderr(&o);
    assert!(
        err.contains(message),
        "{all:?}: expected {message:?} in {err:?}"
    );
    assert_eq!(listing(dir), before, "{all:?} left files behind");
}

#[test]
fn extract_bad_inputs_fail_without_output() {
    let dir = tempfile::tempdir().unwrap();
    let repo = dir.path().join("t.cbdam");
    build_quiet(&data("jacksboro_mpl.tif"), &repo, "1");
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
    let records = rp.section_len(Section::Records) as usize;
    let victim = (0..rp.entries().len())
        .max_by_key(|&i| rp.entries()[i].length)
        .unwrap();
    let e = rp.entries()[victim];
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

/// `verify` checks the nodata mask sample by sample: an input whose nodata differs in a single
/// sample (valid there, within the tolerance of the decoded surface) is rejected by name.
#[test]
fn verify_checks_the_nodata_mask() {
    let dir = tempfile::tempdir().unwrap();
    let rows: Vec<Vec<f64>> = (0..20)
        .map(|y| (0..30).map(|x| f64::from(x * 3 + (y * 2) % 7)).collect())
        .collect();
    let mut holed = rows.clone();
    for (y, row) in holed.iter_mut().enumerate() {
        for (x, v) in row.iter_mut().enumerate() {
            if (x + 2 * y) % 9 == 0 || (10..14).contains(&x) {
                *v = -9999.0;
            }
        }
    }
    let asc = dir.path().join("h.asc");
    write_asc(&asc, &holed, Some(-9999.0));
    let out = s(&dir.path().join("h.cbdam"));
    let o = cbdam(&["build", &s(&asc), "-o", &out, "--max-error", "2", "--quiet"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = cbdam(&["verify", &out, "--against", &s(&asc)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("0 mismatches"), "{}", stdout(&o));

    // Sample (12, 5) had no data; give it its true height.
    let mut filled = holed.clone();
    filled[5][12] = rows[5][12];
    let bad = dir.path().join("filled.asc");
    write_asc(&bad, &filled, Some(-9999.0));
    let o = cbdam(&["verify", &out, "--against", &s(&bad)]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("nodata mask disagrees with the input at 1 samples")
            && stderr(&o).contains("column 12, row 5"),
        "{}",
        stderr(&o)
    );
}

/// `cbdam serve` as a process: serves over loopback, answers a raw HTTP/1.1 request, and exits
/// cleanly (status 0) on SIGTERM.
#[cfg(unix)]
#[test]
fn serve_answers_and_stops_on_sigterm() {
    use std::io::{BufRead, BufReader, Read, Write};
    use std::process::Stdio;

    let dir = tempfile::tempdir().unwrap();
    let repo = dir.path().join("jb.cbdam");
    let o = cbdam(&[
        "build",
        &data("jacksboro_mpl.tif"),
        "-o",
        &s(&repo),
        "--max-error",
        "2",
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let mut child = Command::new(env!("CARGO_BIN_EXE_cbdam"))
        .args(["serve", &s(&repo), "--addr", "127.0.0.1:0"])
        .env("RUST_LOG", "info")
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut err = BufReader::new(child.stderr.take().unwrap());
    let mut seen = String::new();
    let addr = loop {
        let mut line = String::new();
        assert!(
            err.read_line(&mut line).unwrap() > 0,
            "exited early: {seen}"
        );
        seen += &line;
        if let Some(i) = line.find("listening on http://") {
            break line[i + "listening on http://".len()..].trim().to_string();
        }
    };
    let mut t = std::net::TcpStream::connect(&addr).unwrap();
    t.write_all(b"GET /v1/repos HTTP/1.1\r\nhost: x\r\nconnection: close\r\n\r\n")
        .unwrap();
    let mut resp = String::new();
    t.read_to_string(&mut resp).unwrap();
    assert!(resp.starts_with("HTTP/1.1 200"), "{resp}");
    let body = &resp[resp.find("\r\n\r\n").unwrap() + 4..];
    let v: serde_json::Value = serde_json::from_str(body).unwrap();
    assert_eq!(
        v,
        serde_json::json!({"repos": [{"name": "jb", "meta": "/v1/repos/jb/meta"}]})
    );
    let kill = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(kill.success());
    let status = child.wait().unwrap();
    let mut rest = String::new();
    err.read_to_string(&mut rest).unwrap();
    assert!(status.success(), "{status}: {seen}{rest}");
    assert!(
        rest.contains("SIGTERM") && rest.contains("stopped"),
        "{rest}"
    );
    // The access log has the request.
    assert!(
        rest.contains("/v1/repos") && rest.contains("status=200"),
        "{rest}"
    );
}

#[test]
fn serve_refuses_bad_repositories_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.cbdam");
    let o = cbdam(&["serve", &s(&missing), "--addr", "127.0.0.1:0"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("missing.cbdam"), "{}", stderr(&o));
    let junk = dir.path().join("junk.cbdam");
    std::fs::write(&junk, b"not a repository at all").unwrap();
    let o = cbdam(&["serve", &s(&junk), "--addr", "127.0.0.1:0"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("junk.cbdam"), "{}", stderr(&o));
    let o = cbdam(&[
        "serve",
        &format!("a={}", s(&junk)),
        &format!("a={}", s(&missing)),
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains("\"a\" is given twice"),
        "{}",
        stderr(&o)
    );
    let o = cbdam(&["serve", &s(&dir.path().join("bad name.cbdam"))]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains("invalid repository name"),
        "{}",
        stderr(&o)
    );
}

/// `cbdam replay` over a real repository and both shipped flights: the documented header, one
/// row per frame, and a last row (camera held still) that meets the target and has converged.
#[test]
fn replay_writes_documented_csv_and_converges() {
    let dir = tempfile::tempdir().unwrap();
    let repo = dir.path().join("jb.cbdam");
    build_quiet(&data("jacksboro_mpl.tif"), &repo, "1");
    for flight in ["descent.json", "low_pass.json"] {
        let csv = dir.path().join("stats.csv");
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("data/flights")
            .join(flight);
        let o = cbdam(&[
            "replay",
            &s(&repo),
            "--path",
            &s(&path),
            "--size",
            "640x360",
            "--pixel-error",
            "1",
            "--budget-ms",
            "2",
            "--fps",
            "10",
            "--out",
            &s(&csv),
        ]);
        assert!(o.status.success(), "{flight}: {}", stderr(&o));
        assert!(stdout(&o).contains("converged"), "{}", stdout(&o));
        let text = std::fs::read_to_string(&csv).unwrap();
        let mut lines = text.lines();
        let header: Vec<&str> = lines.next().unwrap().split(',').collect();
        for col in [
            "frame",
            "t",
            "refine_ms",
            "decode_ms",
            "max_screen_error_px",
            "met_target",
            "diamonds_in_cut",
            "triangles",
            "refinements",
            "coarsenings",
            "bytes_fetched",
            "requests_in_flight",
            "cut_bytes",
            "memory_limited",
        ] {
            assert!(header.contains(&col), "{flight}: no column {col}");
        }
        let rows: Vec<Vec<f64>> = lines
            .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
            .collect();
        let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
        assert!(rows.iter().all(|r| r.len() == header.len()));
        assert!(rows.len() >= 121, "{flight}: {} rows", rows.len());
        for (i, r) in rows.iter().enumerate() {
            assert_eq!(r[col("frame")], (i + 1) as f64);
        }
        let last = rows.last().unwrap();
        assert_eq!(last[col("settling")], 1.0);
        assert_eq!(last[col("met_target")], 1.0);
        assert_eq!(last[col("converged")], 1.0);
        assert!(last[col("max_screen_error_px")] <= 1.0);
        assert!(last[col("triangles")] > 0.0 && last[col("diamonds_in_cut")] > 0.0);
        assert!(rows.iter().map(|r| r[col("refinements")]).sum::<f64>() > 0.0);
        assert!(last[col("bytes_fetched")] > 0.0);
        // The default cut memory (1 GiB) is far above what this small tile needs.
        assert!(last[col("cut_bytes")] > 0.0);
        assert!(rows.iter().all(|r| r[col("memory_limited")] == 0.0));
    }
}

#[test]
fn replay_reports_unreachable_servers_and_bad_flights() {
    let dir = tempfile::tempdir().unwrap();
    let flight = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/flights/descent.json");
    let out = dir.path().join("x.csv");
    let o = cbdam(&[
        "replay",
        // Nothing listens on the discard port: the error names the URL, quickly.
        "http://127.0.0.1:9/v1/repos/srtm",
        "--path",
        &s(&flight),
        "--out",
        &s(&out),
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains("connecting to http://127.0.0.1:9/v1/repos/srtm"),
        "{}",
        stderr(&o)
    );
    let bad = dir.path().join("bad.json");
    std::fs::write(&bad, r#"{ "keyframes": [] }"#).unwrap();
    let repo = dir.path().join("jb.cbdam");
    build_quiet(&data("jacksboro_mpl.tif"), &repo, "4");
    let o = cbdam(&["replay", &s(&repo), "--path", &s(&bad), "--out", &s(&out)]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains("at least two keyframes"),
        "{}",
        stderr(&o)
    );
    let o = cbdam(&[
        "replay",
        &s(&repo),
        "--path",
        &s(&flight),
        "--out",
        &s(&out),
        "--size",
        "0x5",
    ]);
    assert_eq!(o.status.code(), Some(2));
}

#[test]
fn out_of_core_and_streamed_builds_give_identical_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let ok = |o: &Output| assert!(o.status.success(), "{}", stderr(o));
    // Bundled DEM with nodata: default memory limit vs a limit that forces the mapped field.
    let a = dir.path().join("a.cbdam");
    let b = dir.path().join("b.cbdam");
    let rhine = data("rhine_nodata.tif");
    for (out, extra) in [(&a, None), (&b, Some("1M"))] {
        let mut args = vec!["build", &rhine, "--max-error", "1", "-o"];
        let out = s(out);
        args.push(&out);
        args.push("--quiet");
        if let Some(limit) = extra {
            args.extend(["--memory-limit", limit]);
        }
        ok(&cbdam(&args));
    }
    assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
    // An odd-sized float terrain streamed from raw f32, in memory and forced out of core:
    // identical repositories, within the bound of the same samples read whole (ASCII grid).
    let (w, h) = (131usize, 77usize);
    let rows: Vec<Vec<f64>> = (0..h)
        .map(|y| {
            (0..w)
                .map(|x| f64::from((x as f32 * 0.37).sin() * 40.0 + y as f32 * 1.25 + 300.0))
                .collect()
        })
        .collect();
    let asc = dir.path().join("t.asc");
    write_asc(&asc, &rows, None);
    let raw = dir.path().join("t.f32");
    let bytes: Vec<u8> = rows
        .iter()
        .flatten()
        .flat_map(|&v| (v as f32).to_le_bytes())
        .collect();
    std::fs::write(&raw, bytes).unwrap();
    let (c, d) = (dir.path().join("c.cbdam"), dir.path().join("d.cbdam"));
    ok(&cbdam(&[
        "build",
        &s(&raw),
        "--size",
        "131x77",
        "--max-error",
        "0.5",
        "-o",
        &s(&c),
        "--quiet",
    ]));
    ok(&cbdam(&[
        "build",
        &s(&raw),
        "--size",
        "131x77",
        "--max-error",
        "0.5",
        "-o",
        &s(&d),
        "--quiet",
        "--memory-limit",
        "4K",
    ]));
    assert_eq!(std::fs::read(&c).unwrap(), std::fs::read(&d).unwrap());
    ok(&cbdam(&["verify", &s(&d), "--against", &s(&asc)]));
    // Bad limits and sizes are clear errors.
    for (flag, bad) in [
        ("--memory-limit", "lots"),
        ("--memory-limit", "0"),
        ("--size", "131"),
    ] {
        let mut args = vec!["build", &rhine, "--max-error", "1", "-o"];
        let out = s(&a);
        args.push(&out);
        args.extend([flag, bad]);
        let o = cbdam(&args);
        assert!(!o.status.success());
        assert!(stderr(&o).contains(flag), "{flag} {bad}: {}", stderr(&o));
    }
    let o = cbdam(&["build", &s(&raw), "--max-error", "1", "-o", &s(&a)]);
    assert!(stderr(&o).contains("--size"), "{}", stderr(&o));
}

/// The rows of every Markdown table in `md` whose header has a column named `key`, as maps
/// from column name to cell.
fn tables_with(md: &str, key: &str) -> Vec<Vec<std::collections::HashMap<String, String>>> {
    let cells = |l: &str| -> Vec<String> {
        l.trim()
            .trim_matches('|')
            .split('|')
            .map(|c| c.trim().to_string())
            .collect()
    };
    let lines: Vec<&str> = md.lines().collect();
    let mut out = Vec::new();
    let mut i = 0;
    while i < lines.len() {
        let head = cells(lines[i]);
        if lines[i].starts_with('|') && head.iter().any(|c| c == key) {
            let mut rows = Vec::new();
            i += 2; // header and |---| line
            while i < lines.len() && lines[i].starts_with('|') {
                rows.push(head.iter().cloned().zip(cells(lines[i])).collect());
                i += 1;
            }
            out.push(rows);
        } else {
            i += 1;
        }
    }
    out
}

#[test]
fn bench_report_quick() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("report");
    let o = cbdam(&[
        "bench",
        "report",
        "--quick",
        "--synthetic",
        "65",
        "--out",
        &s(&out),
        &data("jacksboro_mpl.tif"),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(md.contains("| CPU |") && md.contains("| commit |"), "{md}");
    // Rendering cost: the two bundled flights over the DEM at 1 and 4 px (the --quick
    // targets), measured by the real refinement loop.
    let cost = tables_with(&md, "triangles / frame (median)");
    assert_eq!(cost.len(), 1, "{md}");
    let cost = &cost[0];
    assert_eq!(cost.len(), 4, "{cost:?}");
    for flight in ["descent", "low_pass"] {
        let rows: Vec<_> = cost.iter().filter(|r| r["flight"] == flight).collect();
        assert_eq!(rows.len(), 2, "{cost:?}");
        let tris = |r: &std::collections::HashMap<String, String>| -> u64 {
            r["triangles, converged"].parse().unwrap()
        };
        // A looser target never needs more triangles once the cut has converged.
        assert!(tris(rows[1]) <= tris(rows[0]), "{rows:?}");
        for r in &rows {
            let target: f64 = r["target (px)"].parse().unwrap();
            let frames: usize = r["frames"].parse().unwrap();
            assert!(frames > 10, "{r:?}");
            let converged: f64 = r["error (px), converged"]
                .parse()
                .unwrap_or_else(|_| panic!("did not converge: {r:?}"));
            assert!(converged <= target, "{r:?}");
            let csv = out.join("replay").join(format!("{flight}_{target}px.csv"));
            let lines = std::fs::read_to_string(&csv).unwrap().lines().count();
            assert!(lines > frames, "{}: {lines} lines", csv.display());
        }
    }
    assert!(md.contains("(plots/render_cost.svg)"));
    let svg = std::fs::read_to_string(out.join("plots/render_cost.svg")).unwrap();
    assert!(svg.contains("<svg") && svg.contains("low_pass"));
    // One rate table per dataset (the DEM and the synthetic terrain), every default ε, every
    // verified max error within its ε.
    let tables = tables_with(&md, "cbdam max err (m)");
    assert_eq!(tables.len(), 2, "{md}");
    for rows in &tables {
        assert_eq!(rows.len(), 8, "{rows:?}");
        for r in rows {
            let eps: f64 = r["ε (m)"].parse().unwrap();
            let err: f64 = r["cbdam max err (m)"].parse().unwrap();
            let rms: f64 = r["cbdam RMS (m)"].parse().unwrap();
            let bps: f64 = r["cbdam file bits/sample"].parse().unwrap();
            assert!(err <= eps && rms <= err, "{r:?}");
            assert!(bps > 0.0 && bps < 64.0, "{r:?}");
        }
        // Looser tolerance, fewer bits.
        let first: f64 = rows[0]["cbdam file bits/sample"].parse().unwrap();
        let last: f64 = rows[7]["cbdam file bits/sample"].parse().unwrap();
        assert!(last < first, "{rows:?}");
    }
    assert_eq!(tables_with(&md, "cbdam decode").len(), 2);
    for plot in ["jacksboro_mpl.tif.svg", "synthetic_fractal_65.svg"] {
        let svg = std::fs::read_to_string(out.join("plots").join(plot)).unwrap();
        assert!(
            svg.contains("<svg") && svg.contains("cbdam (file)"),
            "{plot}"
        );
        assert!(md.contains(&format!("(plots/{plot})")), "{plot} not linked");
    }
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("results.json")).unwrap()).unwrap();
    assert_eq!(json["cbdam"].as_array().unwrap().len(), 16);
}

/// `--extra-levels auto` (the default) keeps one more level pair only where that gives the
/// smaller file: on the smooth lidar tile at 5 m, where the root field is most of the file, it
/// does; at 1 m, where the extra coarse records cost more than the roots save, it does not.
/// Either way the result is exactly one of the two fixed builds and verifies within ε.
#[test]
fn auto_extra_levels_keep_the_smaller_repository() {
    let dir = tempfile::tempdir().unwrap();
    let lidar = data("lidar1m_mn.tif");
    for (eps, coarser) in [("5", true), ("1", false)] {
        let build = |extra: &str| {
            let out = dir.path().join(format!("{eps}_{extra}.cbdam"));
            let o = cbdam(&[
                "build",
                &lidar,
                "-o",
                &s(&out),
                "--max-error",
                eps,
                "--quiet",
                "--extra-levels",
                extra,
            ]);
            assert!(o.status.success(), "{}", stderr(&o));
            std::fs::read(&out).unwrap()
        };
        let (auto, zero, one) = (build("auto"), build("0"), build("1"));
        assert_eq!(
            coarser,
            one.len() < zero.len(),
            "ε {eps}: {} vs {}",
            one.len(),
            zero.len()
        );
        assert_eq!(auto, if coarser { one } else { zero }, "ε {eps}");
        let k = |b: &[u8]| {
            Repository::from_bytes(b.to_vec())
                .unwrap()
                .params()
                .layout
                .k()
        };
        assert_eq!(k(&auto), k(&build("0")) + u32::from(coarser), "ε {eps}");
        let o = cbdam(&[
            "verify",
            &s(&dir.path().join(format!("{eps}_auto.cbdam"))),
            "--against",
            &lidar,
        ]);
        assert!(o.status.success(), "ε {eps}: {}", stderr(&o));
    }
    let o = cbdam(&[
        "build",
        &lidar,
        "-o",
        &s(&dir.path().join("x.cbdam")),
        "--max-error",
        "1",
        "--extra-levels",
        "lots",
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("neither `auto` nor a number"),
        "{}",
        stderr(&o)
    );
    let x = s(&dir.path().join("x.cbdam"));
    let o = cbdam(&[
        "build",
        &lidar,
        "-o",
        &x,
        "--max-error",
        "1",
        "--extra-levels",
        "3",
    ]);
    assert_eq!(o.status.code(), Some(2));
    let o = cbdam(&[
        "build",
        &lidar,
        &lidar,
        "-o",
        &x,
        "--max-error",
        "1",
        "--extra-levels",
        "1",
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("single-input builds"), "{}", stderr(&o));
    assert!(!dir.path().join("x.cbdam").exists());
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
    let o = cbdam(&[
        "build",
        &s(&asc),
        "-o",
        &s(&repo),
        "--max-error",
        "1",
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
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

/// `verify --against` a raw float32 file: it carries no size, so the repository's is used; a
/// file of another length is refused with both sizes named. (It used to fail on every raw
/// input, asking for a size `verify` has no option for.)
#[test]
fn verify_reads_a_raw_input_at_the_repositorys_size() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (40usize, 30usize);
    let values: Vec<f32> = (0..w * h)
        .map(|i| 250.0 + ((i % w) as f32 * 0.3).sin() * 20.0 + (i / w) as f32 * 0.5)
        .collect();
    let raw = dir.path().join("plane.f32");
    std::fs::write(
        &raw,
        values
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect::<Vec<u8>>(),
    )
    .unwrap();
    let repo = dir.path().join("plane.cbdam");
    let o = cbdam(&[
        "build",
        &s(&raw),
        "--size",
        "40x30",
        "-o",
        &s(&repo),
        "--max-error",
        "0.5",
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = cbdam(&["verify", &s(&repo), "--against", &s(&raw)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("OK"), "{}", stdout(&o));
    let short = dir.path().join("short.f32");
    std::fs::write(&short, &std::fs::read(&raw).unwrap()[..1000]).unwrap();
    let o = cbdam(&["verify", &s(&repo), "--against", &s(&short)]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains("1000 bytes") && stderr(&o).contains("40 x 30"),
        "{}",
        stderr(&o)
    );
}

/// An I/O error is printed once: the codec's, server's and flight's error messages include the
/// OS error, so it is no longer also their `source` (the chain printed it twice).
#[test]
fn io_errors_name_their_cause_once() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.tif");
    let out = dir.path().join("x.cbdam");
    let o = cbdam(&["build", &s(&missing), "-o", &s(&out), "--max-error", "1"]);
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(e.contains("missing.tif"), "{e}");
    assert_eq!(e.matches("No such file or directory").count(), 1, "{e}");
    let repo = dir.path().join("lidar.cbdam");
    build_quiet(&data("lidar1m_mn.tif"), &repo, "5");
    let flight = dir.path().join("no.json");
    let csv = dir.path().join("o.csv");
    let o = cbdam(&[
        "replay",
        &s(&repo),
        "--path",
        &s(&flight),
        "--out",
        &s(&csv),
    ]);
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(e.contains("reading the flight"), "{e}");
    assert_eq!(e.matches("No such file or directory").count(), 1, "{e}");
}
