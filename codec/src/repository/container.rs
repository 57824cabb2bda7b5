//! The single-file repository container (format version 3, reading 1 and 2 too;
//! `docs/FORMAT.md`).
//!
//! Version 1 coded the record index as varints, version 2 range-codes it ([`super::index::IndexCoding`]), and
//! version 3 replaces the fixed 256-byte header with a compact one (`header.rs`); on
//! smooth terrain the index and the header were most of what a file held.
//!
//! Layout: the header, then four sections in this order with no gaps — the coded root field,
//! the record index ([`super::index`]), a table of one CRC-32 per non-empty record in id order,
//! and the records area (record bytes concatenated in id order, so record offsets are the prefix
//! sums of the index's lengths). The file ends exactly where the records area ends.
//!
//! Why per-record checksums: the entropy decoders accept most byte strings, so a damaged record
//! would otherwise decode silently to wrong heights. A renderer that maps the file and touches
//! only the records it draws checks exactly those; [`Repository::open`] checks the header and the
//! small sections but does not scan the records area, so opening a large repository stays cheap.
//! [`Repository::check_all`] checks everything.
//!
//! Writing is `write.rs`, the head and its validation `head.rs` and `validate.rs`, and the hostile
//! writers of tests and fuzzers `craft.rs`; this file holds what they share and [`Repository`].

mod craft;
mod head;
#[cfg(test)]
mod tests;
mod validate;
mod write;

pub use craft::{CRAFTABLE_FIELDS, craft_header, reseal_checksums};
pub use head::RepositoryHead;
pub use validate::MAX_MAGNITUDE;
pub use write::{serialize, write_planet_repository, write_repository};

use std::fs::File;
use std::ops::Deref;
use std::path::Path;

pub use super::header::{
    FLAG_LEVEL_QUANTIZERS, FLAG_PLANET_PROVENANCE, FLAG_RMS_ERROR, PlanetProvenance, VerticalDatum,
};
use super::header::{SectionEntry, crc32, read_header, read_prefix};
use crate::CodecError;
use crate::geometry::DiamondId;
use crate::hierarchy::{Encoded, Record};

pub use super::header::{HEADER_FETCH_LEN, MAGIC, MAX_HEADER_LEN, header_len};
/// The format version this code writes and the newest it reads (it reads every older one).
pub const FORMAT_VERSION: u16 = 3;

/// Nodata policy 0: samples that were nodata in the input are unconstrained in the hierarchy
/// ("don't care") and must not be drawn. The only policy so far.
const NODATA_DONT_CARE: u8 = 0;
/// Header flag bit 0: the root field and every non-empty record begin with a nodata mask
/// (`docs/FORMAT.md`, "Nodata mask"). Clear when the input has no nodata inside the data
/// rectangle, so such repositories are byte for byte what they were before the mask existed,
/// and readers that predate it refuse the flag instead of drawing invented surface.
pub const FLAG_NODATA_MASK: u32 = 1;
/// Header flag bit 1: a colour repository ([`crate::colour`]): the root field and every
/// non-empty record hold three channels Y, Co, Cg (`docs/FORMAT.md`, "Colour repositories").
/// Elevation repositories leave it clear and are unchanged; readers that predate colour refuse
/// it ("unknown header flags") rather than draw chroma as heights.
pub const FLAG_COLOUR: u32 = 2;
/// Header flag bit 2: the domain is a cube-sphere (`Domain::cube_sphere(N, K)`: six faces of
/// one root each, numbered and oriented as `docs/PLANET.md` says, on the WGS84 ellipsoid through
/// the algebraic sigmoid cube warp, c = 0.87). Roots along x and y are 1, the data size is every
/// face's `(S + 1)²` points, and there is no planar georeferencing. Planar repositories leave it
/// clear and are unchanged; readers that predate it refuse it ("unknown header flags").
pub const FLAG_CUBE_SPHERE: u32 = 4;
/// Vertical unit 0: heights are metres.
const VERTICAL_METRES: u8 = 0;

/// The four sections, in file order.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Section {
    /// The coded root field.
    Roots,
    /// The record index.
    Index,
    /// One CRC-32 (little-endian u32) per non-empty record, in id order.
    Checksums,
    /// The records, concatenated in id order.
    Records,
}

impl Section {
    const ALL: [Section; 4] = [
        Section::Roots,
        Section::Index,
        Section::Checksums,
        Section::Records,
    ];

    fn name(self) -> &'static str {
        match self {
            Section::Roots => "root field",
            Section::Index => "record index",
            Section::Checksums => "record checksum table",
            Section::Records => "records area",
        }
    }
}

/// Byte range of a section in the file.
fn range_of(s: &SectionEntry) -> std::ops::Range<usize> {
    // Bounds were checked against the file length at open, so both fit in usize.
    s.offset as usize..(s.offset + s.length) as usize
}
/// The bytes behind a repository: a read-only file mapping, or an owned buffer.
#[derive(Debug)]
enum Backing {
    Map(memmap2::Mmap),
    Owned(Vec<u8>),
}

impl Deref for Backing {
    type Target = [u8];
    fn deref(&self) -> &[u8] {
        match self {
            Backing::Map(m) => m,
            Backing::Owned(v) => v,
        }
    }
}
/// An opened, validated repository: the head plus the mapped records.
#[derive(Debug)]
pub struct Repository {
    bytes: Backing,
    head: RepositoryHead,
}

