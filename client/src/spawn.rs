//! The executor seam: where the refinement loop's decode jobs run.
//!
//! The refiner hands each decode to a [`Spawner`] and collects the result from a channel, so it
//! never names a thread pool. On the desktop [`DecodePool`] queues jobs for a rayon pool of its
//! own whose threads run below the caller's priority, with a standby pool for when those starve
//! ([`rescue`]); [`Inline`] runs them on the calling thread, for targets without threads (wasm32
//! in a browser's main thread) and for tests that want a deterministic order.
//! [`DefaultSpawner`] is the target's natural choice.
//!
//! The refiner's decode jobs are [`Portable`]: besides running in place they can be written as
//! bytes and their results read back, so that a spawner whose workers share no memory with the
//! caller (a page's Web Workers, which get messages) can run them elsewhere
//! ([`Spawner::spawn_job`]). Spawners with threads run them in place, as closures.

use cbdam_codec::CodecError;

#[cfg(not(target_arch = "wasm32"))]
pub mod rescue;

/// A job that runs in place or crosses to a worker that shares no memory with the caller as
/// bytes. It reports its results itself either way (into the channel it carries).
pub trait Portable: Send + 'static {
    /// Runs the job here and reports its results.
    fn run(self);
    /// Runs the job here, asking `stop` between its steps; when told to stop, returns the job
    /// of the steps not run yet. Jobs that cannot stop run whole ([`Portable::run`]).
    fn run_until(self, stop: &dyn Fn() -> bool) -> Option<Self>
    where
        Self: Sized,
    {
        let _ = stop;
        self.run();
        None
    }
    /// The job as a message for a worker (which answers with the bytes for [`Portable::receive`]).
    fn encode(&self) -> Vec<u8>;
    /// Reports the results a worker answered with. A malformed answer is an error and reports
    /// nothing (the caller may then [`Portable::run`] the job itself).
    fn receive(&self, answer: &[u8]) -> Result<(), CodecError>;
    /// How many items (diamonds) the job works on, for counters.
    fn steps(&self) -> usize;
}

/// Runs decode jobs.
pub trait Spawner {
    /// Runs `job`, now or later, on this thread or another. The job reports its result itself.
    fn spawn<F: FnOnce() + Send + 'static>(&self, job: F);
    /// Runs a [`Portable`] job, now or later, here or elsewhere: in place on the spawner's
    /// threads unless a spawner overrides this (one whose workers take messages).
    #[inline]
    fn spawn_job<J: Portable>(&self, job: J) {
        self.spawn(move || job.run());
    }
    /// Whether [`Spawner::spawn_job`] may send jobs as messages ([`Portable::encode`]) to
    /// workers that share no memory with the caller. A spawner that overrides `spawn_job` to do
    /// so must say so: a decode job's message carries its parents' refinements, which the
    /// refiner's nodes otherwise drop once their children's halves are made. False unless a
    /// spawner says so (the default `spawn_job` runs jobs in place).
    fn sends_jobs_as_messages(&self) -> bool {
        false
    }
    /// How many jobs can run at once: the refiner keeps about twice that many in flight.
    fn parallelism(&self) -> usize;
    /// Whether jobs run in the background, so that work handed over at the end of a frame
    /// overlaps the time until the next one (the refiner decodes ahead speculatively only
    /// then). True unless jobs run on the calling thread.
    fn runs_in_background(&self) -> bool {
        true
    }
    /// Whether the workers run below the calling thread's priority, so that a job on every
    /// worker still leaves the caller its core the moment it wants it (the refiner then decodes
    /// ahead on all of them, not on all but one). False unless a spawner says so.
    fn yields_to_caller(&self) -> bool {
        false
    }
}

