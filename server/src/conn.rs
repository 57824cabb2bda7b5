//! Connections: the accept loop, the connection cap and the per-connection deadlines.
//!
//! hyper provides the HTTP/1.1 header-read timeout and the bounds on buffered bytes (see
//! [`crate::run`]); what it has no setting for is here:
//!
//! - **A cap on open connections**, `Config::max_connections`, lowered to what the
//!   file-descriptor limit allows. Every connection is accepted; one beyond the cap closes
//!   another: the least recently active connection of the client address that holds the most.
//!   A flood of idle connections from one address therefore closes its own oldest connections,
//!   never the connections of other clients, and a normal request on a fresh connection is
//!   answered at once, where leaving excess connections in the listen backlog (or refusing
//!   them) would make it wait behind the flood. A connection accepted, then closed, costs a
//!   flooder as much as it costs the server.
//! - **A deadline for the first request**, `Config::header_read_timeout` from the accept:
//!   hyper's own timeout starts only once the protocol (HTTP/1.1 or HTTP/2) is told apart,
//!   and a client sending nothing at all would never reach it.
//! - **An idle timeout**, `Config::idle_timeout`: no byte read or written for that long
//!   closes the connection, whatever it is doing (an idle HTTP/2 connection, a client that does
//!   not read the answer it asked for).

use std::collections::HashMap;
use std::convert::Infallible;
use std::future::Future;
use std::io::IoSlice;
use std::net::{IpAddr, SocketAddr};
use std::pin::Pin;
use std::sync::atomic::Ordering::Relaxed;
use std::sync::atomic::{AtomicBool, AtomicU64};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::Duration;

use axum::Router;
use axum::extract::Request;
use axum::response::Response;
use hyper::body::Incoming;
use hyper_util::rt::{TokioExecutor, TokioIo, TokioTimer};
use hyper_util::server::conn::auto::Builder;
use hyper_util::server::graceful::GracefulShutdown;
use pin_project_lite::pin_project;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::Notify;
use tokio::time::Instant;

use crate::config::Config;

/// hyper's buffer bound for HTTP/1.1 (bytes): the most a request head may take (a longer one is
/// answered 431), and about how much of an answer hyper queues before it stops asking the body
/// for more. The default (about 400 KiB) let a thousand clients that never read their batch
/// answers hold hundreds of megabytes.
pub(crate) const H1_MAX_BUF: usize = 16 << 10;
/// hyper's limit on header fields in an HTTP/1.1 request (431 beyond, with an empty body): above
/// the server's own limit, which answers in JSON.
pub(crate) const H1_MAX_HEADERS: usize = 128;
/// The HTTP/2 counterpart per stream (hyper's default is 400 KiB).
const H2_MAX_SEND_BUF: usize = 32 << 10;
/// HTTP/2 streams a connection may have open at once (hyper's default is 200): each may hold
/// an unread answer's buffers, so this multiplies what one connection can hold; a client
/// asking for more waits for a stream to end.
const H2_MAX_STREAMS: u32 = 32;
/// File descriptors kept out of the connection cap: repositories, the runtime's, the log's.
const FD_RESERVE: u64 = 64;

/// One connection as the cap sees it.
struct Slot {
    ip: IpAddr,
    /// Microseconds since the server started, when the connection was accepted.
    accepted: u64,
    /// Microseconds since the server started, when a byte last moved either way (or the
    /// connection was accepted).
    last_io: AtomicU64,
    /// Whether a request has reached the router.
    requested: AtomicBool,
    /// Bytes of answer chunks made for this connection and not yet written
    /// ([`crate::answer_memory`]).
    held: AtomicU64,
    /// Told when the connection is to close to make room for another.
    evict: Notify,
}

/// The open connections.
#[derive(Default)]
struct Registry {
    next: u64,
    conns: HashMap<u64, Arc<Slot>>,
    per_ip: HashMap<IpAddr, usize>,
}

impl Registry {
    fn add(&mut self, slot: Arc<Slot>) -> u64 {
        let id = self.next;
        self.next += 1;
        *self.per_ip.entry(slot.ip).or_default() += 1;
        self.conns.insert(id, slot);
        id
    }

    fn remove(&mut self, id: u64) {
        if let Some(slot) = self.conns.remove(&id)
            && let Some(n) = self.per_ip.get_mut(&slot.ip)
        {
            *n -= 1;
            if *n == 0 {
                self.per_ip.remove(&slot.ip);
            }
        }
    }

