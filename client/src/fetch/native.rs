//! The desktop transport of the [`fetch`](super)er: a background tokio runtime sending requests
//! with reqwest. What to fetch next, the backoff and the batch framing are the portable parent
//! module's; this module only moves bytes.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use cbdam_codec::CodecError;
use cbdam_codec::geometry::DiamondId;
use cbdam_codec::repository::{HEADER_FETCH_LEN, RepositoryHead, header_len, required_head_len};
use tokio::sync::Notify;
use tokio::task::AbortHandle;
use web_time::Instant;

use super::{
    Endpoint, FetchOptions, FetchStats, Fetched, Pending, RemoteError, State, classify, http_error,
    list_url, next_batch, parse_frames, record_range, single_repository,
};

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
            .timeout(options.timeout)
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
    /// are forgotten, and requests none of whose records are wanted any more are aborted.
    pub fn want(&self, wanted: impl IntoIterator<Item = (DiamondId, f32)>) {
        let mut s = self.shared.state.lock().expect("fetch state");
        let delivered = std::mem::take(&mut s.delivered);
        s.wanted = wanted
            .into_iter()
            .filter(|(id, _)| self.shared.head.position(*id).is_some() && !delivered.contains(id))
            .map(|(id, priority)| (id, Pending { priority }))
            .collect();
        s.delivered = delivered;
        let State {
            wanted,
            batches,
            in_flight,
            ..
        } = &mut *s;
        batches.retain(|(_, ids, handle)| {
            if ids.iter().any(|id| wanted.contains_key(id)) {
                return true;
            }
            handle.abort();
            for id in ids {
                in_flight.remove(id);
            }
            self.shared.stats.cancelled.fetch_add(1, Ordering::Relaxed);
            self.shared.stats.in_flight.fetch_sub(1, Ordering::Relaxed);
            false
        });
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

/// GETs `range` of `url`; returns the body and the total file length from `Content-Range`. A
/// range running past the end of the file gets the bytes up to the end (what a server answers);
/// any other length is an error.
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
    if resp.status() != reqwest::StatusCode::PARTIAL_CONTENT {
        return Err(format!(
            "asked for bytes {}..{}, got HTTP {} (does the server honour Range requests?)",
            range.start,
            range.end,
            resp.status()
        ));
    }
    let total = resp
        .headers()
        .get(reqwest::header::CONTENT_RANGE)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.rsplit_once('/'))
        .and_then(|(_, total)| total.parse::<u64>().ok())
        .ok_or("206 response without a Content-Range total")?;
    let body = resp.bytes().await.map_err(|e| e.to_string())?;
    let end = range.end.min(total.max(range.start));
    if body.len() as u64 != end - range.start {
        return Err(format!(
            "asked for {} bytes, got {}",
            end - range.start,
            body.len()
        ));
    }
    Ok((body.to_vec(), total))
}

