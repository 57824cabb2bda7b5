//! A planet of many SRTM `.hgt` tiles built out of core (`docs/PLANET.md`, "Out of core"): the
//! tiles read when the resampling asks for them through a bounded cache, so the build's peak
//! memory does not grow with their number, and the bytes do not depend on what the cache kept.

use std::path::Path;

use crate::util::{cbdam, data, s, stderr};

/// SRTM 3″ tiles: 1201 samples a side, one degree plus the shared edge.
const SIDE: usize = 1201;

/// A relief with detail at every scale the tiles resolve (deterministic, from latitude and
/// longitude alone, so tiles agree on their shared edges), and voids in round patches.
pub(super) fn height(lat: f64, lon: f64) -> i16 {
    let wave = 800.0 * (lat * 1.3).sin() * (lon * 0.9).cos()
        + 150.0 * (lat * 23.0).sin() * (lon * 31.0).cos()
        + 20.0 * (lat * 410.0 + lon * 370.0).sin();
    let hole = ((lat * 4.0).fract() - 0.5).hypot((lon * 4.0).fract() - 0.5) < 0.05;
    if hole {
        i16::MIN
    } else {
        (1200.0 + wave).round() as i16
    }
}

/// Writes `N{lat}E{lon}.hgt` for each cell (south-west corners) into `dir`.
fn write_tiles(dir: &Path, cells: &[(i32, i32)]) {
    std::fs::create_dir_all(dir).unwrap();
    for &(lat, lon) in cells {
        let mut bytes = Vec::with_capacity(SIDE * SIDE * 2);
        for r in 0..SIDE {
            for c in 0..SIDE {
                let (la, lo) = (
                    f64::from(lat + 1) - r as f64 / (SIDE - 1) as f64,
                    f64::from(lon) + c as f64 / (SIDE - 1) as f64,
                );
                bytes.extend_from_slice(&height(la, lo).to_be_bytes());
            }
        }
        std::fs::write(dir.join(format!("N{lat:02}E{lon:03}.hgt")), bytes).unwrap();
    }
}

/// A block of `rows` × `cols` one-degree cells from 40° N 10° E.
pub(super) fn block(rows: i32, cols: i32) -> Vec<(i32, i32)> {
    (0..rows)
        .flat_map(|r| (0..cols).map(move |c| (40 + r, 10 + c)))
        .collect()
}

/// `cbdam build DIR --planet …` under GNU time: the peak resident memory of the build itself
/// (the child's `ru_maxrss`, bytes), how many times it read an input (its `--timings` line) and
/// the repository's bytes.
fn build(dir: &Path, out: &Path, extra: &[&str]) -> (u64, u64, Vec<u8>) {
    let (dir, out_s) = (s(dir), s(out));
    let o = std::process::Command::new("/usr/bin/time")
        .args(["-f", "peak-rss-kib %M", env!("CARGO_BIN_EXE_cbdam")])
        .args(["build", &dir, "--planet", "-o", &out_s, "--max-error", "2"])
        .args(["--timings", "--quiet"])
        .args(extra)
        .output()
        .expect("run /usr/bin/time (GNU time)");
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(o.status.success(), "{err}");
    let after = |key: &str| -> u64 {
        let rest = &err[err
            .find(key)
            .unwrap_or_else(|| panic!("no {key:?} in {err}"))
            + key.len()..];
        let digits: String = rest.chars().take_while(char::is_ascii_digit).collect();
        digits.parse().unwrap()
    };
    let rss = after("peak-rss-kib ") * 1024;
    let reads = after("inputs read from their files ");
    (rss, reads, std::fs::read(out).unwrap())
}

