//! `cbdam inspect` as a process.

use std::path::Path;
use std::process::Command;

use crate::util::*;

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

/// A planet repository (written through the codec: `build --planet` does not exist yet) is
/// described as one: the cube-sphere domain with its 6 faces, and its distinct lattice points
/// (6·S² + 2, shared edge points once) as its samples.
#[test]
fn inspect_names_a_planet_domain() {
    use cbdam_codec::hierarchy::{EncodeOptions, PlanetGrid, encode_planet};
    use cbdam_codec::quant::QuantPlan;
    let dir = tempfile::tempdir().unwrap();
    let (n, k) = (5usize, 2u32);
    // Heights from the canonical point: every face holding an edge point agrees.
    let planet = PlanetGrid::from_fn(n, k, |p| {
        Some(i32::from(p.face) * 100 + ((p.x * 7 + p.y * 3) % 50) as i32)
    })
    .unwrap();
    let plan = QuantPlan::new(1.0, Some(1.0), 0.0, 600.0).unwrap();
    let opts = EncodeOptions {
        n,
        ..EncodeOptions::default()
    };
    let encoded = encode_planet(&planet, plan.quantizer, &opts).unwrap();
    let path = dir.path().join("planet.cbdam");
    let bytes = cbdam_codec::repository::serialize(&encoded, &plan, None, None).unwrap();
    std::fs::write(&path, bytes).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_cbdam"))
        .args(["inspect", path.to_str().unwrap()])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(
        text.contains("domain          cube-sphere, 6 faces"),
        "{text}"
    );
    let o = Command::new(env!("CARGO_BIN_EXE_cbdam"))
        .args(["inspect", path.to_str().unwrap(), "--json"])
        .output()
        .unwrap();
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["domain"], "cube-sphere");
    assert_eq!(v["faces"], 6);
    let s = (n as u64 - 1) << k;
    assert_eq!(v["nodata_samples"], 0, "{v}");
    assert_eq!(v["samples"].as_u64(), Some(6 * s * s + 2), "{v}");
}

/// A hostile header whose checksums match but whose unit makes every height infinite is
/// refused by every command that opens it, naming the field, instead of being described
/// (`inspect`), written out as ±inf (`extract`) or drawn until the camera panics.
#[test]
fn a_crafted_header_with_infinite_heights_is_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let asc = dir.path().join("a.asc");
    super::write_asc(&asc, &vec![vec![10.0, 12.0, 15.0, 11.0, 9.0]; 4], None);
    let good = dir.path().join("good.cbdam");
    build_quiet(&s(&asc), &good, "0.5");
    let bytes = std::fs::read(&good).unwrap();
    let bad = dir.path().join("bad.cbdam");
    let crafted =
        cbdam_codec::repository::craft_header(&bytes, "unit", 1e308f64.to_bits()).unwrap();
    std::fs::write(&bad, crafted).unwrap();
    let tif = dir.path().join("x.tif");
    let (bad, tif_s) = (s(&bad), s(&tif));
    for args in [
        vec!["inspect", &bad],
        vec!["inspect", &bad, "--json"],
        vec!["extract", &bad, "-o", &tif_s],
    ] {
        let o = cbdam(&args);
        assert!(!o.status.success(), "{args:?} accepted it: {}", stdout(&o));
        assert!(
            stderr(&o).contains("height unit 1e308"),
            "{args:?}: {}",
            stderr(&o)
        );
        assert!(!stderr(&o).contains("panicked"), "{args:?}: {}", stderr(&o));
    }
    assert!(!tif.exists());
    // A server refuses to serve it, at startup, instead of handing it to clients.
    let o = cbdam_within(&["serve", &bad, "--addr", "127.0.0.1:0"], 60);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("height unit 1e308"), "{}", stderr(&o));
}

/// `cbdam inspect REPO` and `cbdam inspect REPO --json`, run in `dir`.
fn inspect_in(dir: &Path, repo: &str) -> [String; 2] {
    [vec![], vec!["--json"]].map(|extra| {
        let o = Command::new(env!("CARGO_BIN_EXE_cbdam"))
            .current_dir(dir)
            .arg("inspect")
            .arg(repo)
            .args(extra)
            .output()
            .unwrap();
        assert!(o.status.success(), "{repo}: {}", stderr(&o));
        stdout(&o)
    })
}

/// The text and the JSON of a plane, a nodata mask, a colour repository, a planet, an RMS bound
/// and a version-1 file are byte for byte what `inspect` printed before it became a report
/// struct (`tests/data/inspect/README.md` says how they were captured).
#[test]
fn inspect_prints_what_it_printed_before_the_report_struct() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let fixtures = root.join("tests/data/inspect");
    let cases = [
        ("plane", fixtures.clone(), "plane.cbdam"),
        ("nodata", fixtures.clone(), "nodata.cbdam"),
        ("colour", fixtures.clone(), "colour.cbdam"),
        ("planet", fixtures.clone(), "planet.cbdam"),
        ("rms", fixtures.clone(), "rms.cbdam"),
        (
            "v1_holes_n9",
            root.join("codec/tests/data/v1"),
            "holes_n9.cbdam",
        ),
    ];
    for (name, dir, repo) in cases {
        let [text, json] = inspect_in(&dir, repo);
        let expected =
            |ext: &str| std::fs::read_to_string(fixtures.join(format!("{name}.{ext}"))).unwrap();
        assert_eq!(text, expected("txt"), "{name}: text");
        assert_eq!(json, expected("json"), "{name}: --json");
    }
}

/// `inspect --digest`: one surface coded by every coder gives one digest (text and JSON agree),
/// and another surface (a looser bound) another.
#[test]
fn the_decoded_digest_is_the_surfaces_not_the_coders() {
    let dir = tempfile::tempdir().unwrap();
    let dem = data("jacksboro_mpl.tif");
    let digest_of = |coder: &str, eps: &str| -> String {
        let repo = dir.path().join(format!("{coder}-{eps}.cbdam"));
        let o = cbdam(&[
            "build",
            &dem,
            "-o",
            &s(&repo),
            "--max-error",
            eps,
            "--coder",
            coder,
            "--quiet",
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
        let text = String::from_utf8(cbdam(&["inspect", &s(&repo), "--digest"]).stdout).unwrap();
        let line = text
            .lines()
            .find(|l| l.starts_with("decoded"))
            .unwrap_or_else(|| panic!("no digest line: {text}"));
        let json: serde_json::Value =
            serde_json::from_slice(&cbdam(&["inspect", &s(&repo), "--digest", "--json"]).stdout)
                .unwrap();
        let d = &json["decoded_digest"];
        let hash = d["fnv1a64"].as_str().unwrap().to_string();
        assert!(line.contains(&hash), "{line} against {d}");
        assert!(d["diamonds"].as_u64().unwrap() > 1, "{d}");
        // Every diamond's N × N grid (N = 65 by default).
        assert_eq!(
            d["samples"].as_u64(),
            d["diamonds"].as_u64().map(|n| n * 65 * 65)
        );
        hash
    };
    let default = digest_of("adaptive-tokens", "1");
    for coder in [
        "adaptive",
        "elias-gamma",
        "fast-rice",
        "adaptive-grid",
        "adaptive-inband",
    ] {
        assert_eq!(digest_of(coder, "1"), default, "{coder}");
    }
    assert_ne!(digest_of("adaptive-tokens", "4"), default);
}
