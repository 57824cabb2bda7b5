//! The token coder ([`CoderKind::AdaptiveTokens`](crate::entropy::CoderKind::AdaptiveTokens)):
//! the same zero-block quadtree and neighbourhood contexts as the bitwise adaptive coder
//! ([`super`]), with a binarisation made for decoding speed.
//!
//! The bitwise coder spends one range-coder decision per unary exponent step, per mantissa bit
//! and per sign, and branches on most of them: at fine tolerances (4–5 bits per coefficient) a
//! coefficient costs six or more dependent decisions. Here:
//!
//! - `v = 0` or not is one adaptive decision (context: class of the neighbourhood sum
//!   `s = 2|L| + 2|T| + |TL| + |TR|` × border), as in the bitwise coder;
//! - for `v ≠ 0`, `s` picks a shift `k = ⌊log2 s⌋ − 3` (0 below 16): the low `k` bits of
//!   `|v| − 1` go to a separate **raw bit stream** (they are close to uniform when the
//!   neighbourhood is that busy), and only `q = (|v| − 1) >> k` is range coded, so that within
//!   each octave of `s` the distribution of `q` is about the same, and small;
//! - `q` is a 3-level binary tree over 8 tokens (context: class of `s`): `q = 0 … 6` directly,
//!   token 7 an escape followed by the Elias-gamma code of `q − 6` in the raw stream. Each tree
//!   decision picks the next model by index, with no branch;
//! - then the sign, one raw bit.
//!
//! So a non-zero coefficient is four range-coder decisions, a zero one is one, and the raw bits
//! are off the range coder's serial dependency chain. The range coder is
//! [`super::wide_range_coder`] (64-bit range, 32-bit renormalisation).
//!
//! Coding order ([`pair_order`]): the non-zero leaf blocks' coefficients of two rows at a time,
//! the second row two coefficients behind the first, so that a decoder runs two rows'
//! context chains (each coefficient waits for its left neighbour) side by side.
//!
//! Record: empty when every band is zero; otherwise the LEB128 length of the raw stream, the raw
//! stream (MSB-first, zero-padded to a byte), then the range-coded stream, which holds each
//! band's quadtree and the coefficients' decisions, bands in order. Models start fresh for
//! every record.

use super::range_coder::Prob;
use super::wide_range_coder::{WideDecoder as Decoder, WideEncoder as Encoder};
use super::{
    B, MAG_SAT, NCLASS, NODE_LEVELS, Scratch, all_zero_checked, class_of, code_node, model_set,
};
use crate::CodecError;
use crate::entropy::bitio::{BitReader, BitWriter};
use crate::entropy::{Band, BandMut, DecodeLimits};

#[cfg(test)]
#[path = "tokens_tests.rs"]
mod tests;

/// Levels of the token tree.
const TREE_LEVELS: u32 = 3;
/// Tokens: `q = 0 ..= 6`, and the escape.
const TOKENS: usize = 1 << TREE_LEVELS;
/// The escape token, `q ≥ 7`.
const ESCAPE: u32 = TOKENS as u32 - 1;
/// Longest Elias-gamma prefix an escape may have: `q − 6 < 2^31`.
const MAX_GAMMA_ZEROS: u32 = 30;

/// How many low bits of `|v| − 1` go to the raw stream for neighbourhood sum `sum`: none below 16,
/// one more per octave above. `sum ≤ 6 · MAG_SAT < 2^19`, so at most 15.
#[inline(always)]
fn shift_of(sum: u32) -> u32 {
    (sum | 1).ilog2().saturating_sub(3)
}

/// The adaptive models of one band kind, `C` contexts for the coefficients: the neighbourhood
/// class plus an offset that a coder may add ([`Activity`]), context `c` starting from class
/// `c % NCLASS`'s priors.
#[derive(Clone)]
pub(super) struct TokenModels<const C: usize> {
    /// "v ≠ 0", by context, then border.
    zero: [[Prob; 2]; C],
    /// Token tree nodes by context; node `n` (1-based, heap order) at `tree[context][n]`.
    tree: [[Prob; TOKENS]; C],
    /// Zero-block quadtree, as in the bitwise coder.
    node: [Prob; NODE_LEVELS * 3],
}

