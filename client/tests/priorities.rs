//! Request priorities and cancellation over loopback HTTP against `cbdam serve`'s router:
//! records arrive in the order of their screen error, an urgent record wanted later overtakes
//! the queue, and a request the view no longer needs is dropped (the server sees it go and
//! stops) while what is still wanted is asked for again.

use std::time::{Duration, Instant};

use axum::extract::Request;
use axum::middleware::Next;
use cbdam_client::fetch::{FetchOptions, RemoteFetcher};
use cbdam_codec::geometry::DiamondId;
use cbdam_codec::hierarchy::{EncodeOptions, Encoder};
use cbdam_codec::quant::{HeightGrid, QuantPlan};
use cbdam_codec::repository::{Repository, serialize};
use cbdam_server::{AppState, Config};

fn image() -> Vec<u8> {
    let (w, h) = (120usize, 90usize);
    let metres: Vec<f64> = (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as f64, (i / w) as f64);
            let noise = ((i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 54) as f64 / 300.0;
            100.0 + 50.0 * (x / 13.0).sin() * (y / 17.0).cos() + noise
        })
        .collect();
    let plan = QuantPlan::new(0.25, None, 0.0, 200.0).unwrap();
    let grid = HeightGrid::from_metres(w, h, &metres, None, &plan).unwrap();
    let opts = EncodeOptions {
        n: 9,
        ..EncodeOptions::default()
    };
    let enc = Encoder::new(&grid, plan.quantizer, &opts).encode().unwrap();
    serialize(&enc, &plan, None, None).unwrap()
}

/// `cbdam serve`'s router on loopback; every batch's response is held `hold` after the
/// handler made it (the body exists, nothing of it sent yet), as a slow link would.
fn serve(rt: &tokio::runtime::Runtime, bytes: &[u8], hold: Duration) -> (String, AppState) {
    let state = AppState::new(
        vec![("t".into(), Repository::from_bytes(bytes.to_vec()).unwrap())],
        Config::default(),
    )
    .unwrap();
    let app = cbdam_server::app(state.clone()).layer(axum::middleware::from_fn(
        move |req: Request, next: Next| async move {
            let batch = req.method() == axum::http::Method::POST;
            let resp = next.run(req).await;
            if batch {
                tokio::time::sleep(hold).await;
            }
            resp
        },
    ));
    let _guard = rt.enter();
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    listener.set_nonblocking(true).unwrap();
    let addr = listener.local_addr().unwrap();
    let listener = tokio::net::TcpListener::from_std(listener).unwrap();
    rt.spawn(async move { axum::serve(listener, app).await.unwrap() });
    (format!("http://{addr}/v1/repos/t"), state)
}

/// Polls `f` until `n` records arrived (or 10 s passed); returns them in arrival order.
fn collect(f: &RemoteFetcher, n: usize) -> Vec<DiamondId> {
    let t0 = Instant::now();
    let mut got = Vec::new();
    while got.len() < n && t0.elapsed() < Duration::from_secs(10) {
        for (id, r) in f.poll() {
            r.expect("a good record");
            got.push(id);
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    got
}

/// Stored diamonds with non-empty records, finest first.
fn stored(repo: &Repository) -> Vec<DiamondId> {
    let mut ids: Vec<DiamondId> = repo
        .head()
        .entries()
        .iter()
        .filter(|e| e.length > 0)
        .map(|e| e.id)
        .collect();
    ids.reverse();
    ids
}

#[test]
fn records_arrive_most_urgent_first_and_urgent_late_wants_overtake_the_queue() {
    let bytes = image();
    let repo = Repository::from_bytes(bytes.clone()).unwrap();
    let rt = tokio::runtime::Runtime::new().unwrap();
    let (url, _) = serve(&rt, &bytes, Duration::from_millis(150));
    let options = FetchOptions {
        max_in_flight: 1,
        max_batch: 4,
        ..FetchOptions::default()
    };
    let f = RemoteFetcher::connect(&url, options).unwrap();
    let ids = stored(&repo);
    // Twelve records with scrambled priorities, then (once the first request is on its way) a
    // thirteenth, more urgent than all.
    let first: Vec<(DiamondId, f32)> = (0..12)
        .map(|k| (ids[k], ((k * 7) % 12) as f32 + 1.0))
        .collect();
    let urgent = (ids[12], 100.0);
    f.want(first.iter().copied());
    std::thread::sleep(Duration::from_millis(50));
    assert_eq!(f.stats().in_flight, 1, "the first request is on its way");
    f.want(first.iter().copied().chain([urgent]));
    let got = collect(&f, 13);

    let mut by_priority = first.clone();
    by_priority.sort_by(|a, b| b.1.total_cmp(&a.1));
    let sorted: Vec<DiamondId> = by_priority.iter().map(|p| p.0).collect();
    // The first request took the four most urgent, in order; then the urgent one, then the
    // rest by priority: exactly the order of the client's queue, as sent.
    let mut want = sorted[..4].to_vec();
    want.push(urgent.0);
    want.extend(&sorted[4..]);
    assert_eq!(got, want);
    assert_eq!(
        f.stats().requests,
        2 + 4,
        "the head's two, then batches of four"
    );
}

#[test]
fn a_request_the_view_no_longer_needs_is_dropped_and_the_server_stops_sending() {
    let bytes = image();
    let repo = Repository::from_bytes(bytes.clone()).unwrap();
    let rt = tokio::runtime::Runtime::new().unwrap();
    let (url, state) = serve(&rt, &bytes, Duration::from_millis(400));
    let f = RemoteFetcher::connect(&url, FetchOptions::default()).unwrap();
    // Eight records, the two kept afterwards the smallest: most of the request's bytes
    // become unwanted.
    let mut eight = stored(&repo)[..8].to_vec();
    eight.sort_by_key(|&id| repo.record(id).unwrap().len());
    f.want(eight.iter().map(|&id| (id, 1.0)));
    std::thread::sleep(Duration::from_millis(100));
    assert_eq!(f.stats().in_flight, 1);
    let kept: Vec<(DiamondId, f32)> = eight[..2].iter().map(|&id| (id, 2.0)).collect();
    f.want(kept.iter().copied());
    let s = f.stats();
    assert_eq!((s.cancelled, s.requeued), (1, 2), "{s:?}");

    // The two still wanted arrive (asked for again); nothing of the dropped request does.
    let got = collect(&f, 2);
    let mut want: Vec<DiamondId> = kept.iter().map(|k| k.0).collect();
    want.sort();
    let mut got_sorted = got.clone();
    got_sorted.sort();
    assert_eq!(got_sorted, want);
    std::thread::sleep(Duration::from_millis(600));
    assert!(f.poll().is_empty(), "no record of the dropped request");
    // The server saw the connection close and dropped the response unsent.
    let t0 = Instant::now();
    while state.metrics().aborted_batches().0 == 0 && t0.elapsed() < Duration::from_secs(5) {
        std::thread::sleep(Duration::from_millis(20));
    }
    let (aborted, unsent) = state.metrics().aborted_batches();
    assert_eq!(aborted, 1);
    let all: u64 = eight
        .iter()
        .map(|&id| 5 + repo.record(id).unwrap().len() as u64)
        .sum();
    assert_eq!(
        unsent,
        8 + all,
        "not a byte of the dropped request was sent"
    );
}
