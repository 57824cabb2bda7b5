//! The hierarchy over a cube-sphere: encoding a [`PlanetGrid`], and the exact verifier and the
//! per-face reconstruction on the decoding side.
//!
//! The planar encoder's steps, per diamond, with every lattice point addressed as
//! `(face, x, y)`: targets and nodata mask are read through [`PlanetGrid::get`] (points of a
//! diamond centred on a cube edge that lie past the edge are read on the neighbouring face),
//! the grids are gathered from the parents' refinements with [`super::gather`] (which carries a
//! half across a face edge, [`crate::geometry::Domain::grid_in_parent_frame`]), the root field
//! codes each shared edge and corner vertex once, and the object error of a diamond centred on
//! a cube edge compares each half with its own face's input. The previous level's refinements
//! are kept per diamond (as [`super::encode`] does for α = ½); α = 1 only.

mod apex;
mod apex_finest;
mod apex_grids;
mod apex_view;
mod block_groups;
mod blocks;
mod finished;
mod grid;
mod outline;
mod spill;
mod tile_source;
mod verify_blocks;

pub use apex::PlanetApex;
pub use apex_grids::{
    ApexGrids, ApexRefinements, IN_MEMORY_BYTES as APEX_GRIDS_IN_MEMORY_BYTES,
    REFINEMENTS_IN_MEMORY_BYTES as APEX_REFINEMENTS_IN_MEMORY_BYTES,
};
pub use apex_view::{ApexView, ApexViewWriter, IN_MEMORY_BYTES as APEX_VIEW_IN_MEMORY_BYTES};
pub use block_groups::{BlockGroups, TileGroup};
pub use finished::{BYTES_PER_RECORD, BYTES_PER_STORED};
pub use outline::PlanetOutline;

pub use blocks::{
    APEX_VIEW_BYTES, Apex, PlanetBlocks, default_cut, encode_planet_in_blocks, planet_block_groups,
};
pub use tile_source::{PlanetTiles, only_part, thinned};
pub use verify_blocks::{PlanetBlockVerify, group_rect};

pub use grid::{MAX_TILES_ACROSS, PlanetGrid, PlanetTile, TILE_MIN_LOG2, tile_log2, tile_of};

use std::borrow::Cow;
use std::collections::{BTreeSet, HashMap};

use rayon::prelude::*;

use super::decode::{LevelReport, VerifyReport, walk_all_with_validity};
use super::encode::{
    EncodeOptions, grid_from_parents, per_diamond_levels, record_of, refine_encode, saturate_errors,
};
use super::object_error::{ErrorInput, grid_abs, surface_error_of};
use super::refine::Refined;
use super::resolution::with_parents;
use super::roots::encode_roots;
use super::{CodecParams, Encoded, Record, RepoKind};
use crate::CodecError;
use crate::geometry::{DiamondId, Domain, DomainKind, Half, Layout};
use crate::lifting::Alpha;
use crate::quant::{HeightGrid, Quantizer};

