//! Decode workers that starve get help.
//!
//! The desktop's decode workers run at `SCHED_IDLE` by default, so that they never take a core
//! from the frame thread. Beside another program that keeps every core busy (a build, a second
//! viewer) such workers get no CPU at all: measured on 2 cores beside two busy loops, 3–7
//! diamonds a second and a cut that never converged. A watchdog notices that jobs wait while no
//! step has finished for [`STARVED_AFTER`] and hands the waiting jobs to a standby pool at the
//! normal policy (with a short time slice where the kernel has one) for at least
//! [`RESCUE_HOLD`]; a job running on a starved worker hands the steps it has not run to the
//! standby pool at its next step. Without such load the idle workers finish a step every
//! fraction of a millisecond, the watchdog never fires, and the standby threads sleep.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, Weak};
use std::time::Duration;

use web_time::Instant;

use super::Portable;

/// Jobs waited and no step finished on the workers for this long: they starve. A step takes
/// 0.1–0.5 ms at N = 65 on this machine, a job of decoding ahead at most 128 of them.
pub const STARVED_AFTER: Duration = Duration::from_millis(100);
/// How often the watchdog looks.
const CHECK_EVERY: Duration = Duration::from_millis(25);
/// Once the workers starved, the standby pool takes jobs for at least this long.
pub const RESCUE_HOLD: Duration = Duration::from_secs(1);

/// Which pool runs a task.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Lane {
    Workers,
    Standby,
}

type Task = Box<dyn FnOnce(Lane, &Arc<Tiers>) + Send>;

/// Two pools sharing one queue of jobs: the workers, which take every job, and the standby
/// pool, which takes them only while the workers starve (see the module's documentation).
pub struct Tiers {
    workers: rayon::ThreadPool,
    standby: rayon::ThreadPool,
    /// Jobs not started, oldest first, each with when it was queued.
    queue: Mutex<VecDeque<(Instant, Task)>>,
    epoch: Instant,
    /// Nanoseconds from `epoch`: when a job on the workers last started, finished a step or
    /// ended.
    last_progress: AtomicU64,
    /// Jobs running on the workers.
    running: AtomicUsize,
    /// Nanoseconds from `epoch` until which the standby pool takes jobs.
    rescue_until: AtomicU64,
    /// Jobs (or the rest of one) the standby pool ran.
    rescued: AtomicU64,
    /// Tasks handed to the standby pool and not started yet.
    standby_waiting: AtomicUsize,
}

impl Tiers {
    /// Two pools under one queue, and the watchdog (a thread that ends with them).
    pub fn new(workers: rayon::ThreadPool, standby: rayon::ThreadPool) -> Arc<Self> {
        let tiers = Arc::new(Self {
            workers,
            standby,
            queue: Mutex::new(VecDeque::new()),
            epoch: Instant::now(),
            last_progress: AtomicU64::new(0),
            running: AtomicUsize::new(0),
            rescue_until: AtomicU64::new(0),
            rescued: AtomicU64::new(0),
            standby_waiting: AtomicUsize::new(0),
        });
        let weak = Arc::downgrade(&tiers);
        std::thread::Builder::new()
            .name("cbdam-watchdog".into())
            .spawn(move || watch(weak))
            .expect("starting the decode watchdog");
        tiers
    }

    /// How many jobs the workers run at once.
    pub fn parallelism(&self) -> usize {
        self.workers.current_num_threads()
    }

    /// How many jobs, or rests of one, the standby pool has run.
    pub fn rescued(&self) -> u64 {
        self.rescued.load(Ordering::Relaxed)
    }

    /// Whether the standby pool takes jobs now.
    pub fn rescuing(&self) -> bool {
        self.now() < self.rescue_until.load(Ordering::Relaxed)
    }

    /// Queues a job that can stop between its steps: on a starving worker it hands the rest
    /// to the standby pool.
    pub fn spawn_job<J: Portable>(self: &Arc<Self>, job: J) {
        self.queue_task(
            Box::new(move |lane, tiers: &Arc<Tiers>| tiers.run(job, lane)),
            false,
        );
    }

