//! The record index: which diamonds are stored, and per record its length, object-space error
//! and height range — everything a renderer needs before it fetches or decodes a record.
//!
//! Layout (all integers little-endian / LEB128 varints):
//! 1. *Stored-set mask*, a bit string (LSB first in each byte, padded to a byte): one bit per
//!    root in layout order; then, level by level in id order, for every stored diamond `D` below
//!    level `L − 1` and every existing child `C` of `D` whose *designated parent* is `D` (its
//!    first existing parent in [`Layout::parents`] order), one bit "C is stored". Each stored
//!    diamond is named exactly once and ids cost no bytes.
//! 2. For every stored diamond in id order: `varint(length)`, `varint(object_error)`,
//!    `zigzag_varint(min − reference min)`, `zigzag_varint(reference max − max)`, where the
//!    reference is the designated parent's range (a child's range is close to its parent's), or
//!    the previous root's for roots.
//!
//! Byte offsets of records are the prefix sums of the lengths in id order, so one diamond or a
//! run of consecutive ids is one contiguous byte range.

use crate::CodecError;
use crate::geometry::{DiamondId, Layout};

/// What the index says about one stored diamond.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct IndexEntry {
    /// The diamond.
    pub id: DiamondId,
    /// Offset of its record from the start of the record area, bytes.
    pub offset: u64,
    /// Length of its record, bytes.
    pub length: u32,
    /// Saturated object-space error, integer units.
    pub object_error: u32,
    /// Smallest vertex height of its grid, units.
    pub min: i32,
    /// Largest vertex height of its grid, units.
    pub max: i32,
}

