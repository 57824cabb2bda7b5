//! From lattice coordinates and integer heights to world metres.
//!
//! A plane's world frame is local and metric: x east, y north, z up, origin at lattice point
//! (0, 0), z = height in metres. Geographic rasters (spacing in degrees) are flattened around the
//! data's centre latitude — a local tangent-plane approximation that is what a viewer of one DEM
//! wants. A planet (a cube-sphere domain) lies on the WGS84 ellipsoid instead: world positions
//! are ECEF metres (`docs/PLANET.md`), a lattice point's surface point computed from its
//! canonical point (so the faces holding an edge vertex get the same bits) and its height
//! displaced along the ellipsoid normal there.
//!
//! What the surface is (faces, roots, where data lies) is the [`Domain`]'s; the world adds only
//! how lattice units become metres. Callers go through [`World::point`],
//! [`World::lattice_vector`], [`World::lattice_of`] and the boxes, never through the planar
//! spacing itself, so a second frame changes this file, not theirs.

use cbdam_codec::geodesy::cube_map::{CubeWarp, face_direction};
use cbdam_codec::geodesy::wgs84;
use cbdam_codec::geometry::{DiamondId, Domain, DomainKind, FacePoint};
use cbdam_codec::hierarchy::CodecParams;
use cbdam_codec::quant::QuantPlan;
use cbdam_codec::repository::GeoRef;
use cbdam_codec::repository::index::IndexEntry;
use glam::DVec3;

use crate::horizon::Occluder;

/// Metres per degree of latitude (WGS 84 mean) — used only to flatten geographic rasters.
const METRES_PER_DEGREE: f64 = 111_195.0;

/// EPSG codes of geographic (degree-based) coordinate systems we meet in DEMs: WGS 84, NAD83,
/// ETRS89, GDA94, NAD27.
const GEOGRAPHIC_EPSG: [u32; 5] = [4326, 4269, 4258, 4283, 4267];

/// The mapping from a repository's lattice to world metres, and the data's extent in it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct World {
    /// The surface the hierarchy covers: faces, roots, the region that holds data.
    pub domain: Domain,
    /// How lattice units become metres on the ground; private, so that callers go through the
    /// methods and a second frame (the ellipsoid's) changes this file only.
    frame: Frame,
    /// Metres per height unit.
    pub unit: f64,
    /// Height in metres of unit 0.
    pub offset: f64,
    /// Lowest height of the data in metres (from the index's per-diamond ranges).
    pub min_height: f64,
    /// Highest height of the data in metres.
    pub max_height: f64,
}

/// How a lattice of the domain lies in world metres.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Frame {
    /// A plane: metres per lattice step eastwards (`step_x`) and southwards (`step_y`; lattice y
    /// runs south, world y north).
    Planar { step_x: f64, step_y: f64 },
    /// The cube-sphere on the WGS84 ellipsoid: ECEF metres; `side` is the face side `S` in
    /// lattice steps.
    Ellipsoid { side: f64 },
}

/// How far below the data's lowest height the horizon occluder lies, metres: more than the
/// difference between an ellipsoid with radii lowered by `h` and the surface `h` below WGS84
/// along its normal (`|h|·f`, about 40 m at 11 km), so the occluder stays inside the terrain.
const OCCLUDER_MARGIN: f64 = 1000.0;

impl World {
    /// A planar world: `domain` with `step` metres per lattice step `(east, south)`, heights of
    /// `unit` metres per unit above `offset`, the data between `heights` metres (low, high).
    pub fn planar(
        domain: Domain,
        step: (f64, f64),
        unit: f64,
        offset: f64,
        heights: (f64, f64),
    ) -> Self {
        Self {
            domain,
            frame: Frame::Planar {
                step_x: step.0,
                step_y: step.1,
            },
            unit,
            offset,
            min_height: heights.0,
            max_height: heights.1,
        }
    }

