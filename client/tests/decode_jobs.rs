//! The decode-job seam for workers that share no memory with the refiner (a page's Web
//! Workers): jobs sent as bytes to a [`WorkerDecoder`] and their answers read back must give
//! the refiner exactly what running them in place gives, and bad bytes must be errors.

use std::cell::RefCell;
use std::rc::Rc;
use std::sync::Arc;
use std::time::Duration;

use cbdam_client::access::LocalSource;
use cbdam_client::camera::Camera;
use cbdam_client::patch::HalfPatch;
use cbdam_client::refine::{
    DetailConfig, FrameStats, HeadBytes, RefineConfig, Refiner, WorkerDecoder,
};
use cbdam_client::spawn::{Inline, Portable, Spawner};
use cbdam_client::world::World;
use cbdam_codec::CodecError;
use cbdam_codec::geometry::{DiamondId, Domain};
use cbdam_codec::repository::Repository;
use glam::DVec3;

use crate::streaming::{refined_set, repository, repository_with};

/// A job with its type erased, as a spawner that queues jobs holds them.
trait Queued {
    fn encode(&self) -> Vec<u8>;
    fn receive(&self, answer: &[u8]) -> Result<(), CodecError>;
}
impl<J: Portable> Queued for J {
    fn encode(&self) -> Vec<u8> {
        Portable::encode(self)
    }
    fn receive(&self, answer: &[u8]) -> Result<(), CodecError> {
        Portable::receive(self, answer)
    }
}

/// A spawner like the page's: every job crosses to a [`WorkerDecoder`] as bytes and comes back
/// as bytes. `deferred`: jobs wait in a queue until [`Messages::deliver`] (between frames, like
/// a worker's answers arriving), and the refiner decodes ahead; otherwise each is answered at
/// once.
#[derive(Clone, Default)]
struct Messages {
    worker: Rc<RefCell<Option<WorkerDecoder>>>,
    queue: Rc<RefCell<Vec<Box<dyn Queued>>>>,
    deferred: bool,
    /// Diamonds answered through bytes.
    answered: Rc<RefCell<usize>>,
}

impl Messages {
    fn set_up(&self, refiner: &Refiner<LocalSource, Messages>, repo: &Repository) {
        let context = refiner.worker_context(head_bytes(repo), None);
        *self.worker.borrow_mut() = Some(WorkerDecoder::new(&context).unwrap());
    }

    fn answer(&self, job: &dyn Queued) {
        let bytes = job.encode();
        let answer = self.worker.borrow().as_ref().unwrap().run(&bytes).unwrap();
        job.receive(&answer).unwrap();
    }

    fn deliver(&self) {
        let jobs = std::mem::take(&mut *self.queue.borrow_mut());
        for job in jobs {
            self.answer(&*job);
        }
    }
}

impl Spawner for Messages {
    fn sends_jobs_as_messages(&self) -> bool {
        true
    }
    fn spawn<F: FnOnce() + Send + 'static>(&self, job: F) {
        job();
    }
    fn spawn_job<J: Portable>(&self, job: J) {
        *self.answered.borrow_mut() += job.steps();
        if self.deferred {
            self.queue.borrow_mut().push(Box::new(job));
        } else {
            self.answer(&job);
        }
    }
    fn parallelism(&self) -> usize {
        2
    }
    fn runs_in_background(&self) -> bool {
        self.deferred
    }
}

fn head_bytes(repo: &Repository) -> HeadBytes<'_> {
    HeadBytes {
        bytes: repo.as_bytes(),
        file_len: repo.head().file_len(),
    }
}

fn drawn<X: Spawner>(r: &Refiner<LocalSource, X>) -> Vec<HalfPatch> {
    r.drawn().map(|p| (**p).clone()).collect()
}

/// Cameras sweeping over the terrain, from far to close.
fn cameras(world: &World) -> Vec<Camera> {
    let (lo, hi) = world.bounds();
    let span = hi - lo;
    (0..12)
        .map(|i| {
            let t = f64::from(i) / 11.0;
            let target = lo + DVec3::new(span.x * (0.2 + 0.6 * t), span.y * 0.5, span.z * 0.5);
            let eye = target
                + DVec3::new(
                    -span.x * 0.3,
                    -span.y * (0.8 - 0.6 * t),
                    span.x * (0.6 - 0.5 * t),
                );
            Camera::looking_at(world, eye, target, 50f64.to_radians(), (640, 480))
        })
        .collect()
}

