//! Helpers shared by the test modules.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// A bundled file of the workspace's `data/`.
pub fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../data")
        .join(name)
}

/// Every bundled `*.tif` DEM.
pub fn bundled_tifs() -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(data(""))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "tif"))
        .collect();
    v.sort();
    v
}

/// The workspace's `cbdam` binary of the same profile as this test: `target/PROFILE/cbdam`
/// (this test runs from `target/PROFILE/deps/`). `cargo test --workspace` builds it before any
/// test runs; alone, build it first with `cargo build -p cbdam`.
pub fn cbdam_binary() -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    let profile_dir = exe.parent().and_then(Path::parent).unwrap();
    let bin = profile_dir.join(format!("cbdam{}", std::env::consts::EXE_SUFFIX));
    assert!(
        bin.is_file(),
        "{} is missing: build it first (`cargo build -p cbdam`) or run `cargo test --workspace`",
        bin.display()
    );
    bin
}

/// Runs the `cbdam` binary with `args`.
pub fn cbdam(args: &[&std::ffi::OsStr]) -> Output {
    Command::new(cbdam_binary())
        .args(args)
        .output()
        .expect("run cbdam")
}
