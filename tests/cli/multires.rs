//! `cbdam build A B …`: several inputs at power-of-two spacings as one variable-resolution
//! repository (paper §5, "graph construction"), checked end to end with verify, inspect and
//! extract, and the geometries that cannot be combined refused by name with nothing left behind.

use std::path::{Path, PathBuf};
use std::process::Output;

use crate::util::*;
use cbdam_builder::input::{ReadOptions, read_dem};
use cbdam_codec::samples::Dem;

/// Side of the lattice in fine samples (the coarse input spans it all).
const SIDE: usize = 513;
/// The coarse input's spacing in fine samples.
const STRIDE: usize = 4;
/// The fine input: first sample (x, y) in model units (y north) and samples per side.
const FINE_AT: (usize, usize) = (64, 64);
const FINE_SIDE: usize = 97;
/// The coarse survey reads this much higher: wherever the wrong input won, it shows.
const COARSE_OFFSET: f64 = 50.0;
const EPS: f64 = 1.0;

/// Terrain at model point (x, y), whole metres.
fn terrain(x: usize, y: usize) -> f64 {
    let (xf, yf) = (x as f64, y as f64);
    (1000.0 + 300.0 * (xf / 23.0).sin() * (yf / 31.0).cos() + ((x * 7 + y * 13) % 5) as f64).round()
}

/// An ESRI ASCII grid of point samples: `side` × `side` at `spacing`, first (south-west) sample
/// centre at `(x0, y0)`, value `f(x, y)` in model units.
fn write_asc(
    path: &Path,
    x0: f64,
    y0: f64,
    spacing: f64,
    side: usize,
    f: impl Fn(f64, f64) -> f64,
) {
    let mut t = format!(
        "ncols {side}\nnrows {side}\nxllcenter {x0}\nyllcenter {y0}\ncellsize {spacing}\n\
         NODATA_value -9999\n"
    );
    for r in 0..side {
        let y = y0 + (side - 1 - r) as f64 * spacing;
        let row: Vec<String> = (0..side)
            .map(|c| f(x0 + c as f64 * spacing, y).to_string())
            .collect();
        t += &row.join(" ");
        t += "\n";
    }
    std::fs::write(path, t).unwrap();
}

fn coarse(dir: &Path) -> PathBuf {
    let p = dir.join("coarse.asc");
    let side = (SIDE - 1) / STRIDE + 1;
    write_asc(&p, 0.0, 0.0, STRIDE as f64, side, |x, y| {
        terrain(x as usize, y as usize) + COARSE_OFFSET
    });
    p
}

fn fine(dir: &Path) -> PathBuf {
    let p = dir.join("fine.asc");
    let (x0, y0) = FINE_AT;
    write_asc(&p, x0 as f64, y0 as f64, 1.0, FINE_SIDE, |x, y| {
        terrain(x as usize, y as usize)
    });
    p
}

fn in_fine(x: usize, y: usize) -> bool {
    let (x0, y0) = FINE_AT;
    (x0..x0 + FINE_SIDE).contains(&x) && (y0..y0 + FINE_SIDE).contains(&y)
}

fn build(inputs: &[&Path], out: &Path) -> Output {
    let out_s = s(out);
    let mut args = vec!["build".to_string()];
    args.extend(inputs.iter().map(|p| s(p)));
    args.extend(
        [
            "-o",
            &out_s,
            "--max-error",
            "1",
            "--diamond-size",
            "17",
            "--quiet",
        ]
        .map(String::from),
    );
    cbdam(&args.iter().map(String::as_str).collect::<Vec<_>>())
}

fn inspect_json(repo: &Path) -> serde_json::Value {
    let o = cbdam(&["inspect", "--json", &s(repo)]);
    assert!(o.status.success(), "inspect: {}", stderr(&o));
    serde_json::from_slice(&o.stdout).unwrap()
}

fn read(path: &Path) -> Dem {
    read_dem(path, &ReadOptions::default()).unwrap()
}

