//! The domain: the shape of the surface the hierarchy covers, and the one owner of it.
//!
//! Everything that depends on the domain's shape asks a [`Domain`]: which diamonds exist, their
//! parents, children and neighbours (across root boundaries now, across face edges on the
//! cube-sphere), the roots, the root field's size, and which lattice points hold data. The rest
//! of the codec, the server and the client work per face with the integer arithmetic of
//! [`Layout`] (grids, radii, bounds), which is the same on every face.
//!
//! Two shapes: the plane (one face, a `roots_x × roots_y` grid of level-0 squares, and a data
//! rectangle in its corner) and the cube-sphere (six faces, each one root square, whose
//! relations cross face edges through one addressing function, [`Cube::locate`]; see
//! [`super::cube`] and `docs/PLANET.md`).

use super::cube::{Cube, Edge, FACES, FacePoint, FrameMap};
use super::{DiamondId, GridMap, Half, Layout};
use crate::CodecError;

/// The kinds of domain (`docs/FORMAT.md`: the header's domain kind).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum DomainKind {
    /// A plane: one face, a rectangle of roots.
    Planar,
    /// A cube-sphere: six faces, one root each, joined along the cube's edges.
    CubeSphere,
}

impl DomainKind {
    /// The name `inspect` and the server's metadata use.
    pub fn name(self) -> &'static str {
        match self {
            DomainKind::Planar => "planar",
            DomainKind::CubeSphere => "cube-sphere",
        }
    }
}

/// The lattice points of a face that hold data: `0..width × 0..height`, the input's samples.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct DataRect {
    /// Columns of samples; lattice x of the data is `0..width`.
    pub width: u32,
    /// Rows of samples; lattice y of the data is `0..height`.
    pub height: u32,
}

impl DataRect {
    /// Whether lattice point `(x, y)` lies in the rectangle.
    #[inline]
    pub fn contains(&self, x: i64, y: i64) -> bool {
        x >= 0 && y >= 0 && x < i64::from(self.width) && y < i64::from(self.height)
    }

    /// Number of lattice points in the rectangle.
    pub fn samples(&self) -> u64 {
        u64::from(self.width) * u64::from(self.height)
    }

    /// The rectangle's size as `(columns, rows)`.
    pub fn size(&self) -> (usize, usize) {
        (self.width as usize, self.height as usize)
    }
}

/// The root field of a face: its level-0 vertices as one `width × height` grid, every
/// `spacing` lattice units.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RootField {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Lattice units between neighbouring root-field points, `2^K`.
    pub spacing: i64,
}

impl RootField {
    /// Number of points.
    pub fn points(&self) -> usize {
        self.width * self.height
    }
}

/// How the faces are shaped and connected. Private: callers ask [`Domain`], so a second shape
/// adds an arm here, not a branch at every call site.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Shape {
    /// One face: the layout's root rectangle, no wrap-around.
    Planar,
    /// Six faces of one root each, the faces of [`Cube`] with side `S`: a closed surface.
    CubeSphere(Cube),
}

/// The surface a hierarchy covers: its faces, its root set, the region that holds data, and
/// the relations between diamonds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Domain {
    shape: Shape,
    layout: Layout,
    data: DataRect,
}

impl Domain {
    /// A planar domain: `layout`'s root rectangle with data on `data`, which must be non-empty
    /// and fit the layout's lattice.
    pub fn planar(layout: Layout, data: DataRect) -> Result<Self, CodecError> {
        let (ex, ey) = layout.face_extent();
        if data.width == 0
            || data.height == 0
            || i64::from(data.width) > ex + 1
            || i64::from(data.height) > ey + 1
        {
            return Err(CodecError::invalid(format!(
                "data size {}×{} does not fit the layout's {}×{} lattice",
                data.width,
                data.height,
                ex + 1,
                ey + 1
            )));
        }
        Ok(Self {
            shape: Shape::Planar,
            layout,
            data,
        })
    }

