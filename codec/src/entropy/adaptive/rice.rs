//! The Rice coder ([`CoderKind::FastRice`](crate::entropy::CoderKind::FastRice)): the token
//! coder's zero-block quadtree and neighbourhood classes, but no arithmetic coding at all, so
//! that a coefficient's decode is a short chain of shifts.
//!
//! Each coefficient `v` is mapped to `u = 2|v| − [v < 0]` (zig-zag) and written as a
//! Golomb–Rice code with parameter `k`: `q = u >> k` zero bits, a one bit, then the low `k` bits
//! of `u`. `k` comes from a per-band table indexed by the class of the neighbourhood sum
//! `s = 2|L| + 2|T| + |TL| + |TR|` (the token coder's 16 classes below `s = 64`, then one
//! per octave: [`RICE_CLASSES`] in all). The encoder picks each class's `k` to minimise the
//! band's bits and stores the table; the decoder never adapts anything. A decoder reads the
//! unary part with one count-leading-zeros on a 64-bit buffer and the whole code with one
//! refill, shift and mask ([`BitReader`]). A quotient of [`ESCAPE`] or more is written as
//! [`ESCAPE`] zeros, a one and `u` in 31 raw bits.
//!
//! Zero blocks: the quadtree over 4×4 leaf blocks of [`super::code_node`], one raw bit per
//! node (the last child of a non-zero node is inferred, as in the other coders). A band whose
//! tree would cost more bits than its zero blocks' samples would as Rice codes (each at least
//! one bit) is marked *dense* and codes every coefficient instead.
//!
//! Two streams, A and B: A holds each band's header (dense bit, quadtree, `k` table) and the
//! coefficients of its even rows, B those of its odd rows. A decoder runs the two rows of a pair
//! side by side, the odd row one 4×4 block behind (its top-right neighbour must be known),
//! so two dependency chains — each through its own bit reader — overlap in the CPU.
//!
//! Record: empty when every band is zero; otherwise the LEB128 length of stream A, stream A
//! (MSB-first, zero-padded to a byte), then stream B, likewise padded. Per band with samples:
//! the dense bit; if not dense, the quadtree (its root is "anything non-zero"; a zero band
//! ends there); then the `k` table: the first class's `k` in 5 bits and each next one as a
//! change, `0` same, `10` one more, `110` one less, `111` and 5 bits otherwise; then the
//! coefficients of the coded leaf blocks in raster order, even rows in A and odd rows in B.

use super::range_coder::Prob;
use super::tokens::put_len;
use super::{B, BinCoder, MAG_SAT, NODE_LEVELS, Scratch, all_zero_checked, code_node};
use crate::CodecError;
use crate::entropy::Band;
use crate::entropy::bitio::{BitReader, BitWriter};

#[path = "rice_decode.rs"]
mod decode;
#[cfg(test)]
#[path = "rice_tests.rs"]
mod tests;

pub(crate) use decode::decode_bands;

/// Neighbourhood classes: the token coder's 11 below `s = 64`, then one per octave up to the
/// largest sum (`6 · MAG_SAT < 2^19`).
pub(super) const RICE_CLASSES: usize = 24;
/// Largest Rice parameter; a code is then at most `ESCAPE + 1 + MAX_K` = 48 bits, within one
/// refill of the reader.
pub(super) const MAX_K: u32 = 23;
/// Quotients from this on are escaped: `ESCAPE` zeros, a one, `u` in [`ESCAPE_BITS`] bits.
pub(super) const ESCAPE: u32 = 24;
/// Width of an escaped `u`: `|v| < 2^30`, so `u < 2^31`.
pub(super) const ESCAPE_BITS: u32 = 31;
/// Width of an absolute `k` in the table.
const K_BITS: u32 = 5;

/// Classes of sums below 64, as in the token coder ([`super::class_of`]).
const SMALL_CLASS: [u8; 64] = {
    let bounds = [0usize, 1, 2, 4, 6, 9, 13, 19, 27, 39, 63];
    let mut lut = [0u8; 64];
    let (mut s, mut c) = (0, 0);
    while s < 64 {
        while s > bounds[c] {
            c += 1;
        }
        lut[s] = c as u8;
        s += 1;
    }
    lut
};

