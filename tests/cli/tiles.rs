//! `cbdam build` and `cbdam verify` over tiles: a directory of tiles sharing edge rows builds the
//! same bytes as the DEM they were cut from and verifies against the directory; `--help` says
//! what an input may be; an empty directory is refused by name, leaving no output.

use std::path::Path;

use cbdam_builder::input::{ReadOptions, read_dem};
use cbdam_builder::write::{Raster, write_geotiff};
use cbdam_codec::repository::GeoRef;

use crate::util::{cbdam, data, s, stderr, stdout};

/// Tile side between shared edges; 2 × 2 tiles of `T + 1` samples.
const T: usize = 96;
const SIDE: usize = 2 * T + 1;

fn write(path: &Path, w: usize, values: Vec<f64>, georef: GeoRef) {
    let r = Raster {
        width: w,
        height: w,
        values,
        georef: Some(georef),
    };
    write_geotiff(std::fs::File::create(path).unwrap(), &r, None, false).unwrap();
}

/// Cuts the north-west `(n·t + 1)²` samples of the DEM `dem` into `n × n` GeoTIFF tiles of
/// `t + 1` samples sharing their edge rows and columns (as SRTM's do), written to `dir`.
pub fn cut_into_tiles(dem: &str, dir: &Path, t: usize, n: usize) {
    let dem = read_dem(Path::new(dem), &ReadOptions::default()).unwrap();
    let g = dem.georef.clone().unwrap();
    let at = |r: usize, c: usize| dem.values[r * dem.width + c];
    std::fs::create_dir(dir).unwrap();
    for tr in 0..n {
        for tc in 0..n {
            let v: Vec<f64> = (0..(t + 1) * (t + 1))
                .map(|i| at(tr * t + i / (t + 1), tc * t + i % (t + 1)))
                .collect();
            let tg = GeoRef {
                origin_x: g.origin_x + (tc * t) as f64 * g.pixel_x,
                origin_y: g.origin_y - (tr * t) as f64 * g.pixel_y,
                ..g.clone()
            };
            write(&dir.join(format!("N{tr}E{tc}.tif")), t + 1, v, tg);
        }
    }
}