    /// The world of a repository, from what its head holds.
    pub fn new(
        params: &CodecParams,
        plan: &QuantPlan,
        georef: Option<&GeoRef>,
        entries: &[IndexEntry],
    ) -> Self {
        let lo = entries.iter().map(|e| e.min).min().unwrap_or(0);
        let hi = entries.iter().map(|e| e.max).max().unwrap_or(0);
        let heights = (
            plan.offset + plan.unit * f64::from(lo),
            plan.offset + plan.unit * f64::from(hi),
        );
        if params.domain.kind() == DomainKind::CubeSphere {
            return Self::planet(params.domain, plan.unit, plan.offset, heights);
        }
        let (step_x, step_y) = match georef {
            Some(g) if g.epsg.is_some_and(|e| GEOGRAPHIC_EPSG.contains(&e)) => {
                let rows = params.domain.data().height;
                let centre_lat = g.origin_y - g.pixel_y * f64::from(rows) / 2.0;
                let cos = centre_lat.to_radians().cos().max(1e-3);
                (
                    g.pixel_x.abs() * METRES_PER_DEGREE * cos,
                    g.pixel_y.abs() * METRES_PER_DEGREE,
                )
            }
            Some(g) if g.pixel_x > 0.0 && g.pixel_y != 0.0 => (g.pixel_x, g.pixel_y.abs()),
            _ => (1.0, 1.0),
        };
        Self::planar(
            params.domain,
            (step_x, step_y),
            plan.unit,
            plan.offset,
            heights,
        )
    }

    /// A planet: the cube-sphere `domain` on WGS84, heights of `unit` metres per unit above
    /// `offset` along the ellipsoid normal, the data between `heights` metres (low, high).
    /// A planar `domain` gives a planar world of 1 m steps.
    pub fn planet(domain: Domain, unit: f64, offset: f64, heights: (f64, f64)) -> Self {
        let frame = match domain.cube() {
            Some(cube) => Frame::Ellipsoid {
                side: cube.side() as f64,
            },
            None => Frame::Planar {
                step_x: 1.0,
                step_y: 1.0,
            },
        };
        Self {
            domain,
            frame,
            unit,
            offset,
            min_height: heights.0,
            max_height: heights.1,
        }
    }

    /// Whether this is a planet (ECEF world positions) rather than a plane.
    pub fn is_planet(&self) -> bool {
        matches!(self.frame, Frame::Ellipsoid { .. })
    }

    /// The world of an opened repository.
    pub fn of_repository(repo: &cbdam_codec::repository::Repository) -> Self {
        Self::new(
            repo.head().params(),
            repo.head().plan(),
            repo.head().georef(),
            repo.head().entries(),
        )
    }

    /// World position of lattice point `(x, y)` at height `h` units (of face 0 on a planet:
    /// use [`World::face_point`] there).
    pub fn point(&self, x: i64, y: i64, h: i32) -> DVec3 {
        self.face_point(0, x, y, self.height(h))
    }

    /// World position of lattice point `(x, y)` of `face` (on a planet possibly past one of its
    /// edges, as grids of straddling diamonds are) at `metres` above the surface. On a planet
    /// the point is computed from its canonical point, so every face holding an edge vertex
    /// gets the same bits; a point off the surface (beyond a cube corner) is clamped onto the
    /// face.
    pub fn face_point(&self, face: u8, x: i64, y: i64, metres: f64) -> DVec3 {
        match self.frame {
            Frame::Planar { .. } => {
                let (wx, wy) = self.lattice_vector(x, y);
                DVec3::new(wx, wy, metres)
            }
            Frame::Ellipsoid { side } => {
                let s = side as i64;
                let FacePoint { face, x, y } =
                    self.domain
                        .canonical_point(face, x, y)
                        .unwrap_or(FacePoint {
                            face,
                            x: x.clamp(0, s),
                            y: y.clamp(0, s),
                        });
                let (surface, normal) = surface_and_normal(face, x as f64 / side, y as f64 / side);
                surface + normal * metres
            }
        }
    }

    /// The ellipsoid's outward unit normal at (or under) ECEF position `p` on a planet (the
    /// local "up"); `+z` on a plane.
    pub fn up(&self, p: DVec3) -> DVec3 {
        match self.frame {
            Frame::Planar { .. } => DVec3::Z,
            Frame::Ellipsoid { .. } => {
                let g = wgs84::Geodetic::from_ecef(p.to_array());
                DVec3::from_array(g.normal())
            }
        }
    }