#[test]
fn coarse_and_fine_inputs_make_one_variable_resolution_repository() {
    let dir = tempfile::tempdir().unwrap();
    let (c, f) = (coarse(dir.path()), fine(dir.path()));
    let out = dir.path().join("multi.cbdam");
    let o = build(&[&c, &f], &out);
    assert!(o.status.success(), "build: {}", stderr(&o));

    let o = cbdam(&["verify", &s(&out), "--against", &s(&c), &s(&f)]);
    let text = stdout(&o);
    assert!(o.status.success(), "verify: {text}{}", stderr(&o));
    assert!(text.contains("OK"), "{text}");
    // Every fine sample wins; coarse samples win outside the fine area only.
    let side = (SIDE - 1) / STRIDE + 1;
    let coarse_inside = (0..side * side)
        .filter(|k| in_fine(k % side * STRIDE, k / side * STRIDE))
        .count();
    assert!(
        text.contains(&format!(
            "{} winning samples (stride 1)",
            FINE_SIDE * FINE_SIDE
        )),
        "{text}"
    );
    assert!(
        text.contains(&format!(
            "{} winning samples (stride {STRIDE})",
            side * side - coarse_inside
        )),
        "{text}"
    );

    // Far fewer records than the whole area at the fine spacing.
    let all = dir.path().join("all_fine.asc");
    write_asc(&all, 0.0, 0.0, 1.0, SIDE, |x, y| {
        terrain(x as usize, y as usize)
    });
    let full = dir.path().join("all_fine.cbdam");
    let o = build(&[&all], &full);
    assert!(o.status.success(), "{}", stderr(&o));
    let (multi, whole) = (inspect_json(&out), inspect_json(&full));
    let records = |v: &serde_json::Value| v["records"].as_u64().unwrap();
    assert!(
        records(&multi) * 3 < records(&whole),
        "{} records vs {} at the fine spacing",
        records(&multi),
        records(&whole)
    );
    assert_eq!(multi["data_width"], SIDE);
    assert_eq!(multi["finest_level"], whole["finest_level"]);

    // The coarse input's level, extracted whole: the fine input where it has data (it wins),
    // the coarse one elsewhere, each within ε — read back by the GeoTIFF reader, not by verify.
    let finest = multi["finest_level"].as_u64().unwrap();
    let level = finest - 2 * STRIDE.trailing_zeros() as u64;
    let tif = dir.path().join("coarse_level.tif");
    let o = cbdam(&[
        "extract",
        &s(&out),
        "--level",
        &level.to_string(),
        "--float64",
        "-o",
        &s(&tif),
    ]);
    assert!(o.status.success(), "extract: {}", stderr(&o));
    let got = read(&tif);
    assert_eq!((got.width, got.height), (side, side));
    for r in 0..side {
        for col in 0..side {
            let (x, y) = (col * STRIDE, (side - 1 - r) * STRIDE);
            let want = if in_fine(x, y) {
                terrain(x, y)
            } else {
                terrain(x, y) + COARSE_OFFSET
            };
            let v = got.values[r * side + col];
            assert!((v - want).abs() <= EPS, "({x}, {y}): {v} vs {want}");
        }
    }
    // The finest level: the fine input within ε, and nothing invented outside it.
    let tif = dir.path().join("finest.tif");
    let o = cbdam(&["extract", &s(&out), "--float64", "-o", &s(&tif)]);
    assert!(o.status.success(), "extract: {}", stderr(&o));
    let got = read(&tif);
    assert_eq!((got.width, got.height), (SIDE, SIDE));
    let (mut inside, mut outside_reached) = (0, 0);
    for r in 0..SIDE {
        for x in 0..SIDE {
            let y = SIDE - 1 - r;
            let k = r * SIDE + x;
            if in_fine(x, y) {
                let v = got.values[k];
                assert!((v - terrain(x, y)).abs() <= EPS, "({x}, {y}): {v}");
                inside += 1;
            } else if got.is_valid(k) {
                outside_reached += 1;
            }
        }
    }
    assert_eq!(inside, FINE_SIDE * FINE_SIDE);
    // Finest-level diamonds exist only where they meet the fine input: at most a diamond's
    // width (16 samples) around it.
    let ring = (FINE_SIDE + 32) * (FINE_SIDE + 32) - FINE_SIDE * FINE_SIDE;
    assert!(
        outside_reached <= ring,
        "{outside_reached} finest points outside"
    );

    // The wrong inputs, or the wrong order of equal-stride inputs, do not verify.
    let o = cbdam(&["verify", &s(&out), "--against", &s(&c)]);
    assert!(!o.status.success());
    let o = cbdam(&["verify", &s(&out), "--against", &s(&all), &s(&f)]);
    assert!(!o.status.success());
}

fn build_fails(dir: &Path, inputs: &[&Path], message: &str) {
    let before = listing(dir);
    let o = build(inputs, &dir.join("bad.cbdam"));
    check_refused(&o, inputs, &[message]);
    assert_eq!(listing(dir), before, "{inputs:?} left files behind");
}

#[test]
fn inputs_that_cannot_share_a_lattice_are_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let (c, f) = (coarse(dir.path()), fine(dir.path()));
    let t = |x: f64, y: f64| terrain(x as usize, y as usize);

    // Ratio 3 (as SRTM 1″ with 3″).
    let r3 = dir.path().join("ratio3.asc");
    write_asc(&r3, 0.0, 0.0, 3.0, 40, t);
    build_fails(
        dir.path(),
        &[&r3, &f],
        "3.000000 × 3.000000 times as coarse",
    );
    build_fails(dir.path(), &[&r3, &f], "ratio3.asc");

    // Half a sample off the fine lattice.
    let off = dir.path().join("half_off.asc");
    write_asc(&off, 0.5, 0.0, 2.0, 40, t);
    build_fails(
        dir.path(),
        &[&off, &f],
        "must fall on the finest input's sample positions",
    );

    // On the lattice, but not on the coarse input's stride.
    let odd = dir.path().join("odd.asc");
    write_asc(&odd, 2.0, 0.0, 4.0, 20, t);
    build_fails(dir.path(), &[&c, &odd, &f], "misaligned");
    build_fails(dir.path(), &[&c, &odd, &f], "odd.asc");

    // Different coordinate reference systems.
    let srtm = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/srtm3_demcompare.tif");
    build_fails(dir.path(), &[&f, &srtm], "coordinate reference system");

    // No georeferencing: a 16-bit PNG.
    let png_path = dir.path().join("plain.png");
    {
        let file = std::fs::File::create(&png_path).unwrap();
        let mut enc = png::Encoder::new(std::io::BufWriter::new(file), 8, 8);
        enc.set_color(png::ColorType::Grayscale);
        enc.set_depth(png::BitDepth::Sixteen);
        let mut w = enc.write_header().unwrap();
        let data: Vec<u8> = (0..64u16).flat_map(|v| (1000 + v).to_be_bytes()).collect();
        w.write_image_data(&data).unwrap();
    }
    build_fails(dir.path(), &[&f, &png_path], "has no georeferencing");
}

