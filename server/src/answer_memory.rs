//! The cap on answer bytes the server holds at once, over all connections
//! (`Config::answer_memory`, `--answer-memory`).
//!
//! A streamed answer (a batch, a file range) is made a chunk at a time, as the connection asks
//! for one; a chunk is held until it is written to the socket. A client that does not read its
//! answer therefore holds one chunk, and a flood of such clients holds one chunk each: bounded
//! per connection, but not in all. Here every chunk first takes room for its bytes from one
//! budget shared by the whole server, and gives it back when it is dropped (written, or its
//! connection closed). When there is no room, the body waits for some, and the connection that
//! has held answer bytes without moving a byte the longest — a client that stopped reading — is
//! closed to make room, once it has been stalled for [`STALLED`]. Clients that read their
//! answers hold their chunks for microseconds and are never closed for memory.

use std::future::Future;
use std::pin::Pin;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll, Waker};
use std::time::Duration;

use bytes::Bytes;
use tokio::time::{Instant, Sleep};

use crate::conn::ConnHandle;

/// A connection holding answer bytes that has moved no byte for this long is one that stopped
/// reading: it may be closed to make room for others.
pub(crate) const STALLED: Duration = Duration::from_secs(1);

/// How often a body waiting for room looks again for a stalled connection to close.
const RETRY: Duration = Duration::from_millis(100);

/// The server-wide budget of answer bytes held.
#[derive(Debug)]
pub(crate) struct AnswerMemory {
    limit: u64,
    state: Mutex<Budget>,
    /// Connections closed to make room.
    closed: AtomicU64,
}

/// The room left and the bodies waiting for some.
#[derive(Debug, Default)]
struct Budget {
    free: u64,
    next_ticket: u64,
    /// Newest last. Room given back wakes the newest first: under a flood of answers nobody
    /// reads, the bodies waiting longest are the flood's own, and a request that comes later
    /// (a client that reads) should not queue behind them.
    waiting: Vec<(u64, Waker)>,
}

impl Budget {
    /// Takes `ticket` out of the queue; the body that is then the newest is woken to take over
    /// looking for stalled connections.
    fn remove(&mut self, ticket: u64) {
        let was_newest = self.waiting.last().is_some_and(|(w, _)| *w == ticket);
        self.waiting.retain(|(w, _)| *w != ticket);
        if was_newest && let Some((_, w)) = self.waiting.last() {
            w.wake_by_ref();
        }
    }
}

impl AnswerMemory {
    /// A budget of `limit` bytes (at least one).
    pub(crate) fn new(limit: u64) -> Self {
        let limit = limit.max(1);
        Self {
            limit,
            state: Mutex::new(Budget {
                free: limit,
                ..Budget::default()
            }),
            closed: AtomicU64::new(0),
        }
    }

    /// Bytes held by chunks not yet written.
    pub(crate) fn held(&self) -> u64 {
        self.limit - self.state.lock().expect("not poisoned").free
    }

    /// Connections closed so far to make room.
    pub(crate) fn closed(&self) -> u64 {
        self.closed.load(Relaxed)
    }

    /// Takes `n` bytes when there are, else queues `ticket` (a new one when `None`) to be woken
    /// through `waker` when room is given back.
    fn take(&self, n: u64, ticket: &mut Option<u64>, waker: &Waker) -> bool {
        let mut b = self.state.lock().expect("not poisoned");
        if b.free >= n {
            b.free -= n;
            if let Some(t) = ticket.take() {
                b.remove(t);
            }
            return true;
        }
        match *ticket {
            Some(t) => {
                if let Some(w) = b.waiting.iter_mut().find(|(w, _)| *w == t) {
                    w.1.clone_from(waker);
                }
            }
            None => {
                let t = b.next_ticket;
                b.next_ticket += 1;
                b.waiting.push((t, waker.clone()));
                *ticket = Some(t);
            }
        }
        false
    }

    /// Gives `n` bytes back and wakes the newest waiting body. (One that still finds too little
    /// room, or one not woken, looks again within [`RETRY`].)
    fn give_back(&self, n: u64) {
        let mut b = self.state.lock().expect("not poisoned");
        b.free += n;
        if let Some((_, w)) = b.waiting.last() {
            w.wake_by_ref();
        }
    }

    /// Forgets a waiting body that went away.
    fn leave(&self, ticket: u64) {
        self.state.lock().expect("not poisoned").remove(ticket);
    }

    /// Whether `ticket` is the newest waiting body's: the one that looks for a stalled
    /// connection to close (one timer for the whole queue, not one per waiting body).
    fn is_newest(&self, ticket: u64) -> bool {
        let b = self.state.lock().expect("not poisoned");
        b.waiting.last().is_some_and(|(w, _)| *w == ticket)
    }

    /// The Prometheus lines of the budget.
    pub(crate) fn render(&self) -> String {
        format!(
            "# HELP cbdam_answer_bytes_held Bytes of answers made and not yet written, all connections.\n\
             # TYPE cbdam_answer_bytes_held gauge\n\
             cbdam_answer_bytes_held {}\n\
             # HELP cbdam_answer_bytes_limit The cap on cbdam_answer_bytes_held (--answer-memory).\n\
             # TYPE cbdam_answer_bytes_limit gauge\n\
             cbdam_answer_bytes_limit {}\n\
             # HELP cbdam_connections_closed_for_memory_total Stalled connections closed to make room for answers.\n\
             # TYPE cbdam_connections_closed_for_memory_total counter\n\
             cbdam_connections_closed_for_memory_total {}\n",
            self.held(),
            self.limit,
            self.closed()
        )
    }
}

