//! The body of a file (or range) answer from a repository opened from a file: read from the
//! file a chunk at a time as the connection takes them, so a large range held by a slow reader
//! costs one chunk (each chunk takes room in the server's answer memory first,
//! [`crate::answer_memory`]), and a file truncated underneath ends the answer with an error (the
//! connection is cut: the client sees a short body) instead of a fault.

use std::ops::Range;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll, ready};

use bytes::Bytes;
use http_body::{Frame, SizeHint};

use crate::answer_memory::{AnswerMemory, Claim};
use crate::conn::ConnHandle;
use crate::state::ServedRepo;

/// Bytes read per chunk.
const CHUNK_BYTES: u64 = 64 << 10;

pub(crate) struct FileBody {
    repo: Arc<ServedRepo>,
    /// What is left to send.
    range: Range<u64>,
    memory: Arc<AnswerMemory>,
    claim: Claim,
    /// The request's connection (absent when the router is called without [`crate::run`]).
    conn: Option<ConnHandle>,
}

impl FileBody {
    pub(crate) fn new(
        repo: Arc<ServedRepo>,
        range: Range<u64>,
        memory: Arc<AnswerMemory>,
        conn: Option<ConnHandle>,
    ) -> Self {
        Self {
            repo,
            range,
            memory,
            claim: Claim::default(),
            conn,
        }
    }
}

impl http_body::Body for FileBody {
    type Data = Bytes;
    type Error = std::io::Error;

    fn poll_frame(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, Self::Error>>> {
        let me = self.get_mut();
        if me.range.is_empty() {
            return Poll::Ready(None);
        }
        let end = me.range.end.min(me.range.start + CHUNK_BYTES);
        let room = ready!(me.claim.poll_room(
            &me.memory,
            me.conn.as_ref(),
            (end - me.range.start) as usize,
            cx
        ));
        let mut out = Vec::with_capacity((end - me.range.start) as usize);
        // A file rewritten in place may keep its length: its identity is checked after each
        // chunk is read, so a chunk read from a changed file is never sent.
        let read = me
            .repo
            .read_into(me.range.start..end, &mut out)
            .and_then(|()| me.repo.check_unchanged());
        Poll::Ready(Some(match read {
            Ok(()) => {
                me.range.start = end;
                Ok(Frame::data(room.fill(out)))
            }
            Err(e) => Err(std::io::Error::other(e.to_string())),
        }))
    }

    fn is_end_stream(&self) -> bool {
        self.range.is_empty()
    }

    fn size_hint(&self) -> SizeHint {
        SizeHint::with_exact(self.range.end - self.range.start)
    }
}