    /// Closes the least recently active connection of the address holding the most. It leaves
    /// the registry at once (its task closes the socket as soon as it runs). False when there
    /// is none.
    fn evict_one(&mut self) -> bool {
        let Some((&ip, _)) = self.per_ip.iter().max_by_key(|(_, n)| **n) else {
            return false;
        };
        let Some((&id, _)) = self
            .conns
            .iter()
            .filter(|(_, s)| s.ip == ip)
            // Of equally recent ones, the first accepted.
            .min_by_key(|&(&id, s)| (s.last_io.load(Relaxed), id))
        else {
            return false;
        };
        let slot = Arc::clone(&self.conns[&id]);
        self.remove(id);
        slot.evict.notify_one();
        true
    }
}

/// The soft limit on open file descriptors, if there is one.
// `rlim_t` is u64 on Linux, not on every Unix.
#[allow(clippy::unnecessary_cast)]
fn fd_limit() -> Option<u64> {
    #[cfg(unix)]
    {
        let mut r = libc::rlimit {
            rlim_cur: 0,
            rlim_max: 0,
        };
        // SAFETY: getrlimit writes into the struct it is given.
        if unsafe { libc::getrlimit(libc::RLIMIT_NOFILE, &mut r) } == 0
            && r.rlim_cur != libc::RLIM_INFINITY
        {
            return Some(r.rlim_cur as u64);
        }
    }
    None
}

/// Raises the soft limit on open file descriptors to the hard limit, so that the connection
/// cap is not lowered by a soft limit the process could lift itself (1 024 by default on many
/// systems, against hard limits of hundreds of thousands). Returns the limit before and after
/// when it was raised; `None` when it already was at the hard limit, or could not be read or
/// set (then the cap follows the soft limit, as [`effective_cap`] says).
// `rlim_t` is u64 on Linux, not on every Unix.
#[allow(clippy::unnecessary_cast)]
pub fn raise_fd_limit() -> Option<(u64, u64)> {
    #[cfg(unix)]
    {
        let mut r = libc::rlimit {
            rlim_cur: 0,
            rlim_max: 0,
        };
        // SAFETY: getrlimit writes into the struct it is given.
        if unsafe { libc::getrlimit(libc::RLIMIT_NOFILE, &mut r) } != 0 || r.rlim_cur >= r.rlim_max
        {
            return None;
        }
        let before = r.rlim_cur as u64;
        r.rlim_cur = r.rlim_max;
        // SAFETY: setrlimit reads the struct it is given; raising the soft limit up to the hard
        // one needs no privilege.
        if unsafe { libc::setrlimit(libc::RLIMIT_NOFILE, &r) } == 0 {
            return Some((before, fd_limit().unwrap_or(u64::MAX)));
        }
    }
    None
}

/// The connection cap in effect: `max_connections`, lowered to what the fd limit leaves.
pub(crate) fn effective_cap(max_connections: usize) -> usize {
    let by_fds = fd_limit().map_or(usize::MAX, |l| {
        usize::try_from(l.saturating_sub(FD_RESERVE).max(1)).unwrap_or(usize::MAX)
    });
    max_connections.max(1).min(by_fds)
}

/// hyper's settings for every connection.
fn builder(cfg: &Config) -> Builder<TokioExecutor> {
    let mut b = Builder::new(TokioExecutor::new());
    b.http1()
        .timer(TokioTimer::new())
        .header_read_timeout(cfg.header_read_timeout)
        .max_buf_size(H1_MAX_BUF)
        .max_headers(H1_MAX_HEADERS);
    b.http2()
        .timer(TokioTimer::new())
        .max_send_buf_size(H2_MAX_SEND_BUF)
        .max_concurrent_streams(H2_MAX_STREAMS)
        .max_header_list_size(H1_MAX_BUF as u32);
    b
}

/// Accepts connections on `listener` and serves `router` on each until `shutdown` completes;
/// then lets the connections finish their requests and returns.
pub(crate) async fn serve(
    listener: TcpListener,
    router: Router,
    cfg: &Config,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    let acceptor = Acceptor::new(router, cfg);
    tokio::pin!(shutdown);
    loop {
        let (tcp, peer) = tokio::select! {
            r = listener.accept() => match r {
                Ok(c) => c,
                Err(e) => {
                    accept_error(&e, &acceptor.registry).await;
                    continue;
                }
            },
            () = &mut shutdown => break,
        };
        acceptor.admit(tcp, peer);
    }
    drop(listener);
    acceptor.graceful.shutdown().await;
    Ok(())
}

/// What the accept loop hands every connection it admits: hyper's settings, the registry of
/// open connections and its cap, the deadlines, and the graceful shutdown they all watch.
struct Acceptor {
    router: Router,
    builder: Arc<Builder<TokioExecutor>>,
    registry: Arc<Mutex<Registry>>,
    graceful: GracefulShutdown,
    limits: Limits,
    cap: usize,
}

