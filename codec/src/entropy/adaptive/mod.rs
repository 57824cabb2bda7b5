//! Context-modelled adaptive binary arithmetic coder for residual bands.
//!
//! Layout of a record: one range-coded stream ([`range_coder`]) over all bands in order; models
//! start fresh for every record. A record whose bands are all zero is the empty byte string.
//!
//! Per band (bands with no samples are skipped entirely):
//! 1. A quadtree of "non-zero" flags over the grid of 4×4 leaf blocks, coded in Z order. The
//!    root flag is the band's "anything non-zero" flag, so an all-zero band costs a single
//!    well-predicted decision. Context: tree level and how many of the left and top neighbours
//!    at the same level are non-zero. The last existing child of a non-zero node is inferred
//!    non-zero when its siblings are all zero.
//! 2. The coefficients of non-zero leaf blocks in raster order over the whole band, so that the
//!    left, top, top-left and top-right neighbours are always known (zero if their block is zero).
//!    Each coefficient is a zero flag (context: neighbourhood class × border), a bypass sign, the
//!    exponent `e = ⌊log2 |v|⌋` in adaptive unary (context: neighbourhood class × bin), the two
//!    mantissa bits below the leading one adaptive (context: exponent) and the rest bypass.
//!
//! The neighbourhood class quantizes `2|L| + 2|T| + |TL| + |TR|` roughly logarithmically into
//! [`NCLASS`] classes. Cells and root bands share one model set, vertex bands have their own.
//! Encoder and decoder run the same generic traversal ([`BinCoder`]) for the quadtree and share
//! the models, the context class and the probability update; the decoder's coefficient pass is
//! a hand-specialised copy of the encoder's ([`decode_coeffs`], for speed), held to it by the
//! round-trip tests and the golden hashes.
//!
//! [`tokens`] codes the same quadtree with the same neighbourhood classes but binarises each
//! coefficient differently (a token tree on its high bits, its low bits and sign in a raw
//! stream) for faster decoding; [`rice`] codes the same quadtree with raw bits and each
//! coefficient as a static Golomb–Rice code, for faster decoding still.

pub(crate) mod grid;
pub(crate) mod inband;
pub(crate) mod integers;
mod range_coder;
pub(crate) mod rice;
#[cfg(test)]
mod tests;
pub(crate) mod tokens;
mod wide_range_coder;

use super::{Band, BandKind, BandMut, DecodeLimits};
use crate::CodecError;
use range_coder::{Decoder, Encoder, Prob};
use wide_range_coder::{WideDecoder, WideEncoder};

/// Side of a leaf block of the zero-block quadtree.
const B: usize = 4;
/// Neighbourhood classes.
const NCLASS: usize = 16;
/// Distinct contexts along the exponent's unary code; later bins share the last.
const EXP_BINS: usize = 10;
/// Exponents get their own mantissa contexts up to this value.
const MANT_E: usize = 12;
/// Distinct quadtree levels in the flag context.
const NODE_LEVELS: usize = 5;
/// `max_abs` < 2^30, so `⌊log2 |v|⌋` ≤ 29; the unary exponent stops there.
const MAX_EXP: u32 = 29;
/// Neighbour magnitudes are stored saturated to this.
const MAG_SAT: u32 = u16::MAX as u32;

/// Class of `s = 2|L| + 2|T| + |TL| + |TR|` for `s < 64`; above, one class per octave. From
/// `s = 1024` (`⌊log2 s⌋ + 5 ≥ 15`) on every class is the last, so the table covers all `s`
/// through `min(s, 1024)`: a load instead of a branch on the context's critical path.
const CLASS_LUT: [u8; 1025] = {
    let mut lut = [0u8; 1025];
    // Upper bounds (inclusive) of classes 0..=10.
    let bounds = [0usize, 1, 2, 4, 6, 9, 13, 19, 27, 39, 63];
    let mut s = 0;
    let mut c = 0;
    while s < 64 {
        while s > bounds[c] {
            c += 1;
        }
        lut[s] = c as u8;
        s += 1;
    }
    while s < 1025 {
        // s ≥ 64 has ilog2 ≥ 6, which continues after class 10.
        let c = s.ilog2() as usize + 5;
        lut[s] = if c < NCLASS { c } else { NCLASS - 1 } as u8;
        s += 1;
    }
    lut
};

#[inline(always)]
pub(crate) fn class_of(s: u32) -> usize {
    CLASS_LUT[s.min(1024) as usize] as usize
}

