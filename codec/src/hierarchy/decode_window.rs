//! Decoding one level over a rectangle of a planar hierarchy, or over rectangles of a planet's
//! faces, in parallel: what a reader of a window (`cbdam.open(...).read(window=...)` and
//! `read_geo` in Python) needs, decoding only the records that reach the window.
//!
//! Which diamonds matter. A grid point of a diamond of level `l` lies within `radius(l)` of its
//! centre, and a parent's centre within the parent's radius of its child's. So every diamond of
//! the target level `L` with a grid point in the window is centred within `radius(L)` of it, and
//! its ancestors at level `l` within `reach(l) = radius(L) + Σ_{m=l}^{L−1} radius(m)`
//! ([`LevelWindow::reach`]). Decoding, level by level, only the stored diamonds within the reach
//! of their level decodes each of them exactly as the whole walk
//! ([`super::walk_all_with_validity`]) does, and visits at level `L`, in the whole walk's order,
//! every diamond the whole walk visits there that has a grid point in the window — so per
//! sample of the window the last visit, the value and validity a reader keeps, is the whole
//! walk's. The refinements of one level are independent of each other and run on rayon's pool.
//!
//! On a planet ([`FaceWindows`]) distances are measured on the cube `[−S, S]³`
//! ([`crate::geometry::Cube::cube_point`], twice the lattice units), L∞. A step between a
//! diamond's centre and a parent's (or one of its grid points) is a straight segment in the
//! diamond's face frame, which relation offsets carry across at most one edge; folded onto the
//! cube along that edge its L∞ length does not grow (the two legs across the edge become
//! orthogonal), so the reach bounds the cube distance as it bounds the plane's.
use std::collections::HashMap;

use rayon::prelude::*;

use super::CodecParams;
use super::decode::{Decoder, leaves_of};
use super::refine::{RefineScratch, Refined};
use crate::CodecError;
use crate::geometry::{Cube, DiamondId, DomainKind, FacePoint};

/// One level's samples over an inclusive lattice rectangle `(x0, y0, x1, y1)` of a planar
/// domain (lattice x = column, y = row of the data, row 0 north).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LevelWindow {
    /// The level to decode (any level; only even ones are axis-aligned grids).
    pub level: u8,
    /// The rectangle, inclusive, in lattice units.
    pub rect: (i64, i64, i64, i64),
}

/// An inclusive lattice rectangle `(x0, y0, x1, y1)` of one face: `(face, rectangle)`.
pub type FaceRect = (u8, (i64, i64, i64, i64));

/// One level's samples over inclusive lattice rectangles of a planet's faces: `(face, (x0, y0,
/// x1, y1))` in that face's lattice units (`0..=S`). A point on a face edge may be asked through
/// any face holding it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FaceWindows {
    /// The level to decode.
    pub level: u8,
    /// The rectangles.
    pub rects: Vec<FaceRect>,
}

/// Diamonds decoded in one parallel step of the target level before they are visited in order:
/// bounds the grids held at once.
const VISIT_CHUNK: usize = 4096;

/// How far (L∞, lattice units) from a window of level `target` the diamonds of `level` that
/// the read needs can be centred (see the module documentation).
fn reach_of(params: &CodecParams, target: u8, level: u8) -> i64 {
    let layout = params.layout();
    let ancestors: i64 = (level..target).map(|l| layout.radius(l)).sum();
    ancestors + layout.radius(target)
}

/// What a windowed decode keeps: the target level and the test of a diamond's centre.
enum Region {
    /// A planar rectangle.
    Plane(LevelWindow),
    /// Boxes on the cube `[−S, S]³`, per axis `(min, max)` ([`Cube::cube_point`]).
    Cube {
        level: u8,
        cube: Cube,
        boxes: Vec<[(i64, i64); 3]>,
    },
}

impl Region {
    fn level(&self) -> u8 {
        match self {
            Region::Plane(w) => w.level,
            Region::Cube { level, .. } => *level,
        }
    }

    /// Whether `id`'s centre lies within `reach` lattice units of the window.
    fn within(&self, id: DiamondId, reach: i64) -> bool {
        let (x, y) = (i64::from(id.x), i64::from(id.y));
        match self {
            Region::Plane(w) => {
                let (x0, y0, x1, y1) = w.rect;
                x >= x0 - reach && x <= x1 + reach && y >= y0 - reach && y <= y1 + reach
            }
            Region::Cube { cube, boxes, .. } => {
                let p = cube.cube_point(FacePoint::new(id.face, x, y));
                // Cube units are twice the lattice's.
                boxes.iter().any(|b| {
                    (0..3).all(|k| p[k] >= b[k].0 - 2 * reach && p[k] <= b[k].1 + 2 * reach)
                })
            }
        }
    }

