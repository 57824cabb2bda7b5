//! The outermost middleware: counts every request in the metrics and writes its access log
//! line, and refuses request heads over the server's limits with the JSON error shape.
//!
//! A hand-written tower layer rather than `axum::middleware::from_fn`: that boxes a future
//! and clones the inner service on every request, which on the record endpoint costs about as
//! much as the answer itself.

use std::convert::Infallible;
use std::future::Future;
use std::pin::Pin;
use std::task::{Context, Poll, ready};
use std::time::Instant;

use axum::body::Body;
use axum::extract::Request;
use axum::http::{Method, StatusCode, Uri, Version};
use axum::response::{IntoResponse, Response};
use pin_project_lite::pin_project;
use tower_layer::Layer;
use tower_service::Service;

use crate::error::ApiError;
use crate::metrics::Endpoint;
use crate::state::AppState;

/// Wraps a service in [`Observe`].
#[derive(Clone)]
pub(crate) struct ObserveLayer {
    st: AppState,
}

impl ObserveLayer {
    pub(crate) fn new(st: AppState) -> Self {
        Self { st }
    }
}

impl<S> Layer<S> for ObserveLayer {
    type Service = Observe<S>;

    fn layer(&self, inner: S) -> Observe<S> {
        Observe {
            inner,
            st: self.st.clone(),
        }
    }
}

/// Counts and logs every request `inner` answers.
#[derive(Clone)]
pub(crate) struct Observe<S> {
    inner: S,
    st: AppState,
}

impl<S> Service<Request> for Observe<S>
where
    S: Service<Request, Response = Response, Error = Infallible>,
{
    type Response = Response;
    type Error = Infallible;
    type Future = ObserveFuture<S::Future>;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), Infallible>> {
        self.inner.poll_ready(cx)
    }

    fn call(&mut self, req: Request) -> Self::Future {
        let start = Instant::now();
        let early = too_large(&req);
        let endpoint = Endpoint::classify(req.method(), req.uri().path());
        // Cloning the method and URI only when the access log is on keeps the hot path free
        // of them when it is off.
        let log = tracing::enabled!(target: "cbdam_server::access", tracing::Level::INFO);
        let seen = log.then(|| (req.method().clone(), req.uri().clone(), req.version()));
        ObserveFuture {
            inner: match early {
                Some(_) => None,
                None => Some(self.inner.call(req)),
            },
            early,
            st: self.st.clone(),
            start,
            endpoint,
            seen,
        }
    }
}

pin_project! {
    /// [`Observe`]'s response future.
    pub(crate) struct ObserveFuture<F> {
        #[pin]
        inner: Option<F>,
        // The answer when the request was refused before reaching `inner`.
        early: Option<ApiError>,
        st: AppState,
        start: Instant,
        endpoint: Endpoint,
        seen: Option<(Method, Uri, Version)>,
    }
}

impl<F> Future for ObserveFuture<F>
where
    F: Future<Output = Result<Response, Infallible>>,
{
    type Output = Result<Response, Infallible>;

    fn poll(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Self::Output> {
        let this = self.project();
        let resp = match this.inner.as_pin_mut() {
            Some(inner) => {
                let Ok(resp) = ready!(inner.poll(cx));
                resp
            }
            None => this
                .early
                .take()
                .expect("polled after completion")
                .into_response(),
        };
        Poll::Ready(Ok(finish(
            this.st,
            *this.endpoint,
            *this.start,
            this.seen.take(),
            resp,
        )))
    }
}

fn finish(
    st: &AppState,
    endpoint: Endpoint,
    start: Instant,
    seen: Option<(Method, Uri, Version)>,
    mut resp: Response,
) -> Response {
    if resp.status() == StatusCode::REQUEST_TIMEOUT {
        // TimeoutLayer answers with an empty body; give it the same JSON shape as every
        // other error.
        resp = ApiError::Timeout(st.config().timeout.as_secs_f64()).into_response();
    }
    let bytes = http_body_size(resp.body());
    let elapsed = start.elapsed();
    st.metrics()
        .observe(endpoint, resp.status(), bytes, elapsed);
    if let Some((method, uri, version)) = seen {
        macro_rules! access {
            ($level:ident) => {
                tracing::$level!(
                    target: "cbdam_server::access",
                    %method,
                    path = %uri,
                    ?version,
                    status = resp.status().as_u16(),
                    bytes,
                    micros = elapsed.as_micros() as u64,
                )
            };
        }
        // Record hits are the bulk of the traffic (tens of thousands a second): a line each
        // at the default level would cost more than answering them. They log at debug
        // (`RUST_LOG=cbdam_server::access=debug`); every other request, and any record
        // request that fails, logs at info.
        let routine = matches!(endpoint, Endpoint::Diamond | Endpoint::Batch)
            && (resp.status().is_success() || resp.status() == StatusCode::NOT_MODIFIED);
        if routine {
            access!(debug);
        } else {
            access!(info);
        }
    }
    resp
}

/// Longest request target answered (longer: 414).
const MAX_URI: usize = 8 << 10;
/// Most header fields in a request (more: 431).
const MAX_HEADERS: usize = 100;
/// Most bytes of header names and values in a request (more: 431).
const MAX_HEADER_BYTES: usize = 8 << 10;

/// Refuses a request head over the limits. hyper refuses larger ones on its own, before any
/// handler, with an empty body: these limits are below its own (`conn::H1_MAX_BUF`,
/// `conn::H1_MAX_HEADERS`), so that every head a client plausibly sends gets the JSON shape.
fn too_large(req: &Request) -> Option<ApiError> {
    let uri = req.uri();
    let uri_len = uri.path_and_query().map_or(0, |p| p.as_str().len());
    if uri_len > MAX_URI {
        return Some(ApiError::UriTooLong(format!(
            "the request target is {uri_len} bytes, at most {MAX_URI} are read"
        )));
    }
    let h = req.headers();
    if h.len() > MAX_HEADERS {
        return Some(ApiError::HeadersTooLarge(format!(
            "{} header fields, at most {MAX_HEADERS} are read",
            h.len()
        )));
    }
    let bytes: usize = h.iter().map(|(k, v)| k.as_str().len() + v.len()).sum();
    if bytes > MAX_HEADER_BYTES {
        return Some(ApiError::HeadersTooLarge(format!(
            "{bytes} bytes of header fields, at most {MAX_HEADER_BYTES} are read"
        )));
    }
    None
}

fn http_body_size(b: &Body) -> u64 {
    use axum::body::HttpBody;
    b.size_hint().exact().unwrap_or(0)
}