/// Class of neighbourhood sum `s` (`< 2^19`): a table below 64, `⌊log2 s⌋ + 5` above.
#[inline(always)]
pub(super) fn rice_class(s: u32) -> usize {
    let small = SMALL_CLASS[s.min(63) as usize] as usize;
    let large = ((s | 1).ilog2() + 5) as usize;
    let c = if s < 64 { small } else { large };
    c.min(RICE_CLASSES - 1)
}

/// A band's `k` table spread over the neighbourhood sums, so that a decoder finds `k` with
/// one load whichever the sum: `small[s]` for `s < 64`, `large[⌊log2 s⌋]` above.
pub(super) struct KBySum {
    small: [u8; 64],
    large: [u8; 32],
}

impl KBySum {
    pub(super) fn new(ks: &[u32; RICE_CLASSES]) -> Self {
        let mut t = KBySum {
            small: [0; 64],
            large: [0; 32],
        };
        for (s, k) in t.small.iter_mut().enumerate() {
            *k = ks[rice_class(s as u32)] as u8;
        }
        for (l, k) in t.large.iter_mut().enumerate() {
            *k = ks[(l + 5).min(RICE_CLASSES - 1)] as u8;
        }
        t
    }

    /// `ks[rice_class(s)]`: both loads issued at once, then a select.
    #[inline(always)]
    pub(super) fn k(&self, s: u32) -> u32 {
        let small = self.small[s.min(63) as usize];
        let large = self.large[((s | 1).ilog2() & 31) as usize];
        u32::from(if s < 64 { small } else { large })
    }
}

/// Zig-zag map: 0, −1, 1, −2, 2 … → 0, 1, 2, 3, 4 …
#[inline(always)]
pub(super) fn zigzag(v: i32) -> u32 {
    ((v << 1) ^ (v >> 31)) as u32
}

/// Bits of the Rice code of `u` with parameter `k`.
#[inline(always)]
fn code_bits(u: u32, k: u32) -> u64 {
    let q = u >> k;
    if q < ESCAPE {
        u64::from(q + 1 + k)
    } else {
        u64::from(ESCAPE + 1 + ESCAPE_BITS)
    }
}

/// Writes the Rice code of `u` with parameter `k`.
#[inline(always)]
fn put_code(w: &mut BitWriter, u: u32, k: u32) {
    let q = u >> k;
    if q < ESCAPE {
        w.put_bits(1, q + 1);
        w.put_bits(u & ((1u32 << k) - 1), k);
    } else {
        w.put_bits(1, ESCAPE + 1);
        w.put_bits(u, ESCAPE_BITS);
    }
}

/// Quadtree flags as raw bits: one per node, the model ignored.
pub(super) struct RawFlags<T>(pub(super) T);

impl BinCoder for RawFlags<&mut BitWriter> {
    fn bit(&mut self, _p: &mut Prob, bit: bool) -> bool {
        self.0.put_bit(bit);
        bit
    }
    fn overran(&self) -> bool {
        false
    }
}

impl BinCoder for RawFlags<&mut BitReader<'_>> {
    fn bit(&mut self, _p: &mut Prob, _bit: bool) -> bool {
        self.0.get_bit()
    }
    fn overran(&self) -> bool {
        self.0.is_overrun()
    }
}

/// Counts the quadtree's bits without writing them.
struct CountFlags(u64);

impl BinCoder for CountFlags {
    fn bit(&mut self, _p: &mut Prob, bit: bool) -> bool {
        self.0 += 1;
        bit
    }
    fn overran(&self) -> bool {
        false
    }
}

/// Unused quadtree models (the raw flags ignore them).
pub(super) fn no_models() -> [Prob; NODE_LEVELS * 3] {
    [Prob::new(2048); NODE_LEVELS * 3]
}

