//! How the block-wise planet encode asks for lattice tiles ([`PlanetTiles`]): whole, thinned
//! to a stride, or only a part of a tile (the strips of neighbouring tiles a block reads), and
//! a whole planet's answer ([`PlanetGrid`]).

use std::collections::HashMap;
use std::sync::Arc;

use super::grid::{tiles_across, tiles_meeting};
use super::outline::PlanetOutline;
use super::{PlanetGrid, PlanetTile};
use crate::CodecError;
use crate::geometry::{DiamondId, Domain};
use crate::hierarchy::resolution::HOLE;
use crate::quant::HeightGrid;

/// Hands out a planet's tiles as the block-wise encode asks for them.
pub trait PlanetTiles: Sync {
    /// Tile `index` of face `face` ([`PlanetGrid::tile_rects`] order) with the points on
    /// multiples of `2^max(s, min(min_stride, tile_log2))` for its own stride `2^s`: the same
    /// values, validity and classes at those points as the tile at its own stride.
    fn tile(&self, face: u8, index: usize, min_stride: u32) -> Result<Arc<PlanetTile>, CodecError>;

    /// Tile `index` of face `face` at its own stride, holding at least the points in `part`
    /// (`(x0, y0, x1, y1)`, inclusive, lattice coordinates of the face) as
    /// [`PlanetTiles::tile`] does; its other points may be holes. A block reads only the
    /// strips of its neighbours' tiles that its diamonds reach.
    fn tile_part(
        &self,
        face: u8,
        index: usize,
        part: (i64, i64, i64, i64),
    ) -> Result<Arc<PlanetTile>, CodecError> {
        let _ = part;
        self.tile(face, index, 0)
    }
}

impl PlanetTiles for PlanetGrid {
    fn tile(&self, face: u8, index: usize, min_stride: u32) -> Result<Arc<PlanetTile>, CodecError> {
        let tiles = self.tiles(face);
        let Some(t) = tiles.get(index) else {
            return Err(CodecError::invalid(format!(
                "face {face} has {} tiles, not {}",
                tiles.len(),
                index + 1
            )));
        };
        thinned(t, min_stride.min(self.tile_log2()))
    }

    /// Its points outside `part` made holes, so that an encode reading outside the strips it
    /// asked for writes other bytes (the block-wise tests check it).
    fn tile_part(
        &self,
        face: u8,
        index: usize,
        part: (i64, i64, i64, i64),
    ) -> Result<Arc<PlanetTile>, CodecError> {
        let t = PlanetTiles::tile(self, face, index, 0)?;
        Ok(Arc::new(only_part(&t, part)?))
    }
}

/// `t` with its points outside `part` (inclusive) made holes.
pub fn only_part(t: &PlanetTile, part: (i64, i64, i64, i64)) -> Result<PlanetTile, CodecError> {
    let (x0, y0, x1, y1) = t.rect;
    let step = 1usize << t.stride;
    let mut values = t.grid.values.to_vec();
    let mut valid = t.grid.valid.to_vec();
    let mut class = t.class.clone();
    let mut k = 0;
    for y in (y0..=y1).step_by(step) {
        for x in (x0..=x1).step_by(step) {
            if !(part.0 <= x && x <= part.2 && part.1 <= y && y <= part.3) {
                values[k] = 0;
                valid[k] = false;
                if let Some(c) = class.as_mut() {
                    c[k] = HOLE;
                }
            }
            k += 1;
        }
    }
    let grid = HeightGrid {
        width: t.grid.width,
        height: t.grid.height,
        values: values.into(),
        valid: valid.into(),
    };
    PlanetTile::new(t.stride, t.rect, grid, class)
}

