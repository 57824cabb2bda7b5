//! Records read where they are decoded: a handle on a record of a memory-mapped repository,
//! which the refiner hands to a worker instead of the record's bytes.
//!
//! Taking a record ([`DataSource::take`](super::DataSource::take)) copies it into the caller's
//! RAM and checks its CRC on the caller's thread, which for the refiner is the frame thread,
//! once for every diamond it decodes (ahead of the cut too). A mapped record is read and
//! checked by the worker that decodes it, from the map, without a copy.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use cbdam_codec::CodecError;
use cbdam_codec::repository::Repository;

/// Record `index` of a mapped repository, not yet read. Cheap to make and to send: the
/// repository is shared.
#[derive(Clone, Debug)]
pub struct MappedRecord {
    repo: Arc<Repository>,
    index: usize,
    reads: Arc<MappedReads>,
}

impl MappedRecord {
    /// Made only by the desktop's [`LocalSource`](super::LocalSource): a browser maps no file.
    #[cfg(not(target_arch = "wasm32"))]
    pub(super) fn new(repo: Arc<Repository>, index: usize, reads: Arc<MappedReads>) -> Self {
        Self { repo, index, reads }
    }

    /// The record's bytes, checked against its CRC; counted in its source's
    /// [`AccessStats`](super::AccessStats) as a record taken (or an error).
    pub fn bytes(&self) -> Result<&[u8], CodecError> {
        let read = self.repo.record_at(self.index);
        match &read {
            Ok(bytes) => {
                self.reads.records.fetch_add(1, Ordering::Relaxed);
                self.reads
                    .bytes
                    .fetch_add(bytes.len() as u64, Ordering::Relaxed);
            }
            Err(_) => {
                self.reads.errors.fetch_add(1, Ordering::Relaxed);
            }
        }
        read
    }
}

/// What a source's mapped records counted when they were read (on any thread).
#[derive(Debug, Default)]
pub(super) struct MappedReads {
    records: AtomicU64,
    bytes: AtomicU64,
    errors: AtomicU64,
}

impl MappedReads {
    /// `stats` with these reads added.
    #[cfg(not(target_arch = "wasm32"))]
    pub(super) fn add_to(&self, stats: super::AccessStats) -> super::AccessStats {
        super::AccessStats {
            records_taken: stats.records_taken + self.records.load(Ordering::Relaxed),
            bytes_fetched: stats.bytes_fetched + self.bytes.load(Ordering::Relaxed),
            errors: stats.errors + self.errors.load(Ordering::Relaxed),
            ..stats
        }
    }
}
