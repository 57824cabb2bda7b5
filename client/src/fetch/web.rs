//! The browser's transport of the [`fetch`](super)er: the page's `fetch`, awaited on its event
//! loop. A page has one thread and must never block it, so there is no scheduler task: requests
//! start when the wanted set changes ([`RemoteFetcher::want`]), when one finishes, and on every
//! [`RemoteFetcher::poll`] (once a frame: backoffs that expired). What to fetch next, the
//! backoff, the byte window, cancellation, the range and record checks and the batch framing are
//! the portable parent module's (one policy for the desktop and the page);
//! this module only moves bytes.
//!
//! A static host on another origin must allow the page's origin (CORS) and expose
//! `Content-Range` (`Access-Control-Expose-Headers`), or range responses cannot be checked.

use std::cell::RefCell;
use std::rc::Rc;
use std::sync::Arc;

use cbdam_codec::geometry::DiamondId;
use cbdam_codec::repository::RepositoryHead;
use js_sys::Uint8Array;
use wasm_bindgen::{JsCast, JsValue};
use wasm_bindgen_futures::JsFuture;
use web_sys::{AbortController, Request, RequestInit, Response};
use web_time::Instant;

use super::{
    Endpoint, FetchOptions, FetchStats, Fetched, RemoteError, State, answer_ids,
    batch_request_body, batch_span, check_records, classify, expect_partial, fetch_head_with,
    http_error, list_url, next_batch, parse_frames, range_total, record_bytes, single_repository,
    split_span,
};

struct Shared {
    state: RefCell<State<AbortController>>,
    stats: RefCell<FetchStats>,
    head: Arc<RepositoryHead>,
    /// The bytes the head was parsed from (for workers that decode: [`RemoteFetcher::head_bytes`]).
    head_bytes: Arc<[u8]>,
    endpoint: Endpoint,
    options: FetchOptions,
    /// Records checked and waiting for [`RemoteFetcher::poll`].
    arrived: RefCell<Vec<Fetched>>,
}

/// Fetches records of one remote repository with the page's `fetch`.
pub struct RemoteFetcher {
    shared: Rc<Shared>,
}

impl std::fmt::Debug for RemoteFetcher {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RemoteFetcher")
            .field("endpoint", &self.shared.endpoint)
            .finish_non_exhaustive()
    }
}

impl RemoteFetcher {
    /// Connects to a repository and fetches its head; awaited before the first frame.
    ///
    /// `url` (absolute) is either a repository of `cbdam serve`
    /// (`http://host:port/v1/repos/NAME`), a `cbdam serve` root that serves exactly one
    /// repository, or the URL of a repository file on any server that honours range requests.
    pub async fn connect(url: &str, options: FetchOptions) -> Result<Self, RemoteError> {
        let endpoint = match classify(url)? {
            Some(endpoint) => endpoint,
            None => {
                let list = list_url(url);
                let (status, body) = send(&list, "GET", None, None, None)
                    .await
                    .map_err(|e| http_error(&list, e))?;
                if !(200..300).contains(&status) {
                    return Err(http_error(&list, format!("HTTP {status}")));
                }
                single_repository(url, &body)?
            }
        };
        let file_url = endpoint.file_url();
        let (head, head_bytes) =
            fetch_head_with(&file_url, |range| get_range(file_url.clone(), range)).await?;
        let shared = Rc::new(Shared {
            state: RefCell::new(State::default()),
            // The head took two requests.
            stats: RefCell::new(FetchStats {
                requests: 2,
                ..FetchStats::default()
            }),
            head: Arc::new(head),
            head_bytes: head_bytes.into(),
            endpoint,
            options,
            arrived: RefCell::new(Vec::new()),
        });
        Ok(Self { shared })
    }

    /// The repository's head.
    pub fn head(&self) -> &Arc<RepositoryHead> {
        &self.shared.head
    }

    /// The bytes the head was read from (the file's first bytes, at least its head): what a
    /// decode worker builds its decoder from ([`crate::refine::Refiner::worker_context`]).
    pub fn head_bytes(&self) -> &[u8] {
        &self.shared.head_bytes
    }

    /// Replaces the set of wanted records (higher priority first). Queued records not in the set
    /// are forgotten, and requests not worth finishing any more (none of their records wanted,
    /// or [`FetchOptions::cancel_waste`] of their bytes unwanted) are aborted, their records that
    /// are still wanted queued again.
    pub fn want(&self, wanted: impl IntoIterator<Item = (DiamondId, f32)>) {
        {
            let mut s = self.shared.state.borrow_mut();
            s.set_wanted(&self.shared.head, wanted);
            let (head, options) = (&self.shared.head, &self.shared.options);
            let abort = |c: &AbortController| c.abort();
            let (cancelled, requeued) = s.cancel_unwanted(head, options, abort);
            let mut stats = self.shared.stats.borrow_mut();
            stats.cancelled += cancelled;
            stats.requeued += requeued;
            stats.in_flight -= cancelled;
        }
        start_batches(&self.shared);
    }

