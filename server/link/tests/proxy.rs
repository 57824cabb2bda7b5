//! The proxy over real loopback sockets: delay and rate within 10 %, a shared cap (which a closed
//! client stops using), resets at the configured rate, bytes unchanged and in order, a clean
//! stop.
//!
//! Timing bounds: the lower bounds are strict (the proxy never releases a byte early: tokio's
//! timers never fire early and the token bucket never lets more than `burst + rate·t` bytes
//! through in `t`). The upper bounds are the expected time plus 10 %, plus [`SLACK`] for
//! scheduling: these tests must pass on a loaded 2-core machine, where a thread can be stalled
//! for ~90 ms (seen in CI, see `client/tests/streaming.rs`).

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use cbdam_link::{Link, Proxy};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};

/// Scheduling slack on top of the 10 % (see the module's documentation): one ~90 ms stall.
const SLACK: Duration = Duration::from_millis(100);

fn localhost() -> SocketAddr {
    "127.0.0.1:0".parse().unwrap()
}

/// Byte `i` of the test stream `k`: a pseudo-random pattern, so a reordered, dropped or
/// duplicated piece shows.
fn pattern(k: u64, i: usize) -> u8 {
    ((i as u64 ^ (k << 40))
        .wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .rotate_left(17)
        >> 56) as u8
}

/// An upstream server that writes `n` bytes of `pattern(0, ·)` to each connection, then closes.
async fn source(n: usize) -> SocketAddr {
    let l = TcpListener::bind(localhost()).await.unwrap();
    let addr = l.local_addr().unwrap();
    let data: Vec<u8> = (0..n).map(|i| pattern(0, i)).collect();
    tokio::spawn(async move {
        loop {
            let (mut s, _) = l.accept().await.unwrap();
            let data = data.clone();
            tokio::spawn(async move {
                let _ = s.write_all(&data).await;
                let _ = s.shutdown().await;
                // Keep the socket until the peer closes (or resets) it.
                let _ = s.read(&mut [0u8; 1]).await;
            });
        }
    });
    addr
}

/// An upstream echo server.
async fn echo() -> SocketAddr {
    let l = TcpListener::bind(localhost()).await.unwrap();
    let addr = l.local_addr().unwrap();
    tokio::spawn(async move {
        loop {
            let (mut s, _) = l.accept().await.unwrap();
            tokio::spawn(async move {
                let (mut r, mut w) = s.split();
                let _ = tokio::io::copy(&mut r, &mut w).await;
                let _ = w.shutdown().await;
            });
        }
    });
    addr
}

/// Connects to `addr` and reads to the end: (seconds to the first byte, seconds to the end, the
/// bytes), all from just before the connect.
async fn fetch(addr: SocketAddr) -> (f64, f64, Vec<u8>) {
    let t0 = Instant::now();
    let mut s = TcpStream::connect(addr).await.unwrap();
    let mut buf = Vec::new();
    let mut first = None;
    let mut chunk = vec![0u8; 64 * 1024];
    loop {
        let n = s.read(&mut chunk).await.unwrap();
        if n == 0 {
            break;
        }
        first.get_or_insert_with(|| t0.elapsed().as_secs_f64());
        buf.extend_from_slice(&chunk[..n]);
    }
    (first.unwrap(), t0.elapsed().as_secs_f64(), buf)
}

fn within(what: &str, got: f64, expected: f64) {
    let hi = expected * 1.1 + SLACK.as_secs_f64();
    eprintln!("{what}: {got:.3} s, expected {expected:.3} s");
    assert!(
        got >= expected && got <= hi,
        "{what}: {got:.3} s, expected {expected:.3} s (allowed {expected:.3} to {hi:.3})"
    );
}

/// 2 Mbit/s down, 100 ms each way: 300 000 bytes take 100 ms + (300 000 − burst) / 250 000 B/s
/// ≈ 1.29 s, the first byte 100 ms.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_transfer_takes_the_delay_and_the_time_the_rate_cap_implies() {
    const N: usize = 300_000;
    let link = Link::custom(2_000_000, 2_000_000, Duration::from_millis(100));
    let proxy = Proxy::start(localhost(), source(N).await, link)
        .await
        .unwrap();
    let (first, total, data) = fetch(proxy.local_addr()).await;
    assert!(data.iter().enumerate().all(|(i, &b)| b == pattern(0, i)));
    assert_eq!(data.len(), N);
    within("first byte", first, 0.1);
    let burst = Link::burst(link.down_bps) as f64;
    within(
        "whole transfer",
        total,
        0.1 + (N as f64 - burst) / 250_000.0,
    );
    let c = proxy.shutdown().await;
    assert_eq!(
        (c.bytes_down, c.bytes_up, c.connections, c.resets),
        (N as u64, 0, 1, 0)
    );
}

