//! The endpoints and the middleware around them.

use std::borrow::Cow;
use std::ops::Range;
use std::sync::Arc;
use std::sync::atomic::Ordering::Relaxed;

use axum::Router;
use axum::body::Body;
use axum::extract::rejection::PathRejection;
use axum::extract::{Path, Request, State};
use axum::http::{HeaderMap, HeaderName, HeaderValue, Method, StatusCode, Uri, header};
use axum::response::Response;
use axum::routing::{get, post};
use bytes::Bytes;
use cbdam_codec::geometry::DiamondId;
use serde::Deserialize;
use tower_http::timeout::TimeoutLayer;

use crate::batch_body::{BatchBody, NOT_STORED};
use crate::conn::ConnHandle;
use crate::cors::cors_layer;
use crate::error::{ApiError, bad_path};
use crate::file_body::FileBody;
use crate::headers::{accepts_gzip, not_modified};
use crate::observe::ObserveLayer;
use crate::range::{RangeRequest, parse_range};
use crate::records::{RecordBuffer, read_records};
use crate::state::{AppState, ServedRepo, Source};

use cbdam_codec::repository::batch::answer_order;
/// The batch framing, defined once in the codec for both ends of the wire.
pub use cbdam_codec::repository::batch::{
    CONTENT_TYPE as BATCH_CONTENT_TYPE, MAGIC as BATCH_MAGIC, STATUS_NOT_STORED, STATUS_RECORD,
};

/// Records never change for a given URL while the same file is served under the same name.
const IMMUTABLE: &str = "public, max-age=31536000, immutable";
/// Meta and file may change if an operator serves a rebuilt file under the same name, so
/// caches revalidate them (cheaply: a 304 against their ETag).
const REVALIDATE: &str = "no-cache";
const OCTETS: &str = "application/octet-stream";
const JSON: &str = "application/json";

/// A static header value (`HeaderValue` consts would trip clippy's interior-mutability lint).
fn hv(s: &'static str) -> HeaderValue {
    HeaderValue::from_static(s)
}

pub(crate) fn router(state: AppState) -> Router {
    let cfg = state.config().clone();
    crate::examples::routes(crate::tiles::routes(Router::new()))
        .route("/v1/repos", get(list))
        .route("/v1/repos/{name}/meta", get(meta))
        .route("/v1/repos/{name}/file", get(file))
        .route("/v1/repos/{name}/diamonds/{id}", get(diamond))
        .route("/v1/repos/{name}/diamonds", post(batch))
        .route("/metrics", get(metrics))
        .route("/", get(index))
        .route("/viewer/{hash}/{file}", get(viewer_file))
        .fallback(not_found)
        .method_not_allowed_fallback(method_not_allowed)
        .layer(TimeoutLayer::with_status_code(
            StatusCode::REQUEST_TIMEOUT,
            cfg.timeout,
        ))
        .layer(cors_layer(&cfg.cors_origin))
        // Outermost, so that it sees (and counts) timeouts, CORS preflights and 404s too.
        .layer(ObserveLayer::new(state.clone()))
        .with_state(state)
}

async fn not_found(uri: Uri) -> ApiError {
    ApiError::NotFound(format!("no such endpoint {}", uri.path()))
}

async fn method_not_allowed(method: Method, uri: Uri) -> ApiError {
    ApiError::MethodNotAllowed(format!("{method} is not allowed on {}", uri.path()))
}

fn lookup<'a>(st: &'a AppState, name: &str) -> Result<&'a Arc<ServedRepo>, ApiError> {
    st.repo(name)
        .ok_or_else(|| ApiError::NotFound(format!("no repository named {name:?}")))
}

fn parse_id(s: &str) -> Result<DiamondId, ApiError> {
    s.parse()
        .map_err(|_| ApiError::BadRequest(format!("malformed diamond id {s:?} (want level-x-y)")))
}

fn find(r: &ServedRepo, id: DiamondId) -> Option<usize> {
    r.repo
        .head()
        .entries()
        .binary_search_by(|e| e.id.cmp(&id))
        .ok()
}

fn respond(status: StatusCode, headers: HeaderMap, body: impl Into<Body>) -> Response {
    let mut r = Response::new(body.into());
    *r.status_mut() = status;
    *r.headers_mut() = headers;
    r
}