#[test]
fn jobs_sent_as_bytes_refine_what_jobs_run_in_place_refine() {
    let repo = repository();
    let world = World::of_repository(&repo);
    let config = RefineConfig {
        budget: None,
        gc_interval: 2,
        ..RefineConfig::default()
    };
    let (_, answered) = compare_in_place_and_by_bytes(&repo, config, &cameras(&world));
    assert!(answered > 50, "{answered} diamonds went through bytes");
}

/// With nodata and synthesised detail below the stored levels: a synthesised diamond's nodata
/// mask is joined from the halves its parents' nodes hold in place, and gathered from the
/// parents' refinements in a worker (whose nodes carry no halves); both must draw the same.
#[test]
fn jobs_sent_as_bytes_synthesise_the_nodata_masks_jobs_run_in_place_do() {
    let repo =
        repository_with(|x, y| (x - 60.0).hypot(y - 70.0) < 18.0 || (x - y - 40.0).abs() < 3.0);
    let world = World::of_repository(&repo);
    let src_finest = repo.head().params().domain.finest_level();
    let config = RefineConfig {
        budget: None,
        gc_interval: 2,
        detail: Some(DetailConfig {
            amplitude: 0.3,
            ..DetailConfig::default()
        }),
        ..RefineConfig::default()
    };
    // Close to the ground along the strip and over the disc: finer than the data.
    let (lo, hi) = world.bounds();
    let at = |x: f64, y: f64| {
        let p = world.point(x as i64, y as i64, 0);
        Camera::looking_at(
            &world,
            DVec3::new(p.x, p.y, hi.z + 2.0),
            DVec3::new(p.x + 25.0, p.y + 10.0, lo.z),
            50f64.to_radians(),
            (640, 480),
        )
    };
    let cams = [at(60.0, 50.0), at(80.0, 40.0), at(100.0, 60.0)];
    let mut in_place =
        Refiner::with_spawner(LocalSource::new(repo.clone()), config.clone(), Inline).unwrap();
    let mut masked_synthetic = 0;
    for cam in &cams {
        in_place.settle(cam, 50);
        masked_synthetic += in_place
            .drawn()
            .filter(|p| p.id.level > src_finest && p.valid.is_some())
            .count();
    }
    assert!(
        masked_synthetic > 0,
        "no synthesised half with a nodata mask was drawn"
    );
    let (_, answered) = compare_in_place_and_by_bytes(&repo, config, &cams);
    assert!(answered > 50, "{answered} diamonds went through bytes");
}

/// Runs `cams` through a refiner decoding in place and one whose jobs cross as bytes, checking
/// after each that they refine, draw and report failures the same; returns the refiner decoding
/// in place and how many diamonds crossed.
fn compare_in_place_and_by_bytes(
    repo: &Arc<Repository>,
    config: RefineConfig,
    cams: &[Camera],
) -> (Refiner<LocalSource, Inline>, usize) {
    let mut in_place =
        Refiner::with_spawner(LocalSource::new(repo.clone()), config.clone(), Inline).unwrap();
    let messages = Messages::default();
    let mut by_bytes =
        Refiner::with_spawner(LocalSource::new(repo.clone()), config, messages.clone()).unwrap();
    messages.set_up(&by_bytes, repo);
    for (i, cam) in cams.iter().enumerate() {
        let a = in_place.frame(cam);
        let b = by_bytes.frame(cam);
        assert_eq!(a.refinements, b.refinements, "frame {i}");
        assert_eq!(
            refined_set(in_place.cut()),
            refined_set(by_bytes.cut()),
            "frame {i}"
        );
        assert_eq!(
            drawn(&in_place),
            drawn(&by_bytes),
            "frame {i}: drawn patches"
        );
        assert_eq!(in_place.errors(), by_bytes.errors(), "frame {i}: failures");
    }
    let answered = *messages.answered.borrow();
    (in_place, answered)
}

