//! The cube of the cube-sphere domain: its six faces, how their lattices join, and the one
//! addressing function that carries a lattice point past a face edge onto the neighbouring face.
//!
//! Each face is a square lattice `[0, S] × [0, S]`, `S = (N − 1)·2^K`. Its point `(x, y)` sits on
//! the cube `[−1, 1]³` at `normal + a·u + b·v` with `a = 2x/S − 1`, `b = 2y/S − 1`, where
//! `(normal, u, v)` is the face's row of [`FACE_FRAMES`]: the one table that fixes the numbering
//! and orientation of the faces. Everything else here (which edge meets which, in which
//! direction, and the integer maps between face frames) is derived from it at compile time.
//!
//! Every face has the same handedness seen from outside the cube (`u × v = −normal`: x to the
//! right, y down, as the rows of an image), so a counter-clockwise triangle on one face stays
//! counter-clockwise when carried onto a neighbouring face.
//!
//! Ownership: a point on a face edge belongs to two faces, a cube corner to three. Its
//! *canonical* coordinates are those of the lowest-numbered face holding it. The same rule picks
//! the owner of a diamond whose centre lies on a face edge (odd levels only; a centre is never a
//! cube corner, see [`Cube::edge_of`]).

/// The six faces, `[normal, u, v]`: the face's centre direction on the cube and the cube
/// directions of its lattice x and y, in the ECEF axes (X to latitude 0 / longitude 0, Y to
/// longitude 90° E, Z to the north pole).
///
/// | face | normal | centre (lat, lon) | x runs | y runs |
/// |------|--------|-------------------|--------|--------|
/// | 0 | +X | 0°, 0°     | east (+Y) | south (−Z) |
/// | 1 | +Y | 0°, 90° E  | east (−X) | south (−Z) |
/// | 2 | −X | 0°, 180°   | east (−Y) | south (−Z) |
/// | 3 | −Y | 0°, 90° W  | east (+X) | south (−Z) |
/// | 4 | +Z | north pole | +Y        | +X (towards face 0) |
/// | 5 | −Z | south pole | +Y        | −X (away from face 0) |
///
/// Faces 0–3 form the equatorial belt with x eastwards; face 4's `y = S` edge is face 0's
/// `y = 0` edge and face 5's `y = 0` edge is face 0's `y = S` edge, both without reversal, so
/// faces 4, 0 and 5 unfold into one column.
pub const FACE_FRAMES: [[[i8; 3]; 3]; 6] = [
    [[1, 0, 0], [0, 1, 0], [0, 0, -1]],
    [[0, 1, 0], [-1, 0, 0], [0, 0, -1]],
    [[-1, 0, 0], [0, -1, 0], [0, 0, -1]],
    [[0, -1, 0], [1, 0, 0], [0, 0, -1]],
    [[0, 0, 1], [0, 1, 0], [1, 0, 0]],
    [[0, 0, -1], [0, 1, 0], [-1, 0, 0]],
];

/// Number of faces of the cube.
pub const FACES: u8 = 6;

/// The four edges of a face, by the lattice line they lie on. The edge parameter `t` runs along
/// +x on edges [`Edge::Y0`] and [`Edge::YS`], along +y on [`Edge::X0`] and [`Edge::XS`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Edge {
    /// `y = 0`.
    Y0 = 0,
    /// `x = S`.
    XS = 1,
    /// `y = S`.
    YS = 2,
    /// `x = 0`.
    X0 = 3,
}

impl Edge {
    /// All four, in number order.
    pub const ALL: [Edge; 4] = [Edge::Y0, Edge::XS, Edge::YS, Edge::X0];

    const fn from_index(i: u8) -> Edge {
        match i {
            0 => Edge::Y0,
            1 => Edge::XS,
            2 => Edge::YS,
            _ => Edge::X0,
        }
    }
}

/// What lies across one edge of a face.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Across {
    /// The neighbouring face.
    pub face: u8,
    /// Its edge that is the same cube edge.
    pub edge: Edge,
    /// Whether the edge parameter runs the other way on the neighbouring face.
    pub reversed: bool,
}

