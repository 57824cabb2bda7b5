//! The single-file repository container (format version 3, reading 1 and 2 too;
//! `docs/FORMAT.md`).
//!
//! Version 1 coded the record index as varints, version 2 range-codes it ([`IndexCoding`]), and
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

use std::fs::File;
use std::io::Write;
use std::ops::Deref;
use std::path::Path;

pub use super::header::{FLAG_PLANET_PROVENANCE, FLAG_RMS_ERROR, PlanetProvenance, VerticalDatum};
use super::header::{
    HeaderFields, SectionEntry, crc32, read_header, read_prefix, reseal_header, u32_at,
    write_compact,
};
use super::index::{IndexCoding, IndexEntry, decode_index, encode_index, range_shift_for};
use crate::CodecError;
use crate::atomic::write_atomically;
use crate::colour::{ColourDecoder, ycocg};
use crate::entropy::CoderKind;
use crate::geometry::{DataRect, DiamondId, Domain, DomainKind, Layout};
use crate::hierarchy::{CodecParams, Decoder, Encoded, Record, RepoKind, root_quantizer};
use crate::lifting::{Alpha, MAX_ABS_HEIGHT};
use crate::quant::{QuantPlan, Quantizer, RmsBound};
use crate::repository::GeoRef;

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

/// Serialises `encoded` as a repository file image. `nodata` is the input's effective nodata
/// value (recorded so that `verify` can re-read the input the same way).
pub fn serialize(
    encoded: &Encoded,
    plan: &QuantPlan,
    georef: Option<&GeoRef>,
    nodata: Option<f64>,
) -> Result<Vec<u8>, CodecError> {
    serialize_with(encoded, plan, georef, nodata, None)
}

/// [`serialize`] with a planet's provenance in the header (flag bit 3; cube-sphere only).
fn serialize_with(
    encoded: &Encoded,
    plan: &QuantPlan,
    georef: Option<&GeoRef>,
    nodata: Option<f64>,
    provenance: Option<&PlanetProvenance>,
) -> Result<Vec<u8>, CodecError> {
    let mut out = Vec::new();
    let total = serialize_to(&mut out, encoded, plan, georef, nodata, provenance)?;
    debug_assert_eq!(out.len() as u64, total);
    Ok(out)
}

/// Writes the file image of [`serialize_with`] to `out`, section by section (a large
/// repository's records are not copied into one buffer first); returns its length.
fn serialize_to(
    out: &mut dyn Write,
    encoded: &Encoded,
    plan: &QuantPlan,
    georef: Option<&GeoRef>,
    nodata: Option<f64>,
    provenance: Option<&PlanetProvenance>,
) -> Result<u64, CodecError> {
    let p = &encoded.params;
    if p.quantizer != plan.quantizer {
        return Err(CodecError::invalid(
            "the quantization plan does not match the encoded hierarchy's quantizer",
        ));
    }
    let entries = encoded.index_entries();
    let index = encode_index(&p.domain, &entries, range_shift_for(p.quantizer));
    // Empty records (all residuals zero) get no checksum: their length of 0 is already covered
    // by the index's CRC, and smooth terrain has many (all 69 of lidar1m_mn's at 5 m).
    let checksums: Vec<u8> = encoded
        .records
        .iter()
        .filter(|r| !r.bytes.is_empty())
        .flat_map(|r| crc32(&r.bytes).to_le_bytes())
        .collect();
    let n = u16::try_from(p.layout().n()).map_err(|_| CodecError::limit("diamond size"))?;
    let k = u8::try_from(p.layout().k()).map_err(|_| CodecError::limit("level pairs"))?;
    let flags = header_flags(encoded, plan, georef.is_some(), provenance.is_some())?;
    let fields = HeaderFields {
        version: FORMAT_VERSION,
        header_len: 0,
        flags,
        n: u32::from(n),
        level_pairs: k,
        alpha: p.alpha.to_byte(),
        coder: p.coder.to_byte(),
        lattice: u8::from(plan.lattice),
        geo_flags: georef.map_or(0, |g| 1 | (u8::from(g.pixel_is_area) << 1)),
        nodata_policy: NODATA_DONT_CARE,
        vertical_unit: VERTICAL_METRES,
        roots_x: p.layout().roots_x(),
        roots_y: p.layout().roots_y(),
        data_width: p.domain.data().width,
        data_height: p.domain.data().height,
        quantizer_k: p.quantizer.k() as u32,
        root_k: None,
        leaf_error: encoded.leaf_error,
        epsg: georef.and_then(|g| g.epsg).unwrap_or(0),
        unit: plan.unit,
        offset: plan.offset,
        epsilon: plan.epsilon,
        representation_error: plan.representation_error,
        geo: georef.map_or([0.0; 4], |g| [g.origin_x, g.origin_y, g.pixel_x, g.pixel_y]),
        nodata: nodata.unwrap_or(f64::NAN),
        wkt: georef.and_then(|g| g.wkt.clone()),
        provenance: provenance.copied(),
        rms: plan.rms.map(|r| (r.target, r.measured)),
        sections: section_entries(encoded, &index, &checksums),
        record_count: encoded.records.len() as u64,
        crc: 0,
    };
    // What a reader would refuse is not written: the same check, blamed on the caller.
    parse_derived(&fields, &p.domain).map_err(|e| match e {
        CodecError::Corrupt(m) => CodecError::InvalidParameter(m),
        e => e,
    })?;
    let h = write_compact(&fields)?;
    let offset = h.len() as u64 + fields.sections.iter().map(|s| s.length).sum::<u64>();

    out.write_all(&h)?;
    out.write_all(&encoded.roots)?;
    out.write_all(&index)?;
    out.write_all(&checksums)?;
    for r in &encoded.records {
        out.write_all(&r.bytes)?;
    }
    Ok(offset)
}

