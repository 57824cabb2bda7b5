//! A test double for remote sources: records arrive frames after they are requested, a limited
//! number per frame, most urgent first, and some arrive corrupt or never. Deterministic (no
//! clock, no randomness beyond a hash of the diamond and attempt), so tests that use it are
//! reproducible.

use std::collections::{HashMap, HashSet};
use std::sync::Arc;

use cbdam_codec::CodecError;
use cbdam_codec::geometry::DiamondId;
use cbdam_codec::repository::Repository;
use cbdam_codec::repository::RepositoryHead;

use super::{AccessError, AccessStats, DataSource, Priority};

/// How badly a [`FlakySource`] behaves.
#[derive(Clone, Debug, Default)]
pub struct FlakyConfig {
    /// A request completes between `latency.0` and `latency.1` pumps (frames) after it is
    /// posted, inclusive.
    pub latency: (u32, u32),
    /// At most this many completions per pump, highest priority first (0: unlimited).
    pub per_frame: usize,
    /// About one first attempt in this many arrives with a flipped byte, which validation
    /// rejects (0: none). Later attempts of the same diamond arrive intact.
    pub corrupt_one_in: u32,
    /// These diamonds fail with a transport error on every attempt.
    pub always_fail: HashSet<DiamondId>,
}

#[derive(Clone, Copy, Debug)]
struct Pending {
    due: u64,
    attempt: u32,
    priority: Priority,
}

/// A source over a repository in memory that behaves like a slow, unreliable network.
#[derive(Debug)]
pub struct FlakySource {
    repo: Arc<Repository>,
    config: FlakyConfig,
    frame: u64,
    pending: HashMap<DiamondId, Pending>,
    arrived: HashMap<DiamondId, Result<Vec<u8>, AccessError>>,
    attempts: HashMap<DiamondId, u32>,
    stats: AccessStats,
    /// Ids whose bytes were delivered corrupt (for tests to check they were rejected).
    corrupted: Vec<DiamondId>,
}

/// SplitMix64 finaliser: a well-mixed hash of one word.
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

fn hash(id: DiamondId, attempt: u32, salt: u64) -> u64 {
    mix(u64::from(id.level)
        ^ mix(u64::from(id.x) << 32 | u64::from(id.y))
        ^ mix(u64::from(attempt) ^ salt))
}

impl FlakySource {
    /// A flaky source over `repo`.
    pub fn new(repo: Arc<Repository>, config: FlakyConfig) -> Self {
        Self {
            repo,
            config,
            frame: 0,
            pending: HashMap::new(),
            arrived: HashMap::new(),
            attempts: HashMap::new(),
            stats: AccessStats::default(),
            corrupted: Vec::new(),
        }
    }

    /// Diamonds whose records were delivered corrupt so far.
    pub fn corrupted(&self) -> &[DiamondId] {
        &self.corrupted
    }

    /// Requests posted and not yet arrived.
    pub fn pending(&self) -> usize {
        self.pending.len()
    }

    fn deliver(&mut self, id: DiamondId, attempt: u32) -> Result<Vec<u8>, AccessError> {
        if self.config.always_fail.contains(&id) {
            return Err(AccessError::Transport {
                id,
                message: "simulated transport failure".into(),
            });
        }
        let record = self
            .repo
            .record(id)
            .map_err(|source| AccessError::Record { id, source })?;
        let mut bytes = record.to_vec();
        let n = u64::from(self.config.corrupt_one_in);
        if n > 0 && attempt == 0 && !bytes.is_empty() && hash(id, 0, 0x00c0_ffee).is_multiple_of(n)
        {
            let at = (hash(id, 1, 7) % bytes.len() as u64) as usize;
            bytes[at] ^= 0x5a;
            self.corrupted.push(id);
        }
        // Validation as a remote source does it: against the head's checksum. Here the true
        // record stands in for the checksum.
        if bytes != record {
            return Err(AccessError::Record {
                id,
                source: CodecError::corrupt("checksum mismatch (simulated corruption)"),
            });
        }
        Ok(bytes)
    }
}

impl DataSource for FlakySource {
    fn head(&self) -> &RepositoryHead {
        self.repo.head()
    }

    fn request(&mut self, id: DiamondId, priority: Priority) {
        if self.arrived.contains_key(&id) {
            return;
        }
        if let Some(p) = self.pending.get_mut(&id) {
            p.priority = priority;
            return;
        }
        let attempt = *self.attempts.entry(id).and_modify(|a| *a += 1).or_insert(0);
        let (lo, hi) = self.config.latency;
        let span = u64::from(hi.saturating_sub(lo)) + 1;
        let due = self.frame + u64::from(lo) + hash(id, attempt, 0x1a7e) % span;
        self.pending.insert(
            id,
            Pending {
                due,
                attempt,
                priority,
            },
        );
        self.stats.requests_issued += 1;
        self.stats.in_flight += 1;
    }

    fn cancel(&mut self, id: DiamondId) {
        if self.pending.remove(&id).is_some() || self.arrived.remove(&id).is_some() {
            self.stats.requests_cancelled += 1;
            self.stats.in_flight -= 1;
        }
    }

    fn is_available(&self, id: DiamondId) -> bool {
        self.arrived.contains_key(&id)
    }

    fn take(&mut self, id: DiamondId) -> Option<Result<Vec<u8>, AccessError>> {
        let r = self.arrived.remove(&id)?;
        self.stats.in_flight -= 1;
        match &r {
            Ok(bytes) => {
                self.stats.records_taken += 1;
                self.stats.bytes_fetched += bytes.len() as u64;
            }
            Err(_) => self.stats.errors += 1,
        }
        Some(r)
    }

    fn pump(&mut self) {
        self.frame += 1;
        let mut due: Vec<(DiamondId, Pending)> = self
            .pending
            .iter()
            .filter(|(_, p)| p.due <= self.frame)
            .map(|(&id, &p)| (id, p))
            .collect();
        due.sort_by(|a, b| b.1.priority.total_cmp(&a.1.priority).then(a.0.cmp(&b.0)));
        if self.config.per_frame > 0 {
            due.truncate(self.config.per_frame);
        }
        for (id, p) in due {
            self.pending.remove(&id);
            let r = self.deliver(id, p.attempt);
            self.arrived.insert(id, r);
        }
    }

    fn stats(&self) -> AccessStats {
        self.stats
    }
}
