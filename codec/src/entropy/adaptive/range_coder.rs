//! LZMA-style binary range coder: 32-bit range, 12-bit probabilities, carry propagation in the
//! encoder through a cached byte and a count of pending `0xFF` bytes.
//!
//! Two departures from LZMA, both to make small records small: the first output byte, which is
//! always zero, is not written, and the flush picks the value in the final interval with the most
//! trailing zero bits and then drops up to [`FLUSH_SLACK`] trailing zero bytes, which the decoder
//! reads back as implicit zeros.

use crate::CodecError;

/// Probability precision.
pub(super) const PROB_BITS: u32 = 12;
/// Probabilities stay within `[P_MIN, P_MAX]` (out of 4096). With the range at least 2^24 before
/// a decision, both sub-ranges are then at least 2^12 · 31 > 2^16, so one byte of renormalisation
/// always suffices.
const P_MIN: i32 = 31;
const P_MAX: i32 = (1 << PROB_BITS) - 31;
/// Renormalise when the range drops below this.
const TOP: u32 = 1 << 24;
/// How many trailing zero bytes the encoder may drop and the decoder may invent.
pub(super) const FLUSH_SLACK: usize = 4;

/// Adaptation shift by how often a model has been used: fast at first, so the few hundred models
/// of a record adapt within the record, settling at 1/32.
const SHIFTS: [u8; 16] = [1, 2, 2, 3, 3, 3, 3, 4, 4, 4, 4, 4, 4, 4, 4, 5];

/// [`SHIFTS`] and the next use count (already in place in the top 4 bits) packed per use count,
/// so that one load replaces the count's compare and increment on every decision.
const STEP: [u16; 16] = {
    let mut t = [0u16; 16];
    let mut s = 0;
    while s < 16 {
        let next = if s < 15 { s + 1 } else { 15 };
        t[s] = ((next as u16) << 12) | SHIFTS[s] as u16;
        s += 1;
    }
    t
};

/// One adaptive binary model: the probability of a 0 in the low 12 bits, a use count (saturating
/// at 15) in the top 4 bits.
#[derive(Clone, Copy, Debug)]
pub(super) struct Prob(u16);

impl Prob {
    /// A model that starts with `P(0) = p0 / 4096`.
    pub(super) const fn new(p0: u16) -> Self {
        let p = if (p0 as i32) < P_MIN {
            P_MIN
        } else if (p0 as i32) > P_MAX {
            P_MAX
        } else {
            p0 as i32
        };
        Self(p as u16)
    }

    #[inline(always)]
    pub(super) fn p0(self) -> u32 {
        (self.0 & 0xFFF) as u32
    }

    /// Stores `old` updated by `bit`: for callers that loaded the model before they knew
    /// which one they would need.
    #[inline(always)]
    pub(super) fn update_from(&mut self, mut old: Prob, bit: bool) {
        old.update(bit);
        *self = old;
    }

    #[inline(always)]
    pub(super) fn update(&mut self, bit: bool) {
        let step = STEP[(self.0 >> 12) as usize];
        let p = (self.0 & 0xFFF) as i32;
        // A select, not a branch: many decisions are close to 50/50, and the mantissa bits'
        // callers do not branch on the bit at all.
        let target = P_MAX + ((P_MIN - P_MAX) & (bit as i32).wrapping_neg());
        // Arithmetic shift rounds towards the target's side, so p never leaves [P_MIN, P_MAX].
        let p = p + ((target - p) >> (step & 0xF));
        self.0 = p as u16 | (step & 0xF000);
    }
}

/// Range encoder writing into its own buffer.
pub(super) struct Encoder {
    low: u64,
    range: u32,
    cache: u8,
    pending: u64,
    out: Vec<u8>,
}

impl Encoder {
    pub(super) fn new() -> Self {
        Self {
            low: 0,
            range: u32::MAX,
            cache: 0,
            pending: 1,
            out: Vec::new(),
        }
    }

    #[inline(always)]
    pub(super) fn encode(&mut self, prob: &mut Prob, bit: bool) {
        let bound = (self.range >> PROB_BITS) * prob.p0();
        // Selects rather than a branch on the bit, as in the decoder.
        let mask = 0u32.wrapping_sub(bit as u32);
        self.low += u64::from(bound & mask);
        self.range = (bound & !mask) | (self.range.wrapping_sub(bound) & mask);
        prob.update(bit);
        if self.range < TOP {
            self.range <<= 8;
            self.shift_low();
        }
    }

    /// Writes the low `n` bits of `bits`, most significant first, each with probability 1/2.
    pub(super) fn encode_bypass(&mut self, bits: u32, n: u32) {
        for i in (0..n).rev() {
            self.range >>= 1;
            if (bits >> i) & 1 != 0 {
                self.low += u64::from(self.range);
            }
            if self.range < TOP {
                self.range <<= 8;
                self.shift_low();
            }
        }
    }

