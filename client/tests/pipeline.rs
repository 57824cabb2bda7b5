//! The pipelined decoder (issue 21): decoding ahead of the cut between frames must not change
//! what is drawn. Replays the example flights on a small repository with a tight budget, so
//! that refinements are decoded ahead and taken from the decoded cache, and checks the drawn
//! patches against the synchronous reference decoder ([`decode_cut`]) along the way, and the
//! converged cut against the cut computed directly from the index (`brute_force`) and the
//! patches again.

use std::path::Path;
use std::time::Duration;

use cbdam_client::access::LocalSource;
use cbdam_client::flight::Flight;
use cbdam_client::patch::{HalfPatch, decode_cut};
use cbdam_client::refine::{RefineConfig, Refiner};
use cbdam_client::spawn::{DecodePool, Spawner};
use cbdam_client::world::World;

use crate::streaming::{brute_force, refined_set, repository, repository_with};

fn flights() -> Vec<(String, Flight)> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/flights");
    let mut out: Vec<(String, Flight)> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "json"))
        .map(|p| {
            let name = p.file_stem().unwrap().to_string_lossy().into_owned();
            (name, Flight::load(&p).unwrap())
        })
        .collect();
    out.sort_by(|a, b| a.0.cmp(&b.0));
    assert!(
        out.len() >= 2,
        "the example flights are in {}",
        dir.display()
    );
    out
}

fn drawn(r: &Refiner<LocalSource>) -> Vec<HalfPatch> {
    r.drawn().map(|p| (**p).clone()).collect()
}

#[test]
fn decoding_ahead_draws_what_the_reference_decoder_draws_and_converges_to_the_same_cut() {
    let repo = repository();
    let world = World::of_repository(&repo);
    let size = (640, 480);
    let fps = 10.0;
    for (name, flight) in flights() {
        let config = RefineConfig {
            budget: Some(Duration::from_micros(300)),
            gc_interval: 3,
            ..RefineConfig::default()
        };
        assert!(config.decode_ahead, "on by default");
        let mut r = Refiner::new(LocalSource::new(repo.clone()), config).unwrap();
        let frames = (flight.duration() * fps).ceil() as usize + 1;
        let (mut ahead, mut refined_ahead, mut checked) = (0, 0, 0);
        for f in 0..frames {
            let cam = flight.camera(&world, (f as f64 / fps).min(flight.duration()), size);
            let s = r.frame(&cam);
            ahead += s.decoded_ahead;
            refined_ahead += s.refined_ahead;
            if f % 16 == 0 {
                let reference = decode_cut(&repo, r.cut()).unwrap();
                assert!(
                    drawn(&r) == reference,
                    "{name}, frame {f}: patches differ from decode_cut"
                );
                checked += 1;
            }
        }
        let cam = flight.camera(&world, flight.duration(), size);
        let mut converged = false;
        for _ in 0..2000 {
            let s = r.frame(&cam);
            ahead += s.decoded_ahead;
            refined_ahead += s.refined_ahead;
            if s.converged {
                converged = true;
                break;
            }
            // Give the workers time, as a viewer's frame interval does.
            std::thread::sleep(Duration::from_micros(500));
        }
        assert!(converged, "{name}: no convergence");
        let expected = brute_force(&repo, &cam, 1.0);
        assert!(expected.len() > 20, "{name}: the view must need detail");
        assert_eq!(refined_set(r.cut()), expected, "{name}: converged cut");
        let reference = decode_cut(&repo, r.cut()).unwrap();
        assert!(
            drawn(&r) == reference,
            "{name}: converged patches differ from decode_cut"
        );
        assert!(checked > 3);
        assert!(
            ahead > 0 && refined_ahead > 0,
            "{name}: nothing was decoded ahead ({ahead}) or refined from it ({refined_ahead})"
        );
    }
}

