//! Byte records that a planet's block-wise encode writes once and reads back many times (the
//! apex diamonds' grids, the apex levels' refinements): kept in memory up to a threshold, then
//! written to an unlinked temporary file, so that the memory of a planet build does not grow
//! with its apex. A small apex stays in memory (no temporary to fill a disk).
//!
//! The file is written through `write` (a full disk is an error naming the temporary, never a
//! fault of a mapping) and read with positioned reads.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::sync::{Arc, Mutex};

use crate::CodecError;
use crate::temp::TempStorage;

/// Where the records' bytes are: in memory, or (past the threshold) in a temporary file and
/// how many bytes it holds.
enum Store {
    Memory(Vec<u8>),
    File(BufWriter<File>, u64),
}

/// Records being written ([`Spill::put`]), from any thread.
pub(super) struct Spill {
    store: Mutex<Store>,
    in_memory: usize,
    what: &'static str,
}

impl Spill {
    /// A spill of `what` (for its errors: "the planet apex's grids") kept in memory up to
    /// `in_memory` bytes.
    pub(super) fn new(what: &'static str, in_memory: usize) -> Self {
        Self {
            store: Mutex::new(Store::Memory(Vec::new())),
            in_memory,
            what,
        }
    }

    /// Appends `bytes`: where they went.
    pub(super) fn put(&self, bytes: &[u8]) -> Result<u64, CodecError> {
        let mut store = self.store.lock().expect("a spill");
        if let Store::Memory(held) = &mut *store {
            if held.len() + bytes.len() <= self.in_memory {
                held.extend_from_slice(bytes);
                return Ok((held.len() - bytes.len()) as u64);
            }
            let file = TempStorage::File(None)
                .unlinked_file(self.what)?
                .expect("a file storage makes a file");
            let mut file = BufWriter::with_capacity(1 << 20, file);
            file.write_all(held).map_err(|e| writing(self.what, e))?;
            let len = held.len() as u64;
            *store = Store::File(file, len);
        }
        let Store::File(file, len) = &mut *store else {
            unreachable!("spilled above")
        };
        let at = *len;
        file.write_all(bytes).map_err(|e| writing(self.what, e))?;
        *len += bytes.len() as u64;
        Ok(at)
    }

    /// The records written, to be read back.
    pub(super) fn finish(self) -> Result<Spilled, CodecError> {
        let what = self.what;
        let bytes = match self.store.into_inner().expect("a spill") {
            Store::Memory(held) => Bytes::Memory(Arc::new(held)),
            Store::File(writer, _) => Bytes::File(Arc::new(
                writer
                    .into_inner()
                    .map_err(|e| writing(what, e.into_error()))?,
            )),
        };
        Ok(Spilled { bytes, what })
    }
}

/// The records' bytes, in memory or in a temporary file.
#[derive(Clone)]
enum Bytes {
    Memory(Arc<Vec<u8>>),
    File(Arc<File>),
}

/// Records a [`Spill`] wrote, read back by position from any thread.
#[derive(Clone)]
pub(super) struct Spilled {
    bytes: Bytes,
    what: &'static str,
}

impl Spilled {
    /// Fills `out` with the bytes written at `at`.
    pub(super) fn read(&self, at: u64, out: &mut [u8]) -> Result<(), CodecError> {
        match &self.bytes {
            Bytes::Memory(held) => {
                let range = usize::try_from(at)
                    .ok()
                    .and_then(|a| Some(a..a.checked_add(out.len())?))
                    .filter(|r| r.end <= held.len());
                let Some(range) = range else {
                    return Err(CodecError::invalid(format!(
                        "{}: {} bytes at {at} past the {} held",
                        self.what,
                        out.len(),
                        held.len()
                    )));
                };
                out.copy_from_slice(&held[range]);
                Ok(())
            }
            Bytes::File(file) => read_at(file, out, at).map_err(|e| {
                CodecError::Io(std::io::Error::new(
                    e.kind(),
                    format!("reading a temporary file for {}: {e}", self.what),
                ))
            }),
        }
    }

    /// Whether the records went to a temporary file.
    #[cfg(test)]
    pub(super) fn in_file(&self) -> bool {
        matches!(self.bytes, Bytes::File(_))
    }
}

/// The error of writing the temporary file for `what`.
fn writing(what: &str, e: std::io::Error) -> CodecError {
    CodecError::Io(std::io::Error::new(
        e.kind(),
        format!("writing a temporary file for {what}: {e}"),
    ))
}

/// Reads `bytes.len()` bytes of `file` at `at`: a positioned read on Unix (the blocks read in
/// parallel, with no shared cursor); elsewhere (where no planet is built today, e.g. the browser
/// build of this crate) a seek and a read, one reader at a time.
fn read_at(file: &File, bytes: &mut [u8], at: u64) -> std::io::Result<()> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileExt;
        file.read_exact_at(bytes, at)
    }
    #[cfg(not(unix))]
    {
        use std::io::{Read, Seek, SeekFrom};
        static CURSOR: Mutex<()> = Mutex::new(());
        let _one_reader = CURSOR.lock().unwrap_or_else(|e| e.into_inner());
        let mut file = file;
        file.seek(SeekFrom::Start(at))?;
        file.read_exact(bytes)
    }
}
