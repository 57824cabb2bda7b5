//! The repository header, in its two layouts: the fixed 256 bytes of versions 1 and 2, and the
//! compact variable-length header of version 3 (`docs/FORMAT.md`, "Header").
//!
//! Both layouts carry the same fields ([`HeaderFields`]); [`super::container`] builds them when
//! writing and validates their meaning when reading, whatever the layout. This module only turns
//! fields into bytes and back, checking what the bytes themselves can get wrong: magic, length,
//! checksum, reserved bytes, numbers that do not fit.
//!
//! Why version 3: the fixed header was 256 bytes, 35 of them reserved zeros and 96 a section
//! table whose offsets the file layout already implies. On smooth terrain at loose tolerances a
//! whole repository is a few hundred bytes (lidar1m_mn at 5 m: 611), so the header was the
//! largest thing in it. Version 3 writes integers as LEB128 varints and floats as varints of
//! their byte-reversed bits, which makes the short mantissas of typical values (1.0, 0.5, whole
//! coordinates) short; section offsets are implied (sections follow the header without gaps).

use crate::CodecError;

/// The first eight bytes of every repository. The CR LF pair catches text-mode transfers that
/// rewrite line endings; the NUL stops it being mistaken for text.
pub const MAGIC: [u8; 8] = *b"CBDAM\0\r\n";
/// The longest header of any version, bytes (its length is a `u16`).
pub const MAX_HEADER_LEN: usize = u16::MAX as usize;
/// A first read of this many bytes from the start of a file (or all of it, if shorter) holds the
/// whole header in versions 1 and 2, and in version 3 unless a long CRS definition (WKT) makes
/// it longer; [`header_len`] says how long it is.
pub const HEADER_FETCH_LEN: usize = 256;
/// The header of versions 1 and 2: always exactly this long.
const FIXED_HEADER_LEN: usize = 256;
/// Magic, version and header length: the same eight + four bytes in every version.
const PREFIX_LEN: usize = 12;

/// Byte offset of the section table in a fixed header.
const SECTIONS_AT: usize = 128;
/// Bytes per section-table entry: offset u64, length u64, CRC-32 u32, reserved u32.
const SECTION_ENTRY: usize = 24;
/// Byte offset of the record count in a fixed header.
const RECORD_COUNT_AT: usize = SECTIONS_AT + 4 * SECTION_ENTRY;
/// Byte offset of the input's nodata value (f64, NaN for none) in a fixed header.
const NODATA_AT: usize = RECORD_COUNT_AT + 8;
/// Byte offset of the header CRC in a fixed header.
const FIXED_CRC_AT: usize = FIXED_HEADER_LEN - 4;

/// One section's place and checksum.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub(crate) struct SectionEntry {
    pub offset: u64,
    pub length: u64,
    pub crc: u32,
}

/// Header flag bit 3 (only with bit 2, a cube-sphere): the header holds the planet's
/// provenance, [`PlanetProvenance`] (`docs/FORMAT.md`, "Cube-sphere repositories").
pub const FLAG_PLANET_PROVENANCE: u32 = 8;

/// Header flag bit 4: the header holds the RMS error bound of a `--rms-error` build, two
/// floats after the nodata value (and a planet's provenance): the target and the RMS error the
/// build measured (`docs/FORMAT.md`, "Header"). Builds that bound the maximum error only leave
/// it clear and are unchanged; readers that predate it refuse it ("unknown header flags").
pub const FLAG_RMS_ERROR: u32 = 16;

/// What the heights of a planet are measured from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VerticalDatum {
    /// Not recorded.
    Unknown,
    /// Orthometric: above mean sea level (a geoid such as EGM96), as DEMs give heights; drawn
    /// along the ellipsoid normal they are off the ellipsoidal height by the geoid undulation
    /// (up to about ±100 m).
    Orthometric,
    /// Ellipsoidal: above the WGS84 ellipsoid.
    Ellipsoidal,
}

impl VerticalDatum {
    /// The byte stored in the header.
    pub fn to_byte(self) -> u8 {
        match self {
            Self::Unknown => 0,
            Self::Orthometric => 1,
            Self::Ellipsoidal => 2,
        }
    }

    /// The datum of a stored byte, `None` for an unknown one.
    pub fn from_byte(b: u8) -> Option<Self> {
        match b {
            0 => Some(Self::Unknown),
            1 => Some(Self::Orthometric),
            2 => Some(Self::Ellipsoidal),
            _ => None,
        }
    }

