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
//! wanted records go into the next request), the backoff, reading the head, checking range
//! responses and records, and the batch parsing. The transports only move bytes: the desktop's
//! ([`RemoteFetcher`]: tokio and reqwest) is in `native`, the browser's (the page's `fetch`,
//! driven by its event loop, never blocking) in `web`.

use std::time::Duration;

use cbdam_codec::CodecError;
use cbdam_codec::geometry::DiamondId;
use std::sync::Arc;

mod schedule;
mod wire;

use schedule::{State, next_batch, record_bytes};
pub use wire::parse_frames;
use wire::{
    answer_ids, batch_request_body, batch_span, check_records, expect_partial, fetch_head_with,
    range_total, split_span,
};

#[cfg(not(target_arch = "wasm32"))]
mod native;
#[cfg(not(target_arch = "wasm32"))]
pub use native::RemoteFetcher;
#[cfg(target_arch = "wasm32")]
mod web;
#[cfg(target_arch = "wasm32")]
pub use web::RemoteFetcher;

/// Tuning of the fetcher; every limit is explicit.
#[derive(Clone, Debug)]
pub struct FetchOptions {
    /// Most records asked for in one request.
    pub max_batch: usize,
    /// Most batch requests to `cbdam serve` in flight at once.
    pub max_in_flight: usize,
    /// Most range requests to a static server in flight at once. A range request carries only a
    /// run of adjacent records (a few KiB), so a link with a round trip of tens of milliseconds
    /// needs many of them in flight to be kept busy (HTTP/2 multiplexes them on one connection;
    /// HTTP/1.1 opens a connection each, which browsers queue at 6 per host).
    pub max_ranges_in_flight: usize,
    /// Bytes of records in flight at most what the link was measured to deliver in this long
    /// (but always two requests): a slow link is not committed to seconds of requests whose
    /// order can no longer follow the view, and none of them waits long enough in the link's
    /// queue to time out. A batch is cut to half that many bytes.
    pub queue_seconds: f64,
    /// The byte limit of records in flight before the link's rate is measured.
    pub initial_window: u64,
    /// Longest silence of one request: connecting, or between two reads of its response (a
    /// slow link that keeps delivering never times out; the browser transport has no such
    /// timer and uses it as the time-out of the whole request).
    pub timeout: Duration,
    /// First retry delay; doubled per failure of the same record, up to `max_backoff`.
    pub initial_backoff: Duration,
    /// Longest retry delay.
    pub max_backoff: Duration,
    /// Range requests to a static server merge records separated by at most this many bytes.
    /// 0 (the default) merges only records that touch: a gap's bytes may belong to records
    /// another request is fetching, and measured on loopback that doubled the bytes fetched.
    pub max_range_gap: u64,
    /// A request in flight is dropped (closing its connection, so the server stops sending)
    /// when at least this fraction of the record bytes it has still to deliver is no longer
    /// wanted; the records of it that are still wanted are requested again. 1 drops only
    /// requests none of whose remaining records is wanted.
    pub cancel_waste: f64,
}

impl Default for FetchOptions {
    fn default() -> Self {
        Self {
            max_batch: 64,
            max_in_flight: 8,
            max_ranges_in_flight: 32,
            queue_seconds: 0.5,
            initial_window: 256 << 10,
            timeout: Duration::from_secs(5),
            initial_backoff: Duration::from_millis(50),
            max_backoff: Duration::from_secs(2),
            max_range_gap: 0,
            cancel_waste: 0.5,
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
    /// Requests aborted because (enough of) their records were not wanted any more
    /// ([`FetchOptions::cancel_waste`]).
    pub cancelled: u64,
    /// Records still wanted that a cancelled request was carrying, queued again.
    pub requeued: u64,
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
    /// Most requests in flight at once to this endpoint.
    fn max_in_flight(&self, options: &FetchOptions) -> usize {
        match self {
            Endpoint::Server { .. } => options.max_in_flight,
            Endpoint::File { .. } => options.max_ranges_in_flight,
        }
    }

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

#[cfg(test)]
mod tests;
