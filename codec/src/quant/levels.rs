//! A quantizer per level (header flag bit 5, `docs/FORMAT.md`): an `--rms-error` build may
//! quantize each level's records with its own step. With α = 1 every sample keeps the error of
//! the level that introduced it, so the surface's mean-square error is the levels' errors
//! weighted by their sample counts, and coarser steps where samples are many can pay.

use super::{MAX_K, Quantizer};
use crate::CodecError;

/// The most levels a hierarchy has: `2K` with `K < 40` ([`crate::geometry::Layout::new`]).
pub const MAX_LEVELS: usize = 80;

/// The quantizer bound `k` of each level's records: entry `l` quantizes the residuals of the
/// records of level-`l` diamonds (the samples that level `l + 1` adds), for `l = 0 … 2K − 1`.
/// The repository's single `k` is then the largest of them; the root field keeps its
/// quantizer, `⌊k / 2⌋` of that largest.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct LevelQuantizers {
    count: u8,
    k: [u32; MAX_LEVELS],
}

impl LevelQuantizers {
    /// The bounds of levels `0 … ks.len() − 1`; each at most [`MAX_K`], one to [`MAX_LEVELS`]
    /// of them.
    pub fn new(ks: &[u32]) -> Result<Self, CodecError> {
        if ks.is_empty() || ks.len() > MAX_LEVELS {
            return Err(CodecError::invalid(format!(
                "{} per-level quantizers (1 … {MAX_LEVELS})",
                ks.len()
            )));
        }
        if let Some(&k) = ks.iter().find(|&&k| k > MAX_K as u32) {
            return Err(CodecError::invalid(format!(
                "per-level quantizer half-step {k} is too large"
            )));
        }
        let mut k = [0u32; MAX_LEVELS];
        k[..ks.len()].copy_from_slice(ks);
        Ok(Self {
            count: ks.len() as u8,
            k,
        })
    }

    /// The bounds, level 0 first.
    pub fn ks(&self) -> &[u32] {
        &self.k[..usize::from(self.count)]
    }

    /// How many levels have a bound: the hierarchy's finest level.
    pub fn len(&self) -> usize {
        usize::from(self.count)
    }

    /// Never: there is at least one level.
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// The largest bound: the repository's `k`.
    pub fn max_k(&self) -> u32 {
        self.ks().iter().copied().max().unwrap_or(0)
    }

    /// Whether every level has the same bound (a build then writes the single `k`).
    pub fn uniform(&self) -> bool {
        self.ks().iter().all(|&k| k == self.k[0])
    }

    /// The quantizer of level-`level` records; `None` past the last level.
    pub fn at(&self, level: u8) -> Option<Quantizer> {
        (usize::from(level) < self.len())
            .then(|| Quantizer::from_k(self.k[usize::from(level)] as i32))
    }

    /// The L∞ bound of level `level`'s samples, units: with α = 1 a sample keeps the error of
    /// the level that added it, so it is the largest bound of the levels above, and the root
    /// field's `root_k`.
    pub fn level_bound(&self, root_k: u32, level: u8) -> u32 {
        let above = usize::from(level).min(self.len());
        self.k[..above].iter().copied().fold(root_k, u32::max)
    }
}

impl std::fmt::Debug for LevelQuantizers {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_tuple("LevelQuantizers").field(&self.ks()).finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bounds_are_read_back_and_checked() {
        let l = LevelQuantizers::new(&[1, 3, 7, 2]).unwrap();
        assert_eq!(
            (l.ks(), l.len(), l.max_k(), l.uniform()),
            (&[1, 3, 7, 2][..], 4, 7, false)
        );
        assert_eq!(l.at(2).map(|q| q.step()), Some(15));
        assert_eq!(l.at(4), None);
        // Level 0 holds the roots only; level 3's samples came from records 0 … 2.
        assert_eq!(
            (
                l.level_bound(0, 0),
                l.level_bound(0, 3),
                l.level_bound(9, 2)
            ),
            (0, 7, 9)
        );
        assert!(LevelQuantizers::new(&[]).is_err());
        assert!(LevelQuantizers::new(&[MAX_K as u32 + 1]).is_err());
        assert!(LevelQuantizers::new(&[0; MAX_LEVELS + 1]).is_err());
        assert!(LevelQuantizers::new(&[4, 4]).unwrap().uniform());
    }
}
