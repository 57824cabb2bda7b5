//! Affine integer maps between a diamond's grid indices and lattice coordinates, and the
//! triangulation of a diamond's grid.

use super::Half;

/// Maps grid index `(i, j)`, `0 ≤ i, j < N`, of a diamond to the lattice point
/// `origin + i·u + j·v`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GridMap {
    /// Lattice point of grid index (0, 0).
    pub origin: (i64, i64),
    /// Lattice step of `i`.
    pub u: (i64, i64),
    /// Lattice step of `j`.
    pub v: (i64, i64),
    /// Grid side `N`.
    pub n: usize,
}

/// Which grid diagonal is the diamond's split diagonal.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Diagonal {
    /// `i == j`.
    Main,
    /// `i + j == N − 1`.
    Anti,
}

impl Diagonal {
    /// Which half of an `n × n` grid split along this diagonal holds the point whose grid
    /// coordinates, times three, are `(si, sj)` (integers, so a triangle's centroid has no
    /// rounding); points on the diagonal count as [`Half::Negative`].
    pub fn half_of_centroid3(self, n: usize, si: i64, sj: i64) -> Half {
        let n1 = n as i64 - 1;
        let positive = match self {
            Diagonal::Main => si > sj,
            Diagonal::Anti => si + sj > 3 * n1,
        };
        if positive {
            Half::Positive
        } else {
            Half::Negative
        }
    }
}

/// The triangles of one half of an `n × n` diamond grid split along `diagonal`, in grid
/// coordinates `(i, j)`: every cell split parallel to the split diagonal, so that each half is a
/// union of whole grid triangles, row by row, each triangle counter-clockwise with `j` down.
///
/// The one triangulation of a diamond half: the cut's triangles ([`crate::geometry::Cut`]) and
/// the renderer's shared index lists are both made of it, so what is drawn is what the crack
/// tests check (any other split would leave T-junctions against the neighbouring halves).
pub fn half_grid_triangles(
    n: usize,
    diagonal: Diagonal,
    half: Half,
) -> impl Iterator<Item = [(i64, i64); 3]> {
    let n1 = n as i64 - 1;
    (0..n1)
        .flat_map(move |j| (0..n1).map(move |i| (i, j)))
        .flat_map(move |(i, j)| match diagonal {
            Diagonal::Main => [
                [(i, j), (i + 1, j), (i + 1, j + 1)],
                [(i, j), (i + 1, j + 1), (i, j + 1)],
            ],
            Diagonal::Anti => [
                [(i, j), (i + 1, j), (i, j + 1)],
                [(i + 1, j), (i + 1, j + 1), (i, j + 1)],
            ],
        })
        .filter(move |t| {
            let si = t[0].0 + t[1].0 + t[2].0;
            let sj = t[0].1 + t[1].1 + t[2].1;
            diagonal.half_of_centroid3(n, si, sj) == half
        })
}

impl GridMap {
    /// The lattice point of grid index `(i, j)`.
    pub fn point(&self, i: i64, j: i64) -> (i64, i64) {
        (
            self.origin.0 + i * self.u.0 + j * self.v.0,
            self.origin.1 + i * self.u.1 + j * self.v.1,
        )
    }

    /// Doubled lattice coordinates of the half-index `(i2/2, j2/2)`: cell centre `(i, j)` is
    /// `point2(2i+1, 2j+1)`. Doubling keeps it integer at the finest levels, where cell centres
    /// and edge midpoints are not lattice points.
    pub fn point2(&self, i2: i64, j2: i64) -> (i64, i64) {
        (
            2 * self.origin.0 + i2 * self.u.0 + j2 * self.v.0,
            2 * self.origin.1 + i2 * self.u.1 + j2 * self.v.1,
        )
    }

    /// Inverse of [`GridMap::point`] for a lattice point that lies on the grid.
    pub fn index_of(&self, p: (i64, i64)) -> Option<(i64, i64)> {
        let d = (p.0 - self.origin.0, p.1 - self.origin.1);
        // u and v are orthogonal with equal length, so the inverse is a pair of dot products.
        let uu = self.u.0 * self.u.0 + self.u.1 * self.u.1;
        let du = d.0 * self.u.0 + d.1 * self.u.1;
        let dv = d.0 * self.v.0 + d.1 * self.v.1;
        if du % uu != 0 || dv % uu != 0 {
            return None;
        }
        Some((du / uu, dv / uu))
    }

    /// The map from this grid's `(i, j)` into the *half-step* grid of `parent` (indices
    /// `(a, b)`, `0 ≤ a, b < 2N − 1`, vertex `(i, j)` of the parent at `(2i, 2j)`, cell centre
    /// `(i, j)` at `(2i+1, 2j+1)`).
    ///
    /// Returns `None` if the two grids are not related by such a map (i.e. `self` is not a child
    /// grid of `parent`).
    pub fn index_map_into_half_step(&self, parent: &GridMap) -> Option<IndexMap> {
        // Work in doubled lattice coordinates so the parent's half steps are integers.
        let pu = parent.u;
        let pv = parent.v;
        // In doubled coordinates the parent's half step is its full lattice step, so
        // 2·(X − O_parent) = a·pu + b·pv, and u, v orthogonal of equal length gives a and b as
        // dot products over |pu|².
        let uu = pu.0 * pu.0 + pu.1 * pu.1;
        let proj = |d: (i64, i64), w: (i64, i64)| -> Option<i64> {
            let num = d.0 * w.0 + d.1 * w.1;
            (num % uu == 0).then_some(num / uu)
        };
        let d0 = (
            2 * (self.origin.0 - parent.origin.0),
            2 * (self.origin.1 - parent.origin.1),
        );
        let su = (2 * self.u.0, 2 * self.u.1);
        let sv = (2 * self.v.0, 2 * self.v.1);
        Some(IndexMap {
            a0: proj(d0, pu)?,
            ai: proj(su, pu)?,
            aj: proj(sv, pu)?,
            b0: proj(d0, pv)?,
            bi: proj(su, pv)?,
            bj: proj(sv, pv)?,
        })
    }
}

/// `a = a0 + ai·i + aj·j`, `b = b0 + bi·i + bj·j`: where grid index `(i, j)` of a child lands in
/// a parent's half-step grid.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct IndexMap {
    /// Offset of `a`.
    pub a0: i64,
    /// `∂a/∂i`.
    pub ai: i64,
    /// `∂a/∂j`.
    pub aj: i64,
    /// Offset of `b`.
    pub b0: i64,
    /// `∂b/∂i`.
    pub bi: i64,
    /// `∂b/∂j`.
    pub bj: i64,
}

impl IndexMap {
    /// `(a, b)` of child index `(i, j)`.
    #[inline]
    pub fn apply(&self, i: i64, j: i64) -> (i64, i64) {
        (
            self.a0 + self.ai * i + self.aj * j,
            self.b0 + self.bi * i + self.bj * j,
        )
    }
}
