//! Records over HTTP: the [`DataSource`] face of [`crate::fetch::RemoteFetcher`].
//!
//! The fetcher keeps the network side (batching, priorities, bounded in-flight requests,
//! cancellation, retries with backoff, checksum checks); this adapter turns the loop's per-diamond
//! `request` / `cancel` / `take` calls into the fetcher's per-frame "wanted set" and collects
//! what arrived on `pump`. Transport failures and rejected records are retried by the fetcher
//! itself (a server that restarts is survived without the loop noticing), so they show up in
//! [`AccessStats::errors`] rather than as failed `take`s; only requests for diamonds the head
//! says are not stored fail, at once.

use std::collections::HashMap;
use std::sync::Arc;

use cbdam_codec::CodecError;
use cbdam_codec::geometry::DiamondId;
use cbdam_codec::repository::RepositoryHead;

use super::{AccessError, AccessStats, DataSource, Priority};
use crate::fetch::{FetchOptions, FetchStats, RemoteError, RemoteFetcher};

/// A repository behind `cbdam serve` or any static server that honours range requests.
#[derive(Debug)]
pub struct RemoteSource {
    fetcher: RemoteFetcher,
    wanted: HashMap<DiamondId, Priority>,
    wanted_changed: bool,
    arrived: HashMap<DiamondId, Result<Arc<[u8]>, AccessError>>,
    /// Records that arrived after their request was cancelled: paid for, so kept (up to
    /// [`SPARE_RECORDS`]) in case the loop asks again — a camera that hesitates would otherwise
    /// fetch the same records over and over.
    spare: HashMap<DiamondId, Arc<[u8]>>,
    stats: AccessStats,
    /// Every record received, with the number of the [`DataSource::pump`] call that collected
    /// it (from 1; a refiner pumps once per frame) and whether it was still wanted then — kept
    /// only after [`RemoteSource::log_received`] (benchmarks): a viewer running for hours
    /// would otherwise grow it without bound.
    received: Vec<Received>,
    log_received: bool,
    pumps: u64,
}

/// A record [`RemoteSource`] received.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Received {
    /// The record.
    pub id: DiamondId,
    /// The number of the [`DataSource::pump`] call that collected it, from 1: with a refiner,
    /// the frame.
    pub pump: u64,
    /// Whether it was still requested when it came (otherwise its request had been cancelled,
    /// and it was kept as a spare).
    pub wanted: bool,
}

/// Most spare records kept.
const SPARE_RECORDS: usize = 4096;

impl RemoteSource {
    /// Connects and fetches the repository head (blocks until it has it or fails). `url` as in
    /// [`RemoteFetcher::connect`].
    #[cfg(not(target_arch = "wasm32"))]
    pub fn connect(url: &str, options: FetchOptions) -> Result<Self, RemoteError> {
        Ok(Self::from_fetcher(RemoteFetcher::connect(url, options)?))
    }

    /// Connects and fetches the repository head (the browser cannot block: awaited before the
    /// first frame). `url` as in [`RemoteFetcher::connect`].
    #[cfg(target_arch = "wasm32")]
    pub async fn connect(url: &str, options: FetchOptions) -> Result<Self, RemoteError> {
        Ok(Self::from_fetcher(
            RemoteFetcher::connect(url, options).await?,
        ))
    }

    fn from_fetcher(fetcher: RemoteFetcher) -> Self {
        Self {
            fetcher,
            wanted: HashMap::new(),
            wanted_changed: false,
            arrived: HashMap::new(),
            spare: HashMap::new(),
            stats: AccessStats::default(),
            received: Vec::new(),
            log_received: false,
            pumps: 0,
        }
    }

    /// The bytes the repository's head was read from, with the file's length: what a decode
    /// worker builds its decoder from ([`crate::refine::Refiner::worker_context`]).
    #[cfg(target_arch = "wasm32")]
    pub fn head_bytes(&self) -> crate::refine::HeadBytes<'_> {
        crate::refine::HeadBytes {
            bytes: self.fetcher.head_bytes(),
            file_len: self.fetcher.head().file_len(),
        }
    }

    /// Keeps a log of every record received from now on ([`RemoteSource::received`]).
    pub fn log_received(&mut self) {
        self.log_received = true;
    }

    /// Every record received since [`RemoteSource::log_received`], in order (empty without it).
    pub fn received(&self) -> &[Received] {
        &self.received
    }

    /// The fetcher's own counters: HTTP requests sent (the head's included), cancelled and
    /// failed ones, response body bytes.
    pub fn fetch_stats(&self) -> FetchStats {
        self.fetcher.stats()
    }
}

impl DataSource for RemoteSource {
    fn head(&self) -> &RepositoryHead {
        self.fetcher.head()
    }

    fn request(&mut self, id: DiamondId, priority: Priority) {
        if self.arrived.contains_key(&id) {
            return;
        }
        if let Some(bytes) = self.spare.remove(&id) {
            self.stats.requests_issued += 1;
            self.arrived.insert(id, Ok(bytes));
            return;
        }
        if self.fetcher.head().position(id).is_none() {
            self.stats.requests_issued += 1;
            let source = CodecError::invalid(format!("{id} is not stored in this repository"));
            self.arrived
                .insert(id, Err(AccessError::Record { id, source }));
            return;
        }
        match self.wanted.insert(id, priority) {
            None => {
                self.stats.requests_issued += 1;
                self.wanted_changed = true;
            }
            Some(old) if old != priority => self.wanted_changed = true,
            Some(_) => {}
        }
    }

    fn cancel(&mut self, id: DiamondId) {
        if self.wanted.remove(&id).is_some() {
            self.stats.requests_cancelled += 1;
            self.wanted_changed = true;
        }
        self.arrived.remove(&id);
    }

    fn is_available(&self, id: DiamondId) -> bool {
        self.arrived.contains_key(&id)
    }

    fn take(&mut self, id: DiamondId) -> Option<Result<Vec<u8>, AccessError>> {
        let r = self.arrived.remove(&id)?;
        match &r {
            Ok(_) => self.stats.records_taken += 1,
            Err(_) => self.stats.errors += 1,
        }
        Some(r.map(|b| b.to_vec()))
    }

    fn pump(&mut self) {
        if self.wanted_changed {
            self.fetcher
                .want(self.wanted.iter().map(|(&id, &p)| (id, p)));
            self.wanted_changed = false;
        }
        self.pumps += 1;
        for (id, result) in self.fetcher.poll() {
            if self.log_received && result.is_ok() {
                self.received.push(Received {
                    id,
                    pump: self.pumps,
                    wanted: self.wanted.contains_key(&id),
                });
            }
            if self.wanted.remove(&id).is_none() {
                if let Ok(bytes) = result
                    && self.spare.len() < SPARE_RECORDS
                {
                    self.spare.insert(id, bytes);
                }
                continue;
            }
            let r = result.map_err(|source| AccessError::Record { id, source });
            self.arrived.insert(id, r);
        }
    }

    fn stats(&self) -> AccessStats {
        let f = self.fetcher.stats();
        AccessStats {
            in_flight: self.wanted.len() as u64,
            bytes_fetched: f.bytes,
            errors: self.stats.errors + f.errors,
            ..self.stats
        }
    }
}
