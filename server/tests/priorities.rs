//! Batches with priorities (answered most urgent first) and batches whose client goes away
//! (the server stops writing and counts what it did not send).

use std::time::{Duration, Instant};

use cbdam_codec::geometry::DiamondId;
use cbdam_server::{AppState, Config};
use tokio::io::{AsyncReadExt, AsyncWriteExt};

use crate::util::{client, error_body, parse_batch, repo, start_one};

#[tokio::test]
async fn batches_with_priorities_answer_the_most_urgent_first() {
    let s = start_one(Config::default()).await;
    let c = client();
    let repo = &s.state.repo("t").unwrap().repo;
    let url = s.url("/v1/repos/t/diamonds");
    // Distinct non-empty records, so that each answer names its id.
    let mut ids: Vec<DiamondId> = Vec::new();
    for e in repo.head().entries() {
        let r = repo.record(e.id).unwrap();
        if !r.is_empty() && ids.iter().all(|&d| repo.record(d).unwrap() != r) {
            ids.push(e.id);
        }
        if ids.len() == 6 {
            break;
        }
    }
    assert_eq!(ids.len(), 6);
    // Scrambled priorities with a tie (request order breaks it) and a not-stored id.
    let priorities = [0.5f32, 7.0, 2.0, 7.0, 0.25, 3.0, 1.0];
    let mut names: Vec<String> = ids.iter().map(ToString::to_string).collect();
    names.push("0-999999-0".into());
    let want_order = [1usize, 3, 5, 2, 6, 0, 4];
    let body = serde_json::json!({ "ids": names, "priorities": priorities }).to_string();
    let r = c
        .post(&url)
        .header("content-type", "application/json")
        .body(body)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    let got = parse_batch(&r.bytes().await.unwrap());
    let expected: Vec<Option<Vec<u8>>> = want_order
        .iter()
        .map(|&k| ids.get(k).map(|&d| repo.record(d).unwrap().to_vec()))
        .collect();
    assert_eq!(got, expected);

    // One priority per id, or the request is refused.
    let bad = serde_json::json!({ "ids": names, "priorities": [1.0] }).to_string();
    let msg = error_body(
        c.post(&url)
            .header("content-type", "application/json")
            .body(bad)
            .send()
            .await
            .unwrap(),
        400,
    )
    .await;
    assert!(msg.contains("1 priorities for 7 ids"), "{msg}");
    // Finished batches are not aborted ones.
    assert_eq!(s.state.metrics().aborted_batches(), (0, 0));
    s.stop().await;
}

/// A client that reads a little of a large batch and closes the connection: the server stops
/// writing it and counts one aborted batch with the bytes it never sent.
#[tokio::test]
async fn a_dropped_batch_stops_the_server_writing() {
    let state = AppState::new(
        vec![("t".into(), repo(1))],
        Config {
            max_batch: 200_000,
            max_body: 8 << 20,
            ..Config::default()
        },
    )
    .unwrap();
    let largest = {
        let r = &state.repo("t").unwrap().repo;
        r.head()
            .entries()
            .iter()
            .max_by_key(|e| e.length)
            .unwrap()
            .id
    };
    // Small socket buffers on both ends, so that the server cannot have written the whole
    // body into the kernel by the time the client goes.
    let socket = tokio::net::TcpSocket::new_v4().unwrap();
    socket.set_send_buffer_size(4096).unwrap();
    socket.bind("127.0.0.1:0".parse().unwrap()).unwrap();
    let listener = socket.listen(16).unwrap();
    let s = start_on(listener, state).await;

    let names: Vec<String> = (0..100_000).map(|_| largest.to_string()).collect();
    let body = serde_json::json!({ "ids": names }).to_string();
    let full = {
        let r = &s.state.repo("t").unwrap().repo;
        8 + 100_000 * (5 + r.record(largest).unwrap().len() as u64)
    };
    let socket = tokio::net::TcpSocket::new_v4().unwrap();
    socket.set_recv_buffer_size(4096).unwrap();
    let mut conn = socket.connect(s.addr).await.unwrap();
    let request = format!(
        "POST /v1/repos/t/diamonds HTTP/1.1\r\nhost: x\r\ncontent-type: application/json\r\n\
         content-length: {}\r\n\r\n{body}",
        body.len()
    );
    conn.write_all(request.as_bytes()).await.unwrap();
    let mut got = vec![0u8; 2048];
    let mut n = 0;
    while n < 1024 {
        let k = conn.read(&mut got[n..]).await.unwrap();
        assert!(k > 0, "the server closed early");
        n += k;
    }
    assert!(got.starts_with(b"HTTP/1.1 200"));
    drop(conn);

    let t0 = Instant::now();
    let (aborted, unsent) = loop {
        let m = s.state.metrics().aborted_batches();
        if m.0 > 0 || t0.elapsed() > Duration::from_secs(10) {
            break m;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    assert_eq!(aborted, 1, "the dropped batch is counted once");
    // Most of the body was never written: the server stopped, it did not push it all out.
    assert!(unsent > full / 2, "{unsent} of {full} bytes unsent");
    let text = s.state.metrics().render();
    assert!(text.contains("cbdam_batches_aborted_total 1"), "{text}");
    // Only the records handed over count as sent, not the whole batch.
    let sent: u64 = text
        .lines()
        .find_map(|l| l.strip_prefix("cbdam_records_sent_total "))
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or_else(|| panic!("no records_sent_total in {text}"));
    assert!(sent < 50_000, "{sent} of 100000 records counted as sent");
    s.stop().await;
}

async fn start_on(listener: tokio::net::TcpListener, state: AppState) -> crate::util::Running {
    let addr = listener.local_addr().unwrap();
    let (tx, rx) = tokio::sync::oneshot::channel::<()>();
    let task = tokio::spawn(cbdam_server::run(listener, state.clone(), async {
        let _ = rx.await;
    }));
    crate::util::Running {
        base: format!("http://{addr}"),
        addr,
        state,
        shutdown: Some(tx),
        task,
    }
}
