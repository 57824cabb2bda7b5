//! A least-recently-used map bounded by the bytes of its values.

use std::collections::{HashMap, VecDeque};
use std::hash::Hash;

use cbdam_codec::geometry::IdBuildHasher;

/// An LRU map that evicts the least recently used entries once the sum of their declared sizes
/// exceeds a byte budget.
#[derive(Debug)]
pub struct LruCache<K, V> {
    /// Keyed by diamond ids in the refiner: the fast hasher, not SipHash (see `IdBuildHasher`).
    map: HashMap<K, (V, usize, u64), IdBuildHasher>,
    /// Keys with the tick of a use, oldest first. An entry whose tick is not its key's current
    /// one (the key was used again, or removed, since) is stale: eviction skips it, and the
    /// queue is compacted when stale entries outnumber the live ones. A use is then a push, not
    /// the removal and insertion of an ordered map's (which were a tenth of the refiner's cost
    /// of taking a record).
    order: VecDeque<(u64, K)>,
    tick: u64,
    bytes: usize,
    budget: usize,
    evictions: u64,
}

impl<K: Copy + Eq + Hash, V> LruCache<K, V> {
    /// An empty cache holding at most `budget` bytes.
    pub fn new(budget: usize) -> Self {
        Self {
            map: HashMap::default(),
            order: VecDeque::new(),
            tick: 0,
            bytes: 0,
            budget,
            evictions: 0,
        }
    }

    /// Inserts or replaces `key`, marks it most recent and evicts down to the budget. A value
    /// larger than the whole budget is not kept.
    pub fn insert(&mut self, key: K, value: V, bytes: usize) {
        self.insert_evicting(key, value, bytes, &mut Vec::new());
    }

    /// [`LruCache::insert`], moving what it evicts (and a value it replaces) into `evicted`
    /// rather than dropping it: the caller chooses where and when values are dropped.
    pub fn insert_evicting(&mut self, key: K, value: V, bytes: usize, evicted: &mut Vec<V>) {
        evicted.extend(self.remove(&key));
        self.tick += 1;
        self.map.insert(key, (value, bytes, self.tick));
        self.order.push_back((self.tick, key));
        self.bytes += bytes;
        while self.bytes > self.budget {
            let Some((t, k)) = self.order.pop_front() else {
                break;
            };
            if self.is_current(t, &k)
                && let Some((v, b, _)) = self.map.remove(&k)
            {
                self.bytes -= b;
                self.evictions += 1;
                evicted.push(v);
            }
        }
        self.compact();
    }

    /// Whether `(t, k)` in the queue is `k`'s last use.
    fn is_current(&self, t: u64, k: &K) -> bool {
        self.map.get(k).is_some_and(|e| e.2 == t)
    }

    /// Drops the stale entries of the queue once they outnumber the live ones (amortised: at
    /// least as many pushes as the live entries come between two compactions).
    fn compact(&mut self) {
        if self.order.len() > 2 * self.map.len() + 16 {
            let map = &self.map;
            self.order
                .retain(|(t, k)| map.get(k).is_some_and(|e| e.2 == *t));
        }
    }

    /// The value of `key`, marked most recent.
    pub fn get(&mut self, key: &K) -> Option<&V> {
        let e = self.map.get_mut(key)?;
        self.tick += 1;
        e.2 = self.tick;
        // The new use is current before the queue may be compacted.
        self.order.push_back((self.tick, *key));
        self.compact();
        self.map.get(key).map(|e| &e.0)
    }

    /// The value of `key`, leaving its recency as it was (for a look that takes the value out
    /// next, or only asks what kind of data is at hand).
    pub fn peek(&self, key: &K) -> Option<&V> {
        self.map.get(key).map(|(v, _, _)| v)
    }

    /// Whether `key` is cached (does not change recency).
    pub fn contains(&self, key: &K) -> bool {
        self.map.contains_key(key)
    }

    /// Removes and returns `key`'s value.
    pub fn remove(&mut self, key: &K) -> Option<V> {
        let (v, b, _) = self.map.remove(key)?;
        self.bytes -= b;
        self.compact();
        Some(v)
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        self.bytes
    }

    /// Entries held.
    pub fn len(&self) -> usize {
        self.map.len()
    }

    /// Whether it holds nothing.
    pub fn is_empty(&self) -> bool {
        self.map.is_empty()
    }