/// The desktop's decode workers: a rayon pool of its own, one thread per core (or
/// `RAYON_NUM_THREADS`), named `cbdam-decode-N`, made on first use and shared by every refiner
/// of the process.
///
/// Beside them waits a standby pool as large, `cbdam-standby-N`, at the caller's policy with a
/// short time slice: it takes the jobs only while the workers starve (another program keeps
/// every core busy and idle-priority workers get none; see [`rescue`]).
///
/// **The workers run below the frame thread's priority** ([`DecodePriority`]; Linux only,
/// elsewhere at the caller's). The frame loop has a deadline and the workers have none: with as
/// many workers as cores, a frame thread at the same priority shares its core with a worker and
/// ends its frames late. What the frame thread does not use the workers still get, so decoding
/// is no slower while the loop waits for it. See docs/REFINEMENT.md, "Decode workers below the
/// frame thread"; figures: docs/RESULTS.md.
#[cfg(not(target_arch = "wasm32"))]
#[derive(Clone, Copy, Debug, Default)]
pub struct DecodePool;

/// How the decode workers yield to the frame thread (Linux).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DecodePriority {
    /// `SCHED_IDLE`: a worker runs only on a core nothing else wants, and a waking frame thread
    /// always takes the core from it at once. A frame thread at nice 0 that sleeps between
    /// frames (a viewer's pacing) wakes with a credit that a worker even at nice 19 does not
    /// always yield to: paced `low_pass` (1920×1080, 2 ms, 2 cores) ran wall p99 6.7–7.0 ms
    /// with nice-19 workers and 2.9 ms with idle ones. The default.
    Idle,
    /// A nice value, 0 to 19, counted from the caller's (0: the caller's priority, as before
    /// issue 21's measurements).
    Nice(i32),
    /// `SCHED_OTHER` at a nice value (counted from the caller's) with a short time slice
    /// (`sched_setattr`, Linux 6.12 and later): a waking frame thread waits at most that slice
    /// for a worker's core.
    Sliced {
        /// 0 to 19.
        nice: i32,
        /// The slice, microseconds.
        slice_us: u32,
    },
}

impl DecodePriority {
    /// The default, or the `CBDAM_DECODE_PRIORITY` environment variable's choice
    /// ([`DecodePriority::parse`]).
    pub fn from_env() -> Self {
        std::env::var("CBDAM_DECODE_PRIORITY").map_or(Self::Idle, |v| Self::parse(&v))
    }

    /// `idle`; a nice value `0`…`19`; or `slice`, `slice:NICE` or `slice:NICE:MICROSECONDS`
    /// (defaults nice 0 and 100 µs, the slice 100 µs to 100 ms). Anything else is the default,
    /// `idle`; values out of range are clamped.
    pub fn parse(v: &str) -> Self {
        let v = v.trim();
        if let Some(rest) = v.strip_prefix("slice") {
            let parts: Vec<&str> = rest.split(':').collect();
            let number = |i: usize, default: i64| -> Option<i64> {
                parts.get(i).map_or(Some(default), |p| p.parse().ok())
            };
            if parts[0].is_empty()
                && parts.len() <= 3
                && let (Some(nice), Some(us)) = (number(1, 0), number(2, 100))
            {
                return Self::Sliced {
                    nice: nice.clamp(0, 19) as i32,
                    slice_us: us.clamp(100, 100_000) as u32,
                };
            }
            return Self::Idle;
        }
        match v.parse::<i32>() {
            Ok(n) => Self::Nice(n.clamp(0, 19)),
            Err(_) => Self::Idle,
        }
    }
}

#[cfg(not(target_arch = "wasm32"))]
impl DecodePool {
    fn pool() -> &'static std::sync::Arc<rescue::Tiers> {
        static POOL: std::sync::OnceLock<std::sync::Arc<rescue::Tiers>> =
            std::sync::OnceLock::new();
        POOL.get_or_init(|| {
            let priority = DecodePriority::from_env();
            let workers = rayon::ThreadPoolBuilder::new()
                .thread_name(|i| format!("cbdam-decode-{i}"))
                .start_handler(move |_| lower_priority(priority))
                .build()
                .expect("starting the decode threads");
            let standby = rayon::ThreadPoolBuilder::new()
                .num_threads(workers.current_num_threads())
                .thread_name(|i| format!("cbdam-standby-{i}"))
                .start_handler(|_| lower_priority(STANDBY_PRIORITY))
                .build()
                .expect("starting the standby decode threads");
            rescue::Tiers::new(workers, standby)
        })
    }

    /// How many jobs, or rests of one, the standby pool has run since the process started
    /// (see [`rescue`]).
    pub fn rescued() -> u64 {
        Self::pool().rescued()
    }
}

