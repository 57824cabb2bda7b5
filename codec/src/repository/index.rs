//! The record index: which diamonds are stored, and per record its length, object-space error
//! and height range — everything a renderer needs before it fetches or decodes a record.
//!
//! Both versions hold the same information in the same order, little-endian / LEB128 varints:
//! 1. `varint(count)`, the number of stored diamonds.
//! 2. The *stored-set mask*: one bit per root in domain order; then, level by level in id
//!    order, for every stored diamond `D` below level `L − 1` and every existing child `C` of `D`
//!    whose *designated parent* is `D` (its first existing parent in [`crate::geometry::Domain::parents`] order),
//!    one bit "C is stored". Each stored diamond is named exactly once and ids cost no bytes.
//! 3. For every stored diamond in id order: its record length, its object error, and its height
//!    range `min`, `max` against a *reference*: the designated parent's range (a child's range is
//!    close to its parent's), or the previous root's for roots.
//!
//! **Version 1** ([`IndexCoding::Varint`]) packs the mask as bits (LSB first in each byte, padded
//! to a byte) and writes per entry `varint(length)`, `varint(object_error)`,
//! `zigzag_varint(min − reference min)`, `zigzag_varint(reference max − max)`: at least four
//! bytes per entry, which on smooth terrain (lidar1m_mn at 1 m: 69 entries, 13 non-empty
//! records) made the index larger than all the records together.
//!
//! **Version 2** ([`IndexCoding::Adaptive`]) codes everything after the count as one adaptive
//! range-coded stream (`entropy::adaptive::integers`: adaptive flags, Exp-Golomb integers with
//! adaptive exponent and top mantissa bits):
//! - mask bit: a flag, model by the child's level (capped at 15);
//! - "record is empty" (length 0): a flag, model by the designated parent's state (none: a root;
//!   empty; non-empty) and the level's parity;
//! - a non-empty record's `length − 1`: unsigned;
//! - `reference error − object_error`: signed, where the reference error is the designated
//!   parent's object error (the saturated errors never grow towards the leaves, so this is
//!   almost always a small non-negative number), or the previous root's for roots;
//! - `min − reference min` and `reference max − max`: signed.
//!
//! The three signed fields have separate models for empty and non-empty records. Models start
//! from even odds and adapt as in the band coder.
//!
//! Byte offsets of records are the prefix sums of the lengths in id order, so one diamond or a
//! run of consecutive ids is one contiguous byte range.

use std::collections::HashMap;

use crate::CodecError;
use crate::entropy::adaptive::integers::{FlagModel, IntDecoder, IntEncoder, IntModel, UintModel};
use crate::geometry::{DiamondId, Domain};
use crate::quant::Quantizer;

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
    /// Lower bound of its grid's vertex heights, units: the exact minimum as the encoder gives it
    /// and in version-1 files; read from a version-2 file, rounded down to a multiple of
    /// `2^range_shift` ([`range_shift_for`]).
    pub min: i32,
    /// Upper bound of its grid's vertex heights, units (like `min`, rounded up).
    pub max: i32,
}

/// How an index is coded: fixed by the repository's format version.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum IndexCoding {
    /// Format version 1: bit-packed mask and four varints per entry.
    Varint,
    /// Format version 2: one adaptive range-coded stream.
    Adaptive,
}

impl IndexCoding {
    /// The coding of a repository of format `version` (1, 2 or 3; 3 differs from 2 only in
    /// its header).
    pub fn for_format_version(version: u16) -> Result<Self, CodecError> {
        match version {
            1 => Ok(Self::Varint),
            2 | 3 => Ok(Self::Adaptive),
            _ => Err(CodecError::unsupported(format!(
                "no index coding for format version {version}"
            ))),
        }
    }
}

/// Mask-bit models: one per level up to this, the rest share the last.
const MASK_LEVELS: usize = 16;

pub(super) fn put_varint(out: &mut Vec<u8>, mut v: u64) {
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

#[cfg(test)]
fn zigzag(v: i64) -> u64 {
    ((v << 1) ^ (v >> 63)) as u64
}

fn unzigzag(v: u64) -> i64 {
    ((v >> 1) as i64) ^ -((v & 1) as i64)
}

/// The children of `d` for which `d` is the designated parent.
fn designated_children(domain: &Domain, d: DiamondId) -> impl Iterator<Item = DiamondId> + '_ {
    domain
        .children(d)
        .into_iter()
        .flatten()
        .filter(move |&c| domain.parents(c).into_iter().flatten().next() == Some(d))
}

