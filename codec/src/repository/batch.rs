//! The batch framing: many records in one response body, as `POST /v1/repos/{name}/diamonds`
//! answers (`docs/HTTP-API.md`). Written by the server ([`BatchWriter`]) and read by
//! the client ([`parse`]), so both ends share one definition of the wire format.
//!
//! All integers are little-endian:
//!
//! | Size | Content |
//! |---:|---|
//! | 4 | ASCII `CBDR` ([`MAGIC`]) |
//! | 4 | `u32` count: the number of ids requested |
//! | | then, for each requested id in request order: |
//! | 1 | `u8` status: [`STATUS_RECORD`] (the record follows) or [`STATUS_NOT_STORED`] |
//! | 4 | `u32` length: the record's length (0 for "not stored", and for an empty record) |
//! | length | the record's bytes |
//!
//! The body ends right after the last entry. The framing is a fixed contract: a new status value
//! or field needs a new content type ([`CONTENT_TYPE`]).

/// The first four bytes of a batch body.
pub const MAGIC: [u8; 4] = *b"CBDR";
/// `Content-Type` of a batch body.
pub const CONTENT_TYPE: &str = "application/x-cbdam-records";
/// Entry status: the record follows.
pub const STATUS_RECORD: u8 = 0;
/// Entry status: the diamond is not stored in this repository (length 0, no bytes).
pub const STATUS_NOT_STORED: u8 = 1;
/// Bytes before the first entry: magic and count.
pub const PREAMBLE_LEN: usize = 8;
/// Bytes of an entry before its record: status and length.
pub const ENTRY_HEAD_LEN: usize = 5;

/// One entry of a batch, borrowing the record's bytes from the body.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Entry<'a> {
    /// The record (possibly empty).
    Record(&'a [u8]),
    /// The diamond is not stored in the repository.
    NotStored,
}

/// Why a batch body does not parse.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum BatchError {
    /// The body does not start with [`MAGIC`].
    #[error("batch response does not start with CBDR")]
    BadMagic,
    /// The body ends before what its framing announces.
    #[error("batch response ends at byte {len}, its framing needs {needed}")]
    Truncated {
        /// The body's length.
        len: usize,
        /// The length the framing needs at least.
        needed: usize,
    },
    /// An entry's status is neither [`STATUS_RECORD`] nor [`STATUS_NOT_STORED`].
    #[error("unknown record status {status} in entry {entry}")]
    UnknownStatus {
        /// Entry number, from 0.
        entry: usize,
        /// The status byte.
        status: u8,
    },
    /// A "not stored" entry with a non-zero length.
    #[error("entry {entry} is \"not stored\" but has length {length}")]
    NotStoredWithBytes {
        /// Entry number, from 0.
        entry: usize,
        /// The length field.
        length: u32,
    },
    /// Bytes follow the last entry.
    #[error("{0} bytes after the last record")]
    Trailing(usize),
}

/// Writes a batch body: the preamble at construction, then one call per entry, in order.
#[derive(Debug)]
pub struct BatchWriter {
    out: Vec<u8>,
    count: u32,
    written: u32,
}

impl BatchWriter {
    /// A body of `count` entries whose records total `record_bytes`: the buffer is sized exactly
    /// ([`body_len`]).
    pub fn new(count: u32, record_bytes: usize) -> Self {
        let mut out = Vec::with_capacity(body_len(count as usize, record_bytes));
        out.extend_from_slice(&MAGIC);
        out.extend_from_slice(&count.to_le_bytes());
        Self {
            out,
            count,
            written: 0,
        }
    }

    /// Appends an entry holding `record`.
    ///
    /// # Panics
    /// If the record is longer than `u32::MAX` bytes (repository records never are: their index
    /// lengths are `u32`).
    pub fn record(&mut self, record: &[u8]) {
        let len = u32::try_from(record.len()).expect("records are at most u32::MAX bytes");
        self.out.push(STATUS_RECORD);
        self.out.extend_from_slice(&len.to_le_bytes());
        self.out.extend_from_slice(record);
        self.written += 1;
    }

