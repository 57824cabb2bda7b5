//! Sharded planets: `cbdam shard plan --planet` / `apex` / `run` / `merge` by hand, and
//! `python -m cbdam_dask build … --planet` on a Dask `LocalCluster` of 2 (also with a worker
//! killed mid-shard), write the bytes `cbdam build --planet` writes with the same arguments;
//! steps out of order, a missing shard, another plan in the work directory and an input changed
//! since the plan are refused by name. The planet is the small one of `cli::planet` with a void
//! and insets on a cube edge (with a void) and on a cube corner.

use std::path::{Path, PathBuf};
use std::process::Command;

use crate::util::*;

/// The arguments every build of the planet shares: its inputs and `--planet`, N = 17, ε = 1 m.
fn planet_args(paths: &[PathBuf]) -> Vec<String> {
    let mut a: Vec<String> = paths.iter().map(|p| s(p)).collect();
    a.extend(["--planet", "--diamond-size", "17", "--max-error", "1"].map(String::from));
    a
}

/// `cbdam build --planet`'s bytes.
fn built(paths: &[PathBuf], out: &Path) -> Vec<u8> {
    let mut a = vec!["build".to_string()];
    a.extend(planet_args(paths));
    a.extend(["-o".into(), s(out), "--quiet".into()]);
    let o = cbdam(&a.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(o.status.success(), "{}", stderr(&o));
    std::fs::read(out).unwrap()
}

fn ok(args: &[&str]) -> String {
    let o = cbdam(args);
    assert!(o.status.success(), "cbdam {args:?}: {}", stderr(&o));
    stdout(&o)
}

/// `a` as the `&str`s [`cbdam`] takes.
fn args(a: &[String]) -> Vec<&str> {
    a.iter().map(String::as_str).collect()
}

fn refused(args: &[&str]) -> String {
    let o = cbdam(args);
    assert_eq!(o.status.code(), Some(1), "cbdam {args:?}: {}", stdout(&o));
    stderr(&o)
}

#[test]
fn sharded_planet_steps_by_hand_merge_to_the_bytes_of_cbdam_build() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let paths = crate::cli::planet::edge_and_corner_planet(d);
    let want = built(&paths, &d.join("whole.cbdam"));
    let (work, out) = (s(&d.join("work")), s(&d.join("sharded.cbdam")));
    let plan_args = |extra: &[&str]| -> Vec<String> {
        let mut a = vec!["shard".to_string(), "plan".into()];
        a.extend(planet_args(&paths));
        a.extend(["-o", &out, "--work", &work, "--shards", "3"].map(String::from));
        a.extend(extra.iter().map(|e| e.to_string()));
        a
    };
    let plan = |extra: &[&str]| {
        let a = plan_args(extra);
        cbdam(&a.iter().map(String::as_str).collect::<Vec<_>>())
    };
    let o = plan(&[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let json: serde_json::Value = serde_json::from_str(stdout(&o).trim()).unwrap();
    assert_eq!(json["planet"], true, "{json}");
    assert_eq!(json["shards"], 3, "{json}");
    assert_eq!(json["reused"], false, "{json}");
    let blocks = json["blocks"].as_u64().unwrap();
    assert!(blocks >= 6, "one block per lattice tile: {json}");
    let step = |what: &str, shard: Option<&str>| {
        let mut a = vec!["shard", what, "--work", work.as_str()];
        if let Some(i) = shard {
            a.extend(["--shard", i]);
        }
        a.into_iter().map(String::from).collect::<Vec<_>>()
    };
    // Out of order: a shard before the apex, the merge before the shards.
    let e = refused(&args(&step("run", Some("0"))));
    assert!(e.contains("cbdam shard apex --work"), "{e}");
    let e = refused(&args(&step("merge", None)));
    assert!(e.contains("3 of 3 shards have not finished"), "{e}");
    assert!(ok(&args(&step("apex", None))).contains("encoded"));
    ok(&args(&step("run", Some("2"))));
    ok(&args(&step("run", Some("0"))));
    let e = refused(&args(&step("merge", None)));
    assert!(e.contains("1 of 3 shards") && e.contains("shard 1 "), "{e}");
    ok(&args(&step("run", Some("1"))));
    // A retried shard keeps what it finished.
    let again = ok(&args(&step("run", Some("1"))));
    assert!(again.contains(", 0 encoded"), "{again}");
    ok(&args(&step("merge", None)));
    assert!(
        std::fs::read(&out).unwrap() == want,
        "the merged planet differs"
    );
    // The same plan again does nothing; another one is refused, naming the difference.
    let o = plan(&[]);
    assert!(stdout(&o).contains("\"reused\":true"), "{}", stdout(&o));
    let mut other = plan_args(&[]);
    let at = other.iter().position(|a| a == "--max-error").unwrap() + 1;
    other[at] = "2".into();
    let e = refused(&args(&other));
    assert!(e.contains("max_error: 1 → 2"), "{e}");
    // An input changed since the plan: a shard that still has work refuses, naming it.
    std::fs::remove_file(d.join("work/blocks/block-000000")).unwrap();
    let mut f = std::fs::OpenOptions::new()
        .append(true)
        .open(&paths[1])
        .unwrap();
    std::io::Write::write_all(&mut f, b"\0").unwrap();
    let e = refused(&args(&step("run", Some("0"))));
    assert!(
        e.contains(&s(&paths[1])) && e.contains("changed since the plan"),
        "{e}"
    );
}

/// A planet planned with the apex (`plan --apex`, as `cbdam_dask` plans) under a memory limit
/// that makes `cbdam build` take the block path, in one shard: the same bytes.
#[test]
fn a_planet_planned_with_its_apex_in_one_shard_merges_to_the_same_bytes() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let paths = crate::cli::planet::edge_and_corner_planet(d);
    let want = built(&paths, &d.join("whole.cbdam"));
    let (work, out) = (s(&d.join("work")), s(&d.join("sharded.cbdam")));
    let mut a = vec!["shard".to_string(), "plan".into()];
    a.extend(planet_args(&paths));
    a.extend(
        [
            "-o",
            &out,
            "--work",
            &work,
            "--shards",
            "1",
            "--apex",
            "--memory-limit",
            "4M",
        ]
        .map(String::from),
    );
    ok(&a.iter().map(String::as_str).collect::<Vec<_>>());
    ok(&["shard", "run", "--work", &work, "--shard", "0"]);
    let e = refused(&["shard", "run", "--work", &work, "--shard", "1"]);
    assert!(e.contains("shard 1 does not exist"), "{e}");
    ok(&["shard", "merge", "--work", &work]);
    assert!(
        std::fs::read(&out).unwrap() == want,
        "the merged planet differs"
    );
}

/// Runs `python -m cbdam_dask build PLANET -o OUT --scheduler local:2`; `kill_marker`: the test
/// hook that kills one shard task's worker once.
fn dask_planet(python: &Path, paths: &[PathBuf], out: &Path, kill_marker: Option<&Path>) -> String {
    let mut cmd = Command::new(python);
    cmd.args(["-m", "cbdam_dask", "build"])
        .args(planet_args(paths))
        .arg("-o")
        .arg(out)
        .args(["--scheduler", "local:2", "--cbdam"])
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

#[test]
fn dask_build_of_a_planet_is_byte_identical_to_cbdam_build_also_with_a_worker_killed() {
    let Some(python) = crate::cli::shard::dask_python() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let paths = crate::cli::planet::edge_and_corner_planet(d);
    let want = built(&paths, &d.join("whole.cbdam"));
    let out = d.join("dask.cbdam");
    let log = dask_planet(&python, &paths, &out, None);
    assert_eq!(log.matches("] shard ").count(), 2, "{log}");
    assert!(
        std::fs::read(&out).unwrap() == want,
        "the Dask planet differs"
    );
    assert!(
        !d.join("dask.cbdam.shards").exists(),
        "the work directory is left"
    );
    let killed = d.join("killed.cbdam");
    let marker = d.join("killed");
    let log = dask_planet(&python, &paths, &killed, Some(&marker));
    assert!(marker.exists(), "the kill hook never ran: {log}");
    assert!(
        std::fs::read(&killed).unwrap() == want,
        "the Dask planet differs after a kill"
    );
}
