//! Helpers shared by the CLI tests: run the binary, read its output, find the bundled data, and
//! the repositories many tests read.
//!
//! The convention (tests/README.md): every CLI test is in a module of `tests/cli/`, one per
//! subcommand or feature, all linked into the one test binary `tests` (`cargo test -p cbdam
//! --test tests cli::build::`). A test runs `cbdam` through [`cbdam`] (the output, for a test
//! that checks more), [`run_ok`] (must succeed: its stdout), [`build_quiet`], or
//! [`run_refused`] (must fail, not by a panic, naming the problem: its stderr;
//! [`run_refused_leaving`] also checks that nothing was left behind). A repository a test only
//! reads comes from `fixture` ([`jacksboro_at`], [`shared_planet`], or [`shared`] for another
//! kind), built once per build; one it changes is built in the test's own temporary directory.
//! The Dask bridge is run through [`dask`].

pub mod dask;
mod fixture;
pub use fixture::*;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};

/// Runs the `cbdam` binary under test with `args`.
pub fn cbdam(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_cbdam"))
        .args(args)
        .output()
        .expect("run cbdam")
}

/// Runs `cbdam args…`, which must succeed; returns its stdout. On failure the test fails with the
/// command and its stderr.
pub fn run_ok(args: &[&str]) -> String {
    let o = cbdam(args);
    assert!(o.status.success(), "cbdam {args:?} failed: {}", stderr(&o));
    stdout(&o)
}

/// Runs `cbdam args…`, which must be refused: exit status 1 (an error) or 2 (a usage error), never
/// a panic or a signal, and stderr naming each of `says`. Returns stderr.
pub fn run_refused(args: &[&str], says: &[&str]) -> String {
    check_refused(&cbdam(args), args, says)
}

/// [`run_refused`] that also checks the refusal left `dir` as it was (no output, not even a
/// temporary file).
pub fn run_refused_leaving(dir: &Path, args: &[&str], says: &[&str]) -> String {
    let before = listing(dir);
    let e = run_refused(args, says);
    assert_eq!(listing(dir), before, "cbdam {args:?} left files behind");
    e
}

/// What [`run_refused`] checks, for output the test got another way (`what`: the command, for
/// the failure message).
pub fn check_refused(o: &Output, what: impl std::fmt::Debug, says: &[&str]) -> String {
    let e = stderr(o);
    // 1: an error the command reports; 2: a usage error clap reports. A panic exits 101, a
    // signal with no code at all.
    assert!(
        matches!(o.status.code(), Some(1 | 2)),
        "cbdam {what:?} was not refused cleanly ({}): {e}{}",
        o.status,
        stdout(o)
    );
    assert!(!e.contains("panicked"), "cbdam {what:?} panicked: {e}");
    for s in says {
        assert!(e.contains(s), "cbdam {what:?}: no {s:?} in: {e}");
    }
    e
}

/// `a` as the `&str`s [`cbdam`] takes.
pub fn strs(a: &[String]) -> Vec<&str> {
    a.iter().map(String::as_str).collect()
}

