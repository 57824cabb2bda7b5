//! The fetcher's portable parts tested without a network: scheduling, the window, backoff,
//! cancelling, batch frames, range spans and record checks.

use super::schedule::{Window, not_worth_finishing};
use super::wire::wire_priorities;
use super::*;
use cbdam_codec::repository::batch;
use std::collections::HashMap;
use web_time::Instant;

fn id(l: u8, x: u32, y: u32) -> DiamondId {
    DiamondId::new(l, x, y)
}

#[test]
fn batches_are_dropped_when_most_of_what_they_still_carry_is_unwanted() {
    use cbdam_codec::hierarchy::{EncodeOptions, Encoder};
    use cbdam_codec::quant::{HeightGrid, QuantPlan};
    let (w, h) = (33usize, 33usize);
    let metres: Vec<f64> = (0..w * h)
        .map(|i| ((i * 7919) % 97) as f64 + (i % w) as f64)
        .collect();
    let plan = QuantPlan::new(0.25, None, 0.0, 200.0).unwrap();
    let grid = HeightGrid::from_metres(w, h, &metres, None, &plan).unwrap();
    let opts = EncodeOptions {
        n: 9,
        ..EncodeOptions::default()
    };
    let enc = Encoder::new(&grid, plan.quantizer, &opts).encode().unwrap();
    let bytes = cbdam_codec::repository::serialize(&enc, &plan, None, None).unwrap();
    let repo = cbdam_codec::repository::Repository::from_bytes(bytes).unwrap();
    let head = repo.head();
    // Four records of the same size, so that fractions are exact.
    let mut by_len: HashMap<u32, Vec<DiamondId>> = HashMap::new();
    for e in repo.head().entries() {
        by_len.entry(e.length).or_default().push(e.id);
    }
    let four: Vec<DiamondId> = by_len
        .into_values()
        .find(|v| v.len() >= 4)
        .expect("four records of one size")[..4]
        .to_vec();
    let o = FetchOptions::default();
    let wanted =
        |n: usize| -> HashMap<DiamondId, ()> { four[..n].iter().map(|&id| (id, ())).collect() };
    assert!(!not_worth_finishing(&four, &wanted(4), head, &o));
    assert!(
        !not_worth_finishing(&four, &wanted(3), head, &o),
        "a quarter unwanted"
    );
    assert!(
        not_worth_finishing(&four, &wanted(2), head, &o),
        "half unwanted"
    );
    assert!(not_worth_finishing(&four, &wanted(0), head, &o));
    // Only what is still to come counts: the two wanted ones delivered, the rest unwanted.
    assert!(not_worth_finishing(&four[2..], &wanted(2), head, &o));
    let lenient = FetchOptions {
        cancel_waste: 1.0,
        ..FetchOptions::default()
    };
    assert!(!not_worth_finishing(&four, &wanted(1), head, &lenient));
    assert!(not_worth_finishing(&four, &wanted(0), head, &lenient));
}

#[test]
fn batch_requests_carry_priorities_and_answers_follow_them() {
    let ids = [id(1, 2, 3), id(2, 4, 5), id(3, 1, 1)];
    let body = batch_request_body(&ids, &[1.0, f32::INFINITY, 4.5]);
    let v: serde_json::Value = serde_json::from_str(&body).unwrap();
    assert_eq!(v["ids"], serde_json::json!(["1-2-3", "2-4-5", "3-1-1"]));
    assert_eq!(v["priorities"], serde_json::json!([1.0, 0.0, 4.5]));
    let short = batch_request_body(&ids[..2], &[2.718_4, 0.012_345_67]);
    assert!(short.contains("[2.72,0.0123]"), "{short}");
    // Rounding keeps a sorted list sorted (ties are answered in request order).
    let sorted = [1234.5f32, 999.6, 999.4, 10.04, 9.996, 0.5, 0.0];
    let wire = wire_priorities(&sorted);
    assert!(wire.windows(2).all(|w| w[0] >= w[1]), "{wire:?}");
    let read: Vec<f32> = wire.iter().map(|&p| p as f32).collect();
    assert_eq!(
        batch::answer_order(&read),
        (0..sorted.len()).collect::<Vec<_>>()
    );
    assert_eq!(
        answer_ids(&ids, &[1.0, f32::INFINITY, 4.5]),
        vec![ids[2], ids[0], ids[1]]
    );
    // What the client sends (most urgent first) comes back as sent.
    assert_eq!(answer_ids(&ids, &[9.0, 9.0, 1.0]), ids.to_vec());
}

#[test]
fn the_byte_window_follows_the_measured_delivery_rate() {
    let o = FetchOptions::default();
    let mut w = Window::default();
    let t0 = Instant::now();
    assert_eq!(w.limit(&o), o.initial_window, "before any measurement");
    w.start(1, 100_000, t0);
    w.start(2, 100_000, t0);
    assert_eq!(w.in_flight, 200_000);
    // The first delivers 100 kB in 1 s: 100 kB/s, half a second's worth in flight at most.
    w.end(1, Some(100_000), t0 + Duration::from_secs(1));
    assert!((w.rate - 100_000.0).abs() < 1.0, "{}", w.rate);
    assert_eq!(w.limit(&o), 50_000);
    // Everything delivered while the second was in flight counts: 200 kB in 4 s.
    w.end(2, Some(100_000), t0 + Duration::from_secs(4));
    assert!((w.rate - (100_000.0 + 0.25 * (50_000.0 - 100_000.0))).abs() < 1.0);
    // A failed or cancelled request frees its bytes and is no sample.
    w.start(3, 7, t0);
    let rate = w.rate;
    w.end(3, None, t0 + Duration::from_secs(9));
    assert_eq!((w.in_flight, w.rate), (0, rate));
    // A very slow link still gets a usable window.
    w.rate = 10.0;
    assert_eq!(w.limit(&o), 16 << 10);
}