    /// Appends a "not stored" entry.
    pub fn not_stored(&mut self) {
        self.out.push(STATUS_NOT_STORED);
        self.out.extend_from_slice(&0u32.to_le_bytes());
        self.written += 1;
    }

    /// The body. Debug builds check that as many entries were written as announced.
    pub fn finish(self) -> Vec<u8> {
        debug_assert_eq!(
            self.written, self.count,
            "batch entries written vs announced"
        );
        self.out
    }
}

/// Length of a body of `count` entries whose records total `record_bytes`.
pub fn body_len(count: usize, record_bytes: usize) -> usize {
    PREAMBLE_LEN + ENTRY_HEAD_LEN * count + record_bytes
}

/// Parses a whole batch body into its entries, in order; the records borrow from `body`. Any
/// departure from the framing is an error; no input panics.
pub fn parse(body: &[u8]) -> Result<Vec<Entry<'_>>, BatchError> {
    let truncated = |needed: usize| BatchError::Truncated {
        len: body.len(),
        needed,
    };
    let take = |pos: &mut usize, n: usize| -> Result<&[u8], BatchError> {
        let end = pos.checked_add(n).ok_or(truncated(usize::MAX))?;
        let s = body.get(*pos..end).ok_or(truncated(end))?;
        *pos = end;
        Ok(s)
    };
    let u32_at = |pos: &mut usize| -> Result<u32, BatchError> {
        let b = take(pos, 4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    };
    let mut pos = 0;
    if take(&mut pos, 4).map_err(|_| BatchError::BadMagic)? != MAGIC {
        return Err(BatchError::BadMagic);
    }
    let count = u32_at(&mut pos)? as usize;
    // Every entry takes at least its head: a count the body cannot hold fails before any
    // allocation is sized by it.
    let needed = body_len(count, 0);
    if body.len() < needed {
        return Err(truncated(needed));
    }
    let mut entries = Vec::with_capacity(count);
    for entry in 0..count {
        let status = take(&mut pos, 1)?[0];
        let length = u32_at(&mut pos)?;
        match status {
            STATUS_RECORD => entries.push(Entry::Record(take(&mut pos, length as usize)?)),
            STATUS_NOT_STORED if length == 0 => entries.push(Entry::NotStored),
            STATUS_NOT_STORED => return Err(BatchError::NotStoredWithBytes { entry, length }),
            status => return Err(BatchError::UnknownStatus { entry, status }),
        }
    }
    if pos != body.len() {
        return Err(BatchError::Trailing(body.len() - pos));
    }
    Ok(entries)
}

/// The order a server answers a batch in when the request gives each id a priority: highest
/// first, ties (and NaNs, which sort lowest) in request order. Returns, for each answer
/// position, the index of the requested id it answers. Both ends compute it with this one
/// definition, so a client that sends its ids most urgent first gets them back in that order.
pub fn answer_order(priorities: &[f32]) -> Vec<usize> {
    let key = |p: f32| if p.is_nan() { f32::NEG_INFINITY } else { p };
    let mut order: Vec<usize> = (0..priorities.len()).collect();
    // A stable sort: equal priorities keep the request's order.
    order.sort_by(|&a, &b| key(priorities[b]).total_cmp(&key(priorities[a])));
    order
}

/// An entry that owns its record (from [`StreamParser`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum OwnedEntry {
    /// The record (possibly empty).
    Record(Vec<u8>),
    /// The diamond is not stored in the repository.
    NotStored,
}

/// Parses a batch body as it arrives, chunk by chunk, handing over each entry as soon as its
/// last byte is in: a streamed response's first records are usable before the rest arrive.
/// Accepts exactly the bodies [`parse`] accepts.
#[derive(Debug, Default)]
pub struct StreamParser {
    /// Bytes received and not yet parsed into entries.
    buf: Vec<u8>,
    /// Bytes received so far.
    received: usize,
    /// The announced count, once the preamble is in.
    count: Option<u32>,
    /// Entries handed over so far.
    parsed: u32,
}