/// The peak memory of a planet build does not grow with the number of its tiles: 8 and 32
/// SRTM tiles (23 and 92 MB of samples at 2 bytes each, as the build held them whole) on the
/// same lattice (`--planet-level 2`, the tiles area-averaged, so the lattice does not grow
/// with them) under a `--memory-limit` that leaves the tiles' cache 8 MiB. Holding the tiles
/// would add 69 MB; the bound is a quarter of that. The cache is used: with it the inputs are
/// read several times each (height range, resampling, resampling error), and the bytes are
/// those of the build whose cache kept every input (read once each).
#[test]
fn a_planet_of_many_tiles_peaks_at_the_same_memory_as_one_of_few() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let few_cells = block(2, 4);
    let many_cells = block(4, 8);
    write_tiles(&d.join("few"), &few_cells);
    write_tiles(&d.join("many"), &many_cells);
    let limited = ["--planet-level", "2", "--memory-limit", "64M"];
    let (few, few_reads, _) = build(&d.join("few"), &d.join("few.cbdam"), &limited);
    let (many, many_reads, limited_bytes) = build(&d.join("many"), &d.join("m.cbdam"), &limited);
    let (_, whole_reads, whole_bytes) = build(
        &d.join("many"),
        &d.join("whole.cbdam"),
        &["--planet-level", "2", "--memory-limit", "8G"],
    );
    let tile_bytes = (SIDE * SIDE * 2) as u64;
    let grown = (many_cells.len() - few_cells.len()) as u64 * tile_bytes;
    let mib = |b: u64| b as f64 / f64::from(1 << 20);
    eprintln!(
        "peak RSS: {} tiles {:.1} MiB ({few_reads} reads), {} tiles {:.1} MiB ({many_reads} \
         reads); holding the {} more tiles would add {:.1} MiB",
        few_cells.len(),
        mib(few),
        many_cells.len(),
        mib(many),
        many_cells.len() - few_cells.len(),
        mib(grown)
    );
    assert!(
        many < few + grown / 4,
        "peak RSS grew from {:.1} MiB to {:.1} MiB",
        mib(few),
        mib(many)
    );
    assert_eq!(
        whole_reads,
        many_cells.len() as u64,
        "a cache holding all reads each once"
    );
    assert!(
        many_reads >= 2 * many_cells.len() as u64,
        "the 8 MiB cache read the 32 tiles only {many_reads} times"
    );
    assert!(
        limited_bytes == whole_bytes,
        "the build whose cache let inputs go wrote other bytes"
    );
}

/// A planet whose lattice's tiles hold several times `--memory-limit` (at 8 bytes a point:
/// height, validity, class and winning input, what holding them costs at the least) builds at
/// its finest input's level, K = 11 for 3″, with the build's peak resident memory (the child's
/// own `ru_maxrss`) within half over the limit: 36 small 3″ insets a degree apart, each making
/// the lattice tiles around it hold every point. Measured: 45.6 M points held (348 MiB at 8 B,
/// 3.6× the limit), peak 131.5 MiB under `--memory-limit 96M` — the issue's 10× and "about the
/// limit" are not reached: each block holds its tile and its neighbours whole (≈ 55 MB).
/// Ignored in CI: about 3 minutes on 2 loaded cores (`--ignored` runs it).
#[test]
#[ignore = "about 3 minutes; run with --ignored"]
fn a_planet_lattice_several_times_the_memory_limit_builds_at_its_inputs_level() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path().join("insets");
    write_insets_a_degree_apart(&d);
    let limit: u64 = 96 << 20;
    let out = tmp.path().join("p.cbdam");
    let (dir, out_s) = (s(&d), s(&out));
    let o = std::process::Command::new("/usr/bin/time")
        .args(["-f", "peak-rss-kib %M", env!("CARGO_BIN_EXE_cbdam")])
        .args(["build", &dir, "--planet", "-o", &out_s, "--max-error", "2"])
        .args(["--memory-limit", "96M"])
        .output()
        .expect("run /usr/bin/time (GNU time)");
    let (text, err) = (
        String::from_utf8_lossy(&o.stdout).to_string(),
        String::from_utf8_lossy(&o.stderr).to_string(),
    );
    assert!(o.status.success(), "{err}");
    assert!(text.contains("K = 11"), "{text}");
    let number_after = |s: &str, key: &str| -> u64 {
        let at = s.find(key).unwrap_or_else(|| panic!("no {key:?} in {s}")) + key.len();
        let digits: String = s[at..].chars().take_while(char::is_ascii_digit).collect();
        digits.parse().unwrap()
    };
    let rss = number_after(&err, "peak-rss-kib ") * 1024;
    let held = number_after(&text, "the build held ");
    let mib = |b: u64| b as f64 / f64::from(1 << 20);
    eprintln!(
        "{held} lattice points held ({:.0} MiB at 8 B), peak RSS {:.1} MiB, limit {:.0} MiB",
        mib(8 * held),
        mib(rss),
        mib(limit)
    );
    assert!(8 * held >= 3 * limit, "only {held} lattice points held");
    assert!(
        rss <= limit + limit / 2,
        "peak RSS {:.1} MiB over the {:.0} MiB limit",
        mib(rss),
        mib(limit)
    );
}

