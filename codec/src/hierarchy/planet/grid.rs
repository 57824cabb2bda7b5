//! The input of a planet: six face grids of integer heights on a cube-sphere's lattice.

use rayon::prelude::*;

use crate::CodecError;
use crate::geometry::{Domain, FacePoint};
use crate::hierarchy::Resolution;
use crate::quant::HeightGrid;

/// Integer heights (and validity) at every lattice point of the six faces of a cube-sphere
/// (`Domain::cube_sphere(n, k)`): one `(S + 1) × (S + 1)` grid per face, `S = (N − 1)·2^K`,
/// indexed by the face's lattice `(x, y)`. A point on a cube edge or corner lies on two or
/// three faces; every face holding it holds the same value and validity (checked by
/// [`PlanetGrid::new`], by construction in [`PlanetGrid::from_fn`]).
///
/// A variable-resolution planet ([`PlanetGrid::with_classes`]) also says, per face point, what
/// the point is ([`Resolution`]): a sample of an input of stride `2^j` (a vertex of level
/// `L − 2j`, constrained from that level on), *coarse only* (between a coarser input's samples:
/// drawn, not constrained, so the hierarchy stops at that input's level there) or a hole.
#[derive(Clone, Debug, PartialEq)]
pub struct PlanetGrid {
    domain: Domain,
    faces: Vec<HeightGrid>,
    classes: Option<Vec<Resolution>>,
}

impl PlanetGrid {
    /// The planet whose faces are `faces` (face `f` at index `f`). Errors if there are not six
    /// faces of `(S + 1)²` points, or if two faces disagree on a shared edge or corner point.
    pub fn new(n: usize, k: u32, faces: Vec<HeightGrid>) -> Result<Self, CodecError> {
        let domain = Domain::cube_sphere(n, k)?;
        let cube = *domain.cube().expect("a cube-sphere has a cube");
        let side = cube.side();
        let points = side as usize + 1;
        if faces.len() != usize::from(domain.faces()) {
            return Err(CodecError::invalid(format!(
                "a planet has 6 faces, not {}",
                faces.len()
            )));
        }
        for (f, g) in faces.iter().enumerate() {
            if (g.width, g.height) != (points, points)
                || g.values.len() != points * points
                || g.valid.len() != points * points
            {
                return Err(CodecError::invalid(format!(
                    "face {f} is {}×{} samples; a cube-sphere face of N = {n}, K = {k} has \
                     {points}×{points}",
                    g.width, g.height
                )));
            }
        }
        let value = |p: FacePoint| faces[usize::from(p.face)].get(p.x, p.y);
        for face in 0..domain.faces() {
            for p in boundary(face, side) {
                let (reps, len) = cube.representations(p);
                for r in &reps[1..len] {
                    if value(p) != value(*r) {
                        let show =
                            |v: Option<i32>| v.map_or("nodata".to_string(), |v| v.to_string());
                        return Err(CodecError::invalid(format!(
                            "face {} ({}, {}) holds {} but face {} ({}, {}), the same point of \
                             a cube edge, holds {}: shared points must hold one value",
                            p.face,
                            p.x,
                            p.y,
                            show(value(p)),
                            r.face,
                            r.x,
                            r.y,
                            show(value(*r))
                        )));
                    }
                }
            }
        }
        Ok(Self {
            domain,
            faces,
            classes: None,
        })
    }

    /// The same planet at variable resolution: `classes[f]` classifies face `f`'s points
    /// ([`Resolution`], row-major like the face grid). Errors if a face's classes do not match
    /// its grid (samples exactly where it is valid) or two faces classify a shared edge or
    /// corner point differently.
    pub fn with_classes(self, classes: Vec<Resolution>) -> Result<Self, CodecError> {
        if classes.len() != self.faces.len() {
            return Err(CodecError::invalid(format!(
                "{} faces of classes for a planet of {} faces",
                classes.len(),
                self.faces.len()
            )));
        }
        for (f, (c, g)) in classes.iter().zip(&self.faces).enumerate() {
            c.check(g)
                .map_err(|e| CodecError::invalid(format!("face {f}: {e}")))?;
        }
        let cube = *self.domain.cube().expect("a cube-sphere has a cube");
        let side = cube.side();
        let points = side as usize + 1;
        let class =
            |p: FacePoint| classes[usize::from(p.face)].class[p.y as usize * points + p.x as usize];
        for face in 0..self.domain.faces() {
            for p in boundary(face, side) {
                let (reps, len) = cube.representations(p);
                if let Some(r) = reps[1..len].iter().find(|r| class(**r) != class(p)) {
                    return Err(CodecError::invalid(format!(
                        "face {} ({}, {}) and face {} ({}, {}), the same point of a cube edge, \
                         have different resolution classes ({} and {})",
                        p.face,
                        p.x,
                        p.y,
                        r.face,
                        r.x,
                        r.y,
                        class(p),
                        class(*r)
                    )));
                }
            }
        }
        Ok(Self {
            classes: Some(classes),
            ..self
        })
    }

