//! `cbdam link` as a process: forwards through the emulated link, prints its counters, stops on
//! SIGTERM; bad flags are refused by name.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::process::{Child, ChildStdout, Command, Stdio};
use std::time::Instant;

use crate::util::*;

/// Starts `cbdam link ARGS… --listen 127.0.0.1:0` and returns it with its `host:port`, what it
/// printed up to there, and its stdout (read on from there).
fn spawn_link(args: &[&str]) -> (Child, String, String, BufReader<ChildStdout>) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_cbdam"))
        .arg("link")
        .args(args)
        .args(["--listen", "127.0.0.1:0"])
        .stdout(Stdio::piped())
        .spawn()
        .expect("run cbdam link");
    let mut out = BufReader::new(child.stdout.take().expect("piped stdout"));
    let mut seen = String::new();
    let addr = loop {
        let mut line = String::new();
        assert!(
            out.read_line(&mut line).expect("read the link's output") > 0,
            "cbdam link exited early: {seen}"
        );
        seen += &line;
        if let Some(rest) = line.strip_prefix("listening on ") {
            break rest.split(';').next().unwrap().to_string();
        }
    };
    (child, addr, seen, out)
}

/// An HTTP/1.1 GET of `path` on `addr` with `connection: close`: the whole response.
fn get(addr: &str, path: &str) -> Vec<u8> {
    let mut t = TcpStream::connect(addr).unwrap();
    write!(
        t,
        "GET {path} HTTP/1.1\r\nhost: x\r\nconnection: close\r\n\r\n"
    )
    .unwrap();
    let mut resp = Vec::new();
    t.read_to_end(&mut resp).unwrap();
    resp
}

/// `cbdam link` in front of `cbdam serve`: the repository's file arrives unchanged, no sooner
/// than the round trip (2 × 100 ms) plus its size at the 1 Mbit/s cap implies, and within 10 %
/// plus 0.5 s of scheduling and process slack; counters printed; exit 0 on SIGTERM with totals.
#[cfg(unix)]
#[test]
fn link_forwards_to_serve_at_the_link_rate_and_stops_on_sigterm() {
    let repo = jacksboro_at("1");
    let (mut server, server_addr) = spawn_serve(&[&format!("jb={}", s(&repo))]);
    let (link, addr, seen, out) = spawn_link(&[
        "--profile",
        "custom",
        "--down",
        "1M",
        "--up",
        "500k",
        "--delay-ms",
        "100",
        "--interval",
        "0.2",
        "--to",
        &server_addr,
    ]);
    assert!(
        seen.contains("1 Mbit/s down, 500 kbit/s up, 100 ms each way"),
        "{seen}"
    );
    let file = std::fs::read(&repo).unwrap();
    let t0 = Instant::now();
    let resp = get(&addr, "/v1/repos/jb/file");
    let took = t0.elapsed().as_secs_f64();
    let direct = get(&server_addr, "/v1/repos/jb/file");
    let _ = server.kill();
    let _ = server.wait();
    assert!(
        resp.starts_with(b"HTTP/1.1 200"),
        "{}",
        String::from_utf8_lossy(&resp[..64])
    );
    assert!(resp.ends_with(&file), "the file arrived changed");
    assert_eq!(resp.len(), direct.len());
    // Request up (100 ms), response down (100 ms) at 125 000 B/s less the first burst.
    let burst = cbdam_link_burst(1_000_000);
    let expected = 0.2 + (resp.len() as f64 - burst) / 125_000.0;
    eprintln!(
        "{} bytes in {took:.3} s, expected {expected:.3} s",
        resp.len()
    );
    assert!(
        took >= expected && took <= expected * 1.1 + 0.5,
        "{} bytes in {took:.3} s, expected {expected:.3} s",
        resp.len()
    );
    let rest = stop(link, out);
    assert!(rest.contains("connections 1 (+1)"), "{rest}");
    let total = format!(
        "1 connections, 0 reset, {:.2} MB down",
        resp.len() as f64 / 1e6
    );
    assert!(
        rest.contains("stopped after") && rest.contains(&total),
        "{rest}"
    );
}

/// Stops `cbdam link` with SIGTERM; returns the rest of its output once it exited with 0.
#[cfg(unix)]
fn stop(mut link: Child, mut out: BufReader<ChildStdout>) -> String {
    let kill = Command::new("kill")
        .args(["-TERM", &link.id().to_string()])
        .status()
        .unwrap();
    assert!(kill.success());
    let status = link.wait().unwrap();
    let mut rest = String::new();
    out.read_to_string(&mut rest).unwrap();
    assert!(status.success(), "{status}: {rest}");
    rest
}

