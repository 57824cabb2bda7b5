//! Sharded builds: `cbdam shard plan|apex|run|merge` by hand, and `python -m cbdam_dask build`
//! on a Dask `LocalCluster` (its requirements installed into a venv under target/), write the
//! bytes `cbdam build` writes with the same arguments, also when a worker is killed mid-build;
//! steps out of order, a missing shard and a work directory of another build are refused by name.

use std::path::Path;

use crate::util::*;

/// Several blocks on the 1000² bundled DEM (and the 999² mosaic cut from it): the cut at level
/// 8, blocks 300 lattice units across.
const BLOCKS: &str = "8,300";

fn build(input: &str, out: &Path) -> Vec<u8> {
    build_quiet(input, out, "1");
    std::fs::read(out).unwrap()
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
    let plan = run_ok(&plan_args("1"));
    assert!(
        plan.contains("\"shards\":3") && plan.contains("\"reused\":false"),
        "{plan}"
    );
    // Steps out of order are refused, saying what to run first.
    run_refused(
        &["shard", "run", "--work", &work, "--shard", "0"],
        &["shard apex --work"],
    );
    run_ok(&["shard", "apex", "--work", &work]);
    run_ok(&["shard", "run", "--work", &work, "--shard", "2"]);
    run_refused(
        &["shard", "merge", "--work", &work],
        &["2 of 3 shards have not finished: shards 0, 1"],
    );
    assert!(
        !d.join("sharded.cbdam").exists(),
        "a merge without shards wrote"
    );
    run_refused(
        &["shard", "run", "--work", &work, "--shard", "3"],
        &["shard 3 does not exist", "3 shards"],
    );
    for shard in ["1", "0"] {
        let line = run_ok(&["shard", "run", "--work", &work, "--shard", shard]);
        assert!(line.contains("0 kept"), "{line}");
    }
    // A repeated shard encodes nothing again.
    let again = run_ok(&["shard", "run", "--work", &work, "--shard", "1"]);
    assert!(again.contains(", 0 encoded,"), "{again}");
    run_ok(&["shard", "merge", "--work", &work]);
    let got = std::fs::read(&out).unwrap();
    assert!(
        got == want,
        "the merged repository differs from cbdam build's"
    );
    // The same plan again is a no-op; another build's is refused, naming the difference.
    assert!(run_ok(&plan_args("1")).contains("\"reused\":true"));
    run_refused(
        &plan_args("2"),
        &["holds the plan of another build", "max_error: 1 → 2"],
    );
    // A work directory of another layout version is refused by every step, saying so.
    let key = Path::new(&work).join("key");
    let text = std::fs::read_to_string(&key).unwrap();
    std::fs::write(&key, text.replace("shard_layout=3\n", "shard_layout=1\n")).unwrap();
    for step in ["apex", "merge"] {
        run_refused(
            &["shard", step, "--work", &work],
            &["planned by another cbdam version (work directory layout 1"],
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
    run_refused(&args, &["not made by `cbdam shard plan`"]);
    assert!(other.join("keep.txt").exists());
}

/// `python -m cbdam_dask build INPUT -o OUT --max-error 1 --scheduler local:3` with several
/// blocks.
fn dask_args(input: &str, out: &Path) -> Vec<String> {
    [
        input,
        "-o",
        &s(out),
        "--max-error",
        "1",
        "--scheduler",
        "local:3",
    ]
    .into_iter()
    .chain(["--block-plan", BLOCKS])
    .map(String::from)
    .collect()
}

#[test]
fn dask_build_of_a_mosaic_is_byte_identical_to_cbdam_builder() {
    let Some(python) = dask::python() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let tiles = d.join("tiles");
    crate::cli::tiles::cut_into_tiles(&data("srtm3_demcompare.tif"), &tiles, 499, 2);
    let want = build(&s(&tiles), &d.join("whole.cbdam"));
    let out = d.join("dask.cbdam");
    let log = dask::build(&python, &dask_args(&s(&tiles), &out), None);
    dask::check_build(&log, &out, &want, Some(3));
}

#[test]
fn dask_build_survives_a_worker_killed_mid_build() {
    let Some(python) = dask::python() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let dem = data("srtm3_demcompare.tif");
    let want = build(&dem, &d.join("whole.cbdam"));
    let out = d.join("dask.cbdam");
    let marker = d.join("killed");
    let log = dask::build(&python, &dask_args(&dem, &out), Some(&marker));
    assert!(marker.exists(), "the kill hook never ran: {log}");
    dask::check_build(&log, &out, &want, None);
}
