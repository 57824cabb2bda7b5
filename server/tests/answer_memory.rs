//! Answers nobody reads, from many connections at once: the server holds at most its answer
//! memory (`Config::answer_memory`) of them in all, closes the connections that stopped
//! reading to make room, and keeps answering normal requests meanwhile.

use std::time::{Duration, Instant};

use crate::child::*;
use crate::util::*;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

/// Unread batch answers in each flood.
const UNREAD: usize = 400;

/// How long a normal request may take during a flood. What this guards is a server that stops
/// answering while its answer memory is full (it would never answer); the time it takes is
/// printed, not judged: on a shared 2-core machine under load 16 a `GET …/meta` took over 1 s
/// (the first deadline) with the server healthy.
const NORMAL_DEADLINE: Duration = Duration::from_secs(10);

/// What a flood of [`UNREAD`] unread batch answers did to a server.
struct Flood {
    /// Resident memory before and during the flood, bytes.
    before: u64,
    during: u64,
    /// The server's own gauge of answer bytes held, during the flood.
    held: u64,
    /// Connections the server closed to make room.
    closed: u64,
    /// The slowest of the normal requests made during the flood.
    slowest: Duration,
}

/// The value of the metric `name` in the server's `/metrics`.
async fn metric(c: &reqwest::Client, server: &Child, name: &str) -> u64 {
    let text = c
        .get(server.url("/metrics"))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    text.lines()
        .find_map(|l| l.strip_prefix(name)?.strip_prefix(' '))
        .unwrap_or_else(|| panic!("no {name} in /metrics"))
        .parse()
        .unwrap()
}

/// Reads a batch answer of `len` bytes to its end from `s`, after its head.
async fn read_answer(s: &mut TcpStream, len: usize) {
    let mut all = Vec::new();
    let mut buf = vec![0u8; 1 << 16];
    // The head ends with a blank line; the body is `len` bytes after it.
    loop {
        let n = s.read(&mut buf).await.unwrap();
        assert!(n > 0, "answer cut short");
        all.extend_from_slice(&buf[..n]);
        if let Some(at) = all.windows(4).position(|w| w == b"\r\n\r\n")
            && all.len() >= at + 4 + len
        {
            assert!(all.starts_with(b"HTTP/1.1 200"));
            return;
        }
    }
}

/// Normal requests during a flood, each given [`NORMAL_DEADLINE`]: a `GET …/meta` and a
/// 64-id batch read to its end. The slowest.
async fn normal_requests(c: &reqwest::Client, server: &Child) -> Duration {
    let (small, small_len) = big_batch(64);
    let mut slowest = Duration::ZERO;
    for _ in 0..3 {
        let t = Instant::now();
        let meta = c.get(server.url("/v1/repos/t/meta")).send();
        let r = tokio::time::timeout(NORMAL_DEADLINE, meta)
            .await
            .expect("GET meta answered during the flood")
            .unwrap();
        assert_eq!(r.status(), 200);
        let mut s = TcpStream::connect(server.addr).await.unwrap();
        s.write_all(&small).await.unwrap();
        tokio::time::timeout(NORMAL_DEADLINE, read_answer(&mut s, small_len))
            .await
            .expect("a 64-id batch answered during the flood");
        slowest = slowest.max(t.elapsed());
    }
    slowest
}

/// Floods a server started with `settings` with [`UNREAD`] batch requests whose answers
/// (megabytes each) nobody reads, and measures it.
async fn flood(settings: &str) -> Flood {
    let mut server = Child::start(settings);
    let (req, answer) = big_batch(4096);
    // Each answer is far more than socket buffers hold.
    assert!(answer > 1 << 20, "{answer}");
    // Warm up (allocator pools, the runtime's threads) with batches read to the end.
    for _ in 0..2 {
        let mut s = TcpStream::connect(server.addr).await.unwrap();
        s.write_all(&req).await.unwrap();
        read_answer(&mut s, answer).await;
    }
    let before = settled_rss(&server, Duration::from_secs(5)).await;
    let mut unread = Vec::with_capacity(UNREAD);
    for _ in 0..UNREAD {
        unread.push(unread_request(server.addr, &req).await);
    }
    let during = settled_rss(&server, Duration::from_secs(10)).await;
    let c = client();
    let slowest = normal_requests(&c, &server).await;
    let held = metric(&c, &server, "cbdam_answer_bytes_held").await;
    let closed = metric(&c, &server, "cbdam_connections_closed_for_memory_total").await;
    assert!(server.alive());
    drop(unread);
    Flood {
        before,
        during,
        held,
        closed,
        slowest,
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn unread_batch_answers_are_capped_in_memory_over_all_connections() {
    let cap: u64 = 4 << 20;
    let capped = flood(&format!("answer_memory={cap}")).await;
    // The same flood against a budget it cannot reach: only the per-connection bound.
    let uncapped = flood(&format!("answer_memory={}", 1u64 << 32)).await;
    for (name, f) in [("capped", &capped), ("uncapped", &uncapped)] {
        eprintln!(
            "{name}: {UNREAD} unread batch answers: RSS {} → {} MiB, answer bytes held {} KiB, \
             {} connections closed for memory, slowest normal request {:.1} ms",
            f.before >> 20,
            f.during >> 20,
            f.held >> 10,
            f.closed,
            f.slowest.as_secs_f64() * 1e3
        );
    }
    assert!(capped.held <= cap, "{} bytes held", capped.held);
    assert!(capped.closed > 0, "no stalled connection was closed");
    // Without the cap the same flood holds more: the test can fail.
    assert!(uncapped.held > 2 * cap, "the flood never needed the cap");
    // What the cap kept from being held is memory the server did not take: at least half of
    // it shows in its resident memory (the rest is allocator noise and per-connection state).
    let grew = |f: &Flood| f.during.saturating_sub(f.before);
    let kept_out = uncapped.held - capped.held;
    assert!(
        grew(&uncapped).saturating_sub(grew(&capped)) > kept_out / 2,
        "RSS grew {} MiB capped, {} MiB without; {} MiB of answers kept out",
        grew(&capped) >> 20,
        grew(&uncapped) >> 20,
        kept_out >> 20
    );
}
