//! `cbdam verify` of a planet within `--memory-limit` (`docs/PLANET.md`, "Verify"): block by
//! block where the lattice does not fit, with the report of the whole comparison.

use std::path::{Path, PathBuf};

use cbdam_builder::write::{Raster, write_geotiff};
use cbdam_codec::repository::GeoRef;

use super::planet::edge_and_corner_planet;
use crate::util::{cbdam, s, stderr, stdout};

/// Builds the planet of [`edge_and_corner_planet`] (N = 17, K = 11, 7.4 M points held) into
/// `d/planet.cbdam`, encoded whole.
fn built(d: &Path) -> ([PathBuf; 3], PathBuf) {
    let paths = edge_and_corner_planet(d);
    let out = d.join("planet.cbdam");
    let mut args: Vec<String> = vec!["build".into()];
    args.extend(paths.iter().map(|p| s(p)));
    args.extend(
        [
            "--planet",
            "--diamond-size",
            "17",
            "--max-error",
            "1",
            "--quiet",
        ]
        .map(String::from),
    );
    args.extend(["--memory-limit".into(), "8G".into(), "-o".into(), s(&out)]);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let o = cbdam(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    (paths, out)
}

/// `cbdam verify REPO --against INPUTS --memory-limit LIMIT` under GNU time: its output and
/// the peak resident memory of verify itself (the child's `ru_maxrss`, bytes).
fn verify(repo: &Path, inputs: &[PathBuf], limit: &str) -> (std::process::Output, u64) {
    let mut args = vec!["verify".to_string(), s(repo), "--against".into()];
    args.extend(inputs.iter().map(|p| s(p)));
    args.extend(["--memory-limit".into(), limit.into()]);
    let o = std::process::Command::new("/usr/bin/time")
        .args(["-f", "peak-rss-kib %M", env!("CARGO_BIN_EXE_cbdam")])
        .args(&args)
        .output()
        .expect("run /usr/bin/time (GNU time)");
    let err = stderr(&o);
    let at = err.rfind("peak-rss-kib ").expect("GNU time's line") + "peak-rss-kib ".len();
    let kib: u64 = err[at..].trim().parse().expect("a number of KiB");
    (o, kib * 1024)
}

/// The report less the line naming the blocks.
fn report(o: &std::process::Output) -> String {
    stdout(o)
        .lines()
        .filter(|l| !l.starts_with("decoded in "))
        .collect::<Vec<_>>()
        .join("\n")
}

/// The decoded finest level's temporary disk that verify's "decoded in …" line states: bytes
/// written, at most held at once, held at the end.
fn decoded_disk(o: &std::process::Output) -> (u64, u64, u64) {
    let out = stdout(o);
    let line = out
        .lines()
        .find(|l| l.starts_with("decoded in "))
        .unwrap_or_else(|| panic!("no \"decoded in\" line: {out}"));
    let number_before = |word: &str| -> u64 {
        let at = line
            .find(word)
            .unwrap_or_else(|| panic!("{word:?} in {line}"));
        let digits: String = line[..at]
            .trim_end()
            .chars()
            .rev()
            .take_while(char::is_ascii_digit)
            .collect();
        digits
            .chars()
            .rev()
            .collect::<String>()
            .parse()
            .expect(line)
    };
    (
        number_before(" bytes written"),
        number_before(" held at once"),
        number_before(" at the end"),
    )
}

/// Under 4 MiB the lattice (7.4 M points held, insets astride a cube edge with a void and on a
/// cube corner over a global grid with a void) is verified block by block, with the whole
/// comparison's report to the last digit: every level's diamonds, vertices and maximum, each
/// input's resampling and end-to-end errors.
#[test]
fn a_planet_verified_block_by_block_reports_what_the_whole_verify_does() {
    let tmp = tempfile::tempdir().unwrap();
    let (inputs, repo) = built(tmp.path());
    let (whole, whole_peak) = verify(&repo, &inputs, "8G");
    assert!(whole.status.success(), "{}", stderr(&whole));
    assert!(
        !stdout(&whole).contains("decoded in "),
        "{}",
        stdout(&whole)
    );
    let (blocks, blocks_peak) = verify(&repo, &inputs, "4M");
    assert!(blocks.status.success(), "{}", stderr(&blocks));
    assert!(
        stdout(&blocks).contains("decoded in ") && stdout(&blocks).contains("block(s)"),
        "{}",
        stdout(&blocks)
    );
    assert_eq!(report(&blocks), report(&whole));
    // The insets' decoded tiles were let go once they were measured: only the global grid's
    // stride of them stays to the end.
    let (written, held, at_end) = decoded_disk(&blocks);
    eprintln!(
        "decoded finest level: {written} B written, at most {held} B held, {at_end} at the end"
    );
    assert!(held < written && at_end * 10 < held, "{}", stdout(&blocks));
    // Every level was compared (the finest with vertices), and each input's samples.
    let report = report(&whole);
    assert!(
        report.contains("every level against the resampled lattice"),
        "{report}"
    );
    for name in ["global.tif", "edge.tif", "corner.tif"] {
        assert!(report.contains(name), "{report}");
    }
    eprintln!("verify peak: whole {whole_peak} B, block by block {blocks_peak} B");
}

/// A planet verified block by block still fails where it should: against an input whose
/// heights moved (a level over the bound, as the whole comparison finds), and with a record
/// damaged.
#[test]
fn a_planet_verified_block_by_block_fails_where_the_whole_verify_does() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let (inputs, repo) = built(d);
    // The corner inset rewritten flat at sea level (its own heights vary by tens of metres).
    let moved = d.join("moved");
    std::fs::create_dir_all(&moved).unwrap();
    let mut changed = inputs.clone();
    changed[2] = moved.join("corner.tif");
    let r = Raster {
        width: 21,
        height: 21,
        values: vec![0.0; 21 * 21],
        georef: Some(GeoRef {
            epsg: Some(4326),
            origin_x: 45.0 - 0.05,
            origin_y: 35.446 + 0.05,
            pixel_x: 0.005,
            pixel_y: 0.005,
            pixel_is_area: false,
            wkt: None,
        }),
    };
    write_geotiff(std::fs::File::create(&changed[2]).unwrap(), &r, None, false).unwrap();
    for limit in ["8G", "4M"] {
        let (o, _) = verify(&repo, &changed, limit);
        assert!(!o.status.success(), "{limit}: {}", stdout(&o));
        assert!(
            stderr(&o).contains("exceeds the bound"),
            "{limit}: {}",
            stderr(&o)
        );
    }
    // A byte of the last record flipped.
    let mut bytes = std::fs::read(&repo).unwrap();
    let at = bytes.len() - 3;
    bytes[at] ^= 0x5a;
    let damaged = d.join("damaged.cbdam");
    std::fs::write(&damaged, bytes).unwrap();
    let (o, _) = verify(&damaged, &inputs, "4M");
    assert!(!o.status.success(), "{}", stdout(&o));
}

