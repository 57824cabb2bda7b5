//! The streaming refinement loop end to end, without a GPU: conformity on random flights,
//! convergence to the cut an independent brute force computes, agreement with the synchronous
//! decoder, and non-blocking behaviour over a slow, lossy source.

use std::collections::{HashMap, HashSet};
use std::sync::Arc;
use std::time::Duration;

use cbdam_client::access::{FlakyConfig, FlakySource, LocalSource};
use cbdam_client::camera::Camera;
use cbdam_client::patch::{HalfPatch, decode_cut};
use cbdam_client::refine::{
    DetailConfig, FrameStats, GC_MIN_COARSENINGS, RefineConfig, Refiner, box_distance,
};
use cbdam_client::world::World;
use cbdam_codec::geometry::{Cut, DiamondId, check_conforming};
use cbdam_codec::hierarchy::{EncodeOptions, Encoder};
use cbdam_codec::quant::{HeightGrid, QuantPlan};
use cbdam_codec::repository::{Repository, serialize};
use glam::DVec3;

/// A 200 × 150 terrain (ridges, a valley and noise) with 9 × 9 grids: levels 0…10, a data
/// rectangle smaller than the domain (so some diamonds are not stored).
pub(crate) fn repository() -> Arc<Repository> {
    repository_with(|_, _| false)
}

/// [`repository`]'s terrain with nodata wherever `hole(x, y)`: the repository then carries a
/// nodata mask.
pub(crate) fn repository_with(hole: impl Fn(f64, f64) -> bool) -> Arc<Repository> {
    let (w, h) = (200usize, 150usize);
    let mut state = 0x2545_f491_4f6c_dd1d_u64;
    let metres: Vec<f64> = (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as f64, (i / w) as f64);
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let noise = (state % 1000) as f64 / 1000.0;
            120.0
                + 80.0 * (x / 23.0).sin() * (y / 31.0).cos()
                + 40.0 * ((x + y) / 11.0).sin()
                + 0.01 * (x - 100.0).powi(2)
                + 3.0 * noise
        })
        .enumerate()
        .map(|(i, m)| {
            let (x, y) = ((i % w) as f64, (i / w) as f64);
            if hole(x, y) { f64::NAN } else { m }
        })
        .collect();
    let plan = QuantPlan::new(0.25, None, -50.0, 400.0).unwrap();
    let grid = HeightGrid::from_metres(w, h, &metres, None, &plan).unwrap();
    let opts = EncodeOptions {
        n: 9,
        ..EncodeOptions::default()
    };
    let enc = Encoder::new(&grid, plan.quantizer, &opts).encode().unwrap();
    Arc::new(Repository::from_bytes(serialize(&enc, &plan, None, None).unwrap()).unwrap())
}

fn unlimited(gc: u32) -> RefineConfig {
    RefineConfig {
        budget: None,
        gc_interval: gc,
        ..RefineConfig::default()
    }
}