    /// Its one-word code (JSON).
    pub fn code(self) -> &'static str {
        match self {
            Self::Unknown => "unknown",
            Self::Orthometric => "orthometric",
            Self::Ellipsoidal => "ellipsoidal",
        }
    }

    /// A phrase for it.
    pub fn name(self) -> &'static str {
        match self {
            Self::Unknown => "unknown",
            Self::Orthometric => "orthometric (above the geoid, as the inputs give it)",
            Self::Ellipsoidal => "ellipsoidal (above WGS84)",
        }
    }
}

/// How a planet's lattice came from its inputs: the vertical datum of the heights and how far
/// the resampled lattice is from the inputs' own samples (`cbdam build --planet`). The L∞
/// bound of the header holds against the resampled lattice; these say what lies between that
/// lattice and the source data.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlanetProvenance {
    /// The inputs' vertical datum.
    pub vertical_datum: VerticalDatum,
    /// Largest |lattice − sample| over the inputs' compared samples, metres.
    pub resampling_max: f64,
    /// Root mean square of the same, metres.
    pub resampling_rms: f64,
}

/// Every header field, as stored (validated for meaning by the container).
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct HeaderFields {
    pub version: u16,
    /// Length of the header, bytes: 256 in versions 1 and 2.
    pub header_len: usize,
    pub flags: u32,
    pub n: u32,
    pub level_pairs: u8,
    pub alpha: u8,
    pub coder: u8,
    pub lattice: u8,
    pub geo_flags: u8,
    pub nodata_policy: u8,
    pub vertical_unit: u8,
    pub roots_x: u32,
    pub roots_y: u32,
    pub data_width: u32,
    pub data_height: u32,
    pub quantizer_k: u32,
    /// The root quantizer's `k` where the layout stores it (versions 1 and 2, which require it
    /// to be `⌊k / 2⌋`); version 3 derives it and stores nothing.
    pub root_k: Option<u32>,
    pub leaf_error: u32,
    pub epsg: u32,
    pub unit: f64,
    pub offset: f64,
    pub epsilon: f64,
    pub representation_error: f64,
    /// Origin x, origin y, pixel size x, pixel size y (zeros without georeferencing).
    pub geo: [f64; 4],
    /// The input's nodata value, NaN for none.
    pub nodata: f64,
    /// The CRS as WKT (version 3, with georeferencing only).
    pub wkt: Option<String>,
    /// A planet's provenance (version 3, with flag bit 3 only).
    pub provenance: Option<PlanetProvenance>,
    /// The RMS bound: target and measured, metres (version 3, with flag bit 4 only).
    pub rms: Option<(f64, f64)>,
    /// Roots, index, checksums, records.
    pub sections: [SectionEntry; 4],
    pub record_count: u64,
    /// The CRC-32 stored at the header's end.
    pub crc: u32,
}

pub(super) fn crc32(bytes: &[u8]) -> u32 {
    crc32fast::hash(bytes)
}

fn u16_at(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([b[at], b[at + 1]])
}
pub(super) fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().expect("4 bytes"))
}
fn u64_at(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().expect("8 bytes"))
}
fn f64_at(b: &[u8], at: usize) -> f64 {
    f64::from_le_bytes(b[at..at + 8].try_into().expect("8 bytes"))
}

/// The length of the header that `prefix`, a file's first bytes (at least 12), starts: how many
/// bytes to read before [`super::required_head_len`] can answer. Checks the magic only.
pub fn header_len(prefix: &[u8]) -> Result<usize, CodecError> {
    Ok(read_prefix(prefix)?.1)
}

/// Checks the magic and reads the version and the header length from a file's first bytes.
pub(crate) fn read_prefix(b: &[u8]) -> Result<(u16, usize), CodecError> {
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
    if b.len() < PREFIX_LEN {
        return Err(CodecError::truncated("file ends inside the header"));
    }
    Ok((u16_at(b, 8), usize::from(u16_at(b, 10))))
}