/// The adaptive models of one band kind.
#[derive(Clone)]
struct Models {
    zero: [Prob; NCLASS * 2],
    exp: [Prob; NCLASS * EXP_BINS],
    mant: [Prob; MANT_E * 2],
    node: [Prob; NODE_LEVELS * 3],
}

impl Models {
    /// Starting points: zeros are likely in quiet neighbourhoods and rare in busy ones; the
    /// rest start near even, and the fast initial adaptation does the remainder.
    const INIT: Models = {
        let mut zero = [Prob::new(2048); NCLASS * 2];
        let p_zero: [u16; NCLASS] = [
            3700, 3200, 2900, 2500, 2100, 1700, 1300, 1000, 700, 500, 350, 250, 180, 120, 80, 60,
        ];
        let mut c = 0;
        while c < NCLASS {
            zero[2 * c] = Prob::new(p_zero[c]);
            // Border residuals come from a lower-order predictor: expect fewer zeros.
            zero[2 * c + 1] = Prob::new(p_zero[c] * 3 / 4);
            c += 1;
        }
        let mut exp = [Prob::new(2048); NCLASS * EXP_BINS];
        let mut c = 0;
        while c < NCLASS {
            // The exponent of a busy neighbourhood is larger: continue more often.
            let p = 3000 - (c as u16) * 150;
            let mut i = 0;
            while i < EXP_BINS {
                exp[c * EXP_BINS + i] = Prob::new(p);
                i += 1;
            }
            c += 1;
        }
        Models {
            zero,
            exp,
            // Laplacian: within an octave the lower half is more likely.
            mant: [Prob::new(2400); MANT_E * 2],
            node: [Prob::new(2048); NODE_LEVELS * 3],
        }
    };
}

/// Which model set a band kind uses.
fn model_set(kind: BandKind) -> usize {
    match kind {
        BandKind::Cells | BandKind::Roots => 0,
        BandKind::Vertices => 1,
    }
}

/// The one operation encoder and decoder share: code a decision. The encoder writes `bit` and
/// returns it; the decoder ignores `bit` and returns what it reads.
trait BinCoder {
    fn bit(&mut self, p: &mut Prob, bit: bool) -> bool;
    /// Whether reading has gone past anything a valid record could need.
    fn overran(&self) -> bool;
}

/// A [`BinCoder`] that also codes equiprobable (bypass) bits.
trait BypassCoder: BinCoder {
    fn bypass(&mut self, bits: u32, n: u32) -> u32;
}

impl BinCoder for Encoder {
    #[inline(always)]
    fn bit(&mut self, p: &mut Prob, bit: bool) -> bool {
        self.encode(p, bit);
        bit
    }
    fn overran(&self) -> bool {
        false
    }
}

impl BypassCoder for Encoder {
    #[inline(always)]
    fn bypass(&mut self, bits: u32, n: u32) -> u32 {
        self.encode_bypass(bits, n);
        bits
    }
}

impl BinCoder for Decoder<'_> {
    #[inline(always)]
    fn bit(&mut self, p: &mut Prob, _bit: bool) -> bool {
        self.decode(p)
    }
    fn overran(&self) -> bool {
        Decoder::overran(self)
    }
}

impl BypassCoder for Decoder<'_> {
    #[inline(always)]
    fn bypass(&mut self, _bits: u32, n: u32) -> u32 {
        self.decode_bypass(n)
    }
}

impl BinCoder for WideEncoder {
    #[inline(always)]
    fn bit(&mut self, p: &mut Prob, bit: bool) -> bool {
        self.encode(p, bit);
        bit
    }
    fn overran(&self) -> bool {
        false
    }
}

impl BinCoder for WideDecoder<'_> {
    #[inline(always)]
    fn bit(&mut self, p: &mut Prob, _bit: bool) -> bool {
        self.decode(p)
    }
    fn overran(&self) -> bool {
        WideDecoder::overran(self)
    }
}

/// Scratch buffers, reused across bands and (through [`super::DecodeScratch`]) records:
/// [`Scratch::reset`] re-initialises everything a band reads, so no state carries over.
#[derive(Debug, Default)]
pub(crate) struct Scratch {
    /// Saturated magnitudes with two rows of zeros above and two columns either side.
    mag: Vec<u16>,
    /// Quadtree flags per level (0 = leaf blocks), each with one padding row above and one
    /// padding column to the left, so neighbour lookups need no edge cases.
    flags: Vec<Vec<u8>>,
    /// Grid width and height per level.
    dims: Vec<(usize, usize)>,
    /// The token coder's columns of one block row's non-zero leaf blocks.
    slots: Vec<u32>,
    /// The fast-rice decoder's copies of its two streams, each padded with zero bytes.
    padded_streams: [Vec<u8>; 2],
}