/// Runs jobs in place like [`Inline`], but says that it sends them as messages: the refiner's
/// nodes then keep their refinements, as they did before nodes dropped them.
#[derive(Clone, Copy, Default)]
struct InlineKeepingRefinements;

impl Spawner for InlineKeepingRefinements {
    fn spawn<F: FnOnce() + Send + 'static>(&self, job: F) {
        job();
    }
    fn sends_jobs_as_messages(&self) -> bool {
        true
    }
    fn parallelism(&self) -> usize {
        1
    }
    fn runs_in_background(&self) -> bool {
        false
    }
}

/// Nodes decoded in place drop their refinements once their children's halves are made: the
/// same cut, the same drawn patches and failures as nodes that keep them, frame by frame, and
/// each refined node holds exactly one refinement (`N² + (N−1)²` heights) less.
#[test]
fn nodes_that_drop_their_refinements_draw_what_nodes_that_keep_them_draw() {
    let repo = repository();
    let world = World::of_repository(&repo);
    let n = repo.head().params().domain.n();
    let config = RefineConfig {
        budget: None,
        gc_interval: 2,
        ..RefineConfig::default()
    };
    let source = || LocalSource::new(repo.clone());
    let mut dropping = Refiner::with_spawner(source(), config.clone(), Inline).unwrap();
    let mut keeping = Refiner::with_spawner(source(), config, InlineKeepingRefinements).unwrap();
    let mut compared = 0;
    for (i, cam) in cameras(&world).iter().enumerate() {
        let a = dropping.frame(cam);
        let b = keeping.frame(cam);
        assert_eq!(a.refinements, b.refinements, "frame {i}");
        assert_eq!(
            refined_set(dropping.cut()),
            refined_set(keeping.cut()),
            "frame {i}"
        );
        assert_eq!(
            drawn(&dropping),
            drawn(&keeping),
            "frame {i}: drawn patches"
        );
        assert_eq!(dropping.errors(), keeping.errors(), "frame {i}: failures");
        let refinement_bytes = 4 * (n * n + (n - 1) * (n - 1));
        assert_eq!(
            b.cut_bytes - a.cut_bytes,
            b.refined * refinement_bytes,
            "frame {i}: bytes of {} refined nodes",
            b.refined
        );
        compared += b.refined;
    }
    assert!(compared > 100, "{compared} refined nodes compared");
}

/// A record of the mapped file that fails its checksum (read by the worker that decodes it in
/// place, or before its job goes out as bytes) fails its diamond alike: the same failures,
/// cut and patches either way, the diamond given up on after its retries, and everything else
/// refined.
#[test]
fn a_corrupt_mapped_record_fails_its_diamond_in_place_and_through_bytes() {
    let good = repository();
    let world = World::of_repository(&good);
    let cams = cameras(&world);
    let config = RefineConfig {
        budget: None,
        gc_interval: 2,
        ..RefineConfig::default()
    };
    // The diamond of level 3 that the sweep's closest view refines first.
    let mut reference =
        Refiner::with_spawner(LocalSource::new(good.clone()), config.clone(), Inline).unwrap();
    reference.settle(&cams[11], 50);
    let (index, id) = good
        .head()
        .entries()
        .iter()
        .enumerate()
        .find(|(_, e)| e.id.level == 3 && e.length > 0 && reference.cut().is_refined(e.id))
        .map(|(i, e)| (i, e.id))
        .expect("the closest view refines a stored level-3 diamond");
    let bad = with_corrupt_record(&good, index);

    let (r, answered) = compare_in_place_and_by_bytes(&bad, config.clone(), &cams);
    assert!(answered > 50, "{answered} diamonds went through bytes");
    assert!(
        !r.cut().is_refined(id),
        "{id} was refined from a corrupt record"
    );
    let failures: Vec<&String> = r
        .errors()
        .iter()
        .filter(|e| e.contains("checksum mismatch"))
        .collect();
    assert_eq!(
        failures.len(),
        config.max_failures as usize,
        "one failure per try, then given up: {:?}",
        r.errors()
    );
    assert!(
        failures.iter().all(|e| e.contains(&id.to_string())),
        "{failures:?}"
    );
    // Everything the good file refines but the corrupt diamond's descendants is refined.
    let below: Vec<_> = reference
        .cut()
        .refined()
        .filter(|d| !r.cut().is_refined(*d))
        .collect();
    assert!(!below.is_empty());
    let domain = good.head().params().domain;
    for d in below {
        assert!(
            descends_from(&domain, d, id),
            "{d} is not refined, and does not lie below {id}"
        );
    }
}

