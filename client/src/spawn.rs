//! The executor seam: where the refinement loop's decode jobs run.
//!
//! The refiner hands each decode to a [`Spawner`] and collects the result from a channel, so it
//! never names a thread pool. On the desktop [`Rayon`] puts jobs on rayon's global pool (the job
//! is passed straight to `rayon::spawn`: no boxing beyond rayon's own); [`Inline`] runs them on
//! the calling thread, for targets without threads (wasm32 in a browser's main thread) and for
//! tests that want a deterministic order. [`DefaultSpawner`] is the target's natural choice.
//!
//! The refiner's decode jobs are [`Portable`]: besides running in place they can be written as
//! bytes and their results read back, so that a spawner whose workers share no memory with the
//! caller (a page's Web Workers, which get messages) can run them elsewhere
//! ([`Spawner::spawn_job`]). Spawners with threads run them in place, as closures.

use cbdam_codec::CodecError;

/// A job that runs in place or crosses to a worker that shares no memory with the caller as
/// bytes. It reports its results itself either way (into the channel it carries).
pub trait Portable: Send + 'static {
    /// Runs the job here and reports its results.
    fn run(self);
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
    /// How many jobs can run at once: the refiner keeps about twice that many in flight.
    fn parallelism(&self) -> usize;
    /// Whether jobs run in the background, so that work handed over at the end of a frame
    /// overlaps the time until the next one (the refiner decodes ahead speculatively only
    /// then). True unless jobs run on the calling thread.
    fn runs_in_background(&self) -> bool {
        true
    }
}

/// Rayon's global thread pool.
#[cfg(not(target_arch = "wasm32"))]
#[derive(Clone, Copy, Debug, Default)]
pub struct Rayon;

#[cfg(not(target_arch = "wasm32"))]
impl Spawner for Rayon {
    #[inline]
    fn spawn<F: FnOnce() + Send + 'static>(&self, job: F) {
        rayon::spawn(job);
    }
    fn parallelism(&self) -> usize {
        rayon::current_num_threads()
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

/// The target's spawner: [`Rayon`] on native targets.
#[cfg(not(target_arch = "wasm32"))]
pub type DefaultSpawner = Rayon;
/// The target's spawner: [`Inline`] on wasm32, which has no threads of its own.
#[cfg(target_arch = "wasm32")]
pub type DefaultSpawner = Inline;
