//! Clients and operators that do not play along: idle and trickling connections, answers
//! nobody reads, a served file changed underneath the server.
//!
//! The flood tests run the server in a child process ([`crate::child`]), so that its
//! file-descriptor limit and its memory are its own to lower and to measure. Everything listens
//! and connects on 127.0.0.1 only.

use std::io::{Seek, SeekFrom, Write};
use std::time::{Duration, Instant};

use crate::child::*;
use crate::util::*;
use cbdam_server::{AppState, Config, RepoSpec};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

#[tokio::test]
async fn an_idle_flood_does_not_keep_a_normal_request_out() {
    // 128 file descriptors: 300 idle connections would take every one of them.
    let mut server = Child::start("nofile=128");
    let flood = idle_connections(server.addr, 300).await;
    // More than the server has descriptors for (connections left in the listen backlog count).
    assert!(flood.len() > 128, "{} connections", flood.len());
    // Let the server take them in (not a bound on anything).
    tokio::time::sleep(Duration::from_millis(300)).await;
    let c = client();
    for _ in 0..3 {
        let r = tokio::time::timeout(
            Duration::from_secs(1),
            c.get(server.url("/v1/repos/t/meta")).send(),
        )
        .await
        .expect("a normal request is answered within 1 s during the flood")
        .unwrap();
        assert_eq!(r.status(), 200);
    }
    assert!(server.alive());
    assert!(server.fds() <= 128, "{} descriptors", server.fds());
    drop(flood);
}

#[tokio::test]
async fn a_flood_over_max_connections_does_not_keep_a_normal_request_out() {
    let s = start_one(Config {
        max_connections: 16,
        ..Config::default()
    })
    .await;
    let flood = idle_connections(s.addr, 100).await;
    assert_eq!(flood.len(), 100);
    let c = client();
    for _ in 0..3 {
        let r = tokio::time::timeout(
            Duration::from_secs(1),
            c.get(s.url("/v1/repos/t/meta")).send(),
        )
        .await
        .expect("a normal request is answered within 1 s during the flood")
        .unwrap();
        assert_eq!(r.status(), 200);
    }
    // The flood's oldest connections were closed to make room.
    let mut closed = 0;
    for mut f in flood.into_iter().take(50) {
        if closed_by_server(&mut f, Duration::from_secs(5)).await {
            closed += 1;
        }
    }
    assert_eq!(closed, 50);
    s.stop().await;
}

/// Reads from `s` until the server closes it, for at most `limit`; whether it did.
async fn closed_by_server(s: &mut TcpStream, limit: Duration) -> bool {
    let mut buf = [0u8; 4096];
    tokio::time::timeout(limit, async {
        loop {
            match s.read(&mut buf).await {
                Ok(0) | Err(_) => return,
                Ok(_) => {}
            }
        }
    })
    .await
    .is_ok()
}

#[tokio::test]
async fn slow_and_silent_connections_are_closed_after_the_header_timeout() {
    let s = start_one(Config {
        header_read_timeout: Duration::from_millis(500),
        ..Config::default()
    })
    .await;

    // A connection that never sends a byte.
    let mut silent = TcpStream::connect(s.addr).await.unwrap();
    assert!(closed_by_server(&mut silent, Duration::from_secs(10)).await);

    // HTTP/2's preface and settings, then nothing.
    let mut h2 = TcpStream::connect(s.addr).await.unwrap();
    h2.write_all(b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n\0\0\0\x04\0\0\0\0\0")
        .await
        .unwrap();
    assert!(closed_by_server(&mut h2, Duration::from_secs(10)).await);

    // A header line every 200 ms: the headers never end. Closed long before the 50 lines.
    let mut trickle = TcpStream::connect(s.addr).await.unwrap();
    trickle
        .write_all(b"GET /v1/repos HTTP/1.1\r\nhost: x\r\n")
        .await
        .unwrap();
    let mut closed = false;
    for _ in 0..50 {
        if closed_by_server(&mut trickle, Duration::from_millis(200)).await
            || trickle.write_all(b"x-slow: 1\r\n").await.is_err()
        {
            closed = true;
            break;
        }
    }
    assert!(closed, "a trickled header was still read after 10 s");

    // A keep-alive connection that has been answered and then stays idle.
    let mut idle = TcpStream::connect(s.addr).await.unwrap();
    idle.write_all(b"GET /v1/repos HTTP/1.1\r\nhost: x\r\n\r\n")
        .await
        .unwrap();
    let mut head = [0u8; 12];
    idle.read_exact(&mut head).await.unwrap();
    assert_eq!(&head, b"HTTP/1.1 200");
    assert!(closed_by_server(&mut idle, Duration::from_secs(10)).await);

    // Meanwhile and afterwards, normal requests are answered.
    let r = client().get(s.url("/v1/repos")).send().await.unwrap();
    assert_eq!(r.status(), 200);
    s.stop().await;
}

/// Serves `path` as `t` (opened from the file), its records held in memory or read from the
/// file as asked for.
async fn serve_file(path: &std::path::Path, held: bool) -> Running {
    let spec: RepoSpec = format!("t={}", path.display()).parse().unwrap();
    let config = Config {
        held_records_bytes: if held { 1 << 30 } else { 1 },
        ..Config::default()
    };
    start(AppState::open(&[spec], config).unwrap()).await
}

#[tokio::test]
async fn a_file_replaced_by_a_rename_keeps_being_served_as_it_was() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t.cbdam");
    std::fs::write(&path, image(1)).unwrap();
    let s = serve_file(&path, false).await;
    let old = repo(1);
    let e = old
        .head()
        .entries()
        .iter()
        .max_by_key(|e| e.length)
        .unwrap();
    let url = s.url(&format!("/v1/repos/t/diamonds/{}", e.id));
    let c = client();
    let r = c.get(&url).send().await.unwrap();
    let etag = r.headers()["etag"].clone();
    // A rebuild written to a new file and renamed over the old one (what `cbdam build` does).
    let new = dir.path().join("t.cbdam.new");
    std::fs::write(&new, image(2)).unwrap();
    std::fs::rename(&new, &path).unwrap();
    let r = c.get(&url).send().await.unwrap();
    assert_eq!(r.status(), 200);
    assert_eq!(r.headers()["etag"], etag);
    assert_eq!(&r.bytes().await.unwrap()[..], old.record(e.id).unwrap());
    s.stop().await;
}