/// One body's way to the budget: polled for room before each chunk is made.
#[derive(Default)]
pub(crate) struct Claim {
    waiting: Option<Waiting>,
}

/// A body waiting for room.
struct Waiting {
    memory: Arc<AnswerMemory>,
    /// Its place in the budget's queue.
    ticket: Option<u64>,
    /// When it next looks for a stalled connection to close (while it is the newest).
    retry: Pin<Box<Sleep>>,
}

/// Room for one chunk, taken from the budget; given back when the chunk made with
/// [`Room::fill`] is dropped.
pub(crate) struct Room {
    memory: Arc<AnswerMemory>,
    bytes: u64,
    conn: Option<ConnHandle>,
}

impl Claim {
    /// Ready with room for `bytes` (the whole budget at most); pending, with the task woken
    /// later, while others hold the budget. While it is the newest body waiting, the connection
    /// that has held answer bytes without moving a byte the longest (at least [`STALLED`]) is
    /// closed, every [`RETRY`].
    pub(crate) fn poll_room(
        &mut self,
        memory: &Arc<AnswerMemory>,
        conn: Option<&ConnHandle>,
        bytes: usize,
        cx: &mut Context<'_>,
    ) -> Poll<Room> {
        let n = (bytes as u64).clamp(1, memory.limit);
        let room = || Room {
            memory: Arc::clone(memory),
            bytes: n,
            conn: conn.cloned(),
        };
        if self.waiting.is_none() {
            let mut ticket = None;
            if memory.take(n, &mut ticket, cx.waker()) {
                return Poll::Ready(room());
            }
            self.waiting = Some(Waiting {
                memory: Arc::clone(memory),
                ticket,
                // Due at once: the first wait looks for a stalled connection straight away.
                retry: Box::pin(tokio::time::sleep(Duration::ZERO)),
            });
        }
        let w = self.waiting.as_mut().expect("set above");
        loop {
            if memory.take(n, &mut w.ticket, cx.waker()) {
                self.waiting = None;
                return Poll::Ready(room());
            }
            // Only the newest waits on a timer; the others are woken as room comes back.
            let newest = w.ticket.is_some_and(|t| memory.is_newest(t));
            if !newest || w.retry.as_mut().poll(cx).is_pending() {
                return Poll::Pending;
            }
            w.retry.as_mut().reset(Instant::now() + RETRY);
            if let Some(c) = conn
                && c.close_most_stalled_holder(STALLED)
            {
                memory.closed.fetch_add(1, Relaxed);
            }
        }
    }
}

impl Drop for Claim {
    fn drop(&mut self) {
        if let Some(Waiting {
            memory,
            ticket: Some(ticket),
            ..
        }) = &self.waiting
        {
            memory.leave(*ticket);
        }
    }
}

impl Room {
    /// The chunk `bytes`, holding this room until it is dropped. Its connection counts the
    /// bytes as held meanwhile.
    pub(crate) fn fill(self, bytes: Vec<u8>) -> Bytes {
        let len = bytes.len() as u64;
        if let Some(c) = &self.conn {
            c.hold(len);
        }
        Bytes::from_owner(HeldChunk {
            bytes,
            room: self,
            len,
        })
    }
}

/// A chunk's bytes and the room they take.
struct HeldChunk {
    bytes: Vec<u8>,
    room: Room,
    len: u64,
}

impl AsRef<[u8]> for HeldChunk {
    fn as_ref(&self) -> &[u8] {
        &self.bytes
    }
}

impl Drop for HeldChunk {
    fn drop(&mut self) {
        if let Some(c) = &self.room.conn {
            c.release(self.len);
        }
    }
}

impl Drop for Room {
    fn drop(&mut self) {
        self.memory.give_back(self.bytes);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn room_is_given_back_when_the_chunk_is_dropped() {
        let memory = Arc::new(AnswerMemory::new(100));
        let mut cx = Context::from_waker(std::task::Waker::noop());
        let Poll::Ready(room) = Claim::default().poll_room(&memory, None, 80, &mut cx) else {
            panic!("room for 80 of 100 bytes")
        };
        let chunk = room.fill(vec![7; 80]);
        assert_eq!(memory.held(), 80);
        let mut other = Claim::default();
        assert!(other.poll_room(&memory, None, 30, &mut cx).is_pending());
        drop(chunk);
        assert_eq!(memory.held(), 0);
        let Poll::Ready(room) = other.poll_room(&memory, None, 30, &mut cx) else {
            panic!("room once the chunk is dropped")
        };
        let chunk = room.fill(vec![1; 30]);
        assert_eq!(memory.held(), 30);
        drop(chunk);
        // More than the budget takes the whole budget, rather than waiting forever.
        let Poll::Ready(room) = Claim::default().poll_room(&memory, None, 1000, &mut cx) else {
            panic!("the whole budget for a chunk larger than it")
        };
        let chunk = room.fill(vec![1; 1000]);
        assert_eq!((chunk.len(), memory.held()), (1000, 100));
    }
}
