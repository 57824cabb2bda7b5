//! Records from a memory-mapped repository file.

use std::path::Path;
use std::sync::Arc;

use cbdam_codec::CodecError;
use cbdam_codec::geometry::DiamondId;
use cbdam_codec::repository::Repository;
use cbdam_codec::repository::RepositoryHead;

use super::mapped::MappedReads;
use super::{AccessError, AccessStats, DataSource, MappedRecord, Priority};

/// A local repository. Every stored record is "immediately available" in the paper's sense: it
/// is mapped, so [`DataSource::take`] only copies and CRC-checks it, [`DataSource::mapped`]
/// hands out a handle that a worker reads and checks, and the loop never needs to request
/// anything. Requests are still accepted (and complete at once) so that code written for
/// remote sources runs unchanged.
#[derive(Debug)]
pub struct LocalSource {
    repo: Arc<Repository>,
    stats: AccessStats,
    /// What the handed-out mapped records counted when read.
    reads: Arc<MappedReads>,
}

impl LocalSource {
    /// Opens (maps and validates) the repository at `path`.
    pub fn open(path: &Path) -> Result<Self, CodecError> {
        Ok(Self::new(Arc::new(Repository::open(path)?)))
    }

    /// A source over an already opened repository.
    pub fn new(repo: Arc<Repository>) -> Self {
        Self {
            repo,
            stats: AccessStats::default(),
            reads: Arc::default(),
        }
    }

    /// The repository.
    pub fn repository(&self) -> &Arc<Repository> {
        &self.repo
    }
}

impl DataSource for LocalSource {
    fn head(&self) -> &RepositoryHead {
        self.repo.head()
    }

    fn request(&mut self, _id: DiamondId, _priority: Priority) {
        // Completes immediately: the record is already mapped. Unstored ids fail on `take`.
        self.stats.requests_issued += 1;
    }

    fn cancel(&mut self, _id: DiamondId) {}

    fn is_available(&self, _id: DiamondId) -> bool {
        // Even unstored ids: `take` answers them at once with an error.
        true
    }

    fn always_available(&self) -> bool {
        true
    }

    fn take(&mut self, id: DiamondId) -> Option<Result<Vec<u8>, AccessError>> {
        // One search of the index (a take per diamond the refiner decodes, on its frame thread).
        let result = match self.repo.head().position(id) {
            Some(i) => self.repo.record_at(i).map(<[u8]>::to_vec),
            None => Err(CodecError::invalid(format!("diamond {id} is not stored"))),
        };
        Some(match result {
            Ok(bytes) => {
                self.stats.records_taken += 1;
                self.stats.bytes_fetched += bytes.len() as u64;
                Ok(bytes)
            }
            Err(source) => {
                self.stats.errors += 1;
                Err(AccessError::Record { id, source })
            }
        })
    }

    fn mapped(&self, id: DiamondId) -> Option<MappedRecord> {
        let i = self.repo.head().position(id)?;
        Some(MappedRecord::new(self.repo.clone(), i, self.reads.clone()))
    }

    fn mapped_entry(&self, id: DiamondId, index: usize) -> Option<MappedRecord> {
        if self
            .repo
            .head()
            .entries()
            .get(index)
            .is_some_and(|e| e.id == id)
        {
            Some(MappedRecord::new(
                self.repo.clone(),
                index,
                self.reads.clone(),
            ))
        } else {
            self.mapped(id)
        }
    }

    fn pump(&mut self) {}

    fn stats(&self) -> AccessStats {
        self.reads.add_to(self.stats)
    }
}
