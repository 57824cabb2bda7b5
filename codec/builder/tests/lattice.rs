//! The quantized lattice out of core: under a `--memory-limit` it exceeds half of, the grid
//! (and a mosaic's classes) go to memory-mapped temporary files, and the build writes the same
//! bytes as with the lattice in memory — single files, with the field in memory, in blocks or
//! mapped too, and block builds interrupted with one storage and resumed with the other.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

use cbdam_builder::journal::Resumed;
use cbdam_builder::{
    BuildOptions, BuildSummary, ElevationSummary, NoProgress, Progress, ProgressEvent, Stage, build,
};
use cbdam_codec::hierarchy::BlockPlan;

use crate::util::data;

fn options(input: &Path, out: &Path, limit: Option<u64>) -> BuildOptions {
    let mut o = BuildOptions::new(vec![input.to_path_buf()], out.to_path_buf(), 1.0);
    o.memory_limit = limit;
    o
}

fn elevation(s: BuildSummary) -> ElevationSummary {
    match s {
        BuildSummary::Elevation(e) => e,
        _ => panic!("not an elevation build"),
    }
}

/// Builds and returns the summary and the repository's bytes.
fn build_bytes(opts: &BuildOptions) -> (ElevationSummary, Vec<u8>) {
    let s = elevation(build(opts, &NoProgress).unwrap());
    (s, std::fs::read(&opts.output).unwrap())
}

/// A file with nodata (997 × 682, 5 bytes a point: 3.4 MB of lattice) under limits that keep
/// the lattice in memory, and that map it with the reconstruction in blocks and in a mapped
/// file: the same bytes, and the summary says where the lattice went.
#[test]
fn a_mapped_lattice_builds_the_same_bytes_as_one_in_memory() {
    let dir = tempfile::tempdir().unwrap();
    let input = data("rhine_nodata.tif");
    let (free, want) = build_bytes(&options(&input, &dir.path().join("free.cbdam"), None));
    assert!(!free.lattice_mapped, "{}", free.temporaries);
    for (limit, field) in [(6u64 << 20, "blocks of"), (4 << 10, "mapped file")] {
        let out = dir.path().join(format!("{limit}.cbdam"));
        let (s, got) = build_bytes(&options(&input, &out, Some(limit)));
        assert!(s.lattice_mapped, "{limit}: {}", s.temporaries);
        assert!(
            s.temporaries.contains(field) && s.temporaries.ends_with("lattice in mapped files"),
            "{limit}: {}",
            s.temporaries
        );
        assert_eq!(s.valid, free.valid, "{limit}");
        assert!(
            got == want,
            "{limit}: the mapped lattice changed the repository"
        );
    }
}

/// Reports nothing, but panics (interrupting the build) once `stop_after` encode units are done,
/// and records the encode's units and whether the build resumed.
struct Interrupt {
    stop_after: usize,
    /// Panics so far (one is enough).
    panics: AtomicUsize,
    total: AtomicUsize,
    resumed: Mutex<Option<String>>,
}

impl Interrupt {
    fn after(stop_after: usize) -> Self {
        Self {
            stop_after,
            panics: AtomicUsize::new(0),
            total: AtomicUsize::new(0),
            resumed: Mutex::new(None),
        }
    }
}

impl Progress for Interrupt {
    fn event(&self, e: ProgressEvent) {
        if e.stage == Stage::Encode && e.done > 0 {
            self.total.fetch_max(e.total, Ordering::Relaxed);
            if e.done >= self.stop_after && self.panics.fetch_add(1, Ordering::Relaxed) == 0 {
                panic!(
                    "interrupted on purpose after {} of {} units",
                    e.done, e.total
                );
            }
        }
    }

    fn resumed(&self, r: &Resumed) {
        *self.resumed.lock().unwrap() = Some(format!("{r:?}"));
    }
}

/// A block build interrupted after some blocks with the lattice mapped resumes with it in memory,
/// and the other way round: the journal's blocks are the same whichever storage wrote them.
#[test]
fn block_builds_resume_across_lattice_storages_with_the_same_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let input = data("rhine_nodata.tif");
    let plan = BlockPlan {
        cut_level: 6,
        block_side: 128,
    };
    let with_plan = |out: &PathBuf, limit: Option<u64>| {
        let mut o = options(&input, out, limit);
        o.block_plan = Some(plan);
        o
    };
    let whole = with_plan(&dir.path().join("whole.cbdam"), None);
    let count = Interrupt::after(usize::MAX);
    build(&whole, &count).unwrap();
    let want = std::fs::read(&whole.output).unwrap();
    let total = count.total.load(Ordering::Relaxed);
    assert!(total > 100, "{total} units");
    for (first, second) in [(Some(4 << 10), None), (None, Some(4 << 10))] {
        let out = dir.path().join(format!("{first:?}.cbdam"));
        let stop = Interrupt::after(total * 2 / 3);
        let r = catch_unwind(AssertUnwindSafe(|| build(&with_plan(&out, first), &stop)));
        assert!(r.is_err(), "the build was not interrupted");
        assert!(!out.exists());
        let resume = Interrupt::after(usize::MAX);
        let s = elevation(build(&with_plan(&out, second), &resume).unwrap());
        assert_eq!(s.lattice_mapped, second.is_some());
        let said = resume.resumed.lock().unwrap().clone().unwrap_or_default();
        assert!(
            said.starts_with("Continuing"),
            "{first:?} → {second:?}: {said}"
        );
        assert!(
            std::fs::read(&out).unwrap() == want,
            "{first:?} → {second:?}: the resumed build differs"
        );
    }
}
