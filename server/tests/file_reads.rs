//! Batches and records read from a served file (merged positioned reads, the identity checked
//! after them, each CRC checked once): answers of any order, duplicates, unstored ids and
//! records far apart in the file are byte for byte what the repository holds, in chunks.

use crate::util::*;
use cbdam_codec::geometry::DiamondId;
use cbdam_server::{AppState, Config, RepoSpec};

#[tokio::test]
async fn batches_read_from_a_file_hold_every_record_as_stored() {
    for held in [false, true] {
        batches_and_records_as_stored(held).await;
    }
}

/// The records of a file held in memory (`held`) or read from it as asked for.
async fn batches_and_records_as_stored(held: bool) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t.cbdam");
    std::fs::write(&path, image(3)).unwrap();
    let spec: RepoSpec = format!("t={}", path.display()).parse().unwrap();
    let config = Config {
        held_records_bytes: if held { 1 << 30 } else { 1 },
        ..Config::default()
    };
    let s = start(AppState::open(&[spec], config).unwrap()).await;
    let repo = repo(3);
    let stored: Vec<DiamondId> = repo.head().entries().iter().map(|e| e.id).collect();
    assert!(stored.len() > 20, "{} records", stored.len());
    // Every record, twice over in several orders (file order, reversed, every third first: runs
    // that merge, runs with gaps), with unstored ids among them; several chunks long.
    let mut ids: Vec<String> = Vec::new();
    for round in (0..3).cycle().take(45) {
        let order: Vec<usize> = match round {
            0 => (0..stored.len()).collect(),
            1 => (0..stored.len()).rev().collect(),
            _ => (0..stored.len())
                .step_by(3)
                .chain(0..stored.len())
                .collect(),
        };
        for (n, k) in order.into_iter().enumerate() {
            if n % 7 == 0 {
                ids.push("0-999999-0".into());
            }
            ids.push(stored[k].to_string());
        }
    }
    let body = serde_json::json!({ "ids": ids }).to_string();
    let c = client();
    let url = s.url("/v1/repos/t/diamonds");
    for _ in 0..2 {
        // The second time, every record's CRC has passed once already.
        let r = c.post(&url).body(body.clone()).send().await.unwrap();
        assert_eq!(r.status(), 200);
        let bytes = r.bytes().await.unwrap();
        assert!(
            bytes.len() > 3 * (16 << 10),
            "{} bytes: a few chunks",
            bytes.len()
        );
        assert!(
            ids.len() <= 4096,
            "{} ids, over the default --max-batch",
            ids.len()
        );
        let got = parse_batch(&bytes);
        assert_eq!(got.len(), ids.len());
        for (id, g) in ids.iter().zip(&got) {
            let want = id
                .parse::<DiamondId>()
                .ok()
                .and_then(|d| repo.record(d).ok())
                .map(<[u8]>::to_vec);
            assert_eq!(g, &want, "{id}");
        }
    }
    for id in stored.iter().step_by(5) {
        let r = c
            .get(s.url(&format!("/v1/repos/t/diamonds/{id}")))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 200);
        assert_eq!(&r.bytes().await.unwrap()[..], repo.record(*id).unwrap());
    }
    s.stop().await;
}
