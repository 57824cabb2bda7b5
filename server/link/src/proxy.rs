//! The shaping proxy: an accept loop and, per connection, two directions, each a reader (source
//! → rate cap → delay line) and a writer (delay line → destination).

use std::io;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::tcp::{ReadHalf, WriteHalf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{Notify, Semaphore, mpsc};
use tokio::task::{JoinHandle, JoinSet};
use tokio::time::{Instant, sleep, sleep_until};

use crate::{Link, RESET_WINDOW, XorShift};

/// What a proxy has done since it started.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Counters {
    /// Bytes delivered to clients (upstream server → client).
    pub bytes_down: u64,
    /// Bytes delivered to the upstream server (client → upstream server).
    pub bytes_up: u64,
    /// Connections accepted.
    pub connections: u64,
    /// Connections reset on purpose (see [`Link::reset_prob`]).
    pub resets: u64,
    /// Accepted connections dropped because the upstream server could not be reached.
    pub upstream_errors: u64,
}

#[derive(Default)]
struct Shared {
    bytes_down: AtomicU64,
    bytes_up: AtomicU64,
    connections: AtomicU64,
    resets: AtomicU64,
    upstream_errors: AtomicU64,
}

/// A running shaping proxy: accepts TCP connections on its listener and forwards each to the
/// upstream address through the emulated [`Link`]. It runs on the tokio runtime it was started
/// on (which needs its time and I/O drivers) and stops — listener closed, every connection
/// dropped — on [`Proxy::shutdown`] or when dropped.
pub struct Proxy {
    addr: SocketAddr,
    upstream: SocketAddr,
    link: Link,
    shared: Arc<Shared>,
    task: Option<JoinHandle<()>>,
}

impl Proxy {
    /// Binds `listen` (port 0 picks a free port) and starts forwarding to `upstream`. Fails on an
    /// invalid link (the message names the parameter) or when the address cannot be bound.
    pub async fn start(listen: SocketAddr, upstream: SocketAddr, link: Link) -> io::Result<Proxy> {
        link.validate()
            .map_err(|e| io::Error::new(io::ErrorKind::InvalidInput, e))?;
        let listener = TcpListener::bind(listen).await?;
        let addr = listener.local_addr()?;
        let shared = Arc::new(Shared::default());
        let task = tokio::spawn(accept_loop(listener, upstream, link, shared.clone()));
        Ok(Proxy {
            addr,
            upstream,
            link,
            shared,
            task: Some(task),
        })
    }

    /// The address the proxy listens on.
    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    /// The address connections are forwarded to.
    pub fn upstream(&self) -> SocketAddr {
        self.upstream
    }

    /// The emulated link.
    pub fn link(&self) -> &Link {
        &self.link
    }

    /// The counters so far.
    pub fn counters(&self) -> Counters {
        let s = &self.shared;
        Counters {
            bytes_down: s.bytes_down.load(Ordering::Relaxed),
            bytes_up: s.bytes_up.load(Ordering::Relaxed),
            connections: s.connections.load(Ordering::Relaxed),
            resets: s.resets.load(Ordering::Relaxed),
            upstream_errors: s.upstream_errors.load(Ordering::Relaxed),
        }
    }

    /// Stops: closes the listener and drops every connection, and returns the final counters.
    pub async fn shutdown(mut self) -> Counters {
        if let Some(task) = self.task.take() {
            task.abort();
            // Cancelled (or, had it panicked, failed): either way it has stopped.
            let _ = task.await;
        }
        self.counters()
    }
}

impl Drop for Proxy {
    fn drop(&mut self) {
        if let Some(task) = self.task.take() {
            task.abort();
        }
    }
}