fn headers<const N: usize>(pairs: [(HeaderName, HeaderValue); N]) -> HeaderMap {
    let mut h = HeaderMap::with_capacity(N + 4);
    for (k, v) in pairs {
        h.insert(k, v);
    }
    h
}

/// `GET /`: the repositories, each opening the viewer when it is served.
async fn index(State(st): State<AppState>) -> Response {
    respond(
        StatusCode::OK,
        headers([
            (header::CONTENT_TYPE, hv("text/html; charset=utf-8")),
            (header::CACHE_CONTROL, hv(REVALIDATE)),
        ]),
        st.inner.index.clone(),
    )
}

/// `GET /viewer/{hash}/{file}`: one of the viewer's files, immutable under its content hash,
/// gzip-compressed when the client accepts it.
async fn viewer_file(
    State(st): State<AppState>,
    path: Result<Path<(String, String)>, PathRejection>,
    req: Request,
) -> Result<Response, ApiError> {
    let Path((hash, file)) = path.map_err(bad_path)?;
    let Some(web) = st.config().web.as_deref() else {
        return Err(ApiError::NotFound(
            "the browser viewer is not served (start cbdam serve with --web DIR)".into(),
        ));
    };
    if hash != web.hash() {
        return Err(ApiError::NotFound(format!(
            "no viewer {hash} (this server's is /viewer/{}/)",
            web.hash()
        )));
    }
    let asset = web
        .get(&file)
        .ok_or_else(|| ApiError::NotFound(format!("the viewer has no file {file:?}")))?;
    let accepts_gzip = accepts_gzip(req.headers());
    let mut h = headers([
        (header::CONTENT_TYPE, hv(asset.content_type)),
        (header::CACHE_CONTROL, hv(IMMUTABLE)),
        (header::VARY, hv("accept-encoding")),
    ]);
    let body = match (&asset.gzip, accepts_gzip) {
        (Some(g), true) => {
            h.insert(header::CONTENT_ENCODING, hv("gzip"));
            g.clone()
        }
        _ => asset.raw.clone(),
    };
    Ok(respond(StatusCode::OK, h, body))
}

async fn list(State(st): State<AppState>) -> Response {
    respond(
        StatusCode::OK,
        headers([
            (header::CONTENT_TYPE, hv(JSON)),
            (header::CACHE_CONTROL, hv(REVALIDATE)),
        ]),
        st.inner.listing.clone(),
    )
}

async fn meta(
    State(st): State<AppState>,
    path: Result<Path<String>, PathRejection>,
    req: Request,
) -> Result<Response, ApiError> {
    let Path(name) = path.map_err(bad_path)?;
    let r = lookup(&st, &name)?;
    // A file rebuilt in place has another header than the one described.
    r.check_unchanged()?;
    let h = headers([
        (header::ETAG, r.meta_etag.clone()),
        (header::CACHE_CONTROL, hv(REVALIDATE)),
    ]);
    if not_modified(req.headers(), &r.meta_etag) {
        return Ok(respond(StatusCode::NOT_MODIFIED, h, Body::empty()));
    }
    let mut h = h;
    h.insert(header::CONTENT_TYPE, hv(JSON));
    Ok(respond(StatusCode::OK, h, r.meta.clone()))
}

async fn diamond(
    State(st): State<AppState>,
    path: Result<Path<(String, String)>, PathRejection>,
    req: Request,
) -> Result<Response, ApiError> {
    let Path((name, id)) = path.map_err(bad_path)?;
    let r = lookup(&st, &name)?;
    let id = parse_id(&id)?;
    let i = find(r, id).ok_or_else(|| {
        ApiError::NotFound(format!("diamond {id} is not stored in repository {name:?}"))
    })?;
    // Before any answer, a 304 included: a file rebuilt in place no longer holds what the
    // ETag names.
    r.check_unchanged()?;
    let etag = r.record_etag(i);
    if not_modified(req.headers(), &etag) {
        return Ok(respond(
            StatusCode::NOT_MODIFIED,
            headers([(header::ETAG, etag), (header::CACHE_CONTROL, hv(IMMUTABLE))]),
            Body::empty(),
        ));
    }
    let mut bytes = Vec::new();
    read_records(&st, r, &[i], &mut RecordBuffer::default(), |_, b| {
        bytes = b.to_vec()
    })?;
    st.metrics().add_records(1);
    Ok(respond(
        StatusCode::OK,
        headers([
            (header::CONTENT_TYPE, hv(OCTETS)),
            (header::ETAG, etag),
            (header::CACHE_CONTROL, hv(IMMUTABLE)),
        ]),
        bytes,
    ))
}

