//! The desktop transport of the [`fetch`](super)er: a background tokio runtime sending requests
//! with reqwest. What to fetch next, the backoff and the batch framing are the portable parent
//! module's; this module only moves bytes.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use cbdam_codec::geometry::DiamondId;
use cbdam_codec::repository::RepositoryHead;
use tokio::sync::Notify;
use tokio::task::AbortHandle;
use web_time::Instant;

use super::{
    Endpoint, FetchOptions, FetchStats, Fetched, RemoteError, State, answer_ids,
    batch_request_body, batch_span, check_records, classify, expect_partial, fetch_head_with,
    http_error, list_url, next_batch, range_total, record_bytes, single_repository, split_span,
};
use cbdam_codec::repository::batch::{OwnedEntry, StreamParser};

struct Shared {
    state: Mutex<State<AbortHandle>>,
    wake: Notify,
    stats: Counters,
    head: Arc<RepositoryHead>,
    endpoint: Endpoint,
    options: FetchOptions,
    client: reqwest::Client,
    results: Mutex<mpsc::Sender<Fetched>>,
}

#[derive(Default)]
struct Counters {
    requests: AtomicU64,
    in_flight: AtomicU64,
    bytes: AtomicU64,
    records: AtomicU64,
    errors: AtomicU64,
    cancelled: AtomicU64,
    requeued: AtomicU64,
}

/// Fetches records of one remote repository in the background.
pub struct RemoteFetcher {
    shared: Arc<Shared>,
    results: mpsc::Receiver<Fetched>,
    runtime: Option<tokio::runtime::Runtime>,
}

impl std::fmt::Debug for RemoteFetcher {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RemoteFetcher")
            .field("endpoint", &self.shared.endpoint)
            .finish_non_exhaustive()
    }
}

impl RemoteFetcher {
    /// Connects to a repository and fetches its head (this one call blocks, before any frame).
    ///
    /// `url` is either a repository of `cbdam serve` (`http://host:port/v1/repos/NAME`), a
    /// `cbdam serve` root that serves exactly one repository (`http://host:port/`), or the URL
    /// of a repository file on any server that honours range requests.
    pub fn connect(url: &str, options: FetchOptions) -> Result<Self, RemoteError> {
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .thread_name("cbdam-fetch")
            .enable_all()
            .build()
            .map_err(|e| RemoteError::Http {
                url: url.to_owned(),
                message: format!("cannot start the network runtime: {e}"),
            })?;
        let client = reqwest::Client::builder()
            .connect_timeout(options.timeout)
            .read_timeout(options.timeout)
            .build()
            .map_err(|e| RemoteError::Http {
                url: url.to_owned(),
                message: e.to_string(),
            })?;
        let (endpoint, head, head_requests) = runtime.block_on(async {
            let endpoint = resolve(&client, url).await?;
            let (head, requests) = fetch_head(&client, &endpoint.file_url()).await?;
            Ok::<_, RemoteError>((endpoint, head, requests))
        })?;
        let (tx, rx) = mpsc::channel();
        let shared = Arc::new(Shared {
            state: Mutex::new(State::default()),
            wake: Notify::new(),
            stats: Counters::default(),
            head: Arc::new(head),
            endpoint,
            options,
            client,
            results: Mutex::new(tx),
        });
        shared
            .stats
            .requests
            .fetch_add(head_requests, Ordering::Relaxed);
        runtime.spawn(schedule(shared.clone()));
        Ok(Self {
            shared,
            results: rx,
            runtime: Some(runtime),
        })
    }

    /// The repository's head.
    pub fn head(&self) -> &Arc<RepositoryHead> {
        &self.shared.head
    }

    /// Replaces the set of wanted records (higher priority first). Queued records not in the set
    /// are forgotten, and requests in flight that are no longer worth finishing (none of their
    /// remaining records wanted, or [`FetchOptions::cancel_waste`] of their bytes unwanted) are
    /// aborted: their connection closes, so the server stops sending, and their records that
    /// are still wanted are queued again.
    pub fn want(&self, wanted: impl IntoIterator<Item = (DiamondId, f32)>) {
        let mut s = self.shared.state.lock().expect("fetch state");
        s.set_wanted(&self.shared.head, wanted);
        let (head, options) = (&self.shared.head, &self.shared.options);
        let (cancelled, requeued) = s.cancel_unwanted(head, options, AbortHandle::abort);
        let stats = &self.shared.stats;
        stats.requeued.fetch_add(requeued, Ordering::Relaxed);
        stats.cancelled.fetch_add(cancelled, Ordering::Relaxed);
        stats.in_flight.fetch_sub(cancelled, Ordering::Relaxed);
        drop(s);
        self.shared.wake.notify_one();
    }