/// Lowers the calling thread's priority (Linux keeps the scheduling policy and the nice value
/// per thread). A nice value counts from the thread's own, so a viewer started under `nice`
/// keeps its workers and standby threads below it and never above (as root, setting nice 0
/// outright would raise them). A failure (a kernel without `SCHED_IDLE`) falls back to nice
/// 19, or leaves the thread as it was.
#[cfg(target_os = "linux")]
fn lower_priority(priority: DecodePriority) {
    let own = own_nice();
    let nice = match priority {
        DecodePriority::Idle => {
            let param = libc::sched_param { sched_priority: 0 };
            // SAFETY: `param` outlives the call, which only reads it; pid 0 is the calling
            // thread.
            if unsafe { libc::sched_setscheduler(0, libc::SCHED_IDLE, &param) } == 0 {
                return;
            }
            19
        }
        DecodePriority::Nice(n) => n,
        DecodePriority::Sliced { nice, slice_us } => {
            let attr = libc::sched_attr {
                size: std::mem::size_of::<libc::sched_attr>() as u32,
                sched_policy: libc::SCHED_OTHER as u32,
                sched_flags: 0,
                sched_nice: lowered(own, nice),
                sched_priority: 0,
                sched_runtime: u64::from(slice_us) * 1000,
                sched_deadline: 0,
                sched_period: 0,
            };
            // SAFETY: `attr` outlives the call, which only reads it; pid 0 is the calling
            // thread, flags 0.
            if unsafe { libc::syscall(libc::SYS_sched_setattr, 0, &attr as *const _, 0) } == 0 {
                return;
            }
            nice
        }
    };
    if nice > 0 {
        // SAFETY: plain integers, no memory of ours; `who` 0 is the calling thread.
        unsafe {
            libc::setpriority(libc::PRIO_PROCESS, 0, lowered(own, nice));
        }
    }
}

/// The calling thread's nice value (0 where it cannot be read).
#[cfg(target_os = "linux")]
fn own_nice() -> i32 {
    // SAFETY: errno is the calling thread's; getpriority takes plain integers, `who` 0 is the
    // calling thread. It may return -1 as a value, so errno tells an error apart.
    unsafe {
        *libc::__errno_location() = 0;
        let nice = libc::getpriority(libc::PRIO_PROCESS, 0);
        if *libc::__errno_location() == 0 {
            nice
        } else {
            0
        }
    }
}

/// A thread at nice `own` lowered by `by`: never above 19, never above `own`'s priority.
#[cfg(target_os = "linux")]
fn lowered(own: i32, by: i32) -> i32 {
    own.saturating_add(by.max(0)).min(19).max(own)
}

#[cfg(all(not(target_os = "linux"), not(target_arch = "wasm32")))]
fn lower_priority(_priority: DecodePriority) {}

/// The standby pool's priority: the caller's, with the shortest slice (measured beside two
/// busy loops on 2 cores: paced `low_pass` at 1 px 1.1–1.2 s after the camera stopped, where
/// idle workers never got there).
#[cfg(not(target_arch = "wasm32"))]
const STANDBY_PRIORITY: DecodePriority = DecodePriority::Sliced {
    nice: 0,
    slice_us: 100,
};

