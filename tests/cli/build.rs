//! `cbdam build` end to end: build → inspect → verify on real DEMs, progress and `--quiet`,
//! out-of-core and streamed builds, `--extra-levels auto`, georeferencing, block encoding and
//! resumed builds, `--rms-error`. What it refuses is in `build_refusals`.

use std::path::Path;
use std::process::Output;

use cbdam_codec::repository::Repository;

use super::write_asc;
use crate::util::*;

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

/// Builds Jacksboro at 1 m with the default coder and with `other`: `inspect` names each coder,
/// and both decode to the same heights (`extract`'s bytes).
fn decodes_to_what_the_default_coder_decodes(other: &str) {
    round_trip("jacksboro_mpl.tif", "1", &["--coder", other]);
    let dir = tempfile::tempdir().unwrap();
    let input = data("jacksboro_mpl.tif");
    let mut extracted = Vec::new();
    for coder in ["adaptive-tokens", other] {
        let repo = s(&dir.path().join(format!("{coder}.cbdam")));
        let o = cbdam(&[
            "build",
            &input,
            "-o",
            &repo,
            "--max-error",
            "1",
            "--coder",
            coder,
        ]);
        assert!(o.status.success(), "build {coder}: {}", stderr(&o));
        let o = cbdam(&["inspect", &repo]);
        assert!(
            stdout(&o).contains(&format!("{coder} coder")),
            "{}",
            stdout(&o)
        );
        let tif = s(&dir.path().join(format!("{coder}.tif")));
        let o = cbdam(&["extract", &repo, "-o", &tif, "--quiet"]);
        assert!(o.status.success(), "extract {coder}: {}", stderr(&o));
        extracted.push(std::fs::read(&tif).unwrap());
    }
    assert!(
        extracted[0] == extracted[1],
        "{other} and the default coder decode different heights"
    );
}

#[test]
fn adaptive_grid_decodes_to_what_the_default_coder_decodes() {
    // Sizes are not compared: on this tile at 1 m the grid coder's file is 0.25 % larger
    // (docs/RESULTS.md, "A coder whose contexts see the grid").
    decodes_to_what_the_default_coder_decodes("adaptive-grid");
}

#[test]
fn adaptive_inband_decodes_to_what_the_default_coder_decodes() {
    decodes_to_what_the_default_coder_decodes("adaptive-inband");
}

