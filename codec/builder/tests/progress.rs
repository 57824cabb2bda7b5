//! Progress events arrive stage by stage, in order, and each stage reaches its total.

use std::sync::Mutex;

use cbdam_builder::{BuildOptions, ProgressEvent, Stage, build};

use crate::util::data;

fn events(mut opts: BuildOptions) -> Vec<ProgressEvent> {
    // One worker: the encoder's events come from one thread, so their order is the order of
    // the work.
    opts.threads = Some(1);
    let seen = Mutex::new(Vec::new());
    build(&opts, &|e: ProgressEvent| seen.lock().unwrap().push(e)).unwrap();
    seen.into_inner().unwrap()
}

/// The stages seen, each once and in order; within each, `done` never decreases, never passes
/// `total`, and ends at it.
fn check(events: &[ProgressEvent]) -> Vec<Stage> {
    let mut stages: Vec<Stage> = Vec::new();
    for w in events.windows(2) {
        assert!(w[0].stage <= w[1].stage, "{w:?}");
        if w[0].stage == w[1].stage {
            assert!(w[0].done <= w[1].done && w[0].total == w[1].total, "{w:?}");
        }
    }
    for e in events {
        assert!(e.done <= e.total && e.total > 0, "{e:?}");
        if stages.last() != Some(&e.stage) {
            stages.push(e.stage);
        }
    }
    for &s in &stages {
        let last = events.iter().rfind(|e| e.stage == s).unwrap();
        assert_eq!(last.done, last.total, "{s:?}: {events:?}");
    }
    stages
}

#[test]
fn elevation_progress_is_in_order_and_complete() {
    let dir = tempfile::tempdir().unwrap();
    let opts = BuildOptions::new(
        vec![data("jacksboro_mpl.tif")],
        dir.path().join("j.cbdam"),
        1.0,
    );
    let ev = events(opts);
    assert_eq!(
        check(&ev),
        [
            Stage::Prepare,
            Stage::Encode,
            Stage::EncodeCoarserRoots,
            Stage::Write
        ]
    );
    // The encoder reports more than its start and end.
    assert!(ev.iter().filter(|e| e.stage == Stage::Encode).count() > 2);
}

#[test]
fn colour_progress_is_in_order_and_complete() {
    let dir = tempfile::tempdir().unwrap();
    let mut opts = BuildOptions::new(
        vec![data("fuji_terrainrgb.png")],
        dir.path().join("c.cbdam"),
        2.0,
    );
    opts.colour = true;
    let ev = events(opts);
    assert_eq!(check(&ev), [Stage::Prepare, Stage::Encode, Stage::Write]);
}
