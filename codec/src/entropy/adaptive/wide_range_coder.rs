//! Binary range coder with a 64-bit range that renormalises 32 bits at a time, for the token
//! coder ([`super::tokens`]).
//!
//! The byte-wise coder ([`super::range_coder`]) renormalises after about every second decision
//! on busy data, a branch taken or not at random. Here the range stays in `[2^32, 2^64)` and a
//! renormalisation moves a whole 32-bit word, about once per 32 bits of output, so the branch is
//! nearly always not taken. Probabilities and their adaptation are the byte-wise coder's
//! ([`Prob`]).
//!
//! The encoder keeps the low 64 bits of the interval's lower end and propagates a carry into
//! the bytes already written (the coded value stays below 1, so a carry always stops inside
//! them). The flush writes the value in the final interval with the most trailing zero bits and
//! drops up to [`FLUSH_SLACK`] trailing zero bytes, which the decoder reads back as zeros. The
//! decoder reads 8 bytes to start and 4 per renormalisation, exactly what the encoder wrote, so
//! a valid stream ends where the decoder stops, give or take the dropped zeros.

use super::range_coder::{PROB_BITS, Prob};
use crate::CodecError;

/// Renormalise when the range drops below this. With probabilities in `[31, 4065]` of 4096 a
/// decision leaves at least `2^20 · 31 > 2^24` of a range of `2^32`, so one renormalisation
/// always suffices.
const TOP: u64 = 1 << 32;
/// How many trailing zero bytes the encoder may drop and the decoder may invent.
const FLUSH_SLACK: usize = 8;

/// Range encoder appending to its own buffer.
pub(super) struct WideEncoder {
    low: u64,
    range: u64,
    out: Vec<u8>,
}

impl WideEncoder {
    pub(super) fn new() -> Self {
        Self {
            low: 0,
            range: u64::MAX,
            out: Vec::new(),
        }
    }

    #[inline(always)]
    pub(super) fn encode(&mut self, prob: &mut Prob, bit: bool) {
        let bound = (self.range >> PROB_BITS) * u64::from(prob.p0());
        // Selects rather than a branch on the bit, as in the decoder; only the rare carry
        // branches.
        let mask = 0u64.wrapping_sub(bit as u64);
        let (low, carry) = self.low.overflowing_add(bound & mask);
        self.low = low;
        if carry {
            self.propagate_carry();
        }
        self.range = (bound & !mask) | (self.range.wrapping_sub(bound) & mask);
        prob.update(bit);
        if self.range < TOP {
            self.out
                .extend_from_slice(&((self.low >> 32) as u32).to_be_bytes());
            self.low <<= 32;
            self.range <<= 32;
        }
    }

    #[cold]
    fn propagate_carry(&mut self) {
        for b in self.out.iter_mut().rev() {
            *b = b.wrapping_add(1);
            if *b != 0 {
                return;
            }
        }
        unreachable!("range coder carry past the first byte");
    }

    /// Flushes and appends the coded bytes to `out`.
    pub(super) fn finish(mut self, out: &mut Vec<u8>) {
        // Any value in [low, low + range) decodes the same; the one with most trailing zeros
        // lets us drop the most bytes. `low + range` may exceed 2^64: work in u128.
        let low = u128::from(self.low);
        let end = low + u128::from(self.range);
        let mut v = low;
        for k in (0..=64).rev() {
            let mask = (1u128 << k) - 1;
            let c = (low + mask) & !mask;
            if c < end {
                v = c;
                break;
            }
        }
        if v >> 64 != 0 {
            self.propagate_carry();
        }
        self.out.extend_from_slice(&(v as u64).to_be_bytes());
        let mut n = self.out.len();
        let mut dropped = 0;
        while dropped < FLUSH_SLACK && n > 0 && self.out[n - 1] == 0 {
            n -= 1;
            dropped += 1;
        }
        out.extend_from_slice(&self.out[..n]);
    }
}

/// Range decoder over a byte slice; reads past the end as zeros and counts how far it went.
///
/// `Copy`, so a hot loop can work on a local copy whose fields stay in registers.
#[derive(Clone, Copy)]
pub(super) struct WideDecoder<'a> {
    range: u64,
    code: u64,
    buf: &'a [u8],
    pos: usize,
}

impl<'a> WideDecoder<'a> {
    pub(super) fn new(buf: &'a [u8]) -> Self {
        let mut d = Self {
            range: u64::MAX,
            code: 0,
            buf,
            pos: 0,
        };
        d.code = u64::from(d.next_word()) << 32;
        d.code |= u64::from(d.next_word());
        d
    }

