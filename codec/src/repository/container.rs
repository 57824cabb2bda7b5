//! The single-file repository container (format version 2, reading 1 too; `docs/FORMAT.md`).
//!
//! The two versions differ only in how the record index is coded ([`IndexCoding`]): version 2
//! range-codes it, which on smooth terrain is most of what a file holds besides the header.
//!
//! Layout: a fixed 256-byte header, then four sections in this order with no gaps — the coded
//! root field, the record index ([`super::index`]), a table of one CRC-32 per non-empty record in
//! id order, and the records area (record bytes concatenated in id order, so record offsets are the prefix
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

use super::index::{IndexCoding, IndexEntry, decode_index, encode_index, range_shift_for};
use crate::CodecError;
use crate::atomic::write_atomically;
use crate::colour::{ColourDecoder, ycocg};
use crate::entropy::CoderKind;
use crate::geometry::{DiamondId, Layout};
use crate::hierarchy::{CodecParams, Decoder, Encoded, Record, RepoKind, root_quantizer};
use crate::input::GeoRef;
use crate::lifting::Alpha;
use crate::quant::{QuantPlan, Quantizer};

/// The first eight bytes of every repository. The CR LF pair catches text-mode transfers that
/// rewrite line endings; the NUL stops it being mistaken for text.
pub const MAGIC: [u8; 8] = *b"CBDAM\0\r\n";
/// The format version this code writes and the newest it reads (it reads every older one).
pub const FORMAT_VERSION: u16 = 2;
/// Size of the header (the same in every version), bytes (the header CRC is its last four bytes).
pub const HEADER_LEN: usize = 256;

/// Byte offset of the section table in the header.
const SECTIONS_AT: usize = 128;
/// Bytes per section-table entry: offset u64, length u64, CRC-32 u32, reserved u32.
const SECTION_ENTRY: usize = 24;
/// Byte offset of the record count.
const RECORD_COUNT_AT: usize = SECTIONS_AT + 4 * SECTION_ENTRY;
/// Byte offset of the input's nodata value (f64, NaN for none).
const NODATA_AT: usize = RECORD_COUNT_AT + 8;
/// Byte offset of the header CRC.
const HEADER_CRC_AT: usize = HEADER_LEN - 4;

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

/// Where a section lies and its checksum.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct SectionInfo {
    offset: u64,
    length: u64,
    crc: u32,
}

impl SectionInfo {
    fn range(&self) -> std::ops::Range<usize> {
        // Bounds were checked against the file length at open, so both fit in usize.
        self.offset as usize..(self.offset + self.length) as usize
    }
}

fn crc32(bytes: &[u8]) -> u32 {
    crc32fast::hash(bytes)
}