    /// Takes the records that arrived since the last call; never blocks. Also starts the
    /// requests whose backoff expired.
    pub fn poll(&self) -> Vec<Fetched> {
        start_batches(&self.shared);
        let got = std::mem::take(&mut *self.shared.arrived.borrow_mut());
        if !got.is_empty() {
            let mut s = self.shared.state.borrow_mut();
            for (id, _) in &got {
                s.delivered.remove(id);
            }
        }
        got
    }

    /// Whether `id` is queued or being fetched.
    pub fn is_pending(&self, id: DiamondId) -> bool {
        let s = self.shared.state.borrow();
        s.wanted.contains_key(&id) || s.in_flight.contains(&id)
    }

    /// The counters so far.
    pub fn stats(&self) -> FetchStats {
        *self.shared.stats.borrow()
    }
}

impl Drop for RemoteFetcher {
    fn drop(&mut self) {
        let mut s = self.shared.state.borrow_mut();
        s.shutdown = true;
        for (_, _, controller) in s.batches.drain(..) {
            controller.abort();
        }
    }
}

/// Starts requests while slots are free (the most urgent wanted records that are neither in
/// flight nor backing off).
fn start_batches(shared: &Rc<Shared>) {
    let mut s = shared.state.borrow_mut();
    if s.shutdown {
        return;
    }
    let (mut ready, _) = s.ready(Instant::now());
    while s.may_start(&shared.options, &shared.endpoint) && !ready.is_empty() {
        let max_bytes = s.batch_bytes(&shared.options);
        let ids = next_batch(
            &mut ready,
            &shared.endpoint,
            &shared.head,
            &shared.options,
            max_bytes,
        );
        let Ok(controller) = AbortController::new() else {
            // Without an AbortController (very old browsers) nothing can be fetched safely.
            break;
        };
        for id in &ids {
            s.in_flight.insert(*id);
        }
        let priorities: Vec<f32> = ids
            .iter()
            .map(|id| s.wanted.get(id).map_or(0.0, |p| p.priority))
            .collect();
        let batch = s.next_batch;
        s.next_batch += 1;
        let signal = controller.signal();
        abort_after(&controller, shared.options.timeout);
        s.window
            .start(batch, record_bytes(&shared.head, &ids), Instant::now());
        s.batches.push((batch, ids.clone(), controller));
        {
            let mut stats = shared.stats.borrow_mut();
            stats.in_flight += 1;
            stats.requests += 1;
        }
        wasm_bindgen_futures::spawn_local(fetch_batch(
            shared.clone(),
            batch,
            ids,
            priorities,
            signal,
        ));
    }
}

/// Aborts the request of `controller` after `timeout` (a no-op once it finished).
fn abort_after(controller: &AbortController, timeout: std::time::Duration) {
    let Some(window) = web_sys::window() else {
        return;
    };
    let controller = controller.clone();
    let abort = wasm_bindgen::closure::Closure::once_into_js(move || controller.abort());
    let ms = i32::try_from(timeout.as_millis()).unwrap_or(i32::MAX);
    let _ = window.set_timeout_with_callback_and_timeout_and_arguments_0(abort.unchecked_ref(), ms);
}

/// Fetches one batch and hands over its records; failures go to backoff.
async fn fetch_batch(
    shared: Rc<Shared>,
    batch: u64,
    ids: Vec<DiamondId>,
    priorities: Vec<f32>,
    signal: web_sys::AbortSignal,
) {
    let outcome = match &shared.endpoint {
        Endpoint::Server { base } => {
            fetch_from_server(&shared, base, &ids, &priorities, &signal).await
        }
        Endpoint::File { url } => fetch_ranges(&shared, url, &ids, &signal).await,
    };
    let (delivered, failed) = match outcome {
        Ok(records) => check_records(&shared.head, records),
        Err(message) => {
            tracing::warn!("request for {} records failed: {message}", ids.len());
            (Vec::new(), ids.clone())
        }
    };
    {
        let mut s = shared.state.borrow_mut();
        let Some(pos) = s.batches.iter().position(|(b, _, _)| *b == batch) else {
            // Cancelled meanwhile: its bookkeeping is already undone.
            return;
        };
        s.batches.swap_remove(pos);
        // A rate sample only from a request that delivered everything it carried.
        let received = failed
            .is_empty()
            .then(|| delivered.iter().map(|(_, r)| r.len() as u64).sum());
        s.window.end(batch, received, Instant::now());
        let mut stats = shared.stats.borrow_mut();
        stats.in_flight -= 1;
        for id in &ids {
            s.in_flight.remove(id);
        }
        if !failed.is_empty() {
            stats.errors += 1;
        }
        s.back_off(failed, Instant::now(), &shared.options);
        let mut arrived = shared.arrived.borrow_mut();
        for (id, bytes) in delivered {
            s.wanted.remove(&id);
            s.backoff.remove(&id);
            s.delivered.insert(id);
            stats.records += 1;
            arrived.push((id, Ok(bytes)));
        }
    }
    start_batches(&shared);
}

