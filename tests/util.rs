//! Helpers shared by the CLI tests: run the binary, read its output, find the bundled data.
//! Each module of `tests.rs` uses some of them.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};

/// Runs the `cbdam` binary under test with `args`.
pub fn cbdam(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_cbdam"))
        .args(args)
        .output()
        .expect("run cbdam")
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

/// A path as a command-line argument.
pub fn s(p: &Path) -> String {
    p.to_string_lossy().into_owned()
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

/// Jacksboro built into `dir` at 2 m: small and quick, and the viewer's and renderer's cuts
/// converge on it in a few frames.
pub fn jacksboro(dir: &Path) -> PathBuf {
    let repo = dir.join("j.cbdam");
    let o = cbdam(&[
        "build",
        &data("jacksboro_mpl.tif"),
        "-o",
        &s(&repo),
        "--max-error",
        "2",
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    repo
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