/// Serialises `encoded` as a repository file image. `nodata` is the input's effective nodata
/// value (recorded so that `verify` can re-read the input the same way).
pub fn serialize(
    encoded: &Encoded,
    plan: &QuantPlan,
    georef: Option<&GeoRef>,
    nodata: Option<f64>,
) -> Result<Vec<u8>, CodecError> {
    let p = &encoded.params;
    if p.quantizer != plan.quantizer {
        return Err(CodecError::invalid(
            "the quantization plan does not match the encoded hierarchy's quantizer",
        ));
    }
    let entries = encoded.index_entries();
    let index = encode_index(&p.layout, &entries, range_shift_for(p.quantizer));
    // Empty records (all residuals zero) get no checksum: their length of 0 is already covered
    // by the index's CRC, and smooth terrain has many (all 69 of lidar1m_mn's at 5 m).
    let checksums: Vec<u8> = encoded
        .records
        .iter()
        .filter(|r| !r.bytes.is_empty())
        .flat_map(|r| crc32(&r.bytes).to_le_bytes())
        .collect();
    let records_len: u64 = encoded.records.iter().map(|r| r.bytes.len() as u64).sum();
    let n = u16::try_from(p.layout.n()).map_err(|_| CodecError::limit("diamond size"))?;
    let k = u8::try_from(p.layout.k()).map_err(|_| CodecError::limit("level pairs"))?;

    let mut h = vec![0u8; HEADER_LEN];
    let mut put = |at: usize, b: &[u8]| h[at..at + b.len()].copy_from_slice(b);
    put(0, &MAGIC);
    put(8, &FORMAT_VERSION.to_le_bytes());
    put(10, &(HEADER_LEN as u16).to_le_bytes());
    let flags = if p.nodata_mask { FLAG_NODATA_MASK } else { 0 }
        | if p.kind == RepoKind::Colour {
            FLAG_COLOUR
        } else {
            0
        };
    put(12, &flags.to_le_bytes());
    put(16, &n.to_le_bytes());
    put(18, &[k]);
    put(19, &[p.alpha.to_byte()]);
    put(20, &[p.coder.to_byte()]);
    put(21, &[u8::from(plan.lattice)]);
    let geo_flags = georef.map_or(0, |g| 1 | (u8::from(g.pixel_is_area) << 1));
    put(22, &[geo_flags]);
    put(23, &[NODATA_DONT_CARE]);
    put(24, &p.layout.roots_x().to_le_bytes());
    put(28, &p.layout.roots_y().to_le_bytes());
    put(32, &p.data_width.to_le_bytes());
    put(36, &p.data_height.to_le_bytes());
    put(40, &(p.quantizer.k() as u32).to_le_bytes());
    put(44, &(p.root_quantizer.k() as u32).to_le_bytes());
    put(48, &encoded.leaf_error.to_le_bytes());
    put(52, &georef.and_then(|g| g.epsg).unwrap_or(0).to_le_bytes());
    put(56, &plan.unit.to_le_bytes());
    put(64, &plan.offset.to_le_bytes());
    put(72, &plan.epsilon.to_le_bytes());
    put(80, &plan.representation_error.to_le_bytes());
    let g = georef.cloned().unwrap_or(GeoRef {
        epsg: None,
        origin_x: 0.0,
        origin_y: 0.0,
        pixel_x: 0.0,
        pixel_y: 0.0,
        pixel_is_area: false,
    });
    put(88, &g.origin_x.to_le_bytes());
    put(96, &g.origin_y.to_le_bytes());
    put(104, &g.pixel_x.to_le_bytes());
    put(112, &g.pixel_y.to_le_bytes());
    put(120, &[VERTICAL_METRES]);
    put(NODATA_AT, &nodata.unwrap_or(f64::NAN).to_le_bytes());
    let mut offset = HEADER_LEN as u64;
    let sections: [(&[u8], u64); 4] = [
        (&encoded.roots, encoded.roots.len() as u64),
        (&index, index.len() as u64),
        (&checksums, checksums.len() as u64),
        (&[], records_len),
    ];
    let mut records_hasher = crc32fast::Hasher::new();
    for r in &encoded.records {
        records_hasher.update(&r.bytes);
    }
    let records_crc = records_hasher.finalize();
    for (i, (bytes, len)) in sections.iter().enumerate() {
        let at = SECTIONS_AT + i * SECTION_ENTRY;
        let crc = if i == 3 { records_crc } else { crc32(bytes) };
        put(at, &offset.to_le_bytes());
        put(at + 8, &len.to_le_bytes());
        put(at + 16, &crc.to_le_bytes());
        offset += len;
    }
    put(
        RECORD_COUNT_AT,
        &(encoded.records.len() as u64).to_le_bytes(),
    );
    let crc = crc32(&h[..HEADER_CRC_AT]);
    h[HEADER_CRC_AT..].copy_from_slice(&crc.to_le_bytes());

    let total = usize::try_from(offset).map_err(|_| CodecError::limit("repository too large"))?;
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(&h);
    out.extend_from_slice(&encoded.roots);
    out.extend_from_slice(&index);
    out.extend_from_slice(&checksums);
    for r in &encoded.records {
        out.extend_from_slice(&r.bytes);
    }
    debug_assert_eq!(out.len(), total);
    Ok(out)
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
    if path.is_dir() {
        return Err(CodecError::invalid(format!(
            "output path {} is a directory",
            path.display()
        )));
    }
    let bytes = serialize(encoded, plan, georef, nodata)?;
    write_atomically(path, |f: &mut File| -> Result<(), CodecError> {
        f.write_all(&bytes)?;
        Ok(())
    })
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
    sections: [SectionInfo; 4],
    entries: Vec<IndexEntry>,
    /// Per entry, its CRC-32 (0 and unused for empty records).
    record_crcs: Vec<u32>,
    roots: Vec<u8>,
    file_len: u64,
    header_crc: u32,
    format_version: u16,
}