/// Reads the header at the start of `b` (at least the whole header), checking its length, CRC
/// and reserved bytes. Versions 1 and 2 have the fixed layout, any later one the compact; the
/// container refuses versions it does not know before calling this.
pub(crate) fn read_header(b: &[u8]) -> Result<HeaderFields, CodecError> {
    let (version, header_len) = read_prefix(b)?;
    let expected = match version {
        1 | 2 => Some(FIXED_HEADER_LEN),
        _ => None,
    };
    if let Some(len) = expected
        && header_len != len
    {
        return Err(CodecError::corrupt(format!(
            "header length {header_len}, version {version} headers are {len} bytes"
        )));
    }
    if !(PREFIX_LEN + 4..=MAX_HEADER_LEN).contains(&header_len) {
        return Err(CodecError::corrupt(format!(
            "header length {header_len} is outside {} … {MAX_HEADER_LEN}",
            PREFIX_LEN + 4
        )));
    }
    if b.len() < header_len {
        return Err(CodecError::truncated(format!(
            "file is {} bytes, shorter than its {header_len}-byte header",
            b.len()
        )));
    }
    let crc = u32_at(b, header_len - 4);
    if crc32(&b[..header_len - 4]) != crc {
        return Err(CodecError::corrupt("header checksum mismatch"));
    }
    // The CRC matched, so what follows are fields some writer meant; the container still
    // validates each, since a buggy or hostile writer can compute a CRC too.
    if expected.is_some() {
        read_fixed(b, version, crc)
    } else {
        read_compact(&b[..header_len], version, crc)
    }
}

fn read_fixed(b: &[u8], version: u16, crc: u32) -> Result<HeaderFields, CodecError> {
    if b[121..SECTIONS_AT].iter().any(|&x| x != 0)
        || b[NODATA_AT + 8..FIXED_CRC_AT].iter().any(|&x| x != 0)
    {
        return Err(CodecError::corrupt("reserved header bytes are not zero"));
    }
    let mut sections = [SectionEntry::default(); 4];
    for (i, s) in sections.iter_mut().enumerate() {
        let at = SECTIONS_AT + i * SECTION_ENTRY;
        if u32_at(b, at + 20) != 0 {
            return Err(CodecError::corrupt(format!(
                "reserved bytes of section entry {i} are not zero"
            )));
        }
        *s = SectionEntry {
            offset: u64_at(b, at),
            length: u64_at(b, at + 8),
            crc: u32_at(b, at + 16),
        };
    }
    Ok(HeaderFields {
        version,
        header_len: FIXED_HEADER_LEN,
        flags: u32_at(b, 12),
        n: u32::from(u16_at(b, 16)),
        level_pairs: b[18],
        alpha: b[19],
        coder: b[20],
        lattice: b[21],
        geo_flags: b[22],
        nodata_policy: b[23],
        vertical_unit: b[120],
        roots_x: u32_at(b, 24),
        roots_y: u32_at(b, 28),
        data_width: u32_at(b, 32),
        data_height: u32_at(b, 36),
        quantizer_k: u32_at(b, 40),
        root_k: Some(u32_at(b, 44)),
        leaf_error: u32_at(b, 48),
        epsg: u32_at(b, 52),
        unit: f64_at(b, 56),
        offset: f64_at(b, 64),
        epsilon: f64_at(b, 72),
        representation_error: f64_at(b, 80),
        geo: [f64_at(b, 88), f64_at(b, 96), f64_at(b, 104), f64_at(b, 112)],
        nodata: f64_at(b, NODATA_AT),
        wkt: None,
        provenance: None,
        rms: None,
        sections,
        record_count: u64_at(b, RECORD_COUNT_AT),
        crc,
    })
}

/// A cursor over a compact header's field bytes (between the prefix and the CRC).
struct Fields<'a> {
    b: &'a [u8],
    pos: usize,
}

impl Fields<'_> {
    fn byte(&mut self) -> Result<u8, CodecError> {
        let v = *self
            .b
            .get(self.pos)
            .ok_or_else(|| CodecError::corrupt("header fields end early"))?;
        self.pos += 1;
        Ok(v)
    }

    /// A canonical LEB128 varint: no value has two spellings, so a file has one header.
    fn varint(&mut self) -> Result<u64, CodecError> {
        let mut v = 0u64;
        for shift in (0..64).step_by(7) {
            let b = self.byte()?;
            if shift == 63 && b > 1 {
                break;
            }
            v |= u64::from(b & 0x7f) << shift;
            if b & 0x80 == 0 {
                if b == 0 && shift > 0 {
                    return Err(CodecError::corrupt("header number has a redundant byte"));
                }
                return Ok(v);
            }
        }
        Err(CodecError::corrupt("header number longer than 64 bits"))
    }

    fn u32(&mut self, what: &str) -> Result<u32, CodecError> {
        let v = self.varint()?;
        u32::try_from(v).map_err(|_| CodecError::corrupt(format!("header {what} {v} too large")))
    }

    fn f64(&mut self) -> Result<f64, CodecError> {
        Ok(f64::from_bits(self.varint()?.swap_bytes()))
    }

    fn bytes(&mut self, n: usize) -> Result<&[u8], CodecError> {
        let end = self
            .pos
            .checked_add(n)
            .filter(|&e| e <= self.b.len())
            .ok_or_else(|| CodecError::corrupt("header fields end early"))?;
        let v = &self.b[self.pos..end];
        self.pos = end;
        Ok(v)
    }

    fn u32_le(&mut self) -> Result<u32, CodecError> {
        Ok(u32_at(self.bytes(4)?, 0))
    }
}

