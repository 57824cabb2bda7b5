//! Variable-resolution data (paper §5, "graph construction"): several inputs on one lattice at
//! the finest input's spacing, coarser inputs sampling it at power-of-two strides.
//!
//! Every lattice point is one of three things:
//! - a **sample** of the input that wins there (the finest input with a valid sample at the
//!   point), tagged with `log2` of that input's stride: the encoder constrains it within ε;
//! - **coarse only** ([`COARSE_ONLY`]): between the samples of a coarser input that has data
//!   around it, and no finer input has a sample there. The encoder does not constrain it ("don't
//!   care" residual), but the nodata mask calls it valid: it is drawn, from the coarser level;
//! - a **hole** ([`HOLE`]): no input has data there; the mask calls it invalid (not drawn).
//!
//! A sample of stride `2^j` is a vertex of level `L − 2j` (the lattice origin is chosen so that
//! every input's samples sit on multiples of its stride), so it is constrained once that level
//! is reached. The stored set is the parent closure of, for each stride `2^j`, the level-`L−2j`
//! diamonds whose closed box holds a sample of that stride; only diamonds that are parents of a
//! stored diamond get a record. Where only coarse data exists, the hierarchy therefore stops at
//! the coarse input's level: no records for finer diamonds, and no client refines there.

use std::collections::BTreeSet;

use crate::CodecError;
use crate::geometry::{DiamondId, Domain};
use crate::quant::HeightGrid;
use crate::temp::LatticeArray;

/// Class of a lattice point between a coarser input's samples (drawn, not constrained).
pub const COARSE_ONLY: u8 = 0xFE;
/// Class of a lattice point without data (not drawn).
pub const HOLE: u8 = 0xFF;

/// What every lattice point of a variable-resolution grid is (see the module documentation).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Resolution {
    /// Row-major like the [`HeightGrid`]: `log2` of the winning input's stride at a sample,
    /// [`COARSE_ONLY`] or [`HOLE`] elsewhere.
    pub class: LatticeArray<u8>,
}

impl Resolution {
    /// Checks that `class` agrees with `grid`: samples exactly where the grid is valid, strides
    /// below 32.
    pub fn check(&self, grid: &HeightGrid) -> Result<(), CodecError> {
        if self.class.len() != grid.valid.len() {
            return Err(CodecError::invalid(
                "resolution classes do not match the grid's size",
            ));
        }
        // By windows: a mapped lattice's resident set stays one window.
        let mut agree = true;
        self.class.for_each_window(|start, class| {
            let valid = &grid.valid[start..start + class.len()];
            agree = agree
                && class.iter().zip(valid).all(|(&c, &v)| {
                    let sample = c < 32;
                    sample == v && (c < 32 || c == COARSE_ONLY || c == HOLE)
                });
            grid.valid.release(start..start + class.len());
        });
        if !agree {
            return Err(CodecError::invalid(
                "resolution classes disagree with the grid's valid samples",
            ));
        }
        Ok(())
    }

    /// Whether lattice point `(x, y)` (inside the grid) is drawn: a sample or coarse only.
    #[inline]
    pub fn drawn(&self, width: usize, x: i64, y: i64) -> bool {
        self.class[y as usize * width + x as usize] != HOLE
    }

    /// The classes of the rectangle `(x0, y0, x1, y1)` of a grid `width` wide in an array of
    /// the same length that holds nothing else (0 elsewhere: meaningless, so read only inside
    /// the rectangle, as under a [`HeightGrid::window`] of it).
    pub fn window(&self, width: usize, rect: (i64, i64, i64, i64)) -> Result<Self, CodecError> {
        Ok(Self {
            class: self.class.window(width, rect)?,
        })
    }

    /// The classes at multiples of `2^shift` of a grid `width` wide, as
    /// [`HeightGrid::strided`] makes its samples.
    pub fn strided(&self, width: usize, shift: u32) -> Result<Self, CodecError> {
        Ok(Self {
            class: self.class.strided(width, shift)?,
        })
    }

    /// Whether some point has no data at all.
    pub fn has_holes(&self) -> bool {
        self.class.any(|&c| c == HOLE)
    }
}

/// The stored diamonds of every level and, per level, which of them get a record (the parents
/// of stored diamonds of the next level).
pub(crate) struct VariableSets {
    pub stored: Vec<Vec<DiamondId>>,
    pub recorded: Vec<BTreeSet<DiamondId>>,
}

/// The stored sets of a variable-resolution grid (module documentation).
pub(crate) fn variable_sets(domain: &Domain, width: usize, res: &Resolution) -> VariableSets {
    let layout = domain.layout();
    let height = res.class.len() / width.max(1);
    let finest = layout.finest_level();
    let (ex, ey) = layout.face_extent();
    let mut present = [false; 32];
    res.class.for_each_window(|_, class| {
        for &c in class {
            if c < 32 {
                present[usize::from(c)] = true;
            }
        }
    });
    let strides = (0..32u8).filter(|&j| present[usize::from(j)]);
    let mut leaves: Vec<BTreeSet<DiamondId>> = vec![BTreeSet::new(); finest as usize + 1];
    for j in strides {
        // Strides above the root spacing are root points: their leaves are roots.
        let level = finest.saturating_sub(2 * j);
        let r = layout.radius(level) as usize;
        let count = |extent: i64, len: usize| {
            let in_domain = (extent as usize).div_ceil(2 * r);
            let reaching_data = len.saturating_sub(1) / (2 * r) + 1;
            in_domain.min(reaching_data)
        };
        let (nx, ny) = (count(ex, width), count(ey, height));
        for b in 0..ny {
            for a in 0..nx {
                let (x0, x1) = (2 * a * r, ((2 * a + 2) * r).min(width - 1));
                let (y0, y1) = (2 * b * r, ((2 * b + 2) * r).min(height - 1));
                let hit =
                    (y0..=y1).any(|y| res.class[y * width + x0..=y * width + x1].contains(&j));
                res.class.touched_rows(y1 - y0 + 1, x1 - x0 + 1);
                if hit {
                    let (cx, cy) = ((2 * a + 1) * r, (2 * b + 1) * r);
                    leaves[level as usize].insert(DiamondId::new(level, cx as u32, cy as u32));
                }
            }
        }
    }
    with_parents(domain, &leaves)
}

/// The stored sets of leaves at several levels (`leaves[l]`: the leaves of level `l`): every
/// leaf and all its ancestors (across face edges on a cube-sphere); the recorded ones are those
/// with a stored child.
pub(crate) fn with_parents(domain: &Domain, leaves: &[BTreeSet<DiamondId>]) -> VariableSets {
    let finest = leaves.len() - 1;
    let mut stored = vec![Vec::new(); finest + 1];
    let mut recorded = vec![BTreeSet::new(); finest + 1];
    stored[finest] = leaves[finest].iter().copied().collect();
    for level in (0..finest).rev() {
        let parents: BTreeSet<DiamondId> = stored[level + 1]
            .iter()
            .flat_map(|&d| domain.parents(d))
            .flatten()
            .collect();
        stored[level] = parents.union(&leaves[level]).copied().collect();
        recorded[level] = parents;
    }
    VariableSets { stored, recorded }
}