/// `P(bit = 0)` out of 4096 for tree node `n` when the tokens are geometric with ratio `rho`
/// (`P(token t) ∝ rho^t`, the escape holding the tail).
const fn tree_prior(rho: f64, n: usize) -> u16 {
    let depth = n.ilog2();
    let span = TOKENS >> depth;
    let first = (n - (1 << depth)) * span;
    let mut mass = [0.0f64; TOKENS];
    let mut p = 1.0 - rho;
    let mut t = 0;
    while t < TOKENS {
        mass[t] = if t + 1 == TOKENS { p / (1.0 - rho) } else { p };
        p *= rho;
        t += 1;
    }
    let (mut left, mut all) = (0.0, 0.0);
    let mut t = first;
    while t < first + span {
        if t < first + span / 2 {
            left += mass[t];
        }
        all += mass[t];
        t += 1;
    }
    (left / all * 4096.0) as u16
}

impl<const C: usize> TokenModels<C> {
    /// Starting points: zeros as likely as in the bitwise coder, and geometric tokens (the
    /// shift keeps `q` small in busy neighbourhoods). The rest is fast adaptation.
    pub(super) const INIT: Self = {
        let p_zero: [u16; NCLASS] = [
            3700, 3200, 2900, 2500, 2100, 1700, 1300, 1000, 700, 500, 350, 250, 180, 120, 80, 60,
        ];
        // Ratio of the geometric prior on q by class: quiet classes are mostly |v| = 1.
        let rho: [f64; NCLASS] = [
            0.2, 0.25, 0.3, 0.35, 0.4, 0.45, 0.5, 0.55, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5,
        ];
        let mut zero = [[Prob::new(2048); 2]; C];
        let mut tree = [[Prob::new(2048); TOKENS]; C];
        let mut ctx = 0;
        while ctx < C {
            let c = ctx % NCLASS;
            zero[ctx][0] = Prob::new(p_zero[c]);
            // Border residuals come from a lower-order predictor: expect fewer zeros.
            zero[ctx][1] = Prob::new(p_zero[c] * 3 / 4);
            let mut n = 1;
            while n < TOKENS {
                tree[ctx][n] = Prob::new(tree_prior(rho[c], n));
                n += 1;
            }
            ctx += 1;
        }
        TokenModels {
            zero,
            tree,
            node: [Prob::new(2048); NODE_LEVELS * 3],
        }
    };
}

/// What a coder knows about each coefficient beyond its coded neighbours: given the
/// coefficient's index in the band and its neighbourhood sum, the sum to use (it picks the
/// class and the raw shift) and an offset added to the class (a multiple of [`NCLASS`], below
/// the models' `C`).
pub(super) trait Activity: Copy {
    fn context(self, index: usize, sum: u32) -> (u32, usize);
}

/// No knowledge beyond the neighbours: [`CoderKind::AdaptiveTokens`](crate::entropy::CoderKind::AdaptiveTokens).
#[derive(Clone, Copy)]
pub(super) struct Flat;

impl Activity for Flat {
    #[inline(always)]
    fn context(self, _: usize, sum: u32) -> (u32, usize) {
        (sum, 0)
    }
}

/// How many coefficients the second row of a pair trails the first by, in coding order: the
/// top-right neighbour of its coefficient at slot `i` is the first row's slot `i + 1` (or a
/// zero block), already coded.
const LAG: usize = 2;

/// The coding order of a block row's coefficients: rows are taken in pairs, and the pair's two
/// rows are interleaved, the second [`LAG`] coefficients behind the first. `f(slot, row)` is
/// called for row 0 or 1 of the pair at each of the `n` slots (columns of its non-zero leaf
/// blocks, left to right). The two rows' contexts do not depend on each other within a step,
/// so a decoder works on two independent dependency chains at once.
#[inline(always)]
fn pair_order(n: usize, pair: bool, mut f: impl FnMut(usize, usize)) {
    if !pair {
        for i in 0..n {
            f(i, 0);
        }
        return;
    }
    for i in 0..n.min(LAG) {
        f(i, 0);
    }
    for i in LAG..n {
        f(i, 0);
        f(i - LAG, 1);
    }
    for i in n.saturating_sub(LAG)..n {
        f(i, 1);
    }
}

impl Scratch {
    /// Sets `slots` to the columns of the non-zero leaf blocks of block row `y / B` of a band
    /// `w` wide, left to right.
    fn fill_slots(&mut self, y: usize, w: usize) {
        let (gw, _) = self.dims[0];
        let frow = &self.flags[0][(y / B + 1) * (gw + 1) + 1..][..gw];
        self.slots.clear();
        for (bx, _) in frow.iter().enumerate().filter(|&(_, &f)| f != 0) {
            self.slots
                .extend((bx * B..(bx * B + B).min(w)).map(|x| x as u32));
        }
    }
}

