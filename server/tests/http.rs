//! `cbdam serve` end to end: a real server on a loopback port driven by a real HTTP client.

use std::time::Duration;

use crate::util::*;
use cbdam_codec::geometry::DiamondId;
use cbdam_codec::repository::Section;
use cbdam_server::{AppState, Config};
use reqwest::StatusCode;
use tokio::io::{AsyncReadExt, AsyncWriteExt};

const IMMUTABLE: &str = "public, max-age=31536000, immutable";

#[tokio::test]
async fn listing_and_meta() {
    let s = start(
        AppState::new(
            vec![("a".into(), repo(1)), ("b.v2".into(), repo(2))],
            Config::default(),
        )
        .unwrap(),
    )
    .await;
    let c = client();
    let v = json(c.get(s.url("/v1/repos")).send().await.unwrap()).await;
    assert_eq!(
        v,
        serde_json::json!({"repos": [
            {"name": "a", "meta": "/v1/repos/a/meta"},
            {"name": "b.v2", "meta": "/v1/repos/b.v2/meta"},
        ]})
    );

    let r = c.get(s.url("/v1/repos/b.v2/meta")).send().await.unwrap();
    assert_eq!(r.status(), 200);
    assert_eq!(r.headers()["content-type"], "application/json");
    let etag = r.headers()["etag"].clone();
    let m = json(r).await;
    let repo = &s.state.repo("b.v2").unwrap().repo;
    assert_eq!(m["name"], "b.v2");
    assert_eq!(m["file"], "/v1/repos/b.v2/file");
    assert_eq!(m["diamonds"], "/v1/repos/b.v2/diamonds");
    assert_eq!(m["diamond_size"], 9);
    assert_eq!(m["data_width"], 61);
    assert_eq!(m["data_height"], 45);
    assert_eq!(m["records"], repo.head().entries().len());
    assert_eq!(m["file_bytes"], repo.head().file_len());
    assert_eq!(m["coder"], "adaptive-tokens");
    assert_eq!(m["alpha"], "1");
    assert_eq!(m["max_error_requested_m"], 0.5);
    assert_eq!(m["georef"]["epsg"], 32632);
    assert_eq!(m["georef"]["pixel_x"], 30.0);
    assert_eq!(
        m["extent"]["bbox"],
        serde_json::json!([
            400_000.0,
            5_100_000.0 - 45.0 * 30.0,
            400_000.0 + 61.0 * 30.0,
            5_100_000.0
        ])
    );
    assert_eq!(
        m["levels"].as_array().unwrap().len(),
        usize::from(repo.head().params().layout().finest_level()) + 1
    );
    // head_len: everything before the records area, which is last.
    let head = repo.head().section_offset(Section::Records);
    assert_eq!(m["head_len"], head);
    assert_eq!(
        head + repo.head().section_len(Section::Records),
        repo.head().file_len()
    );
    assert_eq!(m["sections"]["records"]["offset"], head);
    assert_eq!(
        m["sections"]["roots"]["length"],
        repo.head().section_len(Section::Roots)
    );
    assert_eq!(
        m["root_values"]["head_range"],
        format!("bytes=0-{}", head - 1)
    );
    let roots: Vec<DiamondId> = m["roots"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r.as_str().unwrap().parse().unwrap())
        .collect();
    assert_eq!(
        roots,
        repo.head().params().layout().roots().collect::<Vec<_>>()
    );
    assert!(!roots.is_empty() && roots.iter().all(|r| r.level == 0));

    // Revalidation: the same ETag gives 304 with no body.
    let r = c
        .get(s.url("/v1/repos/b.v2/meta"))
        .header("if-none-match", etag.clone())
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), StatusCode::NOT_MODIFIED);
    assert_eq!(r.headers()["etag"], etag);
    assert!(r.bytes().await.unwrap().is_empty());
    // Different repositories (different files) have different validators.
    let other = c.get(s.url("/v1/repos/a/meta")).send().await.unwrap();
    assert_ne!(other.headers()["etag"], etag);
    s.stop().await;
}