/// Accepts connections until aborted; the connections are tasks of a [`JoinSet`] owned here, so
/// aborting this task drops them all.
async fn accept_loop(listener: TcpListener, upstream: SocketAddr, link: Link, shared: Arc<Shared>) {
    let down = Arc::new(Bucket::new(link.down_bps));
    let up = Arc::new(Bucket::new(link.up_bps));
    let mut rng = XorShift::new(link.seed);
    let mut conns = JoinSet::new();
    loop {
        tokio::select! {
            r = listener.accept() => {
                let client = match r {
                    Ok((c, _)) => c,
                    // Out of descriptors and the like: wait rather than spin.
                    Err(_) => {
                        sleep(Duration::from_millis(10)).await;
                        continue;
                    }
                };
                // The same three draws for every connection, whatever the probability, so one
                // seed gives one sequence.
                let (chosen, at, seed) = (rng.unit(), rng.next_u64() % RESET_WINDOW, rng.next_u64());
                let reset_at = (chosen < link.reset_prob).then_some(at);
                shared.connections.fetch_add(1, Ordering::Relaxed);
                conns.spawn(connection(
                    client,
                    upstream,
                    link,
                    reset_at,
                    seed,
                    [up.clone(), down.clone()],
                    shared.clone(),
                ));
            }
            Some(_) = conns.join_next(), if !conns.is_empty() => {}
        }
    }
}

/// The reset plan of one connection: reset when `sent` reaches `at` bytes (both directions).
struct Reset {
    at: Option<u64>,
    sent: AtomicU64,
    now: Notify,
}

async fn connection(
    client: TcpStream,
    upstream: SocketAddr,
    link: Link,
    reset_at: Option<u64>,
    seed: u64,
    [up, down]: [Arc<Bucket>; 2],
    shared: Arc<Shared>,
) {
    let Ok(mut server) = TcpStream::connect(upstream).await else {
        shared.upstream_errors.fetch_add(1, Ordering::Relaxed);
        return;
    };
    let mut client = client;
    // The link decides the timing, not Nagle's algorithm.
    let _ = client.set_nodelay(true);
    let _ = server.set_nodelay(true);
    if reset_at.is_some() {
        // SO_LINGER 0: closing the socket sends RST instead of FIN. (Deprecated in tokio because a
        // non-zero linger blocks the thread on drop; zero never blocks.)
        #[allow(deprecated)]
        for s in [&client, &server] {
            let _ = s.set_linger(Some(Duration::ZERO));
        }
    }
    let reset = Reset {
        at: reset_at,
        sent: AtomicU64::new(0),
        now: Notify::new(),
    };
    let mut rng = XorShift::new(seed);
    let (up_seed, down_seed) = (rng.next_u64(), rng.next_u64());
    // Borrowed halves: dropping them does not shut the socket down, so a reset's close is a bare
    // RST, with no FIN before it.
    let (cr, cw) = client.split();
    let (sr, sw) = server.split();
    let up_pipe = pipe(cr, sw, &link, &up, up_seed, &reset, &shared.bytes_up);
    let down_pipe = pipe(sr, cw, &link, &down, down_seed, &reset, &shared.bytes_down);
    tokio::select! {
        _ = async { tokio::join!(up_pipe, down_pipe) } => {}
        () = reset.now.notified() => {
            shared.resets.fetch_add(1, Ordering::Relaxed);
        }
    }
    // Both streams close here (RST if chosen for a reset).
}

/// One direction of a connection: read → rate cap → delay line → write, then half-close the
/// destination when the source ends (or reset, when the connection was chosen for one).
async fn pipe(
    src: ReadHalf<'_>,
    dst: WriteHalf<'_>,
    link: &Link,
    bucket: &Bucket,
    seed: u64,
    reset: &Reset,
    delivered: &AtomicU64,
) {
    // Bytes in the delay line, bounded so a slow reader at the far end holds back the source
    // (TCP's back-pressure) instead of filling memory: twice the bandwidth-delay product, at
    // least 256 KiB.
    let bdp = bucket.rate * (link.delay + link.jitter).as_secs_f64();
    let limit = ((2.0 * bdp) as usize).max(256 * 1024);
    let in_flight = Semaphore::new(limit);
    let (tx, rx) = mpsc::unbounded_channel::<DelayedPiece>();
    let rng = XorShift::new(seed);
    tokio::join!(
        into_delay_line(src, link, bucket, rng, &in_flight, tx),
        out_of_delay_line(dst, rx, reset, &in_flight, delivered),
    );
}

/// A piece of the stream in the delay line, and when it is due at the destination.
type DelayedPiece = (Instant, Vec<u8>);