#[test]
fn fast_rice_decodes_to_what_the_default_coder_decodes() {
    decodes_to_what_the_default_coder_decodes("fast-rice");
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

#[test]
fn out_of_core_and_streamed_builds_give_identical_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let ok = |o: &Output| assert!(o.status.success(), "{}", stderr(o));
    // Bundled DEM with nodata: default memory limit vs a limit that forces the mapped field.
    let a = dir.path().join("a.cbdam");
    let b = dir.path().join("b.cbdam");
    let rhine = data("rhine_nodata.tif");
    // `--timings` names where the reconstruction and the lattice went: the limited builds must
    // have taken the other path, or the comparison compares a path with itself.
    let path_taken = |o: &Output| -> String {
        ok(o);
        let err = stderr(o);
        let line = err.lines().find(|l| l.starts_with("timings:"));
        line.unwrap_or_else(|| panic!("no timings in {err}"))
            .to_owned()
    };
    let in_memory = |t: &str| t.ends_with("reconstruction in memory");
    let out_of_core =
        |t: &str| t.contains("reconstruction in mapped file; lattice in mapped files");
    for (out, extra) in [(&a, None), (&b, Some("1M"))] {
        let mut args = vec!["build", &rhine, "--max-error", "1", "-o"];
        let out = s(out);
        args.push(&out);
        args.extend(["--quiet", "--timings"]);
        if let Some(limit) = extra {
            args.extend(["--memory-limit", limit]);
        }
        let t = path_taken(&cbdam(&args));
        match extra {
            None => assert!(in_memory(&t), "{t}"),
            Some(_) => assert!(out_of_core(&t), "{t}"),
        }
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
    let t = path_taken(&cbdam(&[
        "build",
        &s(&raw),
        "--size",
        "131x77",
        "--max-error",
        "0.5",
        "-o",
        &s(&c),
        "--quiet",
        "--timings",
    ]));
    assert!(in_memory(&t), "{t}");
    let t = path_taken(&cbdam(&[
        "build",
        &s(&raw),
        "--size",
        "131x77",
        "--max-error",
        "0.5",
        "-o",
        &s(&d),
        "--quiet",
        "--timings",
        "--memory-limit",
        "4K",
    ]));
    assert!(out_of_core(&t), "{t}");
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
                .head()
                .params()
                .layout()
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

/// Asserts that a command succeeded, printing its stderr otherwise.
fn succeeds(o: &Output) {
    assert!(o.status.success(), "{}", stderr(o));
}

/// `--bounds` and `--crs` georeference a raw float32 input (which carries none): the repository
/// records the CRS and the cell size the edges give; an input with its own georeferencing, a
/// tile set, a malformed box or a missing partner flag are refused, naming the flag.
#[test]
fn bounds_and_crs_georeference_a_raw_input() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (40usize, 30usize);
    let raw = dir.path().join("t.f32");
    let bytes: Vec<u8> = (0..w * h)
        .flat_map(|i| (100.0f32 + (i % 7) as f32).to_le_bytes())
        .collect();
    std::fs::write(&raw, bytes).unwrap();
    let out = dir.path().join("t.cbdam");
    let build = |extra: &[&str]| {
        let mut args = vec!["build", raw.to_str().unwrap(), "--size", "40x30"];
        args.extend(["--max-error", "0.5", "-o", out.to_str().unwrap(), "--quiet"]);
        args.extend(extra);
        cbdam(&args)
    };
    succeeds(&build(&["--bounds", "-10,40,-6,43", "--crs", "EPSG:4326"]));
    let o = cbdam(&["inspect", &s(&out), "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let g = &v["georef"];
    assert_eq!(g["epsg"], 4326);
    // 4° over 40 columns and 3° over 30 rows: 0.1° cells from the north-west corner.
    assert!((g["pixel_x"].as_f64().unwrap() - 0.1).abs() < 1e-12, "{g}");
    assert!((g["pixel_y"].as_f64().unwrap() - 0.1).abs() < 1e-12, "{g}");
    assert_eq!(
        (g["origin_x"].as_f64(), g["origin_y"].as_f64()),
        (Some(-10.0), Some(43.0))
    );
    for (extra, says) in [
        (vec!["--bounds", "1,2,3", "--crs", "EPSG:4326"], "--bounds"),
        (vec!["--bounds", "0,0,1,1", "--crs", "WGS84"], "--crs"),
        (vec!["--bounds", "0,0,1,1"], "--crs"),
    ] {
        let o = build(&extra);
        assert!(!o.status.success(), "{extra:?} accepted");
        assert!(stderr(&o).contains(says), "{extra:?}: {}", stderr(&o));
    }
    let srtm = data("srtm3_demcompare.tif");
    let o = cbdam(&[
        "build",
        &srtm,
        "--max-error",
        "1",
        "-o",
        &s(&out),
        "--bounds",
        "0,0,1,1",
        "--crs",
        "EPSG:4326",
    ]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("carries its own georeferencing"),
        "{}",
        stderr(&o)
    );
}

/// The bundled global DEM is georeferenced (EPSG:4326, PixelIsPoint, lon 0 … 359.917°, lat
/// 90 … −90°, 5′), so that it builds on the globe's scale instead of as a 1 m grid.
#[test]
fn etopo5_carries_its_georeferencing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("e.cbdam");
    succeeds(&cbdam(&[
        "build",
        &data("etopo5_global.tif"),
        "--max-error",
        "50",
        "-o",
        &s(&out),
        "--quiet",
    ]));
    let o = cbdam(&["inspect", &s(&out), "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let g = &v["georef"];
    assert_eq!(g["epsg"], 4326, "{g}");
    assert_eq!(g["pixel_is"], "point", "{g}");
    assert_eq!(
        (g["origin_x"].as_f64(), g["origin_y"].as_f64()),
        (Some(0.0), Some(90.0))
    );
    let step = g["pixel_x"].as_f64().unwrap();
    assert!((step - 1.0 / 12.0).abs() < 1e-15, "{g}");
    // The last column is 359.917°E and the last row the south pole.
    assert!((step * 4319.0 - 359.916_666_666_666_7).abs() < 1e-9);
    assert!((90.0 - g["pixel_y"].as_f64().unwrap() * 2160.0 + 90.0).abs() < 1e-9);
}

/// Under a memory limit that the whole reconstruction field does not fit but blocks do, the
/// encoder works block by block (`--timings` says so) and writes the same bytes; under one that
/// nothing fits, the field goes to a mapped file, again with the same bytes.
#[test]
fn block_encoding_under_a_memory_limit_writes_the_same_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let rhine = data("rhine_nodata.tif");
    let build = |limit: &str| {
        let out = dir.path().join(format!("{limit}.cbdam"));
        let o = cbdam(&[
            "build",
            &rhine,
            "--max-error",
            "1",
            "-o",
            &s(&out),
            "--quiet",
            "--timings",
            "--memory-limit",
            limit,
        ]);
        succeeds(&o);
        (std::fs::read(&out).unwrap(), stderr(&o))
    };
    // 997 × 682 samples: the grid takes 3.4 MB, the whole field 4.2 MB, blocks of 256 2.6 MB.
    let (whole, said) = build("1G");
    assert!(
        said.contains("reconstruction in memory") && !said.contains("blocks"),
        "{said}"
    );
    let (blocks, said) = build("6M");
    assert!(said.contains("blocks of 256"), "{said}");
    assert!(blocks == whole, "block encoding changed the repository");
    let (mapped, said) = build("4K");
    assert!(said.contains("mapped file"), "{said}");
    assert!(mapped == whole, "the mapped field changed the repository");
}

/// A large build keeps a journal of finished blocks: killed (SIGKILL) before any block, after
/// one and after several, it resumes when run again and writes the same bytes as a build that
/// was never interrupted; no partial output is ever left under the output's name, and the
/// journal is gone once the repository is written. Run again with another tolerance, or with a
/// patch of the input changed and its modification time restored, it starts over and says why.
#[test]
fn a_killed_build_resumes_and_writes_the_same_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let raw = dir.path().join("t.f32");
    // 4097² samples: at the size from which builds keep a journal (2^24).
    succeeds(&cbdam(&["synth", "--size", "4097", "-o", &s(&raw)]));
    let args = |out: &Path, eps: &str| -> Vec<String> {
        [
            "build",
            &s(&raw),
            "--size",
            "4097x4097",
            "--max-error",
            eps,
            "-o",
            &s(out),
        ]
        .map(String::from)
        .to_vec()
    };
    let whole = dir.path().join("whole.cbdam");
    succeeds(&cbdam(
        &args(&whole, "1")
            .iter()
            .map(String::as_str)
            .collect::<Vec<_>>(),
    ));
    let expected = std::fs::read(&whole).unwrap();
    let journal = dir.path().join("killed.cbdam.journal");
    let blocks_done = || crate::util::journal_blocks(&journal);
    let out = dir.path().join("killed.cbdam");
    let kill_after_blocks =
        |n: usize| crate::util::kill_after_blocks(&args(&out, "1"), &journal, n);
    for n in [0, 1, 6] {
        kill_after_blocks(n);
        assert!(!out.exists(), "a killed build left {}", out.display());
    }
    let before = blocks_done();
    assert!(before >= 6, "only {before} blocks kept");
    let o = cbdam(
        &args(&out, "1")
            .iter()
            .map(String::as_str)
            .collect::<Vec<_>>(),
    );
    succeeds(&o);
    assert!(
        stderr(&o).contains(&format!("resuming: {before} blocks")),
        "{}",
        stderr(&o)
    );
    assert!(
        std::fs::read(&out).unwrap() == expected,
        "the resumed build differs"
    );
    assert!(!journal.exists(), "the journal outlived the build");
    // Killed again after some blocks, a patch of the input raised by 50 m and its modification
    // time restored: the build starts over, naming the input, and its output verifies.
    kill_after_blocks(2);
    let mtime = std::fs::metadata(&raw).unwrap().modified().unwrap();
    let mut samples = std::fs::read(&raw).unwrap();
    for y in 1000..1300 {
        for x in 1000..1300 {
            let i = (y * 4097 + x) * 4;
            let z = f32::from_le_bytes(samples[i..i + 4].try_into().unwrap()) + 50.0;
            samples[i..i + 4].copy_from_slice(&z.to_le_bytes());
        }
    }
    std::fs::write(&raw, &samples).unwrap();
    let file = std::fs::File::options().write(true).open(&raw).unwrap();
    file.set_modified(mtime).unwrap();
    drop(file);
    let o = cbdam(
        &args(&out, "1")
            .iter()
            .map(String::as_str)
            .collect::<Vec<_>>(),
    );
    succeeds(&o);
    assert!(
        stderr(&o).contains("starting over") && stderr(&o).contains(&format!("input: {}", s(&raw))),
        "{}",
        stderr(&o)
    );
    succeeds(&cbdam(&["verify", &s(&out), "--against", &s(&raw)]));
    // Killed again after some blocks, then run with another tolerance: it starts over.
    kill_after_blocks(2);
    let o = cbdam(
        &args(&out, "2")
            .iter()
            .map(String::as_str)
            .collect::<Vec<_>>(),
    );
    succeeds(&o);
    assert!(
        stderr(&o).contains("starting over") && stderr(&o).contains("max_error: 1 → 2"),
        "{}",
        stderr(&o)
    );
}

/// `--rms-error` end to end: without `--max-error` it builds, the summary, `inspect` (text and
/// JSON) and `verify` state the RMS error, and the figures agree with the bound.
#[test]
fn an_rms_error_build_states_its_bound_everywhere() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("r.cbdam");
    let input = data("lidar1m_mn.tif");
    let o = cbdam(&["build", &input, "-o", &s(&out), "--rms-error", "0.25"]);
    succeeds(&o);
    assert!(stdout(&o).contains("(bound 0.25 m)"), "{}", stdout(&o));
    let o = cbdam(&["inspect", &s(&out)]);
    succeeds(&o);
    assert!(
        stdout(&o).contains("rms error       0.25 m bound"),
        "{}",
        stdout(&o)
    );
    let o = cbdam(&["inspect", "--json", &s(&out)]);
    succeeds(&o);
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    assert_eq!(v["rms_error_bound_m"], 0.25);
    let measured = v["rms_error_measured_m"].as_f64().unwrap();
    assert!(measured > 0.0 && measured <= 0.25, "{measured}");
    let o = cbdam(&["verify", &s(&out), "--against", &input]);
    succeeds(&o);
    assert!(stdout(&o).contains("RMS error") && stdout(&o).contains("(bound 0.25 m)"));
    // Neither bound given is refused by clap, naming both.
    let o = cbdam(&["build", &input, "-o", &s(&out)]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("--max-error"), "{}", stderr(&o));
    // Bad bounds and unsupported combinations are refused by name.
    for extra in [
        &["--rms-error", "0"][..],
        &["--rms-error", "1", "--colour"][..],
    ] {
        let mut args = vec!["build", &input, "-o", "x.cbdam"];
        args.extend_from_slice(extra);
        let o = cbdam(&args);
        assert!(!o.status.success(), "{extra:?}");
        assert!(
            stderr(&o).contains("--rms-error"),
            "{extra:?}: {}",
            stderr(&o)
        );
    }
}