#[tokio::test]
async fn single_records_with_etags() {
    let s = start_one(Config::default()).await;
    let c = client();
    let repo = &s.state.repo("t").unwrap().repo;
    let mut empty = 0;
    let mut etags = std::collections::HashSet::new();
    for e in repo.head().entries() {
        let r = c
            .get(s.url(&format!("/v1/repos/t/diamonds/{}", e.id)))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 200, "{}", e.id);
        assert_eq!(r.headers()["content-type"], "application/octet-stream");
        assert_eq!(r.headers()["cache-control"], IMMUTABLE);
        let etag = r.headers()["etag"].to_str().unwrap().to_string();
        assert!(
            etag.starts_with('"') && etag.ends_with('"'),
            "strong: {etag}"
        );
        let body = r.bytes().await.unwrap();
        assert_eq!(&body[..], repo.record(e.id).unwrap(), "{}", e.id);
        if body.is_empty() {
            empty += 1;
        } else {
            etags.insert(etag);
        }
    }
    assert!(
        empty > 0,
        "the fixture has empty records, served as 200 with no body"
    );
    // Distinct non-empty records almost surely have distinct CRCs here.
    assert!(etags.len() > repo.head().entries().len() / 2);

    let e = repo.head().entries().iter().find(|e| e.length > 0).unwrap();
    let url = s.url(&format!("/v1/repos/t/diamonds/{}", e.id));
    let etag = c.get(&url).send().await.unwrap().headers()["etag"].clone();
    for inm in [
        etag.to_str().unwrap().to_string(),
        format!("W/{}", etag.to_str().unwrap()),
        format!("\"nope\", {}", etag.to_str().unwrap()),
        "*".to_string(),
    ] {
        let r = c
            .get(&url)
            .header("if-none-match", &inm)
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), StatusCode::NOT_MODIFIED, "{inm}");
        assert_eq!(r.headers()["etag"], etag);
        assert_eq!(r.headers()["cache-control"], IMMUTABLE);
        assert!(r.bytes().await.unwrap().is_empty());
    }
    let r = c
        .get(&url)
        .header("if-none-match", "\"other\"")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    assert_eq!(r.bytes().await.unwrap().len(), e.length as usize);
    s.stop().await;
}

#[tokio::test]
async fn bad_requests_are_json_errors() {
    let s = start_one(Config::default()).await;
    let c = client();
    let get = |p: &str| c.get(s.url(p)).send();
    let msg = error_body(get("/v1/repos/nope/meta").await.unwrap(), 404).await;
    assert!(msg.contains("nope"), "{msg}");
    error_body(get("/v1/repos/nope/diamonds/0-0-0").await.unwrap(), 404).await;
    error_body(get("/v1/repos/nope/file").await.unwrap(), 404).await;
    // Traversal-looking names are just names that are not in the map.
    error_body(get("/v1/repos/..%2F..%2Fetc/meta").await.unwrap(), 404).await;
    // Well-formed ids that are not stored: 404; malformed ones: 400.
    let msg = error_body(get("/v1/repos/t/diamonds/0-999999-0").await.unwrap(), 404).await;
    assert!(msg.contains("0-999999-0"), "{msg}");
    for bad in [
        "3-1", "a-b-c", "+1-2-3", "1-2-3-4", "300-1-1", "1--2", "-1-2-3",
    ] {
        let msg = error_body(
            get(&format!("/v1/repos/t/diamonds/{bad}")).await.unwrap(),
            400,
        )
        .await;
        assert!(msg.contains("malformed diamond id"), "{bad}: {msg}");
    }
    error_body(get("/nothing/here").await.unwrap(), 404).await;
    error_body(
        c.delete(s.url("/v1/repos/t/meta")).send().await.unwrap(),
        405,
    )
    .await;
    error_body(
        c.put(s.url("/v1/repos/t/diamonds")).send().await.unwrap(),
        405,
    )
    .await;
    s.stop().await;
}

async fn post(c: &reqwest::Client, url: &str, body: impl Into<reqwest::Body>) -> reqwest::Response {
    c.post(url)
        .header("content-type", "application/json")
        .body(body)
        .send()
        .await
        .unwrap()
}

