//! Sharded builds: `cbdam shard plan|apex|run|merge` by hand, and `python -m cbdam_dask build`
//! on a Dask `LocalCluster` (its requirements installed into a venv under target/), write the
//! bytes `cbdam build` writes with the same arguments, also when a worker is killed mid-build;
//! steps out of order, a missing shard and a work directory of another build are refused by name.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

use crate::util::*;

/// Several blocks on the 1000² bundled DEM (and the 999² mosaic cut from it): the cut at level
/// 8, blocks 300 lattice units across.
const BLOCKS: &str = "8,300";

fn build(input: &str, out: &Path) -> Vec<u8> {
    let o = cbdam(&["build", input, "-o", &s(out), "--max-error", "1", "--quiet"]);
    assert!(o.status.success(), "{}", stderr(&o));
    std::fs::read(out).unwrap()
}

fn ok(args: &[&str]) -> String {
    let o = cbdam(args);
    assert!(o.status.success(), "cbdam {args:?}: {}", stderr(&o));
    stdout(&o)
}

fn refused(args: &[&str]) -> String {
    let o = cbdam(args);
    assert_eq!(o.status.code(), Some(1), "cbdam {args:?}: {}", stdout(&o));
    stderr(&o)
}

#[test]
fn shard_steps_by_hand_merge_to_the_bytes_of_cbdam_builder() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let dem = data("srtm3_demcompare.tif");
    let want = build(&dem, &d.join("whole.cbdam"));
    let work = s(&d.join("work"));
    let out = s(&d.join("sharded.cbdam"));
    let plan_args = |max_error: &'static str| {
        vec![
            "shard",
            "plan",
            dem.as_str(),
            "-o",
            out.as_str(),
            "--max-error",
            max_error,
            "--block-plan",
            BLOCKS,
            "--work",
            work.as_str(),
            "--shards",
            "3",
        ]
    };
    let plan = ok(&plan_args("1"));
    assert!(
        plan.contains("\"shards\":3") && plan.contains("\"reused\":false"),
        "{plan}"
    );
    // Steps out of order are refused, saying what to run first.
    let e = refused(&["shard", "run", "--work", &work, "--shard", "0"]);
    assert!(e.contains("shard apex --work"), "{e}");
    ok(&["shard", "apex", "--work", &work]);
    ok(&["shard", "run", "--work", &work, "--shard", "2"]);
    let e = refused(&["shard", "merge", "--work", &work]);
    assert!(
        e.contains("2 of 3 shards have not finished: shards 0, 1"),
        "{e}"
    );
    assert!(
        !d.join("sharded.cbdam").exists(),
        "a merge without shards wrote"
    );
    let e = refused(&["shard", "run", "--work", &work, "--shard", "3"]);
    assert!(
        e.contains("shard 3 does not exist") && e.contains("3 shards"),
        "{e}"
    );
    for shard in ["1", "0"] {
        let line = ok(&["shard", "run", "--work", &work, "--shard", shard]);
        assert!(line.contains("0 kept"), "{line}");
    }
    // A repeated shard encodes nothing again.
    let again = ok(&["shard", "run", "--work", &work, "--shard", "1"]);
    assert!(again.contains(", 0 encoded,"), "{again}");
    ok(&["shard", "merge", "--work", &work]);
    let got = std::fs::read(&out).unwrap();
    assert!(
        got == want,
        "the merged repository differs from cbdam build's"
    );
    // The same plan again is a no-op; another build's is refused, naming the difference.
    assert!(ok(&plan_args("1")).contains("\"reused\":true"));
    let e = refused(&plan_args("2"));
    assert!(
        e.contains("holds the plan of another build") && e.contains("max_error: 1 → 2"),
        "{e}"
    );
    // A work directory of another layout version is refused by every step, saying so.
    let key = Path::new(&work).join("key");
    let text = std::fs::read_to_string(&key).unwrap();
    std::fs::write(&key, text.replace("shard_layout=3\n", "shard_layout=1\n")).unwrap();
    for step in ["apex", "merge"] {
        let e = refused(&["shard", step, "--work", &work]);
        assert!(
            e.contains("planned by another cbdam version (work directory layout 1"),
            "{e}"
        );
    }
    std::fs::write(&key, text).unwrap();
    // A directory that is not a work directory is never cleared.
    let other = d.join("other");
    std::fs::create_dir(&other).unwrap();
    std::fs::write(other.join("keep.txt"), "mine").unwrap();
    let mut args = plan_args("1");
    let other_s = s(&other);
    let at = args.iter().position(|&a| a == "--work").unwrap() + 1;
    args[at] = other_s.as_str();
    let e = refused(&args);
    assert!(e.contains("not made by `cbdam shard plan`"), "{e}");
    assert!(other.join("keep.txt").exists());
}

/// The Python of a venv under target/ with codec/builder/dask/requirements.txt installed (made
/// once per target directory); `None`, with the reason printed, only when pip or venv is
/// missing, and then only outside CI: under CI that fails the test ([`skip_unless_ci`]).
pub(crate) fn dask_python() -> Option<PathBuf> {
    static PYTHON: OnceLock<Option<PathBuf>> = OnceLock::new();
    PYTHON
        .get_or_init(|| {
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
            // Debian's python3 has the venv module without the ensurepip it needs
            // (python3-venv), and no pip (python3-pip).
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
        })
        .clone()
}

/// Runs `python -m cbdam_dask build INPUT -o OUT --max-error 1 --scheduler local:3` with
/// several blocks; `kill_marker`: the test hook that kills one shard task's worker once.
fn dask_build(python: &Path, input: &str, out: &Path, kill_marker: Option<&Path>) -> String {
    let mut cmd = Command::new(python);
    cmd.args(["-m", "cbdam_dask", "build", input, "-o"])
        .arg(out)
        .args(["--max-error", "1", "--scheduler", "local:3", "--cbdam"])
        .arg(env!("CARGO_BIN_EXE_cbdam"))
        .args(["--block-plan", BLOCKS])
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

#[test]
fn dask_build_of_a_mosaic_is_byte_identical_to_cbdam_builder() {
    let Some(python) = dask_python() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let tiles = d.join("tiles");
    crate::cli::tiles::cut_into_tiles(&data("srtm3_demcompare.tif"), &tiles, 499, 2);
    let want = build(&s(&tiles), &d.join("whole.cbdam"));
    let out = d.join("dask.cbdam");
    let log = dask_build(&python, &s(&tiles), &out, None);
    // One line per shard when not on a terminal: one shard per worker.
    assert_eq!(log.matches("] shard ").count(), 3, "{log}");
    assert!(
        std::fs::read(&out).unwrap() == want,
        "the Dask build differs"
    );
    assert!(
        !d.join("dask.cbdam.shards").exists(),
        "the work directory is left"
    );
}

#[test]
fn dask_build_survives_a_worker_killed_mid_build() {
    let Some(python) = dask_python() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let dem = data("srtm3_demcompare.tif");
    let want = build(&dem, &d.join("whole.cbdam"));
    let out = d.join("dask.cbdam");
    let marker = d.join("killed");
    let log = dask_build(&python, &dem, &out, Some(&marker));
    assert!(marker.exists(), "the kill hook never ran: {log}");
    assert!(
        std::fs::read(&out).unwrap() == want,
        "the Dask build differs"
    );
}
