#![cfg_attr(target_arch = "wasm32", allow(dead_code))]
// No wasm32 transport is written yet: there the portable policy below has no caller.
//! Fetching records over HTTP: from `cbdam serve` (batched `POST …/diamonds`) or from any static
//! server holding the repository file (HTTP range requests).
//!
//! The frame loop never waits on the network. Each frame it hands the fetcher the set of records
//! it wants with their priorities ([`RemoteFetcher::want`]) and collects whatever arrived
//! ([`RemoteFetcher::poll`]). A background tokio runtime sends the most urgent wanted records
//! first, a batch per request, with a bounded number of requests in flight; records no longer
//! wanted are dropped from the queue and requests whose records are all unwanted are aborted;
//! failures (refused connections, time-outs, HTTP errors, records failing their checksum) are
//! retried with exponential backoff, so a server that goes away and comes back is survived.
//! Every record is checked against the repository head's checksum before it is handed over.
//!
//! This module is portable (it builds for wasm32): the endpoint, the scheduling policy (which
//! wanted records go into the next request), the backoff and the batch parsing. The desktop's
//! transport ([`RemoteFetcher`]: tokio and reqwest) is in `native`, compiled for native targets
//! only.

use std::collections::{HashMap, HashSet, VecDeque};
use std::time::Duration;

use cbdam_codec::CodecError;
use cbdam_codec::geometry::DiamondId;
use cbdam_codec::repository::RepositoryHead;
use cbdam_codec::repository::batch::{self, Entry};
use std::sync::Arc;
use web_time::Instant;

#[cfg(not(target_arch = "wasm32"))]
mod native;
#[cfg(not(target_arch = "wasm32"))]
pub use native::RemoteFetcher;

/// Tuning of the fetcher; every limit is explicit.
#[derive(Clone, Debug)]
pub struct FetchOptions {
    /// Most records asked for in one request.
    pub max_batch: usize,
    /// Most requests in flight at once.
    pub max_in_flight: usize,
    /// Time-out of one request.
    pub timeout: Duration,
    /// First retry delay; doubled per failure of the same record, up to `max_backoff`.
    pub initial_backoff: Duration,
    /// Longest retry delay.
    pub max_backoff: Duration,
    /// Range requests to a static server merge records separated by at most this many bytes.
    /// 0 (the default) merges only records that touch: a gap's bytes may belong to records
    /// another request is fetching, and measured on loopback that doubled the bytes fetched.
    pub max_range_gap: u64,
}

impl Default for FetchOptions {
    fn default() -> Self {
        Self {
            max_batch: 64,
            max_in_flight: 8,
            timeout: Duration::from_secs(5),
            initial_backoff: Duration::from_millis(50),
            max_backoff: Duration::from_secs(2),
            max_range_gap: 0,
        }
    }
}

/// Counters of the fetcher's work, cumulative.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FetchStats {
    /// HTTP requests sent: the head's range requests and every batch or range request (a batch
    /// of empty records only needs none). A bare server address's repository list is not
    /// counted.
    pub requests: u64,
    /// Requests in flight now.
    pub in_flight: u64,
    /// Response body bytes received.
    pub bytes: u64,
    /// Records handed over, checked.
    pub records: u64,
    /// Failed requests and rejected records (each retried later).
    pub errors: u64,
    /// Requests aborted because none of their records was wanted any more.
    pub cancelled: u64,
}

/// Where the records come from.
#[derive(Clone, Debug, PartialEq, Eq)]
enum Endpoint {
    /// `cbdam serve`: `base` is `…/v1/repos/{name}`.
    Server { base: String },
    /// Any server of the repository file that honours `Range`.
    File { url: String },
}

impl Endpoint {
    fn file_url(&self) -> String {
        match self {
            Endpoint::Server { base } => format!("{base}/file"),
            Endpoint::File { url } => url.clone(),
        }
    }
}

/// Why connecting failed.
#[derive(Debug, thiserror::Error)]
pub enum RemoteError {
    /// The network or the server failed.
    #[error("{url}: {message}")]
    Http {
        /// What was being fetched.
        url: String,
        /// What went wrong.
        message: String,
    },
    /// The repository bytes are invalid.
    #[error("{url}: {source}")]
    Repository {
        /// Where they came from.
        url: String,
        /// The codec's complaint.
        source: CodecError,
    },
    /// The URL does not name one repository.
    #[error("{0}")]
    Url(String),
}

/// A record that arrived, or a record that could not be had.
pub type Fetched = (DiamondId, Result<Arc<[u8]>, CodecError>);

struct Pending {
    priority: f32,
}