fn designated_parent(domain: &Domain, id: DiamondId) -> Option<DiamondId> {
    domain.parents(id).into_iter().flatten().next()
}

/// The stored-set mask's bits in order, for the stored diamonds `sorted` (in id order).
fn mask_bits(domain: &Domain, sorted: &[&IndexEntry]) -> Vec<(u8, bool)> {
    let stored: std::collections::HashSet<DiamondId> = sorted.iter().map(|e| e.id).collect();
    let mut bits: Vec<(u8, bool)> = domain.roots().map(|r| (0, stored.contains(&r))).collect();
    let last_with_records = domain.finest_level().saturating_sub(1);
    for e in sorted {
        if e.id.level < last_with_records {
            bits.extend(designated_children(domain, e.id).map(|c| (c.level, stored.contains(&c))));
        }
    }
    bits
}

/// Reads the stored-set mask with `next_bit(level of the named diamond)` and returns the stored
/// ids in id order; `count` bounds them.
fn read_mask(
    domain: &Domain,
    count: u64,
    mut next_bit: impl FnMut(u8) -> Result<bool, CodecError>,
) -> Result<Vec<DiamondId>, CodecError> {
    let mut ids: Vec<DiamondId> = Vec::new();
    for r in domain.roots() {
        if next_bit(0)? {
            ids.push(r);
        }
        if ids.len() as u64 > count {
            return Err(CodecError::corrupt(
                "stored-set mask names more diamonds than the index holds",
            ));
        }
    }
    let last_with_records = domain.finest_level().saturating_sub(1);
    // Level by level: the stored diamonds of level l name those of level l + 1.
    let mut level_start = 0;
    loop {
        let level_end = ids.len();
        let mut next: Vec<DiamondId> = Vec::new();
        for &d in &ids[level_start..level_end] {
            if d.level < last_with_records {
                for c in designated_children(domain, d) {
                    if next_bit(c.level)? {
                        next.push(c);
                        if ids.len() as u64 + next.len() as u64 > count {
                            return Err(CodecError::corrupt(
                                "stored-set mask names more diamonds than the index holds",
                            ));
                        }
                    }
                }
            }
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
    Ok(ids)
}

/// What a diamond's fields are coded against: its designated parent's entry (error, range,
/// emptiness), or for roots the previous root's error and range.
#[derive(Clone, Copy)]
struct Reference {
    error: i64,
    min: i64,
    max: i64,
    /// 0: a root; 1: the designated parent's record is empty; 2: it is not.
    parent_state: usize,
}

/// What [`References`] keeps of a coded entry: object error, range (in the coding's range
/// units), emptiness.
type Known = (i64, i64, i64, bool);

/// Tracks the entries coded so far, to give each diamond its [`Reference`].
#[derive(Default)]
struct References {
    known: HashMap<DiamondId, Known>,
    prev_root: (i64, i64, i64),
}

impl References {
    /// The reference of `id`. With `both_parents` the range is the union of both parents'
    /// ranges (version 2: a diamond's two halves lie in its two parents), else the designated
    /// parent's (version 1).
    fn of(&self, domain: &Domain, id: DiamondId, both_parents: bool) -> Reference {
        match designated_parent(domain, id).and_then(|p| self.known.get(&p)) {
            Some(&(error, mut min, mut max, empty)) => {
                if both_parents {
                    for p in domain.parents(id).into_iter().flatten() {
                        if let Some(&(_, lo, hi, _)) = self.known.get(&p) {
                            (min, max) = (min.min(lo), max.max(hi));
                        }
                    }
                }
                Reference {
                    error,
                    min,
                    max,
                    parent_state: if empty { 1 } else { 2 },
                }
            }
            None => Reference {
                error: self.prev_root.0,
                min: self.prev_root.1,
                max: self.prev_root.2,
                parent_state: 0,
            },
        }
    }

    fn record(&mut self, id: DiamondId, known: Known) {
        self.known.insert(id, known);
        if id.level == 0 {
            self.prev_root = (known.0, known.1, known.2);
        }
    }
}

/// What version 1 keeps of an entry: everything exact, in units.
fn known_exact(e: &IndexEntry) -> Known {
    (
        i64::from(e.object_error),
        i64::from(e.min),
        i64::from(e.max),
        e.length == 0,
    )
}

/// The adaptive models of a version-2 index.
#[derive(Default)]
struct Models {
    mask: [FlagModel; MASK_LEVELS],
    empty: [FlagModel; 6],
    length: UintModel,
    /// `[non-empty, empty]`.
    error: [IntModel; 2],
    min: IntModel,
    max: IntModel,
}

fn empty_context(r: &Reference, id: DiamondId) -> usize {
    2 * r.parent_state + usize::from(id.level % 2)
}

/// The largest range shift a version-2 index may declare: heights are `i32`.
const MAX_RANGE_SHIFT: u32 = 30;

/// The range shift [`encode_index`] uses for a repository quantized with `quantizer`: the
/// largest power of two not above its step `2k + 1`, so the stored height bounds are looser than
/// the grid's exact range by less than one quantizer step (about 2ε) on either side — far below
/// what changes a bounding box's culling or distance, and the data is only known within ε.
/// Lossless repositories (`k = 0`) get exact ranges.
pub fn range_shift_for(quantizer: Quantizer) -> u32 {
    (2 * u64::from(quantizer.k().unsigned_abs()) + 1)
        .ilog2()
        .min(MAX_RANGE_SHIFT)
}

/// `(min, max)` rounded outward to multiples of `2^shift`, in those multiples.
fn coarse_range(min: i32, max: i32, shift: u32) -> (i64, i64) {
    let q = 1i64 << shift;
    (
        i64::from(min).div_euclid(q),
        (i64::from(max) + q - 1).div_euclid(q),
    )
}

/// Serialises the index of `entries` (the stored diamonds, any order; offsets are ignored and
/// implied by the id order) in the current coding, [`IndexCoding::Adaptive`], with height ranges
/// rounded outward to multiples of `2^range_shift` units (see [`range_shift_for`]). The stored
/// set must be closed under parents, as the encoder's is.
pub fn encode_index(domain: &Domain, entries: &[IndexEntry], range_shift: u32) -> Vec<u8> {
    let range_shift = range_shift.min(MAX_RANGE_SHIFT);
    let mut sorted: Vec<&IndexEntry> = entries.iter().collect();
    sorted.sort_by_key(|e| e.id);
    let mut out = Vec::new();
    put_varint(&mut out, sorted.len() as u64);
    put_varint(&mut out, u64::from(range_shift));
    let mut enc = IntEncoder::new();
    let mut m = Models::default();
    for (level, on) in mask_bits(domain, &sorted) {
        enc.flag(&mut m.mask[usize::from(level).min(MASK_LEVELS - 1)], on);
    }
    let mut refs = References::default();
    for e in sorted {
        let r = refs.of(domain, e.id, true);
        let empty = e.length == 0;
        enc.flag(&mut m.empty[empty_context(&r, e.id)], empty);
        if !empty {
            enc.uint(&mut m.length, u64::from(e.length) - 1);
        }
        let error = i64::from(e.object_error);
        let (min, max) = coarse_range(e.min, e.max, range_shift);
        enc.int(&mut m.error[usize::from(empty)], r.error - error);
        enc.int(&mut m.min, min - r.min);
        enc.int(&mut m.max, r.max - max);
        refs.record(e.id, (error, min, max, empty));
    }
    enc.finish(&mut out);
    out
}

/// Serialises `entries` as a version-1 (varint) index, for tests of the version-1 reading path:
/// writers only write version 2.
#[cfg(test)]
pub(crate) fn encode_index_v1(domain: &Domain, entries: &[IndexEntry]) -> Vec<u8> {
    let mut sorted: Vec<&IndexEntry> = entries.iter().collect();
    sorted.sort_by_key(|e| e.id);
    let bits = mask_bits(domain, &sorted);
    let mut out = Vec::with_capacity(bits.len() / 8 + 8 * sorted.len());
    put_varint(&mut out, sorted.len() as u64);
    for chunk in bits.chunks(8) {
        out.push(
            chunk
                .iter()
                .enumerate()
                .fold(0u8, |b, (i, &(_, on))| b | (u8::from(on) << i)),
        );
    }
    let mut refs = References::default();
    for e in sorted {
        let r = refs.of(domain, e.id, false);
        put_varint(&mut out, u64::from(e.length));
        put_varint(&mut out, u64::from(e.object_error));
        put_varint(&mut out, zigzag(i64::from(e.min) - r.min));
        put_varint(&mut out, zigzag(r.max - i64::from(e.max)));
        refs.record(e.id, known_exact(e));
    }
    out
}

/// Parses an index of the given coding; `record_area` is the size of the record area, which the
/// lengths must add up to exactly. Never panics on any bytes, and allocates in proportion to
/// `bytes.len()` (see the count bound below).
pub fn decode_index(
    domain: &Domain,
    bytes: &[u8],
    record_area: u64,
    coding: IndexCoding,
) -> Result<Vec<IndexEntry>, CodecError> {
    match coding {
        IndexCoding::Varint => decode_varint(domain, bytes, record_area),
        IndexCoding::Adaptive => decode_adaptive(domain, bytes, record_area),
    }
}

/// Checks a decoded entry's range and appends it at `offset`.
fn push_entry(
    entries: &mut Vec<IndexEntry>,
    offset: &mut u64,
    entry: (DiamondId, u64, u64, i64, i64),
) -> Result<(), CodecError> {
    let (id, length, object_error, min, max) = entry;
    let field = |v: u64, what: &str| -> Result<u32, CodecError> {
        u32::try_from(v).map_err(|_| CodecError::corrupt(format!("index {what} {v} out of range")))
    };
    let height =
        |v: i64| i32::try_from(v).map_err(|_| CodecError::corrupt("index height out of range"));
    let (length, object_error) = (
        field(length, "record length")?,
        field(object_error, "object error")?,
    );
    let (min, max) = (height(min)?, height(max)?);
    if max < min {
        return Err(CodecError::corrupt(format!("index range of {id} is empty")));
    }
    entries.push(IndexEntry {
        id,
        offset: *offset,
        length,
        object_error,
        min,
        max,
    });
    *offset += u64::from(length);
    Ok(())
}

fn check_record_area(offset: u64, record_area: u64) -> Result<(), CodecError> {
    if offset != record_area {
        return Err(CodecError::corrupt(format!(
            "record lengths add up to {offset} bytes, the record area has {record_area}"
        )));
    }
    Ok(())
}

fn decode_adaptive(
    domain: &Domain,
    bytes: &[u8],
    record_area: u64,
) -> Result<Vec<IndexEntry>, CodecError> {
    let mut pos = 0usize;
    let count = get_varint(bytes, &mut pos)?;
    // Every adaptive decision narrows the range by at least a factor 4065/4096 (the models'
    // probability bound), i.e. costs at least 0.0109 bits, and an entry takes at least four
    // decisions (empty, error, min and max), so the stream's bits — its bytes plus the four the
    // decoder may invent at the end — bound the count before anything is allocated.
    let max_count = (bytes.len() as u64 + 8) * 8 * 92 / 4;
    if count > max_count {
        return Err(CodecError::corrupt(format!(
            "index claims {count} records in {} bytes",
            bytes.len()
        )));
    }
    let range_shift = get_varint(bytes, &mut pos)?;
    if range_shift > u64::from(MAX_RANGE_SHIFT) {
        return Err(CodecError::corrupt(format!(
            "index range shift {range_shift} exceeds {MAX_RANGE_SHIFT}"
        )));
    }
    let q = 1i64 << range_shift;
    let mut dec = IntDecoder::new(&bytes[pos..])?;
    let mut m = Models::default();
    let ids = read_mask(domain, count, |level| {
        dec.flag(&mut m.mask[usize::from(level).min(MASK_LEVELS - 1)])
    })?;
    let mut entries = Vec::with_capacity(ids.len());
    let mut offset = 0u64;
    let mut refs = References::default();
    let out_of_range = || CodecError::corrupt("index number out of range");
    for id in ids {
        let r = refs.of(domain, id, true);
        let empty = dec.flag(&mut m.empty[empty_context(&r, id)])?;
        let length = if empty {
            0
        } else {
            dec.uint(&mut m.length)?
                .checked_add(1)
                .ok_or_else(out_of_range)?
        };
        let error = r
            .error
            .checked_sub(dec.int(&mut m.error[usize::from(empty)])?)
            .ok_or_else(out_of_range)?;
        let min = r
            .min
            .checked_add(dec.int(&mut m.min)?)
            .ok_or_else(out_of_range)?;
        let max = r
            .max
            .checked_sub(dec.int(&mut m.max)?)
            .ok_or_else(out_of_range)?;
        let object_error = u64::try_from(error)
            .map_err(|_| CodecError::corrupt("index object error is negative"))?;
        // In units; i32::MAX rounded up to a multiple of q is 2^31, which the bound may clamp.
        let height = |v: i64| v.checked_mul(q).ok_or_else(out_of_range);
        let (lo, hi) = (height(min)?, height(max)?.min(i64::from(i32::MAX)));
        push_entry(
            &mut entries,
            &mut offset,
            (id, length, object_error, lo, hi),
        )?;
        refs.record(id, (error, min, max, empty));
    }
    dec.finish()?;
    check_record_area(offset, record_area)?;
    Ok(entries)
}

fn decode_varint(
    domain: &Domain,
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
    let mask_start = pos;
    let mut bit = 0usize;
    let ids = read_mask(domain, count, |_| {
        let byte = *bytes
            .get(mask_start + bit / 8)
            .ok_or_else(|| CodecError::truncated("index ends inside the stored-set mask"))?;
        let on = byte >> (bit % 8) & 1 == 1;
        bit += 1;
        Ok(on)
    })?;
    pos = mask_start + bit.div_ceil(8);
    if pos > bytes.len() {
        return Err(CodecError::truncated(
            "index ends inside the stored-set mask",
        ));
    }
    let mut entries = Vec::with_capacity(ids.len());
    let mut offset = 0u64;
    let mut refs = References::default();
    for id in ids {
        let length = get_varint(bytes, &mut pos)?;
        let object_error = get_varint(bytes, &mut pos)?;
        let r = refs.of(domain, id, false);
        let out_of_range = || CodecError::corrupt("index height out of range");
        let min = r
            .min
            .checked_add(unzigzag(get_varint(bytes, &mut pos)?))
            .ok_or_else(out_of_range)?;
        let max = r
            .max
            .checked_sub(unzigzag(get_varint(bytes, &mut pos)?))
            .ok_or_else(out_of_range)?;
        push_entry(
            &mut entries,
            &mut offset,
            (id, length, object_error, min, max),
        )?;
        refs.record(id, known_exact(entries.last().expect("just pushed")));
    }
    if pos != bytes.len() {
        return Err(CodecError::corrupt("trailing bytes after the index"));
    }
    check_record_area(offset, record_area)?;
    Ok(entries)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::hierarchy::{EncodeOptions, Encoder};
    use crate::quant::{HeightGrid, Quantizer};

    fn sample() -> (Domain, Vec<IndexEntry>) {
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
        let enc = Encoder::new(
            &grid,
            Quantizer::new(1).unwrap(),
            &EncodeOptions {
                n: 9,
                ..Default::default()
            },
        )
        .encode()
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
        (enc.params.domain, entries)
    }

    /// Both codings' writers: version 2's (current; exact ranges) and version 1's (kept for its
    /// reader).
    fn both(domain: &Domain, entries: &[IndexEntry]) -> [(IndexCoding, Vec<u8>); 2] {
        [
            (IndexCoding::Adaptive, encode_index(domain, entries, 0)),
            (IndexCoding::Varint, encode_index_v1(domain, entries)),
        ]
    }

    #[test]
    fn index_round_trips_with_offsets_as_prefix_sums() {
        let (domain, entries) = sample();
        assert!(entries.len() > 20);
        for (coding, bytes) in both(&domain, &entries) {
            let area: u64 = entries.iter().map(|e| u64::from(e.length)).sum();
            let back = decode_index(&domain, &bytes, area, coding).unwrap();
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
                "{coding:?}: {} bytes for {} records",
                bytes.len(),
                entries.len()
            );
        }
    }

    #[test]
    fn the_adaptive_index_is_smaller_than_the_varint_one() {
        let (domain, entries) = sample();
        let [(_, v2), (_, v1)] = both(&domain, &entries);
        assert!(
            v2.len() * 3 < v1.len() * 2,
            "{} bytes adaptive, {} varint",
            v2.len(),
            v1.len()
        );
    }

    #[test]
    fn rounded_ranges_contain_the_exact_ones_by_less_than_a_step() {
        let (domain, entries) = sample();
        let area: u64 = entries.iter().map(|e| u64::from(e.length)).sum();
        let mut sizes = Vec::new();
        for shift in [0u32, 1, 3, 5, 30] {
            let bytes = encode_index(&domain, &entries, shift);
            sizes.push(bytes.len());
            let back = decode_index(&domain, &bytes, area, IndexCoding::Adaptive).unwrap();
            let q = 1i64 << shift;
            for (a, b) in entries.iter().zip(&back) {
                assert_eq!(
                    (a.id, a.length, a.object_error),
                    (b.id, b.length, b.object_error)
                );
                let (lo, hi) = (i64::from(b.min), i64::from(b.max));
                assert!(
                    lo <= i64::from(a.min) && i64::from(a.max) <= hi,
                    "{shift}: {a:?} {b:?}"
                );
                assert!(
                    i64::from(a.min) - lo < q && hi - i64::from(a.max) < q,
                    "{shift}"
                );
                assert!(lo % q == 0 && (hi % q == 0 || hi == i64::from(i32::MAX)));
            }
        }
        // Coarser bounds are cheaper: the point of rounding them.
        assert!(sizes[3] < sizes[0], "{sizes:?}");
    }

    #[test]
    fn range_shift_follows_the_quantizer_step() {
        let shift = |k| range_shift_for(Quantizer::new(k).unwrap());
        assert_eq!(shift(0), 0); // lossless: exact ranges
        assert_eq!(shift(1), 1); // step 3
        assert_eq!(shift(9), 4); // step 19
        assert_eq!(shift(16), 5); // step 33
    }

    #[test]
    fn extreme_fields_round_trip() {
        let (domain, mut entries) = sample();
        entries.sort_by_key(|e| e.id);
        for (k, e) in entries.iter_mut().enumerate() {
            match k % 4 {
                0 => (e.min, e.max, e.object_error) = (i32::MIN, i32::MAX, u32::MAX),
                1 => (e.min, e.max, e.object_error) = (i32::MAX, i32::MAX, 0),
                2 => (e.min, e.max) = (i32::MIN, i32::MIN),
                _ => e.length = u32::MAX,
            }
        }
        let rounded = encode_index(&domain, &entries, MAX_RANGE_SHIFT);
        let area: u64 = entries.iter().map(|e| u64::from(e.length)).sum();
        let back = decode_index(&domain, &rounded, area, IndexCoding::Adaptive).unwrap();
        for (a, b) in entries.iter().zip(&back) {
            assert!(b.min <= a.min && a.max <= b.max, "{a:?} {b:?}");
        }
        for (coding, bytes) in both(&domain, &entries) {
            let back = decode_index(&domain, &bytes, area, coding).unwrap();
            let fields = |e: &IndexEntry| (e.id, e.length, e.object_error, e.min, e.max);
            assert_eq!(
                back.iter().map(fields).collect::<Vec<_>>(),
                entries.iter().map(fields).collect::<Vec<_>>(),
                "{coding:?}"
            );
        }
    }

    #[test]
    fn damaged_indexes_are_errors_not_panics() {
        let (domain, entries) = sample();
        for (coding, bytes) in both(&domain, &entries) {
            let area: u64 = entries.iter().map(|e| u64::from(e.length)).sum();
            assert!(decode_index(&domain, &bytes, area + 1, coding).is_err());
            for cut in 0..bytes.len() {
                let got = decode_index(&domain, &bytes[..cut], area, coding);
                // Version 1 notices every truncation. A range-coded stream has no end marker
                // (past the end the decoder reads zeros), so a lost final byte can decode to
                // slightly different last fields: like the records, the version-2 index relies on
                // its CRC (checked by the container) for integrity, and here only must not panic.
                assert!(
                    coding == IndexCoding::Adaptive || got.is_err(),
                    "{coding:?}: truncated at {cut}"
                );
            }
            // Appended bytes: the range decoder reads up to four zero bytes past the end that
            // the encoder dropped, so bytes appended there can go unnoticed in version 2 (as in
            // records); the CRC catches them.
            for tail in [[0u8].as_slice(), &[1], &[0, 0, 0, 0, 0, 7]] {
                let mut extra = bytes.clone();
                extra.extend_from_slice(tail);
                let got = decode_index(&domain, &extra, area, coding);
                assert!(coding == IndexCoding::Adaptive || got.is_err(), "{tail:?}");
            }
            for i in 0..bytes.len() * 8 {
                let mut b = bytes.clone();
                b[i / 8] ^= 1 << (i % 8);
                let _ = decode_index(&domain, &b, area, coding);
            }
            for seed in 0..2000u64 {
                let junk = crate::test_junk(seed, seed % 64);
                let _ = decode_index(&domain, &junk, area, coding);
            }
        }
    }
}