/// Encodes a planet with residual quantizer `quantizer`: every reconstructed vertex of every
/// level within `k` units of the input at that point, on every face. `opts.n` must be the
/// planet's `N`; the planet's lattice fixes the levels, so `extra_level_pairs` must be 0.
///
/// Errors for α = ½ (not implemented on a cube-sphere), a planet without data, or heights
/// that overflow the integer range.
pub fn encode_planet(
    planet: &PlanetGrid,
    quantizer: Quantizer,
    opts: &EncodeOptions,
) -> Result<Encoded, CodecError> {
    let domain = *planet.domain();
    let params = planet_params(domain, quantizer, opts, planet.has_nodata())?;
    if planet.range().is_none() {
        return Err(CodecError::invalid("the planet has no valid sample"));
    }
    let (stored, recorded) = stored_sets(planet);
    let (root_field, roots) = encode_roots(
        &params,
        |f, x, y| planet.get(f, x, y),
        |f, x, y| planet.drawn(f, x, y) == Some(true),
    )?;
    let errors = TiledError::new(planet)?;
    let finest = domain.finest_level();
    let pass = per_diamond_levels(&domain, &root_field, &stored, 0..finest + 1, |id, p| {
        let err = planet_surface_error(&domain, id, &p, &errors);
        // Leaves: the finest level, and where coarse data ends the hierarchy above it.
        if !recorded[id.level as usize].contains(&id) {
            return Ok((None, err));
        }
        Ok((Some(refine_diamond(&params, planet, id, &p)?), err))
    })?;
    let own_error: HashMap<DiamondId, u32> = pass.visited.into_iter().collect();
    let records = pass.records;
    let (records, leaf_error) = saturate_errors(&domain, &stored, records, &own_error);
    Ok(Encoded {
        params,
        roots,
        records,
        leaf_error,
    })
}

/// The checks [`encode_planet`] makes of its options, and the parameters it encodes with.
fn planet_params(
    domain: Domain,
    quantizer: Quantizer,
    opts: &EncodeOptions,
    nodata_mask: bool,
) -> Result<CodecParams, CodecError> {
    if opts.alpha != Alpha::One {
        return Err(CodecError::unsupported(
            "a cube-sphere is encoded with α = 1 only (the α = ½ analysis filter is planar)",
        ));
    }
    if opts.n != domain.n() {
        return Err(CodecError::invalid(format!(
            "the planet's lattice is laid out for N = {}, not N = {}",
            domain.n(),
            opts.n
        )));
    }
    if opts.extra_level_pairs != 0 {
        return Err(CodecError::invalid(
            "a planet's lattice fixes its levels: extra level pairs do not apply",
        ));
    }
    Ok(CodecParams {
        domain,
        alpha: opts.alpha,
        coder: opts.coder,
        quantizer,
        levels: None,
        root_quantizer: super::root_quantizer(quantizer),
        nodata_mask,
        kind: RepoKind::Elevation,
    })
}

/// Refines `id`, whose grid is `p`, against the planet's targets: its refinement and record.
fn refine_diamond(
    params: &CodecParams,
    planet: &PlanetGrid,
    id: DiamondId,
    p: &[i32],
) -> Result<(Refined, Record), CodecError> {
    let domain = &params.domain;
    let n = domain.n();
    let side = domain.cube().expect("a cube-sphere").side();
    let drawn = |x, y| planet.drawn(id.face, x, y);
    let (x0, y0, x1, y1) = domain.layout().bounds(id);
    let tile = planet.tile(id.face, planet.tile_index(x0.max(0), y0.max(0)));
    let (tx0, ty0, tx1, ty1) = tile.rect;
    let inside = 0 < x0.min(y0) && x1.max(y1) < side;
    let r = if inside
        && tile.stride == 0
        && (tx0..=tx1).contains(&x0)
        && (tx0..=tx1).contains(&x1)
        && (ty0..=ty1).contains(&y0)
        && (ty0..=ty1).contains(&y1)
    {
        // Strictly inside its face and inside one tile holding every point, every point of
        // the diamond is its own canonical point: read the tile's samples directly (what
        // `PlanetGrid::get` returns there, without locating each point).
        let g = &tile.grid;
        let (values, valid): (&[i32], &[bool]) = (&g.values, &g.valid);
        let w = g.width;
        let target = |x: i64, y: i64| {
            let k = (y - ty0) as usize * w + (x - tx0) as usize;
            valid[k].then(|| values[k])
        };
        refine_encode(params, id, p, target, drawn)?
    } else if inside {
        // Inside the face but over several tiles: each point read on its tile, still without
        // locating it.
        let target = |x: i64, y: i64| {
            let (t, k) = planet.held(id.face, x, y)?;
            t.grid.valid[k].then(|| t.grid.values[k])
        };
        refine_encode(params, id, p, target, drawn)?
    } else {
        refine_encode(params, id, p, |x, y| planet.get(id.face, x, y), drawn)?
    };
    let refined = Refined::from_parts(n, p, &r.cells);
    Ok((refined, record_of(id, p, r.bytes)))
}