/// A `--memory-limit` under what a planet build holds whatever the limit (its floor: the
/// program, the cube map's and the lattice tiles' tables, the spills' in-memory parts, each
/// worker's tile and input) is said before the build, naming the minimum in MiB, and the build's
/// own peak (the child's `ru_maxrss`) stays within a tenth over that minimum; at a limit over
/// the minimum nothing is said and the peak stays within a tenth over the limit. One SRTM tile
/// at its own level (K = 11: 98 304 lattice tiles), under 16M and then 1.25 × the minimum.
/// Before (main `eb637ec`) nothing was said: the limit only sized the caches and blocks, and
/// the floor came on top of it.
#[test]
fn a_limit_under_the_planet_s_minimum_is_said_and_the_peak_stays_near_it() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    write_tiles(&d.join("one"), &block(1, 1));
    let run = |limit: &str| {
        let o = std::process::Command::new("/usr/bin/time")
            .args(["-f", "peak-rss-kib %M", env!("CARGO_BIN_EXE_cbdam")])
            .args(["build", &s(&d.join("one")), "--planet", "--max-error", "2"])
            .args([
                "--quiet",
                "--memory-limit",
                limit,
                "-o",
                &s(&d.join("p.cbdam")),
            ])
            .output()
            .expect("run /usr/bin/time (GNU time)");
        let err = String::from_utf8_lossy(&o.stderr).to_string();
        assert!(o.status.success(), "{err}");
        let after = |key: &str| -> Option<u64> {
            let at = err.find(key)? + key.len();
            let digits: String = err[at..].chars().take_while(char::is_ascii_digit).collect();
            digits.parse().ok()
        };
        let minimum = after("under this planet's minimum of about ").map(|m| m << 20);
        let rss = after("peak-rss-kib ").expect("GNU time's peak") * 1024;
        (minimum, rss, err)
    };
    let mib = |b: u64| b as f64 / f64::from(1 << 20);
    let (minimum, rss, err) = run("16M");
    let minimum = minimum.unwrap_or_else(|| panic!("no minimum named under 16M: {err}"));
    assert!(err.contains("warning: --memory-limit 16 MiB"), "{err}");
    eprintln!(
        "16M: minimum {:.0} MiB, peak {:.1} MiB",
        mib(minimum),
        mib(rss)
    );
    assert!(
        rss <= minimum + minimum / 10,
        "peak {:.1} MiB over the {:.0} MiB minimum named",
        mib(rss),
        mib(minimum)
    );
    let over = minimum + minimum / 4;
    let (said, rss, err) = run(&format!("{}M", over >> 20));
    assert_eq!(said, None, "a limit over the minimum: {err}");
    eprintln!("{:.0}M: peak {:.1} MiB", mib(over), mib(rss));
    assert!(rss <= over + over / 10, "peak {:.1} MiB", mib(rss));
}

/// A tile cut short is refused by name, and nothing is left at `-o`.
#[test]
fn a_truncated_tile_is_named() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    write_tiles(&d.join("t"), &block(1, 2));
    let bad = d.join("t").join("N40E011.hgt");
    std::fs::write(&bad, vec![0u8; 1000]).unwrap();
    let out = d.join("p.cbdam");
    let o = cbdam(&[
        "build",
        &s(&d.join("t")),
        "--planet",
        "-o",
        &s(&out),
        "--max-error",
        "2",
        "--planet-level",
        "2",
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("N40E011.hgt"), "{}", stderr(&o));
    assert!(!out.exists());
}