/// How far past `--max-body` a request body is read (and dropped) before the 413.
const DRAIN_BYTES: usize = 16 << 20;

/// The request body, at most `max` bytes. A longer one is read on to its end (at most
/// [`DRAIN_BYTES`] more, within `--timeout`) and dropped before the 413 is sent: an HTTP/2
/// client still sending when the answer came would otherwise see its stream reset, not the
/// 413.
async fn read_body(mut body: Body, max: usize) -> Result<Bytes, ApiError> {
    use http_body::Body as _;
    let mut kept = Vec::new();
    let mut total = 0usize;
    while let Some(frame) =
        std::future::poll_fn(|cx| std::pin::Pin::new(&mut body).poll_frame(cx)).await
    {
        let frame =
            frame.map_err(|e| ApiError::BadRequest(format!("reading the request body: {e}")))?;
        if let Ok(data) = frame.into_data() {
            total = total.saturating_add(data.len());
            if total <= max {
                kept.extend_from_slice(&data);
            } else if total > max.saturating_add(DRAIN_BYTES) {
                break;
            }
        }
    }
    if total > max {
        return Err(ApiError::TooLarge(format!(
            "request body is over {max} bytes"
        )));
    }
    Ok(Bytes::from(kept))
}

/// `POST /v1/repos/{name}/diamonds` body. Ids are borrowed from the body when they contain no
/// JSON escapes, which is always for well-formed ids. `priorities`, if given, has one number
/// per id (the client's screen error): the answer comes highest first
/// ([`batch::answer_order`](cbdam_codec::repository::batch::answer_order)).
#[derive(Deserialize)]
struct BatchRequest<'a> {
    #[serde(borrow)]
    ids: Vec<Cow<'a, str>>,
    #[serde(default)]
    priorities: Option<Vec<f32>>,
}

async fn batch(
    State(st): State<AppState>,
    path: Result<Path<String>, PathRejection>,
    http: Request,
) -> Result<Response, ApiError> {
    let Path(name) = path.map_err(bad_path)?;
    let r = lookup(&st, &name)?;
    let cfg = st.config();
    let conn = http.extensions().get::<ConnHandle>().cloned();
    let body = read_body(http.into_body(), cfg.max_body).await?;
    let req: BatchRequest = serde_json::from_slice(&body).map_err(|e| {
        ApiError::BadRequest(format!(
            "malformed batch request: {e} (want {{\"ids\": [\"level-x-y\", ...], \"priorities\": [number, ...] (optional)}})"
        ))
    })?;
    if req.ids.len() > cfg.max_batch {
        return Err(ApiError::TooLarge(format!(
            "{} ids in one batch, at most {} allowed",
            req.ids.len(),
            cfg.max_batch
        )));
    }
    let order = match &req.priorities {
        None => (0..req.ids.len()).collect(),
        Some(p) if p.len() != req.ids.len() => {
            return Err(ApiError::BadRequest(format!(
                "{} priorities for {} ids (want one per id)",
                p.len(),
                req.ids.len()
            )));
        }
        Some(p) => answer_order(p),
    };
    // Resolve and check every record before sending anything, so a malformed id or a damaged
    // record fails the request whole, and so the body can be sized exactly.
    let mut slots: Vec<Option<usize>> = Vec::with_capacity(req.ids.len());
    for (k, s) in req.ids.iter().enumerate() {
        let id = s.parse::<DiamondId>().map_err(|_| {
            ApiError::BadRequest(format!(
                "malformed diamond id {s:?} at position {k} (want level-x-y)"
            ))
        })?;
        slots.push(find(r, id));
    }
    // `max_batch` is a usize from the command line; the count field is u32.
    u32::try_from(slots.len())
        .map_err(|_| ApiError::TooLarge("more than 2^32 ids in one batch".into()))?;
    r.check_unchanged()?;
    // Records not checked before are read and checked now, so that a damaged one fails the
    // whole request; the body reads each again as it sends it, and checks the file's identity
    // after each read.
    let unchecked: Vec<usize> = slots
        .iter()
        .flatten()
        .copied()
        .filter(|&i| !r.verified[i].load(Relaxed))
        .collect();
    if !unchecked.is_empty() {
        read_records(&st, r, &unchecked, &mut RecordBuffer::default(), |_, _| {})?;
    }
    // Index positions fit in u32 (index lengths and counts are u32).
    let entries = order
        .into_iter()
        .map(|k| slots[k].map_or(NOT_STORED, |i| i as u32))
        .collect();
    // The records are counted as the body hands them over (`BatchBody`).
    Ok(respond(
        StatusCode::OK,
        headers([
            (
                header::CONTENT_TYPE,
                HeaderValue::from_static(BATCH_CONTENT_TYPE),
            ),
            (header::CACHE_CONTROL, HeaderValue::from_static("no-store")),
        ]),
        // Streamed in answer order, most urgent first; dropped unsent if the client goes.
        Body::new(BatchBody::new(st.clone(), Arc::clone(r), entries, conn)),
    ))
}

