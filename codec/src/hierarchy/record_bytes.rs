//! The coded bytes of a record: in memory, or in a temporary file a large encode spilled them to.
//!
//! A build holds every record until it writes the repository, whose records are in id order
//! while a block encode finishes them block by block. For a large lattice that would be the
//! whole repository in memory (1.1 GB for 4.3 G samples) beside the encoder's fields, and
//! growing with the input. So the block encoder of a mapped lattice appends each finished
//! block's bytes to an unlinked temporary file ([`RecordSpill`]) and keeps only their place; once
//! every block is in, the file is mapped read-only and each record reads its bytes from the
//! mapping — the page cache's, paged in as the writer reads them.

use std::fmt;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::ops::Deref;
use std::sync::Arc;

use super::Record;
use super::field::TempStorage;
use crate::CodecError;

/// A record's coded bytes (see the module documentation). Reads as a byte slice either way.
#[derive(Clone, Default)]
pub struct RecordBytes(Repr);

#[derive(Clone)]
enum Repr {
    Owned(Vec<u8>),
    /// `len` bytes at `start` of a spill file's mapping.
    Spilled {
        map: Arc<memmap2::Mmap>,
        start: usize,
        len: usize,
    },
}

impl Default for Repr {
    fn default() -> Self {
        Repr::Owned(Vec::new())
    }
}

impl RecordBytes {
    /// Whether the bytes live in a spill file.
    pub fn is_spilled(&self) -> bool {
        matches!(self.0, Repr::Spilled { .. })
    }

    /// The bytes to change, copied into memory first if they were spilled.
    pub fn to_mut(&mut self) -> &mut Vec<u8> {
        if let Repr::Spilled { .. } = self.0 {
            self.0 = Repr::Owned(self.to_vec());
        }
        match &mut self.0 {
            Repr::Owned(v) => v,
            Repr::Spilled { .. } => unreachable!("copied into memory just above"),
        }
    }
}

impl Deref for RecordBytes {
    type Target = [u8];

    fn deref(&self) -> &[u8] {
        match &self.0 {
            Repr::Owned(v) => v,
            Repr::Spilled { map, start, len } => &map[*start..*start + *len],
        }
    }
}

impl From<Vec<u8>> for RecordBytes {
    fn from(v: Vec<u8>) -> Self {
        RecordBytes(Repr::Owned(v))
    }
}

/// Equal bytes, wherever they live.
impl PartialEq for RecordBytes {
    fn eq(&self, other: &Self) -> bool {
        self[..] == other[..]
    }
}

impl Eq for RecordBytes {}

impl fmt::Debug for RecordBytes {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        <[u8] as fmt::Debug>::fmt(self, f)
    }
}

/// The records an encode has finished, their bytes in memory or spilled ([`RecordSpill`]).
pub(crate) struct KeptRecords {
    records: Vec<Record>,
    spill: Option<(RecordSpill, Vec<(usize, usize)>)>,
}

impl KeptRecords {
    /// Keeps records in memory, or (`spill`) their bytes in a temporary file.
    pub(crate) fn new(spill: bool) -> Result<Self, CodecError> {
        let spill = match spill {
            true => RecordSpill::new(&TempStorage::File(None))?.map(|s| (s, Vec::new())),
            false => None,
        };
        Ok(Self {
            records: Vec::new(),
            spill,
        })
    }

    /// Keeps `records`.
    pub(crate) fn extend(&mut self, mut records: Vec<Record>) -> Result<(), CodecError> {
        if let Some((spill, spans)) = self.spill.as_mut() {
            spans.extend(spill.spill(&mut records)?);
        }
        self.records.extend(records);
        Ok(())
    }

    /// Every record kept, with its bytes.
    pub(crate) fn finish(self) -> Result<Vec<Record>, CodecError> {
        let mut records = self.records;
        if let Some((spill, spans)) = self.spill {
            spill.finish(&mut records, &spans)?;
        }
        Ok(records)
    }
}

/// Moves records' bytes to an unlinked temporary file as an encode finishes them, and back
/// (as mappings of it) when it is done (see the module documentation).
pub(crate) struct RecordSpill {
    file: BufWriter<File>,
    /// Bytes written so far.
    len: usize,
}

