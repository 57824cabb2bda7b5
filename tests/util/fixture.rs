//! The repositories many CLI tests read, built once and shared: [`shared`] keeps each one under
//! `target/tmp/cli-fixtures/KEY/`, where KEY changes whenever the `cbdam` binary or this test
//! binary changes, so a fixture is built once per build of the code under test (and once per run
//! at most), never reused from an older build. Tests only read a shared repository; a test that
//! changes, moves or lists the directory of its repository builds its own in a temporary
//! directory instead.

use std::collections::HashMap;
use std::hash::{Hash, Hasher};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use super::{build_quiet, data};

/// Jacksboro (`data/jacksboro_mpl.tif`, 403 × 344) built at `max_error` metres.
pub fn jacksboro_at(max_error: &str) -> PathBuf {
    shared(&format!("jacksboro-{max_error}.cbdam"), |out| {
        build_quiet(&data("jacksboro_mpl.tif"), out, max_error)
    })
}

/// The small synthetic planet of [`super::planet`], shared.
pub fn shared_planet() -> PathBuf {
    shared("planet.cbdam", |out| {
        let tmp = tempfile::tempdir_in(out.parent().unwrap()).unwrap();
        std::fs::rename(super::planet(tmp.path()), out).unwrap();
    })
}

/// The file `name` of the shared fixtures, made by `make(path)` if this build has not made it
/// yet. `make` writes `path`; it is renamed into place only once complete, so a test that runs
/// beside another (in this process or another) never reads half a file.
pub fn shared(name: &str, make: impl FnOnce(&Path)) -> PathBuf {
    static MADE: Mutex<Option<HashMap<String, PathBuf>>> = Mutex::new(None);
    // One fixture at a time: tests waiting for the same one wait for its single build.
    let mut made = MADE.lock().unwrap_or_else(|e| e.into_inner());
    let made = made.get_or_insert_with(HashMap::new);
    if let Some(p) = made.get(name) {
        return p.clone();
    }
    let dir = fixture_dir();
    let path = dir.join(name);
    if !path.exists() {
        let partial = dir.join(format!(".partial-{}-{name}", std::process::id()));
        make(&partial);
        std::fs::rename(&partial, &path).unwrap();
    }
    made.insert(name.to_string(), path.clone());
    path
}

/// `target/tmp/cli-fixtures/KEY`, KEY a hash of the length and modification time of the `cbdam`
/// binary and of this test binary (whose codec writes [`shared_planet`]); the directories of
/// other keys are removed when a new one is made.
fn fixture_dir() -> PathBuf {
    let mut h = std::collections::hash_map::DefaultHasher::new();
    for exe in [
        PathBuf::from(env!("CARGO_BIN_EXE_cbdam")),
        std::env::current_exe().unwrap(),
    ] {
        let m = std::fs::metadata(&exe).unwrap();
        (m.len(), m.modified().unwrap()).hash(&mut h);
    }
    let root = Path::new(env!("CARGO_TARGET_TMPDIR")).join("cli-fixtures");
    let dir = root.join(format!("{:016x}", h.finish()));
    if !dir.exists() {
        if let Ok(old) = std::fs::read_dir(&root) {
            for e in old.flatten() {
                let _ = std::fs::remove_dir_all(e.path());
            }
        }
        std::fs::create_dir_all(&dir).unwrap();
    }
    dir
}

/// A shared fixture is made once: asked for twice, `make` runs at most once (not at all when an
/// earlier run of this build made it) and both answers are the same complete file.
#[test]
fn a_shared_fixture_is_made_once_and_reused() {
    use std::sync::atomic::{AtomicUsize, Ordering};
    let made = AtomicUsize::new(0);
    let make = |p: &Path| {
        made.fetch_add(1, Ordering::SeqCst);
        std::fs::write(p, b"fixture").unwrap();
    };
    let a = shared("self-test.txt", make);
    let b = shared("self-test.txt", make);
    assert_eq!(a, b);
    assert!(made.load(Ordering::SeqCst) <= 1);
    assert_eq!(std::fs::read(&b).unwrap(), b"fixture");
}