    /// Queues a job that runs whole wherever it starts.
    pub fn spawn<F: FnOnce() + Send + 'static>(self: &Arc<Self>, job: F) {
        self.queue_task(
            Box::new(move |lane, tiers: &Arc<Tiers>| {
                if lane == Lane::Workers {
                    tiers.started();
                    job();
                    tiers.ended();
                } else {
                    tiers.rescued.fetch_add(1, Ordering::Relaxed);
                    job();
                }
            }),
            false,
        );
    }

    fn queue_task(self: &Arc<Self>, task: Task, first: bool) {
        {
            let mut queue = self.queue.lock().expect("decode queue");
            if first {
                queue.push_front((Instant::now(), task));
            } else {
                queue.push_back((Instant::now(), task));
            }
        }
        // Each task the pools run takes the oldest job queued, whichever it is; one left with
        // none (the other pool took it) ends at once.
        if !first {
            let tiers = Arc::clone(self);
            self.workers.spawn(move || tiers.run_next(Lane::Workers));
        }
        if first || self.rescuing() {
            self.call_standby();
        }
    }

    /// One more task for the standby pool: it takes the oldest job queued.
    fn call_standby(self: &Arc<Self>) {
        self.standby_waiting.fetch_add(1, Ordering::Relaxed);
        let tiers = Arc::clone(self);
        self.standby.spawn(move || {
            tiers.standby_waiting.fetch_sub(1, Ordering::Relaxed);
            tiers.run_next(Lane::Standby);
        });
    }

    fn run_next(self: &Arc<Self>, lane: Lane) {
        let next = self.queue.lock().expect("decode queue").pop_front();
        if let Some((_, task)) = next {
            task(lane, self);
        }
    }

    fn run<J: Portable>(self: &Arc<Self>, job: J, lane: Lane) {
        if lane == Lane::Standby {
            self.rescued.fetch_add(1, Ordering::Relaxed);
            job.run();
            return;
        }
        self.started();
        let rest = job.run_until(&|| {
            self.progress();
            self.rescuing()
        });
        self.ended();
        if let Some(rest) = rest {
            // The rest goes first: the frame may be waiting for its results.
            self.queue_task(
                Box::new(move |lane, tiers: &Arc<Tiers>| tiers.run(rest, lane)),
                true,
            );
        }
    }

    fn started(&self) {
        self.running.fetch_add(1, Ordering::Relaxed);
        self.progress();
    }

    fn ended(&self) {
        self.progress();
        self.running.fetch_sub(1, Ordering::Relaxed);
    }

    fn progress(&self) {
        self.last_progress.store(self.now(), Ordering::Relaxed);
    }

    fn now(&self) -> u64 {
        self.epoch.elapsed().as_nanos() as u64
    }

    /// Whether the workers starve: a job has waited, or one has run, for [`STARVED_AFTER`]
    /// without a step finishing on them. If so, the standby pool takes the jobs queued.
    fn check(self: &Arc<Self>) {
        let now = self.now();
        let last = self.last_progress.load(Ordering::Relaxed);
        let waiting = {
            let queue = self.queue.lock().expect("decode queue");
            queue.front().map(|(queued, _)| {
                (
                    queue.len(),
                    queued.duration_since(self.epoch).as_nanos() as u64,
                )
            })
        };
        let since = match waiting {
            Some((_, queued)) => last.max(queued),
            None if self.running.load(Ordering::Relaxed) > 0 => last,
            None => return,
        };
        if now.saturating_sub(since) < STARVED_AFTER.as_nanos() as u64 {
            return;
        }
        self.rescue_until
            .store(now + RESCUE_HOLD.as_nanos() as u64, Ordering::Relaxed);
        // A task for each job queued that none waits for yet (a starvation that lasts is seen
        // at every check).
        let queued = waiting.map_or(0, |(n, _)| n);
        for _ in self.standby_waiting.load(Ordering::Relaxed)..queued {
            self.call_standby();
        }
    }
}