/// Reads a compact header. Version-3 files written before the CRS definition (WKT) joined the
/// georeferencing fields (commit 08ba422, 2 December 2026, without a new version number) have
/// no WKT length after the geotransform: a georeferenced header that does not read with it is
/// read again without it, and only if that reads to the header's last byte is it taken.
fn read_compact(b: &[u8], version: u16, crc: u32) -> Result<HeaderFields, CodecError> {
    match read_compact_layout(b, version, crc, Wkt::Present) {
        Err(e) if version == 3 => read_compact_layout(b, version, crc, Wkt::Absent).map_err(|_| e),
        read => read,
    }
}

/// Whether a compact header's georeferencing carries the CRS definition's length (every
/// compact header but the earliest version-3 ones, [`read_compact`]).
#[derive(Clone, Copy, PartialEq, Eq)]
enum Wkt {
    Present,
    Absent,
}

fn read_compact_layout(
    b: &[u8],
    version: u16,
    crc: u32,
    wkt_layout: Wkt,
) -> Result<HeaderFields, CodecError> {
    let mut f = Fields {
        b: &b[PREFIX_LEN..b.len() - 4],
        pos: 0,
    };
    let flags = f.u32("flags")?;
    let n = f.u32("diamond size")?;
    let [
        level_pairs,
        alpha,
        coder,
        lattice,
        geo_flags,
        nodata_policy,
        vertical_unit,
    ]: [u8; 7] = f.bytes(7)?.try_into().expect("7 bytes");
    let roots_x = f.u32("root count")?;
    let roots_y = f.u32("root count")?;
    let data_width = f.u32("data width")?;
    let data_height = f.u32("data height")?;
    let quantizer_k = f.u32("quantizer")?;
    let leaf_error = f.u32("leaf error")?;
    let unit = f.f64()?;
    let offset = f.f64()?;
    let epsilon = f.f64()?;
    let representation_error = f.f64()?;
    let (epsg, geo, wkt) = parse_georef(&mut f, geo_flags, wkt_layout)?;
    let nodata = f.f64()?;
    let provenance = parse_provenance(&mut f, flags)?;
    let rms = parse_rms(&mut f, flags)?;
    let record_count = f.varint()?;
    let sections = parse_sections(&mut f, b.len() as u64)?;
    if f.pos != f.b.len() {
        return Err(CodecError::corrupt(format!(
            "{} unexpected bytes at the end of the header fields",
            f.b.len() - f.pos
        )));
    }
    Ok(HeaderFields {
        version,
        header_len: b.len(),
        flags,
        n,
        level_pairs,
        alpha,
        coder,
        lattice,
        geo_flags,
        nodata_policy,
        vertical_unit,
        roots_x,
        roots_y,
        data_width,
        data_height,
        quantizer_k,
        root_k: None,
        leaf_error,
        epsg,
        unit,
        offset,
        epsilon,
        representation_error,
        geo,
        nodata,
        wkt,
        provenance,
        rms,
        sections,
        record_count,
        crc,
    })
}

/// The georeferencing fields: written only with `geo_flags` bit 0; their absence reads as the
/// zeros the fixed layout stores, so the container checks both layouts the same way.
fn parse_georef(
    f: &mut Fields<'_>,
    geo_flags: u8,
    wkt: Wkt,
) -> Result<(u32, [f64; 4], Option<String>), CodecError> {
    if geo_flags & 1 == 0 {
        return Ok((0, [0.0; 4], None));
    }
    let epsg = f.u32("EPSG code")?;
    let geo = [f.f64()?, f.f64()?, f.f64()?, f.f64()?];
    if wkt == Wkt::Absent {
        return Ok((epsg, geo, None));
    }
    let len = f.varint()?;
    if len == 0 {
        return Ok((epsg, geo, None));
    }
    let len = usize::try_from(len)
        .ok()
        .filter(|&l| l <= crate::repository::MAX_WKT_LEN)
        .ok_or_else(|| CodecError::corrupt(format!("CRS definition of {len} bytes")))?;
    let text = std::str::from_utf8(f.bytes(len)?)
        .map_err(|_| CodecError::corrupt("CRS definition is not UTF-8"))?;
    Ok((epsg, geo, Some(text.to_owned())))
}

