//! The repository head: everything in a file but its records, validated once, with the
//! accessors readers use and the per-record check.

use super::validate::{
    parse_derived, parse_georef, parse_header, parse_index, parse_params, parse_placement,
    parse_record_checksums, parse_section_checksums,
};
use super::{Section, range_of};
use crate::CodecError;
use crate::colour::ColourDecoder;
use crate::geometry::DiamondId;
use crate::hierarchy::{CodecParams, Decoder, RepoKind};
use crate::quant::QuantPlan;
use crate::repository::GeoRef;
use crate::repository::header::{PlanetProvenance, SectionEntry, crc32};
use crate::repository::index::IndexEntry;

/// Everything in a repository but its records: header, root field, index and record checksums —
/// the first [`RepositoryHead::records_offset`] bytes of the file. A remote client fetches these
/// bytes once (one range request, see [`required_head_len`]) and then checks each record it
/// fetches with [`RepositoryHead::check_record`], exactly as [`Repository`] does with its map.
#[derive(Clone, Debug)]
pub struct RepositoryHead {
    pub(super) params: CodecParams,
    pub(super) plan: QuantPlan,
    pub(super) georef: Option<GeoRef>,
    pub(super) nodata: Option<f64>,
    pub(super) leaf_error: u32,
    pub(super) sections: [SectionEntry; 4],
    pub(super) entries: Vec<IndexEntry>,
    /// Per entry, its CRC-32 (0 and unused for empty records).
    pub(super) record_crcs: Vec<u32>,
    pub(super) roots: Vec<u8>,
    pub(super) file_len: u64,
    pub(super) header_crc: u32,
    pub(super) header_len: usize,
    pub(super) format_version: u16,
    pub(super) provenance: Option<PlanetProvenance>,
}

impl RepositoryHead {
    /// Validates a repository head: `b` holds at least the first [`required_head_len`] bytes of
    /// a file of `file_len` bytes (the whole file will do). Checks magic, version, header CRC,
    /// every header field, section placement against `file_len`, the CRCs of the root field,
    /// index and checksum table, and the index itself.
    ///
    /// One step per part of the file, in file order; each checks what it reads before the
    /// next one allocates anything sized by it.
    pub fn parse(b: &[u8], file_len: u64) -> Result<Self, CodecError> {
        let h = parse_header(b)?;
        let (params, plan) = parse_params(&h)?;
        let georef = parse_georef(&h)?;
        parse_derived(&h, &params.domain)?;
        let nodata = (!h.nodata.is_nan()).then_some(h.nodata);
        let sections = h.sections;
        parse_placement(&sections, h.header_len, b.len(), file_len)?;
        parse_section_checksums(b, &sections)?;
        let entries = parse_index(b, &h, &params.domain)?;
        let record_crcs = parse_record_checksums(b, &sections, &entries)?;
        Ok(Self {
            params,
            plan,
            georef,
            nodata,
            leaf_error: h.leaf_error,
            sections,
            entries,
            record_crcs,
            roots: b[range_of(&sections[0])].to_vec(),
            file_len,
            header_crc: h.crc,
            header_len: h.header_len,
            format_version: h.version,
            provenance: h.provenance,
        })
    }

    /// The format version of the file (1, 2 or 3; [`FORMAT_VERSION`] is the one this code
    /// writes).
    pub fn format_version(&self) -> u16 {
        self.format_version
    }

    /// Length of the file's header, bytes: 256 in versions 1 and 2, less in version 3. The
    /// root field starts right after it.
    pub fn header_len(&self) -> usize {
        self.header_len
    }

    /// The decoder's header fields.
    pub fn params(&self) -> &CodecParams {
        &self.params
    }

    /// How integer units map to metres, and the tolerance the repository was built for.
    pub fn plan(&self) -> &QuantPlan {
        &self.plan
    }