/// The upstream cap: 1 Mbit/s up, 50 ms each way, fast down. 150 000 bytes up, then a reply of 8
/// bytes down: 2 × 50 ms + (150 000 − burst) / 125 000 B/s ≈ 1.29 s from the first write to the
/// reply.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_upstream_cap_and_delay_apply_to_uploads() {
    const N: usize = 150_000;
    let l = TcpListener::bind(localhost()).await.unwrap();
    let sink = l.local_addr().unwrap();
    tokio::spawn(async move {
        let (mut s, _) = l.accept().await.unwrap();
        let mut got = Vec::new();
        s.read_to_end(&mut got).await.unwrap();
        s.write_all(&(got.len() as u64).to_le_bytes())
            .await
            .unwrap();
    });
    let link = Link::custom(100_000_000, 1_000_000, Duration::from_millis(50));
    let proxy = Proxy::start(localhost(), sink, link).await.unwrap();
    let mut s = TcpStream::connect(proxy.local_addr()).await.unwrap();
    let t0 = Instant::now();
    let data: Vec<u8> = (0..N).map(|i| pattern(1, i)).collect();
    s.write_all(&data).await.unwrap();
    s.shutdown().await.unwrap();
    let mut reply = [0u8; 8];
    s.read_exact(&mut reply).await.unwrap();
    let t = t0.elapsed().as_secs_f64();
    assert_eq!(u64::from_le_bytes(reply), N as u64);
    let burst = Link::burst(link.up_bps) as f64;
    within("upload and reply", t, 0.1 + (N as f64 - burst) / 125_000.0);
    assert_eq!(proxy.counters().bytes_up, N as u64);
}

/// Two connections at once share the cap: together they take as long as one transfer of both
/// sizes (the 10 % bounds above), and neither gets the link to itself (the first to finish
/// takes at least 80 % of the whole time; one served before the other would finish at ~55 %).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn concurrent_connections_share_the_cap() {
    const N: usize = 150_000;
    let link = Link::custom(2_000_000, 2_000_000, Duration::from_millis(100));
    let proxy = Proxy::start(localhost(), source(N).await, link)
        .await
        .unwrap();
    let addr = proxy.local_addr();
    let (a, b) = tokio::join!(fetch(addr), fetch(addr));
    for (_, _, data) in [&a, &b] {
        assert_eq!(data.len(), N);
        assert!(data.iter().enumerate().all(|(i, &b)| b == pattern(0, i)));
    }
    let (early, late) = (a.1.min(b.1), a.1.max(b.1));
    let burst = Link::burst(link.down_bps) as f64;
    within(
        "both transfers",
        late,
        0.1 + (2.0 * N as f64 - burst) / 250_000.0,
    );
    eprintln!("first of two done at {early:.3} s");
    assert!(
        early >= 0.8 * late,
        "one finished at {early:.3} s, the other at {late:.3} s"
    );
    assert_eq!(proxy.counters().bytes_down, 2 * N as u64);
}

/// Runs `count` connections one after the other through a proxy with `link`, each reading a
/// 100 000-byte stream; returns which were reset (the proxy's count must agree) after checking
/// every byte that arrived.
async fn resets(link: Link, count: usize) -> Vec<bool> {
    const N: usize = 100_000;
    let proxy = Proxy::start(localhost(), source(N).await, link)
        .await
        .unwrap();
    let mut out = Vec::new();
    for _ in 0..count {
        let mut s = match TcpStream::connect(proxy.local_addr()).await {
            Ok(s) => s,
            // Reset before the connect returned (tokio reads the socket's pending error).
            Err(e) if e.kind() == std::io::ErrorKind::ConnectionReset => {
                out.push(true);
                continue;
            }
            Err(e) => panic!("connect: {e}"),
        };
        let mut buf = Vec::new();
        let mut chunk = vec![0u8; 64 * 1024];
        let reset = loop {
            match s.read(&mut chunk).await {
                Ok(0) => break false,
                Ok(n) => buf.extend_from_slice(&chunk[..n]),
                Err(e) => {
                    assert_eq!(e.kind(), std::io::ErrorKind::ConnectionReset, "{e}");
                    break true;
                }
            }
        };
        // What arrived is a prefix of the stream; a clean end is the whole stream.
        assert!(buf.iter().enumerate().all(|(i, &b)| b == pattern(0, i)));
        if !reset {
            assert_eq!(buf.len(), N);
        }
        out.push(reset);
    }
    let c = proxy.shutdown().await;
    assert_eq!(c.connections, count as u64);
    assert_eq!(c.resets, out.iter().filter(|&&r| r).count() as u64);
    out
}

/// Resets at the configured rate: 200 connections at p = 0.25 (mean 50, σ ≈ 6.1; the count is
/// fixed by the seed, and the bounds of ±4σ would hold for almost any seed), the same ones again
/// with the same seed, none at p = 0.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn connections_are_reset_at_the_configured_rate_and_reproducibly() {
    let link = Link {
        reset_prob: 0.25,
        seed: 7,
        ..Link::custom(1_000_000_000, 1_000_000_000, Duration::ZERO)
    };
    let first = resets(link, 200).await;
    let n = first.iter().filter(|&&r| r).count();
    eprintln!("{n} of 200 connections reset at p = 0.25");
    assert!(
        (26..=74).contains(&n),
        "{n} of 200 connections reset at p = 0.25"
    );
    assert_eq!(resets(link, 200).await, first, "same seed, same resets");
    let other = resets(Link { seed: 8, ..link }, 200).await;
    assert_ne!(other, first, "another seed, other resets");
    let none = resets(
        Link {
            reset_prob: 0.0,
            ..link
        },
        200,
    )
    .await;
    assert!(none.iter().all(|&r| !r));
    let all = resets(
        Link {
            reset_prob: 1.0,
            ..link
        },
        20,
    )
    .await;
    assert!(all.iter().all(|&r| r));
}

