//! The nodata mask: which lattice points had data in the input.
//!
//! Validity is a fixed function of lattice position (the lattice unit is the input grid), so the
//! mask of a record can never contradict another record's at a point both state. A record states
//! the validity of the level-`l+1` points of its diamond's square — the points of its
//! `(2N−1)²` half-step grid with both coordinates of equal parity (vertices and cell centres) —
//! which are exactly the points of the half-patches a renderer makes from it; the root field
//! states its own points. Points outside the data rectangle, and the edge midpoints of the
//! half-step grid, are "don't care": the encoder picks whatever codes cheapest, and readers never
//! use them.
//!
//! Coding (`docs/FORMAT.md`): a region quadtree over a `W × H` bitmap, bits most significant
//! first. The root covers the smallest power-of-two square holding the bitmap; nodes wholly
//! outside the bitmap are skipped by both sides. A node of side > 1 is `1 v` (every point of it
//! is `v`, 1 = valid) or `0` followed by its four quadrants in raster order (north-west,
//! north-east, south-west, south-east); a node of side 1 is just `v`. The last byte is padded
//! with zero bits. A bitmap whose cared points are all valid costs 2 bits (one byte).

use super::CodecParams;
use crate::CodecError;
use crate::geometry::DiamondId;

/// Side of the smallest power-of-two square holding a `w × h` bitmap.
fn root_side(w: usize, h: usize) -> usize {
    w.max(h).max(1).next_power_of_two()
}

/// What the points of a quadtree node that the encoder cares about hold.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Content {
    None,
    Valid,
    Invalid,
    Mixed,
}

impl Content {
    fn join(self, other: Content) -> Content {
        match (self, other) {
            (Content::None, o) | (o, Content::None) => o,
            (a, b) if a == b => a,
            _ => Content::Mixed,
        }
    }
}

struct BitWriter<'a> {
    out: &'a mut Vec<u8>,
    used: u32,
}

impl BitWriter<'_> {
    fn bit(&mut self, b: bool) {
        if self.used.is_multiple_of(8) {
            self.out.push(0);
        }
        if b {
            *self.out.last_mut().expect("a byte was pushed") |= 0x80 >> (self.used % 8);
        }
        self.used += 1;
    }
}

/// Appends the quadtree of a `w × h` bitmap to `out`. `point(x, y)` is `Some(valid)` where the
/// encoder cares and `None` where it does not (don't-care nodes are coded as valid).
pub fn encode_mask(
    w: usize,
    h: usize,
    point: &dyn Fn(usize, usize) -> Option<bool>,
    out: &mut Vec<u8>,
) {
    // The content of every node, bottom-up, so coding is one top-down pass: level `s` holds the
    // nodes of side `2^s`.
    let side = root_side(w, h);
    let mut levels: Vec<Vec<Content>> = Vec::new();
    let mut cur: Vec<Content> = (0..side * side)
        .map(|k| {
            let (x, y) = (k % side, k / side);
            if x >= w || y >= h {
                return Content::None;
            }
            match point(x, y) {
                None => Content::None,
                Some(true) => Content::Valid,
                Some(false) => Content::Invalid,
            }
        })
        .collect();
    let mut s = side;
    loop {
        levels.push(cur);
        if s == 1 {
            break;
        }
        let prev = levels.last().expect("just pushed");
        let half = s / 2;
        cur = (0..half * half)
            .map(|k| {
                let (x, y) = (2 * (k % half), 2 * (k / half));
                prev[y * s + x]
                    .join(prev[y * s + x + 1])
                    .join(prev[(y + 1) * s + x])
                    .join(prev[(y + 1) * s + x + 1])
            })
            .collect();
        s = half;
    }
    levels.reverse();
    let mut bits = BitWriter { out, used: 0 };
    encode_node(&levels, 0, 0, 0, side, w, h, &mut bits);
}