impl RepositoryHead {
    /// Validates a repository head: `b` holds at least the first [`required_head_len`] bytes of
    /// a file of `file_len` bytes (the whole file will do). Checks magic, version, header CRC,
    /// every header field, section placement against `file_len`, the CRCs of the root field,
    /// index and checksum table, and the index itself.
    pub fn parse(b: &[u8], file_len: u64) -> Result<Self, CodecError> {
        if b.len() < MAGIC.len() {
            return Err(CodecError::truncated(format!(
                "file is {} bytes, too short for the repository magic",
                b.len()
            )));
        }
        if b[..8] != MAGIC {
            return Err(CodecError::corrupt(
                "not a C-BDAM repository (bad magic bytes)",
            ));
        }
        if b.len() < 12 {
            return Err(CodecError::truncated("file ends inside the header"));
        }
        let version = u16_at(b, 8);
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
        let header_len = u16_at(b, 10);
        if usize::from(header_len) != HEADER_LEN {
            return Err(CodecError::corrupt(format!(
                "header length {header_len}, version {version} headers are {HEADER_LEN} bytes"
            )));
        }
        if b.len() < HEADER_LEN {
            return Err(CodecError::truncated(format!(
                "file is {} bytes, shorter than the {HEADER_LEN}-byte header",
                b.len()
            )));
        }
        let stored_crc = u32_at(b, HEADER_CRC_AT);
        if crc32(&b[..HEADER_CRC_AT]) != stored_crc {
            return Err(CodecError::corrupt("header checksum mismatch"));
        }
        // The CRC matched, so what follows are fields some writer meant; still validate each,
        // since a buggy or hostile writer can compute a CRC too.
        let flags = u32_at(b, 12);
        if flags & !(FLAG_NODATA_MASK | FLAG_COLOUR) != 0 {
            return Err(CodecError::unsupported(format!(
                "unknown header flags {flags:#x}"
            )));
        }
        let layout = Layout::new(
            usize::from(u16_at(b, 16)),
            u32::from(b[18]),
            u32_at(b, 24),
            u32_at(b, 28),
        )
        .map_err(|e| CodecError::corrupt(format!("header layout: {e}")))?;
        let alpha = Alpha::from_byte(b[19])
            .ok_or_else(|| CodecError::corrupt(format!("unknown lifting weight id {}", b[19])))?;
        let coder = CoderKind::from_byte(b[20])?;
        let lattice = match b[21] {
            0 => false,
            1 => true,
            v => {
                return Err(CodecError::corrupt(format!(
                    "lattice flag {v} is not 0 or 1"
                )));
            }
        };
        let geo_flags = b[22];
        if geo_flags & !3 != 0 || geo_flags == 2 {
            return Err(CodecError::corrupt(format!(
                "invalid georeferencing flags {geo_flags:#x}"
            )));
        }
        if b[23] != NODATA_DONT_CARE {
            return Err(CodecError::unsupported(format!(
                "unknown nodata policy {}",
                b[23]
            )));
        }
        if b[120] != VERTICAL_METRES {
            return Err(CodecError::unsupported(format!(
                "unknown vertical unit {}",
                b[120]
            )));
        }
        if b[121..SECTIONS_AT].iter().any(|&x| x != 0)
            || b[NODATA_AT + 8..HEADER_CRC_AT].iter().any(|&x| x != 0)
        {
            return Err(CodecError::corrupt("reserved header bytes are not zero"));
        }
        let data_width = u32_at(b, 32);
        let data_height = u32_at(b, 36);
        let (ex, ey) = layout.extent();
        if data_width == 0
            || data_height == 0
            || i64::from(data_width) > ex + 1
            || i64::from(data_height) > ey + 1
        {
            return Err(CodecError::corrupt(format!(
                "data size {data_width}×{data_height} does not fit the layout's {}×{} lattice",
                ex + 1,
                ey + 1
            )));
        }
        let quantizer = Quantizer::new(u32_at(b, 40))
            .map_err(|e| CodecError::corrupt(format!("header quantizer: {e}")))?;
        let root_k = u32_at(b, 44);
        let root_q = root_quantizer(quantizer);
        if root_k != root_q.k() as u32 {
            return Err(CodecError::unsupported(format!(
                "root quantizer k = {root_k}; this reader derives {} from k = {}",
                root_q.k(),
                quantizer.k()
            )));
        }
        let leaf_error = u32_at(b, 48);
        let epsg = u32_at(b, 52);
        let unit = f64_at(b, 56);
        let offset = f64_at(b, 64);
        let epsilon = f64_at(b, 72);
        let representation_error = f64_at(b, 80);
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
            if flags & FLAG_NODATA_MASK != 0 {
                return Err(CodecError::unsupported(
                    "a colour repository with a nodata mask",
                ));
            }
            if unit != 1.0 || offset != 0.0 || !lattice || representation_error != 0.0 {
                return Err(CodecError::corrupt(
                    "a colour repository must have unit 1, offset 0 and lattice input",
                ));
            }
            let bound = ycocg::rgb_bound(quantizer.k() as u32);
            if bound.iter().any(|&b| f64::from(b) > epsilon) {
                return Err(CodecError::corrupt(format!(
                    "colour quantizer k = {} allows RGB errors of {bound:?}, over the stated \
                     tolerance {epsilon}",
                    quantizer.k()
                )));
            }
        }
        if !(representation_error.is_finite() && representation_error >= 0.0) {
            return Err(CodecError::corrupt(
                "representation error is negative or not finite",
            ));
        }
        let geo: Vec<f64> = (0..4).map(|i| f64_at(b, 88 + 8 * i)).collect();
        let georef = if geo_flags & 1 == 1 {
            if geo.iter().any(|v| !v.is_finite()) {
                return Err(CodecError::corrupt("georeferencing values are not finite"));
            }
            Some(GeoRef {
                epsg: (epsg != 0).then_some(epsg),
                origin_x: geo[0],
                origin_y: geo[1],
                pixel_x: geo[2],
                pixel_y: geo[3],
                pixel_is_area: geo_flags & 2 == 2,
            })
        } else {
            if epsg != 0 || geo.iter().any(|&v| v.to_bits() != 0) {
                return Err(CodecError::corrupt(
                    "georeferencing fields are set but the header says there is none",
                ));
            }
            None
        };
        let nodata_value = f64_at(b, NODATA_AT);
        let nodata = (!nodata_value.is_nan()).then_some(nodata_value);

