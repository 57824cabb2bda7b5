//! Reading records for an answer, from one of three places:
//!
//! - a repository given in memory, or a file whose records area the server read into memory
//!   when it opened it ([`crate::state::Config::held_records_bytes`]): no read; each record's
//!   CRC is checked the first time it is served (the bytes cannot change after);
//! - any other file: the records of a batch chunk (or the one of a single GET) are read with as
//!   few positioned reads as their places in the file allow (records near each other in one),
//!   and every record's CRC is checked on every read, so that a file rewritten in place with
//!   its length and modification time kept never sends bytes its ETag does not name.
//!
//! The file's identity ([`crate::state::FileIdentity`]) is checked before every answer and
//! after every read of the file, so a file changed in place is refused, and a file truncated
//! underneath gives a short read, an error, never a fault.

use cbdam_codec::repository::Section;

use crate::error::ApiError;
use crate::state::{AppState, ServedRepo, Source};
use std::sync::atomic::Ordering::Relaxed;

/// Records whose bytes lie at most this far apart are read with one positioned read, the bytes
/// between them read and dropped: a syscall costs about as much as copying a few KiB.
const MERGE_GAP: u64 = 4 << 10;

/// No merged read is longer than this (unless one record is).
const MAX_SPAN: u64 = 1 << 20;

/// Why records could not be read.
#[derive(Debug)]
pub(crate) enum RecordError {
    /// The file could not be read, or changed underneath: the error to answer with.
    Read(ApiError),
    /// The record at this index position fails its CRC.
    Damaged(usize, cbdam_codec::CodecError),
}

/// Buffers reused from one read of records to the next (a batch body keeps one for its life).
#[derive(Default)]
pub(crate) struct RecordBuffer {
    /// The merged reads' bytes, back to back.
    bytes: Vec<u8>,
    /// Per record asked for: where its bytes start in `bytes`.
    starts: Vec<usize>,
    /// Positions into the records asked for, in file order.
    order: Vec<u32>,
}

impl ServedRepo {
    /// Reads the records at index positions `records` and hands each one's bytes to `emit`, in
    /// the order given, once all are read, the file's identity is confirmed and every record
    /// not checked before has passed its CRC. Nothing is emitted on an error.
    pub(crate) fn read_records(
        &self,
        records: &[usize],
        buf: &mut RecordBuffer,
        emit: impl FnMut(usize, &[u8]),
    ) -> Result<(), RecordError> {
        let head = self.repo.head();
        // Index positions come from a search of the index, checked against the file.
        let range = |i: usize| head.record_range(i).expect("an index position");
        match &self.source {
            Source::Memory => {
                let bytes = self.repo.as_bytes();
                let slice = |k: usize| {
                    let r = range(records[k]);
                    &bytes[r.start as usize..r.end as usize]
                };
                self.emit_checked(records, slice, true, emit)
            }
            Source::File {
                held: Some(held), ..
            } => {
                // Read when the file was opened: these are the bytes the ETags name whatever
                // the file does since (each answer checks its identity before it starts).
                let at = head.section_offset(Section::Records);
                let slice = |k: usize| {
                    let r = range(records[k]);
                    &held[(r.start - at) as usize..(r.end - at) as usize]
                };
                self.emit_checked(records, slice, true, emit)
            }
            Source::File { .. } => {
                self.read_merged(records, buf).map_err(RecordError::Read)?;
                // After the reads: an unchanged identity proves they read the file as opened.
                self.check_unchanged().map_err(RecordError::Read)?;
                let (bytes, starts) = (&buf.bytes, &buf.starts);
                let slice = |k: usize| {
                    let r = range(records[k]);
                    &bytes[starts[k]..starts[k] + (r.end - r.start) as usize]
                };
                self.emit_checked(records, slice, false, emit)
            }
        }
    }

    /// Checks the CRC of every record of `records`, whose bytes `slice(k)` gives for the `k`th
    /// (unless it passed before and `trust_verified`), then hands each to `emit`, in order.
    fn emit_checked<'a>(
        &self,
        records: &[usize],
        slice: impl Fn(usize) -> &'a [u8],
        trust_verified: bool,
        mut emit: impl FnMut(usize, &[u8]),
    ) -> Result<(), RecordError> {
        for (k, &i) in records.iter().enumerate() {
            self.check_crc(i, slice(k), trust_verified)?;
        }
        for (k, &i) in records.iter().enumerate() {
            emit(i, slice(k));
        }
        Ok(())
    }

    /// Record `i`'s CRC, unless it passed before and `trust_verified`; marks it verified.
    fn check_crc(&self, i: usize, bytes: &[u8], trust_verified: bool) -> Result<(), RecordError> {
        if trust_verified && self.verified[i].load(Relaxed) {
            return Ok(());
        }
        match self.repo.head().check_record(i, bytes) {
            Ok(()) => {
                self.verified[i].store(true, Relaxed);
                Ok(())
            }
            Err(e) => {
                // Checked once, damaged since: no longer known good.
                self.verified[i].store(false, Relaxed);
                Err(RecordError::Damaged(i, e))
            }
        }
    }

    /// Reads `records` into `buf.bytes` with one positioned read per run of records at most
    /// [`MERGE_GAP`] apart, and notes where each record starts.
    fn read_merged(&self, records: &[usize], buf: &mut RecordBuffer) -> Result<(), ApiError> {
        let head = self.repo.head();
        let range = |k: u32| {
            head.record_range(records[k as usize])
                .expect("an index position")
        };
        buf.order.clear();
        buf.order.extend(0..records.len() as u32);
        buf.order.sort_unstable_by_key(|&k| range(k).start);
        buf.bytes.clear();
        buf.starts.clear();
        buf.starts.resize(records.len(), 0);
        let mut run = 0;
        while run < buf.order.len() {
            let first = range(buf.order[run]).start;
            let mut end = range(buf.order[run]).end;
            let mut next = run + 1;
            while next < buf.order.len() {
                let r = range(buf.order[next]);
                if r.start > end + MERGE_GAP || r.end.max(end) - first > MAX_SPAN {
                    break;
                }
                end = end.max(r.end);
                next += 1;
            }
            let base = buf.bytes.len();
            self.read_into(first..end, &mut buf.bytes)?;
            for &k in &buf.order[run..next] {
                buf.starts[k as usize] = base + (range(k).start - first) as usize;
            }
            run = next;
        }
        Ok(())
    }
}

/// Reads `records` ([`ServedRepo::read_records`]), handing each one's bytes to `emit`. A
/// damaged record is answered with 500 and logged the first time only.
pub(crate) fn read_records(
    st: &AppState,
    r: &ServedRepo,
    records: &[usize],
    buf: &mut RecordBuffer,
    emit: impl FnMut(usize, &[u8]),
) -> Result<(), ApiError> {
    match r.read_records(records, buf, emit) {
        Ok(()) => Ok(()),
        Err(RecordError::Read(e)) => Err(e),
        Err(RecordError::Damaged(i, e)) => {
            st.metrics().add_corrupt();
            let id = r.repo.head().entries()[i].id;
            if !r.corrupt_logged[i].swap(true, Relaxed) {
                tracing::error!(
                    repo = %r.name,
                    diamond = %id,
                    "damaged record, answering 500 for it (logged once): {e}"
                );
            }
            Err(ApiError::Internal(format!(
                "the record of diamond {id} in repository {:?} is damaged",
                r.name
            )))
        }
    }
}