impl StreamParser {
    /// A parser at the start of a body.
    pub fn new() -> Self {
        Self::default()
    }

    /// Entries handed over so far.
    pub fn entries_parsed(&self) -> usize {
        self.parsed as usize
    }

    /// Feeds the next bytes of the body; returns the entries they complete, in order.
    pub fn push(&mut self, chunk: &[u8]) -> Result<Vec<OwnedEntry>, BatchError> {
        self.received += chunk.len();
        self.buf.extend_from_slice(chunk);
        let mut pos = 0;
        if self.count.is_none() {
            if self.buf.len() < PREAMBLE_LEN {
                let n = self.buf.len().min(4);
                if self.buf[..n] != MAGIC[..n] {
                    return Err(BatchError::BadMagic);
                }
                return Ok(Vec::new());
            }
            if self.buf[..4] != MAGIC {
                return Err(BatchError::BadMagic);
            }
            self.count = Some(u32::from_le_bytes([
                self.buf[4],
                self.buf[5],
                self.buf[6],
                self.buf[7],
            ]));
            pos = PREAMBLE_LEN;
        }
        let count = self.count.expect("set above");
        let mut out = Vec::new();
        while self.parsed < count {
            let Some(head) = self.buf.get(pos..pos + ENTRY_HEAD_LEN) else {
                break;
            };
            let status = head[0];
            let length = u32::from_le_bytes([head[1], head[2], head[3], head[4]]);
            let entry = self.parsed as usize;
            match status {
                STATUS_RECORD => {
                    let start = pos + ENTRY_HEAD_LEN;
                    let Some(end) = start.checked_add(length as usize) else {
                        return Err(self.truncated(usize::MAX));
                    };
                    let Some(record) = self.buf.get(start..end) else {
                        break;
                    };
                    out.push(OwnedEntry::Record(record.to_vec()));
                    pos = end;
                }
                STATUS_NOT_STORED if length == 0 => {
                    out.push(OwnedEntry::NotStored);
                    pos += ENTRY_HEAD_LEN;
                }
                STATUS_NOT_STORED => return Err(BatchError::NotStoredWithBytes { entry, length }),
                status => return Err(BatchError::UnknownStatus { entry, status }),
            }
            self.parsed += 1;
        }
        self.buf.drain(..pos);
        if self.parsed == count && !self.buf.is_empty() {
            return Err(BatchError::Trailing(self.buf.len()));
        }
        Ok(out)
    }

    /// The body ended: an error unless every announced entry was complete.
    pub fn finish(&self) -> Result<(), BatchError> {
        match self.count {
            None if self.buf.len() < 4 || self.buf[..4] != MAGIC => Err(BatchError::BadMagic),
            None => Err(self.truncated(PREAMBLE_LEN)),
            Some(count) if self.parsed < count => {
                // At least the heads of the missing entries and whatever the current one
                // announced.
                let missing = (count - self.parsed) as usize;
                let current = match self.buf.get(..ENTRY_HEAD_LEN) {
                    Some(h) if h[0] == STATUS_RECORD => {
                        u32::from_le_bytes([h[1], h[2], h[3], h[4]]) as usize
                    }
                    _ => 0,
                };
                let needed = (self.received - self.buf.len())
                    .saturating_add(missing * ENTRY_HEAD_LEN)
                    .saturating_add(current);
                Err(self.truncated(needed))
            }
            Some(_) => Ok(()),
        }
    }