/// The four sections' lengths and CRCs: roots, index, checksums, records (offsets are laid out
/// by the header writer).
fn section_entries(encoded: &Encoded, index: &[u8], checksums: &[u8]) -> [SectionEntry; 4] {
    let section = |bytes: &[u8]| SectionEntry {
        offset: 0,
        length: bytes.len() as u64,
        crc: crc32(bytes),
    };
    let mut records = crc32fast::Hasher::new();
    for r in &encoded.records {
        records.update(&r.bytes);
    }
    [
        section(&encoded.roots),
        section(index),
        section(checksums),
        SectionEntry {
            offset: 0,
            length: encoded.records.iter().map(|r| r.bytes.len() as u64).sum(),
            crc: records.finalize(),
        },
    ]
}

/// The header's flags for `encoded` under `plan`; errors for what a cube-sphere cannot hold
/// (planar georeferencing, colour) and for a provenance on a plane.
fn header_flags(
    encoded: &Encoded,
    plan: &QuantPlan,
    georeferenced: bool,
    provenance: bool,
) -> Result<u32, CodecError> {
    let p = &encoded.params;
    let cube_sphere = p.domain.kind() == DomainKind::CubeSphere;
    if cube_sphere && (georeferenced || p.kind == RepoKind::Colour) {
        return Err(CodecError::invalid(
            "a cube-sphere repository holds elevation placed by its own mapping: no planar \
             georeferencing, no colour",
        ));
    }
    if provenance && !cube_sphere {
        return Err(CodecError::invalid(
            "a planet's provenance belongs in a cube-sphere repository",
        ));
    }
    let flag = |on: bool, bit: u32| if on { bit } else { 0 };
    Ok(flag(p.nodata_mask, FLAG_NODATA_MASK)
        | flag(p.kind == RepoKind::Colour, FLAG_COLOUR)
        | flag(cube_sphere, FLAG_CUBE_SPHERE)
        | flag(provenance, FLAG_PLANET_PROVENANCE)
        | flag(plan.rms.is_some(), FLAG_RMS_ERROR))
}

/// Writes a repository to `path` atomically, streamed through a buffer.
fn write_streamed(
    path: &Path,
    encoded: &Encoded,
    plan: &QuantPlan,
    georef: Option<&GeoRef>,
    nodata: Option<f64>,
    provenance: Option<&PlanetProvenance>,
) -> Result<(), CodecError> {
    write_atomically(path, |f: &mut File| -> Result<(), CodecError> {
        let mut out = std::io::BufWriter::with_capacity(1 << 20, f);
        serialize_to(&mut out, encoded, plan, georef, nodata, provenance)?;
        out.flush()?;
        Ok(())
    })
}

/// Writes `encoded` to `path` atomically ([`crate::atomic::write_atomically`]): a reader never
/// sees a half-written repository and a failed write leaves nothing behind. Refuses a `path`
/// that is a directory.
pub fn write_repository(
    path: &Path,
    encoded: &Encoded,
    plan: &QuantPlan,
    georef: Option<&GeoRef>,
    nodata: Option<f64>,
) -> Result<(), CodecError> {
    write_streamed(path, encoded, plan, georef, nodata, None)
}