/// A planet's provenance (vertical datum, resampling error), with its flag only.
fn parse_provenance(
    f: &mut Fields<'_>,
    flags: u32,
) -> Result<Option<PlanetProvenance>, CodecError> {
    if flags & FLAG_PLANET_PROVENANCE == 0 {
        return Ok(None);
    }
    let datum = f.byte()?;
    let vertical_datum = VerticalDatum::from_byte(datum)
        .ok_or_else(|| CodecError::unsupported(format!("unknown vertical datum {datum}")))?;
    let (resampling_max, resampling_rms) = (f.f64()?, f.f64()?);
    if !(resampling_max >= 0.0 && resampling_rms >= 0.0 && resampling_rms <= resampling_max) {
        return Err(CodecError::corrupt(format!(
            "resampling error max {resampling_max} m, rms {resampling_rms} m"
        )));
    }
    Ok(Some(PlanetProvenance {
        vertical_datum,
        resampling_max,
        resampling_rms,
    }))
}

/// The RMS bound (target, measured), with its flag only.
fn parse_rms(f: &mut Fields<'_>, flags: u32) -> Result<Option<(f64, f64)>, CodecError> {
    if flags & FLAG_RMS_ERROR == 0 {
        return Ok(None);
    }
    let (target, measured) = (f.f64()?, f.f64()?);
    if !(target.is_finite() && target > 0.0 && measured >= 0.0 && measured <= target) {
        return Err(CodecError::corrupt(format!(
            "RMS error bound {target} m with {measured} m measured"
        )));
    }
    Ok(Some((target, measured)))
}

/// The four sections' lengths (laid out one after the other from the header's end,
/// `header_len`) and then their CRCs.
fn parse_sections(f: &mut Fields<'_>, header_len: u64) -> Result<[SectionEntry; 4], CodecError> {
    let mut sections = [SectionEntry::default(); 4];
    let mut at = header_len;
    for s in &mut sections {
        let length = f.varint()?;
        *s = SectionEntry {
            offset: at,
            length,
            crc: 0,
        };
        at = at
            .checked_add(length)
            .ok_or_else(|| CodecError::corrupt("section lengths overflow"))?;
    }
    for s in &mut sections {
        s.crc = f.u32_le()?;
    }
    Ok(sections)
}

/// Writes `h` as a compact header (version `h.version`, 3 or later). `h.header_len`, `h.crc`,
/// `h.root_k` and the section offsets are ignored: the bytes determine them. Georeferencing
/// fields are written only with `geo_flags` bit 0.
pub(crate) fn write_compact(h: &HeaderFields) -> Result<Vec<u8>, CodecError> {
    let mut out = Vec::with_capacity(HEADER_FETCH_LEN);
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&h.version.to_le_bytes());
    out.extend_from_slice(&[0, 0]); // header length, filled in below
    let varint = |out: &mut Vec<u8>, v: u64| super::index::put_varint(out, v);
    let float = |out: &mut Vec<u8>, v: f64| super::index::put_varint(out, v.to_bits().swap_bytes());
    varint(&mut out, u64::from(h.flags));
    varint(&mut out, u64::from(h.n));
    out.extend_from_slice(&[
        h.level_pairs,
        h.alpha,
        h.coder,
        h.lattice,
        h.geo_flags,
        h.nodata_policy,
        h.vertical_unit,
    ]);
    for v in [
        h.roots_x,
        h.roots_y,
        h.data_width,
        h.data_height,
        h.quantizer_k,
        h.leaf_error,
    ] {
        varint(&mut out, u64::from(v));
    }
    for v in [h.unit, h.offset, h.epsilon, h.representation_error] {
        float(&mut out, v);
    }
    if h.geo_flags & 1 == 1 {
        varint(&mut out, u64::from(h.epsg));
        for v in h.geo {
            float(&mut out, v);
        }
        let wkt = h.wkt.as_deref().unwrap_or("");
        if wkt.len() > crate::repository::MAX_WKT_LEN {
            return Err(CodecError::limit(format!(
                "a CRS definition of {} bytes (at most {} are kept)",
                wkt.len(),
                crate::repository::MAX_WKT_LEN
            )));
        }
        varint(&mut out, wkt.len() as u64);
        out.extend_from_slice(wkt.as_bytes());
    }
    float(&mut out, h.nodata);
    // The flag decides, as it does for the reader; a flag without values writes zeros.
    if h.flags & FLAG_PLANET_PROVENANCE != 0 {
        let p = h.provenance.unwrap_or(PlanetProvenance {
            vertical_datum: VerticalDatum::Unknown,
            resampling_max: 0.0,
            resampling_rms: 0.0,
        });
        out.push(p.vertical_datum.to_byte());
        float(&mut out, p.resampling_max);
        float(&mut out, p.resampling_rms);
    }
    if h.flags & FLAG_RMS_ERROR != 0 {
        let (target, measured) = h.rms.unwrap_or((0.0, 0.0));
        float(&mut out, target);
        float(&mut out, measured);
    }
    varint(&mut out, h.record_count);
    for s in &h.sections {
        varint(&mut out, s.length);
    }
    for s in &h.sections {
        out.extend_from_slice(&s.crc.to_le_bytes());
    }
    let len = out.len() + 4;
    if len > MAX_HEADER_LEN {
        return Err(CodecError::limit(format!(
            "header of {len} bytes is over {MAX_HEADER_LEN}"
        )));
    }
    out[10..12].copy_from_slice(&(len as u16).to_le_bytes());
    let crc = crc32(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    Ok(out)
}