#[allow(clippy::too_many_arguments)]
fn encode_node(
    levels: &[Vec<Content>],
    depth: usize,
    nx: usize,
    ny: usize,
    size: usize,
    w: usize,
    h: usize,
    bits: &mut BitWriter<'_>,
) {
    if nx * size >= w || ny * size >= h {
        return;
    }
    let per_row = 1usize << depth;
    let c = levels[depth][ny * per_row + nx];
    if size == 1 {
        bits.bit(c != Content::Invalid);
        return;
    }
    if c != Content::Mixed {
        bits.bit(true);
        bits.bit(c != Content::Invalid);
        return;
    }
    bits.bit(false);
    for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
        encode_node(
            levels,
            depth + 1,
            2 * nx + dx,
            2 * ny + dy,
            size / 2,
            w,
            h,
            bits,
        );
    }
}

struct BitReader<'a> {
    bytes: &'a [u8],
    used: usize,
}

impl BitReader<'_> {
    fn bit(&mut self) -> Result<bool, CodecError> {
        let byte = self
            .bytes
            .get(self.used / 8)
            .ok_or_else(|| CodecError::corrupt("nodata mask runs past the end of its bytes"))?;
        let b = byte & (0x80 >> (self.used % 8)) != 0;
        self.used += 1;
        Ok(b)
    }
}

/// Decodes a `w × h` bitmap written by [`encode_mask`] from the start of `bytes`. Returns the
/// bitmap (row-major, `true` = valid) and the number of bytes it took. Never panics: running out
/// of bytes is [`CodecError::Corrupt`], and a quadtree cannot code more nodes than the bitmap has.
pub fn decode_mask(w: usize, h: usize, bytes: &[u8]) -> Result<(Vec<bool>, usize), CodecError> {
    let mut out = vec![false; w * h];
    let mut bits = BitReader { bytes, used: 0 };
    // Explicit stack: the depth is only log2 of the side, but an iterative walk needs no
    // recursion limit argument at all.
    let mut stack = vec![(0usize, 0usize, root_side(w, h))];
    while let Some((x0, y0, size)) = stack.pop() {
        if x0 >= w || y0 >= h {
            continue;
        }
        let uniform = size == 1 || bits.bit()?;
        if uniform {
            let v = bits.bit()?;
            for y in y0..(y0 + size).min(h) {
                out[y * w + x0..y * w + (x0 + size).min(w)].fill(v);
            }
            continue;
        }
        let half = size / 2;
        // Pushed in reverse so they pop in raster order.
        for (dx, dy) in [(1, 1), (0, 1), (1, 0), (0, 0)] {
            stack.push((x0 + dx * half, y0 + dy * half, half));
        }
    }
    Ok((out, bits.used.div_ceil(8)))
}

