//! Writing a file so that readers see either the old file or the complete new one.

use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};

use crate::CodecError;

/// Removes the temporary file unless the write went through.
struct TempGuard(Option<PathBuf>);

impl Drop for TempGuard {
    fn drop(&mut self) {
        if let Some(p) = self.0.take() {
            let _ = std::fs::remove_file(p);
        }
    }
}

/// Writes `path` atomically: `write` fills a temporary file in the same directory (same file
/// system, so the rename cannot degrade into a copy), which is synced and then renamed over
/// `path`. A reader never sees a half-written file, and a failed write — an error from `write`
/// included — leaves nothing behind. Refuses a `path` that is a directory.
///
/// The file handed to `write` is seekable, which some encoders (TIFF) need.
pub fn write_atomically<E: From<CodecError> + From<std::io::Error>>(
    path: &Path,
    write: impl FnOnce(&mut File) -> Result<(), E>,
) -> Result<(), E> {
    if path.is_dir() {
        return Err(
            CodecError::invalid(format!("output path {} is a directory", path.display())).into(),
        );
    }
    let name = path.file_name().ok_or_else(|| {
        CodecError::invalid(format!("output path {} names no file", path.display()))
    })?;
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let mut tmp = None;
    let mut file = None;
    for attempt in 0..100u32 {
        let candidate = dir.join(format!(
            ".{}.tmp-{}-{attempt}",
            name.to_string_lossy(),
            std::process::id()
        ));
        match OpenOptions::new()
            .read(true)
            .write(true)
            .create_new(true)
            .open(&candidate)
        {
            Ok(f) => {
                tmp = Some(candidate);
                file = Some(f);
                break;
            }
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(e.into()),
        }
    }
    let (Some(tmp), Some(file)) = (tmp, file) else {
        return Err(
            CodecError::invalid("could not create a temporary file next to the output").into(),
        );
    };
    let mut guard = TempGuard(Some(tmp.clone()));
    {
        // Closed at the end of this block, before the rename.
        let mut file = file;
        write(&mut file)?;
        file.flush()?;
        file.sync_all()?;
    }
    std::fs::rename(&tmp, path)?;
    guard.0 = None;
    // Make the rename itself durable; not every platform lets a directory be opened and synced.
    if let Ok(d) = File::open(&dir) {
        let _ = d.sync_all();
    }
    Ok(())
}