/// Codes the coefficients of one band's non-zero leaf blocks (the flag pyramid in `s` is set),
/// in [`pair_order`], each in the context `activity` gives it.
#[allow(clippy::too_many_arguments)]
fn encode_coeffs<const C: usize>(
    enc: &mut Encoder,
    raw: &mut BitWriter,
    m: &mut TokenModels<C>,
    s: &mut Scratch,
    values: &[i32],
    w: usize,
    h: usize,
    activity: impl Activity,
) {
    let stride = w + 4;
    for y0 in (0..h).step_by(2) {
        if y0 % B == 0 {
            s.fill_slots(y0, w);
        }
        let (slots, mag) = (s.slots.as_slice(), &mut s.mag);
        pair_order(slots.len(), y0 + 1 < h, |i, r| {
            let (x, y) = (slots[i] as usize, y0 + r);
            let j = (y + 2) * stride + 2 + x;
            let sum = 2 * (u32::from(mag[j - 1]) + u32::from(mag[j - stride]))
                + u32::from(mag[j - stride - 1])
                + u32::from(mag[j - stride + 1]);
            let (sum, offset) = activity.context(y * w + x, sum);
            let ctx = class_of(sum) + offset;
            let border = (y < 2 || y + 2 >= h || x < 2 || x + 2 >= w) as usize;
            let k = shift_of(sum);
            let v = values[y * w + x];
            let a = v.unsigned_abs();
            enc.encode(&mut m.zero[ctx][border], a != 0);
            if a != 0 {
                let q = (a - 1) >> k;
                let token = q.min(ESCAPE);
                let tree = &mut m.tree[ctx];
                let mut n = 1;
                for level in (0..TREE_LEVELS).rev() {
                    let bit = (token >> level) & 1 != 0;
                    enc.encode(&mut tree[n], bit);
                    n = 2 * n + bit as usize;
                }
                if token == ESCAPE {
                    raw.put_gamma(q - ESCAPE + 1);
                }
                // The low bits, then the sign: one write.
                raw.put_bits((((a - 1) & ((1 << k) - 1)) << 1) | (v < 0) as u32, k + 1);
            }
            mag[j] = a.min(MAG_SAT) as u16;
        });
    }
}

/// Decodes one coefficient whose neighbourhood sum is `sum` and context offset `offset`:
/// `(magnitude, value)`. The
/// decisions are [`encode_coeffs`]'s, written for speed: no branch in the token tree or the
/// raw reads but the rare escape, and each tree level's two candidate models loaded while the
/// level above is decided, so a decision picks its probability with a select instead of
/// waiting on a load that depends on it. Magnitudes are clamped to below 2^31 whatever the
/// bytes; an escape that no encoder writes sets `bad_escape`.
#[inline(always)]
fn decode_one<const C: usize>(
    d: &mut Decoder<'_>,
    raw: &mut BitReader<'_>,
    m: &mut TokenModels<C>,
    (sum, offset): (u32, usize),
    border: usize,
    bad_escape: &mut bool,
) -> (u32, i32) {
    let ctx = class_of(sum) + offset;
    if !d.decode(&mut m.zero[ctx][border]) {
        return (0, 0);
    }
    let k = shift_of(sum);
    {
        let tree = &mut m.tree[ctx];
        let root = tree[1];
        let (mut lo, mut hi) = (tree[2], tree[3]);
        let b0 = d.decode_p(root.p0());
        tree[1].update_from(root, b0);
        let n1 = 2 + b0 as usize;
        let p1 = if b0 { hi } else { lo };
        lo = tree[(2 * n1) & (TOKENS - 1)];
        hi = tree[(2 * n1 + 1) & (TOKENS - 1)];
        let b1 = d.decode_p(p1.p0());
        tree[n1].update_from(p1, b1);
        let n2 = 2 * n1 + b1 as usize;
        let p2 = if b1 { hi } else { lo };
        let b2 = d.decode_p(p2.p0());
        tree[n2 & (TOKENS - 1)].update_from(p2, b2);
        let token = (2 * (n2 - 4) + b2 as usize) as u32;
        let mut q = token;
        if token == ESCAPE {
            // q·2^k stays at most 2^30 (and a below 2^31) whatever the bytes.
            let q64 = raw
                .get_gamma(MAX_GAMMA_ZEROS)
                .map_or(u64::MAX, |r| u64::from(r) + u64::from(ESCAPE) - 1);
            *bad_escape |= q64 >= (1 << 30) >> k;
            q = q64.min((1 << 30) >> k) as u32;
        }
        raw.ensure(16);
        let bits = raw.peek(k + 1);
        let a = ((q << k) | (bits >> 1)) + 1;
        raw.consume_short(k + 1);
        // a < 2^31: the negation cannot overflow.
        let sign = ((bits & 1) as i32).wrapping_neg();
        (a, (a as i32 ^ sign) - sign)
    }
}

