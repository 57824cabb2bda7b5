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

mod compact;
mod fixed;
mod reseal;

use compact::read_compact;
pub(crate) use compact::write_compact;
use fixed::read_fixed;
pub(crate) use reseal::reseal_header;

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

/// Header flag bit 5 (only with bit 4): a quantizer per level, after the RMS bound: a varint
/// count, one per level of records (`2K`), and each level's `k` as a varint, level 0 first; the
/// header's `k` is their largest ([`crate::quant::LevelQuantizers`], `docs/FORMAT.md`). Written
/// only by `--rms-error` builds that chose unequal steps; every other file leaves it clear.
pub const FLAG_LEVEL_QUANTIZERS: u32 = 32;

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
    /// Each level's quantizer `k`, level 0 first (version 3, with flag bit 5 only).
    pub level_ks: Option<Vec<u32>>,
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

#[cfg(test)]
mod tests;