/// Verify's peak resident memory (the child's own `ru_maxrss`) under a small `--memory-limit`
/// does not follow the lattice: 36 small 3″ insets a degree apart (each making the lattice tiles
/// around it hold every point, K = 11) verified whole and under 64M, with the same report.
/// Measured: whole 327.3 MiB, under 64M 128.1 MiB (with 12 insets: 174.9 against 132.5 MiB,
/// the block path's floor about 100 MiB as the build's).
/// Ignored in CI: about 3 minutes on 2 loaded cores (`--ignored` runs it).
#[test]
#[ignore = "about 3 minutes; run with --ignored"]
fn a_planet_verified_under_a_small_limit_peaks_below_the_whole_verify() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path().join("insets");
    super::planet_out_of_core::write_insets_a_degree_apart(&d);
    let repo = tmp.path().join("p.cbdam");
    let o = cbdam(&[
        "build",
        &s(&d),
        "--planet",
        "-o",
        &s(&repo),
        "--max-error",
        "2",
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let (whole, whole_peak) = verify(&repo, std::slice::from_ref(&d), "8G");
    assert!(whole.status.success(), "{}", stderr(&whole));
    let (blocks, blocks_peak) = verify(&repo, &[d], "64M");
    assert!(blocks.status.success(), "{}", stderr(&blocks));
    assert!(
        stdout(&blocks).contains("decoded in "),
        "{}",
        stdout(&blocks)
    );
    assert_eq!(report(&blocks), report(&whole));
    let (written, held, at_end) = decoded_disk(&blocks);
    eprintln!(
        "decoded finest level: {written} B written, at most {held} B held, {at_end} at the end"
    );
    // Measured: 225.9 MB written, at most 15.8 MB held at once (each inset's tiles let go once
    // it is measured; there is no global input, so nothing is kept to the end).
    assert!(held * 4 < written && at_end == 0, "{}", stdout(&blocks));
    let mib = |b: u64| b as f64 / f64::from(1 << 20);
    eprintln!(
        "verify peak RSS: whole {:.1} MiB, under 64M {:.1} MiB",
        mib(whole_peak),
        mib(blocks_peak)
    );
    assert!(
        blocks_peak * 2 < whole_peak,
        "under 64M {:.1} MiB, whole {:.1} MiB",
        mib(blocks_peak),
        mib(whole_peak)
    );
}