impl Scratch {
    /// Sizes and clears everything for a `w × h` band.
    fn reset(&mut self, w: usize, h: usize) {
        self.mag.clear();
        self.mag.resize((w + 4) * (h + 2), 0);
        self.dims.clear();
        let (mut gw, mut gh) = (w.div_ceil(B), h.div_ceil(B));
        loop {
            self.dims.push((gw, gh));
            if gw == 1 && gh == 1 {
                break;
            }
            gw = gw.div_ceil(2);
            gh = gh.div_ceil(2);
        }
        self.flags.resize_with(self.dims.len(), Vec::new);
        for (f, &(gw, gh)) in self.flags.iter_mut().zip(&self.dims) {
            f.clear();
            f.resize((gw + 1) * (gh + 1), 0);
        }
    }

    /// Fills the flag pyramid from known values (encoder side).
    fn set_flags(&mut self, values: &[i32], w: usize, h: usize) {
        let (gw, _) = self.dims[0];
        let leaf = &mut self.flags[0];
        for y in 0..h {
            let row = &values[y * w..(y + 1) * w];
            let frow = &mut leaf[(y / B + 1) * (gw + 1) + 1..][..gw];
            for (f, chunk) in frow.iter_mut().zip(row.chunks(B)) {
                *f |= chunk.iter().any(|&v| v != 0) as u8;
            }
        }
        for l in 1..self.dims.len() {
            let (cw, ch) = self.dims[l - 1];
            let (pw, _) = self.dims[l];
            let (lower, upper) = self.flags.split_at_mut(l);
            let (child, parent) = (&lower[l - 1], &mut upper[0]);
            for cy in 0..ch {
                for cx in 0..cw {
                    parent[(cy / 2 + 1) * (pw + 1) + cx / 2 + 1] |=
                        child[(cy + 1) * (cw + 1) + cx + 1];
                }
            }
        }
    }
}

/// Codes the quadtree node `(gx, gy)` at `level`, whose flag is known non-zero when `inferred`.
fn code_node<C: BinCoder>(
    c: &mut C,
    node: &mut [Prob; NODE_LEVELS * 3],
    s: &mut Scratch,
    level: usize,
    gx: usize,
    gy: usize,
    inferred: bool,
) -> bool {
    let (gw, _) = s.dims[level];
    let stride = gw + 1;
    let idx = (gy + 1) * stride + gx + 1;
    let flags = &mut s.flags[level];
    let nz = if inferred {
        true
    } else {
        let neigh = (flags[idx - 1] + flags[idx - stride]) as usize;
        let ctx = level.min(NODE_LEVELS - 1) * 3 + neigh;
        c.bit(&mut node[ctx], flags[idx] != 0)
    };
    flags[idx] = nz as u8;
    if nz && level > 0 {
        let (cw, ch) = s.dims[level - 1];
        let mut any = false;
        // Children in Z order, clipped to the grid; the last one is implied by its siblings.
        let kids = [(0, 0), (1, 0), (0, 1), (1, 1)];
        let exists = |&(dx, dy): &(usize, usize)| 2 * gx + dx < cw && 2 * gy + dy < ch;
        let last = kids.iter().rposition(exists).unwrap_or(0);
        for (k, kid) in kids.iter().enumerate() {
            if exists(kid) {
                any |= code_node(
                    c,
                    node,
                    s,
                    level - 1,
                    2 * gx + kid.0,
                    2 * gy + kid.1,
                    k == last && !any,
                );
            }
        }
    }
    nz
}

/// A decoded magnitude above the limit. Kept tiny so the per-coefficient result stays in
/// registers; [`CodecError`] is built only once, outside the loop.
struct TooLarge(u32);

/// Codes one coefficient; `v` is the value to write (ignored when decoding).
#[inline(always)]
fn code_coeff<C: BypassCoder>(
    c: &mut C,
    m: &mut Models,
    class: usize,
    border: usize,
    v: i32,
    max_abs: u32,
) -> Result<i32, TooLarge> {
    if !c.bit(&mut m.zero[class * 2 + border], v != 0) {
        return Ok(0);
    }
    let neg = c.bypass((v < 0) as u32, 1) != 0;
    let a = v.unsigned_abs();
    let e_true = (a | 1).ilog2();
    let exp = &mut m.exp[class * EXP_BINS..(class + 1) * EXP_BINS];
    let mut e = 0u32;
    while e < MAX_EXP && c.bit(&mut exp[(e as usize).min(EXP_BINS - 1)], e < e_true) {
        e += 1;
    }
    let mut mag = 1u32;
    if e >= 1 {
        let ctx = (e as usize).min(MANT_E) - 1;
        let b = c.bit(&mut m.mant[ctx], (a >> (e - 1)) & 1 != 0);
        mag = (mag << 1) | b as u32;
        if e >= 2 {
            let b = c.bit(&mut m.mant[MANT_E + ctx], (a >> (e - 2)) & 1 != 0);
            mag = (mag << 1) | b as u32;
            if e >= 3 {
                let n = e - 2;
                mag = (mag << n) | c.bypass(a & ((1 << n) - 1), n);
            }
        }
    }
    if mag > max_abs {
        return Err(TooLarge(mag));
    }
    Ok(if neg { -(mag as i32) } else { mag as i32 })
}

