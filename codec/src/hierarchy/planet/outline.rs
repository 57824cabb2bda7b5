//! The outline of a planet ([`PlanetOutline`]): what the block-wise encode needs of the whole
//! planet — the leaves its tiles' points make, whether some point is a hole and whether any has
//! data — gathered one tile at a time without holding the tiles.

use std::collections::BTreeSet;

use super::{PlanetGrid, PlanetTile, tile_leaves};
use crate::CodecError;
use crate::geometry::{DiamondId, Domain};
use crate::hierarchy::resolution::HOLE;

/// What the block-wise encode needs of the whole planet, gathered tile by tile
/// ([`PlanetOutline::add`]) without holding the tiles.
#[derive(Clone, Debug)]
pub struct PlanetOutline {
    pub(super) domain: Domain,
    pub(super) tile_log2: u32,
    pub(super) variable: bool,
    pub(super) leaves: Vec<BTreeSet<DiamondId>>,
    pub(super) has_nodata: bool,
    pub(super) has_data: bool,
}

impl PlanetOutline {
    /// The outline of an `n`, `k` planet in tiles of `2^tile_log2` steps, with resolution
    /// classes when `variable`, before any tile is added.
    pub fn new(n: usize, k: u32, tile_log2: u32, variable: bool) -> Result<Self, CodecError> {
        let domain = Domain::cube_sphere(n, k)?;
        Ok(Self {
            domain,
            tile_log2,
            variable,
            leaves: vec![BTreeSet::new(); usize::from(domain.finest_level()) + 1],
            has_nodata: false,
            has_data: false,
        })
    }

    /// The outline of a whole planet.
    pub fn of_planet(planet: &PlanetGrid) -> Self {
        let d = planet.domain();
        let mut out = Self::new(
            d.n(),
            d.layout().k(),
            planet.tile_log2(),
            planet.is_variable(),
        )
        .expect("a planet's own lattice");
        for face in 0..d.faces() {
            for t in planet.tiles(face) {
                out.add(face, t);
            }
        }
        out
    }

    /// Adds tile `t` of face `face` (at its own stride).
    pub fn add(&mut self, face: u8, t: &PlanetTile) {
        for (all, some) in self
            .leaves
            .iter_mut()
            .zip(tile_leaves(&self.domain, face, t))
        {
            all.extend(some);
        }
        self.has_nodata |= match &t.class {
            Some(class) => class.contains(&HOLE),
            None => !t.bounds().1,
        };
        self.has_data |= t.grid.range().is_some();
    }

    /// Adds what another outline of the same planet gathered (tiles outlined apart).
    pub fn merge(&mut self, other: PlanetOutline) {
        for (all, some) in self.leaves.iter_mut().zip(other.leaves) {
            all.extend(some);
        }
        self.has_nodata |= other.has_nodata;
        self.has_data |= other.has_data;
    }

    /// The planet's cube-sphere.
    pub fn domain(&self) -> &Domain {
        &self.domain
    }

    /// `log2` of the side of the planet's tiles.
    pub fn tile_log2(&self) -> u32 {
        self.tile_log2
    }

    /// Whether the tiles carry resolution classes.
    pub fn is_variable(&self) -> bool {
        self.variable
    }

    /// Per level, the leaves the tiles' points make.
    pub fn leaves(&self) -> &[BTreeSet<DiamondId>] {
        &self.leaves
    }

    /// Whether some point is a hole, and whether any has data.
    pub fn has_nodata_and_data(&self) -> (bool, bool) {
        (self.has_nodata, self.has_data)
    }

    /// The outline `new(n, k, tile_log2, variable)` gathers when its tiles make `leaves`
    /// (one set per level, root to finest) and hold a hole (`has_nodata`) and data
    /// (`has_data`): an outline written out and read back.
    pub fn from_parts(
        (n, k, tile_log2, variable): (usize, u32, u32, bool),
        leaves: Vec<BTreeSet<DiamondId>>,
        has_nodata: bool,
        has_data: bool,
    ) -> Result<Self, CodecError> {
        let mut out = Self::new(n, k, tile_log2, variable)?;
        if leaves.len() != out.leaves.len() {
            return Err(CodecError::invalid(format!(
                "an outline of {} levels for a planet of {}",
                leaves.len(),
                out.leaves.len()
            )));
        }
        out.leaves = leaves;
        out.has_nodata = has_nodata;
        out.has_data = has_data;
        Ok(out)
    }
}