impl Acceptor {
    /// The acceptor for `cfg`; warns when the fd limit lowers the connection cap.
    fn new(router: Router, cfg: &Config) -> Self {
        let cap = effective_cap(cfg.max_connections);
        if cap < cfg.max_connections {
            tracing::warn!(
                "at most {cap} connections at once (--max-connections {} is over what the \
                 file-descriptor limit allows; raise it with ulimit -n)",
                cfg.max_connections
            );
        }
        Self {
            router,
            builder: Arc::new(builder(cfg)),
            registry: Arc::new(Mutex::new(Registry::default())),
            graceful: GracefulShutdown::new(),
            limits: Limits {
                header: cfg.header_read_timeout,
                idle: cfg.idle_timeout,
                clock: Instant::now(),
            },
            cap,
        }
    }

    /// Registers an accepted connection (closing another beyond the cap) and serves it on a
    /// task of its own.
    fn admit(&self, tcp: TcpStream, peer: SocketAddr) {
        // Without TCP_NODELAY a small response can wait for the client's delayed ACK (Nagle's
        // algorithm): tens of milliseconds on a request that takes microseconds.
        if let Err(e) = tcp.set_nodelay(true) {
            tracing::debug!("set_nodelay: {e}");
        }
        let (limits, clock) = (self.limits, self.limits.clock);
        let now = limits.now();
        let slot = Arc::new(Slot {
            ip: peer.ip(),
            accepted: now,
            last_io: AtomicU64::new(now),
            requested: AtomicBool::new(false),
            held: AtomicU64::new(0),
            evict: Notify::new(),
        });
        let id = {
            let mut reg = self.registry.lock().expect("not poisoned");
            while reg.conns.len() >= self.cap && reg.evict_one() {}
            reg.add(Arc::clone(&slot))
        };
        let io = TokioIo::new(Tracked {
            io: tcp,
            slot: Arc::clone(&slot),
            clock,
        });
        let svc = Svc {
            router: self.router.clone(),
            conn: ConnHandle {
                slot: Arc::clone(&slot),
                registry: Arc::clone(&self.registry),
                clock,
            },
        };
        let builder = Arc::clone(&self.builder);
        let registry = Arc::clone(&self.registry);
        let watcher = self.graceful.watcher();
        tokio::spawn(async move {
            let conn = watcher.watch(builder.serve_connection(io, svc));
            until_done_evicted_or_late(conn, &slot, limits, peer).await;
            registry.lock().expect("not poisoned").remove(id);
        });
    }
}

/// Drives `conn` until it ends, a newer connection evicts it, or its deadline passes.
async fn until_done_evicted_or_late<E: std::fmt::Display>(
    conn: impl Future<Output = Result<(), E>>,
    slot: &Slot,
    limits: Limits,
    peer: SocketAddr,
) {
    tokio::pin!(conn);
    loop {
        let deadline = limits.deadline(slot);
        tokio::select! {
            r = &mut conn => {
                if let Err(e) = r {
                    tracing::debug!("connection from {peer}: {e}");
                }
                break;
            }
            () = slot.evict.notified() => {
                tracing::debug!("connection from {peer} closed for a newer one");
                break;
            }
            () = tokio::time::sleep_until(deadline) => {
                if limits.deadline(slot) <= Instant::now() {
                    tracing::debug!("connection from {peer} timed out");
                    break;
                }
            }
        }
    }
}

/// An accept that failed. Out of file descriptors: close a connection to make room. A
/// connection that failed before it was accepted: nothing to do. Anything else: log it and
/// pause briefly, as a listener in trouble would otherwise spin.
async fn accept_error(e: &std::io::Error, registry: &Mutex<Registry>) {
    #[cfg(unix)]
    if matches!(
        e.raw_os_error(),
        Some(libc::EMFILE | libc::ENFILE | libc::ENOBUFS | libc::ENOMEM)
    ) {
        tracing::warn!("accept: {e}: closing the least recently active connection");
        let _ = registry.lock().expect("not poisoned").evict_one();
        tokio::time::sleep(Duration::from_millis(10)).await;
        return;
    }
    use std::io::ErrorKind::*;
    if matches!(
        e.kind(),
        ConnectionAborted | ConnectionReset | ConnectionRefused | Interrupted
    ) {
        return;
    }
    #[cfg(not(unix))]
    let _ = registry;
    tracing::error!("accept: {e}");
    tokio::time::sleep(Duration::from_millis(100)).await;
}

#[derive(Clone, Copy)]
struct Limits {
    header: Duration,
    idle: Duration,
    clock: Instant,
}