impl RecordSpill {
    /// A spill file in `storage`'s directory; `None` for [`TempStorage::Memory`] (nothing to
    /// spill to).
    pub(crate) fn new(storage: &TempStorage) -> Result<Option<Self>, CodecError> {
        let Some(file) = storage.unlinked_file("the records")? else {
            return Ok(None);
        };
        Ok(Some(Self {
            file: BufWriter::with_capacity(1 << 20, file),
            len: 0,
        }))
    }

    /// Appends the bytes of `records` to the file and empties them, returning where each one's
    /// bytes went (`(start, len)`, in order) for [`RecordSpill::finish`].
    pub(crate) fn spill(
        &mut self,
        records: &mut [Record],
    ) -> Result<Vec<(usize, usize)>, CodecError> {
        let mut spans = Vec::with_capacity(records.len());
        for r in records {
            spans.push((self.append(&r.bytes)?, r.bytes.len()));
            r.bytes = RecordBytes::default();
        }
        Ok(spans)
    }

    /// Appends `bytes` to the file: where they start.
    pub(crate) fn append(&mut self, bytes: &[u8]) -> Result<usize, CodecError> {
        self.file.write_all(bytes)?;
        let start = self.len;
        self.len += bytes.len();
        Ok(start)
    }

    /// Maps the file and gives each record of `records` its bytes at `spans[i]` back.
    pub(crate) fn finish(
        self,
        records: &mut [Record],
        spans: &[(usize, usize)],
    ) -> Result<(), CodecError> {
        debug_assert_eq!(records.len(), spans.len());
        let Some(map) = self.into_map()? else {
            return Ok(()); // nothing to map: every record is empty
        };
        for (r, &(start, len)) in records.iter_mut().zip(spans) {
            r.bytes = RecordBytes::spilled(&map, start, len);
        }
        Ok(())
    }

    /// The file mapped read-only, once nothing more is appended; `None` when nothing was (an
    /// empty file cannot be mapped).
    pub(crate) fn into_map(self) -> Result<Option<Arc<memmap2::Mmap>>, CodecError> {
        let file = self.file.into_inner().map_err(|e| e.into_error())?;
        if self.len == 0 {
            return Ok(None);
        }
        // SAFETY: the file is unlinked and private to this process, and nothing writes to it
        // any more (the writer was consumed above), so the mapping cannot change under us.
        Ok(Some(Arc::new(unsafe { memmap2::Mmap::map(&file)? })))
    }
}

impl RecordBytes {
    /// `len` bytes at `start` of a spill file's mapping ([`RecordSpill::into_map`]).
    pub(crate) fn spilled(map: &Arc<memmap2::Mmap>, start: usize, len: usize) -> Self {
        debug_assert!(start + len <= map.len());
        RecordBytes(Repr::Spilled {
            map: Arc::clone(map),
            start,
            len,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::DiamondId;

    fn record(i: u32, bytes: Vec<u8>) -> Record {
        Record {
            id: DiamondId::new(3, i, i),
            bytes: bytes.into(),
            object_error: i,
            min: -1,
            max: 1,
        }
    }

    #[test]
    fn spilled_records_read_back_the_same_bytes() {
        let want: Vec<Record> = (0..50)
            .map(|i| record(i, (0..i * 37 % 301).map(|b| (b * i) as u8).collect()))
            .collect();
        assert!(RecordSpill::new(&TempStorage::Memory).unwrap().is_none());
        let mut spill = RecordSpill::new(&TempStorage::File(None)).unwrap().unwrap();
        let mut got = want.clone();
        let mut spans = spill.spill(&mut got[..20]).unwrap();
        spans.extend(spill.spill(&mut got[20..]).unwrap());
        assert!(got.iter().all(|r| r.bytes.is_empty()));
        spill.finish(&mut got, &spans).unwrap();
        assert!(got.iter().all(|r| r.bytes.is_spilled()));
        assert_eq!(got, want);
        assert_eq!(
            format!("{:?}", got[3].bytes),
            format!("{:?}", &want[3].bytes[..])
        );
        // All records empty: nothing to map, and nothing spilled.
        let mut empty = vec![record(1, Vec::new())];
        let mut spill = RecordSpill::new(&TempStorage::File(None)).unwrap().unwrap();
        let spans = spill.spill(&mut empty).unwrap();
        spill.finish(&mut empty, &spans).unwrap();
        assert_eq!(empty, vec![record(1, Vec::new())]);
    }
}