/// Where a header keeps its checksums, for [`reseal_header`].
struct ChecksumPlaces {
    /// The section ranges the header states (`None` where one leaves the bytes).
    ranges: [Option<std::ops::Range<usize>>; 4],
    /// Offsets of the sections' CRCs.
    crc_at: [usize; 4],
    /// Offset of the header's own CRC.
    header_crc_at: usize,
}

fn checksum_places(b: &[u8]) -> Option<ChecksumPlaces> {
    let (version, hl) = read_prefix(b).ok()?;
    if !(PREFIX_LEN + 4..=MAX_HEADER_LEN).contains(&hl) || b.len() < hl {
        return None;
    }
    let (sections, crc_at) = match version {
        1 | 2 if hl == FIXED_HEADER_LEN => {
            let f = read_fixed(b, version, 0).ok()?;
            (
                f.sections,
                [0, 1, 2, 3].map(|i| SECTIONS_AT + i * SECTION_ENTRY + 16),
            )
        }
        3.. => {
            let f = read_compact(&b[..hl], version, 0).ok()?;
            (f.sections, [0, 1, 2, 3].map(|i| hl - 4 - 16 + 4 * i))
        }
        _ => return None,
    };
    let ranges = sections.map(|s| {
        let end = s.offset.checked_add(s.length)?;
        (end <= b.len() as u64).then_some(s.offset as usize..end as usize)
    });
    Some(ChecksumPlaces {
        ranges,
        crc_at,
        header_crc_at: hl - 4,
    })
}