        let mut sections = [SectionInfo {
            offset: 0,
            length: 0,
            crc: 0,
        }; 4];
        let mut expected = HEADER_LEN as u64;
        for (i, s) in Section::ALL.iter().enumerate() {
            let at = SECTIONS_AT + i * SECTION_ENTRY;
            let info = SectionInfo {
                offset: u64_at(b, at),
                length: u64_at(b, at + 8),
                crc: u32_at(b, at + 16),
            };
            if u32_at(b, at + 20) != 0 {
                return Err(CodecError::corrupt(format!(
                    "reserved bytes of the {} entry are not zero",
                    s.name()
                )));
            }
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
            sections[i] = info;
        }
        if expected != file_len {
            return Err(CodecError::corrupt(format!(
                "{} trailing bytes after the records area",
                file_len - expected
            )));
        }
        if (b.len() as u64) < sections[3].offset {
            return Err(CodecError::truncated(format!(
                "{} bytes given, the repository head is {}",
                b.len(),
                sections[3].offset
            )));
        }
        for (i, s) in Section::ALL.iter().enumerate().take(3) {
            if crc32(&b[sections[i].range()]) != sections[i].crc {
                return Err(CodecError::corrupt(format!(
                    "{} checksum mismatch",
                    s.name()
                )));
            }
        }
        let record_count = u64_at(b, RECORD_COUNT_AT);
        let entries = decode_index(
            &layout,
            &b[sections[1].range()],
            sections[3].length,
            IndexCoding::for_format_version(version)?,
        )?;
        if entries.len() as u64 != record_count {
            return Err(CodecError::corrupt(format!(
                "index holds {} records, header says {record_count}",
                entries.len()
            )));
        }
        let non_empty = entries.iter().filter(|e| e.length > 0).count() as u64;
        if non_empty * 4 != sections[2].length {
            return Err(CodecError::corrupt(format!(
                "record checksum table is {} bytes for {non_empty} non-empty records",
                sections[2].length
            )));
        }
        let params = CodecParams {
            layout,
            alpha,
            coder,
            quantizer,
            root_quantizer: root_q,
            data_width,
            data_height,
            nodata_mask: flags & FLAG_NODATA_MASK != 0,
            kind,
        };
        let plan = QuantPlan {
            unit,
            offset,
            quantizer,
            lattice,
            representation_error,
            epsilon,
        };
        let table = &b[sections[2].range()];
        let mut slot = 0;
        let record_crcs = entries
            .iter()
            .map(|e| {
                if e.length == 0 {
                    return 0;
                }
                slot += 4;
                u32_at(table, slot - 4)
            })
            .collect();
        Ok(Self {
            params,
            plan,
            georef,
            nodata,
            leaf_error,
            sections,
            entries,
            record_crcs,
            roots: b[sections[0].range()].to_vec(),
            file_len,
            header_crc: stored_crc,
            format_version: version,
        })
    }

    /// The format version of the file (1 or 2; [`FORMAT_VERSION`] is the one this code writes).
    pub fn format_version(&self) -> u16 {
        self.format_version
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

/// An opened, validated repository: the head plus the mapped records.
#[derive(Debug)]
pub struct Repository {
    bytes: Backing,
    head: RepositoryHead,
}

/// How many bytes from the start of a repository file make up its head (everything before the
/// records area), read from the file's first [`HEADER_LEN`] bytes. Only the header checksum and
/// magic are checked here; [`RepositoryHead::parse`] validates the rest.
pub fn required_head_len(header: &[u8]) -> Result<u64, CodecError> {
    if header.len() < HEADER_LEN {
        return Err(CodecError::truncated(format!(
            "{} bytes given, the header is {HEADER_LEN}",
            header.len()
        )));
    }
    if header[..8] != MAGIC {
        return Err(CodecError::corrupt(
            "not a C-BDAM repository (bad magic bytes)",
        ));
    }
    if crc32(&header[..HEADER_CRC_AT]) != u32_at(header, HEADER_CRC_AT) {
        return Err(CodecError::corrupt("header checksum mismatch"));
    }
    let records_offset = u64_at(header, SECTIONS_AT + 3 * SECTION_ENTRY);
    if records_offset < HEADER_LEN as u64 {
        return Err(CodecError::corrupt(format!(
            "records area starts at byte {records_offset}, inside the header"
        )));
    }
    Ok(records_offset)
}

fn u16_at(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([b[at], b[at + 1]])
}
fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().expect("4 bytes"))
}
fn u64_at(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().expect("8 bytes"))
}
fn f64_at(b: &[u8], at: usize) -> f64 {
    f64::from_le_bytes(b[at..at + 8].try_into().expect("8 bytes"))
}