    fn shift_low(&mut self) {
        if (self.low as u32) < 0xFF00_0000 || (self.low >> 32) != 0 {
            let carry = (self.low >> 32) as u8;
            let mut byte = self.cache;
            loop {
                self.out.push(byte.wrapping_add(carry));
                byte = 0xFF;
                self.pending -= 1;
                if self.pending == 0 {
                    break;
                }
            }
            self.cache = (self.low >> 24) as u8;
        }
        self.pending += 1;
        self.low = (self.low & 0x00FF_FFFF) << 8;
    }

    /// Flushes and appends the coded bytes to `out`.
    pub(super) fn finish(mut self, out: &mut Vec<u8>) {
        // Any value in [low, low + range) decodes the same; the one with most trailing zeros
        // lets us drop the most bytes.
        let end = self.low + u64::from(self.range);
        for k in (0..=32).rev() {
            let mask = (1u64 << k) - 1;
            let v = (self.low + mask) & !mask;
            if v < end {
                self.low = v;
                break;
            }
        }
        for _ in 0..5 {
            self.shift_low();
        }
        // The first byte carries the bits above the initial range, which no carry reaches.
        debug_assert_eq!(self.out[0], 0);
        let mut n = self.out.len();
        let mut dropped = 0;
        while dropped < FLUSH_SLACK && n > 1 && self.out[n - 1] == 0 {
            n -= 1;
            dropped += 1;
        }
        out.extend_from_slice(&self.out[1..n]);
    }
}

/// Range decoder over a byte slice; reads past the end as zeros and counts how far it went.
///
/// `Copy`, so a hot loop can work on a local copy whose fields stay in registers.
#[derive(Clone, Copy)]
pub(super) struct Decoder<'a> {
    range: u32,
    code: u32,
    buf: &'a [u8],
    pos: usize,
}

impl<'a> Decoder<'a> {
    pub(super) fn new(buf: &'a [u8]) -> Result<Self, CodecError> {
        let mut d = Self {
            range: u32::MAX,
            code: 0,
            buf,
            pos: 0,
        };
        for _ in 0..4 {
            d.code = (d.code << 8) | u32::from(d.next_byte());
        }
        // The coded value lies below the initial range.
        if d.code == u32::MAX {
            return Err(CodecError::corrupt("range coder: invalid first bytes"));
        }
        Ok(d)
    }

    #[inline(always)]
    fn next_byte(&mut self) -> u8 {
        let b = self.buf.get(self.pos).copied().unwrap_or(0);
        self.pos += 1;
        b
    }

    #[inline(always)]
    pub(super) fn decode(&mut self, prob: &mut Prob) -> bool {
        let bound = (self.range >> PROB_BITS) * prob.p0();
        let bit = self.code >= bound;
        // Written as selects rather than branches: many decisions are close to 50/50.
        let mask = 0u32.wrapping_sub(bit as u32);
        self.code -= bound & mask;
        self.range = (bound & !mask) | (self.range.wrapping_sub(bound) & mask);
        prob.update(bit);
        if self.range < TOP {
            self.range <<= 8;
            self.code = (self.code << 8) | u32::from(self.next_byte());
        }
        bit
    }

    /// Reads `n` equiprobable bits, most significant first.
    pub(super) fn decode_bypass(&mut self, n: u32) -> u32 {
        let mut v = 0;
        for _ in 0..n {
            self.range >>= 1;
            let b = self.code >= self.range;
            self.code -= self.range & 0u32.wrapping_sub(b as u32);
            v = (v << 1) | b as u32;
            if self.range < TOP {
                self.range <<= 8;
                self.code = (self.code << 8) | u32::from(self.next_byte());
            }
        }
        v
    }

    /// Whether the decoder has already invented more bytes than an encoder flush can omit.
    #[inline]
    pub(super) fn overran(&self) -> bool {
        self.pos > self.buf.len() + FLUSH_SLACK
    }

    /// Checks that the stream ended where it should.
    pub(super) fn finish(self) -> Result<(), CodecError> {
        if self.overran() {
            return Err(CodecError::truncated("adaptive record ends early"));
        }
        if self.pos < self.buf.len() {
            return Err(CodecError::corrupt(format!(
                "adaptive record has {} trailing bytes",
                self.buf.len() - self.pos
            )));
        }
        // A valid stream keeps the code inside the range throughout.
        if self.code >= self.range {
            return Err(CodecError::corrupt("range coder: code outside range"));
        }
        Ok(())
    }
}