    /// Takes the records that arrived since the last call; never blocks.
    pub fn poll(&self) -> Vec<Fetched> {
        let got: Vec<Fetched> = self.results.try_iter().collect();
        if !got.is_empty() {
            let mut s = self.shared.state.lock().expect("fetch state");
            for (id, _) in &got {
                s.delivered.remove(id);
            }
        }
        got
    }

    /// Fetches every record of `ids` and waits for them (a batch reader's call, not a frame
    /// loop's: it blocks). Fails on the first record the fetcher rejects, or when `stall`
    /// passes without a record arriving (a server that is gone: the fetcher itself would retry
    /// for ever), saying how many arrived. Ids not stored are refused at once.
    pub fn fetch_all(
        &self,
        ids: &[DiamondId],
        stall: Duration,
    ) -> Result<std::collections::HashMap<DiamondId, Arc<[u8]>>, String> {
        if let Some(id) = ids
            .iter()
            .find(|&&id| self.shared.head.position(id).is_none())
        {
            return Err(format!("{id} is not stored in this repository"));
        }
        let mut got = std::collections::HashMap::with_capacity(ids.len());
        let missing = |got: &std::collections::HashMap<DiamondId, Arc<[u8]>>| {
            ids.iter().filter(|id| !got.contains_key(*id)).count()
        };
        self.want(ids.iter().map(|&id| (id, 1.0)));
        let result = loop {
            if missing(&got) == 0 {
                break Ok(());
            }
            match self.results.recv_timeout(stall) {
                Ok((id, Ok(bytes))) => {
                    got.insert(id, bytes);
                }
                Ok((id, Err(e))) => break Err(format!("record of {id} rejected: {e}")),
                Err(_) => {
                    break Err(format!(
                        "no record arrived for {:.1} s ({} of {} received, {} failed requests): \
                         is the server still there?",
                        stall.as_secs_f64(),
                        ids.len() - missing(&got),
                        ids.len(),
                        self.stats().errors
                    ));
                }
            }
        };
        self.want(std::iter::empty());
        let mut s = self.shared.state.lock().expect("fetch state");
        for id in got.keys() {
            s.delivered.remove(id);
        }
        drop(s);
        result.map(|()| got)
    }

    /// Whether `id` is queued or being fetched.
    pub fn is_pending(&self, id: DiamondId) -> bool {
        let s = self.shared.state.lock().expect("fetch state");
        s.wanted.contains_key(&id) || s.in_flight.contains(&id)
    }

    /// The counters so far.
    pub fn stats(&self) -> FetchStats {
        let c = &self.shared.stats;
        FetchStats {
            requests: c.requests.load(Ordering::Relaxed),
            in_flight: c.in_flight.load(Ordering::Relaxed),
            bytes: c.bytes.load(Ordering::Relaxed),
            records: c.records.load(Ordering::Relaxed),
            errors: c.errors.load(Ordering::Relaxed),
            cancelled: c.cancelled.load(Ordering::Relaxed),
            requeued: c.requeued.load(Ordering::Relaxed),
        }
    }
}

impl Drop for RemoteFetcher {
    fn drop(&mut self) {
        self.shared.state.lock().expect("fetch state").shutdown = true;
        self.shared.wake.notify_one();
        if let Some(rt) = self.runtime.take() {
            rt.shutdown_background();
        }
    }
}

/// Works out what kind of URL this is, asking a bare server address for its repositories.
async fn resolve(client: &reqwest::Client, url: &str) -> Result<Endpoint, RemoteError> {
    if let Some(endpoint) = classify(url)? {
        return Ok(endpoint);
    }
    let list = list_url(url);
    let body = client
        .get(&list)
        .send()
        .await
        .and_then(|r| r.error_for_status())
        .map_err(|e| http_error(&list, e))?
        .bytes()
        .await
        .map_err(|e| http_error(&list, e))?;
    single_repository(url, &body)
}