/// `synth --earth` writes SRTM's tiles: named by their south-west corner, 1201² big-endian
/// samples, neighbours equal on their shared column, only land cells, and as rough as the
/// bundled SRTM tile where it lies (RMS differences at 3″ and 48″, measured here on both);
/// `--dry-run` counts them and writes nothing.
#[test]
fn synth_earth_writes_srtm_tiles_as_rough_as_the_real_one() {
    use cbdam_builder::earth::Roughness;
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("earth");
    let (etopo, srtm) = (data("etopo5_global.tif"), data("srtm3_demcompare.tif"));
    let base = ["synth", "--etopo", &etopo, "--srtm", &srtm, "--earth"];
    let mut args = base.to_vec();
    let d = s(&dir);
    args.extend([d.as_str(), "--bbox", "40,39,42,40", "--cells", "2"]);
    let o = cbdam(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let read = |name: &str| -> Vec<Option<f64>> {
        let b = std::fs::read(dir.join(name)).unwrap();
        assert_eq!(b.len(), SIDE * SIDE * 2, "{name}");
        b.chunks_exact(2)
            .map(|c| i16::from_be_bytes([c[0], c[1]]))
            .map(|v| (v != i16::MIN).then_some(f64::from(v)))
            .collect()
    };
    let mut names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(names, ["N39E040.hgt", "N39E041.hgt"]);
    let (west, east) = (read("N39E040.hgt"), read("N39E041.hgt"));
    for r in 0..SIDE {
        assert_eq!(west[r * SIDE + SIDE - 1], east[r * SIDE], "row {r}");
    }
    // The real tile: 1000² samples from 40° N 40° E, inside N39E040.
    let real = cbdam_builder::input::read_dem(
        Path::new(&srtm),
        &cbdam_builder::input::ReadOptions::default(),
    )
    .unwrap();
    let real: Vec<Option<f64>> = real.values.iter().map(|&v| Some(v)).collect();
    let synthetic: Vec<Option<f64>> = (0..1000)
        .flat_map(|r| west[r * SIDE..r * SIDE + 1000].to_vec())
        .collect();
    let (a, b) = (Roughness::of(&real, 1000), Roughness::of(&synthetic, 1000));
    eprintln!("real {a:?}, synthetic {b:?}");
    for (x, y) in [(a.lag1, b.lag1), (a.lag16, b.lag16)] {
        assert!((y / x - 1.0).abs() < 0.15, "real {a:?}, synthetic {b:?}");
    }
    // The South Atlantic has no land; an existing tile is not overwritten.
    let mut args = base.to_vec();
    let sea = s(&tmp.path().join("sea"));
    args.extend([sea.as_str(), "--bbox", "-30,-31,-29,-30"]);
    let o = cbdam(&args);
    assert!(
        !o.status.success() && stderr(&o).contains("no land cell"),
        "{}",
        stderr(&o)
    );
    let mut args = base.to_vec();
    args.extend([d.as_str(), "--bbox", "40,39,41,40"]);
    let o = cbdam(&args);
    assert!(
        !o.status.success() && stderr(&o).contains("N39E040.hgt exists"),
        "{}",
        stderr(&o)
    );
    // A dry run counts the tiles of a box and writes nothing.
    let mut args = base.to_vec();
    let dry = s(&tmp.path().join("dry"));
    args.extend([dry.as_str(), "--bbox", "40,39,42,40", "--dry-run"]);
    let o = cbdam(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let said = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(said.starts_with("2 tiles of 1201²"), "{said}");
    assert!(!tmp.path().join("dry").exists());
}

/// A planet over a global input (the bundled ETOPO5, every lattice tile at its stride) and 4
/// synthetic SRTM tiles, under `--memory-limit 256M`: measuring the global input's resampling
/// error a band of rows at a time, with the apex and blocks let go, sets no new peak (the
/// peak after each step, `--timings`), and the build's own peak (GNU time's `ru_maxrss` of the
/// child) stays under 540 MiB. Measured: 472 MiB for 9 tiles, where holding every tile the
/// global input covers peaked at 674 MiB; what is left is the apex (the whole planet at
/// ETOPO5's resolution, and two levels of its refinements). Ignored in CI: about 2 minutes.
/// It does not single out the banded measurement: with the whole-tile measurement put back
/// (a fault tried on 2026-12-07), the global input's resampling error stays under the apex's
/// peak on this planet and the test passes. It checks that the last step sets no new peak, but
/// has not been seen to fail on one.
#[test]
#[ignore = "about 2 minutes; run with --ignored"]
fn a_global_inputs_resampling_error_sets_no_new_peak() {
    let tmp = tempfile::tempdir().unwrap();
    let earth = s(&tmp.path().join("earth"));
    let etopo = data("etopo5_global.tif");
    synth_earth(&etopo, &earth, "6,44,8,46");
    let out = s(&tmp.path().join("p.cbdam"));
    let o = std::process::Command::new("/usr/bin/time")
        .args(["-f", "peak-rss-kib %M", env!("CARGO_BIN_EXE_cbdam")])
        .args([
            "build",
            &earth,
            &etopo,
            "--planet",
            "-o",
            &out,
            "--max-error",
            "16",
        ])
        .args(["--memory-limit", "256M", "--timings"])
        .output()
        .expect("run /usr/bin/time (GNU time)");
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(o.status.success(), "{err}");
    let mib_after = |text: &str, key: &str| -> f64 {
        let at = text
            .find(key)
            .unwrap_or_else(|| panic!("no {key:?} in {err}"))
            + key.len();
        let digits: String = text[at..]
            .chars()
            .take_while(|c| c.is_ascii_digit() || *c == '.')
            .collect();
        digits.parse().unwrap()
    };
    let rss = mib_after(&err, "peak-rss-kib ") / 1024.0;
    let peaks = err
        .lines()
        .find(|l| l.starts_with("peak resident memory after each step"))
        .unwrap_or_else(|| panic!("no peaks in {err}"));
    let (blocks, resampling) = (
        mib_after(peaks, ", blocks "),
        mib_after(peaks, ", resampling error "),
    );
    eprintln!(
        "peak RSS {rss:.1} MiB; after the blocks {blocks}, the resampling error {resampling}"
    );
    assert!(
        resampling <= blocks + 8.0,
        "the resampling error raised the peak from {blocks} to {resampling} MiB"
    );
    assert!(rss <= 540.0, "peak RSS {rss:.1} MiB");
}

/// The apex of a planet over a global input (the bundled ETOPO5: every lattice tile at its
/// stride, 28 M points over the cube at K = 11) and one synthetic SRTM tile, under
/// `--memory-limit 64M`, adds at most APEX_BOUND_MIB to the peak resident memory the outline
/// set (`--timings`' peak after each step, the build's own `ru_maxrss`): the apex's levels go
/// in runs of tiles within a quarter of the limit, and their refinements to a temporary file.
/// Measured on the 9-tile e9 planet (docs/RESULTS.md, "The apex out of core"): the apex added
/// 176 MiB under 64M; held whole (the view of every tile and its last two levels' refinements in
/// memory, main before helper apex7) it added 321 MiB. The bound sits between. Run once on
/// 2026-12-07 (helper apex8): passed, the apex took the peak from 102.5 to 199.4 MiB; it has not
/// been seen to fail with the budget ignored. Ignored in CI: about 2 minutes (196 s loaded).
#[test]
#[ignore = "about 2 minutes; run with --ignored"]
fn the_apex_of_a_global_input_stays_within_a_bound_of_the_limit() {
    const APEX_BOUND_MIB: f64 = 240.0;
    let tmp = tempfile::tempdir().unwrap();
    let earth = s(&tmp.path().join("earth"));
    let etopo = data("etopo5_global.tif");
    synth_earth(&etopo, &earth, "6,44,7,45");
    let out = s(&tmp.path().join("p.cbdam"));
    let o = cbdam(&[
        "build",
        &earth,
        &etopo,
        "--planet",
        "-o",
        &out,
        "--max-error",
        "16",
        "--memory-limit",
        "64M",
        "--timings",
    ]);
    let err = stderr(&o);
    assert!(o.status.success(), "{err}");
    let peaks = err
        .lines()
        .find(|l| l.starts_with("peak resident memory after each step"))
        .unwrap_or_else(|| panic!("no peaks in {err}"));
    let mib_after = |key: &str| -> f64 {
        let at = peaks
            .find(key)
            .unwrap_or_else(|| panic!("no {key:?} in {peaks}"))
            + key.len();
        let digits: String = peaks[at..]
            .chars()
            .take_while(|c| c.is_ascii_digit() || *c == '.')
            .collect();
        digits.parse().unwrap()
    };
    let (outline, apex) = (mib_after(": outline "), mib_after(", apex "));
    eprintln!("peak after the outline {outline} MiB, after the apex {apex} MiB");
    assert!(
        apex <= outline + APEX_BOUND_MIB,
        "the apex raised the peak from {outline} to {apex} MiB"
    );
}

/// Writes `cbdam synth --earth` SRTM-like tiles over ETOPO5 for the cells of `bbox` into `earth`.
fn synth_earth(etopo: &str, earth: &str, bbox: &str) {
    let o = cbdam(&["synth", "--etopo", etopo, "--earth", earth, "--bbox", bbox]);
    assert!(o.status.success(), "{}", stderr(&o));
}

/// 36 small 3″ insets (8 × 8 samples) a degree apart, in `d` (created): each makes the
/// lattice tiles around it hold every point at K = 11.
pub(super) fn write_insets_a_degree_apart(d: &Path) {
    use cbdam_builder::write::{Raster, write_geotiff};
    use cbdam_codec::repository::GeoRef;
    std::fs::create_dir_all(d).unwrap();
    let pixel = 1.0 / 1200.0;
    for (lat, lon) in block(6, 6) {
        let (lat0, lon0) = (f64::from(lat) + 0.5, f64::from(lon) + 0.5);
        let r = Raster {
            width: 8,
            height: 8,
            values: (0..64)
                .map(|i| {
                    let (c, r) = ((i % 8) as f64, (i / 8) as f64);
                    f64::from(height(lat0 - r * pixel, lon0 + c * pixel))
                })
                .collect(),
            georef: Some(GeoRef {
                epsg: Some(4326),
                origin_x: lon0,
                origin_y: lat0,
                pixel_x: pixel,
                pixel_y: pixel,
                pixel_is_area: false,
                wkt: None,
            }),
        };
        let f = std::fs::File::create(d.join(format!("i{lat}_{lon}.tif"))).unwrap();
        write_geotiff(f, &r, Some(f64::from(i16::MIN)), false).unwrap();
    }
}