/// How many bytes from the start of a repository file make up its head (everything before the
/// records area), read from the file's header: its first [`header_len`] bytes, which the first
/// [`HEADER_FETCH_LEN`] bytes almost always hold. Only the magic, header length and header
/// checksum are checked here;
/// [`RepositoryHead::parse`] validates the rest.
pub fn required_head_len(header: &[u8]) -> Result<u64, CodecError> {
    let (version, _) = read_prefix(header)?;
    if version == 0 || version > FORMAT_VERSION {
        return Err(CodecError::unsupported(format!(
            "repository format version {version} is not one this reader knows (1 … \
             {FORMAT_VERSION})"
        )));
    }
    let h = read_header(header)?;
    let records_offset = h.sections[3].offset;
    if records_offset < h.header_len as u64 {
        return Err(CodecError::corrupt(format!(
            "records area starts at byte {records_offset}, inside the header"
        )));
    }
    Ok(records_offset)
}
impl Repository {
    /// Maps and validates the repository at `path`: magic, version, header CRC, every header
    /// field, section bounds against the file length, the CRCs of the root field, index and
    /// checksum table, and the index itself. Record bytes are checked when read
    /// ([`Repository::record`]) or by [`Repository::check_all`].
    pub fn open(path: &Path) -> Result<Self, CodecError> {
        // A FIFO would block the open until a writer came; a device would map or read forever.
        crate::files::check_regular_file(path)?;
        let file = File::open(path)?;
        let len = file.metadata()?.len();
        if len < HEADER_FETCH_LEN as u64 {
            // Small files are read rather than mapped: mapping an empty file fails on some
            // platforms, and the error should name what is missing, not the mapping.
            let bytes = std::fs::read(path)?;
            return Self::from_bytes(bytes);
        }
        // SAFETY: the mapping is read-only. Like every memory-mapped reader we rely on nobody
        // truncating or rewriting the file while it is open; `write_repository` never does (it
        // renames a new file over the old one, leaving the mapped inode intact).
        let map = unsafe { memmap2::Mmap::map(&file)? };
        Self::parse(Backing::Map(map))
    }

    /// Validates a repository held in memory (see [`Repository::open`]).
    pub fn from_bytes(bytes: Vec<u8>) -> Result<Self, CodecError> {
        Self::parse(Backing::Owned(bytes))
    }

    fn parse(bytes: Backing) -> Result<Self, CodecError> {
        let head = RepositoryHead::parse(&bytes, bytes.len() as u64)?;
        Ok(Self { bytes, head })
    }

    /// Drops the pages of a mapped repository from this process's resident set (they stay in
    /// the page cache, and reads fault them back): a pass over every record — `cbdam verify`'s —
    /// would otherwise end with the whole file resident. Nothing for a repository in memory,
    /// nor off Unix.
    pub fn release_pages(&self) {
        #[cfg(unix)]
        if let Backing::Map(map) = &self.bytes {
            // SAFETY: the mapping is read-only: MADV_DONTNEED only unmaps its pages, and later
            // reads fault the same file contents back, so no byte the program can see changes.
            let _ = unsafe { map.unchecked_advise(memmap2::UncheckedAdvice::DontNeed) };
        }
    }

    /// The header, root field, index and checksums.
    pub fn head(&self) -> &RepositoryHead {
        &self.head
    }

    /// The whole file, as validated by [`Repository::open`] (the records area unchecked). For
    /// serving the file verbatim, e.g. to HTTP range requests.
    pub fn as_bytes(&self) -> &[u8] {
        &self.bytes
    }

    /// The bytes of the `i`-th record in id order, checked against its CRC.
    pub fn record_at(&self, i: usize) -> Result<&[u8], CodecError> {
        let range = self.head.record_range(i).ok_or_else(|| {
            CodecError::invalid(format!("record {i} of {}", self.head.entries.len()))
        })?;
        // Offsets and lengths were checked by `decode_index` to add up to the records area.
        let bytes = &self.bytes[range.start as usize..range.end as usize];
        self.head.check_record(i, bytes)?;
        Ok(bytes)
    }

    /// The record of diamond `id`, checked against its CRC.
    pub fn record(&self, id: DiamondId) -> Result<&[u8], CodecError> {
        let i = self.head.position(id).ok_or_else(|| {
            CodecError::invalid(format!(
                "diamond level {} at {}, {} is not stored",
                id.level, id.x, id.y
            ))
        })?;
        self.record_at(i)
    }

    /// Checks the records area's CRC and every record's.
    pub fn check_all(&self) -> Result<(), CodecError> {
        for i in 0..self.head.entries.len() {
            self.record_at(i)?;
        }
        // Per-record CRCs cover every byte of the area (the records tile it), so this only adds
        // a check of the table against the area as a whole.
        let records = self.head.sections[3];
        if crc32(&self.bytes[range_of(&records)]) != records.crc {
            return Err(CodecError::corrupt("records area checksum mismatch"));
        }
        Ok(())
    }

    /// The whole hierarchy in memory (for [`crate::hierarchy::verify`]); checks every record.
    /// Records' height ranges are the index's (bounds in version-2 files, see
    /// [`IndexEntry::min`]); serialising the result again gives the same file.
    pub fn to_encoded(&self) -> Result<Encoded, CodecError> {
        let records = self
            .head
            .entries
            .iter()
            .enumerate()
            .map(|(i, e)| {
                Ok(Record {
                    id: e.id,
                    bytes: self.record_at(i)?.to_vec().into(),
                    object_error: e.object_error,
                    min: e.min,
                    max: e.max,
                })
            })
            .collect::<Result<Vec<_>, CodecError>>()?;
        Ok(Encoded {
            params: self.head.params,
            roots: self.head().root_bytes().to_vec(),
            records,
            leaf_error: self.head.leaf_error,
        })
    }
}