/// Bytes cross unchanged and in order both ways, with jitter on (±4 ms on a 5 ms delay: pieces'
/// delays differ by up to 8 ms, more than the ~1.3 ms a 16 KiB piece takes at the cap): three
/// connections at once each echo 1 MB of a different pattern.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bytes_arrive_unchanged_and_in_order_with_jitter() {
    const N: usize = 1 << 20;
    let link = Link {
        jitter: Duration::from_millis(4),
        ..Link::custom(100_000_000, 100_000_000, Duration::from_millis(5))
    };
    let proxy = Proxy::start(localhost(), echo().await, link).await.unwrap();
    let addr = proxy.local_addr();
    let one = |k: u64| async move {
        let s = TcpStream::connect(addr).await.unwrap();
        let (mut r, mut w) = s.into_split();
        let data: Vec<u8> = (0..N).map(|i| pattern(k, i)).collect();
        let send = async {
            w.write_all(&data).await.unwrap();
            w.shutdown().await.unwrap();
        };
        let mut back = Vec::new();
        let recv = r.read_to_end(&mut back);
        let (_, n) = tokio::join!(send, recv);
        assert_eq!(n.unwrap(), N);
        assert!(back == data, "connection {k}: echo differs");
    };
    tokio::join!(one(1), one(2), one(3));
    let c = proxy.shutdown().await;
    assert_eq!((c.bytes_up, c.bytes_down), (3 * N as u64, 3 * N as u64));
}

/// `shutdown` closes the listener and drops the connections in progress.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shutdown_stops_listening_and_drops_connections() {
    let link = Link::custom(1_000_000, 1_000_000, Duration::from_millis(10));
    let proxy = Proxy::start(localhost(), echo().await, link).await.unwrap();
    let addr = proxy.local_addr();
    let mut s = TcpStream::connect(addr).await.unwrap();
    s.write_all(b"ping").await.unwrap();
    let mut b = [0u8; 4];
    s.read_exact(&mut b).await.unwrap();
    assert_eq!(&b, b"ping");
    let c = proxy.shutdown().await;
    assert_eq!((c.connections, c.bytes_up, c.bytes_down), (1, 4, 4));
    // The open connection ends (EOF or reset, within the generous timeout), and no new one is
    // accepted.
    let end = tokio::time::timeout(Duration::from_secs(10), s.read(&mut b)).await;
    assert!(matches!(end, Ok(Ok(0)) | Ok(Err(_))), "{end:?}");
    assert!(TcpStream::connect(addr).await.is_err());
    // An unreachable upstream is counted, the client dropped.
    let dead = {
        let l = TcpListener::bind(localhost()).await.unwrap();
        l.local_addr().unwrap()
    };
    let proxy = Proxy::start(localhost(), dead, link).await.unwrap();
    let mut s = TcpStream::connect(proxy.local_addr()).await.unwrap();
    let end = tokio::time::timeout(Duration::from_secs(10), s.read(&mut b)).await;
    assert!(matches!(end, Ok(Ok(0)) | Ok(Err(_))), "{end:?}");
    assert_eq!(proxy.counters().upstream_errors, 1);
}

/// A client that goes away stops costing the link: the rest of its response is not pulled
/// through the shared cap (as a real sender stops at the receiver's reset), so a transfer
/// right after takes the time its own size implies. 2 Mbit/s, no delay, 200 000-byte
/// responses: the first client reads 10 000 bytes and closes; the second's whole response
/// then takes (200 000 − burst) / 250 000 B/s ≈ 0.79 s. Draining the first's 190 000 bytes
/// first would take 0.76 s more.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_closed_client_stops_using_the_shared_cap() {
    const N: usize = 200_000;
    let link = Link::custom(2_000_000, 2_000_000, Duration::ZERO);
    let proxy = Proxy::start(localhost(), source(N).await, link)
        .await
        .unwrap();
    let addr = proxy.local_addr();
    {
        let mut s = TcpStream::connect(addr).await.unwrap();
        let mut got = 0;
        let mut chunk = vec![0u8; 4096];
        while got < 10_000 {
            let n = s.read(&mut chunk).await.unwrap();
            assert!(n > 0);
            got += n;
        }
        // Dropped with unread data: the kernel resets the connection.
    }
    // The bucket refills while idle; one burst of it is in the expectation below.
    tokio::time::sleep(Duration::from_millis(20)).await;
    let (_, total, data) = fetch(addr).await;
    assert_eq!(data.len(), N);
    let burst = Link::burst(link.down_bps) as f64;
    within("the next transfer", total, (N as f64 - burst) / 250_000.0);
}