/// Recomputes the section CRCs and then the header CRC of a repository-shaped `b`, whatever its
/// fields say, where the header's structure can be read; returns the checksum table's range.
pub(crate) fn reseal_header(b: &mut [u8]) -> Option<std::ops::Range<usize>> {
    let ChecksumPlaces {
        ranges,
        crc_at,
        header_crc_at,
    } = checksum_places(b)?;
    for (r, at) in ranges.iter().zip(crc_at) {
        if let Some(r) = r {
            let crc = crc32(&b[r.clone()]);
            b[at..at + 4].copy_from_slice(&crc.to_le_bytes());
        }
    }
    let crc = crc32(&b[..header_crc_at]);
    b[header_crc_at..header_crc_at + 4].copy_from_slice(&crc.to_le_bytes());
    ranges[2].clone()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(geo: bool) -> HeaderFields {
        HeaderFields {
            version: 3,
            header_len: 0,
            flags: 1,
            n: 65,
            level_pairs: 3,
            alpha: 0,
            coder: 1,
            lattice: 1,
            geo_flags: if geo { 3 } else { 0 },
            nodata_policy: 0,
            vertical_unit: 0,
            roots_x: 1,
            roots_y: 2,
            data_width: 400,
            data_height: 333,
            quantizer_k: 100,
            root_k: None,
            leaf_error: 57,
            epsg: if geo { 26915 } else { 0 },
            unit: 0.01,
            offset: -431.5,
            epsilon: 1.0,
            representation_error: 0.0,
            geo: if geo {
                [512_345.0, 4_900_000.5, 1.0, 1.0]
            } else {
                [0.0; 4]
            },
            nodata: f64::NAN,
            wkt: None,
            provenance: None,
            rms: None,
            sections: [
                SectionEntry {
                    offset: 0,
                    length: 453,
                    crc: 0xDEAD_BEEF,
                },
                SectionEntry {
                    offset: 0,
                    length: 81,
                    crc: 1,
                },
                SectionEntry {
                    offset: 0,
                    length: 8,
                    crc: 0,
                },
                SectionEntry {
                    offset: 0,
                    length: 7,
                    crc: u32::MAX,
                },
            ],
            record_count: 69,
            crc: 0,
        }
    }

    /// Everything the bytes carry, floats by their bits (NaN payloads and −0 included).
    fn key(h: &HeaderFields) -> String {
        let floats: Vec<u64> = [
            h.unit,
            h.offset,
            h.epsilon,
            h.representation_error,
            h.nodata,
        ]
        .into_iter()
        .chain(h.geo)
        .chain(h.rms.into_iter().flat_map(|(t, m)| [t, m]))
        .map(f64::to_bits)
        .collect();
        let lengths: Vec<(u64, u32)> = h.sections.iter().map(|s| (s.length, s.crc)).collect();
        format!(
            "{:?}",
            (
                (h.flags, h.n, h.level_pairs, h.alpha, h.coder, h.lattice),
                (h.geo_flags, h.nodata_policy, h.vertical_unit),
                (h.roots_x, h.roots_y, h.data_width, h.data_height),
                (h.quantizer_k, h.leaf_error, h.epsg, h.record_count),
                floats,
                lengths
            )
        )
    }

    #[test]
    fn compact_headers_round_trip_and_imply_the_section_offsets() {
        for geo in [false, true] {
            let h = sample(geo);
            let b = write_compact(&h).unwrap();
            let r = read_header(&b).unwrap();
            assert_eq!(key(&r), key(&h));
            assert_eq!(r.header_len, b.len());
            assert_eq!(r.root_k, None);
            // Sections follow the header without gaps.
            assert_eq!(r.sections[0].offset, b.len() as u64);
            assert_eq!(r.sections[1].offset, b.len() as u64 + 453);
            assert_eq!(r.sections[3].offset, b.len() as u64 + 453 + 81 + 8);
            // The point of version 3: well under the fixed layout's 256 bytes.
            assert!(b.len() < if geo { 110 } else { 80 }, "{} bytes", b.len());
        }
    }

    #[test]
    fn an_rms_bound_round_trips_under_flag_bit_4_and_bad_ones_are_refused() {
        let mut h = sample(false);
        let plain = write_compact(&h).unwrap();
        h.flags |= FLAG_RMS_ERROR;
        h.rms = Some((1.0, 0.8140239554214606));
        let b = write_compact(&h).unwrap();
        assert_eq!(key(&read_header(&b).unwrap()), key(&h));
        // Only the flag's two floats are added.
        assert!(b.len() > plain.len() && b.len() <= plain.len() + 2 * 10);
        for bad in [
            (1.0, 1.5),
            (0.0, 0.0),
            (-1.0, -2.0),
            (f64::INFINITY, 1.0),
            (1.0, f64::NAN),
        ] {
            h.rms = Some(bad);
            let e = read_header(&write_compact(&h).unwrap()).unwrap_err();
            assert!(e.to_string().contains("RMS error bound"), "{bad:?}: {e}");
        }
    }

    #[test]
    fn extreme_fields_round_trip_within_the_maximum_length() {
        let mut h = sample(true);
        (h.flags, h.n, h.roots_x, h.roots_y) = (u32::MAX, u32::MAX, u32::MAX, u32::MAX);
        (h.data_width, h.data_height, h.quantizer_k) = (u32::MAX, u32::MAX, u32::MAX);
        (h.leaf_error, h.epsg, h.record_count) = (u32::MAX, u32::MAX, u64::MAX);
        (h.level_pairs, h.alpha, h.coder, h.lattice) = (255, 255, 255, 255);
        (h.nodata_policy, h.vertical_unit, h.geo_flags) = (255, 255, 255);
        h.unit = f64::from_bits(u64::MAX);
        h.offset = -0.0;
        h.epsilon = f64::MIN_POSITIVE / 3.0;
        h.representation_error = f64::INFINITY;
        h.geo = [f64::MAX, f64::MIN, f64::NEG_INFINITY, f64::from_bits(1)];
        h.nodata = f64::from_bits(0x7FF8_0000_0000_0001);
        // Flag bit 4 is among the flags: the RMS bound's extremes (measured ≤ target).
        h.rms = Some((f64::MAX, f64::MIN_POSITIVE / 3.0));
        for s in &mut h.sections {
            s.length = u64::MAX / 8;
        }
        let b = write_compact(&h).unwrap();
        assert!(b.len() <= MAX_HEADER_LEN);
        assert_eq!(key(&read_header(&b).unwrap()), key(&h));
        // Lengths that add up past u64 are refused, not wrapped.
        h.sections[3].length = u64::MAX;
        let b = write_compact(&h).unwrap();
        assert!(read_header(&b).is_err());
    }

    /// A CRS definition rides in the header, past the usual first fetch when it is long; one
    /// that is not UTF-8 or over the limit is refused.
    #[test]
    fn crs_definitions_round_trip_and_bad_ones_are_refused() {
        let mut h = sample(true);
        let wkt = format!("PROJCS[\"x\",{}]", "GEOGCS[\"é\"],".repeat(200));
        h.wkt = Some(wkt.clone());
        let b = write_compact(&h).unwrap();
        assert!(b.len() > HEADER_FETCH_LEN);
        assert_eq!(header_len(&b[..HEADER_FETCH_LEN]).unwrap(), b.len());
        let r = read_header(&b).unwrap();
        assert_eq!(r.wkt.as_deref(), Some(wkt.as_str()));
        assert_eq!(key(&r), key(&h));
        assert!(read_header(&b[..HEADER_FETCH_LEN]).is_err());
        // Without georeferencing nothing is written, even if a WKT is given.
        let mut plain = sample(false);
        plain.wkt = Some(wkt);
        assert_eq!(
            read_header(&write_compact(&plain).unwrap()).unwrap().wkt,
            None
        );
        h.wkt = Some("x".repeat(crate::repository::MAX_WKT_LEN + 1));
        assert!(write_compact(&h).is_err());
        // Invalid UTF-8 in place of the definition, checksums matching.
        h.wkt = Some("PROJCS[]".to_owned());
        let mut b = write_compact(&h).unwrap();
        let at = b.windows(8).position(|w| w == b"PROJCS[]").unwrap();
        b[at] = 0xFF;
        let n = b.len();
        let crc = crc32(&b[..n - 4]);
        b[n - 4..].copy_from_slice(&crc.to_le_bytes());
        let e = read_header(&b).unwrap_err();
        assert!(e.to_string().contains("UTF-8"), "{e}");
    }

    #[test]
    fn every_truncation_and_bit_flip_of_a_compact_header_is_an_error() {
        let b = write_compact(&sample(true)).unwrap();
        for cut in 0..b.len() {
            assert!(read_header(&b[..cut]).is_err(), "cut at {cut}");
        }
        for bit in 0..b.len() * 8 {
            let mut f = b.clone();
            f[bit / 8] ^= 1 << (bit % 8);
            assert!(read_header(&f).is_err(), "bit {bit}");
        }
    }

    /// Fields re-checksummed by a hostile writer: a redundant varint byte, a field running past
    /// the CRC, an extra byte before it, a length outside the bounds.
    #[test]
    fn malformed_fields_with_valid_checksums_are_errors() {
        let good = write_compact(&sample(false)).unwrap();
        let reseal = |mut f: Vec<u8>| {
            let len = f.len() + 4;
            f[10..12].copy_from_slice(&(len as u16).to_le_bytes());
            let crc = crc32(&f);
            f.extend_from_slice(&crc.to_le_bytes());
            f
        };
        let body = &good[..good.len() - 4];
        // flags = 1 written as the two bytes 0x81 0x00.
        assert_eq!(body[12], 1);
        let mut f = body[..12].to_vec();
        f.extend_from_slice(&[0x81, 0x00]);
        f.extend_from_slice(&body[13..]);
        let e = read_header(&reseal(f)).unwrap_err();
        assert!(e.to_string().contains("redundant"), "{e}");
        // One byte too many, one too few.
        let mut f = body.to_vec();
        f.push(0);
        assert!(
            read_header(&reseal(f))
                .unwrap_err()
                .to_string()
                .contains("unexpected")
        );
        let f = body[..body.len() - 1].to_vec();
        assert!(
            read_header(&reseal(f))
                .unwrap_err()
                .to_string()
                .contains("end early")
        );
        // A stated length past the bytes there are, or too short for a CRC.
        for len in [good.len() + 1, 3] {
            let mut f = good.clone();
            f[10..12].copy_from_slice(&(len as u16).to_le_bytes());
            assert!(read_header(&f).is_err(), "length {len}");
        }
        // Not the magic.
        let mut f = good.clone();
        f[0] ^= 1;
        assert!(read_header(&f).unwrap_err().to_string().contains("magic"));
    }
}
