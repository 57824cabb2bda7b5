//! `cbdam build --planet` on SRTM tiles that are not what their names promise: a tile whose
//! length is no SRTM size and a tile truncated mid-way are refused before anything is written,
//! naming the file, and leave nothing at `-o` (no repository, no journal, no temporary); and
//! neighbouring tiles that disagree on their shared edge are refused naming both; a disk that
//! fills during the build is named, leaves nothing at `-o`, and the build resumes from its
//! journal.

use std::path::Path;

use crate::util::{cbdam, names_in, s, stderr, stdout};

/// Side of a 3″ SRTM tile.
const SIDE_3S: usize = 1201;

/// Writes `bytes` bytes of a smooth big-endian `i16` relief (metres) to `path`: the first
/// samples of a 3″ tile, or more than a tile holds.
fn write_hgt_bytes(path: &Path, bytes: usize) {
    let data: Vec<u8> = (0..bytes / 2)
        .flat_map(|i| {
            let (c, r) = (i % SIDE_3S, i / SIDE_3S);
            (((c + r) % 500) as i16 + 200).to_be_bytes()
        })
        .chain((bytes % 2 == 1).then_some(0))
        .collect();
    std::fs::write(path, data).unwrap();
}

/// Builds a planet of the tiles in `inputs` into an empty directory, expecting a refusal that
/// names `bad` and says how long it is, and nothing left in that directory.
fn refused_naming(inputs: &Path, bad: &str, len: usize) {
    let out_dir = tempfile::tempdir().unwrap();
    let out = out_dir.path().join("planet.cbdam");
    let o = cbdam(&[
        "build",
        &s(inputs),
        "--planet",
        "--max-error",
        "16",
        "--memory-limit",
        "64M",
        "-o",
        &s(&out),
    ]);
    assert!(!o.status.success(), "succeeded: {}", stdout(&o));
    let err = stderr(&o);
    assert!(err.contains(bad), "the error does not name {bad}: {err}");
    assert!(
        err.contains(&format!("{len} bytes")),
        "the error does not give the length {len}: {err}"
    );
    assert!(!err.contains("panicked"), "a panic: {err}");
    let left: Vec<_> = std::fs::read_dir(out_dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert!(left.is_empty(), "left behind at -o: {left:?}");
}

/// A good tile beside one of `len` bytes, named `N45E007.hgt`.
fn planet_with_bad_tile(dir: &Path, len: usize) {
    write_hgt_bytes(&dir.join("N45E006.hgt"), SIDE_3S * SIDE_3S * 2);
    write_hgt_bytes(&dir.join("N45E007.hgt"), len);
}

#[test]
fn a_planet_tile_whose_length_is_no_srtm_size_is_refused_by_name() {
    let tmp = tempfile::tempdir().unwrap();
    // Two bytes too many: one sample more than a 3″ tile, fewer than a 1″ one.
    let len = SIDE_3S * SIDE_3S * 2 + 2;
    planet_with_bad_tile(tmp.path(), len);
    refused_naming(tmp.path(), "N45E007.hgt", len);
}

#[test]
fn a_planet_tile_truncated_mid_way_is_refused_by_name() {
    let tmp = tempfile::tempdir().unwrap();
    // Cut off after 600 of its 1201 rows, and in the middle of a sample.
    let len = SIDE_3S * 600 * 2 + 1;
    planet_with_bad_tile(tmp.path(), len);
    refused_naming(tmp.path(), "N45E007.hgt", len);
}

/// Writes the 3″ tile whose south-west corner is (`lat`, `lon`) into `dir`: heights of a relief
/// that is a function of the position alone (so neighbours agree on their shared edge), but
/// `bump` metres added at sample `(c, r)` of `bumped`.
fn write_agreeing_tile(dir: &Path, (lat, lon): (i32, i32), bumped: Option<((usize, usize), i16)>) {
    let mut bytes = Vec::with_capacity(SIDE_3S * SIDE_3S * 2);
    for r in 0..SIDE_3S {
        for c in 0..SIDE_3S {
            // Global column and row of the 3″ grid.
            let (gc, gr) = (
                lon as i64 * 1200 + c as i64,
                (-lat as i64 - 1) * 1200 + r as i64,
            );
            let mut v = ((gc * 3 + gr * 5).rem_euclid(700) + 100) as i16;
            if let Some((_, bump)) = bumped.filter(|&(at, _)| at == (c, r)) {
                v += bump;
            }
            bytes.extend_from_slice(&v.to_be_bytes());
        }
    }
    std::fs::write(dir.join(format!("N{lat:02}E{lon:03}.hgt")), bytes).unwrap();
}

/// Two SRTM tiles whose shared column differs at one sample (row 600 of 1200: 45.5° N, on the
/// 7° E meridian they share) are refused naming both tiles, where, and the two heights;
/// nothing is left at `-o`. The same tiles agreeing build.
#[test]
fn neighbouring_planet_tiles_that_disagree_on_their_shared_edge_are_refused_naming_both() {
    let tmp = tempfile::tempdir().unwrap();
    write_agreeing_tile(tmp.path(), (45, 6), None);
    write_agreeing_tile(tmp.path(), (45, 7), Some(((0, 600), 40)));
    let out_dir = tempfile::tempdir().unwrap();
    let out = out_dir.path().join("planet.cbdam");
    let args = |out: &Path| {
        let mut a: Vec<String> = ["build", &s(tmp.path()), "--planet", "--max-error", "16"]
            .map(String::from)
            .to_vec();
        a.extend(
            [
                "--memory-limit",
                "64M",
                "--planet-level",
                "4",
                "-o",
                &s(out),
            ]
            .map(String::from),
        );
        a
    };
    let refused = cbdam(&args(&out).iter().map(String::as_str).collect::<Vec<_>>());
    assert!(!refused.status.success(), "succeeded: {}", stdout(&refused));
    let err = stderr(&refused);
    for needed in [
        "N45E006.hgt",
        "N45E007.hgt",
        "disagree on 1 of their 1201 shared samples by up to 40 m",
        "latitude 45.500000°, longitude 7.000000°",
    ] {
        assert!(err.contains(needed), "the error lacks {needed:?}: {err}");
    }
    assert!(!err.contains("panicked"), "a panic: {err}");
    let left: Vec<_> = std::fs::read_dir(out_dir.path()).unwrap().collect();
    assert!(left.is_empty(), "left behind at -o: {left:?}");
    write_agreeing_tile(tmp.path(), (45, 7), None);
    let built = cbdam(&args(&out).iter().map(String::as_str).collect::<Vec<_>>());
    assert!(built.status.success(), "{}", stderr(&built));
}

/// Runs `cbdam args…` allowed to write files of at most `limit` bytes (`RLIMIT_FSIZE`, with
/// `SIGXFSZ` ignored, so that a write past it fails with `EFBIG` as a full disk's fails with
/// `ENOSPC`: the same path through the build, without root or a small file system).
#[cfg(unix)]
fn cbdam_with_file_size_limit(args: &[String], limit: u64) -> std::process::Output {
    use std::os::unix::process::CommandExt;
    let mut command = std::process::Command::new(env!("CARGO_BIN_EXE_cbdam"));
    command.args(args);
    // SAFETY: `signal` and `setrlimit` are async-signal-safe; nothing else runs here.
    unsafe {
        command.pre_exec(move || {
            libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
            let r = libc::rlimit {
                rlim_cur: limit as libc::rlim_t,
                rlim_max: limit as libc::rlim_t,
            };
            if libc::setrlimit(libc::RLIMIT_FSIZE, &r) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    command.output().expect("run cbdam")
}

/// A planet built block by block (`--memory-limit 4M`) on a disk that fills: once while the
/// repository is written (every block already in the journal), once while the journal's blocks
/// are. Each time the build fails naming the file and that no room was left, leaves nothing
/// at `-o` but its journal, and, run again with room, continues from the journal and writes the
/// bytes of a build that never failed.
#[cfg(unix)]
#[test]
fn a_planet_build_on_a_disk_that_fills_is_named_and_resumes() {
    let tmp = tempfile::tempdir().unwrap();
    write_agreeing_tile(tmp.path(), (45, 6), None);
    write_agreeing_tile(tmp.path(), (45, 7), None);
    let out_dir = tempfile::tempdir().unwrap();
    let args = |out: &Path| -> Vec<String> {
        let mut a: Vec<String> = ["build", &s(tmp.path()), "--planet", "--max-error", "16"]
            .map(String::from)
            .to_vec();
        a.extend(["--memory-limit", "4M", "--planet-level", "6", "-o", &s(out)].map(String::from));
        a
    };
    let run = |out: &Path| {
        let a = args(out);
        let o = cbdam(&a.iter().map(String::as_str).collect::<Vec<_>>());
        assert!(o.status.success(), "{}", stderr(&o));
        o
    };
    let clean = out_dir.path().join("clean.cbdam");
    run(&clean);
    let expected = std::fs::read(&clean).unwrap();
    std::fs::remove_file(&clean).unwrap();
    let out = out_dir.path().join("planet.cbdam");
    // One byte short of the repository: every journal block fits, the repository does not.
    let full = cbdam_with_file_size_limit(&args(&out), expected.len() as u64 - 1);
    assert!(!full.status.success(), "succeeded: {}", stdout(&full));
    let err = stderr(&full);
    let writing = format!("writing {}", out.display());
    for needed in [
        writing.as_str(),
        "file-size limit",
        "nothing was written at",
        "finished blocks are kept in",
    ] {
        assert!(err.contains(needed), "the error lacks {needed:?}: {err}");
    }
    assert!(!err.contains("panicked"), "a panic: {err}");
    assert_eq!(names_in(out_dir.path()), ["planet.cbdam.journal"], "{err}");
    let resumed = run(&out);
    assert!(
        stderr(&resumed).contains("resuming: "),
        "{}",
        stderr(&resumed)
    );
    assert!(
        std::fs::read(&out).unwrap() == expected,
        "the resumed planet differs"
    );
    assert_eq!(names_in(out_dir.path()), ["planet.cbdam"]);
    // Room for the journal's key (a few hundred bytes) and its smallest blocks, not for all:
    // the block that found no room is named.
    std::fs::remove_file(&out).unwrap();
    let full = cbdam_with_file_size_limit(&args(&out), 1024);
    let err = stderr(&full);
    assert!(!full.status.success(), "succeeded: {}", stdout(&full));
    for needed in [
        "planet.cbdam.journal/block-",
        "file-size limit",
        "nothing was written at",
    ] {
        assert!(err.contains(needed), "the error lacks {needed:?}: {err}");
    }
    assert!(!out.exists() && !err.contains("panicked"), "{err}");
    let resumed = run(&out);
    assert!(
        stderr(&resumed).contains("resuming: "),
        "{}",
        stderr(&resumed)
    );
    assert!(
        std::fs::read(&out).unwrap() == expected,
        "the planet differs"
    );
}
