//! Adaptive coding of loose integers (not bands) on the same range coder: used by the record
//! index of format version 2, whose fields — empty-record flags, lengths, object errors and
//! height ranges relative to the parent — are small, skewed and alike from one entry to the next,
//! so a few adaptive models code them in a fraction of a byte each where varints need a byte.
//!
//! An unsigned `v` is coded as Exp-Golomb: the bit length `e` of `v + 1` minus one in adaptive
//! unary (one model per position, the last shared), then the `e` bits below its leading one,
//! the top two adaptive (per `e`) and the rest bypass. A signed value is a zero flag, an adaptive
//! sign and the magnitude minus one as unsigned. Both ends build the same models from the same
//! decisions, so a stream is only decodable with the model layout that wrote it.

use super::range_coder::{Decoder, Encoder, Prob};
use crate::CodecError;

/// Unary positions with their own model; later ones share the last.
const EXP_MODELS: usize = 12;
/// Values are below 2^64, so the unary exponent stops at 64.
const MAX_EXP: u32 = 64;

/// The models of one unsigned field.
#[derive(Clone, Debug)]
pub(crate) struct UintModel {
    exp: [Prob; EXP_MODELS],
    mant: [Prob; 2 * EXP_MODELS],
}

impl Default for UintModel {
    fn default() -> Self {
        Self {
            exp: [Prob::new(2048); EXP_MODELS],
            mant: [Prob::new(2048); 2 * EXP_MODELS],
        }
    }
}

/// The models of one signed field.
#[derive(Clone, Debug)]
pub(crate) struct IntModel {
    zero: Prob,
    sign: Prob,
    magnitude: UintModel,
}

impl Default for IntModel {
    fn default() -> Self {
        Self {
            zero: Prob::new(2048),
            sign: Prob::new(2048),
            magnitude: UintModel::default(),
        }
    }
}

/// One adaptive binary decision's model, for flags.
#[derive(Clone, Copy, Debug)]
pub(crate) struct FlagModel(Prob);

impl Default for FlagModel {
    fn default() -> Self {
        Self(Prob::new(2048))
    }
}

/// Writes adaptive integers and flags into one range-coded stream.
pub(crate) struct IntEncoder {
    enc: Encoder,
}

impl IntEncoder {
    pub(crate) fn new() -> Self {
        Self {
            enc: Encoder::new(),
        }
    }

    pub(crate) fn flag(&mut self, m: &mut FlagModel, on: bool) {
        self.enc.encode(&mut m.0, on);
    }

    pub(crate) fn uint(&mut self, m: &mut UintModel, v: u64) {
        // v + 1 in u128 so that u64::MAX has a bit length like any other value.
        let w = u128::from(v) + 1;
        let e = 127 - w.leading_zeros();
        for i in 0..e {
            self.enc
                .encode(&mut m.exp[(i as usize).min(EXP_MODELS - 1)], true);
        }
        if e < MAX_EXP {
            self.enc
                .encode(&mut m.exp[(e as usize).min(EXP_MODELS - 1)], false);
        }
        let ctx = 2 * (e as usize).min(EXP_MODELS - 1);
        let mut rest = e;
        for j in 0..2.min(e) {
            rest -= 1;
            let bit = (w >> rest) & 1 == 1;
            self.enc.encode(&mut m.mant[ctx + j as usize], bit);
        }
        while rest > 0 {
            let n = rest.min(16);
            rest -= n;
            self.enc
                .encode_bypass(((w >> rest) & ((1 << n) - 1)) as u32, n);
        }
    }

    pub(crate) fn int(&mut self, m: &mut IntModel, v: i64) {
        self.enc.encode(&mut m.zero, v != 0);
        if v != 0 {
            self.enc.encode(&mut m.sign, v < 0);
            self.uint(&mut m.magnitude, v.unsigned_abs() - 1);
        }
    }

    /// Flushes and appends the stream to `out`.
    pub(crate) fn finish(self, out: &mut Vec<u8>) {
        self.enc.finish(out);
    }
}

/// Reads what [`IntEncoder`] wrote. Past the end of its bytes it reads zeros; every method
/// returns a truncation error once it has read further than a valid stream could need, so a
/// caller's loop over decoded counts stays bounded by the input's length.
pub(crate) struct IntDecoder<'a> {
    dec: Decoder<'a>,
}

impl<'a> IntDecoder<'a> {
    pub(crate) fn new(bytes: &'a [u8]) -> Result<Self, CodecError> {
        Ok(Self {
            dec: Decoder::new(bytes)?,
        })
    }

    fn check(&self) -> Result<(), CodecError> {
        if self.dec.overran() {
            Err(CodecError::truncated("index stream ends early"))
        } else {
            Ok(())
        }
    }

    pub(crate) fn flag(&mut self, m: &mut FlagModel) -> Result<bool, CodecError> {
        let on = self.dec.decode(&mut m.0);
        self.check()?;
        Ok(on)
    }

