//! Sharded planets: `cbdam shard plan --planet` / `apex` / `run` / `merge` by hand, and
//! `python -m cbdam_dask build … --planet` on a Dask `LocalCluster` of 2 (also with a worker
//! killed mid-shard), write the bytes `cbdam build --planet` writes with the same arguments;
//! steps out of order, a missing shard, another plan in the work directory and an input changed
//! since the plan are refused by name. The planet is the small one of `cli::planet` with a void
//! and insets on a cube edge (with a void) and on a cube corner.

use std::path::{Path, PathBuf};

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
    run_ok(&strs(&a));
    std::fs::read(out).unwrap()
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
    run_refused(&strs(&step("run", Some("0"))), &["cbdam shard apex --work"]);
    run_refused(
        &strs(&step("merge", None)),
        &["3 of 3 shards have not finished"],
    );
    assert!(run_ok(&strs(&step("apex", None))).contains("encoded"));
    run_ok(&strs(&step("run", Some("2"))));
    run_ok(&strs(&step("run", Some("0"))));
    run_refused(&strs(&step("merge", None)), &["1 of 3 shards", "shard 1 "]);
    run_ok(&strs(&step("run", Some("1"))));
    // A retried shard keeps what it finished.
    let again = run_ok(&strs(&step("run", Some("1"))));
    assert!(again.contains(", 0 encoded"), "{again}");
    run_ok(&strs(&step("merge", None)));
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
    run_refused(&strs(&other), &["max_error: 1 → 2"]);
    // An input changed since the plan: a shard that still has work refuses, naming it.
    std::fs::remove_file(d.join("work/blocks/block-000000")).unwrap();
    let mut f = std::fs::OpenOptions::new()
        .append(true)
        .open(&paths[1])
        .unwrap();
    std::io::Write::write_all(&mut f, b"\0").unwrap();
    run_refused(
        &strs(&step("run", Some("0"))),
        &[&s(&paths[1]), "changed since the plan"],
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
    run_ok(&strs(&a));
    run_ok(&["shard", "run", "--work", &work, "--shard", "0"]);
    run_refused(
        &["shard", "run", "--work", &work, "--shard", "1"],
        &["shard 1 does not exist"],
    );
    run_ok(&["shard", "merge", "--work", &work]);
    assert!(
        std::fs::read(&out).unwrap() == want,
        "the merged planet differs"
    );
}

/// `python -m cbdam_dask build PLANET -o OUT --scheduler local:2`.
fn dask_args(paths: &[PathBuf], out: &Path) -> Vec<String> {
    let mut a = planet_args(paths);
    a.extend(["-o".into(), s(out), "--scheduler".into(), "local:2".into()]);
    a
}

#[test]
fn dask_build_of_a_planet_is_byte_identical_to_cbdam_build_also_with_a_worker_killed() {
    let Some(python) = dask::python() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let paths = crate::cli::planet::edge_and_corner_planet(d);
    let want = built(&paths, &d.join("whole.cbdam"));
    let out = d.join("dask.cbdam");
    let log = dask::build(&python, &dask_args(&paths, &out), None);
    dask::check_build(&log, &out, &want, Some(2));
    let killed = d.join("killed.cbdam");
    let marker = d.join("killed");
    let log = dask::build(&python, &dask_args(&paths, &killed), Some(&marker));
    assert!(marker.exists(), "the kill hook never ran: {log}");
    dask::check_build(&log, &killed, &want, None);
}

/// A `cbdam shard run` of a planet killed (SIGKILL) after some of its blocks, run again, keeps
/// the blocks it finished and encodes the rest; the merge writes `cbdam build --planet`'s bytes.
#[test]
fn a_killed_planet_shard_run_resumes_and_merges_to_the_same_bytes() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let paths = crate::cli::planet::edge_and_corner_planet(d);
    let want = built(&paths, &d.join("whole.cbdam"));
    let (work, out) = (d.join("work"), d.join("sharded.cbdam"));
    let mut plan = vec!["shard".to_string(), "plan".into()];
    plan.extend(planet_args(&paths));
    plan.extend(
        [
            "-o",
            &s(&out),
            "--work",
            &s(&work),
            "--shards",
            "1",
            "--apex",
        ]
        .map(String::from),
    );
    run_ok(&strs(&plan));
    let run: Vec<String> = ["shard", "run", "--work", &s(&work), "--shard", "0"]
        .map(String::from)
        .to_vec();
    let blocks = work.join("blocks");
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_cbdam"))
        .args(&run)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let start = std::time::Instant::now();
    while journal_blocks(&blocks) < 2 {
        assert!(child.try_wait().unwrap().is_none(), "the shard ended first");
        assert!(start.elapsed().as_secs() < 120, "no block to kill after");
        std::thread::sleep(std::time::Duration::from_millis(2));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    let kept = journal_blocks(&blocks);
    let again = run_ok(&strs(&run));
    assert!(
        again.contains(&format!("{kept} kept from an earlier run")),
        "{kept} blocks were finished: {again}"
    );
    run_ok(&strs(
        &["shard", "merge", "--work", &s(&work)].map(String::from),
    ));
    assert!(
        std::fs::read(&out).unwrap() == want,
        "the merged planet differs"
    );
}