/// Whether `d` is `ancestor` or lies below it (through any parent).
fn descends_from(domain: &Domain, d: DiamondId, ancestor: DiamondId) -> bool {
    d == ancestor
        || (d.level > ancestor.level
            && domain
                .parents(d)
                .into_iter()
                .flatten()
                .any(|p| descends_from(domain, p, ancestor)))
}

/// For results that arrive only between frames: a short budget, since a frame waits for them
/// in vain.
fn between_frames_config() -> RefineConfig {
    RefineConfig {
        budget: Some(Duration::from_millis(2)),
        gc_interval: 3,
        ..RefineConfig::default()
    }
}

/// Flies `r` through the first 8 of `cams`, then holds it at `cam` for up to 200 frames until
/// its cut converges; `after` sees every frame's stats (answers delivered between frames go
/// there). The converged frame's stats, if any.
fn fly_in_and_settle<X: Spawner>(
    r: &mut Refiner<LocalSource, X>,
    cams: &[Camera],
    cam: &Camera,
    mut after: impl FnMut(&FrameStats),
) -> Option<FrameStats> {
    let flight = cams.iter().take(8).chain(std::iter::repeat_n(cam, 200));
    for (i, c) in flight.enumerate() {
        let stats = r.frame(c);
        after(&stats);
        if i >= 8 && stats.converged {
            return Some(stats);
        }
    }
    None
}

/// The cut `cam` converges to, refined in place without a budget.
fn converged_in_place(repo: &Arc<Repository>, cam: &Camera) -> Refiner<LocalSource, Inline> {
    let mut reference = Refiner::with_spawner(
        LocalSource::new(repo.clone()),
        RefineConfig {
            budget: None,
            ..RefineConfig::default()
        },
        Inline,
    )
    .unwrap();
    assert!(reference.settle(cam, 50).converged);
    reference
}

#[test]
fn answers_arriving_between_frames_converge_to_the_cut_refined_in_place() {
    let repo = repository();
    let world = World::of_repository(&repo);
    let cams = cameras(&world);
    let cam = cams[8];
    let reference = converged_in_place(&repo, &cam);

    let messages = Messages {
        deferred: true,
        ..Messages::default()
    };
    let config = between_frames_config();
    let mut r =
        Refiner::with_spawner(LocalSource::new(repo.clone()), config, messages.clone()).unwrap();
    messages.set_up(&r, &repo);
    // Fly in, then hold still until converged; answers come between frames.
    let (mut ahead, mut frames) = (0, 0);
    let last = fly_in_and_settle(&mut r, &cams, &cam, |stats| {
        ahead += stats.decoded_ahead;
        frames += 1;
        messages.deliver();
    });
    let last = last.unwrap_or_else(|| panic!("no convergence in {frames} frames"));
    assert!(last.met_target);
    assert!(ahead > 0, "nothing was decoded ahead through bytes");
    assert_eq!(refined_set(r.cut()), refined_set(reference.cut()));
    assert_eq!(drawn(&r), drawn(&reference));
}

/// A job held back, its message and its worker's answer.
type Exchange = (Box<dyn Queued>, Vec<u8>, Vec<u8>);

/// Captures the context message, and the job messages and answers of a refiner's first frames
/// (never applied).
fn captured(repo: &Arc<Repository>) -> (Vec<u8>, Vec<Exchange>) {
    let world = World::of_repository(repo);
    let messages = Messages {
        deferred: true,
        ..Messages::default()
    };
    let mut r = Refiner::with_spawner(
        LocalSource::new(repo.clone()),
        RefineConfig::default(),
        messages.clone(),
    )
    .unwrap();
    let context = r.worker_context(head_bytes(repo), None);
    messages.set_up(&r, repo);
    let cam = cameras(&world)[10];
    // Frames whose answers are delivered, so that later jobs carry given parents.
    for _ in 0..3 {
        r.frame(&cam);
        messages.deliver();
    }
    r.frame(&cam);
    let jobs: Vec<Box<dyn Queued>> = std::mem::take(&mut *messages.queue.borrow_mut());
    assert!(!jobs.is_empty(), "the frame dispatched jobs");
    let worker = WorkerDecoder::new(&context).unwrap();
    let out = jobs
        .into_iter()
        .map(|j| {
            let bytes = j.encode();
            let answer = worker.run(&bytes).unwrap();
            (j, bytes, answer)
        })
        .collect();
    (context, out)
}