    /// The next 4 bytes, big-endian, zeros past the end.
    #[inline(always)]
    fn next_word(&mut self) -> u32 {
        let w = match self.buf.get(self.pos..self.pos.wrapping_add(4)) {
            Some(b) => u32::from_be_bytes([b[0], b[1], b[2], b[3]]),
            None => self.next_word_slow(),
        };
        self.pos += 4;
        w
    }

    #[cold]
    #[inline(never)]
    fn next_word_slow(&self) -> u32 {
        let mut w = 0u32;
        for i in 0..4 {
            w = (w << 8) | u32::from(self.buf.get(self.pos + i).copied().unwrap_or(0));
        }
        w
    }

    /// Decodes one decision with the probability `p0` of a zero (out of 4096); the caller
    /// updates the model. Split from [`decode`](Self::decode) so that a caller can pick the
    /// probability with a select rather than a dependent load.
    #[inline(always)]
    pub(super) fn decode_p(&mut self, p0: u32) -> bool {
        let bound = (self.range >> PROB_BITS) * u64::from(p0);
        let bit = self.code >= bound;
        // Selects rather than branches: many decisions are close to 50/50.
        let mask = 0u64.wrapping_sub(bit as u64);
        self.code -= bound & mask;
        self.range = (bound & !mask) | (self.range.wrapping_sub(bound) & mask);
        if self.range < TOP {
            self.range <<= 32;
            self.code = (self.code << 32) | u64::from(self.next_word());
        }
        bit
    }

    #[inline(always)]
    pub(super) fn decode(&mut self, prob: &mut Prob) -> bool {
        let bit = self.decode_p(prob.p0());
        prob.update(bit);
        bit
    }

    /// Whether the decoder has already invented more bytes than an encoder flush can omit.
    #[inline]
    pub(super) fn overran(&self) -> bool {
        self.pos > self.buf.len() + FLUSH_SLACK
    }

    /// Checks that the stream ended where it should.
    pub(super) fn finish(self) -> Result<(), CodecError> {
        if self.overran() {
            return Err(CodecError::truncated("adaptive tokens record ends early"));
        }
        if self.pos < self.buf.len() {
            return Err(CodecError::corrupt(format!(
                "adaptive tokens record has {} trailing bytes",
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

#[cfg(test)]
mod tests {
    use super::*;

    fn round_trip(bits: &[(u16, bool)]) -> Vec<u8> {
        let mut enc = WideEncoder::new();
        let mut probs: Vec<Prob> = bits.iter().map(|&(p, _)| Prob::new(p)).collect();
        for (p, &(_, b)) in probs.iter_mut().zip(bits) {
            enc.encode(p, b);
        }
        let mut out = Vec::new();
        enc.finish(&mut out);
        let mut dec = WideDecoder::new(&out);
        let mut probs: Vec<Prob> = bits.iter().map(|&(p, _)| Prob::new(p)).collect();
        for (i, (p, &(_, b))) in probs.iter_mut().zip(bits).enumerate() {
            assert_eq!(dec.decode(p), b, "decision {i}");
        }
        dec.finish().expect("stream ends where it should");
        out
    }

    #[test]
    fn decisions_round_trip_including_carries_and_extreme_probabilities() {
        let mut x = 0x2545_F491_4F6C_DD1Du64;
        for len in [0usize, 1, 2, 7, 64, 1000, 20_000] {
            let bits: Vec<(u16, bool)> = (0..len)
                .map(|_| {
                    x ^= x << 13;
                    x ^= x >> 7;
                    x ^= x << 17;
                    // Extreme probabilities against the odds make long carry chains likely.
                    let p = [1u16, 31, 2048, 4065, 4095][(x % 5) as usize];
                    (p, !(x >> 20).is_multiple_of(3))
                })
                .collect();
            round_trip(&bits);
        }
    }

    #[test]
    fn a_run_of_certain_decisions_costs_almost_nothing() {
        let bits = vec![(4065u16, false); 1000];
        let out = round_trip(&bits);
        assert!(out.len() <= 8, "{} bytes", out.len());
    }

    #[test]
    fn trailing_bytes_are_an_error() {
        let bits = vec![(2048u16, true); 100];
        let mut enc = WideEncoder::new();
        let mut p = Prob::new(2048);
        for &(_, b) in &bits {
            enc.encode(&mut p, b);
        }
        let mut out = Vec::new();
        enc.finish(&mut out);
        // Past anything the decoder reads, whatever the encoder dropped.
        out.extend_from_slice(&[0; 16]);
        out.push(1);
        let mut dec = WideDecoder::new(&out);
        let mut p = Prob::new(2048);
        for _ in &bits {
            dec.decode(&mut p);
        }
        assert!(dec.finish().is_err());
    }
}
