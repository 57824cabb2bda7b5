//! Resealing a header: its checksums recomputed over whatever the bytes say (for crafted and
//! fuzzed repositories).

use super::compact::read_compact;
use super::fixed::read_fixed;
use super::{
    FIXED_HEADER_LEN, MAX_HEADER_LEN, PREFIX_LEN, SECTION_ENTRY, SECTIONS_AT, crc32, read_prefix,
};

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