impl Repository {
    /// Maps and validates the repository at `path`: magic, version, header CRC, every header
    /// field, section bounds against the file length, the CRCs of the root field, index and
    /// checksum table, and the index itself. Record bytes are checked when read
    /// ([`Repository::record`]) or by [`Repository::check_all`].
    pub fn open(path: &Path) -> Result<Self, CodecError> {
        let file = File::open(path)?;
        let len = file.metadata()?.len();
        if len < HEADER_LEN as u64 {
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

    /// The header, root field, index and checksums.
    pub fn head(&self) -> &RepositoryHead {
        &self.head
    }
    /// The decoder's header fields.
    pub fn params(&self) -> &CodecParams {
        self.head.params()
    }

    /// How integer units map to metres, and the tolerance the repository was built for.
    pub fn plan(&self) -> &QuantPlan {
        self.head.plan()
    }

    /// Georeferencing of the data grid, when the input had one.
    pub fn georef(&self) -> Option<&GeoRef> {
        self.head.georef()
    }

    /// The input's nodata value at build time, if any.
    pub fn nodata(&self) -> Option<f64> {
        self.head.nodata()
    }

    /// Object-space error of the finest diamonds, units.
    pub fn leaf_error(&self) -> u32 {
        self.head.leaf_error()
    }

    /// The index entries, in id order.
    pub fn entries(&self) -> &[IndexEntry] {
        self.head.entries()
    }

    /// Total file size, bytes.
    pub fn file_len(&self) -> u64 {
        self.head.file_len()
    }

    /// Length of a section, bytes.
    pub fn section_len(&self, s: Section) -> u64 {
        self.head.section_len(s)
    }

    /// The coded root field.
    pub fn root_bytes(&self) -> &[u8] {
        self.head.root_bytes()
    }

    /// The whole file, as validated by [`Repository::open`] (the records area unchecked). For
    /// serving the file verbatim, e.g. to HTTP range requests.
    pub fn as_bytes(&self) -> &[u8] {
        &self.bytes
    }

    /// Byte offset of a section from the start of the file. The records area is the last
    /// section, so its offset is the length of everything a reader needs besides the records.
    pub fn section_offset(&self, s: Section) -> u64 {
        self.head.section_offset(s)
    }

    /// The header's CRC-32 (see [`RepositoryHead::header_crc`]).
    pub fn header_crc(&self) -> u32 {
        self.head.header_crc()
    }

    /// The CRC-32 stored for the `i`-th record (see [`RepositoryHead::record_checksum`]).
    pub fn record_checksum(&self, i: usize) -> Option<u32> {
        self.head.record_checksum(i)
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
        if crc32(&self.bytes[records.range()]) != records.crc {
            return Err(CodecError::corrupt("records area checksum mismatch"));
        }
        Ok(())
    }

    /// A decoder over the root field (elevation repositories).
    pub fn decoder(&self) -> Result<Decoder, CodecError> {
        self.head.decoder()
    }

    /// What the repository holds.
    pub fn kind(&self) -> RepoKind {
        self.head.kind()
    }

    /// The three-channel decoder over the root field (colour repositories).
    pub fn colour_decoder(&self) -> Result<ColourDecoder, CodecError> {
        self.head.colour_decoder()
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
                    bytes: self.record_at(i)?.to_vec(),
                    object_error: e.object_error,
                    min: e.min,
                    max: e.max,
                })
            })
            .collect::<Result<Vec<_>, CodecError>>()?;
        Ok(Encoded {
            params: self.head.params,
            roots: self.root_bytes().to_vec(),
            records,
            leaf_error: self.head.leaf_error,
        })
    }
}