    /// A cube-sphere: six faces, each one root square with an `(N − 1)·2^K + 1` lattice per
    /// side, data on every lattice point. The face numbering and orientation are
    /// [`super::cube::FACE_FRAMES`]'s.
    pub fn cube_sphere(n: usize, k: u32) -> Result<Self, CodecError> {
        let layout = Layout::new(n, k, 1, 1)?;
        let side = layout.root_side();
        // Crossing an edge handles points up to one face side beyond it: 2S must fit.
        let points = u32::try_from(side + 1)
            .ok()
            .filter(|_| side.checked_mul(2).is_some_and(|d| d < i64::from(u32::MAX)))
            .ok_or_else(|| {
                CodecError::limit(format!("a cube-sphere face of side {side} is too large"))
            })?;
        Ok(Self {
            shape: Shape::CubeSphere(Cube::new(side)),
            layout,
            data: DataRect {
                width: points,
                height: points,
            },
        })
    }

    /// A planar domain with data on every point of `layout`'s lattice.
    pub fn full_plane(layout: Layout) -> Self {
        let (ex, ey) = layout.face_extent();
        let data = DataRect {
            width: (ex + 1) as u32,
            height: (ey + 1) as u32,
        };
        Self::planar(layout, data).expect("a layout's lattice fits itself")
    }

    /// The planar domain whose finest level lies on a `width × height` sample grid
    /// ([`Layout::covering`]), with the data on all of it.
    pub fn covering(
        n: usize,
        width: usize,
        height: usize,
        extra_level_pairs: u32,
    ) -> Result<Self, CodecError> {
        let layout = Layout::covering(n, width, height, extra_level_pairs)?;
        let data = DataRect {
            width: u32::try_from(width).map_err(|_| CodecError::limit("grid too wide"))?,
            height: u32::try_from(height).map_err(|_| CodecError::limit("grid too tall"))?,
        };
        Self::planar(layout, data)
    }

    /// The same surface with `level_pairs` more level pairs below the finest level (the
    /// client's synthetic detail): lattice coordinates scale by `2^level_pairs`, and so does the
    /// data region (its sample spacing, not its count: `(w − 1)·2^m + 1`).
    pub fn with_detail(&self, level_pairs: u32) -> Result<Self, CodecError> {
        if level_pairs == 0 {
            return Ok(*self);
        }
        let l = &self.layout;
        let (rx, ry) = l.root_counts();
        let layout = Layout::new(l.n(), l.k() + level_pairs, rx, ry)?;
        let scale = |v: u32| {
            u32::try_from((u64::from(v.max(1) - 1) << level_pairs) + 1)
                .map_err(|_| CodecError::limit("detail levels overflow the lattice"))
        };
        let data = DataRect {
            width: scale(self.data.width)?,
            height: scale(self.data.height)?,
        };
        match self.shape {
            Shape::Planar => Self::planar(layout, data),
            Shape::CubeSphere(_) => Self::cube_sphere(l.n(), l.k() + level_pairs),
        }
    }

    /// What kind of domain this is.
    pub fn kind(&self) -> DomainKind {
        match self.shape {
            Shape::Planar => DomainKind::Planar,
            Shape::CubeSphere(_) => DomainKind::CubeSphere,
        }
    }

    /// Number of faces (1 for a plane, 6 for a cube-sphere).
    pub fn faces(&self) -> u8 {
        match self.shape {
            Shape::Planar => 1,
            Shape::CubeSphere(_) => FACES,
        }
    }

    /// The per-face lattice arithmetic: grid side, level pairs, grids, radii, bounds.
    #[inline]
    pub fn layout(&self) -> &Layout {
        &self.layout
    }

    /// Grid side `N`.
    #[inline]
    pub fn n(&self) -> usize {
        self.layout.n()
    }

    /// The finest level, `2K`.
    #[inline]
    pub fn finest_level(&self) -> u8 {
        self.layout.finest_level()
    }

    /// The lattice points of each face that hold data.
    #[inline]
    pub fn data(&self) -> DataRect {
        self.data
    }

    /// The distinct lattice points that can hold data: the data rectangle's samples on a plane,
    /// `6·S² + 2` on a cube-sphere (a point on a cube edge or corner counted once).
    pub fn lattice_points(&self) -> u64 {
        match self.shape {
            Shape::Planar => self.data.samples(),
            Shape::CubeSphere(cube) => 6 * (cube.side() as u64).pow(2) + 2,
        }
    }

