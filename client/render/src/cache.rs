//! Bookkeeping of the GPU patch cache: which [`PatchKey`] lives in which slot of the height
//! pool, least-recently-used eviction, and the per-frame upload budget.
//!
//! Pure CPU logic (the renderer does the copies), so it is tested without a GPU. Slots are keyed
//! by [`PatchKey`] and a half-patch never changes once made (see [`cbdam_client::patch`]), so a hit is
//! always the right heights: a slot can be missing, never stale. Slots used by the frame being
//! built are pinned: evicting one would overwrite heights that an earlier instance of the same
//! frame still reads.

use std::collections::{BTreeSet, HashMap};

use cbdam_client::patch::PatchKey;

/// Counters of the patch cache, cumulative since the renderer was made (or since
/// [`SlotCache::clear`]); [`crate::DrawStats`] has the same counts for one frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CacheStats {
    /// Patches found resident.
    pub hits: u64,
    /// Patches copied into a slot.
    pub uploads: u64,
    /// Resident patches evicted to make room.
    pub evictions: u64,
    /// Patches not drawn because the frame's upload budget was spent.
    pub deferred: u64,
    /// Patches not drawn because every slot was pinned by the frame (pool too small).
    pub no_slot: u64,
    /// Bytes uploaded.
    pub uploaded_bytes: u64,
}

impl CacheStats {
    /// `self − earlier`, counter by counter.
    pub fn since(&self, earlier: &CacheStats) -> CacheStats {
        CacheStats {
            hits: self.hits - earlier.hits,
            uploads: self.uploads - earlier.uploads,
            evictions: self.evictions - earlier.evictions,
            deferred: self.deferred - earlier.deferred,
            no_slot: self.no_slot - earlier.no_slot,
            uploaded_bytes: self.uploaded_bytes - earlier.uploaded_bytes,
        }
    }
}

/// What [`SlotCache::request`] decided for one patch.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Residency {
    /// Resident in this slot; draw it.
    Hit(u32),
    /// Given this slot; copy the heights there this frame, then draw it.
    Upload(u32),
    /// Not drawn this frame.
    Missing,
}

/// Slot assignment with LRU eviction.
#[derive(Clone, Debug)]
pub struct SlotCache {
    slot_bytes: u64,
    /// Key and last use (a tick of `clock`), per slot.
    slots: Vec<Option<(PatchKey, u64)>>,
    map: HashMap<PatchKey, u32>,
    /// `(last use, slot)` of every occupied slot: the first entry is the LRU victim.
    lru: BTreeSet<(u64, u32)>,
    free: Vec<u32>,
    /// Ticks once per request, so uses within a frame are ordered too.
    clock: u64,
    /// `clock` when the frame began: slots used since are pinned.
    frame_start: u64,
    budget: u64,
    spent: u64,
    stats: CacheStats,
}

impl SlotCache {
    /// `slots` slots of `slot_bytes` each; at most `upload_budget` bytes copied per frame.
    pub fn new(slots: u32, slot_bytes: u64, upload_budget: u64) -> Self {
        Self {
            slot_bytes,
            slots: vec![None; slots as usize],
            map: HashMap::new(),
            lru: BTreeSet::new(),
            // Popped from the end: hand out slot 0 first.
            free: (0..slots).rev().collect(),
            clock: 0,
            frame_start: 1,
            budget: upload_budget,
            spent: 0,
            stats: CacheStats::default(),
        }
    }

    /// Number of slots.
    pub fn capacity(&self) -> u32 {
        self.slots.len() as u32
    }

    /// Patches resident now.
    pub fn resident(&self) -> usize {
        self.map.len()
    }

    /// Whether `key` is resident (the refinement loop may prefer drawing resident patches).
    pub fn contains(&self, key: &PatchKey) -> bool {
        self.map.contains_key(key)
    }

    /// Cumulative counters.
    pub fn stats(&self) -> CacheStats {
        self.stats
    }

    /// Starts a frame: unpins every slot and resets the upload budget.
    pub fn begin_frame(&mut self) {
        self.frame_start = self.clock + 1;
        self.spent = 0;
    }