/// The scheduler's bookkeeping; `H` is the transport's handle for aborting a request.
struct State<H> {
    wanted: HashMap<DiamondId, Pending>,
    in_flight: HashSet<DiamondId>,
    /// Per record: failures so far and the time before which it is not retried.
    backoff: HashMap<DiamondId, (u32, Instant)>,
    batches: Vec<(u64, Vec<DiamondId>, H)>,
    /// Records sent to the frame loop but not yet polled: a `want` racing with their delivery
    /// must not fetch them again.
    delivered: HashSet<DiamondId>,
    next_batch: u64,
    shutdown: bool,
}

impl<H> Default for State<H> {
    fn default() -> Self {
        Self {
            wanted: HashMap::new(),
            in_flight: HashSet::new(),
            backoff: HashMap::new(),
            batches: Vec::new(),
            delivered: HashSet::new(),
            next_batch: 0,
            shutdown: false,
        }
    }
}

impl<H> State<H> {
    /// The wanted records neither in flight nor backing off, most urgent first, and the earliest
    /// backoff expiry among the others.
    fn ready(&self, now: Instant) -> (VecDeque<DiamondId>, Option<Instant>) {
        let mut next_retry: Option<Instant> = None;
        let mut ready: Vec<(DiamondId, f32)> = Vec::new();
        for (&id, p) in &self.wanted {
            if self.in_flight.contains(&id) {
                continue;
            }
            if let Some(&(_, until)) = self.backoff.get(&id)
                && until > now
            {
                next_retry = Some(next_retry.map_or(until, |t| t.min(until)));
                continue;
            }
            ready.push((id, p.priority));
        }
        ready.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        (ready.into_iter().map(|(id, _)| id).collect(), next_retry)
    }

    /// Puts `failed` records into backoff: each retry waits twice as long as the last, from
    /// [`FetchOptions::initial_backoff`] up to [`FetchOptions::max_backoff`].
    fn back_off(&mut self, failed: Vec<DiamondId>, now: Instant, options: &FetchOptions) {
        for id in failed {
            let attempts = self.backoff.get(&id).map_or(0, |b| b.0) + 1;
            let delay = options
                .initial_backoff
                .saturating_mul(1 << attempts.min(16))
                .min(options.max_backoff);
            self.backoff.insert(id, (attempts, now + delay));
        }
    }
}

/// Takes the next request's records off the front of `ready` (most urgent first): up to
/// [`FetchOptions::max_batch`] for a server; for a static file, the most urgent record and those
/// of the next few that lie near it (one range request covers them), the rest staying queued in
/// order.
fn next_batch(
    ready: &mut VecDeque<DiamondId>,
    endpoint: &Endpoint,
    head: &RepositoryHead,
    options: &FetchOptions,
) -> Vec<DiamondId> {
    match endpoint {
        Endpoint::Server { .. } => {
            let n = ready.len().min(options.max_batch);
            ready.drain(..n).collect()
        }
        Endpoint::File { .. } => {
            let first = ready.pop_front().expect("not empty");
            let r0 = record_range(head, first);
            let (mut lo, mut hi) = (r0.start, r0.end);
            let gap = options.max_range_gap;
            let mut ids = vec![first];
            let mut kept = VecDeque::with_capacity(ready.len());
            for (scanned, id) in ready.drain(..).enumerate() {
                let r = record_range(head, id);
                if scanned < 4 * options.max_batch
                    && ids.len() < options.max_batch
                    && r.start <= hi + gap
                    && r.end + gap >= lo
                {
                    lo = lo.min(r.start);
                    hi = hi.max(r.end);
                    ids.push(id);
                } else {
                    kept.push_back(id);
                }
            }
            *ready = kept;
            ids
        }
    }
}

fn record_range(head: &RepositoryHead, id: DiamondId) -> std::ops::Range<u64> {
    let i = head.position(id).expect("only stored records are wanted");
    head.record_range(i).expect("position is in range")
}

/// What kind of URL this is, when the URL alone tells: `None` for a bare server address, whose
/// repository list must be fetched ([`single_repository`]). `cbdam serve`'s raw file route
/// (`…/v1/repos/NAME/file`) is a file like any other: read with range requests, no batches.
fn classify(url: &str) -> Result<Option<Endpoint>, RemoteError> {
    let trimmed = url.trim_end_matches('/');
    if !(trimmed.starts_with("http://") || trimmed.starts_with("https://")) {
        return Err(RemoteError::Url(format!("{url} is not an http:// URL")));
    }
    let serve_file = trimmed
        .split_once("/v1/repos/")
        .and_then(|(_, rest)| rest.strip_suffix("/file"))
        .is_some_and(|name| !name.is_empty() && !name.contains('/'));
    if serve_file {
        return Ok(Some(Endpoint::File {
            url: trimmed.to_owned(),
        }));
    }
    if trimmed.contains("/v1/repos/") {
        return Ok(Some(Endpoint::Server {
            base: trimmed.to_owned(),
        }));
    }
    let after_scheme = trimmed.split_once("://").map_or("", |(_, rest)| rest);
    if after_scheme.contains('/') {
        return Ok(Some(Endpoint::File {
            url: trimmed.to_owned(),
        }));
    }
    Ok(None)
}

