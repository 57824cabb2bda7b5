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

struct Pending {
    priority: f32,
}

/// The scheduler's bookkeeping; `H` is the transport's handle for aborting a request. Each
/// entry of `batches` lists the records its request has still to deliver (a streamed response
/// delivers them one by one).
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
    /// The link's measured rate and the bytes in flight against it.
    window: Window,
}

/// A byte window over the requests in flight, sized by the link's measured delivery rate.
#[derive(Default)]
struct Window {
    /// Record bytes of the requests in flight.
    in_flight: u64,
    /// Per request in flight: its record bytes, when it started, and `delivered` then.
    started: HashMap<u64, (u64, Instant, u64)>,
    /// Bytes delivered by finished requests so far.
    delivered: u64,
    /// Smoothed delivery rate, bytes per second; 0 until measured.
    rate: f64,
}

impl Window {
    /// The byte limit of records in flight.
    fn limit(&self, options: &FetchOptions) -> u64 {
        if self.rate > 0.0 {
            ((self.rate * options.queue_seconds) as u64).max(16 << 10)
        } else {
            options.initial_window
        }
    }

    fn start(&mut self, batch: u64, bytes: u64, now: Instant) {
        self.in_flight += bytes;
        self.started.insert(batch, (bytes, now, self.delivered));
    }

    /// A request ended: `received` bytes if it succeeded (a rate sample: everything delivered
    /// while it was in flight over its duration), `None` if it failed or was cancelled.
    fn end(&mut self, batch: u64, received: Option<u64>, now: Instant) {
        let Some((bytes, t0, delivered_then)) = self.started.remove(&batch) else {
            return;
        };
        self.in_flight -= bytes;
        let Some(received) = received else { return };
        self.delivered += received;
        let secs = now.saturating_duration_since(t0).as_secs_f64();
        if secs > 0.0 && received > 0 {
            let sample = (self.delivered - delivered_then) as f64 / secs;
            self.rate = if self.rate > 0.0 {
                self.rate + 0.25 * (sample - self.rate)
            } else {
                sample
            };
        }
    }
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
            window: Window::default(),
        }
    }
}

impl<H> State<H> {
    /// Whether another request may start: a free slot, and room in the byte window (always
    /// for the first two).
    fn may_start(&self, options: &FetchOptions, endpoint: &Endpoint) -> bool {
        self.batches.len() < endpoint.max_in_flight(options)
            && (self.batches.len() < 2 || self.window.in_flight < self.window.limit(options))
    }

    /// Most record bytes in the next request.
    fn batch_bytes(&self, options: &FetchOptions) -> u64 {
        (self.window.limit(options) / 2).max(1)
    }

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

    /// Replaces the wanted records (those the head stores and that were not just delivered).
    fn set_wanted(
        &mut self,
        head: &RepositoryHead,
        wanted: impl IntoIterator<Item = (DiamondId, f32)>,
    ) {
        let delivered = &self.delivered;
        self.wanted = wanted
            .into_iter()
            .filter(|(id, _)| head.position(*id).is_some() && !delivered.contains(id))
            .map(|(id, priority)| (id, Pending { priority }))
            .collect();
    }