#[cfg(not(target_arch = "wasm32"))]
impl Spawner for DecodePool {
    #[inline]
    fn spawn<F: FnOnce() + Send + 'static>(&self, job: F) {
        Self::pool().spawn(job);
    }
    fn spawn_job<J: Portable>(&self, job: J) {
        Self::pool().spawn_job(job);
    }
    fn parallelism(&self) -> usize {
        Self::pool().parallelism()
    }
    fn yields_to_caller(&self) -> bool {
        cfg!(target_os = "linux")
    }
}

/// Runs each job at once on the calling thread.
#[derive(Clone, Copy, Debug, Default)]
pub struct Inline;

impl Spawner for Inline {
    #[inline]
    fn spawn<F: FnOnce() + Send + 'static>(&self, job: F) {
        job();
    }
    fn parallelism(&self) -> usize {
        1
    }
    fn runs_in_background(&self) -> bool {
        false
    }
}

/// The target's spawner: [`DecodePool`] on native targets.
#[cfg(not(target_arch = "wasm32"))]
pub type DefaultSpawner = DecodePool;
/// The target's spawner: [`Inline`] on wasm32, which has no threads of its own.
#[cfg(target_arch = "wasm32")]
pub type DefaultSpawner = Inline;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decode_priorities_parse_with_defaults_and_clamps() {
        assert_eq!(DecodePriority::parse("idle"), DecodePriority::Idle);
        assert_eq!(DecodePriority::parse(" 7 "), DecodePriority::Nice(7));
        assert_eq!(DecodePriority::parse("40"), DecodePriority::Nice(19));
        let sliced = |nice, slice_us| DecodePriority::Sliced { nice, slice_us };
        assert_eq!(DecodePriority::parse("slice"), sliced(0, 100));
        assert_eq!(DecodePriority::parse("slice:5"), sliced(5, 100));
        assert_eq!(DecodePriority::parse("slice:5:250"), sliced(5, 250));
        assert_eq!(DecodePriority::parse("slice:-3:1"), sliced(0, 100));
        for bad in ["", "fast", "slicex", "slice:a", "slice:1:2:3", "slice:1:b"] {
            assert_eq!(DecodePriority::parse(bad), DecodePriority::Idle, "{bad:?}");
        }
    }

    /// A sliced worker keeps the normal policy at its nice value (with the slice where the
    /// kernel takes one, Linux 6.12 and later), counted from the thread's own nice value.
    #[cfg(target_os = "linux")]
    #[test]
    fn a_sliced_worker_runs_at_its_nice_value() {
        let (own, nice) = std::thread::spawn(|| {
            let own = own_nice();
            lower_priority(DecodePriority::Sliced {
                nice: 3,
                slice_us: 200,
            });
            // SAFETY: plain integers; `who` 0 is the calling thread.
            let policy = unsafe { libc::sched_getscheduler(0) };
            (own, (policy, own_nice()))
        })
        .join()
        .unwrap();
        assert_eq!(nice, (libc::SCHED_OTHER, (own + 3).min(19)));
    }

    /// Under `nice`, no thread is raised above the caller: the standby pool's slice at nice 0
    /// keeps a thread started at nice 5 at nice 5, and the workers' nice values count from it.
    /// (As root the kernel would take nice 0 outright; CI runs as root.)
    #[cfg(target_os = "linux")]
    #[test]
    fn threads_under_nice_are_never_raised_above_it() {
        let after = |priority| {
            std::thread::spawn(move || {
                // SAFETY: plain integers; `who` 0 is the calling thread.
                unsafe { libc::setpriority(libc::PRIO_PROCESS, 0, 5) };
                let start = own_nice();
                lower_priority(priority);
                (start, own_nice())
            })
            .join()
            .unwrap()
        };
        let (start, standby) = after(STANDBY_PRIORITY);
        assert!(start >= 5, "the thread's nice was not raised to 5: {start}");
        assert_eq!(standby, start);
        assert_eq!(after(DecodePriority::Nice(4)).1, (start + 4).min(19));
        assert_eq!(after(DecodePriority::Nice(19)).1, 19);
    }
}