#[test]
fn a_memory_limit_that_leaves_no_cache_of_tile_rows_builds_the_same_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let (c, f) = (coarse(dir.path()), fine(dir.path()));
    let build_under = |limit: Option<&str>, name: &str| {
        let out = dir.path().join(name);
        let mut args = vec![
            "build".to_string(),
            s(&c),
            s(&f),
            "-o".into(),
            s(&out),
            "--max-error".into(),
            "1".into(),
        ];
        if let Some(l) = limit {
            args.extend(["--memory-limit".to_string(), l.to_string()]);
        }
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let o = cbdam(&args);
        assert!(o.status.success(), "{limit:?}: {}", stderr(&o));
        std::fs::read(&out).unwrap()
    };
    let free = build_under(None, "free.cbdam");
    // The 513² lattice needs 4 626 KiB (6 bytes a point, and one block of composed rows at 12
    // bytes a point): under 4 630 KiB the cache of decoded tile rows gets 2 KiB, so every band
    // of rows is decoded again each time a block needs it.
    let tight = build_under(Some("4630K"), "tight.cbdam");
    assert!(tight == free, "a cache-less build changed the repository");
}

/// A lattice larger than half of `--memory-limit` (here far larger than all of it) goes to
/// memory-mapped temporary files, classes included, and the variable-resolution build writes
/// the same bytes, saying where the lattice went; nothing is left beside the output.
#[test]
fn a_variable_resolution_lattice_beyond_the_memory_limit_is_mapped_with_the_same_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let (c, f) = (coarse(dir.path()), fine(dir.path()));
    let build_under = |limit: &str, name: &str| {
        let out = dir.path().join(name);
        let o = cbdam(&[
            "build",
            &s(&c),
            &s(&f),
            "-o",
            &s(&out),
            "--max-error",
            "1",
            "--timings",
            "--memory-limit",
            limit,
        ]);
        assert!(o.status.success(), "{limit}: {}", stderr(&o));
        (std::fs::read(&out).unwrap(), stderr(&o))
    };
    let (free, said) = build_under("1G", "free.cbdam");
    assert!(!said.contains("lattice in mapped files"), "{said}");
    let before = listing(dir.path());
    // 513² points at 6 bytes: 1.5 MiB, mapped under 2 MiB; under 64 KiB the field is mapped too.
    for limit in ["2M", "64K"] {
        let (mapped, said) = build_under(limit, "mapped.cbdam");
        assert!(
            said.contains("lattice in mapped files") && said.contains("memory-mapped temporary"),
            "{limit}: {said}"
        );
        assert!(
            mapped == free,
            "{limit}: the mapped lattice changed the repository"
        );
        let mut after = listing(dir.path());
        after.retain(|p| !p.ends_with("mapped.cbdam"));
        assert_eq!(after, before, "{limit}: files left behind");
    }
}

#[test]
fn a_sharded_build_of_coarse_and_fine_inputs_has_the_bytes_of_cbdam_builder() {
    let dir = tempfile::tempdir().unwrap();
    let (c, f) = (coarse(dir.path()), fine(dir.path()));
    let want_path = dir.path().join("whole.cbdam");
    let o = build(&[&c, &f], &want_path);
    assert!(o.status.success(), "build: {}", stderr(&o));
    let (c, f) = (s(&c), s(&f));
    let out = s(&dir.path().join("sharded.cbdam"));
    let work = s(&dir.path().join("work"));
    let step = |args: &[&str]| {
        let o = cbdam(args);
        assert!(o.status.success(), "{args:?}: {}", stderr(&o));
    };
    // Blocks of 128 (several, each reading only its tiles of the prepared grid), 3 shards.
    step(&[
        "shard",
        "plan",
        &c,
        &f,
        "-o",
        &out,
        "--max-error",
        "1",
        "--diamond-size",
        "17",
        "--block-plan",
        "6,128",
        "--work",
        &work,
        "--shards",
        "3",
    ]);
    step(&["shard", "apex", "--work", &work]);
    for shard in ["2", "0", "1"] {
        step(&["shard", "run", "--work", &work, "--shard", shard]);
    }
    step(&["shard", "merge", "--work", &work]);
    assert!(
        std::fs::read(&out).unwrap() == std::fs::read(&want_path).unwrap(),
        "the sharded variable-resolution repository differs from cbdam build's"
    );
}