    /// Decides where `key` is drawn from this frame, evicting the least recently used unpinned
    /// slot if needed, and pins that slot for the rest of the frame.
    pub fn request(&mut self, key: PatchKey) -> Residency {
        self.clock += 1;
        if let Some(&slot) = self.map.get(&key) {
            self.touch(slot);
            self.stats.hits += 1;
            return Residency::Hit(slot);
        }
        if self.spent + self.slot_bytes > self.budget {
            self.stats.deferred += 1;
            return Residency::Missing;
        }
        let slot = match self.free.pop() {
            Some(s) => s,
            None => {
                let Some(&(last, victim)) = self.lru.first() else {
                    self.stats.no_slot += 1;
                    return Residency::Missing;
                };
                if last >= self.frame_start {
                    // Even the least recently used slot is drawn this frame.
                    self.stats.no_slot += 1;
                    return Residency::Missing;
                }
                self.lru.remove(&(last, victim));
                let (old, _) = self.slots[victim as usize]
                    .take()
                    .expect("LRU slot occupied");
                self.map.remove(&old);
                self.stats.evictions += 1;
                victim
            }
        };
        self.slots[slot as usize] = Some((key, self.clock));
        self.map.insert(key, slot);
        self.lru.insert((self.clock, slot));
        self.spent += self.slot_bytes;
        self.stats.uploads += 1;
        self.stats.uploaded_bytes += self.slot_bytes;
        Residency::Upload(slot)
    }

    fn touch(&mut self, slot: u32) {
        let entry = self.slots[slot as usize]
            .as_mut()
            .expect("mapped slot occupied");
        self.lru.remove(&(entry.1, slot));
        entry.1 = self.clock;
        self.lru.insert((self.clock, slot));
    }

    /// Forgets every patch (another repository, or a lost device). Counters are kept.
    pub fn clear(&mut self) {
        let n = self.slots.len() as u32;
        self.slots.iter_mut().for_each(|s| *s = None);
        self.map.clear();
        self.lru.clear();
        self.free = (0..n).rev().collect();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cbdam_codec::geometry::{DiamondId, Half};

    fn key(i: u32) -> PatchKey {
        (DiamondId::new(3, i, 0), Half::Positive)
    }

    #[test]
    fn hits_uploads_and_lru_eviction() {
        let mut c = SlotCache::new(3, 100, u64::MAX);
        c.begin_frame();
        assert_eq!(c.request(key(1)), Residency::Upload(0));
        assert_eq!(c.request(key(2)), Residency::Upload(1));
        assert_eq!(c.request(key(3)), Residency::Upload(2));
        c.begin_frame();
        // 2 is used, then 1: 3 is now least recently used.
        assert_eq!(c.request(key(2)), Residency::Hit(1));
        assert_eq!(c.request(key(1)), Residency::Hit(0));
        c.begin_frame();
        assert_eq!(c.request(key(4)), Residency::Upload(2));
        assert!(!c.contains(&key(3)));
        // Next victim is 2 (used before 1 last frame).
        assert_eq!(c.request(key(5)), Residency::Upload(1));
        assert!(c.contains(&key(1)) && !c.contains(&key(2)));
        let s = c.stats();
        assert_eq!((s.hits, s.uploads, s.evictions), (2, 5, 2));
        assert_eq!(s.uploaded_bytes, 500);
    }

    #[test]
    fn pinned_slots_are_never_evicted_within_a_frame() {
        let mut c = SlotCache::new(2, 100, u64::MAX);
        c.begin_frame();
        assert!(matches!(c.request(key(1)), Residency::Upload(_)));
        assert!(matches!(c.request(key(2)), Residency::Upload(_)));
        assert_eq!(c.request(key(3)), Residency::Missing);
        assert_eq!(c.stats().no_slot, 1);
        // Asking again for a resident key of this frame is a hit in the same slot.
        let Residency::Hit(s) = c.request(key(1)) else {
            panic!()
        };
        assert_eq!(c.slots[s as usize].unwrap().0, key(1));
        // The map and the slot table always agree.
        for (k, &s) in &c.map {
            assert_eq!(c.slots[s as usize].unwrap().0, *k);
        }
    }

    #[test]
    fn upload_budget_defers_the_rest_of_the_frame() {
        let mut c = SlotCache::new(10, 100, 250);
        c.begin_frame();
        assert!(matches!(c.request(key(1)), Residency::Upload(_)));
        assert!(matches!(c.request(key(2)), Residency::Upload(_)));
        assert_eq!(c.request(key(3)), Residency::Missing);
        assert!(matches!(c.request(key(1)), Residency::Hit(_)));
        c.begin_frame();
        assert!(matches!(c.request(key(3)), Residency::Upload(_)));
        assert_eq!(c.stats().deferred, 1);
        c.clear();
        assert_eq!(c.resident(), 0);
        c.begin_frame();
        assert_eq!(c.request(key(1)), Residency::Upload(0));
    }
}