#[tokio::test]
async fn a_file_changed_in_place_is_refused_not_served() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t.cbdam");
    let bytes = image(1);
    std::fs::write(&path, &bytes).unwrap();
    let s = serve_file(&path, false).await;
    let held_server = serve_file(&path, true).await;
    let repo = repo(1);
    let e = repo
        .head()
        .entries()
        .iter()
        .max_by_key(|e| e.length)
        .unwrap();
    let all_ids: Vec<String> = repo
        .head()
        .entries()
        .iter()
        .map(|e| e.id.to_string())
        .collect();
    let batch = serde_json::json!({ "ids": all_ids }).to_string();
    let c = client();
    let record = s.url(&format!("/v1/repos/t/diamonds/{}", e.id));
    let held_record = held_server.url(&format!("/v1/repos/t/diamonds/{}", e.id));
    let held = client();
    assert_eq!(held.get(&held_record).send().await.unwrap().status(), 200);
    let urls = [
        record.clone(),
        s.url("/v1/repos/t/meta"),
        s.url("/v1/repos/t/file"),
    ];
    let batch_url = s.url("/v1/repos/t/diamonds");
    let mut etags = Vec::new();
    for u in &urls {
        let r = c.get(u).send().await.unwrap();
        assert_eq!(r.status(), 200, "{u}");
        etags.push(r.headers()["etag"].clone());
    }
    let r = c.post(&batch_url).body(batch.clone()).send().await.unwrap();
    assert_eq!(parse_batch(&r.bytes().await.unwrap()).len(), all_ids.len());

    // One byte of the record changed in place, the modification time put back: the file looks
    // the same to stat, but the record's bytes are no longer what its ETag names. It was
    // checked once already; read from the file, it is checked again.
    let at = repo
        .head()
        .section_offset(cbdam_codec::repository::Section::Records)
        + e.offset
        + 1;
    let f = std::fs::OpenOptions::new().write(true).open(&path).unwrap();
    let mtime = f.metadata().unwrap().modified().unwrap();
    (&f).seek(SeekFrom::Start(at)).unwrap();
    (&f).write_all(&[bytes[at as usize] ^ 0x40]).unwrap();
    f.set_modified(mtime).unwrap();
    drop(f);
    let msg = error_body(c.get(&record).send().await.unwrap(), 500).await;
    assert!(msg.contains("damaged"), "{msg}");
    let r = c.post(&batch_url).body(batch.clone()).send().await.unwrap();
    error_body(r, 500).await;
    // Held in memory, the record is served as it was read at startup: what its ETag names.
    let r = held.get(&held_record).send().await.unwrap();
    assert_eq!(r.status(), 200);
    assert_eq!(r.headers()["etag"], etags[0]);
    assert_eq!(&r.bytes().await.unwrap()[..], repo.record(e.id).unwrap());

    // Overwritten in place with another repository (a rebuild into the same file): every
    // endpoint that reads it refuses, with or without the old ETag, and says why.
    std::thread::sleep(Duration::from_millis(20)); // a later modification time
    std::fs::write(&path, image(2)).unwrap();
    for (u, etag) in urls.iter().zip(&etags) {
        for revalidate in [false, true] {
            let mut req = c.get(u);
            if revalidate {
                req = req.header("if-none-match", etag.clone());
            }
            let msg = error_body(req.send().await.unwrap(), 500).await;
            assert!(msg.contains("changed on disk"), "{u}: {msg}");
        }
    }
    let r = c.post(&batch_url).body(batch.clone()).send().await.unwrap();
    let msg = error_body(r, 500).await;
    assert!(msg.contains("changed on disk"), "{msg}");
    // Held in memory or not, a file changed in place is refused.
    let msg = error_body(held.get(&held_record).send().await.unwrap(), 500).await;
    assert!(msg.contains("changed on disk"), "{msg}");
    held_server.stop().await;

    // Truncated: refused the same way, and the server lives on.
    std::fs::OpenOptions::new()
        .write(true)
        .open(&path)
        .unwrap()
        .set_len(100)
        .unwrap();
    for u in &urls {
        error_body(c.get(u).send().await.unwrap(), 500).await;
    }
    let r = c.post(&batch_url).body(batch).send().await.unwrap();
    error_body(r, 500).await;
    let r = c.get(s.url("/v1/repos")).send().await.unwrap();
    assert_eq!(r.status(), 200);
    s.stop().await;
}