    /// The horizon occluder of a planet: an ellipsoid inside the terrain (WGS84 lowered below
    /// the data's lowest height); `None` on a plane.
    pub fn occluder(&self) -> Option<Occluder> {
        match self.frame {
            Frame::Planar { .. } => None,
            Frame::Ellipsoid { .. } => {
                let drop = self.min_height.min(0.0) - OCCLUDER_MARGIN;
                Some(Occluder {
                    radii: DVec3::new(wgs84::A + drop, wgs84::A + drop, wgs84::B + drop),
                })
            }
        }
    }

    /// World displacement of lattice vector `(dx, dy)` on the ground (no height).
    #[inline]
    pub fn lattice_vector(&self, dx: i64, dy: i64) -> (f64, f64) {
        match self.frame {
            Frame::Planar { step_x, step_y } => (dx as f64 * step_x, -dy as f64 * step_y),
            Frame::Ellipsoid { .. } => {
                let m = self.mean_step();
                (dx as f64 * m, -dy as f64 * m)
            }
        }
    }

    /// Fractional lattice coordinates of the ground under world position `p` (of the face
    /// under it on a planet: see [`World::face_of`]).
    #[inline]
    pub fn lattice_of(&self, p: DVec3) -> (f64, f64) {
        match self.frame {
            Frame::Planar { step_x, step_y } => (p.x / step_x, -p.y / step_y),
            Frame::Ellipsoid { side } => {
                let (_, s, t) = self.face_of(p);
                (s * side, t * side)
            }
        }
    }

    /// The face under world position `p` and its face coordinates `s, t ∈ [0, 1]` (face 0 and
    /// the plane's lattice divided by its extent on a plane).
    pub fn face_of(&self, p: DVec3) -> (u8, f64, f64) {
        match self.frame {
            Frame::Planar { step_x, step_y } => {
                let (ex, ey) = self.domain.layout().face_extent();
                (
                    0,
                    p.x / step_x / ex.max(1) as f64,
                    -p.y / step_y / ey.max(1) as f64,
                )
            }
            Frame::Ellipsoid { .. } => {
                let g = wgs84::Geodetic::from_ecef(p.to_array());
                cbdam_codec::geodesy::cube_map::lat_lon_to_face_st(cbdam_codec::geodesy::LatLon {
                    lat: g.lat,
                    lon: g.lon,
                })
            }
        }
    }

    /// Mean metres per lattice step on the ground (on a planet, a quarter of the equator over
    /// the face side).
    pub fn mean_step(&self) -> f64 {
        match self.frame {
            Frame::Planar { step_x, step_y } => 0.5 * (step_x + step_y),
            Frame::Ellipsoid { side } => std::f64::consts::FRAC_PI_2 * wgs84::A / side,
        }
    }

    /// The shortest metres per lattice step on the ground (on a planet, a lower bound: the
    /// cells' sides vary by less than a factor 0.8 around the mean).
    pub fn min_step(&self) -> f64 {
        match self.frame {
            Frame::Planar { step_x, step_y } => step_x.min(step_y),
            Frame::Ellipsoid { .. } => 0.8 * self.mean_step(),
        }
    }

    /// The same world with `level_pairs` more level pairs of (synthetic) detail below the
    /// finest: lattice coordinates scale by `2^level_pairs`, metres per step shrink by as much.
    pub fn with_detail(&self, level_pairs: u32) -> Result<Self, cbdam_codec::CodecError> {
        let scale = f64::from(1u32 << level_pairs);
        let frame = match self.frame {
            Frame::Planar { step_x, step_y } => Frame::Planar {
                step_x: step_x / scale,
                step_y: step_y / scale,
            },
            Frame::Ellipsoid { side } => Frame::Ellipsoid { side: side * scale },
        };
        Ok(Self {
            domain: self.domain.with_detail(level_pairs)?,
            frame,
            ..*self
        })
    }

    /// Metres of height `h` units.
    pub fn height(&self, h: i32) -> f64 {
        self.offset + self.unit * f64::from(h)
    }