/// A byte range of a repository held in memory, owned by the repository's `Arc`: the body is
/// its bytes themselves, never copied.
struct FileSlice {
    repo: Arc<ServedRepo>,
    range: Range<usize>,
}

impl AsRef<[u8]> for FileSlice {
    fn as_ref(&self) -> &[u8] {
        &self.repo.repo.as_bytes()[self.range.clone()]
    }
}

async fn file(
    State(st): State<AppState>,
    path: Result<Path<String>, PathRejection>,
    req: Request,
) -> Result<Response, ApiError> {
    let Path(name) = path.map_err(bad_path)?;
    let r = lookup(&st, &name)?;
    r.check_unchanged()?;
    let len = r.repo.head().file_len();
    let mut h = headers([
        (header::ETAG, r.file_etag.clone()),
        (header::CACHE_CONTROL, hv(REVALIDATE)),
        (header::ACCEPT_RANGES, HeaderValue::from_static("bytes")),
    ]);
    if not_modified(req.headers(), &r.file_etag) {
        return Ok(respond(StatusCode::NOT_MODIFIED, h, Body::empty()));
    }
    let range = req
        .headers()
        .get(header::RANGE)
        .and_then(|v| v.to_str().ok());
    // If-Range: the range applies only while the client's validator is current (strong
    // comparison); a stale validator or an HTTP date (we give no Last-Modified) gets the whole
    // file.
    let range = match req.headers().get(header::IF_RANGE) {
        Some(v) if v != r.file_etag => None,
        _ => range,
    };
    h.insert(header::CONTENT_TYPE, hv(OCTETS));
    let (status, range) = match parse_range(range, len) {
        RangeRequest::Full => (StatusCode::OK, 0..len),
        RangeRequest::Partial(range) => {
            let cr = format!("bytes {}-{}/{len}", range.start, range.end - 1);
            h.insert(
                header::CONTENT_RANGE,
                HeaderValue::from_str(&cr).expect("ASCII"),
            );
            (StatusCode::PARTIAL_CONTENT, range)
        }
        RangeRequest::Unsatisfiable => return Err(ApiError::RangeNotSatisfiable(len)),
    };
    let body = match r.source {
        // An in-memory repository's bytes themselves, not a copy.
        Source::Memory => Body::from(Bytes::from_owner(FileSlice {
            repo: Arc::clone(r),
            range: range.start as usize..range.end as usize,
        })),
        // Read a chunk at a time as the client takes them.
        Source::File { .. } => Body::new(FileBody::new(
            Arc::clone(r),
            range,
            Arc::clone(&st.inner.answer_memory),
            req.extensions().get::<ConnHandle>().cloned(),
        )),
    };
    Ok(respond(status, h, body))
}

async fn metrics(State(st): State<AppState>) -> Response {
    respond(
        StatusCode::OK,
        headers([
            (
                header::CONTENT_TYPE,
                HeaderValue::from_static("text/plain; version=0.0.4; charset=utf-8"),
            ),
            (header::CACHE_CONTROL, HeaderValue::from_static("no-store")),
        ]),
        st.metrics().render() + &st.inner.answer_memory.render(),
    )
}