    /// Georeferencing of the data grid, when the input had one.
    pub fn georef(&self) -> Option<&GeoRef> {
        self.georef.as_ref()
    }

    /// The input's nodata value at build time, if any.
    pub fn nodata(&self) -> Option<f64> {
        self.nodata
    }

    /// A planet's provenance: vertical datum and resampling error (`None` for planes and for
    /// planets written without it).
    pub fn provenance(&self) -> Option<&PlanetProvenance> {
        self.provenance.as_ref()
    }

    /// Object-space error of the finest diamonds, units.
    pub fn leaf_error(&self) -> u32 {
        self.leaf_error
    }

    /// The index entries, in id order.
    pub fn entries(&self) -> &[IndexEntry] {
        &self.entries
    }

    /// Position in [`RepositoryHead::entries`] of diamond `id`, if stored.
    pub fn position(&self, id: DiamondId) -> Option<usize> {
        self.entries.binary_search_by(|e| e.id.cmp(&id)).ok()
    }

    /// Total file size, bytes.
    pub fn file_len(&self) -> u64 {
        self.file_len
    }

    /// Length of a section, bytes.
    pub fn section_len(&self, s: Section) -> u64 {
        self.sections[Section::ALL.iter().position(|&x| x == s).expect("listed")].length
    }

    /// Byte offset of the records area: the head is the file's bytes before it.
    pub fn records_offset(&self) -> u64 {
        self.sections[3].offset
    }

    /// Byte offset of a section from the start of the file.
    pub fn section_offset(&self, s: Section) -> u64 {
        self.sections[Section::ALL.iter().position(|&x| x == s).expect("listed")].offset
    }

    /// The header's CRC-32. The header holds the CRCs of every section (records area
    /// included), so this identifies the file's content: servers use it in cache validators.
    pub fn header_crc(&self) -> u32 {
        self.header_crc
    }

    /// The CRC-32 stored for the `i`-th record in id order, as the checksum table holds it
    /// (not recomputed); `None` for an empty record (it has no slot) or `i` out of range.
    pub fn record_checksum(&self, i: usize) -> Option<u32> {
        let e = self.entries.get(i)?;
        (e.length > 0).then(|| self.record_crcs[i])
    }

    /// Absolute byte range of record `i` in the file (for range requests).
    pub fn record_range(&self, i: usize) -> Option<std::ops::Range<u64>> {
        let e = self.entries.get(i)?;
        let start = self.sections[3].offset + e.offset;
        Some(start..start + u64::from(e.length))
    }

    /// The coded root field.
    pub fn root_bytes(&self) -> &[u8] {
        &self.roots
    }

    /// Checks that `bytes` are record `i`: its length and CRC-32.
    pub fn check_record(&self, i: usize, bytes: &[u8]) -> Result<(), CodecError> {
        let e = self
            .entries
            .get(i)
            .ok_or_else(|| CodecError::invalid(format!("record {i} of {}", self.entries.len())))?;
        let id = e.id;
        if bytes.len() != e.length as usize {
            return Err(CodecError::corrupt(format!(
                "record {i} (diamond {id}) is {} bytes, the index says {}",
                bytes.len(),
                e.length
            )));
        }
        if !bytes.is_empty() && crc32(bytes) != self.record_crcs[i] {
            return Err(CodecError::corrupt(format!(
                "checksum mismatch in record {i} (diamond level {} at {}, {})",
                id.level, id.x, id.y
            )));
        }
        Ok(())
    }

    /// A decoder over the root field (elevation repositories).
    pub fn decoder(&self) -> Result<Decoder, CodecError> {
        Decoder::new(self.params, &self.roots)
    }

    /// What the repository holds.
    pub fn kind(&self) -> RepoKind {
        self.params.kind
    }

    /// The three-channel decoder over the root field (colour repositories).
    pub fn colour_decoder(&self) -> Result<ColourDecoder, CodecError> {
        ColourDecoder::new(self.params, &self.roots)
    }
}
