//! The streamed body of a batch response: entries are handed to the connection a chunk at a
//! time, in answer order (most urgent first), the records of a chunk read from the file
//! together as it is made ([`crate::records`]: few positioned reads, the file's identity checked
//! after them). The connection asks for a chunk only when its write
//! buffer (bounded, see [`crate::run`]) has room, and each chunk takes room in the server's
//! answer memory first ([`crate::answer_memory`]), so a client that does not read its answer
//! holds one chunk, never the whole answer, and all such clients together at most the budget. A client that drops the request
//! (its view moved on) closes the connection; the body is then dropped unfinished, nothing
//! more of it is read or written, and the metrics count the batch as aborted with the bytes it
//! did not send.

use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll, ready};

use bytes::Bytes;
use cbdam_codec::repository::batch::{
    ENTRY_HEAD_LEN, MAGIC, PREAMBLE_LEN, STATUS_NOT_STORED, STATUS_RECORD,
};
use http_body::{Frame, SizeHint};

use crate::answer_memory::Claim;
use crate::conn::ConnHandle;
use crate::records::{RecordBuffer, read_records};
use crate::state::{AppState, ServedRepo};

/// A chunk is cut after the entry that takes it past this many bytes: small enough that a
/// closed connection stops the body soon and an unread one holds little (all unread ones
/// together are bounded by [`crate::answer_memory`]), large enough that a 64-id batch of
/// kilobyte records is one chunk, one write: with 16 KiB chunks hyper flushed each on its own,
/// and batches cost a quarter more server CPU than slices of a memory map did.
pub(crate) const CHUNK_BYTES: usize = 64 << 10;

/// An entry that is not stored (in [`BatchBody::entries`]).
pub(crate) const NOT_STORED: u32 = u32::MAX;

/// One batch response's body: the preamble, then `entries` in order.
pub(crate) struct BatchBody {
    state: AppState,
    repo: Arc<ServedRepo>,
    /// Per entry in answer order: the record's position in the index, or [`NOT_STORED`]. Four
    /// bytes an entry: a 4 096-id batch waiting on a slow reader holds 16 KiB of them.
    entries: Vec<u32>,
    /// Entries handed over so far.
    next: usize,
    preamble_sent: bool,
    /// Bytes of the body not handed over yet.
    unsent: u64,
    /// Room for each chunk in the server's answer memory ([`crate::answer_memory`]).
    claim: Claim,
    /// The request's connection (absent when the router is called without [`crate::run`]).
    conn: Option<ConnHandle>,
}

impl BatchBody {
    /// The body answering `entries` (in answer order) from `repo`'s file.
    pub(crate) fn new(
        state: AppState,
        repo: Arc<ServedRepo>,
        entries: Vec<u32>,
        conn: Option<ConnHandle>,
    ) -> Self {
        let records: u64 = entries
            .iter()
            .filter(|&&i| i != NOT_STORED)
            .map(|&i| u64::from(repo.repo.head().entries()[i as usize].length))
            .sum();
        let unsent = (PREAMBLE_LEN + ENTRY_HEAD_LEN * entries.len()) as u64 + records;
        Self {
            state,
            repo,
            entries,
            next: 0,
            preamble_sent: false,
            unsent,
            claim: Claim::default(),
            conn,
        }
    }

    fn finished(&self) -> bool {
        self.preamble_sent && self.next == self.entries.len()
    }

    /// The next chunk's entries, `self.next..end`, and its length: whole entries (and the
    /// preamble first) up to the one that takes it past [`CHUNK_BYTES`].
    fn plan_chunk(&self) -> (usize, usize) {
        let head = self.repo.repo.head();
        let mut size = if self.preamble_sent { 0 } else { PREAMBLE_LEN };
        let mut end = self.next;
        while end < self.entries.len() && size < CHUNK_BYTES {
            size += ENTRY_HEAD_LEN;
            let i = self.entries[end];
            if i != NOT_STORED {
                size += head.entries()[i as usize].length as usize;
            }
            end += 1;
        }
        (end, size)
    }

    /// The chunk of entries `self.next..end`, `size` bytes ([`BatchBody::plan_chunk`]). Fails
    /// when a record can no longer be read as it was checked before the answer started (the
    /// file changed underneath): the connection is then cut, so the client sees a truncated
    /// answer, never wrong bytes.
    fn next_chunk(&mut self, end: usize, size: usize) -> Result<Vec<u8>, std::io::Error> {
        let mut out = Vec::with_capacity(size);
        if !self.preamble_sent {
            out.extend_from_slice(&MAGIC);
            // The handler refused batches whose count does not fit in u32.
            out.extend_from_slice(&(self.entries.len() as u32).to_le_bytes());
            self.preamble_sent = true;
        }
        let entries = &self.entries[self.next..end];
        // Made afresh per chunk (one allocation a chunk, none a record): a body waiting on a
        // client that does not read holds no read buffers.
        let records: Vec<usize> = entries
            .iter()
            .filter(|&&i| i != NOT_STORED)
            .map(|&i| i as usize)
            .collect();
        let mut at = 0;
        let not_stored = |out: &mut Vec<u8>, at: &mut usize| {
            while *at < entries.len() && entries[*at] == NOT_STORED {
                out.push(STATUS_NOT_STORED);
                out.extend_from_slice(&0u32.to_le_bytes());
                *at += 1;
            }
        };
        let read = read_records(
            &self.state,
            &self.repo,
            &records,
            &mut RecordBuffer::default(),
            |_, bytes| {
                not_stored(&mut out, &mut at);
                out.push(STATUS_RECORD);
                // Index lengths are u32.
                out.extend_from_slice(&(bytes.len() as u32).to_le_bytes());
                out.extend_from_slice(bytes);
                at += 1;
            },
        );
        if let Err(e) = read {
            tracing::error!(
                repo = %self.repo.name,
                "batch cut short: its records can no longer be read as checked: {e}"
            );
            return Err(std::io::Error::other(e.to_string()));
        }
        not_stored(&mut out, &mut at);
        self.next = end;
        self.unsent -= out.len() as u64;
        // Counted as handed over, so the records of an aborted batch that were never written
        // are not counted as sent.
        if !records.is_empty() {
            self.state.metrics().add_records(records.len() as u64);
        }
        Ok(out)
    }
}

impl http_body::Body for BatchBody {
    type Data = Bytes;
    type Error = std::io::Error;

    fn poll_frame(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, Self::Error>>> {
        let me = self.get_mut();
        if me.finished() {
            return Poll::Ready(None);
        }
        let (end, size) = me.plan_chunk();
        let memory = &me.state.inner.answer_memory;
        let room = ready!(me.claim.poll_room(memory, me.conn.as_ref(), size, cx));
        Poll::Ready(Some(
            me.next_chunk(end, size).map(|c| Frame::data(room.fill(c))),
        ))
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