    /// Whether lattice point `(x, y)` of `face` holds data. On a cube-sphere every point of
    /// the closed face square does (an edge point on each face holding it; its values are
    /// computed once, at [`Domain::canonical_point`]).
    #[inline]
    pub fn holds_data(&self, face: u8, x: i64, y: i64) -> bool {
        face < self.faces() && self.data.contains(x, y)
    }

    /// The one coordinate triple of a surface point: `(face, x, y)` of the face's lattice, or a
    /// point past one of its edges by at most a face side (where relations step), mapped onto
    /// the face holding it and, on a face edge or cube corner, onto the lowest-numbered face
    /// holding it. Every face's coordinates of an edge vertex give the same answer, so code that
    /// computes a vertex from its canonical point computes it once. `None` off the surface
    /// (outside a plane's lattice; beyond a cube corner).
    pub fn canonical_point(&self, face: u8, x: i64, y: i64) -> Option<FacePoint> {
        match self.shape {
            Shape::Planar => {
                let (ex, ey) = self.layout.face_extent();
                (face == 0 && (0..=ex).contains(&x) && (0..=ey).contains(&y))
                    .then_some(FacePoint::new(0, x, y))
            }
            Shape::CubeSphere(cube) => cube.locate(face, x, y).map(|p| cube.canonical(p)),
        }
    }

    /// The cube of a cube-sphere (`None` on a plane).
    pub fn cube(&self) -> Option<&Cube> {
        match &self.shape {
            Shape::Planar => None,
            Shape::CubeSphere(cube) => Some(cube),
        }
    }

    /// The root field of each face.
    pub fn root_field(&self) -> RootField {
        let n1 = self.layout.n() - 1;
        let (rx, ry) = self.layout.root_counts();
        RootField {
            width: rx as usize * n1 + 1,
            height: ry as usize * n1 + 1,
            spacing: 1i64 << self.layout.k(),
        }
    }

    /// Whether `id` is a diamond of this domain (possibly one that sticks out of the data).
    /// On a cube-sphere, a diamond centred on a face edge exists only under its canonical face.
    #[inline]
    pub fn contains(&self, id: DiamondId) -> bool {
        match self.shape {
            Shape::Planar => id.face == 0 && self.layout.contains(id),
            Shape::CubeSphere(cube) => {
                id.face < FACES
                    && self.layout.contains(id)
                    && cube.canonical(centre(id)) == centre(id)
            }
        }
    }