    /// Drops the requests [`not_worth_finishing`] for the wanted set, calling `abort` on each
    /// one's handle; their records go back to the queue. Returns the requests dropped and the
    /// records still wanted that they were carrying.
    fn cancel_unwanted(
        &mut self,
        head: &RepositoryHead,
        options: &FetchOptions,
        abort: impl Fn(&H),
    ) -> (u64, u64) {
        let now = Instant::now();
        let (mut cancelled, mut requeued) = (0, 0);
        let State {
            wanted,
            batches,
            in_flight,
            window,
            ..
        } = self;
        batches.retain(|(batch, ids, handle)| {
            if !not_worth_finishing(ids, wanted, head, options) {
                return true;
            }
            abort(handle);
            window.end(*batch, None, now);
            for id in ids {
                in_flight.remove(id);
                requeued += u64::from(wanted.contains_key(id));
            }
            cancelled += 1;
            false
        });
        (cancelled, requeued)
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
    max_bytes: u64,
) -> Vec<DiamondId> {
    match endpoint {
        Endpoint::Server { .. } => {
            let mut bytes = 0;
            let mut n = 0;
            while n < ready.len().min(options.max_batch) {
                let r = record_range(head, ready[n]);
                if n > 0 && bytes + (r.end - r.start) > max_bytes {
                    break;
                }
                bytes += r.end - r.start;
                n += 1;
            }
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
                    && hi.max(r.end) - lo.min(r.start) <= max_bytes
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

/// Record bytes of `ids`.
fn record_bytes(head: &RepositoryHead, ids: &[DiamondId]) -> u64 {
    ids.iter()
        .map(|&id| {
            let r = record_range(head, id);
            r.end - r.start
        })
        .sum()
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

/// Checks the status of a response to `Range: bytes=start-(end-1)`: it must be 206 (Partial
/// Content); anything else means the server ignored the range (and would send the whole file).
fn expect_partial(range: &std::ops::Range<u64>, status: u16) -> Result<(), String> {
    if status == 206 {
        return Ok(());
    }
    Err(format!(
        "asked for bytes {}..{}, got HTTP {status} (does the server honour Range requests?)",
        range.start, range.end,
    ))
}

/// Checks the body of a 206 response to the request for `range`: `content_range` (the header's
/// value) must carry the file's total length; a range running past the end of the file gets
/// the bytes up to the end (what a server answers), any other body length is an error. Returns
/// the total.
fn range_total(
    range: &std::ops::Range<u64>,
    content_range: Option<&str>,
    body_len: usize,
) -> Result<u64, String> {
    let total = content_range
        .and_then(|v| v.rsplit_once('/'))
        .and_then(|(_, total)| total.parse::<u64>().ok())
        .ok_or("206 response without a Content-Range total")?;
    let end = range.end.min(total.max(range.start));
    if body_len as u64 != end - range.start {
        return Err(format!(
            "asked for {} bytes, got {body_len}",
            end - range.start
        ));
    }
    Ok(total)
}

/// Reads the repository head of the file at `url` with `get_range` (a transport's range GET,
/// returning the body and the file's total length); also returns the head's bytes.
async fn fetch_head_with<F, Fut>(
    url: &str,
    get_range: F,
) -> Result<(RepositoryHead, Vec<u8>), RemoteError>
where
    F: Fn(std::ops::Range<u64>) -> Fut,
    Fut: std::future::Future<Output = Result<(Vec<u8>, u64), String>>,
{
    use cbdam_codec::repository::{HEADER_FETCH_LEN, header_len, required_head_len};
    // A version-3 header is usually shorter than HEADER_FETCH_LEN, and so can be the whole
    // file: a server answers a range past the end with what there is. A long CRS definition
    // makes it longer: then a second request fetches the rest.
    let (mut header, file_len) = get_range(0..HEADER_FETCH_LEN as u64)
        .await
        .map_err(|e| http_error(url, e))?;
    let repo_error = |source| RemoteError::Repository {
        url: url.to_owned(),
        source,
    };
    let len = header_len(&header).map_err(repo_error)?;
    if len > header.len() && len as u64 <= file_len {
        header = get_range(0..len as u64)
            .await
            .map_err(|e| http_error(url, e))?
            .0;
    }
    let head_len = required_head_len(&header).map_err(repo_error)?;
    if head_len > file_len {
        return Err(repo_error(CodecError::truncated(format!(
            "the head is {head_len} bytes, the file {file_len}"
        ))));
    }
    let (head, _) = get_range(0..head_len)
        .await
        .map_err(|e| http_error(url, e))?;
    let parsed = RepositoryHead::parse(&head, file_len).map_err(repo_error)?;
    Ok((parsed, head))
}

/// The byte span of one range request for `ids`' records (chosen close together by
/// [`next_batch`]) and each record's range in the file.
fn batch_span(
    head: &RepositoryHead,
    ids: &[DiamondId],
) -> (std::ops::Range<u64>, Vec<std::ops::Range<u64>>) {
    let ranges: Vec<_> = ids.iter().map(|&id| record_range(head, id)).collect();
    let lo = ranges
        .iter()
        .map(|r| r.start)
        .min()
        .expect("non-empty batch");
    let hi = ranges.iter().map(|r| r.end).max().expect("non-empty batch");
    (lo..hi, ranges)
}

/// Cuts the body of the range request for `span` into `ids`' records; `total` is the file
/// length the server reported.
fn split_span(
    head: &RepositoryHead,
    ids: &[DiamondId],
    span: std::ops::Range<u64>,
    ranges: Vec<std::ops::Range<u64>>,
    body: &[u8],
    total: u64,
) -> Result<Vec<(DiamondId, Vec<u8>)>, String> {
    if total != head.file_len() {
        return Err(format!(
            "the file is now {total} bytes, the head says {}: it changed on the server",
            head.file_len()
        ));
    }
    // The head's records lie inside the file, so only a server that cut the range short gives
    // fewer bytes; the slicing below needs all of them.
    if body.len() as u64 != span.end - span.start {
        return Err(format!(
            "asked for {} bytes, got {}",
            span.end - span.start,
            body.len()
        ));
    }
    let lo = span.start;
    Ok(ids
        .iter()
        .zip(ranges)
        .map(|(&id, r)| {
            (
                id,
                body[(r.start - lo) as usize..(r.end - lo) as usize].to_vec(),
            )
        })
        .collect())
}

/// Records that passed their checks.
type Checked = Vec<(DiamondId, Arc<[u8]>)>;

/// `records` checked against the head: those that pass, and the ids of those that fail (to be
/// retried).
fn check_records(
    head: &RepositoryHead,
    records: Vec<(DiamondId, Vec<u8>)>,
) -> (Checked, Vec<DiamondId>) {
    let mut passed = Vec::with_capacity(records.len());
    let mut failed = Vec::new();
    for (id, bytes) in records {
        let i = head.position(id).expect("stored");
        match head.check_record(i, &bytes) {
            Ok(()) => passed.push((id, Arc::from(bytes))),
            Err(e) => {
                tracing::warn!("record {id} rejected: {e}");
                failed.push(id);
            }
        }
    }
    (passed, failed)
}

/// The JSON body of a batch request (`POST …/diamonds`) for `ids` with their `priorities`
/// (screen errors; the server answers the highest first, see [`batch::answer_order`]), as
/// [`wire_priorities`] writes them.
fn batch_request_body(ids: &[DiamondId], priorities: &[f32]) -> String {
    let names: Vec<String> = ids.iter().map(ToString::to_string).collect();
    serde_json::json!({ "ids": names, "priorities": wire_priorities(priorities) }).to_string()
}

/// Priorities as a batch request carries them: three significant digits (about 4 bytes of
/// JSON each instead of 9: the order, not the value, is what the server needs, and rounding
/// keeps a sorted list sorted), non-finite ones as 0 (JSON has no infinities).
fn wire_priorities(priorities: &[f32]) -> Vec<f64> {
    priorities
        .iter()
        .map(|&p| {
            if !p.is_finite() || p == 0.0 {
                return 0.0;
            }
            let p = f64::from(p);
            let scale = 10f64.powi(2 - p.abs().log10().floor() as i32);
            (p * scale).round() / scale
        })
        .collect()
}

/// The ids of a batch request in the order the server answers them.
fn answer_ids(ids: &[DiamondId], priorities: &[f32]) -> Vec<DiamondId> {
    // As the server reads them: f32.
    let read: Vec<f32> = wire_priorities(priorities)
        .into_iter()
        .map(|p| p as f32)
        .collect();
    batch::answer_order(&read)
        .into_iter()
        .map(|k| ids[k])
        .collect()
}

/// Whether a request whose still-to-come records are `remaining` should be dropped now that
/// `wanted` is what the view wants: none of them is wanted, or at least
/// [`FetchOptions::cancel_waste`] of their bytes (each with its entry's framing) is not.
fn not_worth_finishing<V>(
    remaining: &[DiamondId],
    wanted: &HashMap<DiamondId, V>,
    head: &RepositoryHead,
    options: &FetchOptions,
) -> bool {
    let (mut useful, mut waste) = (0u64, 0u64);
    for &id in remaining {
        let r = record_range(head, id);
        let bytes = r.end - r.start + batch::ENTRY_HEAD_LEN as u64;
        if wanted.contains_key(&id) {
            useful += bytes;
        } else {
            waste += bytes;
        }
    }
    useful == 0 || waste as f64 >= options.cancel_waste * (useful + waste) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    fn id(l: u8, x: u32, y: u32) -> DiamondId {
        DiamondId::new(l, x, y)
    }

    #[test]
    fn batches_are_dropped_when_most_of_what_they_still_carry_is_unwanted() {
        use cbdam_codec::hierarchy::{EncodeOptions, Encoder};
        use cbdam_codec::quant::{HeightGrid, QuantPlan};
        let (w, h) = (33usize, 33usize);
        let metres: Vec<f64> = (0..w * h)
            .map(|i| ((i * 7919) % 97) as f64 + (i % w) as f64)
            .collect();
        let plan = QuantPlan::new(0.25, None, 0.0, 200.0).unwrap();
        let grid = HeightGrid::from_metres(w, h, &metres, None, &plan).unwrap();
        let opts = EncodeOptions {
            n: 9,
            ..EncodeOptions::default()
        };
        let enc = Encoder::new(&grid, plan.quantizer, &opts).encode().unwrap();
        let bytes = cbdam_codec::repository::serialize(&enc, &plan, None, None).unwrap();
        let repo = cbdam_codec::repository::Repository::from_bytes(bytes).unwrap();
        let head = repo.head();
        // Four records of the same size, so that fractions are exact.
        let mut by_len: HashMap<u32, Vec<DiamondId>> = HashMap::new();
        for e in repo.head().entries() {
            by_len.entry(e.length).or_default().push(e.id);
        }
        let four: Vec<DiamondId> = by_len
            .into_values()
            .find(|v| v.len() >= 4)
            .expect("four records of one size")[..4]
            .to_vec();
        let o = FetchOptions::default();
        let wanted =
            |n: usize| -> HashMap<DiamondId, ()> { four[..n].iter().map(|&id| (id, ())).collect() };
        assert!(!not_worth_finishing(&four, &wanted(4), head, &o));
        assert!(
            !not_worth_finishing(&four, &wanted(3), head, &o),
            "a quarter unwanted"
        );
        assert!(
            not_worth_finishing(&four, &wanted(2), head, &o),
            "half unwanted"
        );
        assert!(not_worth_finishing(&four, &wanted(0), head, &o));
        // Only what is still to come counts: the two wanted ones delivered, the rest unwanted.
        assert!(not_worth_finishing(&four[2..], &wanted(2), head, &o));
        let lenient = FetchOptions {
            cancel_waste: 1.0,
            ..FetchOptions::default()
        };
        assert!(!not_worth_finishing(&four, &wanted(1), head, &lenient));
        assert!(not_worth_finishing(&four, &wanted(0), head, &lenient));
    }

    #[test]
    fn batch_requests_carry_priorities_and_answers_follow_them() {
        let ids = [id(1, 2, 3), id(2, 4, 5), id(3, 1, 1)];
        let body = batch_request_body(&ids, &[1.0, f32::INFINITY, 4.5]);
        let v: serde_json::Value = serde_json::from_str(&body).unwrap();
        assert_eq!(v["ids"], serde_json::json!(["1-2-3", "2-4-5", "3-1-1"]));
        assert_eq!(v["priorities"], serde_json::json!([1.0, 0.0, 4.5]));
        let short = batch_request_body(&ids[..2], &[2.718_4, 0.012_345_67]);
        assert!(short.contains("[2.72,0.0123]"), "{short}");
        // Rounding keeps a sorted list sorted (ties are answered in request order).
        let sorted = [1234.5f32, 999.6, 999.4, 10.04, 9.996, 0.5, 0.0];
        let wire = wire_priorities(&sorted);
        assert!(wire.windows(2).all(|w| w[0] >= w[1]), "{wire:?}");
        let read: Vec<f32> = wire.iter().map(|&p| p as f32).collect();
        assert_eq!(
            batch::answer_order(&read),
            (0..sorted.len()).collect::<Vec<_>>()
        );
        assert_eq!(
            answer_ids(&ids, &[1.0, f32::INFINITY, 4.5]),
            vec![ids[2], ids[0], ids[1]]
        );
        // What the client sends (most urgent first) comes back as sent.
        assert_eq!(answer_ids(&ids, &[9.0, 9.0, 1.0]), ids.to_vec());
    }

    #[test]
    fn the_byte_window_follows_the_measured_delivery_rate() {
        let o = FetchOptions::default();
        let mut w = Window::default();
        let t0 = Instant::now();
        assert_eq!(w.limit(&o), o.initial_window, "before any measurement");
        w.start(1, 100_000, t0);
        w.start(2, 100_000, t0);
        assert_eq!(w.in_flight, 200_000);
        // The first delivers 100 kB in 1 s: 100 kB/s, half a second's worth in flight at most.
        w.end(1, Some(100_000), t0 + Duration::from_secs(1));
        assert!((w.rate - 100_000.0).abs() < 1.0, "{}", w.rate);
        assert_eq!(w.limit(&o), 50_000);
        // Everything delivered while the second was in flight counts: 200 kB in 4 s.
        w.end(2, Some(100_000), t0 + Duration::from_secs(4));
        assert!((w.rate - (100_000.0 + 0.25 * (50_000.0 - 100_000.0))).abs() < 1.0);
        // A failed or cancelled request frees its bytes and is no sample.
        w.start(3, 7, t0);
        let rate = w.rate;
        w.end(3, None, t0 + Duration::from_secs(9));
        assert_eq!((w.in_flight, w.rate), (0, rate));
        // A very slow link still gets a usable window.
        w.rate = 10.0;
        assert_eq!(w.limit(&o), 16 << 10);
    }

    /// Range responses: only 206 is accepted; the total comes from `Content-Range`; a range
    /// past the end of the file gets the bytes up to the end, and any other length is an error.
    #[test]
    fn range_responses_are_checked() {
        let r = 10..20;
        assert!(expect_partial(&r, 206).is_ok());
        let e = expect_partial(&r, 200).unwrap_err();
        assert!(e.contains("HTTP 200") && e.contains("Range"), "{e}");
        assert_eq!(range_total(&r, Some("bytes 10-19/100"), 10), Ok(100));
        // The file ends at 15: five bytes are the whole answer.
        assert_eq!(range_total(&r, Some("bytes 10-14/15"), 5), Ok(15));
        assert!(range_total(&r, Some("bytes 10-14/15"), 4).is_err());
        assert!(range_total(&r, Some("bytes 10-19/100"), 9).is_err());
        assert!(range_total(&r, Some("bytes 10-19/*"), 10).is_err());
        assert!(range_total(&r, None, 10).is_err());
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

    /// What the native client and the browser core open a remote repository with: the file of
    /// a hostile server, whose checksums match but whose height unit makes every height
    /// infinite, is refused with the codec's error naming the field, before any world or
    /// camera is made from it (they panicked on such values).
    #[test]
    fn a_crafted_head_from_a_hostile_server_is_refused_by_name() {
        use cbdam_codec::hierarchy::{EncodeOptions, Encoder};
        use cbdam_codec::quant::{HeightGrid, QuantPlan};
        use cbdam_codec::repository::{craft_header, serialize};
        let (w, h) = (33, 33);
        let metres: Vec<f64> = (0..w * h).map(|i| f64::from((i % 7) as u8) * 3.0).collect();
        let plan = QuantPlan::new(1.0, None, 0.0, 18.0).unwrap();
        let grid = HeightGrid::from_metres(w, h, &metres, None, &plan).unwrap();
        let opts = EncodeOptions {
            n: 9,
            ..EncodeOptions::default()
        };
        let enc = Encoder::new(&grid, plan.quantizer, &opts).encode().unwrap();
        let good = serialize(&enc, &plan, None, None).unwrap();
        let open = |bytes: Vec<u8>| {
            let len = bytes.len() as u64;
            let get = |r: std::ops::Range<u64>| {
                let end = r.end.min(len) as usize;
                let body = bytes[r.start as usize..end].to_vec();
                async move { Ok((body, len)) }
            };
            let fut = std::pin::pin!(fetch_head_with("http://hostile/r.cbdam", get));
            let mut cx = std::task::Context::from_waker(std::task::Waker::noop());
            match fut.poll(&mut cx) {
                std::task::Poll::Ready(r) => r.map(|(head, _)| head),
                std::task::Poll::Pending => panic!("an in-memory fetch is never pending"),
            }
        };
        assert!(open(good.clone()).is_ok());
        let bad = craft_header(&good, "unit", 1e308f64.to_bits()).unwrap();
        match open(bad) {
            Err(RemoteError::Repository { source, .. }) => {
                assert!(source.to_string().contains("height unit 1e308"), "{source}");
            }
            other => panic!("{other:?}"),
        }
    }
}
