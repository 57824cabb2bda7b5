//! The batch framing: many records in one response body, as `POST /v1/repos/{name}/diamonds`
//! answers (`docs/FORMAT.md`, "HTTP API"). Written by the server ([`BatchWriter`]) and read by
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
        // Spelled out from docs/FORMAT.md's table, independently of the writer.
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

    proptest! {
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