#[tokio::test]
async fn oversized_requests_get_json_errors_over_http1_and_h2() {
    let s = start_one(Config {
        max_body: 4096,
        ..Config::default()
    })
    .await;
    let h2 = reqwest::Client::builder()
        .http2_prior_knowledge()
        .build()
        .unwrap();
    // A body over --max-body, still being sent when the server answers.
    let huge = format!(r#"{{"ids":["{}"]}}"#, "1".repeat(1 << 20));
    for c in [&client(), &h2] {
        let r = c
            .post(s.url("/v1/repos/t/diamonds"))
            .body(huge.clone())
            .send()
            .await
            .expect("an answer, not a reset stream");
        let msg = error_body(r, 413).await;
        assert!(msg.contains("4096"), "{msg}");
    }
    // Heads larger than the server reads: a long target, many or long header fields.
    let c = client();
    let long = s.url(&format!("/v1/repos/{}", "a".repeat(10_000)));
    error_body(c.get(&long).send().await.unwrap(), 414).await;
    let mut many = c.get(s.url("/v1/repos"));
    for i in 0..110 {
        many = many.header(format!("x-h{i}"), "1");
    }
    error_body(many.send().await.unwrap(), 431).await;
    let r = c
        .get(s.url("/v1/repos"))
        .header("x-long", "v".repeat(12_000))
        .send()
        .await
        .unwrap();
    error_body(r, 431).await;
    // Over h2 too.
    error_body(h2.get(&long).send().await.unwrap(), 414).await;
    s.stop().await;
}

/// Latencies of `n` sequential `GET url` on one keep-alive client, each given 1 s: the 50th and
/// 99th percentiles and the slowest, and how many were not answered 200 in time.
async fn latencies(
    c: &reqwest::Client,
    url: &str,
    n: usize,
) -> (Duration, Duration, Duration, usize) {
    let mut took = Vec::with_capacity(n);
    let mut failed = 0;
    for _ in 0..n {
        let t = Instant::now();
        let answered = tokio::time::timeout(Duration::from_secs(1), async {
            let r = c.get(url).send().await.ok()?;
            (r.status() == 200).then_some(())?;
            r.bytes().await.ok()
        })
        .await;
        match answered {
            Ok(Some(_)) => took.push(t.elapsed()),
            _ => failed += 1,
        }
    }
    took.sort();
    let at = |q: f64| {
        took.get(((took.len() as f64 * q) as usize).min(took.len().saturating_sub(1)))
            .copied()
            .unwrap_or_default()
    };
    (at(0.5), at(0.99), at(1.0), failed)
}

/// The figures of the server under floods: file descriptors, resident memory and the latency of
/// normal requests during 10 000 idle connections, then during 1 000 unread batch answers.
/// Minutes long; run it alone:
/// `cargo test -p cbdam-server --test tests hostile::flood_figures -- --ignored --nocapture`
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "a measurement, not a check: run it alone"]
async fn flood_figures() {
    let limit = set_fd_limit(u64::MAX);
    assert!(
        limit > 12_000,
        "needs a file-descriptor hard limit over 12 000, not {limit}"
    );
    let mut server = Child::start(&format!("nofile={limit}"));
    let c = client();
    let meta = server.url("/v1/repos/t/meta");
    let report = |phase: &str, server: &Child, l: (Duration, Duration, Duration, usize)| {
        eprintln!(
            "{phase}: {} fds, RSS {} MB, GET meta p50 {:.2} ms, p99 {:.2} ms, max {:.2} ms, {} of 200 not answered within 1 s",
            server.fds(),
            server.rss() >> 20,
            l.0.as_secs_f64() * 1e3,
            l.1.as_secs_f64() * 1e3,
            l.2.as_secs_f64() * 1e3,
            l.3
        );
    };
    let l = latencies(&c, &meta, 200).await;
    report("idle server", &server, l);

    let idle = idle_connections(server.addr, 10_000).await;
    eprintln!("{} idle connections opened", idle.len());
    tokio::time::sleep(Duration::from_secs(1)).await;
    let l = latencies(&c, &meta, 200).await;
    report("10 000 idle connections", &server, l);
    drop(idle);
    tokio::time::sleep(Duration::from_secs(2)).await;

    let (req, answer) = big_batch(4096);
    let mut held = Vec::with_capacity(1000);
    for _ in 0..1000 {
        held.push(unread_request(server.addr, &req).await);
    }
    settled_rss(&server, Duration::from_secs(20)).await;
    let l = latencies(&c, &meta, 200).await;
    report(
        &format!("1 000 unread batch answers of {} MB", answer >> 20),
        &server,
        l,
    );
    assert!(server.alive());
}