/// The stored diamonds of every level and, per level, those that get a record (the parents of
/// the next level's stored diamonds).
///
/// At one resolution the leaves are the finest diamonds whose closed square holds a valid point
/// of their face. At variable resolution ([`PlanetGrid::with_classes`]), as on a plane
/// ([`super::resolution`]): for each stride `2^j` a face's samples have, the level-`L − 2j`
/// diamonds (squares inside the face, as every even level's) whose closed square holds a sample
/// of that stride. Then all their ancestors, across face edges. Found tile by tile, from the
/// points the tiles hold.
fn stored_sets(planet: &PlanetGrid) -> (Vec<Vec<DiamondId>>, Vec<BTreeSet<DiamondId>>) {
    let domain = planet.domain();
    let finest = domain.finest_level();
    let found: Vec<Vec<BTreeSet<DiamondId>>> = (0..domain.faces())
        .flat_map(|f| planet.tiles(f).iter().map(move |t| (f, t)))
        .collect::<Vec<_>>()
        .into_par_iter()
        .map(|(face, t)| tile_leaves(domain, face, t))
        .collect();
    let mut leaves: Vec<BTreeSet<DiamondId>> = vec![BTreeSet::new(); finest as usize + 1];
    for tile in found {
        for (all, some) in leaves.iter_mut().zip(tile) {
            all.extend(some);
        }
    }
    let sets = with_parents(domain, &leaves);
    (sets.stored, sets.recorded)
}

/// The leaves (per level) that the points of one tile `t` of face `face` make: for each
/// stride `2^j` its samples have, the level-`L − 2j` diamonds (squares inside the face) whose
/// closed square holds a sample of that stride in the tile ([`stored_sets`]).
fn tile_leaves(domain: &Domain, face: u8, t: &PlanetTile) -> Vec<BTreeSet<DiamondId>> {
    let layout = domain.layout();
    let finest = domain.finest_level();
    let side = domain.cube().expect("a cube-sphere").side();
    // The class of the point held at `k`: its stride's log2 for a sample, ≥ 32 otherwise.
    let class_of = |t: &PlanetTile, k: usize| match &t.class {
        Some(class) => class[k],
        None if t.grid.valid[k] => 0,
        None => u8::MAX,
    };
    let mut leaves = vec![BTreeSet::new(); finest as usize + 1];
    let mut present = 0u32;
    for k in 0..t.points() {
        let c = class_of(t, k);
        if c < 32 {
            present |= 1 << c;
        }
    }
    let (tx0, ty0, tx1, ty1) = t.rect;
    let step = 1i64 << t.stride;
    for j in (0..32u8).filter(|j| present & (1 << j) != 0) {
        // Strides above the root spacing are root points: their leaves are roots.
        let level = finest.saturating_sub(2 * j);
        let r = layout.radius(level);
        // The squares of the level meeting the tile (closed), inside the face.
        let squares = |a0: i64, a1: i64| {
            let first = ((a0 - 1).max(0)) / (2 * r);
            let last = (a1 / (2 * r)).min(side / (2 * r) - 1);
            first..=last
        };
        for sy in squares(ty0, ty1) {
            for sx in squares(tx0, tx1) {
                let (x0, y0) = ((2 * sx * r).max(tx0), (2 * sy * r).max(ty0));
                let (x1, y1) = ((2 * (sx + 1) * r).min(tx1), (2 * (sy + 1) * r).min(ty1));
                if x0 > x1 || y0 > y1 {
                    continue;
                }
                // The held points of the square's part in the tile.
                let up = |v: i64, o: i64| o + (v - o + step - 1) / step * step;
                let hit = (up(y0, ty0)..=y1).step_by(step as usize).any(|y| {
                    (up(x0, tx0)..=x1)
                        .step_by(step as usize)
                        .any(|x| t.index(x, y).is_some_and(|k| class_of(t, k) == j))
                });
                if hit {
                    leaves[level as usize].insert(DiamondId::on_face(
                        face,
                        level,
                        ((2 * sx + 1) * r) as u32,
                        ((2 * sy + 1) * r) as u32,
                    ));
                }
            }
        }
    }
    leaves
}

