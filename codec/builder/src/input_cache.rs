//! The samples of a planet's inputs, read when a lattice tile asks for them and kept while they
//! fit a byte budget.
//!
//! A planet of thousands of SRTM tiles cannot hold them all: each input is opened from its
//! header alone ([`crate::input::TileReader`]) and its samples are read whole the first time a
//! lattice tile (or the resampling error) asks for them, then kept until they are the least
//! recently used and the budget is exceeded. Samples in use are never freed under their user
//! (they are shared), so memory is the budget plus what the build's workers use at once (one
//! input each). An input asked for by several workers at once is read once: the others wait
//! for it. Inputs *pinned* at the start (those around the globe, which every lattice tile
//! asks for) are kept once read, outside the budget: a global base such as ETOPO5 is read
//! once however small the budget.

use std::collections::{HashMap, HashSet};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, Weak};

use crate::band_cache::Samples;
use crate::error::Result;

/// One input's place in the cache: its samples once read (the lock held while they are read).
#[derive(Default)]
struct Slot {
    samples: Mutex<Option<Arc<Samples>>>,
}

/// A slot, the tick of its last use and its bytes (0 while being read).
struct Entry {
    slot: Arc<Slot>,
    used: u64,
    bytes: u64,
}

#[derive(Default)]
struct State {
    entries: HashMap<usize, Entry>,
    /// Inputs evicted while a caller may still hold them: asked for again while one does,
    /// they are taken back rather than read into a second copy.
    let_go: HashMap<usize, Weak<Samples>>,
    bytes: u64,
    tick: u64,
}

/// The cache; see the module notes.
pub struct InputCache {
    budget: AtomicU64,
    pinned: HashSet<usize>,
    state: Mutex<State>,
    reads: AtomicU64,
}

impl InputCache {
    /// An empty cache keeping at most `budget` bytes of samples besides those in use.
    #[cfg(test)]
    pub fn new(budget: u64) -> Self {
        Self::with_pinned(budget, HashSet::new())
    }

    /// An empty cache keeping at most `budget` bytes of samples besides those in use and
    /// those of the inputs in `pinned`, which are kept once read.
    pub fn with_pinned(budget: u64, pinned: HashSet<usize>) -> Self {
        Self {
            budget: AtomicU64::new(budget),
            pinned,
            state: Mutex::new(State::default()),
            reads: AtomicU64::new(0),
        }
    }

    /// The bytes it may keep.
    pub fn budget(&self) -> u64 {
        self.budget.load(Ordering::Relaxed)
    }

    /// Keeps at most `budget` bytes from now on (those kept now are let go as others are read).
    pub fn set_budget(&self, budget: u64) {
        self.budget.store(budget, Ordering::Relaxed);
    }

    /// Whether input `key` is kept once read, outside the budget.
    pub fn is_pinned(&self, key: usize) -> bool {
        self.pinned.contains(&key)
    }

    /// Inputs read so far (a read again after eviction counts again).
    pub fn reads(&self) -> u64 {
        self.reads.load(Ordering::Relaxed)
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The samples of input `key`: kept ones, or read by `read` (once, however many workers
    /// ask at the same time) and kept while the budget allows. `read` runs holding the input's
    /// lock: it must not wait on work of a thread pool that may be asking for the same input.
    pub fn get(&self, key: usize, read: impl FnOnce() -> Result<Samples>) -> Result<Arc<Samples>> {
        let slot = {
            let mut s = self.lock();
            s.tick += 1;
            let tick = s.tick;
            if let Some(alive) = self.take_back(&mut s, key, tick) {
                return Ok(alive);
            }
            let e = s.entries.entry(key).or_insert_with(|| Entry {
                slot: Arc::default(),
                used: tick,
                bytes: 0,
            });
            e.used = tick;
            Arc::clone(&e.slot)
        };
        let mut held = slot.samples.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(samples) = held.as_ref() {
            return Ok(Arc::clone(samples));
        }
        let samples = Arc::new(read()?);
        self.reads.fetch_add(1, Ordering::Relaxed);
        *held = Some(Arc::clone(&samples));
        drop(held);
        let mut s = self.lock();
        // Counted only if the slot is still the cache's (it may have been evicted meanwhile:
        // then the samples live only as long as this caller keeps them).
        // Pinned inputs are kept outside the budget: never counted, never evicted.
        if let Some(e) = s
            .entries
            .get_mut(&key)
            .filter(|e| Arc::ptr_eq(&e.slot, &slot) && !self.pinned.contains(&key))
        {
            e.bytes = samples.bytes();
            s.bytes += samples.bytes();
        }
        self.evict(&mut s, key);
        Ok(samples)
    }

    /// Input `key`'s samples if it was evicted but a caller still holds them: kept again (one
    /// copy, not a second read).
    fn take_back(&self, s: &mut State, key: usize, tick: u64) -> Option<Arc<Samples>> {
        if s.entries.contains_key(&key) {
            return None;
        }
        let alive = s.let_go.remove(&key)?.upgrade()?;
        let bytes = match self.pinned.contains(&key) {
            true => 0,
            false => alive.bytes(),
        };
        let slot = Arc::new(Slot {
            samples: Mutex::new(Some(Arc::clone(&alive))),
        });
        s.entries.insert(
            key,
            Entry {
                slot,
                used: tick,
                bytes,
            },
        );
        s.bytes += bytes;
        self.evict(s, key);
        Some(alive)
    }

    /// Drops the least recently used inputs (read, and other than `keep`) until the kept bytes
    /// are within the budget.
    fn evict(&self, s: &mut State, keep: usize) {
        if s.bytes <= self.budget() {
            return;
        }
        let mut by_use: Vec<(u64, usize)> = s
            .entries
            .iter()
            .filter(|(k, e)| **k != keep && e.bytes > 0)
            .map(|(k, e)| (e.used, *k))
            .collect();
        by_use.sort_unstable();
        for (_, k) in by_use {
            if s.bytes <= self.budget() {
                break;
            }
            if let Some(e) = s.entries.remove(&k) {
                s.bytes -= e.bytes;
                let held = e.slot.samples.lock().unwrap_or_else(|e| e.into_inner());
                if let Some(samples) = held.as_ref() {
                    s.let_go.insert(k, Arc::downgrade(samples));
                }
            }
        }
    }

    /// Bytes kept now (samples in use by a caller but evicted not counted).
    #[cfg(test)]
    pub fn kept_bytes(&self) -> u64 {
        self.lock().bytes
    }
}

/// Makes the C allocator give every block of 1 MiB or more back to the system when it is
/// freed, as it does until its first such free: glibc then raises that threshold to the
/// block's size, and the inputs read and let go one after another (each with a buffer of 8
/// bytes a sample while read) come from its heaps instead, which keep the freed pieces resident
/// and grow with the number of inputs read (figures: `docs/RESULTS.md`, "Planets").
pub(crate) fn give_large_frees_back() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: `mallopt` only changes a tuning parameter of glibc's allocator.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 1 << 20);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn samples(n: usize, v: i16) -> Result<Samples> {
        Ok(Samples::I16(vec![v; n]))
    }