/// The head and how many range requests it took (2, or 3 for a header longer than the first
/// fetch).
async fn fetch_head(
    client: &reqwest::Client,
    url: &str,
) -> Result<(RepositoryHead, u64), RemoteError> {
    // A version-3 header is usually shorter than HEADER_FETCH_LEN, and so can be the whole
    // file: a server answers a range past the end with what there is. A long CRS definition
    // makes it longer: then a second request fetches the rest.
    let (mut header, file_len) = get_range(client, url, 0..HEADER_FETCH_LEN as u64)
        .await
        .map_err(|e| http_error(url, e))?;
    let repo_error = |source| RemoteError::Repository {
        url: url.to_owned(),
        source,
    };
    let len = header_len(&header).map_err(repo_error)?;
    let mut requests = 2;
    if len > header.len() && len as u64 <= file_len {
        requests += 1;
        header = get_range(client, url, 0..len as u64)
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
    let (head, _) = get_range(client, url, 0..head_len)
        .await
        .map_err(|e| http_error(url, e))?;
    Ok((
        RepositoryHead::parse(&head, file_len).map_err(repo_error)?,
        requests,
    ))
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
    while s.batches.len() < shared.options.max_in_flight && !ready.is_empty() {
        let ids = next_batch(&mut ready, &shared.endpoint, &shared.head, &shared.options);
        for id in &ids {
            s.in_flight.insert(*id);
        }
        let batch = s.next_batch;
        s.next_batch += 1;
        let task = tokio::spawn(fetch_batch(shared.clone(), batch, ids.clone()));
        s.batches.push((batch, ids, task.abort_handle()));
        shared.stats.in_flight.fetch_add(1, Ordering::Relaxed);
    }
    next_retry
}

/// Fetches one batch and hands over its records; failures go to backoff.
async fn fetch_batch(shared: Arc<Shared>, batch: u64, ids: Vec<DiamondId>) {
    let outcome = match &shared.endpoint {
        Endpoint::Server { base } => fetch_from_server(&shared, base, &ids).await,
        Endpoint::File { url } => fetch_ranges(&shared, url, &ids).await,
    };
    let mut delivered = Vec::new();
    let mut failed = Vec::new();
    match outcome {
        Ok(records) => {
            for (id, bytes) in records {
                let i = shared.head.position(id).expect("stored");
                match shared.head.check_record(i, &bytes) {
                    Ok(()) => delivered.push((id, Ok(Arc::from(bytes)))),
                    Err(e) => {
                        tracing::warn!("record {id} rejected: {e}");
                        failed.push(id);
                    }
                }
            }
        }
        Err(message) => {
            tracing::warn!("request for {} records failed: {message}", ids.len());
            failed.extend(ids.iter().copied());
        }
    }
    let mut s = shared.state.lock().expect("fetch state");
    let Some(pos) = s.batches.iter().position(|(b, _, _)| *b == batch) else {
        // Cancelled meanwhile: its bookkeeping is already undone.
        return;
    };
    s.batches.swap_remove(pos);
    shared.stats.in_flight.fetch_sub(1, Ordering::Relaxed);
    for id in &ids {
        s.in_flight.remove(id);
    }
    if !failed.is_empty() {
        shared.stats.errors.fetch_add(1, Ordering::Relaxed);
    }
    s.back_off(failed, Instant::now(), &shared.options);
    let tx = shared.results.lock().expect("results").clone();
    for (id, r) in delivered {
        s.wanted.remove(&id);
        s.backoff.remove(&id);
        s.delivered.insert(id);
        shared.stats.records.fetch_add(1, Ordering::Relaxed);
        // The receiver is gone only when the fetcher is being dropped.
        let _ = tx.send((id, r));
    }
    drop(s);
    shared.wake.notify_one();
}

/// `POST …/diamonds`, framing `CBDR`, `u32 count`, then per id `u8 status`, `u32 length`, bytes.
async fn fetch_from_server(
    shared: &Shared,
    base: &str,
    ids: &[DiamondId],
) -> Result<Vec<(DiamondId, Vec<u8>)>, String> {
    let url = format!("{base}/diamonds");
    let names: Vec<String> = ids.iter().map(ToString::to_string).collect();
    let body = serde_json::json!({ "ids": names }).to_string();
    shared.stats.requests.fetch_add(1, Ordering::Relaxed);
    let resp = shared
        .client
        .post(&url)
        .header(reqwest::header::CONTENT_TYPE, "application/json")
        .body(body)
        .send()
        .await
        .and_then(|r| r.error_for_status())
        .map_err(|e| e.to_string())?;
    let bytes = resp.bytes().await.map_err(|e| e.to_string())?;
    shared
        .stats
        .bytes
        .fetch_add(bytes.len() as u64, Ordering::Relaxed);
    parse_frames(&bytes, ids)
}

/// One range request covering `ids`' records (they were chosen close together).
async fn fetch_ranges(
    shared: &Shared,
    url: &str,
    ids: &[DiamondId],
) -> Result<Vec<(DiamondId, Vec<u8>)>, String> {
    let ranges: Vec<_> = ids
        .iter()
        .map(|&id| record_range(&shared.head, id))
        .collect();
    let lo = ranges
        .iter()
        .map(|r| r.start)
        .min()
        .expect("non-empty batch");
    let hi = ranges.iter().map(|r| r.end).max().expect("non-empty batch");
    if lo == hi {
        // Only empty records: nothing to fetch.
        return Ok(ids.iter().map(|&id| (id, Vec::new())).collect());
    }
    shared.stats.requests.fetch_add(1, Ordering::Relaxed);
    let (body, total) = get_range(&shared.client, url, lo..hi).await?;
    if total != shared.head.file_len() {
        return Err(format!(
            "the file is now {total} bytes, the head says {}: it changed on the server",
            shared.head.file_len()
        ));
    }
    // The head's records lie inside the file, so only a server that cut the range short gives
    // fewer bytes; the slicing below needs all of them.
    if body.len() as u64 != hi - lo {
        return Err(format!("asked for {} bytes, got {}", hi - lo, body.len()));
    }
    shared
        .stats
        .bytes
        .fetch_add(body.len() as u64, Ordering::Relaxed);
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
