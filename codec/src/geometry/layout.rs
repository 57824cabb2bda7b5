//! The index arithmetic of the hierarchy on one face: a rectangle of level-0 squares.

use super::{Diagonal, DiamondId, GridMap, Half};
use crate::CodecError;

/// Smallest and largest diamond grid side the format accepts. 3 is the smallest grid with a
/// centre; beyond 1025 a single record would hold a million residuals, too coarse a grain for
/// streaming.
pub const MIN_N: usize = 3;
/// See [`MIN_N`].
pub const MAX_N: usize = 1025;

/// The diamond hierarchy over one face: a `roots_x × roots_y` grid of level-0 squares.
///
/// It knows the integer arithmetic every face shares (grids, radii, bounds, which centres exist
/// and how they relate inside the face). The shape of the whole surface — how many faces, how
/// they connect, where data lies — belongs to [`super::Domain`], which callers ask about
/// existence and relations.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Layout {
    n: usize,
    k: u32,
    roots_x: u32,
    roots_y: u32,
}

impl Layout {
    /// A layout of `roots_x × roots_y` roots with `N × N` grids and finest level `2K`.
    pub fn new(n: usize, k: u32, roots_x: u32, roots_y: u32) -> Result<Self, CodecError> {
        if !(MIN_N..=MAX_N).contains(&n) || !(n - 1).is_power_of_two() {
            return Err(CodecError::invalid(format!(
                "diamond size {n} must be 2^k + 1 between {MIN_N} and {MAX_N}"
            )));
        }
        if roots_x == 0 || roots_y == 0 {
            return Err(CodecError::invalid("a layout needs at least one root"));
        }
        let side = ((n as u64) - 1).checked_shl(k).filter(|_| k < 40);
        let fits = side
            .and_then(|s| s.checked_mul(u64::from(roots_x.max(roots_y))))
            .is_some_and(|e| e < u64::from(u32::MAX));
        if !fits {
            return Err(CodecError::limit(format!(
                "a {roots_x}×{roots_y} layout of {n}-grids with {k} level pairs does not fit a 32-bit lattice"
            )));
        }
        Ok(Self {
            n,
            k,
            roots_x,
            roots_y,
        })
    }

    /// The layout whose finest level lies on a `width × height` sample grid, with one root along
    /// the longer side — or, with `extra_level_pairs > 0`, that many level pairs more, so roots
    /// are `4^extra` times sparser (coarse levels code terrain more cheaply than root values do).
    pub fn covering(
        n: usize,
        width: usize,
        height: usize,
        extra_level_pairs: u32,
    ) -> Result<Self, CodecError> {
        if width == 0 || height == 0 {
            return Err(CodecError::invalid(
                "cannot lay diamonds over an empty grid",
            ));
        }
        let span = (width.max(height) - 1) as u64;
        let mut k = 0u32;
        while ((n as u64 - 1) << k) < span {
            k += 1;
            if k > 32 {
                return Err(CodecError::limit("grid too large"));
            }
        }
        k += extra_level_pairs;
        let side = (n as u64 - 1) << k;
        let roots = |len: usize| (((len as u64).saturating_sub(1)).div_ceil(side)).max(1) as u32;
        Self::new(n, k, roots(width), roots(height))
    }

    /// Grid side `N`.
    pub fn n(&self) -> usize {
        self.n
    }
    /// `K`: the finest level is `2K`.
    pub fn k(&self) -> u32 {
        self.k
    }
    /// Number of roots along x.
    pub fn roots_x(&self) -> u32 {
        self.roots_x
    }
    /// Number of roots along y.
    pub fn roots_y(&self) -> u32 {
        self.roots_y
    }
    /// The finest level, `2K`, whose grids sample the lattice at unit spacing.
    pub fn finest_level(&self) -> u8 {
        (2 * self.k) as u8
    }
    /// Side of a root square in lattice units, `S0 = (N − 1)·2^K`.
    #[inline]
    pub fn root_side(&self) -> i64 {
        ((self.n - 1) as i64) << self.k
    }
    /// Number of roots along x and y.
    pub fn root_counts(&self) -> (u32, u32) {
        (self.roots_x, self.roots_y)
    }
    /// Lattice extent of the face: `[0, ex] × [0, ey]`.
    #[inline]
    pub fn face_extent(&self) -> (i64, i64) {
        let s = self.root_side();
        (s * i64::from(self.roots_x), s * i64::from(self.roots_y))
    }

    /// Half-side (even level) or half-diagonal (odd level) of a level's diamonds: a power of
    /// two, at least 1 up to the finest level.
    #[inline]
    pub fn radius(&self, level: u8) -> i64 {
        self.root_side() >> (u32::from(level) / 2 + 1)
    }