impl Scratch {
    /// Marks every leaf block as coded (a dense band).
    pub(super) fn set_dense(&mut self) {
        let (gw, gh) = self.dims[0];
        let leaf = &mut self.flags[0];
        for by in 0..gh {
            leaf[(by + 1) * (gw + 1) + 1..][..gw].fill(1);
        }
    }

    /// Sets `slots` to the columns of the coded leaf blocks of block row `y / B`.
    pub(super) fn rice_slots(&mut self, y: usize, w: usize) {
        let (gw, _) = self.dims[0];
        let frow = &self.flags[0][(y / B + 1) * (gw + 1) + 1..][..gw];
        self.slots.clear();
        for (bx, _) in frow.iter().enumerate().filter(|&(_, &f)| f != 0) {
            self.slots
                .extend((bx * B..(bx * B + B).min(w)).map(|x| x as u32));
        }
    }

    /// Sets `slots` to the first columns of the coded leaf blocks of block row `y / B` (the
    /// decoder walks them a block at a time).
    pub(super) fn coded_block_starts(&mut self, y: usize) {
        let (gw, _) = self.dims[0];
        let frow = &self.flags[0][(y / B + 1) * (gw + 1) + 1..][..gw];
        self.slots.clear();
        let coded = frow.iter().enumerate().filter(|&(_, &f)| f != 0);
        self.slots.extend(coded.map(|(bx, _)| (bx * B) as u32));
    }
}

/// Writes the `k` table (see the module comment).
fn put_k_table(w: &mut BitWriter, ks: &[u32; RICE_CLASSES]) {
    w.put_bits(ks[0], K_BITS);
    for pair in ks.windows(2) {
        let (prev, k) = (pair[0], pair[1]);
        if k == prev {
            w.put_bits(0, 1);
        } else if k == prev + 1 {
            w.put_bits(0b10, 2);
        } else if k + 1 == prev {
            w.put_bits(0b110, 3);
        } else {
            w.put_bits(0b111, 3);
            w.put_bits(k, K_BITS);
        }
    }
}

/// Reads the `k` table; a `k` above [`MAX_K`] is corrupt.
pub(super) fn get_k_table(r: &mut BitReader<'_>) -> Result<[u32; RICE_CLASSES], CodecError> {
    let mut ks = [0u32; RICE_CLASSES];
    for c in 0..RICE_CLASSES {
        let prev = if c == 0 { 0 } else { ks[c - 1] };
        // Each k is checked before the next builds on it, so none of this can overflow.
        let k = if c == 0 {
            r.get_bits(K_BITS)
        } else if !r.get_bit() {
            prev
        } else if !r.get_bit() {
            prev + 1
        } else if !r.get_bit() {
            prev.wrapping_sub(1)
        } else {
            r.get_bits(K_BITS)
        };
        if k > MAX_K {
            return Err(CodecError::corrupt(format!(
                "fast-rice: Rice parameter {} of class {c} outside 0..={MAX_K}",
                k as i32
            )));
        }
        ks[c] = k;
    }
    Ok(ks)
}

/// For each class, the `k` that codes its `(class, u)` pairs in the fewest bits; a class
/// with none keeps the previous class's `k` (the cheapest table entry).
fn best_k_table(coded: &[(u8, u32)]) -> [u32; RICE_CLASSES] {
    let mut cost = [[0u64; MAX_K as usize + 1]; RICE_CLASSES];
    let mut used = [false; RICE_CLASSES];
    for &(class, u) in coded {
        let c = usize::from(class);
        used[c] = true;
        for (k, total) in cost[c].iter_mut().enumerate() {
            *total += code_bits(u, k as u32);
        }
    }
    let mut ks = [0u32; RICE_CLASSES];
    for c in 0..RICE_CLASSES {
        ks[c] = if used[c] {
            (0..=MAX_K)
                .min_by_key(|&k| cost[c][k as usize])
                .unwrap_or(0)
        } else if c > 0 {
            ks[c - 1]
        } else {
            0
        };
    }
    ks
}

