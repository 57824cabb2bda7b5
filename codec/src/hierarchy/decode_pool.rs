//! Buffers a whole-hierarchy walk reuses instead of asking the heap for fresh ones: each level's
//! grids and refinements (about 33 KB a diamond at N = 65), and each worker's refinement scratch.
//! Freed heap memory goes back to the system between levels and comes back as page faults — a
//! fifth of a whole-file decode's time on one core before this pool.

use std::cell::RefCell;
use std::sync::Mutex;

use super::refine::{RefineScratch, Refined};

/// Grid buffers given back by a walk (the visited leaves, the refinements of the level before
/// last) and taken again by the next diamonds' grids.
#[derive(Debug, Default)]
pub(super) struct GridPool {
    free: Mutex<Vec<Vec<i32>>>,
}

impl GridPool {
    /// An empty buffer with room for `capacity` values: a given-back one when there is one.
    pub(super) fn take(&self, capacity: usize) -> Vec<i32> {
        let reused = self.free.lock().map(|mut free| free.pop()).unwrap_or(None);
        match reused {
            Some(mut v) => {
                v.clear();
                v.reserve(capacity);
                v
            }
            None => Vec::with_capacity(capacity),
        }
    }

    /// Keeps `v` for a later [`GridPool::take`].
    pub(super) fn give(&self, v: Vec<i32>) {
        if v.capacity() > 0
            && let Ok(mut free) = self.free.lock()
        {
            free.push(v);
        }
    }

    /// Keeps the buffers of `refinements`, which are no longer needed.
    pub(super) fn give_refinements(&self, refinements: impl IntoIterator<Item = Refined>) {
        let Ok(mut free) = self.free.lock() else {
            return;
        };
        free.extend(refinements.into_iter().map(Refined::into_values));
    }
}

thread_local! {
    /// Each worker thread's refinement scratch, kept between the diamonds and levels it decodes.
    static SCRATCH: RefCell<RefineScratch> = RefCell::new(RefineScratch::default());
}

/// Runs `f` with this thread's refinement scratch (a fresh one if it is already in use
/// further up this thread's stack).
pub(super) fn with_thread_scratch<T>(f: impl FnOnce(&mut RefineScratch) -> T) -> T {
    SCRATCH.with(|cell| match cell.try_borrow_mut() {
        Ok(mut scratch) => f(&mut scratch),
        Err(_) => f(&mut RefineScratch::default()),
    })
}
