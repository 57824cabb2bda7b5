//! How the block-wise planet encode asks for lattice tiles ([`PlanetTiles`]): whole, thinned
//! to a stride, or only a part of a tile (the strips of neighbouring tiles a block reads), and
//! a whole planet's answer ([`PlanetGrid`]).

use std::sync::Arc;

use super::{PlanetGrid, PlanetTile};
use crate::CodecError;
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
