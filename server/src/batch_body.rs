//! The streamed body of a batch response: entries are handed to the connection a chunk at a
//! time, in answer order (most urgent first), straight from the memory map. A client that
//! drops the request (its view moved on) closes the connection; the body is then dropped
//! unfinished, nothing more of it is written, and the metrics count the batch as aborted with
//! the bytes it did not send.

use std::ops::Range;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};

use bytes::Bytes;
use cbdam_codec::repository::batch::{
    ENTRY_HEAD_LEN, MAGIC, PREAMBLE_LEN, STATUS_NOT_STORED, STATUS_RECORD,
};
use http_body::{Frame, SizeHint};

use crate::state::{AppState, ServedRepo};

/// A chunk is cut after the entry that takes it past this many bytes: small enough that a
/// closed connection stops the body soon, large enough to keep per-chunk costs negligible.
const CHUNK_BYTES: usize = 16 << 10;

/// One batch response's body: the preamble, then `entries` in order.
pub(crate) struct BatchBody {
    state: AppState,
    repo: Arc<ServedRepo>,
    /// Per entry in answer order: the record's bytes in the mapped file, or `None` when the
    /// diamond is not stored.
    entries: Vec<Option<Range<usize>>>,
    /// Entries handed over so far.
    next: usize,
    preamble_sent: bool,
    /// Bytes of the body not handed over yet.
    unsent: u64,
}

impl BatchBody {
    /// The body answering `entries` (in answer order) from `repo`'s file.
    pub(crate) fn new(
        state: AppState,
        repo: Arc<ServedRepo>,
        entries: Vec<Option<Range<usize>>>,
    ) -> Self {
        let records: usize = entries.iter().flatten().map(|r| r.len()).sum();
        let unsent = (PREAMBLE_LEN + ENTRY_HEAD_LEN * entries.len() + records) as u64;
        Self {
            state,
            repo,
            entries,
            next: 0,
            preamble_sent: false,
            unsent,
        }
    }

    fn finished(&self) -> bool {
        self.preamble_sent && self.next == self.entries.len()
    }

    /// The next chunk: whole entries (and the preamble first) up to about [`CHUNK_BYTES`].
    fn next_chunk(&mut self) -> Vec<u8> {
        let mut out = Vec::with_capacity(CHUNK_BYTES + 64);
        if !self.preamble_sent {
            out.extend_from_slice(&MAGIC);
            // The handler refused batches whose count does not fit in u32.
            out.extend_from_slice(&(self.entries.len() as u32).to_le_bytes());
            self.preamble_sent = true;
        }
        let file = self.repo.repo.as_bytes();
        let mut records = 0;
        while self.next < self.entries.len() && out.len() < CHUNK_BYTES {
            match &self.entries[self.next] {
                Some(range) => {
                    records += 1;
                    out.push(STATUS_RECORD);
                    // Index lengths are u32.
                    out.extend_from_slice(&(range.len() as u32).to_le_bytes());
                    out.extend_from_slice(&file[range.clone()]);
                }
                None => {
                    out.push(STATUS_NOT_STORED);
                    out.extend_from_slice(&0u32.to_le_bytes());
                }
            }
            self.next += 1;
        }
        self.unsent -= out.len() as u64;
        // Counted as handed over, so the records of an aborted batch that were never written
        // are not counted as sent.
        if records > 0 {
            self.state.metrics().add_records(records);
        }
        out
    }
}

impl http_body::Body for BatchBody {
    type Data = Bytes;
    type Error = std::convert::Infallible;

    fn poll_frame(
        self: Pin<&mut Self>,
        _cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, Self::Error>>> {
        let me = self.get_mut();
        if me.finished() {
            return Poll::Ready(None);
        }
        Poll::Ready(Some(Ok(Frame::data(Bytes::from(me.next_chunk())))))
    }

    fn is_end_stream(&self) -> bool {
        self.finished()
    }

    fn size_hint(&self) -> SizeHint {
        SizeHint::with_exact(self.unsent)
    }
}

impl Drop for BatchBody {
    fn drop(&mut self) {
        if self.unsent > 0 {
            self.state.metrics().add_aborted_batch(self.unsent);
        }
    }
}