/// GETs `range` of `url`; returns the body and the total file length from `Content-Range`
/// ([`expect_partial`], [`range_total`]).
async fn get_range(
    client: &reqwest::Client,
    url: &str,
    range: std::ops::Range<u64>,
) -> Result<(Vec<u8>, u64), String> {
    let resp = client
        .get(url)
        .header(
            reqwest::header::RANGE,
            format!("bytes={}-{}", range.start, range.end - 1),
        )
        .send()
        .await
        .map_err(|e| e.to_string())?;
    expect_partial(&range, resp.status().as_u16())?;
    let content_range = resp
        .headers()
        .get(reqwest::header::CONTENT_RANGE)
        .and_then(|v| v.to_str().ok())
        .map(str::to_owned);
    let body = resp.bytes().await.map_err(|e| e.to_string())?;
    let total = range_total(&range, content_range.as_deref(), body.len())?;
    Ok((body.to_vec(), total))
}

/// The head and how many range requests it took (2, or 3 for a header longer than the first
/// fetch).
async fn fetch_head(
    client: &reqwest::Client,
    url: &str,
) -> Result<(RepositoryHead, u64), RemoteError> {
    let requests = std::sync::atomic::AtomicU64::new(0);
    let (head, _) = fetch_head_with(url, |range| {
        requests.fetch_add(1, Ordering::Relaxed);
        get_range(client, url, range)
    })
    .await?;
    Ok((head, requests.into_inner()))
}

/// The scheduler: whenever woken (new wants, a finished request, a backoff expiring), starts the
/// most urgent wanted records that are neither in flight nor backing off.
async fn schedule(shared: Arc<Shared>) {
    loop {
        let next_retry = {
            let mut s = shared.state.lock().expect("fetch state");
            if s.shutdown {
                return;
            }
            start_batches(&shared, &mut s)
        };
        let wait = next_retry.map_or(Duration::from_millis(250), |t| {
            t.saturating_duration_since(Instant::now())
        });
        tokio::select! {
            () = shared.wake.notified() => {}
            () = tokio::time::sleep(wait) => {}
        }
    }
}

/// Starts requests while slots are free; returns the earliest backoff expiry among wanted records.
fn start_batches(shared: &Arc<Shared>, s: &mut State<AbortHandle>) -> Option<Instant> {
    let (mut ready, next_retry) = s.ready(Instant::now());
    while s.may_start(&shared.options, &shared.endpoint) && !ready.is_empty() {
        let max_bytes = s.batch_bytes(&shared.options);
        let ids = next_batch(
            &mut ready,
            &shared.endpoint,
            &shared.head,
            &shared.options,
            max_bytes,
        );
        for id in &ids {
            s.in_flight.insert(*id);
        }
        let priorities: Vec<f32> = ids
            .iter()
            .map(|id| s.wanted.get(id).map_or(0.0, |p| p.priority))
            .collect();
        let batch = s.next_batch;
        s.next_batch += 1;
        s.window
            .start(batch, record_bytes(&shared.head, &ids), Instant::now());
        let task = tokio::spawn(fetch_batch(shared.clone(), batch, ids.clone(), priorities));
        s.batches.push((batch, ids, task.abort_handle()));
        shared.stats.in_flight.fetch_add(1, Ordering::Relaxed);
    }
    next_retry
}

/// Fetches one batch and hands over its records as they arrive; what it failed to deliver
/// goes to backoff.
async fn fetch_batch(shared: Arc<Shared>, batch: u64, ids: Vec<DiamondId>, priorities: Vec<f32>) {
    let outcome = match &shared.endpoint {
        Endpoint::Server { base } => {
            stream_from_server(&shared, batch, base, &ids, &priorities).await
        }
        Endpoint::File { url } => match fetch_ranges(&shared, url, &ids).await {
            Ok(records) => {
                let received = records.iter().map(|(_, r)| r.len() as u64).sum();
                deliver(&shared, batch, records);
                Ok(received)
            }
            Err(e) => Err(e),
        },
    };
    let mut s = shared.state.lock().expect("fetch state");
    let Some(pos) = s.batches.iter().position(|(b, _, _)| *b == batch) else {
        // Cancelled meanwhile: its bookkeeping is already undone.
        return;
    };
    // What the request did not deliver: all of it if it failed, records that failed their
    // check, and (from a server that broke the framing) whatever did not come.
    let (_, failed, _) = s.batches.swap_remove(pos);
    if let Err(message) = &outcome {
        tracing::warn!("request for {} records failed: {message}", ids.len());
    }
    let received = outcome.ok().filter(|_| failed.is_empty());
    s.window.end(batch, received, Instant::now());
    shared.stats.in_flight.fetch_sub(1, Ordering::Relaxed);
    for id in &failed {
        s.in_flight.remove(id);
    }
    if !failed.is_empty() {
        shared.stats.errors.fetch_add(1, Ordering::Relaxed);
    }
    s.back_off(failed, Instant::now(), &shared.options);
    drop(s);
    shared.wake.notify_one();
}