    /// World bounding box `(min, max)` of a diamond whose heights lie in `min..=max` units.
    ///
    /// On a planet the box holds the diamond's curved surface between both heights: the box of
    /// 3 × 3 points of its grid at both heights, grown by twice the sagitta of the spacing
    /// between them (`L²/(8R)`, `R` the polar radius), which bounds how far the surface between
    /// the samples bulges out of their hull.
    pub fn diamond_box(&self, id: DiamondId, min: i32, max: i32) -> (DVec3, DVec3) {
        if let Frame::Ellipsoid { .. } = self.frame {
            return self.curved_box(id, self.height(min), self.height(max));
        }
        let (x0, y0, x1, y1) = self.domain.layout().bounds(id);
        let a = self.point(x0, y0, min);
        let b = self.point(x1, y1, max);
        (a.min(b), a.max(b))
    }

    /// How far a diamond's flat triangles fall below the curved surface they stand for, metres:
    /// on a planet the sagitta `L²/(8R)` of its longest triangle edge `L` (the grid's cell
    /// diagonal, taken 1.2 times the mean step long: cells vary about the mean by less), `R` the
    /// polar radius; 0 on a plane. The object error measures heights only, so a coarse diamond
    /// seen close must be refined for this too (a root's triangles cut up to ~8 km under the
    /// surface on a 129-point face).
    pub fn chord_error(&self, id: DiamondId) -> f64 {
        match self.frame {
            Frame::Planar { .. } => 0.0,
            Frame::Ellipsoid { .. } => {
                let g = self.domain.layout().grid(id);
                let diag = |a: (i64, i64), b: (i64, i64)| {
                    ((a.0 + b.0) as f64)
                        .hypot((a.1 + b.1) as f64)
                        .max(((a.0 - b.0) as f64).hypot((a.1 - b.1) as f64))
                };
                let l = diag(g.u, g.v) * 1.2 * self.mean_step();
                l * l / (8.0 * wgs84::B)
            }
        }
    }

    fn curved_box(&self, id: DiamondId, lo_m: f64, hi_m: f64) -> (DVec3, DVec3) {
        let g = self.domain.layout().grid(id);
        let last = g.n as i64 - 1;
        let mut lo = DVec3::splat(f64::INFINITY);
        let mut hi = DVec3::splat(f64::NEG_INFINITY);
        let mut spacing: f64 = 0.0;
        for j in 0..3 {
            for i in 0..3 {
                let (x, y) = g.point(i * last / 2, j * last / 2);
                let at_lo = self.face_point(id.face, x, y, lo_m);
                let at_hi = self.face_point(id.face, x, y, hi_m);
                lo = lo.min(at_lo).min(at_hi);
                hi = hi.max(at_lo).max(at_hi);
                if i == 1 && j == 1 {
                    for (a, b) in [(0, 1), (2, 1), (1, 0), (1, 2)] {
                        let (px, py) = g.point(a * last / 2, b * last / 2);
                        let d = (self.face_point(id.face, px, py, lo_m) - at_lo).length();
                        spacing = spacing.max(d);
                    }
                }
            }
        }
        // Diagonal neighbours are √2 farther apart than the axis ones measured.
        let l = spacing * std::f64::consts::SQRT_2 * 1.1;
        let pad = l * l / (4.0 * (wgs84::B + lo_m.min(0.0))) + 1.0;
        (lo - DVec3::splat(pad), hi + DVec3::splat(pad))
    }

    /// World bounding box `(min, max)` of the region that holds data, over the data's height
    /// range: what a first view frames (on a planet, the box of the whole globe).
    pub fn bounds(&self) -> (DVec3, DVec3) {
        if let Frame::Ellipsoid { .. } = self.frame {
            let top = self.max_height.max(0.0);
            let r = DVec3::new(wgs84::A + top, wgs84::A + top, wgs84::B + top);
            return (-r, r);
        }
        let data = self.domain.data();
        let (wx, wy) = self.lattice_vector(
            i64::from(data.width.saturating_sub(1)),
            i64::from(data.height.saturating_sub(1)),
        );
        let a = DVec3::new(0.0, 0.0, self.min_height);
        let b = DVec3::new(wx, wy, self.max_height);
        (a.min(b), a.max(b))
    }
}

