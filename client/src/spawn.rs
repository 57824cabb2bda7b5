//! The executor seam: where the refinement loop's decode jobs run.
//!
//! The refiner hands each decode to a [`Spawner`] and collects the result from a channel, so it
//! never names a thread pool. On the desktop [`Rayon`] puts jobs on rayon's global pool (the job
//! is passed straight to `rayon::spawn`: no boxing beyond rayon's own); [`Inline`] runs them on
//! the calling thread, for targets without threads (wasm32 in a browser's main thread) and for
//! tests that want a deterministic order. [`DefaultSpawner`] is the target's natural choice.

/// Runs decode jobs.
pub trait Spawner {
    /// Runs `job`, now or later, on this thread or another. The job reports its result itself.
    fn spawn<F: FnOnce() + Send + 'static>(&self, job: F);
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