/// The reading end of [`pipe`]: each piece read waits for room in the delay line and for the
/// rate cap, then goes in, due after the link's delay (± jitter, never before the last piece).
async fn into_delay_line(
    mut src: ReadHalf<'_>,
    link: &Link,
    bucket: &Bucket,
    mut rng: XorShift,
    in_flight: &Semaphore,
    tx: mpsc::UnboundedSender<DelayedPiece>,
) {
    let mut buf = vec![0u8; bucket.burst];
    let mut last = Instant::now();
    loop {
        let n = match src.read(&mut buf).await {
            Ok(0) | Err(_) => break,
            Ok(n) => n,
        };
        // n ≤ 16 KiB ≤ limit: the permits always exist. The semaphore is closed only when
        // the destination is gone.
        let Ok(permit) = in_flight.acquire_many(n as u32).await else {
            break;
        };
        permit.forget();
        bucket.take(n).await;
        let mut d = link.delay.as_secs_f64();
        if !link.jitter.is_zero() {
            d += link.jitter.as_secs_f64() * (2.0 * rng.unit() - 1.0);
        }
        let release = (Instant::now() + Duration::from_secs_f64(d.max(0.0))).max(last);
        last = release;
        if tx.send((release, buf[..n].to_vec())).is_err() {
            break;
        }
    }
    // Dropping `tx` ends the writer once the delay line is empty.
}

/// The writing end of [`pipe`]: each piece is written when due, until the reset byte (then the
/// connection is reset) or the end of the stream (then the destination is half-closed).
async fn out_of_delay_line(
    mut dst: WriteHalf<'_>,
    mut rx: mpsc::UnboundedReceiver<DelayedPiece>,
    reset: &Reset,
    in_flight: &Semaphore,
    delivered: &AtomicU64,
) {
    while let Some((release, piece)) = rx.recv().await {
        sleep_until(release).await;
        let mut len = piece.len();
        let mut hit = false;
        if let Some(at) = reset.at {
            let before = reset.sent.fetch_add(len as u64, Ordering::Relaxed);
            if before + len as u64 >= at {
                len = at.saturating_sub(before) as usize;
                hit = true;
            }
        }
        if dst.write_all(&piece[..len]).await.is_err() {
            // The destination is gone: stop the reader too, so the rest of the stream is
            // not pulled through the shared cap for nobody (a real sender stops at the
            // receiver's reset). Its next permit or send fails.
            rx.close();
            in_flight.close();
            return;
        }
        delivered.fetch_add(len as u64, Ordering::Relaxed);
        in_flight.add_permits(piece.len());
        if hit {
            reset.now.notify_one();
            return std::future::pending().await;
        }
    }
    if reset.at.is_some() {
        // Ended before its reset byte: reset instead of closing in order.
        reset.now.notify_one();
        return std::future::pending().await;
    }
    let _ = dst.shutdown().await;
}

/// A token bucket in bytes, shared by the connections of one direction. A taker subtracts what
/// it takes at once (the level may go negative) and sleeps until the level is back to zero, so
/// takers are served in order and never more than `burst + rate·t` bytes pass in any `t`.
struct Bucket {
    /// Bytes per second.
    rate: f64,
    burst: usize,
    /// Level (bytes) and when it was last brought up to date.
    state: Mutex<(f64, Instant)>,
}

impl Bucket {
    fn new(bps: u64) -> Bucket {
        let burst = Link::burst(bps);
        Bucket {
            rate: bps as f64 / 8.0,
            burst,
            state: Mutex::new((burst as f64, Instant::now())),
        }
    }

    async fn take(&self, n: usize) {
        let wait = {
            let mut s = self.state.lock().unwrap_or_else(|e| e.into_inner());
            let now = Instant::now();
            let level = (s.0 + (now - s.1).as_secs_f64() * self.rate).min(self.burst as f64);
            *s = (level - n as f64, now);
            (s.0 < 0.0).then(|| Duration::from_secs_f64(-s.0 / self.rate))
        };
        if let Some(wait) = wait {
            sleep(wait).await;
        }
    }
}