    /// The roots, face by face, row by row.
    pub fn roots(&self) -> impl Iterator<Item = DiamondId> + '_ {
        let faces = self.faces();
        (0..faces).flat_map(move |face| self.layout.roots().map(move |r| on_face(r, face)))
    }

    /// Every diamond of `level`, face by face, in id order.
    pub fn level(&self, level: u8) -> impl Iterator<Item = DiamondId> + '_ {
        let levels = if level <= self.finest_level() {
            level..level + 1
        } else {
            0..0
        };
        let faces = self.faces();
        levels.flat_map(move |l| {
            (0..faces).flat_map(move |face| {
                self.layout
                    .level(l)
                    .map(move |id| on_face(id, face))
                    .filter(move |&id| self.contains(id))
            })
        })
    }

    /// The two parents, `[positive half's, negative half's]`; `None` for roots and for the
    /// missing parent of a diamond on a plane's edge. On a cube-sphere every diamond but the
    /// roots has both; those of a diamond centred on a face edge lie on the two faces.
    #[inline]
    pub fn parents(&self, id: DiamondId) -> [Option<DiamondId>; 2] {
        match self.shape {
            Shape::Planar => self.layout.parents(id),
            Shape::CubeSphere(cube) => {
                if id.level == 0 {
                    return [None, None];
                }
                let (offsets, _) = self.layout.parent_offsets(id);
                offsets.map(|o| self.cube_step(cube, id, id.level - 1, o))
            }
        }
    }

    /// The parent on one side, or `None`.
    #[inline]
    pub fn parent(&self, id: DiamondId, half: Half) -> Option<DiamondId> {
        self.parents(id)[half as usize]
    }

    /// Which half of `child` lies in `parent`, if `parent` is one of its parents.
    #[inline]
    pub fn half_in(&self, child: DiamondId, parent: DiamondId) -> Option<Half> {
        let p = self.parents(child);
        if p[0] == Some(parent) {
            Some(Half::Positive)
        } else if p[1] == Some(parent) {
            Some(Half::Negative)
        } else {
            None
        }
    }

    /// The up to 4 children (fewer on a plane's edge, none at the finest level).
    #[inline]
    pub fn children(&self, id: DiamondId) -> [Option<DiamondId>; 4] {
        match self.shape {
            Shape::Planar => self.layout.children(id),
            Shape::CubeSphere(cube) => {
                if id.level >= self.finest_level() {
                    return [None; 4];
                }
                self.layout
                    .child_offsets(id)
                    .map(|o| self.cube_step(cube, id, id.level + 1, o))
            }
        }
    }

    /// The diamonds of the same level that share a side with `id` (up to 4).
    #[inline]
    pub fn neighbours(&self, id: DiamondId) -> [Option<DiamondId>; 4] {
        match self.shape {
            Shape::Planar => self.layout.neighbours(id),
            Shape::CubeSphere(cube) => self
                .layout
                .neighbour_offsets(id)
                .map(|o| self.cube_step(cube, id, id.level, o)),
        }
    }

    /// The diamond of `level` centred at `from`'s centre plus `offset` (in `from`'s face frame,
    /// possibly past one of its edges), under its canonical face.
    #[inline]
    fn cube_step(
        &self,
        cube: Cube,
        from: DiamondId,
        level: u8,
        offset: (i64, i64),
    ) -> Option<DiamondId> {
        let (x, y) = (i64::from(from.x) + offset.0, i64::from(from.y) + offset.1);
        let s = cube.side();
        let c = if 0 < x && x < s && 0 < y && y < s && from.face < FACES {
            // Inside the face, off its edges (most steps): the point is its own owner.
            FacePoint::new(from.face, x, y)
        } else {
            cube.canonical(cube.locate(from.face, x, y)?)
        };
        let id = DiamondId::on_face(
            c.face,
            level,
            u32::try_from(c.x).ok()?,
            u32::try_from(c.y).ok()?,
        );
        // Canonical already: only the lattice test of `contains` is left.
        self.layout.contains(id).then_some(id)
    }

    /// The face that half `half` of `id` lies on, and the map from `id`'s face frame to that
    /// face's frame (`None` when it is `id`'s own face). Every half lies on one face: only a
    /// diamond centred on a cube edge (odd levels) has a half on another face than its own.
    pub fn half_face(&self, id: DiamondId, half: Half) -> (u8, Option<FrameMap>) {
        let Shape::CubeSphere(cube) = self.shape else {
            return (id.face, None);
        };
        let Some(edge) = cube.edge_of(centre(id)).filter(|_| id.face < FACES) else {
            return (id.face, None);
        };
        // The half lies on the side of the split diagonal (the edge) where its parent is.
        let (offsets, _) = self.layout.parent_offsets(id);
        let o = offsets[half as usize];
        let (t, out) = match edge {
            Edge::Y0 => (o.0, -o.1),
            Edge::XS => (o.1, o.0),
            Edge::YS => (o.0, o.1),
            Edge::X0 => (o.1, -o.0),
        };
        debug_assert_eq!(
            t, 0,
            "a split diagonal on an edge has its parents across it"
        );
        if out > 0 {
            let map = cube.frame_across(id.face, edge);
            let across = super::cube::ADJACENCY[id.face as usize][edge as usize].face;
            (across, Some(map))
        } else {
            (id.face, None)
        }
    }

    /// The grid of `id` in the frame of the face its half `half` lies on: the same `N × N`
    /// vertices, with origin and steps carried across the cube edge when that half lies on
    /// the neighbouring face. Returns that face too.
    pub fn half_grid(&self, id: DiamondId, half: Half) -> (u8, GridMap) {
        let g = self.layout.grid(id);
        match self.half_face(id, half) {
            (face, None) => (face, g),
            (face, Some(map)) => (
                face,
                GridMap {
                    origin: map.point(g.origin),
                    u: map.step(g.u),
                    v: map.step(g.v),
                    n: g.n,
                },
            ),
        }
    }
}