/// The number of samples of the data rectangle that had data, from the masks alone (no residual
/// is decoded): every lattice point is either a root-field point or the cell centre of exactly
/// one diamond's square at the level where it first appears, so the valid root points plus the
/// valid cell centres of all records count every valid sample once; points in diamonds that are
/// not stored had no data. `records` are the stored diamonds' ids and bytes. On a cube-sphere
/// the samples are the surface's distinct lattice points (`6·S² + 2` without nodata): a root
/// point shared by several faces counts on its owner's face only, and the cell centres of a
/// diamond centred on a cube edge count on whichever face they lie.
pub fn count_valid_samples<'a>(
    params: &CodecParams,
    root_bytes: &[u8],
    records: impl IntoIterator<Item = (DiamondId, &'a [u8])>,
) -> Result<u64, CodecError> {
    let domain = &params.domain;
    let layout = domain.layout();
    let cube = domain.cube();
    if !params.nodata_mask {
        return Ok(domain.lattice_points());
    }
    // A point of `face`'s frame (possibly past an edge) that holds a sample, counted once.
    let counts = |face: u8, x: i64, y: i64, root: bool| match cube {
        // Root points are listed on every face holding them; cell centres once.
        Some(_) => domain
            .canonical_point(face, x, y)
            .is_some_and(|c| !root || c == crate::geometry::FacePoint::new(face, x, y)),
        None => domain.holds_data(face, x, y),
    };
    let rf = domain.root_field();
    let (rw, rh, s) = (rf.width, rf.height, rf.spacing);
    let (roots, _) = decode_mask(rw, rh * usize::from(domain.faces()), root_bytes)?;
    let mut count = 0u64;
    for (k, &v) in roots.iter().enumerate() {
        let (face, k) = ((k / rf.points()) as u8, k % rf.points());
        let (x, y) = ((k % rw) as i64 * s, (k / rw) as i64 * s);
        count += u64::from(v && counts(face, x, y, true));
    }
    let n = layout.n();
    let side = 2 * n - 1;
    for (id, bytes) in records {
        if id.level >= layout.finest_level() || !domain.contains(id) {
            return Err(CodecError::corrupt(format!(
                "record for impossible diamond {id}"
            )));
        }
        let mask = if bytes.is_empty() {
            None
        } else {
            Some(decode_mask(side, side, bytes)?.0)
        };
        let g = layout.grid(id);
        for b in (1..side).step_by(2) {
            for a in (1..side).step_by(2) {
                let (x2, y2) = g.point2(a as i64, b as i64);
                let valid = mask.as_ref().is_none_or(|m| m[b * side + a]);
                count += u64::from(valid && counts(id.face, x2 / 2, y2 / 2, false));
            }
        }
    }
    Ok(count)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn round_trip(w: usize, h: usize, mask: &[bool]) -> usize {
        let mut bytes = vec![];
        encode_mask(w, h, &|x, y| Some(mask[y * w + x]), &mut bytes);
        let (back, used) = decode_mask(w, h, &bytes).unwrap();
        assert_eq!(back, mask, "{w}×{h}");
        assert_eq!(used, bytes.len());
        bytes.len()
    }

    #[test]
    fn uniform_bitmaps_cost_one_byte() {
        for (w, h) in [(1, 1), (129, 129), (33, 7), (1, 300)] {
            assert_eq!(round_trip(w, h, &vec![true; w * h]), 1);
            assert_eq!(round_trip(w, h, &vec![false; w * h]), 1);
        }
    }

    #[test]
    fn adversarial_patterns_round_trip() {
        let (w, h) = (129, 129);
        let checker: Vec<bool> = (0..w * h).map(|k| (k % w + k / w) % 2 == 0).collect();
        let n = round_trip(w, h, &checker);
        // A checkerboard is the worst case: about one bit per point plus the inner nodes.
        assert!(n <= (w * h) * 2 / 8 + 16, "{n}");
        let mut single = vec![true; w * h];
        single[64 * w + 77] = false;
        assert!(round_trip(w, h, &single) < 12);
        let mut border = vec![true; w * h];
        for k in 0..w {
            border[k] = false;
            border[k * w + w - 1] = false;
        }
        round_trip(w, h, &border);
    }

    #[test]
    fn dont_care_points_take_the_cheapest_code() {
        let (w, h) = (64, 64);
        let mut bytes = vec![];
        // Invalid where cared, and the don't-care half would be valid: still one uniform node.
        encode_mask(w, h, &|x, _| (x < 32).then_some(false), &mut bytes);
        assert_eq!(bytes.len(), 1);
        let (back, _) = decode_mask(w, h, &bytes).unwrap();
        assert!(back[..32].iter().all(|v| !v));
    }

    #[test]
    fn truncated_masks_are_errors() {
        let (w, h) = (17, 17);
        let mask: Vec<bool> = (0..w * h).map(|k| k % 3 == 0).collect();
        let mut bytes = vec![];
        encode_mask(w, h, &|x, y| Some(mask[y * w + x]), &mut bytes);
        for cut in 0..bytes.len() {
            assert!(decode_mask(w, h, &bytes[..cut]).is_err(), "cut at {cut}");
        }
    }

    proptest! {
        #[test]
        fn random_bitmaps_round_trip(w in 1usize..70, h in 1usize..70, seed in any::<u64>(), density in 0u32..4) {
            let mut s = seed | 1;
            let mask: Vec<bool> = (0..w * h).map(|_| {
                s ^= s << 13; s ^= s >> 7; s ^= s << 17;
                (s % 4) as u32 >= density
            }).collect();
            round_trip(w, h, &mask);
        }

        #[test]
        fn any_bytes_decode_or_fail_cleanly(w in 0usize..80, h in 0usize..80, bytes in proptest::collection::vec(any::<u8>(), 0..64)) {
            if let Ok((m, used)) = decode_mask(w, h, &bytes) {
                prop_assert_eq!(m.len(), w * h);
                prop_assert!(used <= bytes.len());
            }
        }
    }
}