/// Writes a planet repository with its provenance ([`PlanetProvenance`]) atomically, as
/// [`write_repository`] does.
pub fn write_planet_repository(
    path: &Path,
    encoded: &Encoded,
    plan: &QuantPlan,
    nodata: Option<f64>,
    provenance: &PlanetProvenance,
) -> Result<(), CodecError> {
    write_streamed(path, encoded, plan, None, nodata, Some(provenance))
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

/// Everything in a repository but its records: header, root field, index and record checksums —
/// the first [`RepositoryHead::records_offset`] bytes of the file. A remote client fetches these
/// bytes once (one range request, see [`required_head_len`]) and then checks each record it
/// fetches with [`RepositoryHead::check_record`], exactly as [`Repository`] does with its map.
#[derive(Clone, Debug)]
pub struct RepositoryHead {
    params: CodecParams,
    plan: QuantPlan,
    georef: Option<GeoRef>,
    nodata: Option<f64>,
    leaf_error: u32,
    sections: [SectionEntry; 4],
    entries: Vec<IndexEntry>,
    /// Per entry, its CRC-32 (0 and unused for empty records).
    record_crcs: Vec<u32>,
    roots: Vec<u8>,
    file_len: u64,
    header_crc: u32,
    header_len: usize,
    format_version: u16,
    provenance: Option<PlanetProvenance>,
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

/// The header step of [`RepositoryHead::parse`]: a version this reader knows, then the header's
/// bytes (magic, length, CRC, reserved bytes; [`read_header`]).
fn parse_header(b: &[u8]) -> Result<HeaderFields, CodecError> {
    let (version, _) = read_prefix(b)?;
    if version > FORMAT_VERSION {
        return Err(CodecError::unsupported(format!(
            "repository format version {version} is newer than this reader (version \
             {FORMAT_VERSION}); upgrade cbdam"
        )));
    }
    if version == 0 {
        return Err(CodecError::corrupt(
            "repository format version 0 does not exist",
        ));
    }
    read_header(b)
}

/// The decoder's parameters and the quantization plan from the header's fields: the flags,
/// the layout and the coding ([`parse_layout`]), then the quantizers and the plan
/// ([`parse_plan`]).
fn parse_params(h: &HeaderFields) -> Result<(CodecParams, QuantPlan), CodecError> {
    let (domain, alpha, coder, lattice) = parse_layout(h)?;
    let (plan, root_quantizer, kind) = parse_plan(h, lattice)?;
    let params = CodecParams {
        domain,
        alpha,
        coder,
        quantizer: plan.quantizer,
        root_quantizer,
        nodata_mask: h.flags & FLAG_NODATA_MASK != 0,
        kind,
    };
    Ok((params, plan))
}

/// Flags, layout, lifting weight, coder, lattice flag, georeferencing flags, nodata policy,
/// vertical unit and the data rectangle (which with the layout makes the domain), checked in
/// that order.
fn parse_layout(h: &HeaderFields) -> Result<(Domain, Alpha, CoderKind, bool), CodecError> {
    let flags = h.flags;
    let known =
        FLAG_NODATA_MASK | FLAG_COLOUR | FLAG_CUBE_SPHERE | FLAG_PLANET_PROVENANCE | FLAG_RMS_ERROR;
    if flags & !known != 0 {
        return Err(CodecError::unsupported(format!(
            "unknown header flags {flags:#x}"
        )));
    }
    if flags & FLAG_PLANET_PROVENANCE != 0 && flags & FLAG_CUBE_SPHERE == 0 {
        return Err(CodecError::corrupt(
            "a planet's provenance (flag bit 3) in a planar repository",
        ));
    }
    let n = usize::try_from(h.n).map_err(|_| CodecError::corrupt("diamond size too large"))?;
    let layout = Layout::new(n, u32::from(h.level_pairs), h.roots_x, h.roots_y)
        .map_err(|e| CodecError::corrupt(format!("header layout: {e}")))?;
    let alpha = Alpha::from_byte(h.alpha)
        .ok_or_else(|| CodecError::corrupt(format!("unknown lifting weight id {}", h.alpha)))?;
    let coder = CoderKind::from_byte(h.coder)?;
    let lattice = match h.lattice {
        0 => false,
        1 => true,
        v => {
            return Err(CodecError::corrupt(format!(
                "lattice flag {v} is not 0 or 1"
            )));
        }
    };
    let geo_flags = h.geo_flags;
    if geo_flags & !3 != 0 || geo_flags == 2 {
        return Err(CodecError::corrupt(format!(
            "invalid georeferencing flags {geo_flags:#x}"
        )));
    }
    if h.nodata_policy != NODATA_DONT_CARE {
        return Err(CodecError::unsupported(format!(
            "unknown nodata policy {}",
            h.nodata_policy
        )));
    }
    if h.vertical_unit != VERTICAL_METRES {
        return Err(CodecError::unsupported(format!(
            "unknown vertical unit {}",
            h.vertical_unit
        )));
    }
    let data = DataRect {
        width: h.data_width,
        height: h.data_height,
    };
    if flags & FLAG_CUBE_SPHERE != 0 {
        return cube_sphere_layout(h, data).map(|domain| (domain, alpha, coder, lattice));
    }
    // A header whose data rectangle does not fit its layout is corrupt, not a bad argument.
    let domain = Domain::planar(layout, data).map_err(|e| match e {
        CodecError::InvalidParameter(m) => CodecError::Corrupt(m),
        e => e,
    })?;
    Ok((domain, alpha, coder, lattice))
}

/// The domain of a header with [`FLAG_CUBE_SPHERE`]: one root per face, every face's points
/// holding data, no georeferencing, elevation only.
fn cube_sphere_layout(h: &HeaderFields, data: DataRect) -> Result<Domain, CodecError> {
    if h.flags & FLAG_COLOUR != 0 {
        return Err(CodecError::unsupported(
            "a colour cube-sphere repository (this reader knows elevation planets only)",
        ));
    }
    if (h.roots_x, h.roots_y) != (1, 1) {
        return Err(CodecError::corrupt(format!(
            "a cube-sphere has one root per face, not {}×{}",
            h.roots_x, h.roots_y
        )));
    }
    if h.geo_flags != 0 {
        return Err(CodecError::corrupt(
            "a cube-sphere repository has planar georeferencing",
        ));
    }
    let n = usize::try_from(h.n).map_err(|_| CodecError::corrupt("diamond size too large"))?;
    let domain = Domain::cube_sphere(n, u32::from(h.level_pairs))
        .map_err(|e| CodecError::corrupt(format!("header cube-sphere: {e}")))?;
    if domain.data() != data {
        let side = domain.data().width;
        return Err(CodecError::corrupt(format!(
            "a cube-sphere face of this N and K has {side}×{side} points, the header says {}×{}",
            data.width, data.height
        )));
    }
    Ok(domain)
}

/// The quantizers, the height unit and offset, the tolerance (by kind: colour repositories
/// have their own rules) and the representation error, checked in that order. Returns the
/// plan, the root quantizer and the kind.
fn parse_plan(
    h: &HeaderFields,
    lattice: bool,
) -> Result<(QuantPlan, Quantizer, RepoKind), CodecError> {
    let flags = h.flags;
    let quantizer = Quantizer::new(h.quantizer_k)
        .map_err(|e| CodecError::corrupt(format!("header quantizer: {e}")))?;
    let root_q = root_quantizer(quantizer);
    if let Some(root_k) = h.root_k
        && root_k != root_q.k() as u32
    {
        return Err(CodecError::unsupported(format!(
            "root quantizer k = {root_k}; this reader derives {} from k = {}",
            root_q.k(),
            quantizer.k()
        )));
    }
    let (unit, offset, epsilon, representation_error) =
        (h.unit, h.offset, h.epsilon, h.representation_error);
    if !(unit.is_finite() && unit > 0.0) {
        return Err(CodecError::corrupt(format!(
            "height unit {unit} is not positive"
        )));
    }
    if !offset.is_finite() {
        return Err(CodecError::corrupt("height offset is not finite"));
    }
    let kind = if flags & FLAG_COLOUR != 0 {
        RepoKind::Colour
    } else {
        RepoKind::Elevation
    };
    // A colour tolerance of 0 levels is lossless and meaningful; an elevation one is not.
    let eps_ok = match kind {
        RepoKind::Elevation => epsilon > 0.0,
        RepoKind::Colour => epsilon >= 0.0,
    };
    if !(epsilon.is_finite() && eps_ok) {
        return Err(CodecError::corrupt(format!(
            "tolerance {epsilon} is not positive"
        )));
    }
    if kind == RepoKind::Colour {
        check_colour_plan(h, lattice, quantizer)?;
    }
    if !(representation_error.is_finite() && representation_error >= 0.0) {
        return Err(CodecError::corrupt(
            "representation error is negative or not finite",
        ));
    }
    let plan = QuantPlan {
        unit,
        offset,
        quantizer,
        lattice,
        representation_error,
        epsilon,
        rms: h
            .rms
            .map(|(target, measured)| RmsBound { target, measured }),
    };
    if plan.rms.is_some() && kind == RepoKind::Colour {
        return Err(CodecError::corrupt(
            "an RMS error bound in a colour repository",
        ));
    }
    Ok((plan, root_q, kind))
}

/// A colour repository's plan: no nodata mask, unit 1, offset 0, lattice input, and a
/// quantizer whose RGB error is within the stated tolerance.
fn check_colour_plan(
    h: &HeaderFields,
    lattice: bool,
    quantizer: Quantizer,
) -> Result<(), CodecError> {
    if h.flags & FLAG_NODATA_MASK != 0 {
        return Err(CodecError::unsupported(
            "a colour repository with a nodata mask",
        ));
    }
    if h.unit != 1.0 || h.offset != 0.0 || !lattice || h.representation_error != 0.0 {
        return Err(CodecError::corrupt(
            "a colour repository must have unit 1, offset 0 and lattice input",
        ));
    }
    let bound = ycocg::rgb_bound(quantizer.k() as u32);
    if bound.iter().any(|&b| f64::from(b) > h.epsilon) {
        return Err(CodecError::corrupt(format!(
            "colour quantizer k = {} allows RGB errors of {bound:?}, over the stated tolerance \
             {}",
            quantizer.k(),
            h.epsilon
        )));
    }
    Ok(())
}

/// The georeferencing fields: finite where the flags say they are present, all zero where
/// they say there are none ([`parse_layout`] checked the flags themselves).
fn parse_georef(h: &HeaderFields) -> Result<Option<GeoRef>, CodecError> {
    let (geo_flags, epsg, geo) = (h.geo_flags, h.epsg, h.geo);
    if geo_flags & 1 == 1 {
        if geo.iter().any(|v| !v.is_finite()) {
            return Err(CodecError::corrupt("georeferencing values are not finite"));
        }
        Ok(Some(GeoRef {
            epsg: (epsg != 0).then_some(epsg),
            origin_x: geo[0],
            origin_y: geo[1],
            pixel_x: geo[2],
            pixel_y: geo[3],
            pixel_is_area: geo_flags & 2 == 2,
            wkt: h.wkt.clone(),
        }))
    } else {
        if epsg != 0 || geo.iter().any(|&v| v.to_bits() != 0) {
            return Err(CodecError::corrupt(
                "georeferencing fields are set but the header says there is none",
            ));
        }
        Ok(None)
    }
}

/// Largest magnitude of any height (metres) or georeferenced coordinate (CRS units) a
/// repository may describe. Far beyond any planet (the Earth's circumference is 4·10⁷ m, and a
/// degree 1.1·10⁵ m), yet small enough that what consumers compute from it — distances and
/// their squares, projection matrices, coordinates relative to an eye in `f32`, degrees turned
/// into metres — stays finite.
pub const MAX_MAGNITUDE: f64 = 1e15;

/// The derived-values step: each field is finite on its own ([`parse_plan`], [`parse_georef`]),
/// but what readers compute from them must be too. Every height a record can reconstruct
/// (`offset + unit·h` for `|h| ≤` [`MAX_ABS_HEIGHT`]), every georeferenced coordinate of the
/// lattice (`origin + pixel·i` for `i` from −1 to the lattice's extent) and a planet's
/// resampling errors must be finite and within [`MAX_MAGNITUDE`]; the representation error must
/// lie within its range (below half a unit and the tolerance for lattice input, 0 otherwise).
/// The errors name the field and its value. Writers run the same check, so nothing writes what
/// a reader refuses.
fn parse_derived(h: &HeaderFields, domain: &Domain) -> Result<(), CodecError> {
    let within = |v: f64| v.is_finite() && v.abs() <= MAX_MAGNITUDE;
    let reach = h.unit * f64::from(MAX_ABS_HEIGHT);
    let (low, high) = (h.offset - reach, h.offset + reach);
    if !(within(low) && within(high) && low <= high) {
        return Err(CodecError::corrupt(format!(
            "header height unit {:?} m with offset {:?} m: the heights it spans ({low:?} … \
             {high:?} m, offset ± unit · {MAX_ABS_HEIGHT}) are not finite and within \
             ±{MAX_MAGNITUDE:e} m",
            h.unit, h.offset
        )));
    }
    let repr = h.representation_error;
    let repr_ok = repr == 0.0 || (h.lattice == 1 && repr < h.unit / 2.0 && repr < h.epsilon);
    if !repr_ok {
        return Err(CodecError::corrupt(format!(
            "header representation error {repr:?} m is out of range for unit {:?} m and \
             tolerance {:?} m (lattice input: below half a unit and the tolerance; otherwise 0)",
            h.unit, h.epsilon
        )));
    }
    if h.geo_flags & 1 == 1 {
        let (ex, ey) = domain.layout().face_extent();
        let [ox, oy, px, py] = h.geo;
        for (axis, origin, pixel, extent) in [("x", ox, px, ex), ("y", oy, py, ey)] {
            // Pixel-is-point extents reach half a pixel before the origin; a whole one covers it.
            let (first, last) = (origin - pixel, origin + pixel * extent as f64);
            if !(within(origin) && within(first) && within(last)) {
                return Err(CodecError::corrupt(format!(
                    "header georeferencing origin {axis} {origin:?} with pixel size {axis} \
                     {pixel:?}: the lattice's coordinates ({first:?} … {last:?}, over {extent} \
                     points) are not finite and within ±{MAX_MAGNITUDE:e}"
                )));
            }
        }
    }
    if let Some(p) = h.provenance {
        for (what, v) in [
            ("maximum", p.resampling_max),
            ("root mean square", p.resampling_rms),
        ] {
            if !within(v) {
                return Err(CodecError::corrupt(format!(
                    "header planet resampling error ({what}) {v:?} m is not finite and within \
                     ±{MAX_MAGNITUDE:e} m"
                )));
            }
        }
    }
    Ok(())
}

/// The placement step: the sections follow the header and one another without gaps, end
/// within `file_len` and the records area ends the file; the `given` bytes hold everything
/// before the records area.
fn parse_placement(
    sections: &[SectionEntry; 4],
    header_len: usize,
    given: usize,
    file_len: u64,
) -> Result<(), CodecError> {
    let mut expected = header_len as u64;
    for (i, s) in Section::ALL.iter().enumerate() {
        let info = sections[i];
        // Sections follow one another without gaps: anything else is not a repository.
        if info.offset != expected {
            return Err(CodecError::corrupt(format!(
                "{} starts at byte {}, expected {expected}",
                s.name(),
                info.offset
            )));
        }
        let end = info
            .offset
            .checked_add(info.length)
            .ok_or_else(|| CodecError::corrupt(format!("{} length overflows", s.name())))?;
        if end > file_len {
            return Err(CodecError::truncated(format!(
                "{} ends at byte {end} but the file is {file_len} bytes",
                s.name()
            )));
        }
        expected = end;
    }
    if expected != file_len {
        return Err(CodecError::corrupt(format!(
            "{} trailing bytes after the records area",
            file_len - expected
        )));
    }
    if (given as u64) < sections[3].offset {
        return Err(CodecError::truncated(format!(
            "{given} bytes given, the repository head is {}",
            sections[3].offset
        )));
    }
    Ok(())
}

/// The checksum step: the CRCs of the root field, the index and the record checksum table
/// (placed by [`parse_placement`]).
fn parse_section_checksums(b: &[u8], sections: &[SectionEntry; 4]) -> Result<(), CodecError> {
    for (i, s) in Section::ALL.iter().enumerate().take(3) {
        if crc32(&b[range_of(&sections[i])]) != sections[i].crc {
            return Err(CodecError::corrupt(format!(
                "{} checksum mismatch",
                s.name()
            )));
        }
    }
    Ok(())
}

/// The index step: the record index, decoded in the coding of the file's version, holds as
/// many records as the header says.
fn parse_index(b: &[u8], h: &HeaderFields, domain: &Domain) -> Result<Vec<IndexEntry>, CodecError> {
    let sections = &h.sections;
    let record_count = h.record_count;
    let entries = decode_index(
        domain,
        &b[range_of(&sections[1])],
        sections[3].length,
        IndexCoding::for_format_version(h.version)?,
    )?;
    if entries.len() as u64 != record_count {
        return Err(CodecError::corrupt(format!(
            "index holds {} records, header says {record_count}",
            entries.len()
        )));
    }
    Ok(entries)
}

/// The record checksum table: one CRC-32 per non-empty record of `entries`, nothing more;
/// returns one per entry (0 for empty records).
fn parse_record_checksums(
    b: &[u8],
    sections: &[SectionEntry; 4],
    entries: &[IndexEntry],
) -> Result<Vec<u32>, CodecError> {
    let non_empty = entries.iter().filter(|e| e.length > 0).count() as u64;
    if non_empty * 4 != sections[2].length {
        return Err(CodecError::corrupt(format!(
            "record checksum table is {} bytes for {non_empty} non-empty records",
            sections[2].length
        )));
    }
    let table = &b[range_of(&sections[2])];
    let mut slot = 0;
    Ok(entries
        .iter()
        .map(|e| {
            if e.length == 0 {
                return 0;
            }
            slot += 4;
            u32_at(table, slot - 4)
        })
        .collect())
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

/// Makes every checksum of a repository-shaped file match its bytes, in place: section CRCs,
/// header CRC and, when the head then parses, each non-empty record's slot in the checksum
/// table. For fuzzers and tests of hostile writers (checksums guard against damage, not against
/// a writer who computes them): what lies behind the checksums must still be validated.
/// Bytes whose header structure cannot be read are left as they are.
#[doc(hidden)]
pub fn reseal_checksums(b: &mut [u8]) {
    let Some(table) = reseal_header(b) else {
        return;
    };
    if let Ok(head) = RepositoryHead::parse(b, b.len() as u64) {
        let mut slot = 0;
        for i in 0..head.entries().len() {
            let Some(r) = head.record_range(i) else {
                continue;
            };
            if r.start == r.end {
                continue;
            }
            let at = table.start + 4 * slot;
            slot += 1;
            if at + 4 > table.end || r.end > b.len() as u64 {
                break;
            }
            let crc = crc32(&b[r.start as usize..r.end as usize]);
            b[at..at + 4].copy_from_slice(&crc.to_le_bytes());
        }
        reseal_header(b);
    }
}

/// The header fields [`craft_header`] can set, by name.
#[doc(hidden)]
pub const CRAFTABLE_FIELDS: &[&str] = &[
    "flags",
    "n",
    "level_pairs",
    "alpha",
    "coder",
    "lattice",
    "geo_flags",
    "nodata_policy",
    "vertical_unit",
    "roots_x",
    "roots_y",
    "data_width",
    "data_height",
    "quantizer_k",
    "leaf_error",
    "epsg",
    "unit",
    "offset",
    "epsilon",
    "representation_error",
    "origin_x",
    "origin_y",
    "pixel_x",
    "pixel_y",
    "nodata",
    "record_count",
    "resampling_max",
    "resampling_rms",
    "rms_target",
    "rms_measured",
];

/// A hostile writer's header: the repository `b` (format version 3 or later) with one header
/// field, named as in [`CRAFTABLE_FIELDS`], set to `bits` (a float's bits, or an integer, which
/// must fit the field), the header rewritten and every checksum made to match
/// ([`reseal_checksums`]). For tests and fuzzers of the validation behind the checksums.
///
/// # Errors
/// When `b`'s header cannot be read, is a fixed (version 1 or 2) one, the field is unknown or
/// the value does not fit it.
#[doc(hidden)]
pub fn craft_header(b: &[u8], field: &str, bits: u64) -> Result<Vec<u8>, CodecError> {
    let mut sealed = b.to_vec();
    reseal_header(&mut sealed);
    let mut h = read_header(&sealed)?;
    if h.version < 3 {
        return Err(CodecError::unsupported(
            "crafting a fixed (version 1 or 2) header",
        ));
    }
    let too_large = || CodecError::invalid(format!("{bits} does not fit header field {field}"));
    let int = || u32::try_from(bits).map_err(|_| too_large());
    let byte = || u8::try_from(bits).map_err(|_| too_large());
    let float = f64::from_bits(bits);
    let provenance = |h: &mut HeaderFields| {
        *h.provenance.get_or_insert(PlanetProvenance {
            vertical_datum: VerticalDatum::Unknown,
            resampling_max: 0.0,
            resampling_rms: 0.0,
        })
    };
    match field {
        "flags" => h.flags = int()?,
        "n" => h.n = int()?,
        "level_pairs" => h.level_pairs = byte()?,
        "alpha" => h.alpha = byte()?,
        "coder" => h.coder = byte()?,
        "lattice" => h.lattice = byte()?,
        "geo_flags" => h.geo_flags = byte()?,
        "nodata_policy" => h.nodata_policy = byte()?,
        "vertical_unit" => h.vertical_unit = byte()?,
        "roots_x" => h.roots_x = int()?,
        "roots_y" => h.roots_y = int()?,
        "data_width" => h.data_width = int()?,
        "data_height" => h.data_height = int()?,
        "quantizer_k" => h.quantizer_k = int()?,
        "leaf_error" => h.leaf_error = int()?,
        "epsg" => h.epsg = int()?,
        "unit" => h.unit = float,
        "offset" => h.offset = float,
        "epsilon" => h.epsilon = float,
        "representation_error" => h.representation_error = float,
        "origin_x" => h.geo[0] = float,
        "origin_y" => h.geo[1] = float,
        "pixel_x" => h.geo[2] = float,
        "pixel_y" => h.geo[3] = float,
        "nodata" => h.nodata = float,
        "record_count" => h.record_count = bits,
        "resampling_max" => {
            h.provenance = Some(PlanetProvenance {
                resampling_max: float,
                ..provenance(&mut h)
            });
        }
        "resampling_rms" => {
            h.provenance = Some(PlanetProvenance {
                resampling_rms: float,
                ..provenance(&mut h)
            });
        }
        "rms_target" => h.rms = Some((float, h.rms.map_or(0.0, |r| r.1))),
        "rms_measured" => h.rms = Some((h.rms.map_or(float, |r| r.0), float)),
        _ => {
            return Err(CodecError::invalid(format!(
                "no header field {field} (one of {})",
                CRAFTABLE_FIELDS.join(", ")
            )));
        }
    }
    let mut out = write_compact(&h)?;
    out.extend_from_slice(&sealed[h.header_len..]);
    reseal_checksums(&mut out);
    Ok(out)
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::hierarchy::{EncodeOptions, PlanetGrid, encode_planet};

    /// A small planet (N = 3, K = 1), its plan and its encoding.
    fn small_planet() -> (PlanetGrid, QuantPlan, Encoded) {
        let planet = PlanetGrid::from_fn(3, 1, |p| Some(p.x as i32 - p.y as i32)).unwrap();
        let plan = QuantPlan::new(1.0, Some(1.0), -2.0, 2.0).unwrap();
        let opts = EncodeOptions {
            n: 3,
            ..EncodeOptions::default()
        };
        let encoded = encode_planet(&planet, plan.quantizer, &opts).unwrap();
        (planet, plan, encoded)
    }

    #[test]
    fn a_cube_sphere_header_is_checked_field_by_field() {
        let (planet, plan, encoded) = small_planet();
        let bytes = serialize(&encoded, &plan, None, None).unwrap();
        let h = parse_header(&bytes).unwrap();
        assert_eq!(h.flags, FLAG_CUBE_SPHERE);
        let (domain, ..) = parse_layout(&h).unwrap();
        assert_eq!(domain, *planet.domain());
        let refused = |change: &dyn Fn(&mut HeaderFields), says: &str| {
            let mut bad = h.clone();
            change(&mut bad);
            let e = parse_layout(&bad).unwrap_err().to_string();
            assert!(e.contains(says), "{e}");
        };
        refused(&|h| h.roots_y = 2, "one root per face");
        refused(&|h| h.geo_flags = 1, "georeferencing");
        refused(&|h| h.data_width -= 1, "points, the header says");
        refused(&|h| h.flags |= FLAG_COLOUR, "colour cube-sphere");
        refused(&|h| h.flags |= 32, "unknown header flags");
        refused(
            &|h| h.flags = FLAG_PLANET_PROVENANCE,
            "provenance (flag bit 3) in a planar",
        );
        // Without the flag the same header is a plane.
        let mut plane = h.clone();
        plane.flags = 0;
        let (domain, ..) = parse_layout(&plane).unwrap();
        assert_eq!(domain.kind(), DomainKind::Planar);
    }

    /// A planet's provenance round-trips through the header (flag bit 3), is absent without
    /// it, and a planar repository cannot carry it.
    #[test]
    fn a_planet_provenance_round_trips() {
        let (_, plan, encoded) = small_planet();
        let pv = PlanetProvenance {
            vertical_datum: VerticalDatum::Orthometric,
            resampling_max: 12.25,
            resampling_rms: 0.5,
        };
        let bytes = serialize_with(&encoded, &plan, None, None, Some(&pv)).unwrap();
        let head = RepositoryHead::parse(&bytes, bytes.len() as u64).unwrap();
        assert_eq!(head.provenance(), Some(&pv));
        assert_eq!(
            parse_header(&bytes).unwrap().flags,
            FLAG_CUBE_SPHERE | FLAG_PLANET_PROVENANCE
        );
        let plain = serialize(&encoded, &plan, None, None).unwrap();
        assert_eq!(
            RepositoryHead::parse(&plain, plain.len() as u64)
                .unwrap()
                .provenance(),
            None
        );
        // An rms above the max is corrupt (the CRC is resealed so the field check is reached).
        let mut h = parse_header(&bytes).unwrap();
        h.provenance = Some(PlanetProvenance {
            resampling_rms: 20.0,
            ..pv
        });
        let bad = write_compact(&h).unwrap();
        let e = read_header(&bad).unwrap_err().to_string();
        assert!(e.contains("resampling error"), "{e}");
    }
}