/// The repository list of a bare server address: the address's `/v1/repos`.
fn list_url(url: &str) -> String {
    format!("{}/v1/repos", url.trim_end_matches('/'))
}

/// The endpoint of a bare server address `url` given its repository list (`body`, JSON): its
/// repository if it serves exactly one.
fn single_repository(url: &str, body: &[u8]) -> Result<Endpoint, RemoteError> {
    let trimmed = url.trim_end_matches('/');
    let list = list_url(url);
    let json: serde_json::Value =
        serde_json::from_slice(body).map_err(|e| http_error(&list, format!("not JSON: {e}")))?;
    let names: Vec<String> = json["repos"]
        .as_array()
        .map(|a| {
            a.iter()
                .filter_map(|r| r["name"].as_str().map(str::to_owned))
                .collect()
        })
        .unwrap_or_default();
    match names.as_slice() {
        [one] => Ok(Endpoint::Server {
            base: format!("{trimmed}/v1/repos/{one}"),
        }),
        [] => Err(RemoteError::Url(format!("{url} serves no repository"))),
        many => Err(RemoteError::Url(format!(
            "{url} serves {} repositories ({}); name one: {trimmed}/v1/repos/NAME",
            many.len(),
            many.join(", ")
        ))),
    }
}

fn http_error(url: &str, e: impl std::fmt::Display) -> RemoteError {
    RemoteError::Http {
        url: url.to_owned(),
        message: e.to_string(),
    }
}

/// Splits the body of a batch request for `ids` into records: the framing is the codec's
/// ([`cbdam_codec::repository::batch`]); every id must be answered, in order, with a record.
pub fn parse_frames(body: &[u8], ids: &[DiamondId]) -> Result<Vec<(DiamondId, Vec<u8>)>, String> {
    let entries = batch::parse(body).map_err(|e| e.to_string())?;
    if entries.len() != ids.len() {
        return Err(format!(
            "asked for {} records, response holds {}",
            ids.len(),
            entries.len()
        ));
    }
    ids.iter()
        .zip(entries)
        .map(|(&id, entry)| match entry {
            Entry::Record(bytes) => Ok((id, bytes.to_vec())),
            Entry::NotStored => Err(format!(
                "server says {id} is not stored, the head says it is"
            )),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn id(l: u8, x: u32, y: u32) -> DiamondId {
        DiamondId::new(l, x, y)
    }

    #[test]
    fn urls_name_a_server_repository_a_file_or_a_server() {
        let server = |base: &str| {
            Some(Endpoint::Server {
                base: base.to_owned(),
            })
        };
        let file = |url: &str| {
            Some(Endpoint::File {
                url: url.to_owned(),
            })
        };
        let c = |u: &str| classify(u).unwrap();
        assert_eq!(
            c("http://h:1/v1/repos/jb"),
            server("http://h:1/v1/repos/jb")
        );
        assert_eq!(
            c("http://h:1/v1/repos/jb/"),
            server("http://h:1/v1/repos/jb")
        );
        // cbdam serve's raw file route: range requests on the file, not batches.
        assert_eq!(
            c("http://h:1/v1/repos/jb/file"),
            file("http://h:1/v1/repos/jb/file")
        );
        // A repository named "file" is still a repository.
        assert_eq!(
            c("http://h:1/v1/repos/file"),
            server("http://h:1/v1/repos/file")
        );
        assert_eq!(
            c("http://h:1/data/jb.cbdam"),
            file("http://h:1/data/jb.cbdam")
        );
        assert_eq!(c("http://h:1/"), None);
        assert!(classify("ftp://h/x").is_err());
    }

    #[test]
    fn frames_parse_and_bad_frames_are_errors() {
        let ids = [id(1, 2, 3), id(2, 4, 5)];
        let mut body = b"CBDR".to_vec();
        body.extend(2u32.to_le_bytes());
        body.push(0);
        body.extend(3u32.to_le_bytes());
        body.extend([7, 8, 9]);
        body.push(0);
        body.extend(0u32.to_le_bytes());
        let r = parse_frames(&body, &ids).unwrap();
        assert_eq!(r, vec![(ids[0], vec![7, 8, 9]), (ids[1], vec![])]);
        for cut in 0..body.len() {
            assert!(parse_frames(&body[..cut], &ids).is_err(), "cut at {cut}");
        }
        let mut longer = body.clone();
        longer.push(0);
        assert!(parse_frames(&longer, &ids).is_err());
        assert!(parse_frames(&body, &ids[..1]).is_err());
        let mut missing = body.clone();
        missing[8] = 1;
        assert!(parse_frames(&missing, &ids).is_err());
    }
}