impl Limits {
    fn now(&self) -> u64 {
        self.clock.elapsed().as_micros() as u64
    }

    /// When the connection is to close unless something happens: its first request's headers
    /// are due `header` after the accept, and after that a byte every `idle`.
    fn deadline(&self, slot: &Slot) -> Instant {
        let last = self.clock + Duration::from_micros(slot.last_io.load(Relaxed));
        if slot.requested.load(Relaxed) {
            last + self.idle
        } else {
            self.clock + Duration::from_micros(slot.accepted) + self.header
        }
    }
}

/// The router, as hyper calls it; marks the connection as having made a request, and hands
/// each request its connection ([`ConnHandle`], a request extension).
#[derive(Clone)]
struct Svc {
    router: Router,
    conn: ConnHandle,
}

/// A request's connection, as the answer-memory budget sees it ([`crate::answer_memory`]): it
/// counts the answer bytes held for the connection, and can close the connection elsewhere
/// that has held answer bytes without moving a byte the longest.
#[derive(Clone)]
pub(crate) struct ConnHandle {
    slot: Arc<Slot>,
    registry: Arc<Mutex<Registry>>,
    clock: Instant,
}

impl ConnHandle {
    /// Counts `n` more answer bytes held for this connection.
    pub(crate) fn hold(&self, n: u64) {
        self.slot.held.fetch_add(n, Relaxed);
    }

    /// Counts `n` answer bytes written or dropped.
    pub(crate) fn release(&self, n: u64) {
        self.slot.held.fetch_sub(n, Relaxed);
    }

    /// Closes the connection, other than this one, that holds answer bytes and has moved no
    /// byte for the longest, if that is at least `stalled`. False when there is none.
    pub(crate) fn close_most_stalled_holder(&self, stalled: Duration) -> bool {
        let Some(before) = self.clock.elapsed().checked_sub(stalled) else {
            return false;
        };
        let before = before.as_micros() as u64;
        let mut reg = self.registry.lock().expect("not poisoned");
        let most_stalled = reg
            .conns
            .iter()
            .filter(|(_, s)| !Arc::ptr_eq(s, &self.slot) && s.held.load(Relaxed) > 0)
            .map(|(&id, s)| (s.last_io.load(Relaxed), id))
            .filter(|&(last, _)| last <= before)
            .min();
        let Some((_, id)) = most_stalled else {
            return false;
        };
        let slot = Arc::clone(&reg.conns[&id]);
        reg.remove(id);
        slot.evict.notify_one();
        true
    }
}

impl hyper::service::Service<hyper::Request<Incoming>> for Svc {
    type Response = Response;
    type Error = Infallible;
    type Future = axum::routing::future::RouteFuture<Infallible>;

    fn call(&self, req: hyper::Request<Incoming>) -> Self::Future {
        self.conn.slot.requested.store(true, Relaxed);
        let mut req: Request = req.map(axum::body::Body::new);
        req.extensions_mut().insert(self.conn.clone());
        tower_service::Service::call(&mut self.router.clone(), req)
    }
}

pin_project! {
    /// A TCP stream that notes when a byte last moved.
    struct Tracked {
        #[pin]
        io: TcpStream,
        slot: Arc<Slot>,
        clock: Instant,
    }
}

impl Tracked {
    fn touch(slot: &Slot, clock: Instant) {
        slot.last_io
            .store(clock.elapsed().as_micros() as u64, Relaxed);
    }
}

impl AsyncRead for Tracked {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        let this = self.project();
        let before = buf.filled().len();
        let r = this.io.poll_read(cx, buf);
        if matches!(r, Poll::Ready(Ok(()))) && buf.filled().len() > before {
            Tracked::touch(this.slot, *this.clock);
        }
        r
    }
}

impl AsyncWrite for Tracked {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<std::io::Result<usize>> {
        let this = self.project();
        let r = this.io.poll_write(cx, buf);
        if matches!(r, Poll::Ready(Ok(n)) if n > 0) {
            Tracked::touch(this.slot, *this.clock);
        }
        r
    }

    fn poll_write_vectored(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[IoSlice<'_>],
    ) -> Poll<std::io::Result<usize>> {
        let this = self.project();
        let r = this.io.poll_write_vectored(cx, bufs);
        if matches!(r, Poll::Ready(Ok(n)) if n > 0) {
            Tracked::touch(this.slot, *this.clock);
        }
        r
    }

    fn is_write_vectored(&self) -> bool {
        self.io.is_write_vectored()
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        self.project().io.poll_flush(cx)
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        self.project().io.poll_shutdown(cx)
    }
}