#[test]
fn a_directory_of_tiles_builds_and_verifies_like_one_file() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let dem = read_dem(
        Path::new(&data("srtm3_demcompare.tif")),
        &ReadOptions::default(),
    )
    .unwrap();
    let g = dem.georef.clone().unwrap();
    let at = |r: usize, c: usize| dem.values[r * dem.width + c];
    let whole: Vec<f64> = (0..SIDE * SIDE).map(|i| at(i / SIDE, i % SIDE)).collect();
    write(&d.join("whole.tif"), SIDE, whole, g.clone());
    let tiles = d.join("tiles");
    cut_into_tiles(&data("srtm3_demcompare.tif"), &tiles, T, 2);
    let build = |input: &Path, out: &Path| {
        let o = cbdam(&[
            "build",
            &s(input),
            "-o",
            &s(out),
            "--max-error",
            "1.5",
            "--quiet",
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        std::fs::read(out).unwrap()
    };
    let want = build(&d.join("whole.tif"), &d.join("whole.cbdam"));
    let got = build(&tiles, &d.join("tiles.cbdam"));
    assert!(got == want, "the directory of tiles built different bytes");
    let o = cbdam(&[
        "verify",
        &s(&d.join("tiles.cbdam")),
        "--against",
        &s(&tiles),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(stdout(&o).contains("OK"), "{}", stdout(&o));
    // Each tile is named with its winning samples: the four tiles were all used.
    assert_eq!(
        stdout(&o).matches("winning samples").count(),
        4,
        "{}",
        stdout(&o)
    );
    // Decoded in smaller blocks (the smallest a memory limit picks here is the whole domain),
    // the same findings; below what the smallest blocks need, verify says so.
    let small = cbdam(&[
        "verify",
        &s(&d.join("tiles.cbdam")),
        "--against",
        &s(&tiles),
        "--block-plan",
        "1,64",
    ]);
    assert!(small.status.success(), "{}", stderr(&small));
    let without_plan = |text: &str| {
        text.lines()
            .filter(|l| !l.starts_with("decoded in"))
            .collect::<Vec<_>>()
            .join("\n")
    };
    assert_eq!(without_plan(&stdout(&small)), without_plan(&stdout(&o)));
    let blocks = |text: &str| {
        let line = text.lines().find(|l| l.starts_with("decoded in")).unwrap();
        line.split(' ').nth(2).unwrap().parse::<usize>().unwrap()
    };
    assert!(
        blocks(&stdout(&small)) > blocks(&stdout(&o)),
        "{}",
        stdout(&small)
    );
    let tiny = cbdam(&[
        "verify",
        &s(&d.join("tiles.cbdam")),
        "--against",
        &s(&tiles),
        "--memory-limit",
        "1M",
    ]);
    assert!(!tiny.status.success());
    assert!(
        stderr(&tiny).contains("raise --memory-limit"),
        "{}",
        stderr(&tiny)
    );

    let help = stdout(&cbdam(&["build", "--help"]));
    for what in ["directory", "glob", "@LIST", "VRT", "disagree"] {
        assert!(help.contains(what), "--help does not mention {what}");
    }

    let empty = d.join("empty");
    std::fs::create_dir(&empty).unwrap();
    let out = d.join("empty.cbdam");
    let o = cbdam(&["build", &s(&empty), "-o", &s(&out), "--max-error", "1"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains(&s(&empty)), "{err}");
    assert!(!out.exists());
}

/// The byte identity that `mosaic_peak_memory_does_not_grow_with_the_tile_count` checks at
/// 8193² (ignored: minutes), at a size every CI run affords: one 1025² int16 grid as 4 and as 64
/// GeoTIFF tiles sharing their edges builds the same bytes, with the lattice in memory and
/// under a memory limit that puts it (and the reconstruction) in mapped files, each path shown
/// by `--timings`.
#[test]
fn four_and_sixty_four_tiles_build_the_same_bytes() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    for n in ["2", "8"] {
        let out = s(&d.join(format!("t{n}")));
        let o = cbdam(&[
            "synth", "--size", "1025", "--tiff", "plain", "--int16", "--tiles", n, "-o", &out,
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
    }
    assert_eq!(std::fs::read_dir(d.join("t8")).unwrap().count(), 64);
    for (limit, path) in [
        (None, "reconstruction in memory"),
        (Some("1M"), "lattice in mapped files"),
    ] {
        let build = |tiles: &str| {
            let (input, out) = (s(&d.join(tiles)), s(&d.join(format!("{tiles}.cbdam"))));
            let mut args = vec![
                "build",
                &input,
                "-o",
                &out,
                "--max-error",
                "1",
                "--quiet",
                "--timings",
            ];
            if let Some(l) = limit {
                args.extend(["--memory-limit", l]);
            }
            let o = cbdam(&args);
            assert!(o.status.success(), "{args:?}: {}", stderr(&o));
            assert!(stderr(&o).contains(path), "{args:?}: {}", stderr(&o));
            std::fs::read(d.join(format!("{tiles}.cbdam"))).unwrap()
        };
        assert!(
            build("t2") == build("t8"),
            "4 and 64 tiles built different bytes (memory limit {limit:?})"
        );
    }
}

/// Peak resident memory (KiB) of `cbdam ARGS`, as GNU time reports it (`/usr/bin/time -f %M`:
/// the child's `ru_maxrss`); panics if the command fails.
fn peak_rss_kib(args: &[&str]) -> u64 {
    let o = std::process::Command::new("/usr/bin/time")
        .args(["-f", "peak-rss-kib %M", env!("CARGO_BIN_EXE_cbdam")])
        .args(args)
        .output()
        .expect("run /usr/bin/time (GNU time)");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "cbdam {args:?}: {err}");
    err.lines()
        .rev()
        .find_map(|l| l.strip_prefix("peak-rss-kib "))
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or_else(|| panic!("no peak RSS in: {err}"))
}

/// The peak memory of a mosaic build does not grow with the number of tiles, and stays within
/// the lattice's own arrays of a streamed single-file build: the same 8193² int16 grid (134 MB
/// of tiles) as 4 and as 64 GeoTIFF tiles sharing their edges, against the grid as one raw
/// float32 file (streamed, no cache). Under a --memory-limit that leaves the mosaic's cache of
/// decoded tile rows 8 MiB, holding the tiles (≥ 134 MB) would show far beyond the bounds:
/// - RSS(64 tiles) − RSS(4 tiles) < ⅛ of the tiles' bytes;
/// - RSS(64 tiles) − RSS(one file) < the resolution classes (1 byte a lattice point, which only
///   several inputs have) + ¼ of the tiles' bytes.
///
/// Minutes in a debug build: run it with
/// `cargo test --release -p cbdam --test tests -- --ignored cli::tiles::mosaic_peak_memory`.
#[test]
#[ignore = "minutes: builds a 67 M-sample grid three times"]
fn mosaic_peak_memory_does_not_grow_with_the_tile_count() {
    const SIZE: usize = 8193;
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let synth = |extra: &[&str], out: &Path| {
        let size = SIZE.to_string();
        let mut args = vec!["synth", "--size", &size];
        args.extend_from_slice(extra);
        let out = s(out);
        args.extend(["-o", &out]);
        let o = cbdam(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    };
    synth(&[], &d.join("whole.f32"));
    synth(
        &["--tiff", "plain", "--int16", "--tiles", "2"],
        &d.join("t4"),
    );
    synth(
        &["--tiff", "plain", "--int16", "--tiles", "8"],
        &d.join("t64"),
    );
    let tile_bytes: u64 = std::fs::read_dir(d.join("t64"))
        .unwrap()
        .map(|e| e.unwrap().metadata().unwrap().len())
        .sum();
    let points = (SIZE * SIZE) as u64;
    // What the mosaic's lattice took in memory: 6 bytes a point and a block of 2^20 points at
    // 12 bytes, and 16 MiB more. Above half the limit the lattice is now mapped
    // (cbdam_builder::mosaic::bytes_in_memory counts a resident window of each array), which
    // leaves the cache of tile rows more room: the same for every tile count.
    let limit = format!("{}K", (6 * points + 12 * (1 << 20) + (16 << 20)) / 1024);
    let build = |input: &Path, out: &str, raw: bool| {
        let (input, out) = (s(input), s(&d.join(out)));
        let mut args = vec![
            "build",
            &input,
            "-o",
            &out,
            "--max-error",
            "1",
            "--memory-limit",
            &limit,
            "--quiet",
        ];
        let size = format!("{SIZE}x{SIZE}");
        if raw {
            args.extend(["--size", &size]);
        }
        peak_rss_kib(&args) * 1024
    };
    let one = build(&d.join("whole.f32"), "one.cbdam", true);
    let four = build(&d.join("t4"), "t4.cbdam", false);
    let many = build(&d.join("t64"), "t64.cbdam", false);
    assert!(
        std::fs::read(d.join("t4.cbdam")).unwrap() == std::fs::read(d.join("t64.cbdam")).unwrap(),
        "4 and 64 tiles built different bytes"
    );
    let mib = |b: u64| b as f64 / (1 << 20) as f64;
    eprintln!(
        "peak RSS: one file {:.0} MiB, 4 tiles {:.0} MiB, 64 tiles {:.0} MiB; tiles {:.0} MiB",
        mib(one),
        mib(four),
        mib(many),
        mib(tile_bytes)
    );
    assert!(
        many.abs_diff(four) < tile_bytes / 8,
        "64 tiles {:.0} MiB, 4 tiles {:.0} MiB",
        mib(many),
        mib(four)
    );
    assert!(
        many.saturating_sub(one) < points + tile_bytes / 4,
        "64 tiles {:.0} MiB, one file {:.0} MiB",
        mib(many),
        mib(one)
    );
}

/// `synth --tiles N --mirrored` (the generator of mosaics larger than memory) writes tiles that
/// agree on every shared row and column — the build refuses tiles that do not, naming both —
/// mirror images of each other across each edge, not copies.
#[test]
fn mirrored_synthetic_tiles_agree_on_their_shared_edges() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("tiles");
    let o = cbdam(&[
        "synth",
        "--size",
        "49",
        "--tiff",
        "plain",
        "--int16",
        "--tiles",
        "3",
        "--mirrored",
        "-o",
        &s(&dir),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let read = |name: &str| read_dem(&dir.join(name), &ReadOptions::default()).unwrap();
    let (a, b, c) = (
        read("r000c000.tif"),
        read("r000c001.tif"),
        read("r001c000.tif"),
    );
    assert_eq!((a.width, a.height), (17, 17));
    let at = |d: &cbdam_codec::samples::Dem, x: usize, y: usize| d.values[y * d.width + x];
    for i in 0..17 {
        for j in 0..17 {
            assert_eq!(
                at(&b, i, j),
                at(&a, 16 - i, j),
                "left–right mirror at {i}, {j}"
            );
            assert_eq!(
                at(&c, i, j),
                at(&a, i, 16 - j),
                "top–bottom mirror at {i}, {j}"
            );
        }
    }
    assert!(
        (0..17).any(|i| at(&a, i, 3) != at(&a, 16 - i, 3)),
        "a symmetric tile proves nothing"
    );
    let out = tmp.path().join("m.cbdam");
    let o = cbdam(&[
        "build",
        &s(&dir),
        "-o",
        &s(&out),
        "--max-error",
        "1",
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}