/// The object errors of diamonds against a planet's tiles: each tile measured in a lattice
/// coarsened to its stride ([`ErrorInput::placed_at`] on a layout of `K − s` level pairs, where
/// the diamond's grid spacing is the same number of the tile's points), or, for a diamond finer
/// than a tile's points (next to finer data), on a grid of the points it covers at the
/// diamond's finest spacing.
struct TiledError<'a> {
    planet: &'a PlanetGrid,
    /// Index `s`: the layout of the lattice coarsened `2^s` times.
    layouts: Vec<Layout>,
}

impl<'a> TiledError<'a> {
    fn new(planet: &'a PlanetGrid) -> Result<Self, CodecError> {
        let domain = planet.domain();
        let layout = domain.layout();
        let layouts = (0..=layout.k())
            .map(|s| Ok(*Domain::cube_sphere(layout.n(), layout.k() - s)?.layout()))
            .collect::<Result<Vec<_>, CodecError>>()?;
        Ok(Self { planet, layouts })
    }

    /// The error of `id`'s grid `p` (in the frame of `id.face`) against the valid points of
    /// that face under it.
    fn face_error(&self, id: DiamondId, p: &[i32]) -> u32 {
        let bounds = self.planet.domain().layout().bounds(id);
        let meeting: Vec<usize> = self.planet.tiles_meeting(bounds).collect();
        self.face_error_over(id, p, meeting)
    }

    /// [`TiledError::face_error`] over the tiles `meeting` of `id.face` only (indices among
    /// [`PlanetGrid::tiles`]): the face's error is the largest over the tiles meeting the
    /// diamond.
    fn face_error_over(&self, id: DiamondId, p: &[i32], meeting: Vec<usize>) -> u32 {
        let planet = self.planet;
        let layout = planet.domain().layout();
        let finest = layout.finest_level();
        let bounds = layout.bounds(id);
        let p_abs = grid_abs(p);
        let one = |i: usize| -> u32 {
            let t = planet.tile(id.face, i);
            let (max_abs, all_valid) = t.bounds();
            // The coarsest spacing, in lattice steps, at which the diamond's grid lies on
            // lattice points: its level's finest.
            let fits = u32::from(finest - id.level) / 2;
            let scaled = |s: u32| DiamondId::on_face(id.face, id.level, id.x >> s, id.y >> s);
            if t.stride <= fits {
                let s = t.stride;
                let input = ErrorInput::with_bounds(&t.grid, max_abs, all_valid)
                    .placed_at((t.rect.0 >> s, t.rect.1 >> s));
                return surface_error_of(&self.layouts[s as usize], scaled(s), p, p_abs, &input);
            }
            // Finer than the tile's points: its part of the tile at spacing 2^fits, the
            // tile's points valid where they are.
            let s = fits;
            let step = 1i64 << t.stride;
            let (tx0, ty0, tx1, ty1) = t.rect;
            let down = |v: i64, o: i64| o + (v - o).div_euclid(step) * step;
            let (x0, y0) = (down(bounds.0.max(tx0), tx0), down(bounds.1.max(ty0), ty0));
            let up = |v: i64, o: i64| down(v + step - 1, o);
            let (x1, y1) = (up(bounds.2.min(tx1), tx0), up(bounds.3.min(ty1), ty0));
            if x0 > x1 || y0 > y1 {
                return 0;
            }
            let (w, h) = (((x1 - x0) >> s) as usize + 1, ((y1 - y0) >> s) as usize + 1);
            let mut values = vec![0; w * h];
            let mut valid = vec![false; w * h];
            for y in (y0..=y1).step_by(step as usize) {
                for x in (x0..=x1).step_by(step as usize) {
                    if let Some(k) = t.index(x, y) {
                        let at = ((y - y0) >> s) as usize * w + ((x - x0) >> s) as usize;
                        values[at] = t.grid.values[k];
                        valid[at] = t.grid.valid[k];
                    }
                }
            }
            let grid = HeightGrid {
                width: w,
                height: h,
                values: values.into(),
                valid: valid.into(),
            };
            let input =
                ErrorInput::with_bounds(&grid, max_abs, false).placed_at((x0 >> s, y0 >> s));
            surface_error_of(&self.layouts[s as usize], scaled(s), p, p_abs, &input)
        };
        if meeting.len() > 2 {
            meeting.into_par_iter().map(one).max().unwrap_or(0)
        } else {
            meeting.into_iter().map(one).max().unwrap_or(0)
        }
    }
}

