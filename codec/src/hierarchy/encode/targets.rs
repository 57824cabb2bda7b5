//! What the encoder aims for: the filtered height at each lattice point of a level, and what
//! the nodata mask says of it.

use crate::hierarchy::CodecParams;
use crate::hierarchy::analysis::LevelField;
use crate::hierarchy::resolution::Resolution;
use crate::quant::HeightGrid;

/// The filtered height the encoder aims for at a lattice point of a level, `None` where it is
/// "don't care" (outside the data or at nodata).
pub(super) struct Targets<'a> {
    pub(super) grid: &'a HeightGrid,
    pub(super) fields: Option<Vec<LevelField>>,
    /// Variable-resolution classes: points without a sample may still be drawn.
    pub(super) resolution: Option<&'a Resolution>,
    /// `grid` (and `resolution`) hold only the points at multiples of `2^shift`, compacted
    /// ([`HeightGrid::strided`]): the levels above a block plan's cut read no others.
    pub(super) shift: u32,
}

impl Targets<'_> {
    /// Whether the nodata mask calls `(x, y)` (inside the data rectangle) valid: a sample, or a
    /// point between a coarser input's samples.
    #[inline]
    pub(super) fn drawn(&self, x: i64, y: i64) -> bool {
        let (x, y) = self.compact(x, y);
        match self.resolution {
            Some(r) => r.drawn(self.grid.width, x, y),
            None => self.grid.get(x, y).is_some(),
        }
    }

    /// `(x, y)` in `grid`'s points.
    #[inline]
    pub(super) fn compact(&self, x: i64, y: i64) -> (i64, i64) {
        let mask = (1i64 << self.shift) - 1;
        debug_assert!(
            x & mask == 0 && y & mask == 0,
            "({x}, {y}) is not on the targets' lattice of spacing 2^{}",
            self.shift
        );
        (x >> self.shift, y >> self.shift)
    }

    /// What the nodata mask says of `(x, y)`: `None` (don't care) outside the data rectangle.
    #[inline]
    pub(super) fn mask(&self, params: &CodecParams, x: i64, y: i64) -> Option<bool> {
        params
            .domain
            .data()
            .contains(x, y)
            .then(|| self.drawn(x, y))
    }

    /// Drops the resident pages of a mapped input ([`HeightGrid::release_all`]).
    pub(super) fn release_all(&self) {
        self.grid.release_all();
        if let Some(r) = self.resolution {
            r.class.release(0..r.class.len());
        }
    }

    #[inline]
    pub(super) fn at(&self, level: u8, x: i64, y: i64) -> Option<i32> {
        match &self.fields {
            // A valid sample lies in the data rectangle, inside the domain: no reflection, and
            // the input's own value is not needed.
            Some(f) => self
                .grid
                .is_valid(x, y)
                .then(|| f[level as usize].get_in_domain(x, y)),
            None => {
                let (x, y) = self.compact(x, y);
                self.grid.get(x, y)
            }
        }
    }
}
