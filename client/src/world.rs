//! From lattice coordinates and integer heights to world metres.
//!
//! The world frame is local and metric: x east, y north, z up, origin at lattice point (0, 0),
//! z = height in metres. Geographic rasters (spacing in degrees) are flattened around the data's
//! centre latitude — a local tangent-plane approximation that is what a viewer of one DEM wants;
//! a planet-wide mosaic needs the cube-sphere domain and an ellipsoid frame instead.
//!
//! What the surface is (faces, roots, where data lies) is the [`Domain`]'s; the world adds only
//! how lattice units become metres. Callers go through [`World::point`],
//! [`World::lattice_vector`], [`World::lattice_of`] and the boxes, never through the planar
//! spacing itself, so a second frame changes this file, not theirs.

use cbdam_codec::geometry::{DiamondId, Domain};
use cbdam_codec::hierarchy::CodecParams;
use cbdam_codec::input::GeoRef;
use cbdam_codec::quant::QuantPlan;
use cbdam_codec::repository::index::IndexEntry;
use glam::DVec3;

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
}

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
        let lo = entries.iter().map(|e| e.min).min().unwrap_or(0);
        let hi = entries.iter().map(|e| e.max).max().unwrap_or(0);
        Self::planar(
            params.domain,
            (step_x, step_y),
            plan.unit,
            plan.offset,
            (
                plan.offset + plan.unit * f64::from(lo),
                plan.offset + plan.unit * f64::from(hi),
            ),
        )
    }

    /// The world of an opened repository.
    pub fn of_repository(repo: &cbdam_codec::repository::Repository) -> Self {
        Self::new(repo.params(), repo.plan(), repo.georef(), repo.entries())
    }

    /// World position of lattice point `(x, y)` at height `h` units.
    pub fn point(&self, x: i64, y: i64, h: i32) -> DVec3 {
        let (wx, wy) = self.lattice_vector(x, y);
        DVec3::new(wx, wy, self.height(h))
    }

    /// World displacement of lattice vector `(dx, dy)` on the ground (no height).
    #[inline]
    pub fn lattice_vector(&self, dx: i64, dy: i64) -> (f64, f64) {
        match self.frame {
            Frame::Planar { step_x, step_y } => (dx as f64 * step_x, -dy as f64 * step_y),
        }
    }

    /// Fractional lattice coordinates of the ground under world position `p`.
    #[inline]
    pub fn lattice_of(&self, p: DVec3) -> (f64, f64) {
        match self.frame {
            Frame::Planar { step_x, step_y } => (p.x / step_x, -p.y / step_y),
        }
    }

    /// Mean metres per lattice step on the ground.
    pub fn mean_step(&self) -> f64 {
        match self.frame {
            Frame::Planar { step_x, step_y } => 0.5 * (step_x + step_y),
        }
    }

    /// The shortest metres per lattice step on the ground.
    pub fn min_step(&self) -> f64 {
        match self.frame {
            Frame::Planar { step_x, step_y } => step_x.min(step_y),
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
    pub fn diamond_box(&self, id: DiamondId, min: i32, max: i32) -> (DVec3, DVec3) {
        let (x0, y0, x1, y1) = self.domain.layout().bounds(id);
        let a = self.point(x0, y0, min);
        let b = self.point(x1, y1, max);
        (a.min(b), a.max(b))
    }

    /// World bounding box `(min, max)` of the region that holds data, over the data's height
    /// range: what a first view frames.
    pub fn bounds(&self) -> (DVec3, DVec3) {
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