/// Chooses dense or quadtree for a band whose leaf flags are set, writes the choice (and the
/// tree) to `a`, and leaves the coded blocks' flags set. Returns whether anything is coded.
fn put_zero_blocks(a: &mut BitWriter, s: &mut Scratch, w: usize, h: usize) -> bool {
    let top = s.dims.len() - 1;
    let mut count = CountFlags(0);
    let any = code_node(&mut count, &mut no_models(), s, top, 0, 0, false);
    let (gw, gh) = s.dims[0];
    let mut zero_samples = 0u64;
    for by in 0..gh {
        for bx in 0..gw {
            if s.flags[0][(by + 1) * (gw + 1) + bx + 1] == 0 {
                let bw = B.min(w - bx * B);
                let bh = B.min(h - by * B);
                zero_samples += (bw * bh) as u64;
            }
        }
    }
    let dense = any && count.0 >= zero_samples;
    a.put_bit(dense);
    if dense {
        s.set_dense();
        return true;
    }
    code_node(
        &mut RawFlags(&mut *a),
        &mut no_models(),
        s,
        top,
        0,
        0,
        false,
    )
}

/// Every coded coefficient's `(class, u)`, in raster order, with the magnitudes set in `s`.
fn contexts(s: &mut Scratch, values: &[i32], w: usize, h: usize, out: &mut Vec<(u8, u32)>) {
    out.clear();
    let stride = w + 4;
    for y in 0..h {
        if y % B == 0 {
            s.rice_slots(y, w);
        }
        for &x in &s.slots {
            let x = x as usize;
            let j = (y + 2) * stride + 2 + x;
            let mag = &mut s.mag;
            let sum = 2 * (u32::from(mag[j - 1]) + u32::from(mag[j - stride]))
                + u32::from(mag[j - stride - 1])
                + u32::from(mag[j - stride + 1]);
            let v = values[y * w + x];
            out.push((rice_class(sum) as u8, zigzag(v)));
            mag[j] = v.unsigned_abs().min(MAG_SAT) as u16;
        }
    }
}

/// Encodes `bands` as one record appended to `out`.
pub(crate) fn encode_bands(bands: &[Band<'_>], out: &mut Vec<u8>) {
    if all_zero_checked(bands) {
        return;
    }
    let (mut a, mut b) = (BitWriter::new(), BitWriter::new());
    let mut s = Scratch::default();
    let mut coded = Vec::new();
    for band in bands {
        let (w, h) = (band.width, band.height);
        if w == 0 || h == 0 {
            continue;
        }
        s.reset(w, h);
        s.set_flags(band.values, w, h);
        if !put_zero_blocks(&mut a, &mut s, w, h) {
            continue;
        }
        contexts(&mut s, band.values, w, h, &mut coded);
        let ks = best_k_table(&coded);
        put_k_table(&mut a, &ks);
        let mut next = 0;
        for y in 0..h {
            if y % B == 0 {
                s.rice_slots(y, w);
            }
            let stream = if y % 2 == 0 { &mut a } else { &mut b };
            for &(class, u) in &coded[next..next + s.slots.len()] {
                put_code(stream, u, ks[usize::from(class)]);
            }
            next += s.slots.len();
        }
    }
    let a = a.finish();
    put_len(out, a.len());
    out.extend_from_slice(&a);
    b.finish_into(out);
}

/// Checks that only the zero padding of its last byte is left of stream `stream`.
pub(crate) fn check_padding(r: &mut BitReader<'_>, stream: &str) -> Result<(), CodecError> {
    match r.remaining_padding() {
        Some((_, 0)) => Ok(()),
        Some(_) => Err(CodecError::corrupt(format!(
            "fast-rice record: non-zero padding after stream {stream}"
        ))),
        None if r.is_overrun() => Err(CodecError::truncated(format!(
            "fast-rice record: stream {stream} ends early"
        ))),
        None => Err(CodecError::corrupt(format!(
            "fast-rice record: unused bytes after stream {stream}"
        ))),
    }
}
