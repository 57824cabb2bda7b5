//! A least-recently-used map bounded by the bytes of its values.

use std::collections::{BTreeMap, HashMap};
use std::hash::Hash;

use cbdam_codec::geometry::IdBuildHasher;

/// An LRU map that evicts the least recently used entries once the sum of their declared sizes
/// exceeds a byte budget.
#[derive(Debug)]
pub struct LruCache<K, V> {
    /// Keyed by diamond ids in the refiner: the fast hasher, not SipHash (see `IdBuildHasher`).
    map: HashMap<K, (V, usize, u64), IdBuildHasher>,
    order: BTreeMap<u64, K>,
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
            order: BTreeMap::new(),
            tick: 0,
            bytes: 0,
            budget,
            evictions: 0,
        }
    }

    /// Inserts or replaces `key`, marks it most recent and evicts down to the budget. A value
    /// larger than the whole budget is not kept.
    pub fn insert(&mut self, key: K, value: V, bytes: usize) {
        self.remove(&key);
        self.tick += 1;
        self.map.insert(key, (value, bytes, self.tick));
        self.order.insert(self.tick, key);
        self.bytes += bytes;
        while self.bytes > self.budget {
            let Some((_, k)) = self.order.pop_first() else {
                break;
            };
            if let Some((_, b, _)) = self.map.remove(&k) {
                self.bytes -= b;
                self.evictions += 1;
            }
        }
    }

    /// The value of `key`, marked most recent.
    pub fn get(&mut self, key: &K) -> Option<&V> {
        let (_, _, t) = self.map.get(key)?;
        let old = *t;
        self.tick += 1;
        self.order.remove(&old);
        self.order.insert(self.tick, *key);
        let e = self.map.get_mut(key).expect("present");
        e.2 = self.tick;
        Some(&e.0)
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
        let (v, b, t) = self.map.remove(key)?;
        self.order.remove(&t);
        self.bytes -= b;
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
}