/// Runs `cbdam args…`, failing the test (and killing the process) if it has not finished
/// within `secs` seconds: for commands that must refuse at once rather than wait (on a FIFO, or
/// serving what they should have refused).
pub fn cbdam_within(args: &[&str], secs: u64) -> Output {
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_cbdam"))
        .args(args)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(secs);
    while child.try_wait().unwrap().is_none() {
        if std::time::Instant::now() > deadline {
            child.kill().unwrap();
            child.wait().unwrap();
            panic!("{args:?} still running after {secs} s");
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    child.wait_with_output().unwrap()
}

/// Starts `cbdam serve ARGS… --addr 127.0.0.1:0` and returns the process with its `host:port`
/// once it logs that it listens. The rest of its log is drained on a thread, so the server never
/// blocks on a full pipe; kill the child when done.
pub fn spawn_serve(args: &[&str]) -> (Child, String) {
    use std::io::{BufRead, BufReader};
    let mut server = Command::new(env!("CARGO_BIN_EXE_cbdam"))
        .arg("serve")
        .args(args)
        .args(["--addr", "127.0.0.1:0"])
        .env("RUST_LOG", "info")
        .stderr(Stdio::piped())
        .spawn()
        .expect("run cbdam serve");
    let mut err = BufReader::new(server.stderr.take().expect("piped stderr"));
    let mut seen = String::new();
    let addr = loop {
        let mut line = String::new();
        assert!(
            err.read_line(&mut line).expect("read the server's log") > 0,
            "cbdam serve exited early: {seen}"
        );
        seen += &line;
        if let Some(i) = line.find("listening on http://") {
            break line[i + "listening on http://".len()..].trim().to_string();
        }
    };
    std::thread::spawn(move || for _ in err.lines() {});
    (server, addr)
}

/// Whether `ci`, the value of the `CI` environment variable, marks a CI run: set, as CI
/// services set it (`true`, `1`, …), and not `false`, `0` or empty.
fn is_ci(ci: Option<&std::ffi::OsStr>) -> bool {
    ci.is_some_and(|v| !matches!(v.to_str(), Some("" | "0" | "false" | "FALSE" | "False")))
}

/// A test whose prerequisite (a program, a display, pip) is missing: outside CI it prints
/// `SKIPPED test: why` and the caller returns; under CI (`CI` set, see [`is_ci`]) a missing
/// prerequisite is a failure, never a skip, so a green CI run has run every test.
pub fn skip_unless_ci(test: &str, why: &str) {
    skip_or_fail(std::env::var_os("CI").as_deref(), test, why);
}

fn skip_or_fail(ci: Option<&std::ffi::OsStr>, test: &str, why: &str) {
    assert!(
        !is_ci(ci),
        "{test}: a prerequisite is missing and CI is set, so this fails instead of skipping: \
         {why}"
    );
    println!("SKIPPED {test}: {why}");
}

/// Under CI a missing prerequisite fails the test; elsewhere it is skipped.
#[test]
fn a_missing_prerequisite_fails_under_ci_and_skips_elsewhere() {
    use std::ffi::OsStr;
    for ci in [None, Some(""), Some("0"), Some("false")] {
        skip_or_fail(ci.map(OsStr::new), "t", "no tool");
    }
    for ci in ["true", "1", "yes"] {
        let r = std::panic::catch_unwind(|| skip_or_fail(Some(OsStr::new(ci)), "t", "no tool"));
        assert!(r.is_err(), "CI={ci} skipped");
    }
}

/// `cbdam build INPUT -o OUT --max-error E --quiet`, which must succeed.
pub fn build_quiet(input: &str, out: &Path, max_error: &str) {
    let out = s(out);
    run_ok(&[
        "build",
        input,
        "-o",
        &out,
        "--max-error",
        max_error,
        "--quiet",
    ]);
}

/// A path as a command-line argument.
pub fn s(p: &Path) -> String {
    p.to_string_lossy().into_owned()
}

/// The file name of `p`, as `cbdam` prints it in its tables.
pub fn file_name(p: &Path) -> String {
    p.file_name().unwrap().to_string_lossy().into_owned()
}

/// A bundled DEM of `data/`, as a command-line argument.
pub fn data(name: &str) -> String {
    s(&Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("data")
        .join(name))
}

pub fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Files in `dir`, to show that a failed command leaves nothing (not even a temporary).
pub fn listing(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    v.sort();
    v
}

/// The names left in `dir`, sorted.
pub fn names_in(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

/// Jacksboro built into `dir` at 2 m: small and quick, and the viewer's and renderer's cuts
/// converge on it in a few frames.
pub fn jacksboro(dir: &Path) -> PathBuf {
    let repo = dir.join("j.cbdam");
    build_quiet(&data("jacksboro_mpl.tif"), &repo, "2");
    repo
}

/// A 2 s camera flight over Jacksboro (the ends of the shipped `descent.json`), written into
/// `dir`: short enough for a replay over a slow link.
pub fn short_flight(dir: &Path) -> PathBuf {
    let flight = dir.join("short.json");
    std::fs::write(
        &flight,
        r#"{ "keyframes": [
            { "t": 0.0, "eye": [0.50, -0.60, 25.0], "target": [0.50, 0.50, 0.00] },
            { "t": 2.0, "eye": [0.51, 0.48, 1.08], "target": [0.54, 0.53, 0.50] } ] }"#,
    )
    .unwrap();
    flight
}

/// An RGBA PNG (what `render` and `view` write): width, height and the pixels.
pub fn read_rgba_png(path: &Path) -> (u32, u32, Vec<u8>) {
    let file = std::io::BufReader::new(std::fs::File::open(path).unwrap());
    let mut reader = png::Decoder::new(file).read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgba);
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}