fn put_varint(out: &mut Vec<u8>, mut v: u64) {
    while v >= 0x80 {
        out.push((v as u8) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

fn get_varint(bytes: &[u8], pos: &mut usize) -> Result<u64, CodecError> {
    let mut v = 0u64;
    for shift in (0..64).step_by(7) {
        let b = *bytes
            .get(*pos)
            .ok_or_else(|| CodecError::truncated("index ends inside a number"))?;
        *pos += 1;
        v |= u64::from(b & 0x7f) << shift;
        if b & 0x80 == 0 {
            if shift == 63 && b > 1 {
                break;
            }
            return Ok(v);
        }
    }
    Err(CodecError::corrupt("index number longer than 64 bits"))
}

fn zigzag(v: i64) -> u64 {
    ((v << 1) ^ (v >> 63)) as u64
}

fn unzigzag(v: u64) -> i64 {
    ((v >> 1) as i64) ^ -((v & 1) as i64)
}

/// The children of `d` for which `d` is the designated parent.
fn designated_children(layout: &Layout, d: DiamondId) -> impl Iterator<Item = DiamondId> + '_ {
    layout
        .children(d)
        .into_iter()
        .flatten()
        .filter(move |&c| layout.parents(c).into_iter().flatten().next() == Some(d))
}

/// Serialises the index of `entries` (the stored diamonds, any order; offsets are ignored and
/// implied by the id order). The stored set must be closed under parents, as the encoder's is.
pub fn encode_index(layout: &Layout, entries: &[IndexEntry]) -> Vec<u8> {
    let mut sorted: Vec<&IndexEntry> = entries.iter().collect();
    sorted.sort_by_key(|e| e.id);
    let stored: std::collections::HashSet<DiamondId> = sorted.iter().map(|e| e.id).collect();
    let mut bits: Vec<bool> = layout.roots().map(|r| stored.contains(&r)).collect();
    let last_with_records = layout.finest_level().saturating_sub(1);
    for e in &sorted {
        if e.id.level < last_with_records {
            bits.extend(designated_children(layout, e.id).map(|c| stored.contains(&c)));
        }
    }
    let mut out = Vec::with_capacity(bits.len() / 8 + 8 * sorted.len());
    put_varint(&mut out, sorted.len() as u64);
    for chunk in bits.chunks(8) {
        out.push(
            chunk
                .iter()
                .enumerate()
                .fold(0u8, |b, (i, &on)| b | (u8::from(on) << i)),
        );
    }
    let mut ranges: std::collections::HashMap<DiamondId, (i64, i64)> =
        std::collections::HashMap::new();
    let mut prev_root = (0i64, 0i64);
    for e in sorted {
        let (min, max) = (i64::from(e.min), i64::from(e.max));
        let reference = reference_range(layout, e.id, &ranges, prev_root);
        put_varint(&mut out, u64::from(e.length));
        put_varint(&mut out, u64::from(e.object_error));
        put_varint(&mut out, zigzag(min - reference.0));
        put_varint(&mut out, zigzag(reference.1 - max));
        ranges.insert(e.id, (min, max));
        if e.id.level == 0 {
            prev_root = (min, max);
        }
    }
    out
}

/// The height range a diamond's range is coded against: its designated parent's, or the
/// previous root's for roots.
fn reference_range(
    layout: &Layout,
    id: DiamondId,
    ranges: &std::collections::HashMap<DiamondId, (i64, i64)>,
    prev_root: (i64, i64),
) -> (i64, i64) {
    layout
        .parents(id)
        .into_iter()
        .flatten()
        .next()
        .and_then(|p| ranges.get(&p).copied())
        .unwrap_or(prev_root)
}

/// Parses an index written by [`encode_index`]; `record_area` is the size of the record area,
/// which the lengths must add up to exactly. Never panics on any bytes.
pub fn decode_index(
    layout: &Layout,
    bytes: &[u8],
    record_area: u64,
) -> Result<Vec<IndexEntry>, CodecError> {
    let mut pos = 0usize;
    let count = get_varint(bytes, &mut pos)?;
    // Every record costs at least 4 bytes of entry, which bounds the count before allocating.
    if count > (bytes.len() as u64) / 4 {
        return Err(CodecError::corrupt(format!(
            "index claims {count} records in {} bytes",
            bytes.len()
        )));
    }
    let mut bit = 0usize;
    let mask_start = pos;
    let mut next_bit = |bytes: &[u8]| -> Result<bool, CodecError> {
        let byte = *bytes
            .get(mask_start + bit / 8)
            .ok_or_else(|| CodecError::truncated("index ends inside the stored-set mask"))?;
        let on = byte >> (bit % 8) & 1 == 1;
        bit += 1;
        Ok(on)
    };
    let mut ids: Vec<DiamondId> = Vec::new();
    for r in layout.roots() {
        if next_bit(bytes)? {
            ids.push(r);
        }
    }
    let last_with_records = layout.finest_level().saturating_sub(1);
    // Level by level: the stored diamonds of level l name those of level l + 1.
    let mut level_start = 0;
    loop {
        let level_end = ids.len();
        let mut next: Vec<DiamondId> = Vec::new();
        for &d in &ids[level_start..level_end] {
            if d.level < last_with_records {
                for c in designated_children(layout, d) {
                    if next_bit(bytes)? {
                        next.push(c);
                    }
                }
            }
        }
        if ids.len() as u64 + next.len() as u64 > count {
            return Err(CodecError::corrupt(
                "stored-set mask names more diamonds than the index holds",
            ));
        }
        if next.is_empty() {
            break;
        }
        next.sort();
        level_start = level_end;
        ids.extend(next);
    }
    if ids.len() as u64 != count {
        return Err(CodecError::corrupt(format!(
            "stored-set mask names {} diamonds, the index holds {count}",
            ids.len()
        )));
    }
    pos = mask_start + bit.div_ceil(8);
    if pos > bytes.len() {
        return Err(CodecError::truncated(
            "index ends inside the stored-set mask",
        ));
    }
    let mut entries = Vec::with_capacity(ids.len());
    let mut offset = 0u64;
    let mut ranges: std::collections::HashMap<DiamondId, (i64, i64)> =
        std::collections::HashMap::new();
    let mut prev_root = (0i64, 0i64);
    let field = |v: u64, what: &str| -> Result<u32, CodecError> {
        u32::try_from(v).map_err(|_| CodecError::corrupt(format!("index {what} {v} out of range")))
    };
    for id in ids {
        let length = field(get_varint(bytes, &mut pos)?, "record length")?;
        let object_error = field(get_varint(bytes, &mut pos)?, "object error")?;
        let reference = reference_range(layout, id, &ranges, prev_root);
        let out_of_range = || CodecError::corrupt("index height out of range");
        let min = reference
            .0
            .checked_add(unzigzag(get_varint(bytes, &mut pos)?))
            .and_then(|m| i32::try_from(m).ok())
            .ok_or_else(out_of_range)?;
        let max = reference
            .1
            .checked_sub(unzigzag(get_varint(bytes, &mut pos)?))
            .and_then(|m| i32::try_from(m).ok())
            .ok_or_else(out_of_range)?;
        if max < min {
            return Err(CodecError::corrupt(format!("index range of {id} is empty")));
        }
        ranges.insert(id, (i64::from(min), i64::from(max)));
        if id.level == 0 {
            prev_root = (i64::from(min), i64::from(max));
        }
        entries.push(IndexEntry {
            id,
            offset,
            length,
            object_error,
            min,
            max,
        });
        offset += u64::from(length);
    }
    if pos != bytes.len() {
        return Err(CodecError::corrupt("trailing bytes after the index"));
    }
    if offset != record_area {
        return Err(CodecError::corrupt(format!(
            "record lengths add up to {offset} bytes, the record area has {record_area}"
        )));
    }
    Ok(entries)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::hierarchy::{EncodeOptions, encode};
    use crate::quant::{HeightGrid, Quantizer};

    fn sample() -> (Layout, Vec<IndexEntry>) {
        // An L-shaped valid region so the stored set is irregular.
        let (w, h) = (70, 50);
        let mut grid = HeightGrid::all_valid(
            w,
            h,
            (0..w * h).map(|k| ((k * 37) % 101) as i32 - 50).collect(),
        );
        for y in 0..h {
            for x in 0..w {
                if x > 30 && y > 20 {
                    grid.valid[y * w + x] = false;
                }
            }
        }
        let enc = encode(
            &grid,
            Quantizer::new(1).unwrap(),
            &EncodeOptions {
                n: 9,
                ..Default::default()
            },
        )
        .unwrap();
        let entries = enc
            .records
            .iter()
            .map(|r| IndexEntry {
                id: r.id,
                offset: 0,
                length: r.bytes.len() as u32,
                object_error: r.object_error,
                min: r.min,
                max: r.max,
            })
            .collect();
        (enc.params.layout, entries)
    }

    #[test]
    fn index_round_trips_with_offsets_as_prefix_sums() {
        let (layout, entries) = sample();
        assert!(entries.len() > 20);
        let bytes = encode_index(&layout, &entries);
        let area: u64 = entries.iter().map(|e| u64::from(e.length)).sum();
        let back = decode_index(&layout, &bytes, area).unwrap();
        let mut offset = 0;
        for (a, b) in entries.iter().zip(&back) {
            assert_eq!(
                (a.id, a.length, a.object_error, a.min, a.max),
                (b.id, b.length, b.object_error, b.min, b.max)
            );
            assert_eq!(b.offset, offset);
            offset += u64::from(b.length);
        }
        assert_eq!(back.len(), entries.len());
        // A few bytes per record: the point of a compact index.
        assert!(
            bytes.len() < 8 * entries.len(),
            "{} bytes for {} records",
            bytes.len(),
            entries.len()
        );
    }

    #[test]
    fn damaged_indexes_are_errors_not_panics() {
        let (layout, entries) = sample();
        let bytes = encode_index(&layout, &entries);
        let area: u64 = entries.iter().map(|e| u64::from(e.length)).sum();
        assert!(decode_index(&layout, &bytes, area + 1).is_err());
        for cut in 0..bytes.len() {
            assert!(
                decode_index(&layout, &bytes[..cut], area).is_err(),
                "truncated at {cut}"
            );
        }
        let mut extra = bytes.clone();
        extra.push(0);
        assert!(decode_index(&layout, &extra, area).is_err());
        for i in 0..bytes.len() * 8 {
            let mut b = bytes.clone();
            b[i / 8] ^= 1 << (i % 8);
            let _ = decode_index(&layout, &b, area);
        }
        for seed in 0..2000u64 {
            let junk: Vec<u8> = (0..(seed % 64))
                .map(|k| {
                    (seed
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(k.wrapping_mul(1442695040888963407))
                        >> 33) as u8
                })
                .collect();
            let _ = decode_index(&layout, &junk, area);
        }
    }
}