/// Flips byte `at` and, if `fix_crc`, recomputes the trailing checksum.
fn flipped(bytes: &[u8], at: usize, fix_crc: bool) -> Vec<u8> {
    let mut b = bytes.to_vec();
    b[at] ^= 0x5a;
    if fix_crc {
        let n = b.len() - 4;
        let crc = crc32fast::hash(&b[..n]);
        b[n..].copy_from_slice(&crc.to_le_bytes());
    }
    b
}

/// `repo` with one byte of record `index` changed (its checksum no longer matches).
fn with_corrupt_record(repo: &Repository, index: usize) -> Arc<Repository> {
    let range = repo.head().record_range(index).unwrap();
    let mut bytes = repo.as_bytes().to_vec();
    bytes[((range.start + range.end) / 2) as usize] ^= 0x10;
    Arc::new(Repository::from_bytes(bytes).unwrap())
}

#[test]
fn bad_messages_are_errors_never_panics() {
    let repo = repository();
    let (context, jobs) = captured(&repo);
    let worker = WorkerDecoder::new(&context).unwrap();
    let (job, bytes, answer) = jobs.iter().max_by_key(|(_, b, _)| b.len()).expect("jobs");
    assert!(bytes.len() > 100 && answer.len() > 100);
    damaged_messages_are_errors(&worker, &context, &**job, bytes, answer);

    // A job with a step whose record failed its check where the job was made (the first
    // level-1 record is corrupt): its answer is an error for that step; damaged, an error.
    let level_1 = repo
        .head()
        .entries()
        .iter()
        .position(|e| e.id.level == 1)
        .unwrap();
    let (bad_context, bad_jobs) = captured(&with_corrupt_record(&repo, level_1));
    let bad_worker = WorkerDecoder::new(&bad_context).unwrap();
    let unreadable = |b: &[u8]| b.windows(17).any(|w| w == b"checksum mismatch");
    let (bad_job, bad_bytes, bad_answer) = bad_jobs
        .iter()
        .find(|(_, b, _)| unreadable(b))
        .expect("a job carries the unreadable record");
    assert!(unreadable(bad_answer), "the answer carries the failure");
    damaged_messages_are_errors(&bad_worker, &bad_context, &**bad_job, bad_bytes, bad_answer);
    for at in 5..bad_bytes.len() - 4 {
        let _ = bad_worker.run(&flipped(bad_bytes, at, true));
    }

    // Each message read as another kind: the magic differs.
    assert!(worker.run(answer).is_err());
    assert!(job.receive(bytes).is_err());
    assert!(WorkerDecoder::new(bytes).is_err());
    // Another job's answer does not match this job's steps (when they differ).
    for (other, _, other_answer) in &jobs {
        if other.encode() != job.encode() {
            assert!(job.receive(other_answer).is_err());
        }
    }

    // Random bytes, some with a valid magic, version and checksum: errors.
    let mut state = 0x9e37_79b9_7f4a_7c15_u64;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    for i in 0..3000 {
        let len = (next() % 600) as usize;
        let mut b: Vec<u8> = (0..len).map(|_| next() as u8).collect();
        if i % 2 == 0 && len >= 9 {
            let magic = [b"CBDJ", b"CBDR", b"CBDC"][i % 3];
            b[..4].copy_from_slice(magic);
            b[4] = 1;
            let n = b.len() - 4;
            let crc = crc32fast::hash(&b[..n]);
            b[n..].copy_from_slice(&crc.to_le_bytes());
        }
        assert!(worker.run(&b).is_err(), "random job {i}");
        assert!(job.receive(&b).is_err(), "random answer {i}");
        assert!(WorkerDecoder::new(&b).is_err(), "random context {i}");
    }

    // A flipped byte behind a valid checksum (a message built wrong, not damaged): whatever it
    // says, reading it and running it returns (an error, or results), never panics. The
    // answers go to a refiner that is not used again.
    for (_, bytes, answer) in &jobs {
        for at in 5..bytes.len() - 4 {
            let _ = worker.run(&flipped(bytes, at, true));
        }
        for at in 5..answer.len() - 4 {
            let _ = job.receive(&flipped(answer, at, true));
        }
    }
}