/// Range responses: only 206 is accepted; the total comes from `Content-Range`; a range
/// past the end of the file gets the bytes up to the end, and any other length is an error.
#[test]
fn range_responses_are_checked() {
    let r = 10..20;
    assert!(expect_partial(&r, 206).is_ok());
    let e = expect_partial(&r, 200).unwrap_err();
    assert!(e.contains("HTTP 200") && e.contains("Range"), "{e}");
    assert_eq!(range_total(&r, Some("bytes 10-19/100"), 10), Ok(100));
    // The file ends at 15: five bytes are the whole answer.
    assert_eq!(range_total(&r, Some("bytes 10-14/15"), 5), Ok(15));
    assert!(range_total(&r, Some("bytes 10-14/15"), 4).is_err());
    assert!(range_total(&r, Some("bytes 10-19/100"), 9).is_err());
    assert!(range_total(&r, Some("bytes 10-19/*"), 10).is_err());
    assert!(range_total(&r, None, 10).is_err());
}

#[test]
fn urls_name_a_server_repository_a_file_or_a_server() {
    let server = |base: &str| {
        Some(Endpoint::Server {
            base: base.to_owned(),
        })
    };
    let file = |url: &str| {
        Some(Endpoint::File {
            url: url.to_owned(),
        })
    };
    let c = |u: &str| classify(u).unwrap();
    assert_eq!(
        c("http://h:1/v1/repos/jb"),
        server("http://h:1/v1/repos/jb")
    );
    assert_eq!(
        c("http://h:1/v1/repos/jb/"),
        server("http://h:1/v1/repos/jb")
    );
    // cbdam serve's raw file route: range requests on the file, not batches.
    assert_eq!(
        c("http://h:1/v1/repos/jb/file"),
        file("http://h:1/v1/repos/jb/file")
    );
    // A repository named "file" is still a repository.
    assert_eq!(
        c("http://h:1/v1/repos/file"),
        server("http://h:1/v1/repos/file")
    );
    assert_eq!(
        c("http://h:1/data/jb.cbdam"),
        file("http://h:1/data/jb.cbdam")
    );
    assert_eq!(c("http://h:1/"), None);
    assert!(classify("ftp://h/x").is_err());
}

#[test]
fn frames_parse_and_bad_frames_are_errors() {
    let ids = [id(1, 2, 3), id(2, 4, 5)];
    let mut body = b"CBDR".to_vec();
    body.extend(2u32.to_le_bytes());
    body.push(0);
    body.extend(3u32.to_le_bytes());
    body.extend([7, 8, 9]);
    body.push(0);
    body.extend(0u32.to_le_bytes());
    let r = parse_frames(&body, &ids).unwrap();
    assert_eq!(r, vec![(ids[0], vec![7, 8, 9]), (ids[1], vec![])]);
    for cut in 0..body.len() {
        assert!(parse_frames(&body[..cut], &ids).is_err(), "cut at {cut}");
    }
    let mut longer = body.clone();
    longer.push(0);
    assert!(parse_frames(&longer, &ids).is_err());
    assert!(parse_frames(&body, &ids[..1]).is_err());
    let mut missing = body.clone();
    missing[8] = 1;
    assert!(parse_frames(&missing, &ids).is_err());
}

/// What the native client and the browser core open a remote repository with: the file of
/// a hostile server, whose checksums match but whose height unit makes every height
/// infinite, is refused with the codec's error naming the field, before any world or
/// camera is made from it (they panicked on such values).
#[test]
fn a_crafted_head_from_a_hostile_server_is_refused_by_name() {
    use cbdam_codec::hierarchy::{EncodeOptions, Encoder};
    use cbdam_codec::quant::{HeightGrid, QuantPlan};
    use cbdam_codec::repository::{craft_header, serialize};
    let (w, h) = (33, 33);
    let metres: Vec<f64> = (0..w * h).map(|i| f64::from((i % 7) as u8) * 3.0).collect();
    let plan = QuantPlan::new(1.0, None, 0.0, 18.0).unwrap();
    let grid = HeightGrid::from_metres(w, h, &metres, None, &plan).unwrap();
    let opts = EncodeOptions {
        n: 9,
        ..EncodeOptions::default()
    };
    let enc = Encoder::new(&grid, plan.quantizer, &opts).encode().unwrap();
    let good = serialize(&enc, &plan, None, None).unwrap();
    let open = |bytes: Vec<u8>| {
        let len = bytes.len() as u64;
        let get = |r: std::ops::Range<u64>| {
            let end = r.end.min(len) as usize;
            let body = bytes[r.start as usize..end].to_vec();
            async move { Ok((body, len)) }
        };
        let fut = std::pin::pin!(fetch_head_with("http://hostile/r.cbdam", get));
        let mut cx = std::task::Context::from_waker(std::task::Waker::noop());
        match fut.poll(&mut cx) {
            std::task::Poll::Ready(r) => r.map(|(head, _)| head),
            std::task::Poll::Pending => panic!("an in-memory fetch is never pending"),
        }
    };
    assert!(open(good.clone()).is_ok());
    let bad = craft_header(&good, "unit", 1e308f64.to_bits()).unwrap();
    match open(bad) {
        Err(RemoteError::Repository { source, .. }) => {
            assert!(source.to_string().contains("height unit 1e308"), "{source}");
        }
        other => panic!("{other:?}"),
    }
}
