//! `cbdam serve` as a process.

use crate::util::*;

/// `cbdam serve` as a process: serves over loopback, answers a raw HTTP/1.1 request, and exits
/// cleanly (status 0) on SIGTERM.
#[cfg(unix)]
#[test]
fn serve_answers_and_stops_on_sigterm() {
    use std::io::{BufRead, BufReader, Read, Write};
    use std::process::{Command, Stdio};

    let dir = tempfile::tempdir().unwrap();
    let repo = dir.path().join("jb.cbdam");
    build_quiet(&data("jacksboro_mpl.tif"), &repo, "2");
    let mut child = Command::new(env!("CARGO_BIN_EXE_cbdam"))
        .args(["serve", &s(&repo), "--addr", "127.0.0.1:0"])
        .env("RUST_LOG", "info")
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut err = BufReader::new(child.stderr.take().unwrap());
    let mut seen = String::new();
    let addr = loop {
        let mut line = String::new();
        assert!(
            err.read_line(&mut line).unwrap() > 0,
            "exited early: {seen}"
        );
        seen += &line;
        if let Some(i) = line.find("listening on http://") {
            break line[i + "listening on http://".len()..].trim().to_string();
        }
    };
    let mut t = std::net::TcpStream::connect(&addr).unwrap();
    t.write_all(b"GET /v1/repos HTTP/1.1\r\nhost: x\r\nconnection: close\r\n\r\n")
        .unwrap();
    let mut resp = String::new();
    t.read_to_string(&mut resp).unwrap();
    assert!(resp.starts_with("HTTP/1.1 200"), "{resp}");
    let body = &resp[resp.find("\r\n\r\n").unwrap() + 4..];
    let v: serde_json::Value = serde_json::from_str(body).unwrap();
    assert_eq!(
        v,
        serde_json::json!({"repos": [{"name": "jb", "meta": "/v1/repos/jb/meta"}]})
    );
    let kill = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(kill.success());
    let status = child.wait().unwrap();
    let mut rest = String::new();
    err.read_to_string(&mut rest).unwrap();
    assert!(status.success(), "{status}: {seen}{rest}");
    assert!(
        rest.contains("SIGTERM") && rest.contains("stopped"),
        "{rest}"
    );
    // The access log has the request.
    assert!(
        rest.contains("/v1/repos") && rest.contains("status=200"),
        "{rest}"
    );
}

#[test]
fn serve_refuses_bad_repositories_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.cbdam");
    let o = cbdam(&["serve", &s(&missing), "--addr", "127.0.0.1:0"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("missing.cbdam"), "{}", stderr(&o));
    let junk = dir.path().join("junk.cbdam");
    std::fs::write(&junk, b"not a repository at all").unwrap();
    let o = cbdam(&["serve", &s(&junk), "--addr", "127.0.0.1:0"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("junk.cbdam"), "{}", stderr(&o));
    let o = cbdam(&[
        "serve",
        &format!("a={}", s(&junk)),
        &format!("a={}", s(&missing)),
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains("\"a\" is given twice"),
        "{}",
        stderr(&o)
    );
    let o = cbdam(&["serve", &s(&dir.path().join("bad name.cbdam"))]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains("invalid repository name"),
        "{}",
        stderr(&o)
    );
}

/// `cbdam serve` started under a low soft limit on open files raises it to the hard limit and
/// says so: the soft limit bounds `--max-connections`, and 1 024 is a common default.
#[cfg(unix)]
#[test]
fn serve_raises_its_soft_fd_limit_to_the_hard_limit() {
    use std::io::{BufRead, BufReader};
    use std::process::{Command, Stdio};

    let hard = Command::new("sh")
        .args(["-c", "ulimit -Hn"])
        .output()
        .unwrap();
    let hard = String::from_utf8_lossy(&hard.stdout).trim().to_string();
    assert!(
        hard == "unlimited" || hard.parse::<u64>().unwrap() > 512,
        "the test lowers the soft limit to 256 and needs a hard limit over 512, not {hard}"
    );
    let repo = jacksboro_at("2");
    let mut child = Command::new("sh")
        .args([
            "-c",
            "ulimit -Sn 256 && exec \"$0\" serve \"$1\" --addr 127.0.0.1:0",
        ])
        .arg(env!("CARGO_BIN_EXE_cbdam"))
        .arg(&repo)
        .env("RUST_LOG", "info")
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut err = BufReader::new(child.stderr.take().unwrap());
    let mut seen = String::new();
    while !seen.contains("listening on http://") {
        let mut line = String::new();
        if err.read_line(&mut line).unwrap() == 0 {
            break;
        }
        seen += &line;
    }
    child.kill().unwrap();
    child.wait().unwrap();
    assert!(
        seen.contains(&format!(
            "raised the soft limit on open files from 256 to the hard limit, {hard}"
        )),
        "{seen}"
    );
}