/// A job message, its answer and the context, truncated or with any byte flipped: errors (the
/// length or the checksum gives them away).
fn damaged_messages_are_errors(
    worker: &WorkerDecoder,
    context: &[u8],
    job: &dyn Queued,
    bytes: &[u8],
    answer: &[u8],
) {
    for len in 0..bytes.len() {
        assert!(worker.run(&bytes[..len]).is_err(), "job truncated to {len}");
    }
    for len in 0..answer.len() {
        assert!(
            job.receive(&answer[..len]).is_err(),
            "answer truncated to {len}"
        );
    }
    for len in (0..context.len()).step_by(97) {
        assert!(
            WorkerDecoder::new(&context[..len]).is_err(),
            "context truncated to {len}"
        );
    }
    for at in 0..bytes.len() {
        assert!(
            worker.run(&flipped(bytes, at, false)).is_err(),
            "job byte {at} flipped"
        );
    }
    for at in 0..answer.len() {
        assert!(
            job.receive(&flipped(answer, at, false)).is_err(),
            "answer byte {at} flipped"
        );
    }
    for at in (0..context.len()).step_by(13) {
        assert!(
            WorkerDecoder::new(&flipped(context, at, false)).is_err(),
            "context byte {at}"
        );
    }
}

/// A spawner whose jobs wait in a queue until [`Stopping::deliver`] (between frames, like a
/// worker's answers arriving, so that the refiner decodes ahead in jobs of several steps), and
/// each job stops after every step and goes on as the job of the steps left — as a job on a
/// starving decode worker hands its rest to the standby pool.
#[derive(Clone, Default)]
struct Stopping {
    /// Each job run to its end answers how many times it stopped.
    queue: Rc<RefCell<Vec<StoppingJob>>>,
    /// Times a job stopped and went on.
    stops: Rc<RefCell<usize>>,
}

type StoppingJob = Box<dyn FnOnce() -> usize>;

impl Stopping {
    fn deliver(&self) {
        let jobs = std::mem::take(&mut *self.queue.borrow_mut());
        for job in jobs {
            *self.stops.borrow_mut() += job();
        }
    }
}

impl Spawner for Stopping {
    fn spawn<F: FnOnce() + Send + 'static>(&self, job: F) {
        job();
    }
    fn spawn_job<J: Portable>(&self, job: J) {
        self.queue.borrow_mut().push(Box::new(move || {
            let (mut job, mut stops) = (job, 0);
            while let Some(rest) = job.run_until(&|| true) {
                job = rest;
                stops += 1;
            }
            stops
        }));
    }
    fn parallelism(&self) -> usize {
        2
    }
}

#[test]
fn jobs_that_stop_after_every_step_and_go_on_converge_to_the_cut_refined_in_place() {
    let repo = repository();
    let world = World::of_repository(&repo);
    let cams = cameras(&world);
    let cam = cams[8];
    let reference = converged_in_place(&repo, &cam);

    let stopping = Stopping::default();
    let config = between_frames_config();
    let mut r =
        Refiner::with_spawner(LocalSource::new(repo.clone()), config, stopping.clone()).unwrap();
    let converged = fly_in_and_settle(&mut r, &cams, &cam, |_| stopping.deliver());
    assert!(converged.is_some(), "no convergence");
    // Decoding ahead made jobs of several steps, and they did stop.
    assert!(
        *stopping.stops.borrow() > 20,
        "{} stops",
        stopping.stops.borrow()
    );
    assert_eq!(refined_set(r.cut()), refined_set(reference.cut()));
    assert_eq!(drawn(&r), drawn(&reference));
}
