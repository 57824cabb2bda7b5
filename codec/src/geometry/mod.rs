//! The diamond hierarchy (4-8 / bintree) laid over an integer lattice.
//!
//! Every diamond is identified by its level and its centre on a global integer lattice whose unit
//! is the sample spacing of the finest level (the input grid). Even levels are axis-aligned
//! squares, odd levels squares rotated by 45°; each diamond carries an `N × N` vertex grid that
//! maps to lattice points by an affine *integer* map ([`GridMap`]). Parent/child relations,
//! grid gathering and triangulation are therefore index arithmetic: no floating point anywhere
//! in the hierarchy logic.
//!
//! Conventions (lattice units, `S0 = (N−1)·2^K` the root side, `L = 2K` the finest level):
//! - level `2m` (even): squares of half-side `r = S0 / 2^(m+1)`, centres `((2i+1)r, (2j+1)r)`;
//! - level `2m+1` (odd): squares rotated 45° with half-diagonal `R = S0 / 2^(m+1)`, centred on
//!   the midpoints of the sides of the level-`2m` squares.
//!
//! Refining a diamond splits it at its centre; its 4 children are centred on the midpoints of
//! its 4 sides. A child's *split diagonal* is the side its two parents share.

pub mod cube;
mod cut;
mod diamond;
mod domain;
mod grid;
mod id_hash;
mod layout;

pub use cube::{Cube, FacePoint};
pub use cut::{Cut, FaceTriangle, Triangle, check_conforming, check_conforming_surface};
pub use diamond::{DiamondId, Half};
pub use domain::{DataRect, Domain, DomainKind, RootField};
pub use grid::{Diagonal, GridMap, IndexMap, half_grid_triangles};
pub use id_hash::{IdBuildHasher, IdHasher, IdMap, IdSet};
pub use layout::Layout;
