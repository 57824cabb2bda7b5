//! The fixed 256-byte header of format versions 1 and 2, read.

use crate::CodecError;

use super::{
    FIXED_CRC_AT, FIXED_HEADER_LEN, HeaderFields, NODATA_AT, RECORD_COUNT_AT, SECTION_ENTRY,
    SECTIONS_AT, SectionEntry, f64_at, u16_at, u32_at, u64_at,
};

/// Reads a fixed header (`b` at least 256 bytes, its length and CRC checked).
pub(super) fn read_fixed(b: &[u8], version: u16, crc: u32) -> Result<HeaderFields, CodecError> {
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
        level_ks: None,
        sections,
        record_count: u64_at(b, RECORD_COUNT_AT),
        crc,
    })
}