/// The last CSV row of a replay, by column name.
fn last_row(csv: &std::path::Path) -> std::collections::HashMap<String, f64> {
    let text = std::fs::read_to_string(csv).unwrap();
    let header: Vec<&str> = text.lines().next().unwrap().split(',').collect();
    let last = text.lines().last().unwrap();
    header
        .iter()
        .zip(last.split(','))
        .map(|(h, v)| (h.to_string(), v.parse().unwrap()))
        .collect()
}

/// A replay over `cbdam serve` through the `mobile` profile with resets made frequent
/// (`--reset-prob 0.5`; seed 7 resets the first connection after 6 212 bytes, mid-way through
/// the ~51 KB the replay fetches, and the third at its end) converges to the same cut as the
/// same replay on the local file. A 2 s flight (the shipped descent's ends), paced in real time
/// over the network.
#[cfg(unix)]
#[test]
fn replay_through_a_mobile_link_with_resets_converges_to_the_local_cut() {
    let dir = tempfile::tempdir().unwrap();
    let repo = jacksboro_at("1");
    let flight = short_flight(dir.path());
    let (mut server, server_addr) = spawn_serve(&[&format!("jb={}", s(&repo))]);
    let (link, addr, seen, out) = spawn_link(&[
        "--profile",
        "mobile",
        "--reset-prob",
        "0.5",
        "--seed",
        "7",
        "--interval",
        "0.2",
        "--to",
        &server_addr,
    ]);
    assert!(
        seen.contains("5 Mbit/s down, 1 Mbit/s up, 60 ms each way"),
        "{seen}"
    );
    let replay = |source: &str, csv: &std::path::Path| {
        let o = cbdam(&[
            "replay",
            source,
            "--path",
            &s(&flight),
            "--size",
            "640x360",
            "--fps",
            "10",
            "--out",
            &s(csv),
        ]);
        assert!(o.status.success(), "{source}: {}", stderr(&o));
        assert!(stdout(&o).contains("converged"), "{source}: {}", stdout(&o));
        last_row(csv)
    };
    let remote = replay(
        &format!("http://{addr}/v1/repos/jb"),
        &dir.path().join("remote.csv"),
    );
    let rest = stop(link, out);
    let _ = server.kill();
    let _ = server.wait();
    let local = replay(&s(&repo), &dir.path().join("local.csv"));
    for col in [
        "converged",
        "met_target",
        "max_screen_error_px",
        "diamonds_in_cut",
        "drawn_halves",
        "triangles",
        "cut_bytes",
    ] {
        assert_eq!(remote[col], local[col], "{col}");
    }
    assert_eq!(local["converged"], 1.0);
    let stopped = rest
        .lines()
        .find(|l| l.starts_with("stopped after"))
        .unwrap();
    let resets: u64 = stopped
        .split(", ")
        .find_map(|p| p.strip_suffix(" reset"))
        .unwrap()
        .parse()
        .unwrap();
    assert!(resets >= 1, "{rest}");
}

/// The link's burst (10 ms of the rate within 1 500 B and 16 KiB), as documented.
fn cbdam_link_burst(bps: u64) -> f64 {
    ((bps / 800) as f64).clamp(1500.0, 16384.0)
}

#[test]
fn link_refuses_bad_flags_by_name() {
    let to = ["--to", "127.0.0.1:9", "--listen", "127.0.0.1:0"];
    let run = |extra: &[&str]| {
        let mut a = vec!["link"];
        a.extend_from_slice(extra);
        a.extend_from_slice(&to);
        cbdam(&a)
    };
    for (extra, code, word) in [
        (
            &["--profile", "custom", "--up", "1M"][..],
            1,
            "--down, --delay-ms",
        ),
        (&["--profile", "isdn"], 1, "not a link profile"),
        (&["--profile", "adsl", "--down", "fast"], 2, "--down"),
        (
            &["--profile", "adsl", "--reset-prob", "2"],
            1,
            "--reset-prob",
        ),
        (&["--profile", "adsl", "--delay-ms", "-5"], 1, "--delay-ms"),
        (
            &["--profile", "adsl", "--jitter-ms", "1e9"],
            1,
            "--jitter-ms",
        ),
    ] {
        let o = run(extra);
        assert_eq!(o.status.code(), Some(code), "{extra:?}: {}", stderr(&o));
        assert!(stderr(&o).contains(word), "{extra:?}: {}", stderr(&o));
    }
}