/// `t` with only its points on multiples of `2^stride` (itself when it holds no finer ones).
pub fn thinned(t: &Arc<PlanetTile>, stride: u32) -> Result<Arc<PlanetTile>, CodecError> {
    if stride <= t.stride {
        return Ok(Arc::clone(t));
    }
    let (x0, y0, x1, y1) = t.rect;
    let step = 1usize << stride;
    let mut values = Vec::new();
    let mut valid = Vec::new();
    let mut class = t.class.as_ref().map(|_| Vec::new());
    for y in (y0..=y1).step_by(step) {
        for x in (x0..=x1).step_by(step) {
            let k = t
                .index(x, y)
                .expect("a point of the tile on a coarser stride");
            values.push(t.grid.values[k]);
            valid.push(t.grid.valid[k]);
            if let (Some(out), Some(c)) = (class.as_mut(), t.class.as_ref()) {
                out.push(c[k]);
            }
        }
    }
    let grid = HeightGrid {
        width: ((x1 - x0) >> stride) as usize + 1,
        height: ((y1 - y0) >> stride) as usize + 1,
        values: values.into(),
        valid: valid.into(),
    };
    Ok(Arc::new(PlanetTile::new(stride, t.rect, grid, class)?))
}

/// A planet of the outline's domain holding `held`'s tiles only.
pub(super) fn held_planet(
    outline: &PlanetOutline,
    held: HashMap<(u8, usize), Arc<PlanetTile>>,
) -> Result<PlanetGrid, CodecError> {
    let d = &outline.domain;
    PlanetGrid::partial(
        d.n(),
        d.layout().k(),
        outline.tile_log2,
        outline.variable,
        held,
    )
}

/// Lattice points `(x0, y0, x1, y1)` of a face, inclusive.
pub(super) type Rect = (i64, i64, i64, i64);

/// The smallest rectangle holding `a` and `b`.
pub(super) fn union(a: Rect, b: Rect) -> Rect {
    (a.0.min(b.0), a.1.min(b.1), a.2.max(b.2), a.3.max(b.3))
}

/// The tiles (face, index) holding a point of `id`'s square or of any face's view of it, each
/// with the rectangle of its points there: its bounds cut at its face's edges, each part
/// carried onto the face it lies on (a part beyond a cube corner is off the surface), every
/// corner of a part on every face holding it.
pub(super) fn tiles_under(
    domain: &Domain,
    tile_log2: u32,
    id: DiamondId,
) -> Vec<(u8, usize, Rect)> {
    let cube = domain.cube().expect("a cube-sphere");
    let side = cube.side();
    let layout = domain.layout();
    let mut rects: HashMap<u8, Rect> = HashMap::new();
    let mut everything = false;
    let parts = |a0: i64, a1: i64| {
        [
            (a0, a1.min(-1), true),
            (a0.max(0), a1.min(side), false),
            (a0.max(side + 1), a1, true),
        ]
        .into_iter()
        .filter(|(a, b, _)| a <= b)
    };
    let (x0, y0, x1, y1) = layout.bounds(id);
    for (xa, xb, x_out) in parts(x0, x1) {
        for (ya, yb, y_out) in parts(y0, y1) {
            if x_out && y_out {
                continue;
            }
            for (x, y) in [(xa, ya), (xb, ya), (xa, yb), (xb, yb)] {
                let Some(p) = cube.locate(id.face, x, y) else {
                    everything = true;
                    continue;
                };
                let (reps, len) = cube.representations(p);
                for r in &reps[..len] {
                    let e = rects.entry(r.face).or_insert((r.x, r.y, r.x, r.y));
                    *e = union(*e, (r.x, r.y, r.x, r.y));
                }
            }
        }
    }
    if everything {
        rects = (0..domain.faces())
            .map(|f| (f, (0, 0, side, side)))
            .collect();
    }
    let across = tiles_across(side, tile_log2);
    let t = 1i64 << tile_log2;
    let mut out = Vec::new();
    for (f, rect) in rects {
        for i in tiles_meeting(side, tile_log2, rect) {
            // The tile's rectangle (as `PlanetGrid::tile_rects` gives it), clipping the part.
            let (bx, by) = ((i % across) as i64, (i / across) as i64);
            let (tx0, ty0) = (bx * t, by * t);
            let (tx1, ty1) = ((tx0 + t).min(side), (ty0 + t).min(side));
            let part = (
                rect.0.max(tx0),
                rect.1.max(ty0),
                rect.2.min(tx1),
                rect.3.min(ty1),
            );
            out.push((f, i, part));
        }
    }
    out
}