/// A small deterministic generator for camera paths.
struct Rng(u64);
impl Rng {
    fn f(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// A random camera above the terrain looking at a random point of the data.
fn random_camera(world: &World, rng: &mut Rng) -> Camera {
    let (lo, hi) = world.bounds();
    let span = hi - lo;
    let target = lo + DVec3::new(rng.f() * span.x, rng.f() * span.y, rng.f() * span.z);
    let eye = DVec3::new(
        lo.x + (rng.f() * 1.6 - 0.3) * span.x,
        lo.y + (rng.f() * 1.6 - 0.3) * span.y,
        hi.z + 5.0 + rng.f() * rng.f() * 2.0 * span.x,
    );
    Camera::looking_at(world, eye, target, 50f64.to_radians(), (640, 480))
}

fn run_until_converged<S: cbdam_client::access::DataSource>(
    r: &mut Refiner<S>,
    cam: &Camera,
    max_frames: usize,
) -> FrameStats {
    for _ in 0..max_frames {
        let s = r.frame(cam);
        if s.converged {
            return s;
        }
    }
    panic!("no convergence in {max_frames} frames");
}

/// The cut a view needs, computed directly from the index: a stored diamond is refined iff its
/// error, saturated over its stored descendants (found here by explicit search, not the
/// refiner's bottom-up pass), projected at the distance of the union of its descendants' boxes,
/// exceeds the target, and that box meets the frustum.
pub(crate) fn brute_force(repo: &Repository, cam: &Camera, target: f64) -> HashSet<DiamondId> {
    let world = World::of_repository(repo);
    let domain = repo.head().params().domain;
    let layout = *domain.layout();
    let by_id: HashMap<DiamondId, _> = repo.head().entries().iter().map(|e| (e.id, *e)).collect();
    let frustum = cam.frustum();
    let mut out = HashSet::new();
    for e in repo.head().entries() {
        let (mut lo, mut hi) = world.diamond_box(e.id, e.min, e.max);
        let mut err = e.object_error;
        let mut stack = vec![e.id];
        let mut seen = HashSet::new();
        while let Some(d) = stack.pop() {
            for c in layout.children(d).into_iter().flatten() {
                if let Some(ce) = by_id.get(&c)
                    && seen.insert(c)
                {
                    let (a, b) = world.diamond_box(c, ce.min, ce.max);
                    lo = lo.min(a);
                    hi = hi.max(b);
                    err = err.max(ce.object_error);
                    stack.push(c);
                }
            }
        }
        let px = f64::from(err) * world.unit * cam.pixels_per_metre(box_distance(cam.eye, lo, hi));
        if frustum.intersects_box(lo, hi) && px > target {
            out.insert(e.id);
        }
    }
    out
}

pub(crate) fn refined_set(cut: &Cut) -> HashSet<DiamondId> {
    cut.refined().collect()
}

/// A local source hands out its records mapped (read and checked by whoever decodes them) or
/// taken (copied): the same bytes, counted alike; an unstored diamond maps to nothing (taking it
/// is the error that names it). Mapped by position in the index, the same records.
#[test]
fn mapped_records_read_what_taken_records_copy_and_count_alike() {
    use cbdam_client::access::DataSource;
    let repo = repository();
    let (mut taken, mapped) = (
        LocalSource::new(repo.clone()),
        LocalSource::new(repo.clone()),
    );
    let handles: Vec<_> = repo
        .head()
        .entries()
        .iter()
        .map(|e| (e.id, mapped.mapped(e.id).expect("stored")))
        .collect();
    assert_eq!(
        mapped.stats().records_taken,
        0,
        "counted when read, not when handed out"
    );
    for (id, handle) in &handles {
        let copy = taken.take(*id).unwrap().unwrap();
        assert_eq!(handle.bytes().unwrap(), &copy[..], "{id}");
    }
    assert_eq!(mapped.stats(), taken.stats());
    assert_eq!(
        mapped.stats().records_taken,
        repo.head().entries().len() as u64
    );
    let unstored = DiamondId::new(repo.head().params().domain.finest_level() + 1, 0, 0);
    assert!(mapped.mapped(unstored).is_none());
    assert!(matches!(taken.take(unstored), Some(Err(_))));
    // Found by its position in the index (the refiner knows it) without a search: the same
    // record; a position that is not the diamond's is searched for instead, so still the same.
    let entries = repo.head().entries();
    for (i, e) in entries.iter().enumerate() {
        let expected = mapped.mapped(e.id).unwrap();
        let expected = expected.bytes().unwrap();
        for index in [i, (i + 1) % entries.len(), usize::MAX] {
            let found = mapped.mapped_entry(e.id, index).expect("stored");
            assert_eq!(found.bytes().unwrap(), expected, "{} at {index}", e.id);
        }
    }
    assert!(mapped.mapped_entry(unstored, 0).is_none());
}

#[test]
fn the_cut_conforms_after_every_frame_of_random_flights() {
    let repo = repository();
    let domain = repo.head().params().domain;
    let layout = *domain.layout();
    let world = World::of_repository(&repo);
    for (seed, latency) in [(1u64, (0, 0)), (2, (1, 4)), (3, (0, 2))] {
        let mut rng = Rng(seed);
        let source = FlakySource::new(
            repo.clone(),
            FlakyConfig {
                latency,
                per_frame: 6,
                corrupt_one_in: 5,
                ..FlakyConfig::default()
            },
        );
        let config = RefineConfig {
            budget: Some(Duration::from_micros(300)),
            gc_interval: 3,
            ..RefineConfig::default()
        };
        let mut r = Refiner::new(source, config).unwrap();
        let (mut a, mut b) = (
            random_camera(&world, &mut rng),
            random_camera(&world, &mut rng),
        );
        let mut refined_any = false;
        // 60 frames of flight; then, if a loaded machine left the 300 µs budgets too short to
        // refine anything, more frames at the last camera (each checked the same way) until the
        // cut refines or 30 s pass, so that the checks never pass on an empty cut.
        let started = std::time::Instant::now();
        let mut f = 0;
        while f < 60 || (!refined_any && started.elapsed() < Duration::from_secs(30)) {
            if f < 60 && f % 12 == 0 {
                (a, b) = (b, random_camera(&world, &mut rng));
            }
            let u = if f < 60 { (f % 12) as f64 / 12.0 } else { 1.0 };
            let mut cam = a;
            cam.eye = a.eye.lerp(b.eye, u);
            cam.target = a.target.lerp(b.target, u);
            let s = r.frame(&cam);
            let cut = r.cut();
            let triangles = cut.triangles(&domain);
            check_conforming(&domain, &triangles)
                .unwrap_or_else(|e| panic!("seed {seed} frame {f}: {e}"));
            assert_eq!(s.triangles, triangles.len() as u64);
            assert_eq!(s.refined, cut.refined().count());
            for d in cut.refined() {
                for p in layout.parents(d).into_iter().flatten() {
                    assert!(cut.is_refined(p), "parent {p} of refined {d}");
                }
            }
            let keys: Vec<_> = r.drawn().map(|p| p.key()).collect();
            assert_eq!(keys, cut.drawn_halves(&domain));
            refined_any |= cut.refined().count() > 3;
            f += 1;
        }
        assert!(
            refined_any,
            "seed {seed}: the flights must refine something"
        );
    }
}

#[test]
fn unlimited_budget_converges_to_the_brute_force_cut() {
    let repo = repository();
    let domain = repo.head().params().domain;
    let world = World::of_repository(&repo);
    let mut rng = Rng(7);
    let mut r = Refiner::new(LocalSource::new(repo.clone()), unlimited(1)).unwrap();
    let mut sizes = Vec::new();
    // One refiner over several views: each converged cut must not depend on the previous ones
    // (coarsening has to remove what the new view does not need).
    for view in 0..8 {
        let cam = random_camera(&world, &mut rng);
        let s = run_until_converged(&mut r, &cam, 10);
        assert!(s.met_target && s.max_screen_error_px <= 1.0);
        let expected = brute_force(&repo, &cam, 1.0);
        assert_eq!(refined_set(r.cut()), expected, "view {view}");
        sizes.push(expected.len());

        // The target holds with plain per-diamond boxes too, everywhere in the frustum: every
        // drawn stored diamond whose own box meets the frustum is within 1 px.
        let frustum = cam.frustum();
        for (id, _) in r.cut().drawn_halves(&domain) {
            let Ok(i) = repo.head().entries().binary_search_by(|e| e.id.cmp(&id)) else {
                continue;
            };
            let e = repo.head().entries()[i];
            let (lo, hi) = world.diamond_box(id, e.min, e.max);
            if frustum.intersects_box(lo, hi) {
                let px = f64::from(e.object_error)
                    * world.unit
                    * cam.pixels_per_metre(box_distance(cam.eye, lo, hi));
                assert!(px <= 1.0, "view {view}: drawn {id} at {px} px");
            }
        }
    }
    assert!(
        sizes.iter().any(|&n| n > 20) && sizes.iter().any(|&n| n < sizes.iter().max().unwrap() / 2),
        "views should need different amounts of detail: {sizes:?}"
    );
}

#[test]
fn drawn_patches_equal_the_synchronous_decoder() {
    let repo = repository();
    let world = World::of_repository(&repo);
    let mut rng = Rng(11);
    let config = RefineConfig {
        budget: Some(Duration::from_micros(500)),
        gc_interval: 2,
        ..RefineConfig::default()
    };
    let mut r = Refiner::new(LocalSource::new(repo.clone()), config).unwrap();
    for _ in 0..3 {
        let cam = random_camera(&world, &mut rng);
        for _ in 0..4 {
            r.frame(&cam);
        }
        let reference = decode_cut(&repo, r.cut()).unwrap();
        let drawn: Vec<HalfPatch> = r.drawn().map(|p| (**p).clone()).collect();
        assert_eq!(drawn.len(), reference.len());
        assert!(
            drawn == reference,
            "streamed patches differ from decode_cut"
        );
    }
}

#[test]
fn a_slow_lossy_source_never_blocks_and_converges_to_the_local_cut() {
    let repo = repository();
    let domain = repo.head().params().domain;
    let world = World::of_repository(&repo);
    let mut rng = Rng(5);
    let budget = Duration::from_millis(2);
    let source = FlakySource::new(
        repo.clone(),
        FlakyConfig {
            latency: (2, 8),
            per_frame: 10,
            corrupt_one_in: 3,
            ..FlakyConfig::default()
        },
    );
    let config = RefineConfig {
        budget: Some(budget),
        ..RefineConfig::default()
    };
    let mut r = Refiner::new(source, config.clone()).unwrap();
    let (a, b) = (
        random_camera(&world, &mut rng),
        random_camera(&world, &mut rng),
    );
    let mut frame_ms = Vec::new();
    let mut saw_in_flight = false;
    for f in 0..40 {
        let u = f as f64 / 40.0;
        let mut cam = a;
        cam.eye = a.eye.lerp(b.eye, u);
        cam.target = a.target.lerp(b.target, u);
        let s = r.frame(&cam);
        frame_ms.push(s.refine_ms);
        saw_in_flight |= s.access.in_flight > 0;
        // Nothing is refined without its record having arrived: the first frames cannot have
        // refined anything (the root's record is at least 2 frames away).
        if f == 0 {
            assert_eq!(s.refined, 0);
        }
    }
    assert!(saw_in_flight);
    // The machine is shared: allow a generous margin over the budget, and one frame beyond it
    // (fresh-clone CI runs, writing gigabytes of build output, have stalled a thread for ~90
    // ms); a loop that waited for data would never return at all (records only arrive on later
    // frames), and one that waited on every frame would break the margin on many.
    let over: Vec<f64> = frame_ms
        .iter()
        .copied()
        .filter(|&ms| ms > 2.0 + 100.0)
        .collect();
    assert!(over.len() <= 1, "frames over budget + 100 ms: {over:?}");

    let mut settled = None;
    for _ in 0..400 {
        let s = r.frame(&b);
        if s.converged {
            settled = Some(s);
            break;
        }
    }
    let s = settled.expect("converges once the camera stops");
    assert!(s.access.requests_issued > 0 && s.access.bytes_fetched > 0);

    let corrupted = r.source().corrupted().to_vec();
    assert!(
        !corrupted.is_empty(),
        "the double delivered corrupt records"
    );
    assert!(s.failures >= corrupted.len() as u64);
    assert!(r.errors().iter().any(|e| e.contains("checksum")));

    let mut local = Refiner::new(LocalSource::new(repo.clone()), unlimited(1)).unwrap();
    run_until_converged(&mut local, &b, 10);
    assert_eq!(refined_set(r.cut()), refined_set(local.cut()));
    assert_eq!(refined_set(r.cut()), brute_force(&repo, &b, 1.0));
    let x: Vec<_> = r.drawn().collect();
    let y: Vec<_> = local.drawn().collect();
    assert!(x == y, "same cut, same patches");
    check_conforming(&domain, &r.cut().triangles(&domain)).unwrap();
}

#[test]
fn a_record_that_always_fails_is_given_up_on_without_stalling() {
    let repo = repository();
    let world = World::of_repository(&repo);
    let overview = Camera::overview(&world, (800, 600));
    let mut local = Refiner::new(LocalSource::new(repo.clone()), unlimited(1)).unwrap();
    run_until_converged(&mut local, &overview, 10);
    // A refined level-2 diamond of the converged cut fails forever.
    let bad = local
        .cut()
        .refined()
        .find(|d| d.level == 2)
        .expect("the overview refines level 2");
    let source = FlakySource::new(
        repo.clone(),
        FlakyConfig {
            latency: (1, 2),
            always_fail: [bad].into_iter().collect(),
            ..FlakyConfig::default()
        },
    );
    let mut r = Refiner::new(source, unlimited(1)).unwrap();
    let mut last = FrameStats::default();
    for _ in 0..100 {
        last = r.frame(&overview);
        if last.converged {
            break;
        }
    }
    assert!(last.converged, "the rest of the cut converges");
    assert!(!r.cut().is_refined(bad));
    assert!(r.errors().iter().any(|e| e.contains("giving up")));
    assert_eq!(
        last.failures,
        u64::from(RefineConfig::default().max_failures)
    );
    // Everything that does not depend on the broken diamond is refined as locally.
    let domain = repo.head().params().domain;
    let layout = *domain.layout();
    for d in local.cut().refined() {
        let mut ancestors = vec![d];
        let mut depends = false;
        while let Some(a) = ancestors.pop() {
            depends |= a == bad;
            ancestors.extend(layout.parents(a).into_iter().flatten());
        }
        assert_eq!(r.cut().is_refined(d), !depends, "{d}");
    }
}

#[test]
fn detail_synthesis_is_off_by_default_deterministic_and_conforming() {
    let repo = repository();
    let world = World::of_repository(&repo);
    let src_finest = repo.head().params().domain.finest_level();
    // Close to the ground, looking along it: the data's resolution is not enough.
    let (lo, hi) = world.bounds();
    let c = (lo + hi) * 0.5;
    let cam = Camera::looking_at(
        &world,
        DVec3::new(c.x, c.y, hi.z + 2.0),
        DVec3::new(c.x + 30.0, c.y + 10.0, lo.z),
        50f64.to_radians(),
        (640, 480),
    );
    let mut plain = Refiner::new(LocalSource::new(repo.clone()), unlimited(1)).unwrap();
    run_until_converged(&mut plain, &cam, 20);
    assert_eq!(plain.layout(), repo.head().params().layout());
    assert!(plain.cut().refined().all(|d| d.level < src_finest));

    let detail = RefineConfig {
        detail: Some(DetailConfig {
            amplitude: 0.3,
            ..DetailConfig::default()
        }),
        ..unlimited(1)
    };
    let mut runs = Vec::new();
    for _ in 0..2 {
        let mut r = Refiner::new(LocalSource::new(repo.clone()), detail.clone()).unwrap();
        run_until_converged(&mut r, &cam, 20);
        let domain = *r.domain();
        assert_eq!(domain.finest_level(), src_finest + 2);
        check_conforming(&domain, &r.cut().triangles(&domain)).unwrap();
        assert!(
            r.cut().refined().any(|d| d.level >= src_finest),
            "synthesised"
        );
        // Stored levels are the repository's data: every drawn patch of a diamond above the
        // source's finest level matches the synchronous decoder's patch of the same diamond.
        let src_cut = {
            let mut cut = Cut::new();
            for d in r.cut().refined().filter_map(|d| r.source_id(d)) {
                if d.level < src_finest {
                    cut.refine(&repo.head().params().domain, d);
                }
            }
            cut
        };
        let reference: HashMap<_, _> = decode_cut(&repo, &src_cut)
            .unwrap()
            .into_iter()
            .map(|p| (p.key(), p))
            .collect();
        let mut compared = 0;
        for p in r.drawn() {
            if let Some(sid) = r.source_id(p.id)
                && let Some(q) = reference.get(&(sid, p.half))
                && p.id.level <= src_finest
            {
                assert_eq!(p.heights, q.heights, "{}", p.id);
                compared += 1;
            }
        }
        assert!(compared > 0);
        runs.push(r.drawn().map(|p| (**p).clone()).collect::<Vec<_>>());
    }
    assert!(runs[0] == runs[1], "synthesis is deterministic");
}

#[test]
fn requests_the_view_no_longer_needs_are_cancelled() {
    let repo = repository();
    let world = World::of_repository(&repo);
    let (lo, hi) = world.bounds();
    let look = |x: f64| {
        let eye = DVec3::new(lo.x + x * (hi.x - lo.x), lo.y - 20.0, hi.z + 30.0);
        let target = DVec3::new(eye.x, (lo.y + hi.y) / 2.0, lo.z);
        Camera::looking_at(&world, eye, target, 30f64.to_radians(), (640, 480))
    };
    let source = FlakySource::new(
        repo.clone(),
        FlakyConfig {
            latency: (3, 3),
            ..FlakyConfig::default()
        },
    );
    let mut r = Refiner::new(source, unlimited(1)).unwrap();
    let (west, east) = (look(0.05), look(0.95));
    let mut s = FrameStats::default();
    for _ in 0..12 {
        s = r.frame(&west);
    }
    assert!(s.refined > 0 && s.access.requests_cancelled == 0);
    // Turn away while the next level's records are in flight: they are cancelled, not waited
    // for.
    for _ in 0..4 {
        s = r.frame(&west);
        if s.access.in_flight > 0 {
            break;
        }
    }
    assert!(s.access.in_flight > 0, "west still needs records");
    let in_flight_west = s.access.in_flight;
    s = r.frame(&east);
    assert!(s.access.requests_cancelled > 0);
    assert!(s.access.requests_issued > 0 && in_flight_west > 0);
}

/// Bytes of one node at N = 9 with its four child halves: the unit the budget counts in.
const NODE_BYTES_N9: usize = 4 * (17 * 17 + 4 * 9 * 9);

#[test]
fn a_memory_budget_bounds_the_cut_and_degrades_it_coarser_never_wrong() {
    let repo = repository();
    let world = World::of_repository(&repo);
    let mut rng = Rng(23);
    let mut checked = 0;
    for view in 0..12 {
        let cam = random_camera(&world, &mut rng);
        let mut free = Refiner::new(LocalSource::new(repo.clone()), unlimited(1)).unwrap();
        let full_stats = run_until_converged(&mut free, &cam, 10);
        let full = refined_set(free.cut());
        if full.len() < 24 {
            continue;
        }
        checked += 1;
        if checked > 4 {
            break;
        }
        let mut errors = Vec::new();
        for fraction in [3, 2] {
            let limit = full.len() / fraction * NODE_BYTES_N9;
            let config = RefineConfig {
                cut_bytes: Some(limit),
                ..unlimited(1)
            };
            let mut r = Refiner::new(LocalSource::new(repo.clone()), config).unwrap();
            let mut limited = false;
            let mut last = None;
            // The same view for a while, then the free cut's view from a new camera and back:
            // swaps happen while the camera moves as well as at rest.
            let other = random_camera(&world, &mut rng);
            for (i, c) in std::iter::repeat_n(cam, 6)
                .chain(std::iter::repeat_n(other, 3))
                .chain(std::iter::repeat_n(cam, 6))
                .enumerate()
            {
                let s = r.frame(&c);
                limited |= s.memory_limited;
                assert!(
                    s.cut_bytes <= limit,
                    "view {view} frame {i}: {} > {limit}",
                    s.cut_bytes
                );
                let domain = repo.head().params().domain;
                check_conforming(&domain, &r.cut().triangles(&domain))
                    .unwrap_or_else(|e| panic!("view {view} frame {i}: {e}"));
                if [5, 8, 14].contains(&i) {
                    // At the end of each camera phase (decoding every cut is slow).
                    let reference = decode_cut(&repo, r.cut()).unwrap();
                    let drawn: Vec<HalfPatch> = r.drawn().map(|p| (**p).clone()).collect();
                    assert!(drawn == reference, "view {view} frame {i}: wrong patches");
                }
                last = Some(s);
            }
            let s = last.unwrap();
            assert!(
                limited,
                "view {view}: 1/{fraction} of the cut never hit the limit"
            );
            assert!(!s.met_target && s.max_screen_error_px > full_stats.max_screen_error_px);
            // Only what the view needs is refined: the limited cut lies inside the free one.
            let cut = refined_set(r.cut());
            assert!(
                cut.is_subset(&full),
                "view {view}: refined outside the needed cut"
            );
            assert!(
                cut.len() * 2 >= full.len() / fraction,
                "view {view}: budget left unused"
            );
            errors.push(s.max_screen_error_px);
        }
        // More memory, no larger error.
        assert!(errors[1] <= errors[0] + 1e-9, "view {view}: {errors:?}");
    }
    assert!(checked > 4, "too few detailed views: {checked}");
}

/// A garbage collection stops at the frame's budget and goes on in the next frames: a view that
/// suddenly needs far less (here the pixel target raised 64-fold) leaves hundreds of diamonds
/// to coarsen, which a collection without a budget does in one frame; with a budget already
/// spent each frame coarsens `GC_MIN_COARSENINGS`, and the frames end at the same cut.
#[test]
fn garbage_collection_stops_at_the_budget_and_goes_on_in_the_next_frames() {
    let repo = repository();
    let world = World::of_repository(&repo);
    let (lo, hi) = world.bounds();
    let c = (lo + hi) * 0.5;
    let cam = Camera::looking_at(
        &world,
        DVec3::new(c.x, c.y - 40.0, hi.z + 20.0),
        DVec3::new(c.x, c.y + 20.0, lo.z),
        50f64.to_radians(),
        (640, 480),
    );
    let settled = || {
        let mut r = Refiner::new(LocalSource::new(repo.clone()), unlimited(4)).unwrap();
        r.set_pixel_error(0.25);
        assert!(run_until_converged(&mut r, &cam, 20).converged);
        r.set_pixel_error(16.0);
        r
    };
    let (mut whole, mut bounded) = (settled(), settled());
    let before = refined_set(whole.cut());
    // The collection runs every 4 frames: the whole one in the first of them.
    let mut coarsened_whole = 0;
    for _ in 0..4 {
        coarsened_whole += whole.frame(&cam).coarsenings;
    }
    let after = refined_set(whole.cut());
    assert!(
        coarsened_whole > 4 * GC_MIN_COARSENINGS && after.len() < before.len(),
        "too little garbage to test with: {coarsened_whole} of {}",
        before.len()
    );
    // The budget spent before the collection starts: it does its least each frame.
    bounded.set_budget(Some(Duration::from_nanos(1)));
    let (mut frames, mut coarsened) = (0, 0);
    for _ in 0..400 {
        let s = bounded.frame(&cam);
        assert!(
            s.coarsenings <= GC_MIN_COARSENINGS,
            "{} coarsened in one frame over budget",
            s.coarsenings
        );
        coarsened += s.coarsenings;
        frames += usize::from(s.coarsenings > 0);
        if refined_set(bounded.cut()) == after {
            break;
        }
    }
    assert_eq!(
        refined_set(bounded.cut()),
        after,
        "the collection did not finish"
    );
    assert_eq!(coarsened, coarsened_whole);
    assert!(frames > 4, "coarsened in {frames} frames only");
}

/// A still view whose budget ends with refinements left does not collect garbage in that
/// frame: its collection waits until the loop has refined all it could, then coarsens what
/// the previous view left, so the cut still converges to the view's own (the brute-force
/// one) and every diamond left behind is collected.
#[test]
fn a_still_view_refines_before_it_collects() {
    let repo = repository();
    let world = World::of_repository(&repo);
    let mut rng = Rng(11);
    let (first, second) = (
        random_camera(&world, &mut rng),
        random_camera(&world, &mut rng),
    );
    let mut r = Refiner::new(LocalSource::new(repo.clone()), unlimited(2)).unwrap();
    run_until_converged(&mut r, &first, 20);
    // Every frame over budget: each starts one refinement.
    r.set_budget(Some(Duration::from_nanos(1)));
    let left_behind: Vec<DiamondId> = refined_set(r.cut())
        .difference(&brute_force(&repo, &second, 1.0))
        .copied()
        .collect();
    // The first frame of the new view moves the camera: its collection comes first.
    r.frame(&second);
    let (mut waited, mut collected_after) = (0, 0);
    let mut last = None;
    // Frames of 1 ns run back to back in microseconds: bounded by time as well as by count, so
    // that decode workers slowed by the other tests' threads (idle-priority ones, until their
    // standby pool takes over) still get to answer.
    let started = std::time::Instant::now();
    for i in 0.. {
        if i >= 4000 && started.elapsed() > Duration::from_secs(30) {
            break;
        }
        let s = r.frame(&second);
        if s.budget_exhausted && s.refinements > 0 {
            assert_eq!(
                s.coarsenings, 0,
                "frame {} coarsened with refinements left",
                s.frame
            );
            waited += 1;
        } else {
            collected_after += s.coarsenings;
        }
        last = Some(s);
        if s.converged {
            break;
        }
    }
    let last = last.expect("frames ran");
    assert!(last.converged, "no convergence: {last:?}");
    assert_eq!(refined_set(r.cut()), brute_force(&repo, &second, 1.0));
    assert!(
        waited > 0 && collected_after > 0 && !left_behind.is_empty(),
        "nothing tested: {waited} frames waited, {collected_after} coarsened after, {} left \
         behind",
        left_behind.len()
    );
}

/// The desktop's decode workers run below the frame thread's priority (Linux keeps the
/// scheduling policy and the nice value per thread: `/proc/self/task/*/stat` fields 41 and 19):
/// the frame loop has a deadline and they have none, so at equal priority a worker sharing the
/// frame thread's core makes frames end late.
#[cfg(target_os = "linux")]
#[test]
fn decode_workers_run_below_the_frame_threads_priority() {
    use cbdam_client::spawn::{DecodePool, Spawner};
    const SCHED_IDLE: i32 = 5;
    if std::env::var_os("CBDAM_DECODE_PRIORITY").is_some() {
        eprintln!("CBDAM_DECODE_PRIORITY is set: the workers' priority is the caller's choice");
        return;
    }
    let repo = repository();
    let world = World::of_repository(&repo);
    let mut r = Refiner::new(LocalSource::new(repo), unlimited(4)).unwrap();
    let mut rng = Rng(7);
    for _ in 0..3 {
        r.frame(&random_camera(&world, &mut rng));
    }
    // "tid (comm) state ppid …": the fields after the last ')' start at field 3.
    let field = |stat: &str, n: usize| -> i32 {
        let rest = &stat[stat.rfind(')').expect("a stat line") + 1..];
        rest.split_whitespace().nth(n - 3).unwrap().parse().unwrap()
    };
    let own = std::fs::read_to_string("/proc/thread-self/stat").unwrap();
    let (own_policy, own_nice) = (field(&own, 41), field(&own, 19));
    let threads = |prefix: &str| {
        let mut found = Vec::new();
        for task in std::fs::read_dir("/proc/self/task").unwrap() {
            let dir = task.unwrap().path();
            let Ok(comm) = std::fs::read_to_string(dir.join("comm")) else {
                continue; // a thread that ended meanwhile
            };
            if comm.trim().starts_with(prefix)
                && let Ok(stat) = std::fs::read_to_string(dir.join("stat"))
            {
                found.push((comm.trim().to_string(), field(&stat, 41), field(&stat, 19)));
            }
        }
        found
    };
    let workers = threads("cbdam-decode-");
    assert_eq!(
        workers.len(),
        DecodePool.parallelism(),
        "decode threads found: {workers:?}"
    );
    // The standby pool, for when the workers starve, runs at the frame thread's policy.
    let standby = threads("cbdam-standby-");
    assert_eq!(
        standby.len(),
        DecodePool.parallelism(),
        "standby threads found: {standby:?}"
    );
    for (name, policy, nice) in &standby {
        assert_eq!((*policy, *nice), (own_policy, own_nice), "{name}");
    }
    for (name, policy, nice) in &workers {
        // SCHED_IDLE, or where a kernel refuses it the fallback: nice 19.
        assert!(
            *policy == SCHED_IDLE || (*policy == own_policy && *nice == 19),
            "{name}: policy {policy}, nice {nice}; the frame thread's: policy {own_policy}, \
             nice {own_nice}"
        );
    }
}
