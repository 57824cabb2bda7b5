//! Hash maps and sets keyed by diamond ids, with a fast hasher.
//!
//! The refinement loop looks ids up tens of thousands of times per frame (is it refined, what
//! is its error, is it being decoded); with the standard library's SipHash those lookups were
//! a third of the loop's time on a 16385² repository. The ids are made by the program itself,
//! so SipHash's resistance to chosen keys buys nothing here.

use std::collections::{HashMap, HashSet};
use std::hash::{BuildHasherDefault, Hasher};

use super::DiamondId;

/// Multiply–rotate hashing of the id's fields (FxHash's step) with a 64-bit finaliser
/// (MurmurHash3's fmix64), so that ids differing only in high bits — coarse levels are
/// multiples of large powers of two — still spread over the table's low bits.
#[derive(Clone, Copy, Debug, Default)]
pub struct IdHasher(u64);

impl IdHasher {
    #[inline]
    fn add(&mut self, word: u64) {
        self.0 = (self.0.rotate_left(5) ^ word).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
}

impl Hasher for IdHasher {
    #[inline]
    fn finish(&self) -> u64 {
        let mut h = self.0;
        h ^= h >> 33;
        h = h.wrapping_mul(0xff51_afd7_ed55_8ccd);
        h ^= h >> 33;
        h = h.wrapping_mul(0xc4ce_b9fe_1a85_ec53);
        h ^ (h >> 33)
    }
    #[inline]
    fn write(&mut self, bytes: &[u8]) {
        for chunk in bytes.chunks(8) {
            let mut w = [0u8; 8];
            w[..chunk.len()].copy_from_slice(chunk);
            self.add(u64::from_le_bytes(w));
        }
    }
    #[inline]
    fn write_u8(&mut self, v: u8) {
        self.add(u64::from(v));
    }
    #[inline]
    fn write_u32(&mut self, v: u32) {
        self.add(u64::from(v));
    }
    #[inline]
    fn write_u64(&mut self, v: u64) {
        self.add(v);
    }
    #[inline]
    fn write_usize(&mut self, v: usize) {
        self.add(v as u64);
    }
}

/// The hasher's builder.
pub type IdBuildHasher = BuildHasherDefault<IdHasher>;
/// A map keyed by diamond ids.
pub type IdMap<V> = HashMap<DiamondId, V, IdBuildHasher>;
/// A set of diamond ids.
pub type IdSet = HashSet<DiamondId, IdBuildHasher>;

#[cfg(test)]
mod tests {
    use super::*;
    use std::hash::BuildHasher;

    #[test]
    fn ids_spread_over_low_bits() {
        // Coarse-level ids: centres on multiples of 2^12. A table of 4096 buckets indexes by
        // the low 12 bits; they must not collapse onto a few buckets.
        let b = IdBuildHasher::default();
        let mut buckets = std::collections::HashSet::new();
        let mut n = 0;
        for x in 0..64u32 {
            for y in 0..64u32 {
                let id = DiamondId::new(4, x << 12, y << 12);
                buckets.insert(b.hash_one(id) & 4095);
                n += 1;
            }
        }
        // Random hashing fills about 1 − 1/e ≈ 63 % of 4096 buckets with 4096 keys.
        assert!(
            buckets.len() > n * 55 / 100,
            "{} of {n} buckets",
            buckets.len()
        );
        let mut set = IdSet::default();
        assert!(set.insert(DiamondId::new(1, 2, 3)) && !set.insert(DiamondId::new(1, 2, 3)));
        assert!(set.contains(&DiamondId::new(1, 2, 3)) && !set.contains(&DiamondId::new(1, 3, 2)));
    }
}