/// Face `f`'s cube point for the cube-face coordinates `a, b ∈ {−1, 0, 1}` (integers, so the
/// adjacency can be derived at compile time).
const fn corner(face: usize, a: i8, b: i8) -> [i8; 3] {
    let [n, u, v] = FACE_FRAMES[face];
    [
        n[0] + a * u[0] + b * v[0],
        n[1] + a * u[1] + b * v[1],
        n[2] + a * u[2] + b * v[2],
    ]
}

/// The cube corners at `t = 0` and `t = S` of an edge.
const fn edge_ends(face: usize, edge: u8) -> ([i8; 3], [i8; 3]) {
    match edge {
        0 => (corner(face, -1, -1), corner(face, 1, -1)),
        1 => (corner(face, 1, -1), corner(face, 1, 1)),
        2 => (corner(face, -1, 1), corner(face, 1, 1)),
        _ => (corner(face, -1, -1), corner(face, -1, 1)),
    }
}

const fn same(p: [i8; 3], q: [i8; 3]) -> bool {
    p[0] == q[0] && p[1] == q[1] && p[2] == q[2]
}

/// For every face and edge, the face and edge sharing its two cube corners. A table that fails
/// to close the cube (an edge with no partner) fails the build.
const fn derive_adjacency() -> [[Across; 4]; 6] {
    let mut out = [[Across {
        face: 0,
        edge: Edge::Y0,
        reversed: false,
    }; 4]; 6];
    let mut f = 0;
    while f < 6 {
        let mut e = 0;
        while e < 4 {
            let (p0, p1) = edge_ends(f, e);
            let mut found = false;
            let mut g = 0;
            while g < 6 {
                let mut h = 0;
                while g != f && h < 4 {
                    let (q0, q1) = edge_ends(g, h);
                    let forward = same(p0, q0) && same(p1, q1);
                    let backward = same(p0, q1) && same(p1, q0);
                    if forward || backward {
                        assert!(!found, "an edge shared by three faces");
                        found = true;
                        out[f][e as usize] = Across {
                            face: g as u8,
                            edge: Edge::from_index(h),
                            reversed: backward,
                        };
                    }
                    h += 1;
                }
                g += 1;
            }
            assert!(found, "a face edge with no neighbouring face");
            e += 1;
        }
        f += 1;
    }
    out
}

/// What lies across each edge of each face, derived from [`FACE_FRAMES`].
pub const ADJACENCY: [[Across; 4]; 6] = derive_adjacency();

/// A lattice point of one face, `(face, x, y)`. Ordered by face, then x, then y.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct FacePoint {
    /// The face.
    pub face: u8,
    /// Lattice column of the face.
    pub x: i64,
    /// Lattice row of the face.
    pub y: i64,
}

impl FacePoint {
    /// `(face, x, y)`.
    #[inline]
    pub const fn new(face: u8, x: i64, y: i64) -> Self {
        Self { face, x, y }
    }
}

/// An integer rigid map between two faces' lattice frames: `p ↦ m·p + o`. Crossing a cube edge
/// is a rotation by a multiple of 90° and a translation by multiples of `S`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameMap {
    /// The rotation, row-major: `x' = m[0][0]·x + m[0][1]·y + o.0`.
    pub m: [[i64; 2]; 2],
    /// The translation.
    pub o: (i64, i64),
}

impl FrameMap {
    /// The image of point `p`.
    #[inline]
    pub fn point(&self, p: (i64, i64)) -> (i64, i64) {
        (
            self.m[0][0] * p.0 + self.m[0][1] * p.1 + self.o.0,
            self.m[1][0] * p.0 + self.m[1][1] * p.1 + self.o.1,
        )
    }

    /// The image of a step (a difference of points): the rotation only.
    #[inline]
    pub fn step(&self, d: (i64, i64)) -> (i64, i64) {
        (
            self.m[0][0] * d.0 + self.m[0][1] * d.1,
            self.m[1][0] * d.0 + self.m[1][1] * d.1,
        )
    }

