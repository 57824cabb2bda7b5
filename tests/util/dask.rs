//! The Dask bridge (`python -m cbdam_dask`, codec/builder/dask) as the CLI tests run it: one venv
//! with its requirements per target directory, and one way to run a build through it.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

use super::skip_unless_ci;

/// The Python of a venv under target/ with codec/builder/dask/requirements.txt installed (made
/// once per target directory); `None`, with the reason printed, only when pip or venv is
/// missing, and then only outside CI: under CI that fails the test ([`skip_unless_ci`]).
pub fn python() -> Option<PathBuf> {
    static PYTHON: OnceLock<Option<PathBuf>> = OnceLock::new();
    PYTHON.get_or_init(make_venv).clone()
}

fn make_venv() -> Option<PathBuf> {
    let venv = Path::new(env!("CARGO_TARGET_TMPDIR")).join("cbdam-dask-venv");
    let python = venv.join("bin").join("python");
    let imports = |p: &Path| {
        Command::new(p)
            .args(["-c", "import dask.distributed"])
            .output()
            .is_ok_and(|o| o.status.success())
    };
    if imports(&python) {
        return Some(python);
    }
    // Debian's python3 has the venv module without the ensurepip it needs (python3-venv), and
    // no pip (python3-pip).
    for (module, probe) in [("pip", "import pip"), ("venv", "import venv, ensurepip")] {
        let there = Command::new("python3")
            .args(["-c", probe])
            .output()
            .is_ok_and(|o| o.status.success());
        if !there {
            skip_unless_ci(
                "the Dask tests",
                &format!(
                    "`python3 -m {module}` is not available, so the Dask requirements \
                     (codec/builder/dask/requirements.txt) cannot be installed \
                     (apt-get install python3-pip python3-venv)"
                ),
            );
            return None;
        }
    }
    let run = |cmd: &mut Command| {
        let o = cmd.output().expect("run python3");
        assert!(
            o.status.success(),
            "{cmd:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
    };
    run(Command::new("python3").args(["-m", "venv"]).arg(&venv));
    let requirements =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("codec/builder/dask/requirements.txt");
    run(Command::new(&python)
        .args(["-m", "pip", "install", "--quiet", "-r"])
        .arg(&requirements));
    assert!(
        imports(&python),
        "dask.distributed does not import after install"
    );
    Some(python)
}

/// Runs `python -m cbdam_dask build ARGS --cbdam <the cbdam under test>` and returns its log
/// (stderr), failing the test if it fails. `kill_marker`: the test hook that kills one shard
/// task's worker once, and leaves this file to say it did.
pub fn build(python: &Path, args: &[String], kill_marker: Option<&Path>) -> String {
    let mut cmd = Command::new(python);
    cmd.args(["-m", "cbdam_dask", "build"])
        .args(args)
        .arg("--cbdam")
        .arg(env!("CARGO_BIN_EXE_cbdam"))
        .env(
            "PYTHONPATH",
            Path::new(env!("CARGO_MANIFEST_DIR")).join("codec/builder/dask"),
        );
    if let Some(m) = kill_marker {
        cmd.env("CBDAM_DASK_TEST_KILL_ONCE", m);
    }
    let o = cmd.output().expect("run python -m cbdam_dask");
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(o.status.success(), "cbdam_dask failed: {err}");
    err
}

/// Checks what every Dask build must leave: `out` holds `want`'s bytes, the work directory
/// (`OUT.shards`) is gone, and the log names one shard per worker (`shards` of them) —
/// `shards` `None` when a killed worker makes the count vary.
pub fn check_build(log: &str, out: &Path, want: &[u8], shards: Option<usize>) {
    if let Some(n) = shards {
        // One line per shard when not on a terminal.
        assert_eq!(log.matches("] shard ").count(), n, "{log}");
    }
    assert!(
        std::fs::read(out).unwrap() == want,
        "the Dask build {} differs from cbdam's",
        out.display()
    );
    let mut work = out.as_os_str().to_owned();
    work.push(".shards");
    assert!(
        !Path::new(&work).exists(),
        "the work directory is left: {}",
        Path::new(&work).display()
    );
}