    /// Kept inputs are not read again; past the budget the least recently used go, and a
    /// later ask reads them again.
    #[test]
    fn inputs_are_kept_within_the_budget_least_recently_used_first() {
        let cache = InputCache::new(2 * 200);
        for key in 0..2 {
            cache.get(key, || samples(100, key as i16)).unwrap();
        }
        assert_eq!(cache.reads(), 2);
        assert_eq!(cache.kept_bytes(), 400);
        // 0 used again: 1 is now the least recently used.
        let again = cache.get(0, || panic!("0 is kept")).unwrap();
        assert_eq!(again.get(7), 0.0);
        cache.get(2, || samples(100, 2)).unwrap();
        assert_eq!(cache.kept_bytes(), 400);
        cache.get(0, || panic!("0 is still kept")).unwrap();
        cache.get(2, || panic!("2 is kept")).unwrap();
        let one = cache.get(1, || samples(100, 1)).unwrap();
        assert_eq!(one.get(0), 1.0);
        assert_eq!(cache.reads(), 4);
    }

    /// An input larger than the budget is returned (and not kept once another is asked for);
    /// a failed read is reported and read again next time.
    #[test]
    fn an_input_over_the_budget_and_a_failed_read() {
        let cache = InputCache::new(10);
        let big = cache.get(0, || samples(100, 5)).unwrap();
        assert_eq!(big.get(99), 5.0);
        cache.get(1, || samples(100, 6)).unwrap();
        assert_eq!(cache.kept_bytes(), 200);
        let e = cache.get(2, || crate::error::bail!("tile 2 is truncated"));
        assert!(e.unwrap_err().to_string().contains("tile 2 is truncated"));
        assert_eq!(cache.get(2, || samples(3, 7)).unwrap().get(2), 7.0);
        assert_eq!(cache.kept_bytes(), 6);
    }

    /// A pinned input is read once and kept, whatever the budget and however many other
    /// inputs come and go; the others are evicted as before.
    #[test]
    fn a_pinned_input_is_read_once_outside_the_budget() {
        let cache = InputCache::with_pinned(150, HashSet::from([9]));
        for round in 0..3 {
            let base = cache.get(9, || samples(1000, 9)).unwrap();
            assert_eq!(base.get(999), 9.0);
            for key in 0..3 {
                cache.get(key, || samples(100, key as i16)).unwrap();
                assert!(
                    cache.kept_bytes() <= 200,
                    "round {round}: {}",
                    cache.kept_bytes()
                );
            }
        }
        // The base once; the three others each round (only one of them fits).
        assert_eq!(cache.reads(), 1 + 3 * 3);
    }

    /// An input evicted while a caller still holds it is taken back when asked for again, not
    /// read into a second copy; once no one holds it, it is read again.
    #[test]
    fn an_evicted_input_still_in_use_is_taken_back_not_read_again() {
        let cache = InputCache::new(150);
        let first = cache.get(0, || samples(100, 0)).unwrap();
        cache.get(1, || samples(100, 1)).unwrap();
        // 0 was evicted for 1, but `first` still holds it.
        let again = cache.get(0, || panic!("0 is still in use")).unwrap();
        assert!(Arc::ptr_eq(&first, &again));
        assert_eq!(cache.reads(), 2);
        drop((first, again));
        cache.get(1, || samples(100, 1)).unwrap();
        cache.get(0, || samples(100, 0)).unwrap();
        assert_eq!(cache.reads(), 4);
    }

    /// Workers asking for the same input at once read it once.
    #[test]
    fn an_input_asked_for_by_several_workers_at_once_is_read_once() {
        let cache = InputCache::new(1 << 20);
        std::thread::scope(|s| {
            for _ in 0..8 {
                s.spawn(|| {
                    cache
                        .get(3, || {
                            std::thread::sleep(std::time::Duration::from_millis(20));
                            samples(10, 3)
                        })
                        .unwrap()
                });
            }
        });
        assert_eq!(cache.reads(), 1);
    }
}