    pub(crate) fn uint(&mut self, m: &mut UintModel) -> Result<u64, CodecError> {
        let mut e = 0u32;
        while e < MAX_EXP
            && self
                .dec
                .decode(&mut m.exp[(e as usize).min(EXP_MODELS - 1)])
        {
            e += 1;
            self.check()?;
        }
        let ctx = 2 * (e as usize).min(EXP_MODELS - 1);
        let mut w: u128 = 1;
        let mut rest = e;
        for j in 0..2.min(e) {
            rest -= 1;
            w = (w << 1) | u128::from(self.dec.decode(&mut m.mant[ctx + j as usize]));
        }
        while rest > 0 {
            let n = rest.min(16);
            rest -= n;
            w = (w << n) | u128::from(self.dec.decode_bypass(n));
        }
        self.check()?;
        u64::try_from(w - 1).map_err(|_| CodecError::corrupt("index number longer than 64 bits"))
    }

    pub(crate) fn int(&mut self, m: &mut IntModel) -> Result<i64, CodecError> {
        if !self.dec.decode(&mut m.zero) {
            self.check()?;
            return Ok(0);
        }
        let negative = self.dec.decode(&mut m.sign);
        let magnitude = self.uint(&mut m.magnitude)?;
        // |v| − 1 is at most 2^63 − 2 for positive v and 2^63 − 1 for negative (i64::MIN); a
        // hostile stream can say more, which must be an error, not an overflow.
        let out_of_range = || CodecError::corrupt("index number out of range");
        let m1 = i64::try_from(magnitude).map_err(|_| out_of_range())?;
        if negative {
            Ok(-m1 - 1)
        } else {
            m1.checked_add(1).ok_or_else(out_of_range)
        }
    }

    /// Checks that the stream ended where it should: no bytes left over, none missing.
    pub(crate) fn finish(self) -> Result<(), CodecError> {
        self.dec.finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn values() -> Vec<i64> {
        let mut v = vec![
            0,
            1,
            -1,
            2,
            -2,
            3,
            100,
            -100,
            i64::MAX,
            i64::MIN,
            i64::MIN + 1,
        ];
        v.extend((0..64).map(|s| 1i64 << s.min(62)));
        v.extend((0..64).map(|s| -(1i64 << s.min(62)) - 1));
        v
    }

    #[test]
    fn integers_and_flags_round_trip_including_extremes() {
        let ints = values();
        let uints: Vec<u64> = [0, 1, 2, 3, u64::MAX, u64::MAX - 1, 1 << 63]
            .into_iter()
            .chain((0..64).map(|s| (1u64 << s) - 1))
            .collect();
        let mut enc = IntEncoder::new();
        let (mut mi, mut mu, mut mf) = (
            IntModel::default(),
            UintModel::default(),
            FlagModel::default(),
        );
        for (k, &v) in ints.iter().enumerate() {
            enc.int(&mut mi, v);
            enc.flag(&mut mf, k % 3 == 0);
        }
        for &u in &uints {
            enc.uint(&mut mu, u);
        }
        let mut bytes = Vec::new();
        enc.finish(&mut bytes);
        let mut dec = IntDecoder::new(&bytes).unwrap();
        let (mut mi, mut mu, mut mf) = (
            IntModel::default(),
            UintModel::default(),
            FlagModel::default(),
        );
        for (k, &v) in ints.iter().enumerate() {
            assert_eq!(dec.int(&mut mi).unwrap(), v);
            assert_eq!(dec.flag(&mut mf).unwrap(), k % 3 == 0);
        }
        for &u in &uints {
            assert_eq!(dec.uint(&mut mu).unwrap(), u);
        }
        dec.finish().unwrap();
    }

    #[test]
    fn magnitudes_beyond_i64_are_errors_not_overflows() {
        // What only a hostile stream holds: a positive value of magnitude 2^63 (and larger).
        for magnitude in [i64::MAX as u64, u64::MAX] {
            let mut enc = IntEncoder::new();
            let mut m = IntModel::default();
            enc.enc.encode(&mut m.zero, true);
            enc.enc.encode(&mut m.sign, false);
            enc.uint(&mut m.magnitude, magnitude);
            let mut bytes = Vec::new();
            enc.finish(&mut bytes);
            let mut dec = IntDecoder::new(&bytes).unwrap();
            assert!(dec.int(&mut IntModel::default()).is_err(), "{magnitude}");
        }
    }

    #[test]
    fn runs_of_small_values_cost_well_under_a_byte_each() {
        let mut enc = IntEncoder::new();
        let mut m = IntModel::default();
        for k in 0..1000 {
            enc.int(&mut m, [0, 0, 1, 0, -1, 0, 0, 2][k % 8]);
        }
        let mut bytes = Vec::new();
        enc.finish(&mut bytes);
        assert!(bytes.len() < 300, "{} bytes for 1000 values", bytes.len());
    }

    #[test]
    fn arbitrary_bytes_decode_to_values_or_errors() {
        for seed in 0..3000u64 {
            let junk = crate::test_junk(seed, seed % 40);
            let Ok(mut dec) = IntDecoder::new(&junk) else {
                continue;
            };
            let (mut mi, mut mu) = (IntModel::default(), UintModel::default());
            // Bounded: past the end every call errors.
            for _ in 0..10_000 {
                if dec.int(&mut mi).is_err() || dec.uint(&mut mu).is_err() {
                    break;
                }
            }
        }
    }
}