/// The object error of `id` with grid `p` against the planet's faces: the largest over its
/// [`views`].
fn planet_surface_error(domain: &Domain, id: DiamondId, p: &[i32], errors: &TiledError) -> u32 {
    views(domain, id, p)
        .into_iter()
        .map(|(seen, q)| errors.face_error(seen, &q))
        .max()
        .unwrap_or(0)
}

/// The faces' views of `id` with grid `p` that its object error measures: its own face's, and
/// for a diamond centred on a cube edge also the neighbouring face's under its other half — the
/// same diamond seen from that face (the grid carried into that face's frame and re-indexed as
/// that face's diamond of the same centre, whose split diagonal is the same edge).
fn views<'p>(domain: &Domain, id: DiamondId, p: &'p [i32]) -> Vec<(DiamondId, Cow<'p, [i32]>)> {
    let layout = domain.layout();
    let mut out = vec![(id, Cow::Borrowed(p))];
    for half in Half::BOTH {
        let (face, g) = domain.half_grid(id, half);
        if face == id.face {
            continue;
        }
        let n = layout.n();
        let mid = (n as i64 - 1) / 2;
        let (cx, cy) = g.point(mid, mid);
        let (Ok(cx), Ok(cy)) = (u32::try_from(cx), u32::try_from(cy)) else {
            continue;
        };
        let seen = DiamondId::on_face(face, id.level, cx, cy);
        let g_seen = layout.grid(seen);
        let mut q = vec![0i32; n * n];
        for j in 0..n {
            for i in 0..n {
                let (a, b) = g
                    .index_of(g_seen.point(i as i64, j as i64))
                    .expect("the same diamond's grid points");
                q[j * n + i] = p[b as usize * n + a as usize];
            }
        }
        out.push((seen, Cow::Owned(q)));
    }
    out
}

fn planet_only(encoded: &Encoded, planet: &PlanetGrid) -> Result<(), CodecError> {
    if encoded.params.domain.kind() != DomainKind::CubeSphere {
        return Err(CodecError::invalid(
            "this hierarchy is planar: verify it against a height grid",
        ));
    }
    if encoded.params.domain != *planet.domain() {
        return Err(CodecError::invalid(
            "the planet's lattice (N, K) differs from the hierarchy's",
        ));
    }
    Ok(())
}

