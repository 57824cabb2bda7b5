//! A repository whose records area is damaged on disk: the damaged record answers 500, is
//! logged once, and everything else keeps being served. In its own test binary because it
//! installs a global log subscriber to count the log lines: a subscriber for this test's
//! thread alone is not enough inside `tests.rs`, where the other tests hit the same log
//! callsites at the same time and tracing caches their interest process-wide (tried: the
//! access lines went missing whenever the HTTP tests ran alongside).

mod util;

use std::io::Write;
use std::sync::{Arc, Mutex};

use cbdam_codec::repository::{Repository, Section};
use cbdam_server::{AppState, Config, RepoSpec};
use util::*;

/// Collects everything logged.
#[derive(Clone, Default)]
struct Capture(Arc<Mutex<Vec<u8>>>);

impl Write for Capture {
    fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
        self.0.lock().unwrap().extend_from_slice(b);
        Ok(b.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

#[tokio::test]
async fn a_damaged_record_fails_alone_and_is_logged_once() {
    let log = Capture::default();
    let sink = log.clone();
    tracing_subscriber::fmt()
        .with_writer(move || sink.clone())
        .with_ansi(false)
        .with_max_level(tracing::Level::INFO)
        .init();

    // Flip one byte inside the records area of a copy on disk, inside the largest record.
    let dir = tempfile::tempdir().unwrap();
    let bytes = image(1);
    let clean = Repository::from_bytes(bytes.clone()).unwrap();
    let (bad_i, bad) = clean
        .head()
        .entries()
        .iter()
        .enumerate()
        .max_by_key(|(_, e)| e.length)
        .unwrap();
    let bad_id = bad.id;
    let at = clean.head().section_offset(Section::Records) as usize + bad.offset as usize + 1;
    let mut damaged = bytes.clone();
    damaged[at] ^= 0x40;
    let broken_path = dir.path().join("broken.cbdam");
    let good_path = dir.path().join("good.cbdam");
    std::fs::File::create(&broken_path)
        .unwrap()
        .write_all(&damaged)
        .unwrap();
    std::fs::write(&good_path, &bytes).unwrap();

    // Opening does not scan the records area, so the server starts.
    let specs: Vec<RepoSpec> = [&broken_path, &good_path]
        .iter()
        .map(|p| p.to_str().unwrap().parse().unwrap())
        .collect();
    let s = start(AppState::open(&specs, Config::default()).unwrap()).await;
    let c = client();
    let bad_url = s.url(&format!("/v1/repos/broken/diamonds/{bad_id}"));
    for _ in 0..3 {
        let msg = error_body(c.get(&bad_url).send().await.unwrap(), 500).await;
        assert!(
            msg.contains(&bad_id.to_string()) && msg.contains("damaged"),
            "{msg}"
        );
    }
    // A batch that includes it fails too; one that does not, works.
    let other = clean
        .head()
        .entries()
        .iter()
        .find(|e| e.id != bad_id && e.length > 0)
        .unwrap()
        .id;
    let url = s.url("/v1/repos/broken/diamonds");
    let r = c
        .post(&url)
        .body(format!(r#"{{"ids":["{other}","{bad_id}"]}}"#))
        .send()
        .await
        .unwrap();
    error_body(r, 500).await;
    let r = c
        .post(&url)
        .body(format!(r#"{{"ids":["{other}"]}}"#))
        .send()
        .await
        .unwrap();
    assert_eq!(
        parse_batch(&r.bytes().await.unwrap()),
        vec![Some(clean.record(other).unwrap().to_vec())]
    );

    // Every other record of the damaged repository, and the other repository, still serve.
    for (i, e) in clean.head().entries().iter().enumerate() {
        for name in ["broken", "good"] {
            let r = c
                .get(s.url(&format!("/v1/repos/{name}/diamonds/{}", e.id)))
                .send()
                .await
                .unwrap();
            if name == "broken" && i == bad_i {
                assert_eq!(r.status(), 500);
            } else {
                assert_eq!(r.status(), 200, "{name} {}", e.id);
                assert_eq!(&r.bytes().await.unwrap()[..], clean.record(e.id).unwrap());
            }
        }
    }
    let metrics = c
        .get(s.url("/metrics"))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    assert!(
        metrics.contains("cbdam_corrupt_record_requests_total 5"),
        "{metrics}"
    );
    assert!(metrics.contains(r#"cbdam_http_requests_total{endpoint="diamond",status="500"} 4"#));
    s.stop().await;

    // Five requests met the damaged record; its error was logged once. Access logs carry
    // every failed request at info.
    let text = String::from_utf8(log.0.lock().unwrap().clone()).unwrap();
    let damaged_lines: Vec<&str> = text
        .lines()
        .filter(|l| l.contains("damaged record"))
        .collect();
    assert_eq!(damaged_lines.len(), 1, "{text}");
    assert!(damaged_lines[0].contains(&bad_id.to_string()) && damaged_lines[0].contains("broken"));
    assert!(
        text.lines().filter(|l| l.contains("status=500")).count() >= 5,
        "{text}"
    );
    // Successful record requests (hundreds above) log at debug, under this INFO subscriber.
    assert!(
        !text
            .lines()
            .any(|l| l.contains("/diamonds/") && l.contains("status=200")),
        "{text}"
    );
}
