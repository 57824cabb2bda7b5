//! A map shared between threads that holds at most a given number of bytes of values, the
//! oldest insertions dropped first: the tiler's caches of work shared between tiles.

use std::collections::{HashMap, VecDeque};
use std::hash::Hash;
use std::sync::{Arc, Mutex, MutexGuard};

/// Values by key, within `limit` bytes (as each insertion states them).
#[derive(Debug)]
pub struct Bounded<K, V> {
    inner: Mutex<Inner<K, V>>,
    limit: usize,
}

#[derive(Debug)]
struct Inner<K, V> {
    map: HashMap<K, (Arc<V>, usize)>,
    order: VecDeque<K>,
    bytes: usize,
}

impl<K: Hash + Eq + Clone, V> Bounded<K, V> {
    /// An empty map holding at most `limit` bytes.
    pub fn new(limit: usize) -> Self {
        Bounded {
            inner: Mutex::new(Inner {
                map: HashMap::new(),
                order: VecDeque::new(),
                bytes: 0,
            }),
            limit,
        }
    }

    fn lock(&self) -> MutexGuard<'_, Inner<K, V>> {
        // A panic elsewhere while holding it leaves a consistent map: every change is whole.
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The value of `key`, if held.
    pub fn get(&self, key: &K) -> Option<Arc<V>> {
        self.lock().map.get(key).map(|v| Arc::clone(&v.0))
    }

    /// The value of `key`, made by `make` (outside the lock: two threads may both make it,
    /// the first one kept) and held when its `bytes` fit the limit.
    pub fn get_or_make(&self, key: K, bytes: usize, make: impl FnOnce() -> V) -> Arc<V> {
        if let Some(v) = self.get(&key) {
            return v;
        }
        let made = Arc::new(make());
        self.insert(key, made, bytes)
    }

    /// Holds `value` under `key` (unless one is already there: that one is returned), dropping
    /// the oldest values until the bytes fit the limit; a value larger than the limit is
    /// returned without being held.
    pub fn insert(&self, key: K, value: Arc<V>, bytes: usize) -> Arc<V> {
        if bytes > self.limit {
            return value;
        }
        let mut inner = self.lock();
        if let Some(v) = inner.map.get(&key) {
            return Arc::clone(&v.0);
        }
        while inner.bytes + bytes > self.limit {
            let Some(old) = inner.order.pop_front() else {
                break;
            };
            if let Some((_, b)) = inner.map.remove(&old) {
                inner.bytes -= b;
            }
        }
        inner.bytes += bytes;
        inner.order.push_back(key.clone());
        inner.map.insert(key, (Arc::clone(&value), bytes));
        value
    }

    /// Drops every value.
    pub fn clear(&self) {
        let mut inner = self.lock();
        inner.map.clear();
        inner.order.clear();
        inner.bytes = 0;
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        self.lock().bytes
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_oldest_values_go_first_and_the_bytes_stay_within_the_limit() {
        let map: Bounded<u32, u32> = Bounded::new(10);
        for k in 0..5 {
            map.insert(k, Arc::new(k * 10), 3);
            assert!(map.bytes() <= 10, "{} bytes held after {k}", map.bytes());
        }
        // 3 values of 3 bytes fit: 2, 3 and 4 are held, 0 and 1 went first.
        assert_eq!(map.get(&0), None);
        assert_eq!(map.get(&1), None);
        assert_eq!(map.get(&2).as_deref(), Some(&20));
        assert_eq!(map.get(&4).as_deref(), Some(&40));
        assert_eq!(map.bytes(), 9);
    }

    #[test]
    fn a_held_value_is_kept_and_one_over_the_limit_is_not_held() {
        let map: Bounded<u32, u32> = Bounded::new(10);
        assert_eq!(*map.get_or_make(1, 4, || 7), 7);
        assert_eq!(*map.get_or_make(1, 4, || 8), 7, "the first value is kept");
        assert_eq!(*map.get_or_make(2, 11, || 9), 9);
        assert_eq!(map.get(&2), None, "over the limit: returned, not held");
        map.clear();
        assert_eq!((map.get(&1), map.bytes()), (None, 0));
    }
}