/// Checks `records` of `batch` against the head and hands over those that pass, unless the
/// batch was cancelled meanwhile; each one handed over leaves the batch's list of records to
/// come (those that fail stay there, to be backed off when the batch ends).
fn deliver(shared: &Shared, batch: u64, records: Vec<(DiamondId, Vec<u8>)>) {
    // Those that fail stay in the batch's list of records to come.
    let (checked, _) = check_records(&shared.head, records);
    if checked.is_empty() {
        return;
    }
    let mut s = shared.state.lock().expect("fetch state");
    let State {
        batches,
        in_flight,
        wanted,
        backoff,
        delivered,
        ..
    } = &mut *s;
    let Some((_, remaining, _)) = batches.iter_mut().find(|(b, _, _)| *b == batch) else {
        return;
    };
    let tx = shared.results.lock().expect("results").clone();
    for (id, r) in checked {
        let Some(k) = remaining.iter().position(|&d| d == id) else {
            continue; // a duplicate: already handed over
        };
        remaining.swap_remove(k);
        in_flight.remove(&id);
        wanted.remove(&id);
        backoff.remove(&id);
        delivered.insert(id);
        shared.stats.records.fetch_add(1, Ordering::Relaxed);
        // The receiver is gone only when the fetcher is being dropped.
        let _ = tx.send((id, Ok(r)));
    }
}

/// `POST …/diamonds` with the ids and their priorities; the response (framing `CBDR`,
/// `u32 count`, then per id `u8 status`, `u32 length`, bytes, in the server's answer order:
/// most urgent first) is read as it streams in, each record handed over as soon as it is
/// complete. Returns the record bytes received.
async fn stream_from_server(
    shared: &Shared,
    batch: u64,
    base: &str,
    ids: &[DiamondId],
    priorities: &[f32],
) -> Result<u64, String> {
    let url = format!("{base}/diamonds");
    let body = batch_request_body(ids, priorities);
    let order = answer_ids(ids, priorities);
    shared.stats.requests.fetch_add(1, Ordering::Relaxed);
    let mut resp = shared
        .client
        .post(&url)
        .header(reqwest::header::CONTENT_TYPE, "application/json")
        .body(body)
        .send()
        .await
        .and_then(|r| r.error_for_status())
        .map_err(|e| e.to_string())?;
    let mut parser = StreamParser::new();
    let mut received = 0;
    loop {
        let chunk = resp.chunk().await.map_err(|e| e.to_string())?;
        let Some(chunk) = chunk else { break };
        shared
            .stats
            .bytes
            .fetch_add(chunk.len() as u64, Ordering::Relaxed);
        let first = parser.entries_parsed();
        let entries = parser.push(&chunk).map_err(|e| e.to_string())?;
        if first + entries.len() > order.len() {
            return Err(format!(
                "asked for {} records, the response holds more",
                order.len()
            ));
        }
        let mut records = Vec::with_capacity(entries.len());
        for (k, entry) in entries.into_iter().enumerate() {
            let id = order[first + k];
            match entry {
                OwnedEntry::Record(bytes) => {
                    received += bytes.len() as u64;
                    records.push((id, bytes));
                }
                OwnedEntry::NotStored => {
                    return Err(format!(
                        "server says {id} is not stored, the head says it is"
                    ));
                }
            }
        }
        deliver(shared, batch, records);
    }
    parser.finish().map_err(|e| e.to_string())?;
    if parser.entries_parsed() != order.len() {
        return Err(format!(
            "asked for {} records, response holds {}",
            order.len(),
            parser.entries_parsed()
        ));
    }
    Ok(received)
}

/// One range request covering `ids`' records (they were chosen close together).
async fn fetch_ranges(
    shared: &Shared,
    url: &str,
    ids: &[DiamondId],
) -> Result<Vec<(DiamondId, Vec<u8>)>, String> {
    let (span, ranges) = batch_span(&shared.head, ids);
    if span.is_empty() {
        // Only empty records: nothing to fetch.
        return Ok(ids.iter().map(|&id| (id, Vec::new())).collect());
    }
    shared.stats.requests.fetch_add(1, Ordering::Relaxed);
    let (body, total) = get_range(&shared.client, url, span.clone()).await?;
    let records = split_span(&shared.head, ids, span, ranges, &body, total)?;
    shared
        .stats
        .bytes
        .fetch_add(body.len() as u64, Ordering::Relaxed);
    Ok(records)
}
