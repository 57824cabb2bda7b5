//! The records a remote reader keeps between reads: a record fetched for one read is not
//! fetched again by a later read that needs it, while the records held stay within a byte
//! budget (least recently used dropped first). Tested by pytest (`tests/test_cache.py`): the
//! extension module links against the interpreter, so it has no Rust test binary.

use std::collections::HashMap;
use std::sync::Arc;

use cbdam_codec::geometry::DiamondId;

/// Records by diamond, at most `limit` bytes of them.
#[derive(Debug, Default)]
pub struct RecordCache {
    /// Each record and the read that last used it.
    records: HashMap<DiamondId, (Arc<[u8]>, u64)>,
    /// Bytes held (the records' lengths).
    bytes: usize,
    /// The budget; 0 keeps nothing.
    limit: usize,
    /// Reads so far: the clock of "least recently used".
    reads: u64,
    /// Records a read found here, and records it had to fetch, since the reader opened.
    hits: u64,
    misses: u64,
}

/// What `cache_info` reports.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CacheInfo {
    /// Records held.
    pub records: usize,
    /// Bytes held.
    pub bytes: usize,
    /// The budget, bytes.
    pub limit: usize,
    /// Records reads found held.
    pub hits: u64,
    /// Records reads fetched.
    pub misses: u64,
}

impl RecordCache {
    /// An empty cache holding at most `limit` bytes of records.
    pub fn new(limit: usize) -> RecordCache {
        RecordCache {
            limit,
            ..RecordCache::default()
        }
    }

    /// Starts a read of `needed`: the records held (marked used by this read) and the ids
    /// still to fetch, in `needed`'s order.
    pub fn take(
        &mut self,
        needed: &[DiamondId],
    ) -> (HashMap<DiamondId, Arc<[u8]>>, Vec<DiamondId>) {
        self.reads += 1;
        let mut held = HashMap::with_capacity(needed.len());
        let mut missing = Vec::new();
        for &id in needed {
            match self.records.get_mut(&id) {
                Some((bytes, used)) => {
                    *used = self.reads;
                    held.insert(id, bytes.clone());
                }
                None => missing.push(id),
            }
        }
        self.hits += held.len() as u64;
        self.misses += missing.len() as u64;
        (held, missing)
    }

    /// Keeps the records a read fetched, then drops the least recently used until the cache is
    /// within its budget (a record larger than the whole budget is not kept).
    pub fn keep(&mut self, fetched: &HashMap<DiamondId, Arc<[u8]>>) {
        if self.limit == 0 {
            return;
        }
        for (&id, bytes) in fetched {
            if bytes.len() > self.limit {
                continue;
            }
            if let Some((old, _)) = self.records.insert(id, (bytes.clone(), self.reads)) {
                self.bytes -= old.len();
            }
            self.bytes += bytes.len();
        }
        if self.bytes <= self.limit {
            return;
        }
        let mut by_age: Vec<(u64, DiamondId)> = self
            .records
            .iter()
            .map(|(&id, &(_, used))| (used, id))
            .collect();
        by_age.sort_unstable();
        for (_, id) in by_age {
            if self.bytes <= self.limit {
                break;
            }
            if let Some((old, _)) = self.records.remove(&id) {
                self.bytes -= old.len();
            }
        }
    }

    /// What it holds and how it has done.
    pub fn info(&self) -> CacheInfo {
        CacheInfo {
            records: self.records.len(),
            bytes: self.bytes,
            limit: self.limit,
            hits: self.hits,
            misses: self.misses,
        }
    }
}