    /// The stored diamonds above the target level within their level's reach, in id order.
    fn records_needed(&self, params: &CodecParams, stored: &[DiamondId]) -> Vec<DiamondId> {
        let target = self.level();
        let mut ids: Vec<DiamondId> = stored
            .iter()
            .copied()
            .filter(|&id| id.level < target && self.within(id, reach_of(params, target, id.level)))
            .collect();
        ids.sort_unstable();
        ids
    }
}

/// Refuses a level past the finest.
fn check_level(params: &CodecParams, level: u8) -> Result<(), CodecError> {
    let finest = params.layout().finest_level();
    if level > finest {
        return Err(CodecError::invalid(format!(
            "level {level}: the finest level of this repository is {finest}"
        )));
    }
    Ok(())
}

impl LevelWindow {
    /// How far (L∞, lattice units) from the rectangle the diamonds of `level` that the read
    /// needs can be centred (see the module documentation).
    pub fn reach(&self, params: &CodecParams, level: u8) -> i64 {
        reach_of(params, self.level, level)
    }

    /// The stored diamonds (of `stored`, the index's ids) whose records the read decodes: those
    /// above the target level within their level's reach, in id order. What a remote reader
    /// fetches before [`decode_window`].
    pub fn records_needed(&self, params: &CodecParams, stored: &[DiamondId]) -> Vec<DiamondId> {
        Region::Plane(*self).records_needed(params, stored)
    }

    /// Refuses what this reader cannot decode: a cube-sphere, or a level past the finest.
    fn region(&self, params: &CodecParams) -> Result<Region, CodecError> {
        if params.domain.kind() != DomainKind::Planar {
            return Err(CodecError::unsupported(
                "a window read decodes planar repositories; this one is a planet (cube-sphere)",
            ));
        }
        check_level(params, self.level)?;
        Ok(Region::Plane(*self))
    }
}

impl FaceWindows {
    /// The stored diamonds (of `stored`) whose records [`decode_face_windows`] decodes, in id
    /// order; an error for what it refuses (see there).
    pub fn records_needed(
        &self,
        params: &CodecParams,
        stored: &[DiamondId],
    ) -> Result<Vec<DiamondId>, CodecError> {
        Ok(self.region(params)?.records_needed(params, stored))
    }

    /// Refuses a plane, a face that is not one, a rectangle off its face, a level past the
    /// finest.
    fn region(&self, params: &CodecParams) -> Result<Region, CodecError> {
        let Some(cube) = params.domain.cube().copied() else {
            return Err(CodecError::unsupported(
                "face windows are read from planets (cube-sphere); this repository is planar",
            ));
        };
        check_level(params, self.level)?;
        let s = cube.side();
        let mut boxes = Vec::with_capacity(self.rects.len());
        for &(face, (x0, y0, x1, y1)) in &self.rects {
            let on_face = (0..=s).contains(&x0) && (x0..=s).contains(&x1);
            let on_face = on_face && (0..=s).contains(&y0) && (y0..=s).contains(&y1);
            if face >= params.domain.faces() || !on_face {
                return Err(CodecError::invalid(format!(
                    "face window {face} ({x0}, {y0})–({x1}, {y1}) is not on a face of side {s}"
                )));
            }
            let a = cube.cube_point(FacePoint::new(face, x0, y0));
            let b = cube.cube_point(FacePoint::new(face, x1, y1));
            boxes.push(std::array::from_fn(|k| (a[k].min(b[k]), a[k].max(b[k]))));
        }
        Ok(Region::Cube {
            level: self.level,
            cube,
            boxes,
        })
    }
}

/// Decodes `window.level` over `window.rect` and hands `visit` every diamond of that level the
/// whole walk ([`super::walk_all_with_validity`]) visits with a grid point in the rectangle, in
/// the same order, with its grid and validity: the stored diamonds and the leaves below stored
/// parents. `stored`: every stored diamond (the index's ids); `record`: the bytes of one of them
/// (asked only for [`LevelWindow::records_needed`], from rayon's threads), checked by the
/// caller. A stored diamond with a parent that is not is corrupt, as in the whole walk.
pub fn decode_window<'a>(
    params: CodecParams,
    roots: &[u8],
    stored: &[DiamondId],
    record: impl Fn(DiamondId) -> Result<&'a [u8], CodecError> + Sync,
    window: LevelWindow,
    visit: impl FnMut(DiamondId, &[i32], Option<&[bool]>),
) -> Result<(), CodecError> {
    let region = window.region(&params)?;
    decode_region(params, roots, stored, record, &region, visit)
}