#[tokio::test]
async fn batches_in_request_order() {
    let s = start_one(Config {
        max_batch: 64,
        max_body: 4096,
        ..Config::default()
    })
    .await;
    let c = client();
    let repo = &s.state.repo("t").unwrap().repo;
    let url = s.url("/v1/repos/t/diamonds");
    let stored: Vec<DiamondId> = repo.head().entries().iter().map(|e| e.id).collect();
    // Out of order, with duplicates, an empty record and ids that are not stored.
    let empty = repo
        .head()
        .entries()
        .iter()
        .find(|e| e.length == 0)
        .unwrap()
        .id;
    let mut ids: Vec<String> = vec![
        stored[stored.len() - 1].to_string(),
        "0-999999-0".into(),
        stored[0].to_string(),
        empty.to_string(),
        stored[0].to_string(),
        "200-1-1".into(),
    ];
    ids.extend(stored.iter().rev().take(20).map(|i| i.to_string()));
    let body = serde_json::json!({ "ids": ids }).to_string();
    let r = post(&c, &url, body).await;
    assert_eq!(r.status(), 200);
    assert_eq!(r.headers()["content-type"], "application/x-cbdam-records");
    let got = parse_batch(&r.bytes().await.unwrap());
    assert_eq!(got.len(), ids.len());
    for (id, g) in ids.iter().zip(&got) {
        let want = id
            .parse::<DiamondId>()
            .ok()
            .and_then(|d| repo.record(d).ok())
            .map(<[u8]>::to_vec);
        assert_eq!(g, &want, "{id}");
    }
    assert_eq!(got[1], None);
    assert_eq!(got[3], Some(vec![]));
    assert_eq!(got[2], got[4]);

    // An empty batch is a valid, empty answer.
    let r = post(&c, &url, r#"{"ids":[]}"#).await;
    assert_eq!(&r.bytes().await.unwrap()[..], b"CBDR\0\0\0\0");

    // Over the id limit, over the body limit.
    let many: Vec<String> = (0..65).map(|_| stored[0].to_string()).collect();
    let msg = error_body(
        post(&c, &url, serde_json::json!({ "ids": many }).to_string()).await,
        413,
    )
    .await;
    assert!(msg.contains("at most 64"), "{msg}");
    let huge = format!(r#"{{"ids":["{}"]}}"#, "1".repeat(5000));
    error_body(post(&c, &url, huge).await, 413).await;

    // Malformed bodies and ids.
    for bad in [
        "",
        "{",
        "[]",
        r#"{"ids": "0-0-0"}"#,
        r#"{"ids": [1, 2]}"#,
        r#"{"id": ["0-0-0"]}"#,
        "\u{0}\u{1}",
    ] {
        let msg = error_body(post(&c, &url, bad).await, 400).await;
        assert!(msg.contains("malformed batch request"), "{bad:?}: {msg}");
    }
    let msg = error_body(post(&c, &url, r#"{"ids":["0-0-0","x-1-2"]}"#).await, 400).await;
    assert!(msg.contains("\"x-1-2\" at position 1"), "{msg}");
    // Unknown repository.
    error_body(
        post(&c, &s.url("/v1/repos/zz/diamonds"), r#"{"ids":[]}"#).await,
        404,
    )
    .await;
    s.stop().await;
}

#[tokio::test]
async fn file_with_ranges() {
    let s = start_one(Config::default()).await;
    let c = client();
    let repo = &s.state.repo("t").unwrap().repo;
    let file = repo.as_bytes().to_vec();
    let len = file.len();
    let url = s.url("/v1/repos/t/file");
    let get = |range: Option<&str>| {
        let mut b = c.get(&url);
        if let Some(r) = range {
            b = b.header("range", r);
        }
        b.send()
    };

    let r = get(None).await.unwrap();
    assert_eq!(r.status(), 200);
    assert_eq!(r.headers()["accept-ranges"], "bytes");
    assert_eq!(r.headers()["content-length"], len.to_string().as_str());
    let etag = r.headers()["etag"].clone();
    assert_eq!(&r.bytes().await.unwrap()[..], &file[..]);

    let cases: [(&str, std::ops::Range<usize>); 5] = [
        ("bytes=0-9", 0..10),
        ("bytes=10-", 10..len),
        ("bytes=-16", len - 16..len),
        ("bytes=5-999999999", 5..len),
        ("bytes=-999999999", 0..len),
    ];
    for (h, want) in cases {
        let r = get(Some(h)).await.unwrap();
        assert_eq!(r.status(), StatusCode::PARTIAL_CONTENT, "{h}");
        assert_eq!(
            r.headers()["content-range"],
            format!("bytes {}-{}/{len}", want.start, want.end - 1).as_str(),
            "{h}"
        );
        assert_eq!(r.headers()["etag"], etag);
        assert_eq!(&r.bytes().await.unwrap()[..], &file[want], "{h}");
    }
    // The head range a client fetches to get everything but the records.
    let head = cbdam_server::head_len(repo) as usize;
    let r = get(Some(&format!("bytes=0-{}", head - 1))).await.unwrap();
    let got = r.bytes().await.unwrap();
    assert_eq!(&got[..], &file[..head]);
    // Every record is the same range of the file as what the record endpoint serves.
    let rec_at = repo.head().section_offset(Section::Records) as usize;
    let e = repo.head().entries().iter().find(|e| e.length > 3).unwrap();
    let a = rec_at + e.offset as usize;
    let r = get(Some(&format!("bytes={a}-{}", a + e.length as usize - 1)))
        .await
        .unwrap();
    assert_eq!(&r.bytes().await.unwrap()[..], repo.record(e.id).unwrap());

    for h in [
        format!("bytes={len}-"),
        format!("bytes={len}-{}", len + 5),
        "bytes=-0".into(),
    ] {
        let r = get(Some(&h)).await.unwrap();
        assert_eq!(
            r.headers()["content-range"],
            format!("bytes */{len}").as_str()
        );
        error_body(r, 416).await;
    }
    // Ignored Range headers: the whole file.
    for h in ["bytes=5-2", "bytes=0-1,4-5", "lines=1-2"] {
        let r = get(Some(h)).await.unwrap();
        assert_eq!(r.status(), 200, "{h}");
        assert_eq!(r.bytes().await.unwrap().len(), len);
    }
    // If-Range: current validator → the range; stale one → the whole file.
    let r = c
        .get(&url)
        .header("range", "bytes=0-3")
        .header("if-range", etag.clone())
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 206);
    let r = c
        .get(&url)
        .header("range", "bytes=0-3")
        .header("if-range", "\"stale\"")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    // If-None-Match.
    let r = c
        .get(&url)
        .header("if-none-match", etag.clone())
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 304);
    // HEAD: headers only.
    let r = c.head(&url).send().await.unwrap();
    assert_eq!(r.status(), 200);
    assert_eq!(r.headers()["content-length"], len.to_string().as_str());
    assert!(r.bytes().await.unwrap().is_empty());
    s.stop().await;
}

#[tokio::test]
async fn cors_headers() {
    let s = start_one(Config::default()).await;
    let c = client();
    let r = c
        .get(s.url("/v1/repos/t/meta"))
        .header("origin", "https://viewer.example")
        .send()
        .await
        .unwrap();
    assert_eq!(r.headers()["access-control-allow-origin"], "*");
    let exposed = r.headers()["access-control-expose-headers"]
        .to_str()
        .unwrap()
        .to_lowercase();
    assert!(
        exposed.contains("etag") && exposed.contains("content-range"),
        "{exposed}"
    );
    // A preflight for the batch POST with a JSON body.
    let r = c
        .request(reqwest::Method::OPTIONS, s.url("/v1/repos/t/diamonds"))
        .header("origin", "https://viewer.example")
        .header("access-control-request-method", "POST")
        .header("access-control-request-headers", "content-type")
        .send()
        .await
        .unwrap();
    assert!(r.status().is_success(), "{}", r.status());
    assert_eq!(r.headers()["access-control-allow-origin"], "*");
    let methods = r.headers()["access-control-allow-methods"]
        .to_str()
        .unwrap();
    assert!(methods.contains("POST"), "{methods}");
    s.stop().await;

    // A configured origin is echoed to that origin only.
    let s = start_one(Config {
        cors_origin: "https://a.example, https://b.example".into(),
        ..Config::default()
    })
    .await;
    let r = c
        .get(s.url("/v1/repos"))
        .header("origin", "https://b.example")
        .send()
        .await
        .unwrap();
    assert_eq!(
        r.headers()["access-control-allow-origin"],
        "https://b.example"
    );
    let r = c
        .get(s.url("/v1/repos"))
        .header("origin", "https://evil.example")
        .send()
        .await
        .unwrap();
    assert!(r.headers().get("access-control-allow-origin").is_none());
    s.stop().await;
    assert!(matches!(
        AppState::new(
            vec![("t".into(), repo(1))],
            Config {
                cors_origin: "bad\norigin".into(),
                ..Config::default()
            }
        ),
        Err(cbdam_server::ServerError::InvalidCorsOrigin(_))
    ));
}

#[tokio::test]
async fn h2c_prior_knowledge() {
    let s = start_one(Config::default()).await;
    let c = reqwest::Client::builder()
        .http2_prior_knowledge()
        .build()
        .unwrap();
    let repo = &s.state.repo("t").unwrap().repo;
    let e = repo.head().entries().iter().find(|e| e.length > 0).unwrap();
    // Several requests concurrently on the one HTTP/2 connection.
    let urls: Vec<String> = (0..8)
        .map(|_| s.url(&format!("/v1/repos/t/diamonds/{}", e.id)))
        .collect();
    let resps = futures_join(urls.iter().map(|u| c.get(u).send())).await;
    for r in resps {
        let r = r.unwrap();
        assert_eq!(r.version(), reqwest::Version::HTTP_2);
        assert_eq!(r.status(), 200);
        assert_eq!(&r.bytes().await.unwrap()[..], repo.record(e.id).unwrap());
    }
    let r = post(
        &c,
        &s.url("/v1/repos/t/diamonds"),
        format!(r#"{{"ids":["{}"]}}"#, e.id),
    )
    .await;
    assert_eq!(r.version(), reqwest::Version::HTTP_2);
    assert_eq!(parse_batch(&r.bytes().await.unwrap()).len(), 1);
    // And HTTP/1.1 on the same port.
    let r = client().get(s.url("/v1/repos")).send().await.unwrap();
    assert_eq!(r.version(), reqwest::Version::HTTP_11);
    s.stop().await;
}

/// Awaits all futures concurrently (no extra dependency for `join_all`).
async fn futures_join<F>(fs: impl Iterator<Item = F>) -> Vec<F::Output>
where
    F: std::future::Future + Send + 'static,
    F::Output: Send + 'static,
{
    let handles: Vec<_> = fs.map(tokio::spawn).collect();
    let mut out = Vec::new();
    for h in handles {
        out.push(h.await.unwrap());
    }
    out
}

#[tokio::test]
async fn metrics_count_requests() {
    let s = start_one(Config::default()).await;
    let c = client();
    let repo = &s.state.repo("t").unwrap().repo;
    let id = repo.head().entries()[0].id;
    for _ in 0..3 {
        let r = c
            .get(s.url(&format!("/v1/repos/t/diamonds/{id}")))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 200);
        r.bytes().await.unwrap();
    }
    c.get(s.url("/v1/repos/t/diamonds/x")).send().await.unwrap();
    c.get(s.url("/v1/repos/q/meta")).send().await.unwrap();
    post(
        &c,
        &s.url("/v1/repos/t/diamonds"),
        format!(r#"{{"ids":["{id}","{id}"]}}"#),
    )
    .await;
    let r = c.get(s.url("/metrics")).send().await.unwrap();
    assert_eq!(r.status(), 200);
    assert!(
        r.headers()["content-type"]
            .to_str()
            .unwrap()
            .starts_with("text/plain")
    );
    let t = r.text().await.unwrap();
    let has = |l: &str| assert!(t.lines().any(|x| x == l), "missing {l:?} in\n{t}");
    has(r#"cbdam_http_requests_total{endpoint="diamond",status="200"} 3"#);
    has(r#"cbdam_http_requests_total{endpoint="diamond",status="400"} 1"#);
    has(r#"cbdam_http_requests_total{endpoint="meta",status="404"} 1"#);
    has(r#"cbdam_http_requests_total{endpoint="batch",status="200"} 1"#);
    has(r#"cbdam_http_errors_total{endpoint="diamond",class="client"} 1"#);
    has(r#"cbdam_http_request_duration_seconds_count{endpoint="diamond"} 4"#);
    has("cbdam_records_sent_total 5");
    let bytes = 3 * repo.head().entries()[0].length as u64;
    let sent = t
        .lines()
        .find_map(|l| l.strip_prefix(r#"cbdam_http_response_bytes_total{endpoint="diamond"} "#))
        .unwrap();
    // 3 records plus the 400's JSON body.
    assert!(sent.parse::<u64>().unwrap() > bytes, "{sent}");
    assert!(t.contains("# TYPE cbdam_http_request_duration_seconds histogram"));
    s.stop().await;
}

#[tokio::test]
async fn graceful_shutdown_returns_after_the_signal() {
    let mut s = start_one(Config::default()).await;
    let c = client();
    assert_eq!(
        c.get(s.url("/v1/repos")).send().await.unwrap().status(),
        200
    );
    // Still running while the shutdown future is pending.
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert!(!s.task.is_finished());
    let addr = s.addr;
    s.shutdown.take().unwrap().send(()).unwrap();
    tokio::time::timeout(Duration::from_secs(10), &mut s.task)
        .await
        .expect("run returns after shutdown")
        .unwrap()
        .unwrap();
    // Nothing listens any more.
    assert!(tokio::net::TcpStream::connect(addr).await.is_err());
}

#[tokio::test]
async fn slow_requests_time_out_with_json() {
    let s = start_one(Config {
        timeout: Duration::from_millis(200),
        ..Config::default()
    })
    .await;
    // A batch whose body never arrives: the handler waits on it until the timeout.
    let mut t = tokio::net::TcpStream::connect(s.addr).await.unwrap();
    t.write_all(
        b"POST /v1/repos/t/diamonds HTTP/1.1\r\nhost: x\r\ncontent-type: application/json\r\n\
          content-length: 100\r\n\r\n{\"ids\":",
    )
    .await
    .unwrap();
    let mut buf = Vec::new();
    let read = tokio::time::timeout(Duration::from_secs(5), async {
        let mut chunk = [0u8; 1024];
        loop {
            let n = t.read(&mut chunk).await.unwrap();
            buf.extend_from_slice(&chunk[..n]);
            if n == 0 || buf.windows(4).any(|w| w == b"\r\n\r\n") && buf.ends_with(b"}") {
                break;
            }
        }
    })
    .await;
    assert!(read.is_ok(), "no answer: {}", String::from_utf8_lossy(&buf));
    let text = String::from_utf8_lossy(&buf);
    assert!(text.starts_with("HTTP/1.1 408"), "{text}");
    assert!(text.contains(r#""status":408"#), "{text}");
    s.stop().await;
}

#[tokio::test]
async fn startup_errors_name_the_problem() {
    use cbdam_server::{RepoSpec, ServerError};
    let dir = tempfile::tempdir().unwrap();
    let good = dir.path().join("good.cbdam");
    std::fs::write(&good, image(1)).unwrap();
    let spec = |s: &str| s.parse::<RepoSpec>().unwrap();
    let open = |specs: &[RepoSpec]| AppState::open(specs, Config::default());

    let missing = dir.path().join("missing.cbdam");
    let e = open(&[
        spec(good.to_str().unwrap()),
        spec(missing.to_str().unwrap()),
    ])
    .unwrap_err();
    assert!(matches!(e, ServerError::Open { .. }));
    assert!(e.to_string().contains("missing.cbdam"), "{e}");

    let mut bytes = image(1);
    bytes[40] ^= 1; // a header field: the header CRC no longer matches
    let bad = dir.path().join("bad.cbdam");
    std::fs::write(&bad, &bytes).unwrap();
    let e = open(&[spec(bad.to_str().unwrap())]).unwrap_err();
    assert!(
        e.to_string().contains("bad.cbdam") && e.to_string().contains("checksum"),
        "{e}"
    );

    let trunc = dir.path().join("trunc.cbdam");
    std::fs::write(&trunc, &image(1)[..300]).unwrap();
    let e = open(&[spec(trunc.to_str().unwrap())]).unwrap_err();
    assert!(e.to_string().contains("trunc.cbdam"), "{e}");

    // Same stem twice, or a name given twice: refused before opening anything.
    let e = open(&[
        spec(good.to_str().unwrap()),
        spec(&format!("good={}", missing.display())),
    ])
    .unwrap_err();
    assert!(
        matches!(e, ServerError::DuplicateName(ref n) if n == "good"),
        "{e}"
    );
    // Invalid names.
    assert!(matches!(
        "bad name.cbdam".parse::<RepoSpec>(),
        Err(ServerError::InvalidName { .. })
    ));
    let e = AppState::new(vec![("a/b".into(), repo(1))], Config::default()).unwrap_err();
    assert!(matches!(e, ServerError::InvalidName { .. }), "{e}");
    assert!(matches!(
        AppState::new(vec![], Config::default()),
        Err(ServerError::NoRepositories)
    ));
    // And the good one alone opens.
    let st = open(&[spec(&format!("g={}", good.display()))]).unwrap();
    assert!(st.repo("g").is_some());
}

/// `GET /` lists the repositories; with the viewer's files (`Config::web`) each links to the
/// viewer, whose files come back under their content hash with their content types, immutable,
/// gzip-compressed on request (decompressing to the file), whole otherwise; a stale hash, an
/// unknown file and a server without the viewer answer 404 with the reason.
#[tokio::test]
async fn the_index_page_and_the_viewer_files() {
    use std::io::Read;
    let dir = tempfile::tempdir().unwrap();
    let wasm: Vec<u8> = (0..20_000u32).map(|i| (i % 7) as u8).collect();
    std::fs::write(
        dir.path().join("index.html"),
        "<!doctype html><title>viewer</title>",
    )
    .unwrap();
    std::fs::write(
        dir.path().join("cbdam_web.js"),
        "export function start() {}\n".repeat(50),
    )
    .unwrap();
    std::fs::write(dir.path().join("cbdam_web_bg.wasm"), &wasm).unwrap();
    let web = std::sync::Arc::new(cbdam_server::WebAssets::load(dir.path()).unwrap());
    let hash = web.hash().to_string();
    let s = start_one(Config {
        web: Some(web),
        ..Config::default()
    })
    .await;
    // Plain client: no automatic decompression, so the encoding is seen as sent.
    let c = client();
    let r = c.get(s.url("/")).send().await.unwrap();
    assert_eq!(r.status(), StatusCode::OK);
    assert_eq!(r.headers()["content-type"], "text/html; charset=utf-8");
    assert_eq!(r.headers()["cache-control"], "no-cache");
    let page = r.text().await.unwrap();
    let link = format!("/viewer/{hash}/index.html?repo=/v1/repos/t");
    assert!(page.contains(&link), "{page}");
    // A UTM repository: web-map tiles are made of it, and linked.
    assert!(
        page.contains("/v1/repos/t/quantized-mesh/layer.json"),
        "{page}"
    );
    assert!(page.contains("/v1/repos/t/terrarium/tiles.json"), "{page}");

    let wasm_url = s.url(&format!("/viewer/{hash}/cbdam_web_bg.wasm"));
    let r = c
        .get(&wasm_url)
        .header("accept-encoding", "gzip, br")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), StatusCode::OK);
    assert_eq!(r.headers()["content-type"], "application/wasm");
    assert_eq!(r.headers()["content-encoding"], "gzip");
    assert!(
        r.headers()["cache-control"]
            .to_str()
            .unwrap()
            .contains("immutable")
    );
    let zipped = r.bytes().await.unwrap();
    assert!(zipped.len() < wasm.len() / 4, "{} bytes", zipped.len());
    let mut unzipped = Vec::new();
    flate2::read::GzDecoder::new(&zipped[..])
        .read_to_end(&mut unzipped)
        .unwrap();
    assert_eq!(unzipped, wasm);
    for refuse in [None, Some("identity"), Some("gzip;q=0")] {
        let mut q = c.get(&wasm_url);
        if let Some(v) = refuse {
            q = q.header("accept-encoding", v);
        }
        let r = q.send().await.unwrap();
        assert!(r.headers().get("content-encoding").is_none(), "{refuse:?}");
        assert_eq!(r.bytes().await.unwrap(), wasm, "{refuse:?}");
    }
    let r = c
        .get(s.url(&format!("/viewer/{hash}/main.js")))
        .send()
        .await
        .unwrap();
    assert!(error_body(r, 404).await.contains("no file"));
    let r = c
        .get(s.url("/viewer/0000000000000000/index.html"))
        .send()
        .await
        .unwrap();
    assert!(error_body(r, 404).await.contains(&hash));
    s.stop().await;

    let s = start_one(Config::default()).await;
    let page = c
        .get(s.url("/"))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    assert!(
        page.contains("--web") && !page.contains("/viewer/"),
        "{page}"
    );
    let r = c
        .get(s.url(&format!("/viewer/{hash}/index.html")))
        .send()
        .await
        .unwrap();
    assert!(error_body(r, 404).await.contains("--web"));
    s.stop().await;

    // A directory that is not the bundle is refused naming the missing file.
    std::fs::remove_file(dir.path().join("cbdam_web_bg.wasm")).unwrap();
    let e = cbdam_server::WebAssets::load(dir.path())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("cbdam_web_bg.wasm") && e.contains("web-build.sh"),
        "{e}"
    );
}