    /// Entries evicted so far.
    pub fn evictions(&self) -> u64 {
        self.evictions
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn evicts_least_recently_used_within_budget() {
        let mut c = LruCache::new(10);
        c.insert(1, "a", 4);
        c.insert(2, "b", 4);
        assert_eq!(c.peek(&2), Some(&"b")); // a peek leaves 2 the oldest
        assert_eq!(c.get(&1), Some(&"a")); // 2 is now the oldest
        c.insert(3, "c", 4);
        assert!(c.contains(&1) && !c.contains(&2) && c.contains(&3));
        assert_eq!((c.bytes(), c.len(), c.evictions()), (8, 2, 1));
        c.insert(4, "huge", 11);
        assert!(c.is_empty() && c.bytes() == 0);
        c.insert(5, "e", 3);
        assert_eq!(c.remove(&5), Some("e"));
        assert_eq!(c.bytes(), 0);
    }

    /// Uses that evict nothing leave stale entries in the queue; compaction keeps it within
    /// twice the live entries (plus a constant), however many uses come.
    #[test]
    fn the_use_queue_stays_bounded() {
        let mut c = LruCache::new(100);
        for k in 0..4 {
            c.insert(k, k, 1);
        }
        for i in 0..10_000 {
            c.get(&(i % 3));
            c.insert(3, i, 1);
            assert!(
                c.order.len() <= 2 * c.len() + 17,
                "{} queued",
                c.order.len()
            );
        }
        assert_eq!((c.len(), c.evictions()), (4, 0));
    }

    /// Against a model that keeps every entry's last use and evicts the oldest: the same
    /// entries, bytes and evictions after every operation of random sequences (uses of few
    /// keys, so that the queue fills with stale entries and is compacted), and every insertion
    /// hands out the values the model evicted and replaced.
    #[test]
    fn evicts_as_a_model_of_last_uses_does() {
        use proptest::prelude::*;
        #[derive(Clone, Debug)]
        enum Op {
            Insert(u8, usize),
            Get(u8),
            Peek(u8),
            Remove(u8),
        }
        let op = prop_oneof![
            (0u8..12, 1usize..6).prop_map(|(k, b)| Op::Insert(k, b)),
            (0u8..12).prop_map(Op::Get),
            (0u8..12).prop_map(Op::Peek),
            (0u8..12).prop_map(Op::Remove),
        ];
        proptest!(|(ops in proptest::collection::vec(op, 1..400))| {
            let mut c = LruCache::new(20);
            // key -> (value, bytes, last use)
            let mut model: HashMap<u8, (u32, usize, u64)> = HashMap::new();
            let (mut tick, mut evictions) = (0u64, 0u64);
            for (i, op) in ops.into_iter().enumerate() {
                let v = i as u32;
                match op {
                    Op::Insert(k, b) => {
                        let mut out = Vec::new();
                        c.insert_evicting(k, v, b, &mut out);
                        tick += 1;
                        let replaced = model.insert(k, (v, b, tick));
                        let mut gone: Vec<u32> = replaced.map(|e| e.0).into_iter().collect();
                        while model.values().map(|e| e.1).sum::<usize>() > 20 {
                            let oldest = *model.iter().min_by_key(|(_, e)| e.2).unwrap().0;
                            gone.push(model.remove(&oldest).unwrap().0);
                            evictions += 1;
                        }
                        out.sort_unstable();
                        gone.sort_unstable();
                        prop_assert_eq!(out, gone);
                    }
                    Op::Get(k) => {
                        let got = c.get(&k).copied();
                        prop_assert_eq!(got, model.get(&k).map(|e| e.0));
                        if let Some(e) = model.get_mut(&k) {
                            tick += 1;
                            e.2 = tick;
                        }
                    }
                    Op::Peek(k) => prop_assert_eq!(c.peek(&k).copied(), model.get(&k).map(|e| e.0)),
                    Op::Remove(k) => {
                        prop_assert_eq!(c.remove(&k), model.remove(&k).map(|e| e.0));
                    }
                }
                let mut held: Vec<u8> = (0..12).filter(|k| c.contains(k)).collect();
                let mut want: Vec<u8> = model.keys().copied().collect();
                held.sort_unstable();
                want.sort_unstable();
                prop_assert_eq!(held, want);
                prop_assert_eq!(c.bytes(), model.values().map(|e| e.1).sum::<usize>());
                prop_assert_eq!(c.evictions(), evictions);
                prop_assert!(c.order.len() <= 2 * c.len() + 17);
            }
        });
    }
}
