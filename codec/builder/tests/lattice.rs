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

/// A smooth raw float32 DEM of `side`² samples, `bump` metres higher in a patch of it.
fn write_raw(path: &Path, side: usize, bump: f32) {
    let mut bytes = Vec::with_capacity(side * side * 4);
    for y in 0..side {
        for x in 0..side {
            let (fx, fy) = (x as f32, y as f32);
            let mut z = 300.0 + 80.0 * (fx / 37.0).sin() * (fy / 23.0).cos() + 0.05 * fx;
            if (200..260).contains(&x) && (300..340).contains(&y) {
                z += bump;
            }
            bytes.extend_from_slice(&z.to_le_bytes());
        }
    }
    std::fs::write(path, bytes).unwrap();
}

fn raw_options(input: &Path, out: &Path, side: usize) -> BuildOptions {
    let mut o = options(input, out, None);
    o.raw_size = Some((side, side));
    o.block_plan = Some(BlockPlan {
        cut_level: 6,
        block_side: 128,
    });
    o
}

/// An input changed in place after a build was interrupted, and given its old size and
/// modification time back, is not resumed from the blocks of its old bytes: the build starts
/// over, names the input, and writes what a fresh build of the new bytes writes.
#[test]
fn a_changed_input_with_its_old_mtime_starts_the_build_over() {
    let dir = tempfile::tempdir().unwrap();
    let side = 1025;
    let (input, changed) = (dir.path().join("in.f32"), dir.path().join("changed.f32"));
    write_raw(&input, side, 0.0);
    write_raw(&changed, side, 50.0);
    let fresh = raw_options(&changed, &dir.path().join("fresh.cbdam"), side);
    let count = Interrupt::after(usize::MAX);
    build(&fresh, &count).unwrap();
    let want = std::fs::read(&fresh.output).unwrap();
    let total = count.total.load(Ordering::Relaxed);
    assert!(total > 10, "{total} units");

    let out = dir.path().join("out.cbdam");
    let stop = Interrupt::after(total * 19 / 20);
    let r = catch_unwind(AssertUnwindSafe(|| {
        build(&raw_options(&input, &out, side), &stop)
    }));
    assert!(r.is_err(), "the build was not interrupted");
    let journal = cbdam_builder::journal::Journal::dir_of(&out);
    assert!(std::fs::read_dir(&journal).unwrap().count() > 2);
    // The patch raised by 50 m, the size and the modification time as they were.
    let mtime = std::fs::metadata(&input).unwrap().modified().unwrap();
    std::fs::copy(&changed, &input).unwrap();
    let file = std::fs::File::options().write(true).open(&input).unwrap();
    file.set_modified(mtime).unwrap();
    drop(file);
    assert_eq!(
        std::fs::metadata(&input).unwrap().modified().unwrap(),
        mtime
    );

    let resume = Interrupt::after(usize::MAX);
    build(&raw_options(&input, &out, side), &resume).unwrap();
    let said = resume.resumed.lock().unwrap().clone().unwrap_or_default();
    assert!(
        said.starts_with("StartedOver") && said.contains(&format!("input: {}", input.display())),
        "{said}"
    );
    assert!(
        std::fs::read(&out).unwrap() == want,
        "the build resumed from blocks of the old input"
    );
}

/// A block file damaged after an interrupted build (cut short, as a power loss may leave it) is
/// counted as encoded again, not as kept, and the resumed build writes the same bytes.
#[test]
fn a_damaged_block_file_is_counted_as_encoded_again() {
    let dir = tempfile::tempdir().unwrap();
    let side = 1025;
    let input = dir.path().join("in.f32");
    write_raw(&input, side, 0.0);
    let whole = raw_options(&input, &dir.path().join("whole.cbdam"), side);
    let count = Interrupt::after(usize::MAX);
    build(&whole, &count).unwrap();
    let want = std::fs::read(&whole.output).unwrap();
    let total = count.total.load(Ordering::Relaxed);

    let out = dir.path().join("out.cbdam");
    let stop = Interrupt::after(total * 19 / 20);
    let r = catch_unwind(AssertUnwindSafe(|| {
        build(&raw_options(&input, &out, side), &stop)
    }));
    assert!(r.is_err(), "the build was not interrupted");
    let mut blocks: Vec<PathBuf> = std::fs::read_dir(cbdam_builder::journal::Journal::dir_of(&out))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| {
            p.file_name()
                .unwrap()
                .to_string_lossy()
                .starts_with("block-")
        })
        .collect();
    blocks.sort();
    assert!(blocks.len() >= 2, "{} blocks", blocks.len());
    let bytes = std::fs::read(&blocks[0]).unwrap();
    std::fs::write(&blocks[0], &bytes[..bytes.len() / 2]).unwrap();

    let resume = Interrupt::after(usize::MAX);
    build(&raw_options(&input, &out, side), &resume).unwrap();
    let said = resume.resumed.lock().unwrap().clone().unwrap_or_default();
    assert_eq!(
        said,
        format!("Continuing {{ blocks: {}, damaged: 1 }}", blocks.len() - 1)
    );
    assert!(
        std::fs::read(&out).unwrap() == want,
        "the resumed build differs"
    );
}
