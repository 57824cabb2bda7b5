//! The `cbdam` binary end to end: build → inspect → verify on real DEMs, bad inputs that must
//! fail cleanly without leaving files behind, and damaged repositories that `verify` must catch.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use cbdam_codec::repository::{Repository, Section};

fn cbdam(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_cbdam"))
        .args(args)
        .output()
        .expect("run cbdam")
}

fn data(name: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("data")
        .join(name)
        .to_string_lossy()
        .into_owned()
}

fn s(p: &Path) -> String {
    p.to_string_lossy().into_owned()
}

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Files in `dir`, to show that a failed build leaves nothing (not even a temporary).
fn listing(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    v.sort();
    v
}

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
    // Header and checksum table: 256 bytes plus 4 per non-empty record.
    let empty = v["empty_records"].as_u64().unwrap();
    assert_eq!(v["container_overhead_bytes"], 256 + 4 * (records - empty));
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