/// An HTTP/2 batch request whose body is over `--max-body` gets its 413 on a stream the server
/// ends cleanly: not reset before or after the answer (some clients report any reset as a
/// failed request, whatever answer came first).
#[tokio::test]
async fn an_oversized_h2_body_gets_its_413_without_a_stream_reset() {
    let s = start_one(Config {
        max_body: 4096,
        ..Config::default()
    })
    .await;
    let tcp = TcpStream::connect(s.addr).await.unwrap();
    let (h2, conn) = h2::client::handshake(tcp).await.unwrap();
    tokio::spawn(conn);
    let mut h2 = h2.ready().await.unwrap();
    let req = axum::http::Request::post(s.url("/v1/repos/t/diamonds"))
        .body(())
        .unwrap();
    let (resp, mut send) = h2.send_request(req, false).unwrap();
    send.send_data(bytes::Bytes::from(vec![b'1'; 256 << 10]), true)
        .unwrap();
    let resp = resp.await.expect("an answer, not a reset stream");
    assert_eq!(resp.status(), 413);
    let mut body = resp.into_body();
    let mut text = Vec::new();
    while let Some(chunk) = body.data().await {
        let chunk = chunk.expect("the whole answer, not a reset stream");
        let _ = body.flow_control().release_capacity(chunk.len());
        text.extend_from_slice(&chunk);
    }
    let v: serde_json::Value = serde_json::from_slice(&text).unwrap();
    assert_eq!(v["status"], 413);
    // A second request on the connection: frames arrive in order, so a reset of the first
    // stream sent with or after its answer has arrived once this is answered.
    let mut h2 = h2.ready().await.unwrap();
    let (resp, _) = h2
        .send_request(
            axum::http::Request::get(s.url("/v1/repos"))
                .body(())
                .unwrap(),
            true,
        )
        .unwrap();
    assert_eq!(resp.await.unwrap().status(), 200);
    let reset = std::future::poll_fn(|cx| {
        std::task::Poll::Ready(match send.poll_reset(cx) {
            std::task::Poll::Ready(r) => Some(r),
            std::task::Poll::Pending => None,
        })
    })
    .await;
    assert!(reset.is_none(), "the stream was reset: {reset:?}");
    s.stop().await;
}

/// The hot path's figure: sequential single-record `GET`s on one keep-alive connection against
/// a repository served from its file. Run alone:
/// `cargo test -p cbdam-server --test tests hostile::record_figures -- --ignored --nocapture`
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "a measurement, not a check: run it alone"]
async fn record_figures() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t.cbdam");
    let repo = noise_repo();
    std::fs::write(&path, repo.as_bytes()).unwrap();
    let s = serve_file(&path, false).await;
    let c = client();
    let urls: Vec<String> = repo
        .head()
        .entries()
        .iter()
        .filter(|e| e.length > 0)
        .map(|e| s.url(&format!("/v1/repos/t/diamonds/{}", e.id)))
        .collect();
    let mut bytes = 0;
    for round in 0..6 {
        let n = 4000;
        let t = Instant::now();
        for u in urls.iter().cycle().take(n) {
            bytes += c.get(u).send().await.unwrap().bytes().await.unwrap().len();
        }
        let took = t.elapsed();
        if round > 0 {
            eprintln!(
                "{n} record GETs: {:.1} µs each",
                took.as_secs_f64() * 1e6 / n as f64
            );
        }
    }
    assert!(bytes > 0);
    s.stop().await;
}