    /// Every diamond of `level` on the face, in id order (by centre x, then y).
    pub fn level(&self, level: u8) -> impl Iterator<Item = DiamondId> + '_ {
        let r = self.radius(level.min(self.finest_level()));
        let (ex, ey) = self.face_extent();
        let valid = level <= self.finest_level();
        let step = r as usize;
        (0..=ex)
            .step_by(step)
            .filter(move |_| valid)
            .flat_map(move |x| {
                (0..=ey)
                    .step_by(step)
                    .map(move |y| DiamondId::new(level, x as u32, y as u32))
            })
            .filter(move |&id| self.contains(id))
    }

    /// Whether `id` is a diamond of this hierarchy (possibly one that sticks out of the domain).
    #[inline]
    pub fn contains(&self, id: DiamondId) -> bool {
        if id.level > self.finest_level() {
            return false;
        }
        let r = self.radius(id.level);
        let (x, y) = (i64::from(id.x), i64::from(id.y));
        let (ex, ey) = self.face_extent();
        // r is a power of two and x, y are not negative: `v & mask` is `v % 2r`, without the
        // division (this test runs for every relation the refinement loop asks for).
        let mask = 2 * r - 1;
        let (mx, my) = (x & mask, y & mask);
        if id.is_even() {
            mx == r && my == r && x < ex && y < ey
        } else {
            let on_horizontal = mx == r && my == 0;
            let on_vertical = mx == 0 && my == r;
            (on_horizontal || on_vertical) && x <= ex && y <= ey
        }
    }

    /// The roots, row by row.
    pub fn roots(&self) -> impl Iterator<Item = DiamondId> + '_ {
        let r = self.radius(0);
        (0..i64::from(self.roots_y)).flat_map(move |j| {
            (0..i64::from(self.roots_x))
                .map(move |i| DiamondId::new(0, ((2 * i + 1) * r) as u32, ((2 * j + 1) * r) as u32))
        })
    }

    /// Lattice offsets from the centre to the two parents' centres, `[positive, negative]`,
    /// and the split diagonal. Level 0 has no parents; its diagonal is chosen the same way as at
    /// other even levels.
    #[inline]
    pub(super) fn parent_offsets(&self, id: DiamondId) -> ([(i64, i64); 2], Diagonal) {
        let r = self.radius(id.level);
        let (x, y) = (i64::from(id.x), i64::from(id.y));
        if id.is_even() {
            // Centres are ((2i+1)r, (2j+1)r); the split diagonal runs along (1, 1) when i + j is
            // even, because then c + r·(1, −1) is an odd-level centre (a parent).
            let ij = (x / r - 1) / 2 + (y / r - 1) / 2;
            if ij % 2 == 0 {
                ([(r, -r), (-r, r)], Diagonal::Main)
            } else {
                ([(r, r), (-r, -r)], Diagonal::Anti)
            }
        } else if x % (2 * r) == r {
            // On a horizontal side of the coarser level: the side is the split diagonal and the
            // parents sit above and below it.
            ([(0, r), (0, -r)], Diagonal::Main)
        } else {
            ([(r, 0), (-r, 0)], Diagonal::Anti)
        }
    }

    /// The split diagonal of a diamond in its own grid coordinates.
    pub fn diagonal(&self, id: DiamondId) -> Diagonal {
        self.parent_offsets(id).1
    }

    /// The two parents, `[positive half's, negative half's]`; `None` for roots and for the
    /// missing parent of a diamond on the domain's edge.
    pub fn parents(&self, id: DiamondId) -> [Option<DiamondId>; 2] {
        if id.level == 0 {
            return [None, None];
        }
        let (offsets, _) = self.parent_offsets(id);
        offsets.map(|o| self.at(id.level - 1, id, o))
    }

    /// The up to 4 children (fewer on the domain's edge, none at the finest level).
    pub fn children(&self, id: DiamondId) -> [Option<DiamondId>; 4] {
        if id.level >= self.finest_level() {
            return [None; 4];
        }
        self.child_offsets(id).map(|o| self.at(id.level + 1, id, o))
    }

    /// Lattice offsets from the centre to the 4 children's centres (the midpoints of the
    /// diamond's sides).
    #[inline]
    pub(super) fn child_offsets(&self, id: DiamondId) -> [(i64, i64); 4] {
        let r = self.radius(id.level);
        if id.is_even() {
            [(r, 0), (0, r), (-r, 0), (0, -r)]
        } else {
            let h = r / 2;
            [(h, h), (-h, h), (-h, -h), (h, -h)]
        }
    }

    /// The diamonds of the same level that share a side with `id` (up to 4).
    pub fn neighbours(&self, id: DiamondId) -> [Option<DiamondId>; 4] {
        self.neighbour_offsets(id).map(|o| self.at(id.level, id, o))
    }

    /// Lattice offsets from the centre to the 4 same-level diamonds sharing a side.
    #[inline]
    pub(super) fn neighbour_offsets(&self, id: DiamondId) -> [(i64, i64); 4] {
        let r = self.radius(id.level);
        if id.is_even() {
            [(2 * r, 0), (0, 2 * r), (-2 * r, 0), (0, -2 * r)]
        } else {
            [(r, r), (-r, r), (-r, -r), (r, -r)]
        }
    }

    fn at(&self, level: u8, from: DiamondId, o: (i64, i64)) -> Option<DiamondId> {
        let x = i64::from(from.x) + o.0;
        let y = i64::from(from.y) + o.1;
        let id = DiamondId::on_face(
            from.face,
            level,
            u32::try_from(x).ok()?,
            u32::try_from(y).ok()?,
        );
        self.contains(id).then_some(id)
    }

    /// The affine map of the diamond's `N × N` grid onto the lattice.
    ///
    /// Even levels: origin at the corner of smallest coordinates `c − (r, r)`, `u = (h, 0)`,
    /// `v = (0, h)`.
    /// Odd levels: origin at the left corner `c − (R, 0)`, `u = (d, d)`, `v = (d, −d)`. With these
    /// conventions the split diagonal is `i == j` ([`Diagonal::Main`]) or `i + j == N − 1`.
    pub fn grid(&self, id: DiamondId) -> GridMap {
        let r = self.radius(id.level);
        let c = (i64::from(id.x), i64::from(id.y));
        let n1 = (self.n - 1) as i64;
        if id.is_even() {
            let h = 2 * r / n1;
            GridMap {
                origin: (c.0 - r, c.1 - r),
                u: (h, 0),
                v: (0, h),
                n: self.n,
            }
        } else {
            let d = r / n1;
            GridMap {
                origin: (c.0 - r, c.1),
                u: (d, d),
                v: (d, -d),
                n: self.n,
            }
        }
    }

    /// Lattice bounding box of a diamond, `(x0, y0, x1, y1)` inclusive (it may stick out of the
    /// domain for edge diamonds).
    pub fn bounds(&self, id: DiamondId) -> (i64, i64, i64, i64) {
        let r = self.radius(id.level);
        let (x, y) = (i64::from(id.x), i64::from(id.y));
        (x - r, y - r, x + r, y + r)
    }

    /// Which half of `id` grid point `(i, j)` lies in; `None` on the split diagonal, which
    /// belongs to both.
    pub fn half_of_point(&self, id: DiamondId, i: usize, j: usize) -> Option<Half> {
        let n1 = self.n - 1;
        let on_diagonal = match self.diagonal(id) {
            Diagonal::Main => i == j,
            Diagonal::Anti => i + j == n1,
        };
        (!on_diagonal).then(|| self.half_of_centroid3(id, 3 * i as i64, 3 * j as i64))
    }

    /// Which half of `id` grid index `(i, j)` of a cell-split triangle belongs to, from three
    /// times its centroid `(si, sj)` (integers, so no rounding).
    pub(crate) fn half_of_centroid3(&self, id: DiamondId, si: i64, sj: i64) -> Half {
        self.diagonal(id).half_of_centroid3(self.n, si, sj)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Domain;
    use std::collections::HashSet;

    fn all_diamonds(layout: &Layout) -> Vec<DiamondId> {
        let mut out: Vec<DiamondId> = layout.roots().collect();
        let mut level: Vec<DiamondId> = out.clone();
        while !level.is_empty() {
            let next: HashSet<DiamondId> = level
                .iter()
                .flat_map(|&d| layout.children(d))
                .flatten()
                .collect();
            level = next.into_iter().collect();
            out.extend(&level);
        }
        out
    }

    #[test]
    fn parents_and_children_agree_at_every_level() {
        for (n, k, rx, ry) in [(3, 3, 1, 1), (5, 2, 3, 2), (9, 2, 2, 1), (65, 1, 1, 2)] {
            let layout = Layout::new(n, k, rx, ry).unwrap();
            let all = all_diamonds(&layout);
            let set: HashSet<_> = all.iter().copied().collect();
            assert_eq!(
                set.len(),
                all.len(),
                "a diamond reached twice was counted twice"
            );
            let mut per_level = vec![0usize; layout.finest_level() as usize + 1];
            for &d in &all {
                assert!(layout.contains(d), "{d} was produced but is not contained");
                per_level[d.level as usize] += 1;
                for c in layout.children(d).into_iter().flatten() {
                    assert_eq!(c.level, d.level + 1);
                    assert!(
                        Domain::full_plane(layout).half_in(c, d).is_some(),
                        "{c} does not list {d} as parent"
                    );
                }
                for (h, p) in layout.parents(d).into_iter().enumerate() {
                    let Some(p) = p else { continue };
                    assert!(set.contains(&p));
                    assert!(
                        layout.children(p).contains(&Some(d)),
                        "{p} does not list child {d}"
                    );
                    // The parent's centre is the grid corner on its side of the split diagonal.
                    let g = layout.grid(d);
                    let n1 = (n - 1) as i64;
                    let corner = match (layout.diagonal(d), h) {
                        (Diagonal::Main, 0) => (n1, 0),
                        (Diagonal::Main, _) => (0, n1),
                        (Diagonal::Anti, 0) => (n1, n1),
                        (Diagonal::Anti, _) => (0, 0),
                    };
                    assert_eq!(
                        g.point(corner.0, corner.1),
                        (i64::from(p.x), i64::from(p.y))
                    );
                }
                if d.level > 0 {
                    let n_parents = layout.parents(d).iter().flatten().count();
                    assert!(n_parents >= 1, "{d} is an orphan");
                }
                for nb in layout.neighbours(d).into_iter().flatten() {
                    assert!(layout.neighbours(nb).contains(&Some(d)));
                }
            }
            // Even levels tile the domain with (S0/side)² squares per root.
            let (ex, ey) = layout.face_extent();
            for (l, &count) in per_level.iter().enumerate() {
                if l % 2 == 0 {
                    let side = 2 * layout.radius(l as u8);
                    assert_eq!(count as i64, (ex / side) * (ey / side), "level {l}");
                }
            }
            // The finest grids sample the lattice at unit spacing.
            let fine = all
                .iter()
                .find(|d| d.level == layout.finest_level())
                .unwrap();
            assert_eq!(layout.grid(*fine).u, (1, 0));
        }
    }

    #[test]
    fn child_grids_map_into_parent_half_step_grids() {
        let layout = Layout::new(9, 2, 2, 2).unwrap();
        let n = layout.n() as i64;
        for d in all_diamonds(&layout) {
            for p in layout.parents(d).into_iter().flatten() {
                let m = layout
                    .grid(d)
                    .index_map_into_half_step(&layout.grid(p))
                    .unwrap();
                // The half in the parent lands inside the parent's (2N−1)² half-step grid on
                // points with a + b even (vertices and cell centres, never edge midpoints).
                let half = Domain::full_plane(layout).half_in(d, p).unwrap();
                let mut inside = 0;
                for i in 0..n {
                    for j in 0..n {
                        let (a, b) = m.apply(i, j);
                        assert_eq!((a + b).rem_euclid(2), 0);
                        let in_parent = (0..2 * n - 1).contains(&a) && (0..2 * n - 1).contains(&b);
                        let on_side = match (layout.diagonal(d), half) {
                            (Diagonal::Main, Half::Positive) => i >= j,
                            (Diagonal::Main, Half::Negative) => i <= j,
                            (Diagonal::Anti, Half::Positive) => i + j >= n - 1,
                            (Diagonal::Anti, Half::Negative) => i + j < n,
                        };
                        assert_eq!(in_parent, on_side, "{d} in {p} at ({i},{j}) -> ({a},{b})");
                        inside += usize::from(in_parent);
                    }
                }
                assert_eq!(inside as i64, n * (n + 1) / 2);
            }
        }
    }

    #[test]
    fn covering_layout_fits_the_samples() {
        let l = Layout::covering(65, 1000, 1000, 0).unwrap();
        assert_eq!((l.k(), l.roots_x(), l.roots_y()), (4, 1, 1));
        let l = Layout::covering(65, 16385, 16385, 0).unwrap();
        assert_eq!(
            (l.k(), l.roots_x(), l.roots_y(), l.root_side()),
            (8, 1, 1, 16384)
        );
        let l = Layout::covering(65, 4320, 2161, 0).unwrap();
        assert!(l.face_extent().0 >= 4319 && l.face_extent().1 >= 2160);
        assert!(Layout::covering(65, 0, 5, 0).is_err());
        assert!(Layout::new(64, 1, 1, 1).is_err());
        assert!(Layout::new(65, 30, 1, 1).is_err());
    }
}