    /// The rotation's determinant: +1 for every edge crossing (the faces' frames all have the
    /// same handedness).
    pub fn determinant(&self) -> i64 {
        self.m[0][0] * self.m[1][1] - self.m[0][1] * self.m[1][0]
    }
}

/// The lattice of the six faces of a cube of side `S`: the addressing across face edges.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Cube {
    side: i64,
}

impl Cube {
    /// A cube whose faces are `[0, side]²` lattices.
    pub const fn new(side: i64) -> Self {
        Self { side }
    }

    /// `S`, the lattice side of a face.
    #[inline]
    pub const fn side(&self) -> i64 {
        self.side
    }

    /// `(t, out)` of a point of `edge`'s face frame: the parameter along the edge and the
    /// distance past it (negative inside the face).
    fn edge_coordinates(&self, edge: Edge, (x, y): (i64, i64)) -> (i64, i64) {
        let s = self.side;
        match edge {
            Edge::Y0 => (x, -y),
            Edge::XS => (y, x - s),
            Edge::YS => (x, y - s),
            Edge::X0 => (y, -x),
        }
    }

    /// The point of `edge`'s face frame at parameter `t` and distance `depth` inside the face.
    fn at_edge_coordinates(&self, edge: Edge, t: i64, depth: i64) -> (i64, i64) {
        let s = self.side;
        match edge {
            Edge::Y0 => (t, depth),
            Edge::XS => (s - depth, t),
            Edge::YS => (t, s - depth),
            Edge::X0 => (depth, t),
        }
    }

    /// Where a point of `face`'s frame lying past (or on) `edge` is on the neighbouring face.
    fn carry(&self, face: u8, edge: Edge, p: (i64, i64)) -> FacePoint {
        let across = ADJACENCY[face as usize][edge as usize];
        let (t, out) = self.edge_coordinates(edge, p);
        let t = if across.reversed { self.side - t } else { t };
        let (x, y) = self.at_edge_coordinates(across.edge, t, out);
        FacePoint::new(across.face, x, y)
    }

    /// The integer map from `face`'s frame to the frame of the face across `edge`.
    ///
    /// # Panics
    /// If `face` is not a face (≥ 6).
    pub fn frame_across(&self, face: u8, edge: Edge) -> FrameMap {
        // The map is affine; read it off the images of three points.
        let o = self.carry(face, edge, (0, 0));
        let ex = self.carry(face, edge, (1, 0));
        let ey = self.carry(face, edge, (0, 1));
        FrameMap {
            m: [[ex.x - o.x, ey.x - o.x], [ex.y - o.y, ey.y - o.y]],
            o: (o.x, o.y),
        }
    }

    /// Which edge of its face a point lies on, if exactly one (`None` inside the face, at a
    /// corner or outside).
    #[inline]
    pub fn edge_of(&self, p: FacePoint) -> Option<Edge> {
        let s = self.side;
        let inside = |v: i64| 0 < v && v < s;
        match (p.x, p.y) {
            (x, 0) if inside(x) => Some(Edge::Y0),
            (x, y) if x == s && inside(y) => Some(Edge::XS),
            (x, y) if y == s && inside(x) => Some(Edge::YS),
            (0, y) if inside(y) => Some(Edge::X0),
            _ => None,
        }
    }

    /// The addressing function: a point of `face`'s frame, inside the face or past at most one
    /// of its edges by at most `S`, as a point of the face that holds it (the neighbouring
    /// face's coordinates if it lies past an edge). `None` beyond a corner (past two edges at
    /// once, where the cube has no lattice: three faces meet there, not four) or farther out.
    /// A point on an edge keeps this face's coordinates; [`Cube::canonical`] picks its owner.
    #[inline]
    pub fn locate(&self, face: u8, x: i64, y: i64) -> Option<FacePoint> {
        let s = self.side;
        if face >= FACES {
            return None;
        }
        let within = |v: i64| (0..=s).contains(&v);
        let past = |v: i64| (-s..0).contains(&v) || (s + 1..=2 * s).contains(&v);
        let edge = match (within(x), within(y)) {
            (true, true) => return Some(FacePoint::new(face, x, y)),
            (false, true) if past(x) => {
                if x < 0 {
                    Edge::X0
                } else {
                    Edge::XS
                }
            }
            (true, false) if past(y) => {
                if y < 0 {
                    Edge::Y0
                } else {
                    Edge::YS
                }
            }
            _ => return None,
        };
        Some(self.carry(face, edge, (x, y)))
    }

