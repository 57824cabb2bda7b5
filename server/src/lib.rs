//! The HTTP server of diamond residuals (`cbdam serve`).
//!
//! Serves per-diamond records of one or more memory-mapped repositories over HTTP/1.1 and
//! HTTP/2 cleartext (prior knowledge). The endpoints and the batch framing are specified in
//! `docs/HTTP-API.md`:
//!
//! - `GET /v1/repos`: the repositories served.
//! - `GET /v1/repos/{name}/meta`: a repository's header as JSON ([`describe::describe`] plus
//!   links).
//! - `GET /v1/repos/{name}/diamonds/{l-x-y}`: one record's bytes.
//! - `POST /v1/repos/{name}/diamonds`: many records in one framed body.
//! - `GET /v1/repos/{name}/file`: the repository file itself, with range requests.
//! - `GET /v1/repos/{name}/{terrarium|terrain-rgb}/{z}/{x}/{y}.{png|webp}`, `…/tiles.json`,
//!   `…/quantized-mesh/{z}/{x}/{y}.terrain`, `…/quantized-mesh/layer.json`: web-map tiles
//!   ([`tiles`], `docs/WEB-MAPS.md`).
//! - `GET /metrics`: Prometheus counters.
//! - `GET /`: a page listing the repositories; with `--web DIR`, each opens the browser viewer,
//!   whose files are served under `/viewer/{hash}/` ([`web`]).
//!
//! [`app`] builds the router, [`run`] serves it on a listener until a shutdown future
//! completes.
//!
//! # Performance
//!
//! A single-record `GET` is the hot path (a client refining a view asks for many small
//! records). It formats nothing: each record's ETag is sliced from one buffer built at startup,
//! its body is one positioned read of the file, checked against the record's CRC. The metrics
//! and the access log are one hand-written layer, and successful record requests log at debug,
//! so the default `info` level does not write a line per record. `cbdam bench serve` measures
//! records/s, latency and CPU time per request.
//!
//! # A served file rebuilt while the server runs
//!
//! The server holds each repository file open and reads it with positioned reads (never through
//! a memory map, so nothing done to the file can crash it):
//!
//! - **Replaced by a rename** (a new file written next to it and renamed over it, which is what
//!   `cbdam build` does): the server keeps serving the file it opened, unchanged and under the
//!   same ETags, until it is restarted; then it serves the new one.
//! - **Overwritten or truncated in place** (`cp` onto it, a build writing into it): every
//!   request that reads the repository (meta, records, batches, the file, revalidations
//!   included) is answered 500 with a JSON error saying the file changed on disk, logged once,
//!   until the server is restarted. The change is seen by the file's length and modification
//!   time, checked on each such request; records are also checked against their CRC every time
//!   they are sent, so bytes that changed without either (a modification time put back) are
//!   answered 500 as damaged, never served under the old ETag. An answer under way when the file
//!   changes is cut short (the connection is closed) rather than finished with other bytes.
#![deny(missing_docs)]

mod answer_memory;
mod batch_body;
mod config;
mod conn;
mod cors;
pub mod describe;
mod error;
mod examples;
mod file_body;
mod headers;
pub mod metrics;
mod observe;
mod range;
mod records;
mod routes;
mod state;
mod tiles;
pub mod web;

use std::future::Future;

use axum::Router;
use tokio::net::TcpListener;

pub use config::Config;
pub use conn::raise_fd_limit;
pub use describe::{describe, head_len, summarize};
pub use error::{ApiError, ServerError};
pub use examples::{WebLibs, WebLibsError};
pub use range::{RangeRequest, parse_range};
pub use routes::{BATCH_CONTENT_TYPE, BATCH_MAGIC, STATUS_NOT_STORED, STATUS_RECORD};
pub use state::{AppState, RepoSpec, ServedRepo, validate_name};
pub use web::{WebAssets, WebError};

/// The router with every endpoint and middleware (CORS, timeout, metrics and request logs).
pub fn app(state: AppState) -> Router {
    routes::router(state)
}

/// Serves `state` on `listener` until `shutdown` completes, then stops accepting, lets the
/// requests in flight finish and returns. HTTP/1.1 and HTTP/2 are told apart per connection
/// (HTTP/2 cleartext needs prior knowledge: there is no `Upgrade: h2c` dance).
///
/// Hostile or broken clients cannot exhaust it (see [`Config`] for the settings):
///
/// - a request's headers must arrive within [`Config::header_read_timeout`] (hyper's
///   HTTP/1.1 timeout, and the server's own from the accept until the first request);
/// - a connection moving no byte for [`Config::idle_timeout`] is closed;
/// - at most [`Config::max_connections`] are open at once (fewer when the file-descriptor
///   limit is lower): a new connection beyond it closes the least recently active one of the
///   client address that holds the most, so an idle flood cannot keep other clients out;
/// - hyper buffers a bounded part of each answer (one chunk for HTTP/1.1, 32 KiB per HTTP/2
///   stream, at most 32 streams a connection) and bodies are produced as it asks for them, so
///   a client that never reads its batch answer holds one chunk, not the answer;
/// - the chunks held, over all connections, take at most [`Config::answer_memory`]: beyond it
///   answers wait, and connections that stopped reading are closed to make room
///   ([`answer_memory`]);
/// - request heads are limited to 16 KiB (431 beyond).
pub async fn run(
    listener: TcpListener,
    state: AppState,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> Result<(), ServerError> {
    let cfg = state.config().clone();
    conn::serve(listener, app(state), &cfg, shutdown).await?;
    Ok(())
}

/// Completes on SIGINT (Ctrl-C) or, on Unix, SIGTERM: the shutdown future for [`run`].
///
/// The handlers are installed when this is called (inside a Tokio runtime), not when the future
/// is first polled: call it before announcing the address, so that a signal sent as soon as the
/// server says it listens shuts it down cleanly instead of killing it.
pub fn shutdown_signal() -> impl Future<Output = ()> + Send + 'static {
    #[cfg(unix)]
    let (int, term) = {
        use tokio::signal::unix::{SignalKind, signal};
        let listen = |kind: SignalKind, name: &str| match signal(kind) {
            Ok(s) => Some(s),
            Err(e) => {
                tracing::error!("cannot listen for {name}: {e}");
                None
            }
        };
        (
            listen(SignalKind::interrupt(), "SIGINT"),
            listen(SignalKind::terminate(), "SIGTERM"),
        )
    };
    async move {
        #[cfg(unix)]
        {
            let wait = |s: Option<tokio::signal::unix::Signal>| async move {
                match s {
                    Some(mut s) => {
                        s.recv().await;
                    }
                    None => std::future::pending::<()>().await,
                }
            };
            tokio::select! {
                () = wait(int) => tracing::info!("SIGINT received, shutting down"),
                () = wait(term) => tracing::info!("SIGTERM received, shutting down"),
            }
        }
        #[cfg(not(unix))]
        {
            if let Err(e) = tokio::signal::ctrl_c().await {
                tracing::error!("cannot listen for Ctrl-C: {e}");
                std::future::pending::<()>().await;
            }
            tracing::info!("Ctrl-C received, shutting down");
        }
    }
}
