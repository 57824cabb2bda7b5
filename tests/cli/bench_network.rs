//! `cbdam bench network` on a small repository and a 2 s flight: its figures checked against
//! the server's own request counters, the index, and the local file's cut.

use std::path::Path;

use serde_json::Value;

use crate::util::*;

/// Jacksboro at ε = 1 m and a 2 s flight (the shipped descent's ends), in `dir`.
fn inputs(dir: &Path) -> (String, String) {
    let repo = jacksboro_at("1");
    let flight = short_flight(dir);
    (s(&repo), s(&flight))
}

/// Runs the bench with `extra` arguments into `out`; returns its stdout and `network.json`'s runs.
fn bench(repo: &str, flight: &str, out: &Path, extra: &[&str]) -> (String, Vec<Value>) {
    let mut args = vec![
        "bench",
        "network",
        "--repo",
        repo,
        "--flights",
        flight,
        "--size",
        "640x360",
        "--fps",
        "10",
        "--max-settle-s",
        "20",
        "--out",
    ];
    let out_s = s(out);
    args.push(&out_s);
    args.extend_from_slice(extra);
    let o = cbdam(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let json: Value =
        serde_json::from_slice(&std::fs::read(out.join("network.json")).unwrap()).unwrap();
    (stdout(&o), json["runs"].as_array().unwrap().clone())
}

fn u(v: &Value, key: &str) -> u64 {
    v[key]
        .as_u64()
        .unwrap_or_else(|| panic!("{key} is not a count: {v}"))
}

/// Through the `mobile` profile with resets made frequent (`--reset-prob 0.5`, seed 7: the
/// link test's setting, which resets connections mid-transfer), both servers' replays converge
/// to exactly the local file's cut (the refined diamonds, compared by the bench), and what they
/// fetched covers at least the records the cuts used.
#[test]
fn through_a_mobile_link_with_resets_both_servers_converge_to_the_local_cut() {
    let dir = tempfile::tempdir().unwrap();
    let (repo, flight) = inputs(dir.path());
    let out = dir.path().join("net");
    let (stdout, runs) = bench(
        &repo,
        &flight,
        &out,
        &["--profiles", "mobile", "--reset-prob", "0.5", "--seed", "7"],
    );
    assert_eq!(runs.len(), 3, "local, serve, static: {runs:?}");
    assert_eq!(runs[0]["profile"], "local");
    assert_eq!(runs[0]["converged"], true);
    let mut resets = 0;
    for r in &runs[1..] {
        assert_eq!(r["profile"], "mobile");
        assert_eq!(r["converged"], true, "{r}");
        assert_eq!(r["final_cut_same_as_local"], true, "{r}");
        assert_eq!(r["final_cut_diamonds"], runs[0]["final_cut_diamonds"]);
        // Every record a cut used came over the link at least once.
        assert!(u(r, "bytes_used") > 0, "{r}");
        assert!(u(r, "bytes_fetched") >= u(r, "bytes_used"), "{r}");
        // The records received are those the cuts used and those they did not, prefetched or
        // wanted by the cut: the log of arrivals covers every record a cut used.
        let got = &r["received"];
        assert_eq!(
            u(got, "record_bytes"),
            u(r, "bytes_used")
                + u(got, "prefetch_unused_bytes")
                + u(got, "cut_wanted_unused_bytes"),
            "{r}"
        );
        assert!(u(got, "final_cut_missing_at_stop_bytes") <= u(got, "final_cut_bytes"));
        // mobile: 5 Mbit/s down.
        let bound = got["lower_bound_s"].as_f64().unwrap();
        let missing = u(got, "final_cut_missing_at_stop_bytes") as f64;
        assert!((bound - missing * 8.0 / 5e6).abs() < 1e-9, "{r}");
        assert!(got["any_policy_bound_s"].as_f64().unwrap() >= 0.0, "{r}");
        resets += u(&r["wire"], "resets");
    }
    assert!(resets >= 1, "no connection was reset: {runs:?}");
    assert!(
        stdout.contains("| mobile | static (Range) | short |"),
        "{stdout}"
    );
    let md = std::fs::read_to_string(out.join("network.md")).unwrap();
    assert!(md.contains("| mobile | serve (batched) | short |"), "{md}");
    assert!(md.contains("plots/screen_error.svg"));
    let svg = std::fs::read_to_string(out.join("plots/screen_error.svg")).unwrap();
    assert!(svg.starts_with("<svg") && svg.contains("short, mobile"));
    assert!(out.join("csv/short_mobile_static.csv").exists());
}

/// A static-server run reads records with range requests only, and the bench's count of them
/// (the client's, from its fetcher) agrees with the server's own counters: every request the
/// server answered was sent, and every request sent reached the server unless the client
/// aborted it (no failures on a link without resets; the bench waits for the requests the last
/// frame left in flight). The batched server gets batches and
/// only the head's two range requests.
#[test]
fn a_static_server_run_issues_range_requests_and_the_counts_agree() {
    let dir = tempfile::tempdir().unwrap();
    let (repo, flight) = inputs(dir.path());
    let out = dir.path().join("net");
    let (stdout, runs) = bench(&repo, &flight, &out, &["--profiles", "fibre"]);
    assert_eq!(runs.len(), 3);
    let (serve, stat) = (&runs[1], &runs[2]);
    assert_eq!(serve["server"], "serve");
    assert_eq!(stat["server"], "static");

    let w = &stat["wire"];
    let (client, cancelled, errors) = (
        u(w, "client_requests"),
        u(w, "client_cancelled"),
        u(w, "client_errors"),
    );
    let ranges = u(w, "server_range_requests");
    eprintln!("static: client {client} (cancelled {cancelled}), server {ranges} range requests");
    assert_eq!(errors, 0, "{w}");
    assert_eq!(u(w, "client_in_flight_at_end"), 0, "{w}");
    assert_eq!(u(w, "server_batch_requests"), 0, "{w}");
    assert_eq!(u(w, "server_other_requests"), 0, "{w}");
    // The head takes 2; the records at least one more.
    assert!(ranges > 2, "{w}");
    assert!(ranges <= client && client - cancelled <= ranges, "{w}");
    // The table shows the server's count, and per second of the run.
    let per_s = ranges as f64 / stat["wall_s"].as_f64().unwrap();
    let cell = format!("| {ranges} ({per_s:.1}) |");
    let row = stdout
        .lines()
        .find(|l| l.starts_with("| fibre | static (Range) |"))
        .unwrap();
    assert!(row.contains(&cell), "{cell} not in {row}");

    let w = &serve["wire"];
    let batches = u(w, "server_batch_requests");
    assert!(batches >= 1, "{w}");
    assert_eq!(u(w, "server_range_requests"), 2, "{w}");
    let client = u(w, "client_requests");
    assert!(
        batches + 2 <= client && client - u(w, "client_cancelled") <= batches + 2,
        "{w}"
    );
    for r in &runs[1..] {
        assert_eq!(r["final_cut_same_as_local"], true, "{r}");
    }
}
