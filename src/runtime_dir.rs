//! A private `XDG_RUNTIME_DIR` for the commands that open a GPU device.
//!
//! Mesa's Vulkan drivers (lavapipe included) try to reach a Wayland display when a device is
//! created, and libwayland prints `error: XDG_RUNTIME_DIR is invalid or not set in the
//! environment.` when the variable is missing or names no directory of ours — an "error" that is
//! none, but it reads as one in every `cbdam render`, `demo` and `view` run on a server, in a
//! container or in CI. When no usable runtime directory is set, [`ensure`] makes one (mode 0700,
//! in the temporary directory) and points the variable at it for this process and its children;
//! the directory is removed when `main` returns.

use std::path::Path;

use crate::Command;
use crate::bench::BenchCommand;

/// Whether `command` creates a GPU device (and so would make Mesa complain).
pub fn needed(command: &Command) -> bool {
    matches!(
        command,
        Command::Render(_)
            | Command::View(_)
            | Command::Demo(_)
            | Command::Bench(BenchCommand::Render(_))
    )
}

/// Whether `dir` can serve as the runtime directory: an absolute path (all libwayland checks)
/// to a directory owned by this user (what the XDG Base Directory specification asks;
/// `scripts/test.sh` applies the same rule).
#[cfg(unix)]
fn usable(dir: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    // SAFETY: geteuid has no preconditions and cannot fail.
    let uid = unsafe { libc::geteuid() };
    dir.is_absolute() && std::fs::metadata(dir).is_ok_and(|m| m.is_dir() && m.uid() == uid)
}

#[cfg(not(unix))]
fn usable(_: &Path) -> bool {
    true
}

/// A fresh directory in `parent`, mode 0700 (the runtime directory's mode by the XDG Base
/// Directory specification), removed when the value is dropped.
fn make(parent: &Path) -> std::io::Result<tempfile::TempDir> {
    let mut builder = tempfile::Builder::new();
    builder.prefix("cbdam-runtime-");
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        builder.permissions(std::fs::Permissions::from_mode(0o700));
    }
    builder.tempdir_in(parent)
}

/// Sets `XDG_RUNTIME_DIR` to a fresh private directory when `needed` and the variable names no
/// usable one; the directory is removed when the returned value is dropped (keep it until
/// `main` returns).
/// `None` when nothing was changed, or when no directory could be made (then Mesa's message
/// shows, nothing worse).
///
/// # Safety
///
/// Changes the process environment: call it before any other thread exists (first thing in
/// `main`), since reading the environment from another thread at the same time is undefined
/// behaviour on most platforms.
pub unsafe fn ensure(needed: bool) -> Option<tempfile::TempDir> {
    if !cfg!(unix) || !needed {
        return None;
    }
    if std::env::var_os("XDG_RUNTIME_DIR").is_some_and(|d| usable(Path::new(&d))) {
        return None;
    }
    let dir = make(&std::env::temp_dir()).ok()?;
    // SAFETY: the caller guarantees that no other thread exists.
    unsafe { std::env::set_var("XDG_RUNTIME_DIR", dir.path()) };
    Some(dir)
}

#[cfg(all(test, unix))]
mod tests {
    use super::*;

    #[test]
    fn a_directory_of_ours_is_usable_and_others_are_not() {
        let dir = tempfile::tempdir().unwrap();
        assert!(usable(dir.path()));
        assert!(!usable(&dir.path().join("missing")));
        assert!(
            !usable(Path::new(".")),
            "a relative path is refused by libwayland"
        );
        let file = dir.path().join("file");
        std::fs::write(&file, b"").unwrap();
        assert!(!usable(&file), "a file is no runtime directory");
        // The root directory belongs to root: unusable unless the tests run as root.
        // SAFETY: geteuid has no preconditions.
        assert_eq!(usable(Path::new("/")), unsafe { libc::geteuid() } == 0);
    }

    #[test]
    fn the_made_directory_is_private_and_removed_when_dropped() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let guard = make(dir.path()).unwrap();
        let path = guard.path().to_path_buf();
        let mode = std::fs::metadata(&path).unwrap().permissions().mode();
        assert_eq!(mode & 0o777, 0o700);
        assert!(usable(&path));
        drop(guard);
        assert!(!path.exists());
    }
}
