//! `cbdam inspect` as a process.

use std::process::Command;

#[test]
fn a_closed_stdout_ends_inspect_quietly() {
    let repo = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/codec/tests/data/v1/lidar1m_eps1.cbdam"
    );
    let mut child = Command::new(env!("CARGO_BIN_EXE_cbdam"))
        .args(["inspect", repo])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // As `| head -0` does: the reader goes away before anything is read.
    drop(child.stdout.take());
    let o = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!err.contains("panicked"), "{err}");
    assert_ne!(o.status.code(), Some(101), "{err}");
}