/// Where the repository has nodata, the halves drawn while decoding ahead carry the nodata
/// masks the reference decoder gives them (each half's mask read from its parent's record
/// mask), along a flight and converged.
#[test]
fn decoding_ahead_draws_the_reference_nodata_masks() {
    // A disc and a diagonal strip of nodata, crossing many diamonds' split diagonals.
    let repo =
        repository_with(|x, y| (x - 60.0).hypot(y - 70.0) < 18.0 || (x - y - 90.0).abs() < 4.0);
    let world = World::of_repository(&repo);
    let size = (640, 480);
    let (name, flight) = flights().into_iter().next().expect("a flight");
    let config = RefineConfig {
        budget: Some(Duration::from_micros(300)),
        ..RefineConfig::default()
    };
    let mut r = Refiner::new(LocalSource::new(repo.clone()), config).unwrap();
    let mut masked = 0;
    let mut compare = |r: &Refiner<LocalSource>, when: &str| {
        let patches = drawn(r);
        assert!(
            patches == decode_cut(&repo, r.cut()).unwrap(),
            "{name}, {when}: patches differ from decode_cut"
        );
        masked += patches.iter().filter(|p| p.valid.is_some()).count();
    };
    let frames = (flight.duration() * 10.0).ceil() as usize + 1;
    for f in 0..frames {
        let cam = flight.camera(&world, (f as f64 / 10.0).min(flight.duration()), size);
        r.frame(&cam);
        if f % 16 == 0 {
            compare(&r, &format!("frame {f}"));
        }
    }
    let cam = flight.camera(&world, flight.duration(), size);
    let mut converged = false;
    for _ in 0..2000 {
        if r.frame(&cam).converged {
            converged = true;
            break;
        }
        std::thread::sleep(Duration::from_micros(500));
    }
    assert!(converged, "{name}: no convergence");
    compare(&r, "converged");
    assert!(masked > 0, "{name}: no drawn half had a nodata mask");
}

/// Decoding ahead is planned last in its frame and stops at the end of the budget once it has
/// taken a diamond per free worker: with a budget that is always spent, a frame hands each
/// worker at most one diamond to decode ahead, and still hands them one.
#[test]
fn decoding_ahead_stops_at_the_budget_but_keeps_the_workers_busy() {
    let repo = repository();
    let world = World::of_repository(&repo);
    let workers = DecodePool.parallelism();
    for (name, flight) in flights() {
        let config = RefineConfig {
            budget: Some(Duration::from_nanos(1)),
            ..RefineConfig::default()
        };
        let mut r = Refiner::new(LocalSource::new(repo.clone()), config).unwrap();
        let frames = 40;
        let mut ahead = 0;
        for f in 0..frames {
            let t = flight.duration() * f as f64 / frames as f64;
            ahead += r.frame(&flight.camera(&world, t, (640, 480))).decoded_ahead;
            // Time for the workers to finish what they were given, as a viewer's frame
            // interval gives them.
            std::thread::sleep(Duration::from_millis(4));
        }
        assert!(ahead > 0, "{name}: nothing was decoded ahead");
        assert!(
            ahead <= frames * workers,
            "{name}: {ahead} diamonds decoded ahead in {frames} frames with {workers} workers"
        );
    }
}

/// The codec's `refine` benchmark on a repository file: every record refined once, in file
/// order, on one thread, its grid gathered beforehand (not timed), output samples `(N−1)²` per
/// record — what `cbdam replay`'s "M cells/s" (in-loop decoding, per second of worker time)
/// is compared with. `CBDAM_BENCH_REPO=FILE cargo test --release -p cbdam-client --test tests
/// refine_bench -- --ignored --nocapture`
#[test]
#[ignore = "a benchmark: needs CBDAM_BENCH_REPO"]
fn refine_bench_on_a_repository() {
    use cbdam_codec::hierarchy::{RefineScratch, Refined};
    use cbdam_codec::repository::Repository;
    use std::collections::HashMap;
    let path = std::env::var("CBDAM_BENCH_REPO").expect("CBDAM_BENCH_REPO=FILE");
    let repo = Repository::open(Path::new(&path)).unwrap();
    let decoder = repo.head().decoder().unwrap();
    let domain = repo.head().params().domain;
    let mut refined: HashMap<_, Refined> = HashMap::new();
    let mut grids = Vec::new();
    let mut scratch = RefineScratch::default();
    for e in repo.head().entries() {
        let parents = domain
            .parents(e.id)
            .map(|p| p.and_then(|p| refined.get(&p)));
        let grid = decoder.grid_of(e.id, parents);
        let r = decoder
            .refine(e.id, &grid, repo.record(e.id).unwrap(), &mut scratch)
            .unwrap();
        grids.push(grid);
        refined.insert(e.id, r);
    }
    let cells = (domain.n() - 1).pow(2) * repo.head().entries().len();
    let mut runs = Vec::new();
    for _ in 0..5 {
        let t = std::time::Instant::now();
        for (e, grid) in repo.head().entries().iter().zip(&grids) {
            std::hint::black_box(
                decoder
                    .refine(e.id, grid, repo.record(e.id).unwrap(), &mut scratch)
                    .unwrap(),
            );
        }
        runs.push(cells as f64 / t.elapsed().as_secs_f64() / 1e6);
    }
    runs.sort_by(f64::total_cmp);
    println!(
        "{path}: {} records, refine {:.1} M cells/s (median of 5; min {:.1}, max {:.1})",
        repo.head().entries().len(),
        runs[2],
        runs[0],
        runs[4]
    );
}