/// Codes a `w × h` band. Encoding: `values` holds the band and `s` its flag pyramid. Decoding:
/// `values` is zero and `s` freshly reset; both are filled in.
fn code_band<C: BypassCoder>(
    c: &mut C,
    m: &mut Models,
    s: &mut Scratch,
    values: &mut [i32],
    w: usize,
    h: usize,
    max_abs: u32,
) -> Result<(), CodecError> {
    let top = s.dims.len() - 1;
    if !code_node(c, &mut m.node, s, top, 0, 0, false) {
        return Ok(());
    }
    if c.overran() {
        return Err(CodecError::truncated("adaptive record ends early"));
    }
    let (gw, _) = s.dims[0];
    let stride = w + 4;
    let leaf = &s.flags[0];
    let mag = &mut s.mag;
    for y in 0..h {
        let frow = &leaf[(y / B + 1) * (gw + 1) + 1..][..gw];
        let row_border = (y < 2 || y + 2 >= h) as usize;
        let row = &mut values[y * w..(y + 1) * w];
        let base = (y + 2) * stride + 2;
        for (bx, _) in frow.iter().enumerate().filter(|&(_, &f)| f != 0) {
            let x0 = bx * B;
            // The left neighbour is the value just coded: keep it in a register rather than
            // reload it through the store, which would lengthen the serial chain.
            let mut left = u32::from(mag[base + x0 - 1]);
            for (dx, r) in row[x0..(x0 + B).min(w)].iter_mut().enumerate() {
                let x = x0 + dx;
                let j = base + x;
                let sum = 2 * (left + u32::from(mag[j - stride]))
                    + u32::from(mag[j - stride - 1])
                    + u32::from(mag[j - stride + 1]);
                let border = row_border | (x < 2 || x + 2 >= w) as usize;
                let v = code_coeff(c, m, class_of(sum), border, *r, max_abs).map_err(
                    |TooLarge(a)| {
                        CodecError::corrupt(format!(
                            "adaptive: magnitude {a} exceeds the limit {max_abs}"
                        ))
                    },
                )?;
                *r = v;
                left = v.unsigned_abs().min(MAG_SAT);
                mag[j] = left as u16;
            }
        }
        if c.overran() {
            return Err(CodecError::truncated("adaptive record ends early"));
        }
    }
    Ok(())
}