    fn truncated(&self, needed: usize) -> BatchError {
        BatchError::Truncated {
            len: self.received,
            needed,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn write(entries: &[Option<Vec<u8>>]) -> Vec<u8> {
        let bytes = entries.iter().flatten().map(Vec::len).sum();
        let mut w = BatchWriter::new(entries.len() as u32, bytes);
        for e in entries {
            match e {
                Some(r) => w.record(r),
                None => w.not_stored(),
            }
        }
        let body = w.finish();
        assert_eq!(body.len(), body_len(entries.len(), bytes));
        body
    }

    #[test]
    fn writes_the_documented_bytes() {
        // Spelled out from docs/HTTP-API.md's table, independently of the writer.
        let mut want = b"CBDR".to_vec();
        want.extend([3, 0, 0, 0]);
        want.extend([0, 3, 0, 0, 0, 7, 8, 9]);
        want.extend([1, 0, 0, 0, 0]);
        want.extend([0, 0, 0, 0, 0]);
        assert_eq!(write(&[Some(vec![7, 8, 9]), None, Some(vec![])]), want);
        assert_eq!(write(&[]), b"CBDR\0\0\0\0");
        assert_eq!(
            parse(&want).unwrap(),
            [
                Entry::Record(&[7, 8, 9]),
                Entry::NotStored,
                Entry::Record(&[])
            ]
        );
    }

    #[test]
    fn bad_bodies_are_typed_errors() {
        let body = write(&[Some(vec![1, 2]), None]);
        assert_eq!(parse(b"CBD"), Err(BatchError::BadMagic));
        assert_eq!(parse(b"XBDR\0\0\0\0"), Err(BatchError::BadMagic));
        let mut trailing = body.clone();
        trailing.push(0);
        assert_eq!(parse(&trailing), Err(BatchError::Trailing(1)));
        let mut status = body.clone();
        status[8] = 2;
        assert_eq!(
            parse(&status),
            Err(BatchError::UnknownStatus {
                entry: 0,
                status: 2
            })
        );
        let mut not_stored = write(&[None]);
        not_stored[9] = 1;
        not_stored.push(0);
        assert_eq!(
            parse(&not_stored),
            Err(BatchError::NotStoredWithBytes {
                entry: 0,
                length: 1
            })
        );
        // A count no body could hold is refused before anything is sized by it.
        let huge = [b'C', b'B', b'D', b'R', 255, 255, 255, 255];
        assert!(matches!(parse(&huge), Err(BatchError::Truncated { .. })));
        for cut in 0..body.len() {
            assert!(parse(&body[..cut]).is_err(), "cut at {cut}");
        }
    }

    /// Feeds `body` to a [`StreamParser`] in chunks of `chunk` bytes.
    fn stream(body: &[u8], chunk: usize) -> Result<Vec<OwnedEntry>, BatchError> {
        let mut p = StreamParser::new();
        let mut out = Vec::new();
        for c in body.chunks(chunk.max(1)) {
            out.extend(p.push(c)?);
        }
        p.finish()?;
        Ok(out)
    }

    #[test]
    fn answer_order_is_by_priority_then_request_order() {
        assert_eq!(answer_order(&[]), Vec::<usize>::new());
        assert_eq!(answer_order(&[1.0, 3.0, 2.0, 3.0]), vec![1, 3, 2, 0]);
        assert_eq!(answer_order(&[f32::NAN, -1.0, 0.5]), vec![2, 1, 0]);
        // Already sorted (what the client sends): unchanged.
        assert_eq!(answer_order(&[9.0, 9.0, 4.0, 0.0]), vec![0, 1, 2, 3]);
    }

    #[test]
    fn the_stream_parser_hands_over_entries_as_their_last_byte_arrives() {
        let body = write(&[Some(vec![1, 2, 3]), None, Some(vec![4])]);
        let mut p = StreamParser::new();
        // Preamble and the first entry's head and two of its bytes: nothing complete yet.
        assert_eq!(p.push(&body[..15]).unwrap(), vec![]);
        // Its last byte, and the whole "not stored" entry.
        assert_eq!(
            p.push(&body[15..21]).unwrap(),
            vec![OwnedEntry::Record(vec![1, 2, 3]), OwnedEntry::NotStored]
        );
        assert_eq!(p.entries_parsed(), 2);
        assert!(p.finish().is_err(), "one entry is missing");
        assert_eq!(
            p.push(&body[21..]).unwrap(),
            vec![OwnedEntry::Record(vec![4])]
        );
        p.finish().unwrap();
        assert_eq!(stream(b"XB", 1), Err(BatchError::BadMagic));
        assert_eq!(stream(b"CB", 1), Err(BatchError::BadMagic));
        let mut trailing = body.clone();
        trailing.push(0);
        assert_eq!(stream(&trailing, 4), Err(BatchError::Trailing(1)));
    }

    proptest! {
        #[test]
        fn streamed_parsing_matches_whole_parsing(
            mut bytes in prop::collection::vec(any::<u8>(), 0..200),
            magic: bool,
            chunk in 1usize..40,
        ) {
            if magic && bytes.len() >= 8 {
                bytes[..4].copy_from_slice(&MAGIC);
                let count = u32::from(bytes[4] % 4);
                bytes[4..8].copy_from_slice(&count.to_le_bytes());
            }
            let whole = parse(&bytes).map(|entries| {
                entries
                    .iter()
                    .map(|e| match e {
                        Entry::Record(r) => OwnedEntry::Record(r.to_vec()),
                        Entry::NotStored => OwnedEntry::NotStored,
                    })
                    .collect::<Vec<_>>()
            });
            let streamed = stream(&bytes, chunk);
            prop_assert_eq!(whole.is_ok(), streamed.is_ok(), "{:?} vs {:?}", whole, streamed);
            if let (Ok(w), Ok(s)) = (whole, streamed) {
                prop_assert_eq!(w, s);
            }
        }

        #[test]
        fn written_bodies_stream_back_in_any_chunks(entries in prop::collection::vec(
            prop::option::of(prop::collection::vec(any::<u8>(), 0..40)), 0..20),
            chunk in 1usize..64,
        ) {
            let body = write(&entries);
            let want: Vec<OwnedEntry> = entries
                .iter()
                .map(|e| e.clone().map_or(OwnedEntry::NotStored, OwnedEntry::Record))
                .collect();
            prop_assert_eq!(stream(&body, chunk).unwrap(), want);
            for cut in 0..body.len() {
                prop_assert!(stream(&body[..cut], chunk).is_err());
            }
        }

        #[test]
        fn round_trips(entries in prop::collection::vec(
            prop::option::of(prop::collection::vec(any::<u8>(), 0..40)), 0..20)
        ) {
            let body = write(&entries);
            let parsed = parse(&body).unwrap();
            prop_assert_eq!(parsed.len(), entries.len());
            for (p, e) in parsed.iter().zip(&entries) {
                match (p, e) {
                    (Entry::Record(r), Some(e)) => prop_assert_eq!(*r, e.as_slice()),
                    (Entry::NotStored, None) => {}
                    _ => prop_assert!(false, "{:?} vs {:?}", p, e),
                }
            }
            // Every strict prefix is refused.
            for cut in 0..body.len() {
                prop_assert!(parse(&body[..cut]).is_err());
            }
        }

        #[test]
        fn never_panics(mut bytes in prop::collection::vec(any::<u8>(), 0..200), magic: bool) {
            // Half the cases get the magic and a small count, so that entries get parsed.
            if magic && bytes.len() >= 8 {
                bytes[..4].copy_from_slice(&MAGIC);
                let count = u32::from(bytes[4] % 4);
                bytes[4..8].copy_from_slice(&count.to_le_bytes());
            }
            if let Ok(entries) = parse(&bytes) {
                // What parses is exactly what the writer would write back.
                let owned: Vec<Option<Vec<u8>>> = entries
                    .iter()
                    .map(|e| match e {
                        Entry::Record(r) => Some(r.to_vec()),
                        Entry::NotStored => None,
                    })
                    .collect();
                prop_assert_eq!(write(&owned), bytes);
            }
        }
    }
}