impl Domain {
    /// The grid of `id` in the frame of `parent`, its parent on `half` (the frame that parent's
    /// own grid and refinement use). On a plane, `id`'s own grid; on a cube-sphere carried
    /// across a cube edge when the half lies on the neighbouring face ([`Domain::half_grid`])
    /// or when the parent is a diamond centred on a cube edge whose canonical face is not the
    /// face the half lies on. Gathering a child from its parents maps this grid into the
    /// parent's half-step grid. `None` if no face of the half's borders `parent`'s face (then
    /// `parent` is not that parent).
    #[inline]
    pub fn grid_in_parent_frame(
        &self,
        id: DiamondId,
        half: Half,
        parent: DiamondId,
    ) -> Option<GridMap> {
        let Shape::CubeSphere(cube) = self.shape else {
            return Some(self.layout.grid(id));
        };
        let (face, g) = self.half_grid(id, half);
        if parent.face == face {
            return Some(g);
        }
        // The parent straddles the edge between the half's face and its own canonical face.
        let edge = Edge::ALL
            .into_iter()
            .find(|&e| super::cube::ADJACENCY[face as usize][e as usize].face == parent.face)?;
        let map = cube.frame_across(face, edge);
        Some(GridMap {
            origin: map.point(g.origin),
            u: map.step(g.u),
            v: map.step(g.v),
            n: g.n,
        })
    }
}

/// A diamond's centre as a face point.
fn centre(id: DiamondId) -> FacePoint {
    FacePoint::new(id.face, i64::from(id.x), i64::from(id.y))
}

fn on_face(id: DiamondId, face: u8) -> DiamondId {
    DiamondId { face, ..id }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeSet;

    #[test]
    fn a_plane_is_one_face_whose_data_fits_its_lattice() {
        let d = Domain::covering(65, 1000, 700, 0).unwrap();
        assert_eq!((d.kind(), d.faces()), (DomainKind::Planar, 1));
        assert!(d.holds_data(0, 999, 699) && !d.holds_data(0, 1000, 0));
        assert_eq!(d.lattice_points(), 1000 * 700);
        assert!(!d.holds_data(0, -1, 0) && !d.holds_data(1, 0, 0));
        let rf = d.root_field();
        assert_eq!((rf.width, rf.height, rf.spacing), (65, 65, 16));
        let layout = *d.layout();
        let (ex, _) = layout.face_extent();
        let too_wide = DataRect {
            width: ex as u32 + 2,
            height: 1,
        };
        assert!(Domain::planar(layout, too_wide).is_err());
        assert!(
            Domain::planar(
                layout,
                DataRect {
                    width: 0,
                    height: 5
                }
            )
            .is_err()
        );
        assert!(!d.contains(DiamondId::on_face(1, 0, 512, 512)));
        // Two more level pairs: the same ground at a quarter of the spacing.
        let fine = d.with_detail(2).unwrap();
        assert_eq!(fine.finest_level(), d.finest_level() + 4);
        assert_eq!(
            (fine.data().width, fine.data().height),
            (999 * 4 + 1, 699 * 4 + 1)
        );
        assert_eq!(d.with_detail(0).unwrap(), d);
    }

    #[test]
    fn per_level_iteration_is_the_closure_of_the_roots_under_children() {
        // Independently of `level`: walk children from the roots and collect per level.
        let d = Domain::planar(
            Layout::new(5, 2, 3, 2).unwrap(),
            DataRect {
                width: 40,
                height: 30,
            },
        )
        .unwrap();
        let mut frontier: BTreeSet<DiamondId> = d.roots().collect();
        for level in 0..=d.finest_level() {
            let listed: Vec<DiamondId> = d.level(level).collect();
            let as_set: BTreeSet<DiamondId> = listed.iter().copied().collect();
            assert_eq!(
                as_set.len(),
                listed.len(),
                "level {level} lists a diamond twice"
            );
            assert!(
                listed.windows(2).all(|w| w[0] < w[1]),
                "level {level} not in id order"
            );
            assert_eq!(as_set, frontier, "level {level}");
            frontier = frontier
                .iter()
                .flat_map(|&id| d.children(id))
                .flatten()
                .collect();
        }
        assert!(frontier.is_empty());
        assert_eq!(d.level(d.finest_level() + 1).count(), 0);
    }
}