/// `POST …/diamonds` with the ids and their priorities; the response's framing is parsed by
/// [`parse_frames`], its entries in the server's answer order (most urgent first).
async fn fetch_from_server(
    shared: &Shared,
    base: &str,
    ids: &[DiamondId],
    priorities: &[f32],
    signal: &web_sys::AbortSignal,
) -> Result<Vec<(DiamondId, Vec<u8>)>, String> {
    let url = format!("{base}/diamonds");
    let body = batch_request_body(ids, priorities);
    let (status, bytes) = send(
        &url,
        "POST",
        Some(("Content-Type", "application/json")),
        Some(&body),
        Some(signal),
    )
    .await?;
    if !(200..300).contains(&status) {
        return Err(format!("{url}: HTTP {status}"));
    }
    shared.stats.borrow_mut().bytes += bytes.len() as u64;
    parse_frames(&bytes, &answer_ids(ids, priorities))
}

/// One range request covering `ids`' records (they were chosen close together).
async fn fetch_ranges(
    shared: &Shared,
    url: &str,
    ids: &[DiamondId],
    signal: &web_sys::AbortSignal,
) -> Result<Vec<(DiamondId, Vec<u8>)>, String> {
    let (span, ranges) = batch_span(&shared.head, ids);
    if span.is_empty() {
        // Only empty records: nothing to fetch.
        return Ok(ids.iter().map(|&id| (id, Vec::new())).collect());
    }
    let (body, total) = range_request(url, span.clone(), Some(signal)).await?;
    let records = split_span(&shared.head, ids, span, ranges, &body, total)?;
    shared.stats.borrow_mut().bytes += body.len() as u64;
    Ok(records)
}

/// GETs `range` of `url` (the head's reads, which have no abort signal).
async fn get_range(url: String, range: std::ops::Range<u64>) -> Result<(Vec<u8>, u64), String> {
    range_request(&url, range, None).await
}

/// GETs `range` of `url`; returns the body and the file's total length.
async fn range_request(
    url: &str,
    range: std::ops::Range<u64>,
    signal: Option<&web_sys::AbortSignal>,
) -> Result<(Vec<u8>, u64), String> {
    let value = format!("bytes={}-{}", range.start, range.end - 1);
    let response = request(url, "GET", Some(("Range", &value)), None, signal).await?;
    expect_partial(&range, response.status())?;
    let content_range = response.headers().get("Content-Range").ok().flatten();
    let body = body_bytes(&response).await?;
    let total = range_total(&range, content_range.as_deref(), body.len())?;
    Ok((body, total))
}

/// Sends a request and reads the whole body; returns the status and the body.
async fn send(
    url: &str,
    method: &str,
    header: Option<(&str, &str)>,
    body: Option<&str>,
    signal: Option<&web_sys::AbortSignal>,
) -> Result<(u16, Vec<u8>), String> {
    let response = request(url, method, header, body, signal).await?;
    let status = response.status();
    Ok((status, body_bytes(&response).await?))
}

/// Starts a request and awaits its response headers.
async fn request(
    url: &str,
    method: &str,
    header: Option<(&str, &str)>,
    body: Option<&str>,
    signal: Option<&web_sys::AbortSignal>,
) -> Result<Response, String> {
    let init = RequestInit::new();
    init.set_method(method);
    if let Some(body) = body {
        init.set_body(&JsValue::from_str(body));
    }
    if let Some(signal) = signal {
        init.set_signal(Some(signal));
    }
    let request = Request::new_with_str_and_init(url, &init).map_err(js_error)?;
    if let Some((name, value)) = header {
        request.headers().set(name, value).map_err(js_error)?;
    }
    let window = web_sys::window().ok_or("no window (not in a page)")?;
    let response = JsFuture::from(window.fetch_with_request(&request))
        .await
        .map_err(js_error)?;
    response
        .dyn_into::<Response>()
        .map_err(|_| "fetch did not answer a Response".to_owned())
}

/// The whole body of `response`.
async fn body_bytes(response: &Response) -> Result<Vec<u8>, String> {
    let buffer = JsFuture::from(response.array_buffer().map_err(js_error)?)
        .await
        .map_err(js_error)?;
    Ok(Uint8Array::new(&buffer).to_vec())
}

/// A JavaScript exception as text.
fn js_error(e: JsValue) -> String {
    e.as_string()
        .or_else(|| {
            e.dyn_ref::<js_sys::Error>()
                .map(|e| String::from(e.message()))
        })
        .unwrap_or_else(|| format!("{e:?}"))
}