/// [`decode_window`] on a planet: `visit` gets every diamond of `windows.level` the whole walk
/// visits with a grid point in one of the rectangles (a straddling diamond's grid runs past its
/// face's edge: carry its points with [`crate::geometry::Domain::canonical_point`]), in the
/// whole walk's order. `record` is asked only for [`FaceWindows::records_needed`].
pub fn decode_face_windows<'a>(
    params: CodecParams,
    roots: &[u8],
    stored: &[DiamondId],
    record: impl Fn(DiamondId) -> Result<&'a [u8], CodecError> + Sync,
    windows: &FaceWindows,
    visit: impl FnMut(DiamondId, &[i32], Option<&[bool]>),
) -> Result<(), CodecError> {
    let region = windows.region(&params)?;
    decode_region(params, roots, stored, record, &region, visit)
}

/// The decode both share: the stored diamonds within reach, level by level, then the visits.
fn decode_region<'a>(
    params: CodecParams,
    roots: &[u8],
    stored: &[DiamondId],
    record: impl Fn(DiamondId) -> Result<&'a [u8], CodecError> + Sync,
    region: &Region,
    mut visit: impl FnMut(DiamondId, &[i32], Option<&[bool]>),
) -> Result<(), CodecError> {
    let target = region.level();
    let decoder = Decoder::new(params, roots)?;
    let finest = params.layout().finest_level();
    let mut by_level: Vec<Vec<DiamondId>> = vec![Vec::new(); usize::from(finest) + 1];
    for &id in stored {
        if id.level >= finest || !params.domain.contains(id) {
            return Err(CodecError::corrupt(format!(
                "record for impossible diamond {id}"
            )));
        }
        if id.level <= target && region.within(id, reach_of(&params, target, id.level)) {
            by_level[usize::from(id.level)].push(id);
        }
    }
    for level in &mut by_level {
        level.sort_unstable();
    }
    let mut prev: HashMap<DiamondId, Refined> = HashMap::new();
    for level in 0..=target {
        let stored_here = &by_level[usize::from(level)];
        let ids = if finest == 0 {
            // A single level: the roots are the leaves, and there are no records.
            params.domain.roots().collect()
        } else if level == 0 {
            stored_here.clone()
        } else {
            let reach = reach_of(&params, target, level);
            let mut ids = leaves_of(&params, prev.keys().copied(), &prev, |c| {
                region.within(c, reach)
            });
            ids.extend_from_slice(stored_here);
            ids.sort_unstable();
            ids.dedup();
            ids
        };
        if level == target {
            return visit_level(&decoder, &ids, &prev, &mut visit);
        }
        check_parents(&decoder, stored_here, &prev)?;
        prev = refine_level(&decoder, stored_here, &prev, &record)?;
    }
    Ok(())
}

/// A stored diamond whose existing parents are not all stored is corrupt.
fn check_parents(
    decoder: &Decoder,
    ids: &[DiamondId],
    prev: &HashMap<DiamondId, Refined>,
) -> Result<(), CodecError> {
    let domain = &decoder.params().domain;
    for &id in ids.iter().filter(|id| id.level > 0) {
        if domain
            .parents(id)
            .into_iter()
            .flatten()
            .any(|p| !prev.contains_key(&p))
        {
            return Err(CodecError::corrupt(format!(
                "{id} is stored but a parent is not"
            )));
        }
    }
    Ok(())
}

/// The refinements of the stored diamonds `ids` of one level, in parallel.
fn refine_level<'a>(
    decoder: &Decoder,
    ids: &[DiamondId],
    prev: &HashMap<DiamondId, Refined>,
    record: &(impl Fn(DiamondId) -> Result<&'a [u8], CodecError> + Sync),
) -> Result<HashMap<DiamondId, Refined>, CodecError> {
    let domain = &decoder.params().domain;
    ids.par_iter()
        .map_init(RefineScratch::default, |scratch, &id| {
            let parents = domain.parents(id).map(|p| p.and_then(|p| prev.get(&p)));
            let p = decoder.grid_of(id, parents);
            Ok((id, decoder.refine(id, &p, record(id)?, scratch)?))
        })
        .collect()
}

/// Gathers the grids of the target level's `ids` in parallel, a chunk at a time, and visits
/// them in order.
fn visit_level(
    decoder: &Decoder,
    ids: &[DiamondId],
    prev: &HashMap<DiamondId, Refined>,
    visit: &mut impl FnMut(DiamondId, &[i32], Option<&[bool]>),
) -> Result<(), CodecError> {
    let domain = &decoder.params().domain;
    for chunk in ids.chunks(VISIT_CHUNK) {
        let grids: Vec<(Vec<i32>, Option<Vec<bool>>)> = chunk
            .par_iter()
            .map(|&id| {
                let parents = domain.parents(id).map(|p| p.and_then(|p| prev.get(&p)));
                (
                    decoder.grid_of(id, parents),
                    decoder.validity_of(id, parents),
                )
            })
            .collect();
        for (&id, (grid, valid)) in chunk.iter().zip(&grids) {
            visit(id, grid, valid.as_deref());
        }
    }
    Ok(())
}