    /// Every face's coordinates of a point of the closed face square: one for an inner point,
    /// two on an edge, three at a cube corner. The given face's coordinates come first. A point
    /// of no face (face ≥ 6) is left alone.
    pub fn representations(&self, p: FacePoint) -> ([FacePoint; 3], usize) {
        let s = self.side;
        let mut out = [p; 3];
        let mut len = 1;
        if p.face >= FACES {
            return (out, len);
        }
        for (on, edge) in [
            (p.y == 0, Edge::Y0),
            (p.x == s, Edge::XS),
            (p.y == s, Edge::YS),
            (p.x == 0, Edge::X0),
        ] {
            if on && len < 3 {
                out[len] = self.carry(p.face, edge, (p.x, p.y));
                len += 1;
            }
        }
        (out, len)
    }

    /// The canonical coordinates of a point of the closed face square: those of the
    /// lowest-numbered face holding it.
    #[inline]
    pub fn canonical(&self, p: FacePoint) -> FacePoint {
        let s = self.side;
        if 0 < p.x && p.x < s && 0 < p.y && p.y < s {
            return p;
        }
        let (reps, len) = self.representations(p);
        reps[..len]
            .iter()
            .copied()
            .min_by_key(|r| r.face)
            .unwrap_or(p)
    }

    /// The point on the cube `[−S, S]³` (scaled by `S` so that it is an exact integer; the
    /// face-coordinate pair `(a, b)` is `(2x − S, 2y − S)/S`).
    ///
    /// # Panics
    /// If `p.face` is not a face (≥ 6).
    pub fn cube_point(&self, p: FacePoint) -> [i64; 3] {
        let [n, u, v] = FACE_FRAMES[p.face as usize];
        let s = self.side;
        let (a, b) = (2 * p.x - s, 2 * p.y - s);
        std::array::from_fn(|k| i64::from(n[k]) * s + a * i64::from(u[k]) + b * i64::from(v[k]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_face_frame_is_orthonormal_and_seen_from_outside_the_same_way() {
        for [n, u, v] in FACE_FRAMES {
            let dot = |p: [i8; 3], q: [i8; 3]| (0..3).map(|k| p[k] * q[k]).sum::<i8>();
            let cross = |p: [i8; 3], q: [i8; 3]| {
                [
                    p[1] * q[2] - p[2] * q[1],
                    p[2] * q[0] - p[0] * q[2],
                    p[0] * q[1] - p[1] * q[0],
                ]
            };
            assert_eq!((dot(n, n), dot(u, u), dot(v, v)), (1, 1, 1));
            assert_eq!((dot(n, u), dot(n, v), dot(u, v)), (0, 0, 0));
            assert_eq!(cross(u, v), n.map(|c| -c));
        }
        // Six different normals: a cube, not a face twice.
        let normals: std::collections::HashSet<_> = FACE_FRAMES.iter().map(|f| f[0]).collect();
        assert_eq!(normals.len(), 6);
    }

    #[test]
    fn adjacency_is_an_involution_and_crossings_are_rotations() {
        let cube = Cube::new(8);
        for f in 0..FACES {
            for e in Edge::ALL {
                let a = ADJACENCY[f as usize][e as usize];
                assert_ne!(a.face, f);
                let back = ADJACENCY[a.face as usize][a.edge as usize];
                assert_eq!((back.face, back.edge, back.reversed), (f, e, a.reversed));
                let m = cube.frame_across(f, e);
                assert_eq!(m.determinant(), 1, "face {f} edge {e:?}");
                let back_map = cube.frame_across(a.face, a.edge);
                for p in [(0, 0), (3, 5), (-2, 7), (8, 9)] {
                    assert_eq!(back_map.point(m.point(p)), p);
                }
            }
        }
        // Each face meets the other four that are not its opposite.
        for row in &ADJACENCY {
            let faces: std::collections::BTreeSet<u8> = row.iter().map(|a| a.face).collect();
            assert_eq!(faces.len(), 4);
        }
        // The documented unfolding: faces 4, 0, 5 form a column without reversal.
        assert_eq!(
            ADJACENCY[0][Edge::Y0 as usize],
            Across {
                face: 4,
                edge: Edge::YS,
                reversed: false
            }
        );
        assert_eq!(
            ADJACENCY[0][Edge::YS as usize],
            Across {
                face: 5,
                edge: Edge::Y0,
                reversed: false
            }
        );
        assert_eq!(ADJACENCY[0][Edge::XS as usize].face, 1);
    }

    #[test]
    fn every_boundary_point_has_one_cube_point_and_one_canonical_owner() {
        let s = 6;
        let cube = Cube::new(s);
        let mut corners = std::collections::HashSet::new();
        for f in 0..FACES {
            for x in 0..=s {
                for y in 0..=s {
                    let p = FacePoint::new(f, x, y);
                    let (reps, len) = cube.representations(p);
                    let on_x = x == 0 || x == s;
                    let on_y = y == 0 || y == s;
                    let expected = 1 + usize::from(on_x) + usize::from(on_y);
                    assert_eq!(len, expected, "{p:?}");
                    let canonical = cube.canonical(p);
                    let faces: std::collections::BTreeSet<u8> =
                        reps[..len].iter().map(|r| r.face).collect();
                    assert_eq!(faces.len(), len, "{p:?} lists a face twice");
                    for r in &reps[..len] {
                        assert_eq!(cube.cube_point(*r), cube.cube_point(p), "{p:?} vs {r:?}");
                        assert_eq!(cube.canonical(*r), canonical);
                        assert_eq!(canonical.face, *faces.first().unwrap());
                    }
                    if len == 3 {
                        corners.insert(cube.cube_point(p));
                    }
                }
            }
        }
        assert_eq!(corners.len(), 8, "the eight cube corners");
    }

    #[test]
    fn locate_steps_across_one_edge_and_refuses_the_corner_regions() {
        let s = 8;
        let cube = Cube::new(s);
        for f in 0..FACES {
            for (x, y) in [(-1, 3), (s + 2, 0), (5, -s), (4, 2 * s), (-3, s)] {
                let q = cube.locate(f, x, y).unwrap();
                assert!((0..=s).contains(&q.x) && (0..=s).contains(&q.y));
                assert_ne!(q.face, f);
                // Past the edge by d: d lattice steps inside the neighbour from its edge.
                let (d, crossed) = [
                    (-y, Edge::Y0),
                    (x - s, Edge::XS),
                    (y - s, Edge::YS),
                    (-x, Edge::X0),
                ]
                .into_iter()
                .max_by_key(|&(d, _)| d)
                .unwrap();
                let across = ADJACENCY[f as usize][crossed as usize];
                assert_eq!(q.face, across.face);
                let depth = match across.edge {
                    Edge::Y0 => q.y,
                    Edge::XS => s - q.x,
                    Edge::YS => s - q.y,
                    Edge::X0 => q.x,
                };
                assert_eq!(depth, d, "{f} ({x},{y}) -> {q:?}");
            }
            assert_eq!(cube.locate(f, -1, -1), None);
            assert_eq!(cube.locate(f, s + 1, -1), None);
            assert_eq!(cube.locate(f, 3, 2 * s + 1), None);
            assert_eq!(cube.locate(f, 3, 4), Some(FacePoint::new(f, 3, 4)));
        }
        assert_eq!(cube.locate(6, 1, 1), None);
    }
}