/// Decodes the whole hierarchy and compares every reconstructed vertex of every level, on
/// every face (a diamond centred on a cube edge: both halves, each read on its own face), with
/// the planet's input there. A bound violation is reported, not an error.
pub fn verify_planet(encoded: &Encoded, planet: &PlanetGrid) -> Result<VerifyReport, CodecError> {
    planet_only(encoded, planet)?;
    let layout = encoded.params.layout();
    let n = layout.n();
    let mut levels = LevelReport::empty(&encoded.params);
    walk_all_with_validity(encoded, |id, p, _| {
        let report = &mut levels[id.level as usize];
        let g = layout.grid(id);
        report.diamonds += 1;
        for j in 0..n {
            for i in 0..n {
                let (x, y) = g.point(i as i64, j as i64);
                let Some(want) = planet.get(id.face, x, y) else {
                    continue;
                };
                let e = (i64::from(p[j * n + i]) - i64::from(want)).unsigned_abs();
                report.max_error = report.max_error.max(u32::try_from(e).unwrap_or(u32::MAX));
                report.vertices += 1;
            }
        }
    })?;
    Ok(VerifyReport {
        levels,
        bound: encoded.params.quantizer.k() as u32,
    })
}

/// Decodes the finest level onto the six faces: one `(S + 1)²` grid per face, every lattice
/// point of the face (edge and corner points on every face holding them, each written by that
/// face's own finest diamonds), validity from the nodata mask (`false` where no stored diamond
/// reaches). Errors on a planar hierarchy.
pub fn reconstruct_planet(encoded: &Encoded) -> Result<Vec<HeightGrid>, CodecError> {
    let domain = encoded.params.domain;
    let Some(cube) = domain.cube() else {
        return Err(CodecError::invalid(
            "this hierarchy is planar: reconstruct it onto one grid",
        ));
    };
    let points = cube.side() as usize + 1;
    let mut faces: Vec<HeightGrid> = (0..domain.faces())
        .map(|_| HeightGrid {
            width: points,
            height: points,
            values: vec![0; points * points].into(),
            valid: vec![false; points * points].into(),
        })
        .collect();
    let layout = domain.layout();
    let n = layout.n();
    let finest = layout.finest_level();
    // Every level, coarse to fine: where coarse data ends the hierarchy above the finest level
    // (a variable-resolution planet), the leaves' points are the lattice's there. With α = 1 a
    // point keeps its value at every finer level, so the finest diamonds write the same values
    // again elsewhere. Even levels' diamonds are squares inside their face; odd levels' points
    // are all points of the next (even) level.
    walk_all_with_validity(encoded, |id, p, v| {
        if id.level % 2 != finest % 2 {
            return;
        }
        let g = layout.grid(id);
        let face = &mut faces[usize::from(id.face)];
        for j in 0..n {
            for i in 0..n {
                let (x, y) = g.point(i as i64, j as i64);
                let k = y as usize * points + x as usize;
                face.values[k] = p[j * n + i];
                face.valid[k] = v.is_none_or(|v| v[j * n + i]);
            }
        }
    })?;
    Ok(faces)
}

/// Decodes the finest level onto the points `like` holds (the same tiles; a resampled planet
/// of any size, where [`reconstruct_planet`] would need every lattice point): every point of
/// a tile written by its face's own diamonds, validity from the nodata mask. Errors on a
/// planar hierarchy or a planet of another lattice.
pub fn reconstruct_planet_like(
    encoded: &Encoded,
    like: &PlanetGrid,
) -> Result<PlanetGrid, CodecError> {
    planet_only(encoded, like)?;
    let layout = encoded.params.domain.layout();
    let n = layout.n();
    let finest = layout.finest_level();
    let mut out = like.blank_like();
    // As in `reconstruct_planet`: coarse to fine, even levels of the finest level's parity.
    walk_all_with_validity(encoded, |id, p, v| {
        if id.level % 2 != finest % 2 {
            return;
        }
        let g = layout.grid(id);
        for j in 0..n {
            for i in 0..n {
                let (x, y) = g.point(i as i64, j as i64);
                let k = j * n + i;
                out.set(id.face, x, y, p[k], v.is_none_or(|v| v[k]));
            }
        }
    })?;
    Ok(out)
}