/// A small synthetic planet repository (cube-sphere, N = 9, K = 2: 33 points per face side),
/// written through the codec (`build --planet` is not used): a smooth relief from geodetic
/// latitude and longitude and one 4 km mountain at 30° N, 20° E.
pub fn planet(dir: &Path) -> PathBuf {
    use cbdam_codec::geodesy::lattice_lat_lon;
    use cbdam_codec::geometry::Domain;
    use cbdam_codec::hierarchy::{EncodeOptions, PlanetGrid, encode_planet};
    use cbdam_codec::quant::QuantPlan;
    let (n, k) = (9usize, 2u32);
    let domain = Domain::cube_sphere(n, k).unwrap();
    let plan = QuantPlan::new(5.0, None, -3000.0, 5000.0).unwrap();
    let grid = PlanetGrid::from_fn(n, k, |p| {
        let ll = lattice_lat_lon(&domain, p.face, p.x, p.y)?;
        let (la, lo) = (ll.lat.to_radians(), ll.lon.to_radians());
        let d2 = (ll.lat - 30.0).powi(2) + (ll.lon - 20.0).powi(2);
        let h = 800.0 * (2.0 * la).sin() * (3.0 * lo).cos() + 4000.0 * (-d2 / 200.0).exp();
        plan.to_units(h).ok().flatten()
    })
    .unwrap();
    let opts = EncodeOptions {
        n,
        ..EncodeOptions::default()
    };
    let encoded = encode_planet(&grid, plan.quantizer, &opts).unwrap();
    let path = dir.join("planet.cbdam");
    let bytes = cbdam_codec::repository::serialize(&encoded, &plan, None, None).unwrap();
    std::fs::write(&path, bytes).unwrap();
    path
}

/// The finished-block files (`block-*`) in a build's journal directory; 0 when it is absent.
pub fn journal_blocks(journal: &Path) -> usize {
    std::fs::read_dir(journal).map_or(0, |d| {
        d.filter_map(|e| e.ok())
            .filter(|e| e.file_name().to_string_lossy().starts_with("block-"))
            .count()
    })
}

/// Starts `cbdam ARGS --quiet` and SIGKILLs it once its journal (whose key is written before
/// the encode) holds `n` blocks; fails if the build ended or stalled before that.
pub fn kill_after_blocks(args: &[String], journal: &Path, n: usize) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_cbdam"))
        .args(args)
        .arg("--quiet")
        .spawn()
        .unwrap();
    let start = std::time::Instant::now();
    while !(journal.join("key").exists() && journal_blocks(journal) >= n) {
        assert!(start.elapsed().as_secs() < 120, "no progress to kill at");
        if child.try_wait().unwrap().is_some() {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(2));
    }
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    assert!(
        journal_blocks(journal) >= n,
        "the build was not killed after {n} blocks"
    );
}

/// [`check_refused`] passes a clean refusal (status 1 or 2, every word named) and fails a
/// success, a panic (status 101), a signal and a refusal that does not name the problem.
#[cfg(unix)]
#[test]
fn a_refusal_must_fail_cleanly_and_name_the_problem() {
    use std::os::unix::process::ExitStatusExt;
    let output = |raw: i32, err: &str| Output {
        status: std::process::ExitStatus::from_raw(raw),
        stdout: Vec::new(),
        stderr: err.as_bytes().to_vec(),
    };
    let named = "cbdam: error: bad.tif: no such file";
    check_refused(&output(1 << 8, named), "ok", &["bad.tif", "no such file"]);
    check_refused(&output(2 << 8, named), "usage", &["bad.tif"]);
    for (raw, err, says) in [
        (0, named, vec!["bad.tif"]),
        (101 << 8, "thread 'main' panicked at src/x.rs", vec![]),
        (9, "", vec![]), // killed by SIGKILL
        (1 << 8, named, vec!["other.tif"]),
    ] {
        let r = std::panic::catch_unwind(|| check_refused(&output(raw, err), "bad", &says));
        assert!(r.is_err(), "status {raw:#x}, {err:?}: passed");
    }
}