/// Decodes what [`encode_coeffs`] wrote, in [`pair_order`]: the two rows of a pair are two
/// independent dependency chains (each coefficient's context waits for its left neighbour),
/// so the CPU works on both at once. Magnitudes are checked against `max_abs` once per pair.
/// Each coefficient's context is the one `activity` gives it, as in [`encode_coeffs`].
// The slot loops spell out `pair_order` step by step, by index, so that they can be compared.
#[allow(clippy::too_many_arguments, clippy::needless_range_loop)]
fn decode_coeffs<const C: usize>(
    dec: &mut Decoder<'_>,
    raw: &mut BitReader<'_>,
    m: &mut TokenModels<C>,
    s: &mut Scratch,
    values: &mut [i32],
    w: usize,
    h: usize,
    max_abs: u32,
    activity: impl Activity,
) -> Result<(), CodecError> {
    let mut d = *dec;
    let stride = w + 4;
    let mut worst = 0u32;
    let mut bad_escape = false;
    for y0 in (0..h).step_by(2) {
        if y0 % B == 0 {
            s.fill_slots(y0, w);
        }
        // A slice, not the Vec: its pointer and length then stay in registers across the
        // stores below.
        let slots = s.slots.as_slice();
        let n = slots.len();
        if n == 0 {
            continue;
        }
        // Magnitude rows (two padding columns either side): `up` above row y0, `ma` row y0
        // (written by the first row, read by the second), `mb` row y0 + 1.
        let (above, below) = s.mag.split_at_mut((y0 + 2) * stride);
        let up = &above[(y0 + 1) * stride..];
        let (ma, below) = below.split_at_mut(stride);
        let (va, vb) = values[y0 * w..].split_at_mut(w);
        let border_a = y0 < 2 || y0 + 2 >= h;
        let border_b = y0 + 1 < 2 || y0 + 3 >= h;
        let col_border = |x: usize| x < 2 || x + 2 >= w;
        let (mut left_a, mut next_a) = (0u32, usize::MAX);
        let (mut left_b, mut next_b) = (0u32, usize::MAX);
        // Row y0 at slot i.
        macro_rules! step_a {
            ($i:expr) => {{
                let x = slots[$i] as usize;
                let t = &up[x + 1..x + 4];
                // A zero block's magnitudes are zero: the previous coefficient of this row is
                // the left neighbour only when adjacent.
                let left = if next_a == x { left_a } else { 0 };
                let sum = 2 * (left + u32::from(t[1])) + u32::from(t[0]) + u32::from(t[2]);
                let border = (border_a || col_border(x)) as usize;
                let context = activity.context(y0 * w + x, sum);
                let (a, v) = decode_one(&mut d, raw, m, context, border, &mut bad_escape);
                worst = worst.max(a);
                va[x] = v;
                left_a = a.min(MAG_SAT);
                ma[x + 2] = left_a as u16;
                next_a = x + 1;
            }};
        }
        if y0 + 1 >= h {
            for i in 0..n {
                step_a!(i);
            }
        } else {
            let mb = &mut below[..stride];
            macro_rules! step_b {
                ($i:expr) => {{
                    let x = slots[$i] as usize;
                    let t = &ma[x + 1..x + 4];
                    let left = if next_b == x { left_b } else { 0 };
                    let sum = 2 * (left + u32::from(t[1])) + u32::from(t[0]) + u32::from(t[2]);
                    let border = (border_b || col_border(x)) as usize;
                    let context = activity.context((y0 + 1) * w + x, sum);
                    let (a, v) = decode_one(&mut d, raw, m, context, border, &mut bad_escape);
                    worst = worst.max(a);
                    vb[x] = v;
                    left_b = a.min(MAG_SAT);
                    mb[x + 2] = left_b as u16;
                    next_b = x + 1;
                }};
            }
            for i in 0..n.min(LAG) {
                step_a!(i);
            }
            for i in LAG..n {
                step_a!(i);
                step_b!(i - LAG);
            }
            for i in n.saturating_sub(LAG)..n {
                step_b!(i);
            }
        }
        if bad_escape {
            return Err(CodecError::corrupt(
                "adaptive tokens: escaped magnitude of 2^30 or more",
            ));
        }
        if worst > max_abs {
            return Err(CodecError::corrupt(format!(
                "adaptive tokens: magnitude {worst} exceeds the limit {max_abs}"
            )));
        }
        if d.overran() || raw.is_overrun() {
            return Err(CodecError::truncated("adaptive tokens record ends early"));
        }
    }
    *dec = d;
    Ok(())
}

