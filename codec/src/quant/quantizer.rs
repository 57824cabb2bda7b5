//! The residual quantizer: uniform, with odd step `2k + 1` units, its division done as a
//! multiplication.

use super::MAX_K;
use crate::CodecError;

/// Uniform quantizer with odd step `2k + 1` (in units): index `⌊(r + k) / (2k+1)⌋`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Quantizer {
    k: i32,
    /// `⌈2⁶⁴ / step⌉` (0 for step 1): division by the step as a multiplication, exact for
    /// 32-bit numerators. A 64-bit division costs tens of cycles, at one per encoded sample.
    magic: u64,
    /// `⌈FAST_INDEX_RANGE / step⌉`: numerators are shifted by this many steps.
    shift_q: i64,
}

/// Numerators `|r + k|` below this take the multiplication in [`Quantizer::index`].
pub(super) const FAST_INDEX_RANGE: i64 = 1 << 30;

impl Quantizer {
    pub(super) const fn from_k(k: i32) -> Self {
        let step = 2 * k as u64 + 1;
        let magic = if step == 1 { 0 } else { u64::MAX / step + 1 };
        let step = step as i64;
        let shift_q = (FAST_INDEX_RANGE + step - 1) / step;
        Self { k, magic, shift_q }
    }

    /// A quantizer whose reconstruction error is at most `k` units.
    pub fn new(k: u32) -> Result<Self, CodecError> {
        let k = i32::try_from(k)
            .ok()
            .filter(|&k| k <= MAX_K)
            .ok_or_else(|| CodecError::invalid(format!("quantizer half-step {k} is too large")))?;
        Ok(Self::from_k(k))
    }

    /// The error bound in units.
    pub fn k(&self) -> i32 {
        self.k
    }

    /// The step `2k + 1`.
    pub fn step(&self) -> i32 {
        2 * self.k + 1
    }

    /// The index of residual `r`. Floor division: residuals are negative half of the time, and
    /// Rust's truncating `/` would round those towards zero and break the bound.
    #[inline]
    pub fn index(&self, r: i64) -> i64 {
        let x = r + i64::from(self.k);
        let step = i64::from(self.step());
        if self.magic == 0 {
            return x;
        }
        if x.abs() >= FAST_INDEX_RANGE {
            return x.div_euclid(step);
        }
        // Shifted by a multiple of the step to a non-negative numerator below 2³², where
        // ⌊n / d⌋ = ⌊n · ⌈2⁶⁴/d⌉ / 2⁶⁴⌋ for every d < 2³² (Lemire, Kaser and Kurz 2019).
        let n = (x + self.shift_q * step) as u64;
        let q = ((u128::from(n) * u128::from(self.magic)) >> 64) as i64;
        q - self.shift_q
    }
}