/// The decoder's half of [`code_band`]'s coefficient pass, written out for speed: the coder's
/// state lives in a local copy (registers, not memory), the neighbour rows are sliced once per
/// block so the loop has no bounds checks, and the magnitude limit is checked once per row on
/// the largest value seen (decoded magnitudes are below 2^30 whatever the bytes, so the rest of
/// the row cannot overflow anything). The decisions and their contexts are exactly those of
/// [`code_band`], which the encoder runs; the round-trip tests hold the two together.
fn decode_coeffs(
    dec: &mut Decoder<'_>,
    m: &mut Models,
    s: &mut Scratch,
    values: &mut [i32],
    w: usize,
    h: usize,
    max_abs: u32,
) -> Result<(), CodecError> {
    let mut d = *dec;
    let (gw, _) = s.dims[0];
    let stride = w + 4;
    let leaf = &s.flags[0];
    let mut worst = 0u32;
    for y in 0..h {
        let frow = &leaf[(y / B + 1) * (gw + 1) + 1..][..gw];
        let row_border = (y < 2 || y + 2 >= h) as usize;
        let row = &mut values[y * w..(y + 1) * w];
        let base = (y + 2) * stride + 2;
        // `up[x + 1]` is the top neighbour of column `x`, `cur[x + 1]` the sample itself and
        // `cur[x]` its left neighbour.
        let (above, cur) = s.mag.split_at_mut(base - 1);
        let up = &above[base - stride - 1..][..w + 2];
        for (bx, _) in frow.iter().enumerate().filter(|&(_, &f)| f != 0) {
            let x0 = bx * B;
            let bw = B.min(w - x0);
            let up = &up[x0..][..bw + 2];
            let cur = &mut cur[x0..][..bw + 1];
            let out = &mut row[x0..][..bw];
            let mut left = u32::from(cur[0]);
            for dx in 0..bw {
                let x = x0 + dx;
                let sum =
                    2 * (left + u32::from(up[dx + 1])) + u32::from(up[dx]) + u32::from(up[dx + 2]);
                let class = class_of(sum);
                let border = row_border | (x < 2 || x + 2 >= w) as usize;
                let mut a = 0u32;
                let mut v = 0i32;
                if d.decode(&mut m.zero[class * 2 + border]) {
                    let neg = d.decode_bypass(1);
                    let exp = &mut m.exp[class * EXP_BINS..][..EXP_BINS];
                    let mut e = 0u32;
                    while e < MAX_EXP && d.decode(&mut exp[(e as usize).min(EXP_BINS - 1)]) {
                        e += 1;
                    }
                    a = 1;
                    if e >= 1 {
                        let ctx = (e as usize).min(MANT_E) - 1;
                        a = (a << 1) | d.decode(&mut m.mant[ctx]) as u32;
                        if e >= 2 {
                            a = (a << 1) | d.decode(&mut m.mant[MANT_E + ctx]) as u32;
                            if e >= 3 {
                                let n = e - 2;
                                a = (a << n) | d.decode_bypass(n);
                            }
                        }
                    }
                    worst = worst.max(a);
                    // a < 2^30: the negation cannot overflow.
                    let sign = (neg as i32).wrapping_neg();
                    v = (a as i32 ^ sign) - sign;
                }
                out[dx] = v;
                left = a.min(MAG_SAT);
                cur[dx + 1] = left as u16;
            }
        }
        if worst > max_abs {
            return Err(CodecError::corrupt(format!(
                "adaptive: magnitude {worst} exceeds the limit {max_abs}"
            )));
        }
        if d.overran() {
            return Err(CodecError::truncated("adaptive record ends early"));
        }
    }
    *dec = d;
    Ok(())
}

/// Whether `bands` make an empty record (all zero); panics on a value the decoders would refuse
/// (a caller bug, see [`super::encode_bands`]).
fn all_zero_checked(bands: &[Band<'_>]) -> bool {
    let max_abs = DecodeLimits::default().max_abs;
    for b in bands {
        assert!(
            b.values.iter().all(|v| v.unsigned_abs() <= max_abs),
            "band value exceeds ±{max_abs}"
        );
    }
    bands.iter().all(|b| b.values.iter().all(|&v| v == 0))
}

/// Encodes `bands` as one record appended to `out`.
pub(crate) fn encode_bands(bands: &[Band<'_>], out: &mut Vec<u8>) {
    if all_zero_checked(bands) {
        return;
    }
    let mut enc = Encoder::new();
    let mut models = [Models::INIT, Models::INIT];
    let mut s = Scratch::default();
    let mut values = Vec::new();
    for b in bands {
        if b.width == 0 || b.height == 0 {
            continue;
        }
        s.reset(b.width, b.height);
        s.set_flags(b.values, b.width, b.height);
        values.clear();
        values.extend_from_slice(b.values);
        let m = &mut models[model_set(b.kind)];
        code_band(
            &mut enc,
            m,
            &mut s,
            &mut values,
            b.width,
            b.height,
            u32::MAX,
        )
        .expect("encoding cannot fail");
    }
    enc.finish(out);
}

/// Decodes one record written by [`encode_bands`] into `bands`.
pub(crate) fn decode_bands(
    bytes: &[u8],
    bands: &mut [BandMut<'_>],
    limits: DecodeLimits,
    s: &mut Scratch,
) -> Result<(), CodecError> {
    for b in bands.iter_mut() {
        b.values.fill(0);
    }
    if bytes.is_empty() {
        return Ok(());
    }
    let mut dec = Decoder::new(bytes)?;
    let mut models = [Models::INIT, Models::INIT];
    for b in bands.iter_mut() {
        if b.width == 0 || b.height == 0 {
            continue;
        }
        s.reset(b.width, b.height);
        let m = &mut models[model_set(b.kind)];
        let top = s.dims.len() - 1;
        if !code_node(&mut dec, &mut m.node, s, top, 0, 0, false) {
            continue;
        }
        if dec.overran() {
            return Err(CodecError::truncated("adaptive record ends early"));
        }
        decode_coeffs(&mut dec, m, s, b.values, b.width, b.height, limits.max_abs)?;
    }
    dec.finish()
}