/// The ellipsoid point of face coordinates `s, t` (the ray of the warped cube direction meets
/// WGS84) and the ellipsoid's outward unit normal there.
fn surface_and_normal(face: u8, s: f64, t: f64) -> (DVec3, DVec3) {
    let d = DVec3::from_array(face_direction(CubeWarp::PLANET, face, s, t));
    let (a2, b2) = (wgs84::A * wgs84::A, wgs84::B * wgs84::B);
    let k = 1.0 / ((d.x * d.x + d.y * d.y) / a2 + d.z * d.z / b2).sqrt();
    let surface = d * k;
    let normal = DVec3::new(surface.x / a2, surface.y / a2, surface.z / b2).normalize();
    (surface, normal)
}

/// `world` with heights scaled by `factor` about 0 m, for vertical exaggeration: hand it to
/// the renderer and the camera, and the same factor to
/// [`RefineConfig::exaggeration`](crate::refine::RefineConfig::exaggeration). The colour ramp spans
/// the data's height range and sea level stays at 0 m, so land colours do not change; only the
/// water's depth tint (absolute metres) deepens with the factor.
pub fn exaggerated(world: &World, factor: f64) -> World {
    World {
        unit: world.unit * factor,
        offset: world.offset * factor,
        min_height: world.min_height * factor,
        max_height: world.max_height * factor,
        ..*world
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn planet() -> World {
        World::planet(
            Domain::cube_sphere(5, 3).unwrap(),
            1.0,
            0.0,
            (-4000.0, 6000.0),
        )
    }

    /// Every face holding an edge or corner vertex computes the same bits for it, and heights
    /// go along the ellipsoid normal (the geodetic height of the point is the height given).
    #[test]
    fn planet_vertices_are_one_point_from_every_face_and_heights_follow_the_normal() {
        let w = planet();
        let cube = *w.domain.cube().unwrap();
        let s = cube.side();
        let mut shared = 0;
        for face in 0..6u8 {
            for y in 0..=s {
                for x in 0..=s {
                    let p = w.face_point(face, x, y, 1234.5);
                    let (reps, count) = cube.representations(FacePoint { face, x, y });
                    for r in &reps[..count] {
                        assert_eq!(w.face_point(r.face, r.x, r.y, 1234.5), p, "{r:?}");
                        shared += usize::from(r.face != face);
                    }
                    if (x + y) % 7 == 0 {
                        let g = wgs84::Geodetic::from_ecef(p.to_array());
                        assert!((g.height - 1234.5).abs() < 1e-6, "{}", g.height);
                    }
                }
            }
        }
        assert!(shared > 0);
    }

    /// A diamond's box holds every vertex of its grid (both halves, across cube edges) at its
    /// lowest and highest height, on every level.
    #[test]
    fn planet_boxes_hold_their_diamonds() {
        let w = planet();
        let n = w.domain.n() as i64;
        for level in 0..=w.domain.finest_level() {
            for id in w.domain.level(level) {
                let (lo, hi) = w.diamond_box(id, -4000, 6000);
                let g = w.domain.layout().grid(id);
                for j in 0..n {
                    for i in 0..n {
                        let (x, y) = g.point(i, j);
                        for m in [-4000.0, 6000.0] {
                            let p = w.face_point(id.face, x, y, m);
                            assert!(p.cmpge(lo).all() && p.cmple(hi).all(), "{id} {i},{j}");
                        }
                    }
                }
            }
        }
    }

    /// The occluder hides the far side from a point above the near side, and never a vertex
    /// that a ray from the eye reaches without crossing the ellipsoid lowered to the data's
    /// lowest height.
    #[test]
    fn the_planet_occluder_hides_the_far_side_only() {
        let w = planet();
        let h = w
            .occluder()
            .unwrap()
            .from_eye(DVec3::new(wgs84::A + 500_000.0, 0.0, 0.0))
            .unwrap();
        assert!(h.hides_point(w.face_point(2, 4, 4, 6000.0)));
        assert!(!h.hides_point(w.face_point(0, 16, 16, -4000.0)));
        assert!(w.occluder().unwrap().from_eye(DVec3::ZERO).is_none());
    }
}
