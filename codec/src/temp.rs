//! The build's large temporaries: where they live ([`TempStorage`]) and the lattice arrays
//! ([`LatticeArray`]) that hold one value per input lattice point (quantized heights, validity,
//! resolution classes).
//!
//! In memory a lattice array is a plain `Vec`. Past the build's memory limit it is a
//! memory-mapped file, created already unlinked: its pages are the kernel's page cache, written
//! back to disk as needed, and a page the process has touched counts in its resident set until
//! it is unmapped. So the passes over a mapped array drop the pages they are done with
//! (`madvise(MADV_DONTNEED)`, which on a shared file mapping keeps the data in the file):
//! sequential passes ([`LatticeArray::release`]) the rows behind them, the encoder's scans
//! every [`MAPPED_WINDOW_BYTES`] they report having read ([`LatticeArray::touched`]). The
//! resident part of a mapped array is then about one window, whatever the lattice's size.
//!
//! Chosen over `pread`/`pwrite` of windows because the encoder reads the lattice at random
//! under every diamond of every level, through slices: a mapping keeps those reads zero-copy and
//! the code the same for both storages.
//!
//! The block encoder reads a mapped lattice through a [`LatticeArray::window`] instead: a copy
//! of one rectangle of it, read with `pread` (no page faults, and the page cache it reads from
//! is not the process's), in an array of the lattice's full length whose other pages are never
//! touched (an anonymous mapping reserved but not allocated). Readers index it like the whole
//! lattice, and it holds memory only for the rectangle's rows. The levels above the blocks read
//! a [`LatticeArray::strided`] copy of their points. Scattered reads of the mapping itself
//! would cost far more than the pages they read: a read fault maps the whole folio of the page
//! cache around it, up to 2 MiB on Linux 6.18 with ext4's large folios (measured: 64 one-byte
//! reads 16 MiB apart left 123 MiB of the file resident; `MADV_RANDOM` and
//! `MADV_NOHUGEPAGE` change nothing).

use std::path::{Path, PathBuf};

use crate::CodecError;

mod lattice_array;
mod reserve;

pub use lattice_array::{LatticeArray, LatticeElement};
pub(crate) use reserve::reserve;

/// Where the build keeps a large temporary (the reconstruction field, the lattice).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum TempStorage {
    /// Anonymous memory.
    #[default]
    Memory,
    /// A memory-mapped temporary file, created already unlinked in this directory (the system
    /// temporary directory when `None`), so the kernel can write pages back to disk under memory
    /// pressure instead of failing.
    File(Option<PathBuf>),
    /// A memory-mapped file in this directory under a temporary name, removed when the array
    /// is dropped unless [`LatticeArray::persist`] gives it a lasting one: a lattice that other
    /// processes read afterwards (a sharded build's prepared grid) without a second copy.
    Named(PathBuf),
}

impl TempStorage {
    /// Where a build keeps a lattice of `bytes` (all its arrays) under a memory limit of
    /// `limit` bytes: in memory when it takes at most half of the limit, the other half being
    /// for the encoder's reconstruction fields and a mosaic's cache of decoded tiles; otherwise
    /// in mapped temporary files, of which about [`MAPPED_RESIDENT_BYTES`] an array stay
    /// resident.
    pub fn for_lattice(bytes: u64, limit: u64) -> Self {
        if bytes <= limit / 2 {
            TempStorage::Memory
        } else {
            TempStorage::File(None)
        }
    }

    /// This storage, with its mapped files named in `dir` when given ([`TempStorage::Named`]);
    /// memory stays memory.
    pub fn named_in(self, dir: Option<&Path>) -> Self {
        match (self, dir) {
            (TempStorage::File(_) | TempStorage::Named(_), Some(dir)) => {
                TempStorage::Named(dir.to_path_buf())
            }
            (storage, _) => storage,
        }
    }

    /// The directory this storage's files go in (the system's temporary directory for
    /// `File(None)`); `None` for [`TempStorage::Memory`].
    pub fn dir(&self) -> Option<PathBuf> {
        match self {
            TempStorage::Memory => None,
            TempStorage::File(Some(dir)) | TempStorage::Named(dir) => Some(dir.clone()),
            TempStorage::File(None) => Some(std::env::temp_dir()),
        }
    }

    /// A temporary file created already unlinked in this storage's directory (the system's
    /// temporary directory for `File(None)`), private to this process: a `Named` storage's
    /// directory too, for what is never kept. `None` for [`TempStorage::Memory`]. An error
    /// says the file was for `what`.
    pub fn unlinked_file(&self, what: &str) -> Result<Option<std::fs::File>, CodecError> {
        match self {
            TempStorage::Memory => return Ok(None),
            TempStorage::File(Some(dir)) | TempStorage::Named(dir) => tempfile::tempfile_in(dir),
            TempStorage::File(None) => tempfile::tempfile(),
        }
        .map(Some)
        .map_err(|e| creating(what, e))
    }
}

/// The error of creating a temporary file for `what`.
fn creating(what: &str, e: std::io::Error) -> CodecError {
    CodecError::Io(std::io::Error::new(
        e.kind(),
        format!("creating a temporary file for {what}: {e}"),
    ))
}

/// The start of the names of a lattice's temporary files in a directory
/// ([`TempStorage::Named`], [`LatticeArray::persist`]): removed when the array is dropped or
/// the file persisted, left behind only by a killed process.
pub const LATTICE_TEMP_PREFIX: &str = ".lattice.";

/// Bytes a mapped [`LatticeArray`] lets its readers touch before it drops its resident pages.
pub const MAPPED_WINDOW_BYTES: u64 = 64 << 20;

/// What a build counts resident of one mapped lattice array: a window, and as much again for
/// the pages the other workers touch while one drops them.
pub const MAPPED_RESIDENT_BYTES: u64 = 2 * MAPPED_WINDOW_BYTES;

#[cfg(test)]
mod tests;