fn watch(tiers: Weak<Tiers>) {
    loop {
        std::thread::sleep(CHECK_EVERY);
        let Some(tiers) = tiers.upgrade() else { return };
        tiers.check();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cbdam_codec::CodecError;
    use std::sync::mpsc;

    fn pool(name: &'static str, threads: usize) -> rayon::ThreadPool {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(move |i| format!("{name}-{i}"))
            .build()
            .unwrap()
    }

    type Log = Arc<Mutex<Vec<(u32, String)>>>;

    /// A job of numbered steps, each logged with the thread that ran it.
    struct Steps {
        left: VecDeque<u32>,
        step: Duration,
        log: Log,
        done: mpsc::Sender<()>,
    }

    impl Steps {
        fn one(&mut self) {
            let n = self.left.pop_front().unwrap();
            std::thread::sleep(self.step);
            let thread = std::thread::current().name().unwrap_or("?").to_owned();
            self.log.lock().unwrap().push((n, thread));
            if self.left.is_empty() {
                self.done.send(()).unwrap();
            }
        }
    }

    impl Portable for Steps {
        fn run(mut self) {
            while !self.left.is_empty() {
                self.one();
            }
        }
        fn run_until(mut self, stop: &dyn Fn() -> bool) -> Option<Self> {
            while !self.left.is_empty() {
                self.one();
                if !self.left.is_empty() && stop() {
                    return Some(self);
                }
            }
            None
        }
        fn encode(&self) -> Vec<u8> {
            Vec::new()
        }
        fn receive(&self, _: &[u8]) -> Result<(), CodecError> {
            Ok(())
        }
        fn steps(&self) -> usize {
            self.left.len()
        }
    }

    /// Tiers whose one worker is held (as a starved worker is: it never runs a job), and the
    /// sender that frees it.
    fn held_worker() -> (Arc<Tiers>, mpsc::Sender<()>) {
        let workers = pool("test-workers", 1);
        let (release, held) = mpsc::channel::<()>();
        let (holding, is_held) = mpsc::channel();
        workers.spawn(move || {
            holding.send(()).unwrap();
            let _ = held.recv();
        });
        is_held.recv().unwrap();
        (Tiers::new(workers, pool("test-standby", 2)), release)
    }

    #[test]
    fn jobs_of_starving_workers_run_on_the_standby_pool() {
        let (tiers, release) = held_worker();
        let (done, finished) = mpsc::channel();
        let runs = Arc::new(AtomicUsize::new(0));
        for _ in 0..10 {
            let (done, runs) = (done.clone(), Arc::clone(&runs));
            tiers.spawn(move || {
                runs.fetch_add(1, Ordering::Relaxed);
                done.send(()).unwrap();
            });
        }
        for _ in 0..10 {
            finished
                .recv_timeout(Duration::from_secs(10))
                .expect("a queued job ran although the worker is held");
        }
        assert_eq!(tiers.rescued(), 10);
        assert!(tiers.rescuing());
        // Freed, the worker's leftover tasks find the queue empty: every job ran once.
        release.send(()).unwrap();
        std::thread::sleep(Duration::from_millis(50));
        assert_eq!(runs.load(Ordering::Relaxed), 10);
    }

    #[test]
    fn a_job_on_a_worker_hands_its_rest_over_while_rescuing() {
        let (tiers, release) = held_worker();
        // Starve the worker until the watchdog rescues, then free it: its queued task starts
        // the next job there, which must stop after one step and go on in the standby pool.
        let (done, finished) = mpsc::channel();
        tiers.spawn(move || done.send(()).unwrap());
        finished.recv_timeout(Duration::from_secs(10)).unwrap();
        assert!(tiers.rescuing());
        release.send(()).unwrap();
        std::thread::sleep(Duration::from_millis(20));
        // The standby threads busy for a while, so that the worker starts the job.
        for _ in 0..2 {
            tiers
                .standby
                .spawn(|| std::thread::sleep(Duration::from_millis(60)));
        }
        let log = Log::default();
        let (done, finished) = mpsc::channel();
        tiers.spawn_job(Steps {
            left: (0..6).collect(),
            step: Duration::from_millis(2),
            log: Arc::clone(&log),
            done,
        });
        finished.recv_timeout(Duration::from_secs(10)).unwrap();
        let log = log.lock().unwrap().clone();
        let order: Vec<u32> = log.iter().map(|(n, _)| *n).collect();
        assert_eq!(
            order,
            (0..6).collect::<Vec<_>>(),
            "every step once, in order"
        );
        // Started on the worker, from its second step on it ran on the standby pool.
        assert!(log[0].1.starts_with("test-workers"), "{log:?}");
        assert!(
            log[1..].iter().all(|(_, t)| t.starts_with("test-standby")),
            "{log:?}"
        );
    }

    #[test]
    fn workers_that_keep_up_get_no_help() {
        let tiers = Tiers::new(pool("test-workers", 1), pool("test-standby", 1));
        let log = Log::default();
        let (done, finished) = mpsc::channel();
        // A job longer than STARVED_AFTER, and jobs queued behind it for as long: each step
        // that finishes shows the worker is running.
        for _ in 0..3 {
            tiers.spawn_job(Steps {
                left: (0..40).collect(),
                step: Duration::from_millis(5),
                log: Arc::clone(&log),
                done: done.clone(),
            });
        }
        for _ in 0..3 {
            finished.recv_timeout(Duration::from_secs(20)).unwrap();
        }
        assert_eq!(tiers.rescued(), 0);
        assert!(!tiers.rescuing());
        let log = log.lock().unwrap();
        assert_eq!(log.len(), 120);
        assert!(log.iter().all(|(_, t)| t.starts_with("test-workers")));
    }
}
