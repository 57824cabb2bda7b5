//! A plane's surface over a lattice rectangle only, decoded with the codec's windowed decoder
//! ([`cbdam_codec::hierarchy::decode_window`]): the records within reach of the rectangle,
//! not the whole repository. Inside the rectangle its samples, and so its heights, are those of
//! [`Surface::decode`] (the windowed decoder visits every diamond the whole walk visits there,
//! in the same order).

use std::collections::HashMap;

use cbdam_codec::CodecError;
use cbdam_codec::geometry::DiamondId;
use cbdam_codec::hierarchy::{Encoded, decode_window};
use cbdam_codec::quant::QuantPlan;

use super::{LevelRaster, Surface};

/// Where each stored diamond's record lies in an [`Encoded`] hierarchy, and the stored ids.
#[derive(Clone, Debug, Default)]
pub struct RecordIndex {
    ids: Vec<DiamondId>,
    at: HashMap<DiamondId, usize>,
}

impl RecordIndex {
    /// Indexes the records of `encoded`.
    pub fn of(encoded: &Encoded) -> RecordIndex {
        let ids: Vec<DiamondId> = encoded.records.iter().map(|r| r.id).collect();
        let at = ids.iter().enumerate().map(|(i, &id)| (id, i)).collect();
        RecordIndex { ids, at }
    }
}

impl Surface {
    /// The even levels of step `2^coarsen` and coarser of a plane, over the lattice rectangle
    /// `rect` (`x0, y0, x1, y1`, inclusive, finest units, clipped to the data) with one sample
    /// of margin on each level, so that [`Surface::height`] anywhere in `rect` with at least
    /// `coarsen` answers as the whole surface does. Planets are refused (the windowed decoder
    /// reads planes).
    pub fn decode_window(
        encoded: &Encoded,
        index: &RecordIndex,
        plan: &QuantPlan,
        rect: (i64, i64, i64, i64),
        coarsen: usize,
    ) -> Result<Surface, CodecError> {
        let domain = encoded.params.domain;
        let (w, h) = domain.data().size();
        let extent = (0, 0, w as i64 - 1, h as i64 - 1);
        let finest = domain.finest_level();
        let count = usize::from(finest / 2) + 1;
        let first = coarsen.min(count - 1);
        let record = |id: DiamondId| match index.at.get(&id) {
            Some(&i) => Ok(&encoded.records[i].bytes[..]),
            None => Err(CodecError::invalid(format!("{id} is not stored"))),
        };
        let mut levels = Vec::with_capacity(count);
        for m in 0..count {
            let level = finest - 2 * m as u8;
            if m < first {
                levels.push(empty(level, 1i64 << m));
                continue;
            }
            let mut raster = window_raster(&domain, level, rect, extent)?;
            let block = &raster.blocks[0];
            let window = cbdam_codec::hierarchy::LevelWindow {
                level,
                rect: (
                    block.x0,
                    block.y0,
                    block.x0 + (block.width as i64 - 1) * raster.step,
                    block.y0 + (block.height as i64 - 1) * raster.step,
                ),
            };
            decode_window(
                encoded.params,
                &encoded.roots,
                &index.ids,
                record,
                window,
                |id, grid, valid| raster.put_diamond(&domain, id, grid, valid),
            )?;
            levels.push(raster);
        }
        Ok(Surface::of_levels(levels, first, extent, plan))
    }
}

/// A level not decoded.
fn empty(level: u8, step: i64) -> LevelRaster {
    LevelRaster {
        level,
        step,
        blocks: Vec::new(),
    }
}

/// The raster of `level` over `rect` with one sample of margin, clipped to `extent`, its
/// corner on a multiple of the level's step (as [`super::decode_levels`] lays it out).
fn window_raster(
    domain: &cbdam_codec::geometry::Domain,
    level: u8,
    rect: (i64, i64, i64, i64),
    extent: (i64, i64, i64, i64),
) -> Result<LevelRaster, CodecError> {
    let finest = domain.finest_level();
    if !level.is_multiple_of(2) || level > finest {
        return Err(CodecError::invalid(format!(
            "level {level}: only even levels 0, 2, …, {finest} are axis-aligned grids"
        )));
    }
    let step = 1i64 << ((finest - level) / 2);
    let lo = |v: i64, min: i64| (v - step).max(min).div_euclid(step) * step;
    let hi = |v: i64, max: i64| (v + step).min(max);
    let (x0, y0) = (lo(rect.0, extent.0), lo(rect.1, extent.1));
    let (x1, y1) = (hi(rect.2, extent.2), hi(rect.3, extent.3));
    if x0 > x1 || y0 > y1 {
        return Err(CodecError::invalid(format!(
            "an empty window {rect:?} of the data {extent:?}"
        )));
    }
    LevelRaster::new(domain, level, &[(0, (x0, y0, x1, y1))])
}