    /// The planet whose height at every lattice point is `height` of the point's canonical
    /// coordinates ([`Domain::canonical_point`]; `None`: nodata), so shared edge and corner
    /// points are computed once.
    pub fn from_fn(
        n: usize,
        k: u32,
        height: impl Fn(FacePoint) -> Option<i32> + Sync,
    ) -> Result<Self, CodecError> {
        let domain = Domain::cube_sphere(n, k)?;
        let points = domain.cube().expect("a cube-sphere has a cube").side() as usize + 1;
        let faces = (0..domain.faces())
            .map(|face| {
                let samples: Vec<Option<i32>> = (0..points * points)
                    .into_par_iter()
                    .map(|k| {
                        let (x, y) = ((k % points) as i64, (k / points) as i64);
                        let c = domain
                            .canonical_point(face, x, y)
                            .expect("a point of the face square is on the surface");
                        height(c)
                    })
                    .collect();
                HeightGrid {
                    width: points,
                    height: points,
                    values: samples.iter().map(|v| v.unwrap_or(0)).collect(),
                    valid: samples.iter().map(Option::is_some).collect(),
                }
            })
            .collect();
        Ok(Self {
            domain,
            faces,
            classes: None,
        })
    }

    /// The cube-sphere the grids cover.
    pub fn domain(&self) -> &Domain {
        &self.domain
    }

    /// The grid of face `face`.
    ///
    /// # Panics
    /// If `face` is not a face (≥ 6).
    pub fn face(&self, face: u8) -> &HeightGrid {
        &self.faces[usize::from(face)]
    }

    /// The height at lattice point `(x, y)` of `face`'s frame — a point of the face or one past
    /// one of its edges (read on the face holding it) — or `None` at nodata or off the surface.
    #[inline]
    pub fn get(&self, face: u8, x: i64, y: i64) -> Option<i32> {
        let c = self.domain.canonical_point(face, x, y)?;
        self.faces[usize::from(c.face)].get(c.x, c.y)
    }

    /// Whether `(x, y)` of `face`'s frame (as for [`PlanetGrid::get`]) has data; `None` off the
    /// surface.
    #[inline]
    pub fn validity(&self, face: u8, x: i64, y: i64) -> Option<bool> {
        let c = self.domain.canonical_point(face, x, y)?;
        Some(self.faces[usize::from(c.face)].is_valid(c.x, c.y))
    }

    /// The resolution classes of face `face`, for a variable-resolution planet.
    pub fn classes(&self, face: u8) -> Option<&Resolution> {
        self.classes.as_ref().map(|c| &c[usize::from(face)])
    }

    /// Whether `(x, y)` of `face`'s frame (as for [`PlanetGrid::get`]) is drawn: a sample, or
    /// coarse only on a variable-resolution planet (what the nodata mask records); `None` off
    /// the surface.
    #[inline]
    pub fn drawn(&self, face: u8, x: i64, y: i64) -> Option<bool> {
        let c = self.domain.canonical_point(face, x, y)?;
        let g = &self.faces[usize::from(c.face)];
        Some(match &self.classes {
            Some(classes) => classes[usize::from(c.face)].drawn(g.width, c.x, c.y),
            None => g.is_valid(c.x, c.y),
        })
    }

    /// Whether some point is not drawn (no data at all): the hierarchy then carries a nodata
    /// mask.
    pub fn has_nodata(&self) -> bool {
        match &self.classes {
            Some(classes) => classes.iter().any(Resolution::has_holes),
            None => self.faces.iter().any(|g| g.valid.contains(&false)),
        }
    }

    /// Smallest and largest valid height, `None` when no point has data.
    pub fn range(&self) -> Option<(i32, i32)> {
        self.faces
            .iter()
            .filter_map(HeightGrid::range)
            .reduce(|a, b| (a.0.min(b.0), a.1.max(b.1)))
    }

    /// Distinct lattice points of the surface: `6·S² + 2` (edge and corner points once).
    pub fn lattice_points(&self) -> u64 {
        self.domain.lattice_points()
    }
}

/// The points on the boundary of face `face`'s square `[0, side]²` (corners twice).
fn boundary(face: u8, side: i64) -> impl Iterator<Item = FacePoint> {
    (0..=side).flat_map(move |t| {
        [(t, 0), (t, side), (0, t), (side, t)].map(|(x, y)| FacePoint::new(face, x, y))
    })
}