/// Where a worker's time per diamond goes beyond the `refine` bench, on a repository file: every
/// record refined in file order on one thread (grids gathered beforehand, not timed), then
/// - `refine`: the refinement alone (the bench);
/// - `+ halves, dropped`: and the four children's halves made from it (`HalfPatch::from_parent`,
///   what `DecodeJob::node` adds), all dropped at once, so the allocator hands the same memory
///   back every time;
/// - `+ halves, kept`: the same, every refinement and half kept until the round ends, as the
///   client's cache kept them before nodes dropped their refinements: new memory for every
///   diamond;
/// - `+ halves kept, refinement dropped`: the halves kept and each refinement dropped once they
///   are made, as a node decoded in place keeps them now (`cbdam replay`).
///
/// Rates in M cells/s (`(N−1)²` a record) of the thread's CPU time, median of 5 rounds.
/// `CBDAM_BENCH_REPO=FILE cargo test --release -p cbdam-client --test tests worker_decode_cost
/// -- --ignored --nocapture`
#[test]
#[ignore = "a benchmark: needs CBDAM_BENCH_REPO"]
fn worker_decode_cost_on_a_repository() {
    use cbdam_client::stats::thread_cpu_seconds;
    use cbdam_codec::hierarchy::{RefineScratch, Refined};
    use cbdam_codec::repository::Repository;
    use std::collections::HashMap;
    let path = std::env::var("CBDAM_BENCH_REPO").expect("CBDAM_BENCH_REPO=FILE");
    let repo = Repository::open(Path::new(&path)).unwrap();
    let decoder = repo.head().decoder().unwrap();
    let domain = repo.head().params().domain;
    let entries = repo.head().entries();
    let mut refined: HashMap<_, Refined> = HashMap::new();
    let mut grids = Vec::new();
    let mut scratch = RefineScratch::default();
    for e in entries {
        let parents = domain
            .parents(e.id)
            .map(|p| p.and_then(|p| refined.get(&p)));
        let grid = decoder.grid_of(e.id, parents);
        let r = decoder.refine(e.id, &grid, repo.record(e.id).unwrap(), &mut scratch);
        grids.push(grid);
        refined.insert(e.id, r.unwrap());
    }
    let cells = ((domain.n() - 1).pow(2) * entries.len()) as f64;
    let halves = |id, r: &Refined| {
        domain
            .children(id)
            .map(|c| c.and_then(|c| HalfPatch::from_parent(&domain, c, id, r)))
    };
    let mut rate = |with_halves: bool, keep: bool, keep_refined: bool| {
        let mut runs = Vec::new();
        for _ in 0..5 {
            let mut kept = Vec::new();
            let t = thread_cpu_seconds().expect("a thread CPU clock");
            for (e, grid) in entries.iter().zip(&grids) {
                let record = repo.record(e.id).unwrap();
                let r = decoder.refine(e.id, grid, record, &mut scratch).unwrap();
                let h = with_halves.then(|| halves(e.id, &r));
                if keep {
                    kept.push((keep_refined.then_some(r), h));
                } else {
                    std::hint::black_box((r, h));
                }
            }
            runs.push(cells / (thread_cpu_seconds().unwrap() - t) / 1e6);
            drop(kept);
        }
        runs.sort_by(f64::total_cmp);
        runs[2]
    };
    let bench = rate(false, false, false);
    let dropped = rate(true, false, false);
    let kept = rate(true, true, true);
    let halves_kept = rate(true, true, false);
    println!(
        "{path}: {} records; M cells/s of CPU time: refine {bench:.1}, + halves, dropped \
         {dropped:.1} ({:.2}× refine), + halves, kept {kept:.1} ({:.2}×), + halves kept, \
         refinement dropped {halves_kept:.1} ({:.2}×)",
        entries.len(),
        dropped / bench,
        kept / bench,
        halves_kept / bench
    );
}