/// Encodes `bands` as one record appended to `out`.
pub(crate) fn encode_bands(bands: &[Band<'_>], out: &mut Vec<u8>) {
    if all_zero_checked(bands) {
        return;
    }
    let mut record = RecordEncoder::<NCLASS>::new();
    for b in bands {
        record.band(b, Flat);
    }
    record.finish(out);
}

/// One record being written: the range coder, the raw stream, the models of both sets and the
/// working memory. A coder whose contexts differ from [`Flat`] writes its bands through it.
pub(super) struct RecordEncoder<const C: usize> {
    enc: Encoder,
    raw: BitWriter,
    models: [TokenModels<C>; 2],
    s: Scratch,
}

impl<const C: usize> RecordEncoder<C> {
    pub(super) fn new() -> Self {
        Self {
            enc: Encoder::new(),
            raw: BitWriter::new(),
            models: [TokenModels::INIT, TokenModels::INIT],
            s: Scratch::default(),
        }
    }

    /// Codes band `b`'s quadtree and coefficients, each in the context `activity` gives it.
    pub(super) fn band(&mut self, b: &Band<'_>, activity: impl Activity) {
        if b.width == 0 || b.height == 0 {
            return;
        }
        let s = &mut self.s;
        s.reset(b.width, b.height);
        s.set_flags(b.values, b.width, b.height);
        let m = &mut self.models[model_set(b.kind)];
        let top = s.dims.len() - 1;
        if code_node(&mut self.enc, &mut m.node, s, top, 0, 0, false) {
            let (w, h) = (b.width, b.height);
            encode_coeffs(&mut self.enc, &mut self.raw, m, s, b.values, w, h, activity);
        }
    }

    /// Writes `n` bits of `value` to the raw stream (side information a coder puts before a
    /// band, read back by [`RecordDecoder::raw_bits`] at the same point).
    pub(super) fn raw_bits(&mut self, value: u32, n: u32) {
        self.raw.put_bits(value, n);
    }

    /// Appends the record: the raw stream's length, the raw stream, the range-coded stream.
    pub(super) fn finish(self, out: &mut Vec<u8>) {
        let raw = self.raw.finish();
        put_len(out, raw.len());
        out.extend_from_slice(&raw);
        self.enc.finish(out);
    }
}

/// Decodes one record written by [`encode_bands`] into `bands`.
pub(crate) fn decode_bands(
    bytes: &[u8],
    bands: &mut [BandMut<'_>],
    limits: DecodeLimits,
    s: &mut Scratch,
) -> Result<(), CodecError> {
    decode_record::<NCLASS>(bytes, bands, s, |_, record, b| record.band(b, limits, Flat))
}

/// One record being read: [`RecordEncoder`]'s counterpart.
pub(super) struct RecordDecoder<'a, 's, const C: usize> {
    dec: Decoder<'a>,
    raw: BitReader<'a>,
    models: [TokenModels<C>; 2],
    s: &'s mut Scratch,
}

impl<const C: usize> RecordDecoder<'_, '_, C> {
    /// Reads `n` bits that [`RecordEncoder::raw_bits`] wrote (zeros past the end of the raw
    /// stream, which [`decode_record`] then reports).
    pub(super) fn raw_bits(&mut self, n: u32) -> u32 {
        self.raw.get_bits(n)
    }

    /// Decodes band `b`'s quadtree and coefficients, each in the context `activity` gives it.
    pub(super) fn band(
        &mut self,
        b: &mut BandMut<'_>,
        limits: DecodeLimits,
        activity: impl Activity,
    ) -> Result<(), CodecError> {
        if b.width == 0 || b.height == 0 {
            return Ok(());
        }
        let s = &mut *self.s;
        s.reset(b.width, b.height);
        let m = &mut self.models[model_set(b.kind)];
        let top = s.dims.len() - 1;
        if !code_node(&mut self.dec, &mut m.node, s, top, 0, 0, false) {
            return Ok(());
        }
        if self.dec.overran() {
            return Err(CodecError::truncated("adaptive tokens record ends early"));
        }
        let (w, h, max) = (b.width, b.height, limits.max_abs);
        let raw = &mut self.raw;
        decode_coeffs(&mut self.dec, raw, m, s, b.values, w, h, max, activity)
    }
}

/// Decodes a record of the token format: zeroes `bands`, then (unless the record is empty)
/// hands `band(index, record, band)` each band in order, then checks that both streams end
/// where they should.
pub(super) fn decode_record<const C: usize>(
    bytes: &[u8],
    bands: &mut [BandMut<'_>],
    s: &mut Scratch,
    mut band: impl FnMut(
        usize,
        &mut RecordDecoder<'_, '_, C>,
        &mut BandMut<'_>,
    ) -> Result<(), CodecError>,
) -> Result<(), CodecError> {
    for b in bands.iter_mut() {
        b.values.fill(0);
    }
    if bytes.is_empty() {
        return Ok(());
    }
    let (raw_bytes, coded) = split_streams(bytes, "adaptive tokens", "raw stream")?;
    let mut record = RecordDecoder {
        dec: Decoder::new(coded),
        raw: BitReader::new(raw_bytes),
        models: [TokenModels::INIT, TokenModels::INIT],
        s,
    };
    for (index, b) in bands.iter_mut().enumerate() {
        band(index, &mut record, b)?;
    }
    record.dec.finish()?;
    // Only the zero padding of the raw stream's last byte may be left.
    match record.raw.remaining_padding() {
        Some((_, 0)) => Ok(()),
        Some(_) => Err(CodecError::corrupt(
            "adaptive tokens record: non-zero padding after the raw bits",
        )),
        None if record.raw.is_overrun() => Err(CodecError::truncated(
            "adaptive tokens record: raw stream ends early",
        )),
        None => Err(CodecError::corrupt(
            "adaptive tokens record: unused bytes in the raw stream",
        )),
    }
}

/// Appends `len` as LEB128.
pub(super) fn put_len(out: &mut Vec<u8>, mut len: usize) {
    while len >= 0x80 {
        out.push((len as u8) | 0x80);
        len >>= 7;
    }
    out.push(len as u8);
}

/// Splits a non-empty `coder` record into its first stream, whose length leads the record
/// (`first` names it in errors), and the rest.
pub(super) fn split_streams<'a>(
    bytes: &'a [u8],
    coder: &str,
    first: &str,
) -> Result<(&'a [u8], &'a [u8]), CodecError> {
    let (len, header) = get_len(bytes, coder)?;
    let rest = &bytes[header..];
    if len > rest.len() {
        return Err(CodecError::truncated(format!(
            "{coder} record: {first} of {len} bytes, {} left",
            rest.len()
        )));
    }
    Ok(rest.split_at(len))
}

/// Reads a canonical LEB128 length below 2^32 at the start of a `coder` record: `(value, bytes
/// read)`.
pub(super) fn get_len(bytes: &[u8], coder: &str) -> Result<(usize, usize), CodecError> {
    let mut v = 0u64;
    for (i, &b) in bytes.iter().enumerate().take(5) {
        v |= u64::from(b & 0x7f) << (7 * i);
        if b & 0x80 == 0 {
            if i > 0 && b == 0 {
                return Err(CodecError::corrupt(format!(
                    "{coder} record: over-long stream length"
                )));
            }
            let v = u32::try_from(v).map_err(|_| {
                CodecError::corrupt(format!("{coder} record: stream length over 4 GiB"))
            })?;
            return Ok((v as usize, i + 1));
        }
    }
    if bytes.len() < 5 {
        Err(CodecError::truncated(format!(
            "{coder} record ends inside its stream length"
        )))
    } else {
        Err(CodecError::corrupt(format!(
            "{coder} record: stream length over 4 GiB"
        )))
    }
}
