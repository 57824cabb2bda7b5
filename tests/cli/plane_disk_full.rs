//! A plane's mapped temporaries on a disk that fills (`docs/BUILD.md`, "A disk that fills"):
//! `cbdam build` and `cbdam verify --against` above `--memory-limit` keep the lattice and the
//! reconstruction field in mapped files in the temporary directory, and a write through a
//! mapping that finds no room would kill the process with `SIGBUS`. Their blocks are reserved
//! before they are mapped, so a full temporary directory is an error naming the file and the
//! directory, nothing is left at `-o`, and the same command run with room writes the bytes of a
//! build that never failed.
//!
//! The full disk is real: a tmpfs of a few pages, mounted in a mount namespace of the test's
//! own (`unshare --user --map-root-user --mount`: no root needed where user namespaces are
//! allowed) and given to `cbdam` as `TMPDIR`. (`ulimit -f` does not reach this path: the
//! file's length is set past the limit before anything is mapped, which fails already.)

use std::path::Path;
use std::process::{Command, Output};

use crate::util::{cbdam, data, names_in, s, skip_unless_ci, stderr, stdout};

/// Exit status of the wrapper when the tmpfs could not be mounted.
const NO_MOUNT: i32 = 97;

/// Runs `cbdam args…` with `TMPDIR` on an empty tmpfs of `bytes` bytes mounted at `mount`
/// (an empty directory) in a mount namespace of its own; `None` (saying why) when the
/// namespace or the mount cannot be made here.
#[cfg(target_os = "linux")]
fn cbdam_with_small_tmpdir(mount: &Path, bytes: u64, args: &[&str]) -> Result<Output, String> {
    let script = format!(
        "mount -t tmpfs -o size={bytes} tmpfs \"$0\" || exit {NO_MOUNT}; TMPDIR=\"$0\" exec \"$@\""
    );
    let output = Command::new("unshare")
        .args(["--user", "--map-root-user", "--mount", "sh", "-c", &script])
        .arg(mount)
        .arg(env!("CARGO_BIN_EXE_cbdam"))
        .args(args)
        .output()
        .map_err(|e| format!("cannot run unshare (util-linux): {e}"))?;
    let err = stderr(&output);
    if output.status.code() == Some(NO_MOUNT) || err.starts_with("unshare: ") {
        return Err(format!(
            "cannot mount a small tmpfs in a namespace of our own: {err}"
        ));
    }
    Ok(output)
}

/// The error of a command that found its temporary directory full: a clear error naming
/// what the file was for, the file and the directory, the error kind's explanation, and no
/// signal or panic.
fn check_named(output: &Output, mount: &Path, what: &str, said: &[&str]) {
    let err = stderr(output);
    assert_eq!(
        output.status.code(),
        Some(1),
        "not a clean failure (a signal is SIGBUS: a mapped write found the disk full): {err}\n{}",
        stdout(output)
    );
    let file = format!("{what}'s temporary file (an unlinked file in {}", s(mount));
    let dir = format!("temporary directory {})", s(mount));
    for needed in [file.as_str(), dir.as_str(), "No space left on device"]
        .iter()
        .chain(said)
    {
        assert!(err.contains(needed), "the error lacks {needed:?}: {err}");
    }
    assert!(!err.contains("panicked"), "a panic: {err}");
}

/// `args` as the `&str`s `cbdam` takes.
fn argv(args: &[String]) -> Vec<&str> {
    args.iter().map(String::as_str).collect()
}

/// `cbdam build` of a plane above `--memory-limit 1M` (lattice and reconstruction field in
/// mapped files) with a 64 KiB temporary directory fails naming the lattice's temporary file and
/// the directory; with room for the lattice only, naming the reconstruction field's. Neither
/// leaves anything at `-o`, and the build run again with room writes what a build that never
/// failed writes. `cbdam verify --against` past its limit fails naming its lattice's file.
#[cfg(target_os = "linux")]
#[test]
fn a_plane_build_whose_temporary_directory_is_full_is_named_and_runs_again() {
    let test = "a_plane_build_whose_temporary_directory_is_full_is_named_and_runs_again";
    let mount = tempfile::tempdir().unwrap();
    let out_dir = tempfile::tempdir().unwrap();
    let rhine = data("rhine_nodata.tif");
    let build = |out: &Path| -> Vec<String> {
        let a = [
            "build",
            &rhine,
            "--max-error",
            "1",
            "--memory-limit",
            "1M",
            "--timings",
        ];
        let mut a: Vec<String> = a.map(String::from).to_vec();
        a.extend(["-o".to_string(), s(out)]);
        a
    };
    let clean = out_dir.path().join("clean.cbdam");
    let built = cbdam(&argv(&build(&clean)));
    assert!(built.status.success(), "{}", stderr(&built));
    assert!(
        stderr(&built).contains("lattice in mapped files"),
        "the limit no longer maps the lattice, so this tests nothing: {}",
        stderr(&built)
    );
    let expected = std::fs::read(&clean).unwrap();
    std::fs::remove_file(&clean).unwrap();
    let out = out_dir.path().join("rhine.cbdam");
    let full = match cbdam_with_small_tmpdir(mount.path(), 64 << 10, &argv(&build(&out))) {
        Ok(o) => o,
        Err(why) => return skip_unless_ci(test, &why),
    };
    let nothing_at = format!("nothing was written at {}", s(&out));
    check_named(
        &full,
        mount.path(),
        "the lattice",
        &["the disk is full", &nothing_at],
    );
    assert!(names_in(out_dir.path()).is_empty(), "left behind at -o");
    // Room for the lattice's arrays (3.4 MB), not for the reconstruction field after them
    // (4.2 MB): the field is named.
    let full = cbdam_with_small_tmpdir(mount.path(), 6_000_000, &argv(&build(&out))).unwrap();
    check_named(
        &full,
        mount.path(),
        "the reconstruction field",
        &["the disk is full", &nothing_at],
    );
    assert!(names_in(out_dir.path()).is_empty(), "left behind at -o");
    let again = cbdam(&argv(&build(&out)));
    assert!(again.status.success(), "{}", stderr(&again));
    assert!(
        std::fs::read(&out).unwrap() == expected,
        "the build run again differs"
    );
    // `verify --against` maps its lattice past half its limit, and decodes by blocks needing
    // about 100 MiB: a larger input (ETOPO5 as a plane, 9.3 M samples) under 200M.
    let etopo = out_dir.path().join("etopo.cbdam");
    let (e, input) = (s(&etopo), data("etopo5_global.tif"));
    let built = cbdam(&["build", &input, "--max-error", "16", "--quiet", "-o", &e]);
    assert!(built.status.success(), "{}", stderr(&built));
    let verify = ["verify", &e, "--against", &input, "--memory-limit", "200M"];
    let full = cbdam_with_small_tmpdir(mount.path(), 64 << 10, &verify).unwrap();
    check_named(&full, mount.path(), "the lattice", &[]);
}
