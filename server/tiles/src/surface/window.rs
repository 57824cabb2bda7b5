//! A surface over a part of the repository only, decoded with the codec's windowed decoders: a
//! plane's over a lattice rectangle ([`cbdam_codec::hierarchy::decode_window`]), a planet's
//! over the boxes around some face points ([`cbdam_codec::hierarchy::decode_face_windows`]).
//! They read the records within reach of the window, not the whole repository. Inside the
//! window the samples, and so the heights, are those of [`Surface::decode`] (the windowed
//! decoders visit every diamond the whole walk visits there, in the same order).

use std::collections::HashMap;

use cbdam_codec::CodecError;
use cbdam_codec::geometry::DiamondId;
use cbdam_codec::hierarchy::{Encoded, FaceRect, FaceWindows, decode_face_windows, decode_window};
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

    /// The stored diamonds, in record order.
    pub fn ids(&self) -> &[DiamondId] {
        &self.ids
    }

    /// The record bytes of stored diamond `id` of `encoded` (the hierarchy indexed).
    fn record<'e>(&self, encoded: &'e Encoded, id: DiamondId) -> Result<&'e [u8], CodecError> {
        match self.at.get(&id) {
            Some(&i) => Ok(&encoded.records[i].bytes[..]),
            None => Err(CodecError::invalid(format!("{id} is not stored"))),
        }
    }
}

/// What both windowed decodes start from: the domain, its data's extent (finest units), the
/// finest level, how many even levels there are, and the first one decoded for `coarsen`.
struct WindowLevels {
    domain: cbdam_codec::geometry::Domain,
    extent: (i64, i64, i64, i64),
    finest: u8,
    count: usize,
    first: usize,
}

impl WindowLevels {
    fn of(encoded: &Encoded, coarsen: usize) -> WindowLevels {
        let domain = encoded.params.domain;
        let (w, h) = domain.data().size();
        let finest = domain.finest_level();
        let count = usize::from(finest / 2) + 1;
        WindowLevels {
            domain,
            extent: (0, 0, w as i64 - 1, h as i64 - 1),
            finest,
            count,
            first: coarsen.min(count - 1),
        }
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
        let WindowLevels {
            domain,
            extent,
            finest,
            count,
            first,
        } = WindowLevels::of(encoded, coarsen);
        let record = |id: DiamondId| index.record(encoded, id);
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

impl Surface {
    /// The even levels of step `2^coarsen` and coarser of a planet, on each face over the box
    /// of the face points `points` (lattice units) with one sample of margin on each level, so
    /// that [`Surface::height`] at any of them with at least `coarsen` answers as the whole
    /// surface does. Planes are refused.
    pub fn decode_faces(
        encoded: &Encoded,
        index: &RecordIndex,
        plan: &QuantPlan,
        points: &[(u8, f64, f64)],
        coarsen: usize,
    ) -> Result<Surface, CodecError> {
        let WindowLevels {
            domain,
            extent,
            finest,
            count,
            first,
        } = WindowLevels::of(encoded, coarsen);
        let Some(cube) = domain.cube() else {
            return Err(CodecError::invalid("face windows are read from planets"));
        };
        let side = cube.side();
        let record = |id: DiamondId| index.record(encoded, id);
        let mut boxes: [Option<(f64, f64, f64, f64)>; 6] = [None; 6];
        for &(face, x, y) in points {
            let b = boxes.get_mut(usize::from(face)).ok_or_else(|| {
                CodecError::invalid(format!("face {face} is not one of the planet's"))
            })?;
            *b = Some(b.map_or((x, y, x, y), |(x0, y0, x1, y1)| {
                (x0.min(x), y0.min(y), x1.max(x), y1.max(y))
            }));
        }
        let mut levels = Vec::with_capacity(count);
        for m in 0..count {
            let level = finest - 2 * m as u8;
            let step = 1i64 << m;
            if m < first {
                levels.push(empty(level, step));
                continue;
            }
            let lo = |v: f64| ((v / step as f64).floor() as i64 - 1).max(0) * step;
            let hi = |v: f64| (((v / step as f64).ceil() as i64 + 1) * step).min(side);
            let rects: Vec<FaceRect> = (0u8..6)
                .filter_map(|f| boxes[usize::from(f)].map(|b| (f, b)))
                .map(|(f, (x0, y0, x1, y1))| (f, (lo(x0), lo(y0), hi(x1), hi(y1))))
                .collect();
            let mut raster = LevelRaster::new(&domain, level, &rects)?;
            let windows = FaceWindows { level, rects };
            decode_face_windows(
                encoded.params,
                &encoded.roots,
                &index.ids,
                record,
                &windows,
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
