//! A repository's surface in memory: the decoded samples of its even levels (the axis-aligned
//! grids), face by face, and the height at any lattice position by bilinear interpolation.
//!
//! There is one reconstruction path: [`decode_levels`] walks the hierarchy with
//! [`walk_all_with_validity`] and copies each wanted level's grid points into a raster; `cbdam
//! extract` decodes its window through it too. A plane's surface over a part of it is decoded
//! with the codec's windowed decoder instead ([`Surface::decode_window`], in `window.rs`), to
//! the same samples there.

mod window;

pub use window::RecordIndex;

use cbdam_codec::CodecError;
use cbdam_codec::geometry::Domain;
use cbdam_codec::hierarchy::{Encoded, FaceRect, LevelSample, walk_all_with_validity};
pub use cbdam_codec::hierarchy::{LevelRaster, MASKED, NO_DATA};
use cbdam_codec::quant::QuantPlan;

/// What to decode of one level: the lattice window `x0..=x1, y0..=y1` of every face.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LevelWindow {
    /// An even level.
    pub level: u8,
    /// Inclusive lattice window (finest-level units), on each face.
    pub x0: i64,
    /// See `x0`.
    pub y0: i64,
    /// See `x0`.
    pub x1: i64,
    /// See `x0`.
    pub y1: i64,
}

/// Decodes the levels `windows` ask for in one walk of the hierarchy: for each, a
/// [`LevelRaster`] with the window on every face (at most one window a level).
///
/// A point is [`MASKED`] when the repository's nodata mask marks it, [`NO_DATA`] when no
/// decoded diamond covers it (no valid input sample nearby; in a variable-resolution repository, a
/// level finer than the data there). On a planet, a point on a face edge is written to every
/// face holding it.
pub fn decode_levels(
    encoded: &Encoded,
    windows: &[LevelWindow],
) -> Result<Vec<LevelRaster>, CodecError> {
    let domain = encoded.params.domain;
    let mut rasters: Vec<LevelRaster> = Vec::with_capacity(windows.len());
    // Per level, the raster it fills (at most one window per level).
    let mut of_level: Vec<Option<usize>> = vec![None; domain.finest_level() as usize + 1];
    for w in windows {
        let rects: Vec<FaceRect> = (0..domain.faces())
            .map(|f| (f, (w.x0, w.y0, w.x1, w.y1)))
            .collect();
        let raster = LevelRaster::new(&domain, w.level, &rects)?;
        if of_level[w.level as usize].is_some() {
            return Err(CodecError::invalid(format!(
                "level {}: an empty or repeated window",
                w.level
            )));
        }
        of_level[w.level as usize] = Some(rasters.len());
        rasters.push(raster);
    }
    walk_all_with_validity(encoded, |id, grid, valid| {
        if let Some(k) = of_level[id.level as usize] {
            rasters[k].put_diamond(&domain, id, grid, valid);
        }
    })?;
    Ok(rasters)
}

/// Every even level of a repository, whole, and the heights between their samples.
#[derive(Clone, Debug)]
pub struct Surface {
    /// Level rasters, finest first (index `i` has step `2^i`); those finer than `first` are
    /// empty (not decoded).
    levels: Vec<LevelRaster>,
    /// Index of the finest level decoded.
    first: usize,
    /// The data's lattice rectangle `(x0, y0, x1, y1)`, inclusive, finest units.
    extent: (i64, i64, i64, i64),
    plan: QuantPlan,
    /// Smallest and largest height of any decoded sample, metres (`None`: no data at all).
    range: Option<(f64, f64)>,
}

impl Surface {
    /// The lattice points a surface of `domain` holds, all levels together (what decoding it
    /// costs in memory, 4 bytes each).
    pub fn samples(domain: &Domain) -> u64 {
        let (w, h) = domain.data().size();
        let faces = u64::from(domain.faces());
        (0..=domain.finest_level() / 2)
            .map(|m| {
                let step = 1u64 << m;
                faces * (w as u64).div_ceil(step) * (h as u64).div_ceil(step)
            })
            .sum()
    }

    /// Decodes every even level of `encoded` (its heights are `plan`'s units).
    pub fn decode(encoded: &Encoded, plan: &QuantPlan) -> Result<Surface, CodecError> {
        let domain = encoded.params.domain;
        let (w, h) = domain.data().size();
        let finest = domain.finest_level();
        let windows: Vec<LevelWindow> = (0..=finest / 2)
            .map(|m| LevelWindow {
                level: finest - 2 * m,
                x0: 0,
                y0: 0,
                x1: w as i64 - 1,
                y1: h as i64 - 1,
            })
            .collect();
        let levels = decode_levels(encoded, &windows)?;
        Ok(Surface::of_levels(
            levels,
            0,
            (0, 0, w as i64 - 1, h as i64 - 1),
            plan,
        ))
    }

    fn of_levels(
        levels: Vec<LevelRaster>,
        first: usize,
        extent: (i64, i64, i64, i64),
        plan: &QuantPlan,
    ) -> Surface {
        let units = levels
            .iter()
            .flat_map(|l| l.units())
            .filter(|&u| u != NO_DATA && u != MASKED);
        let (lo, hi) = units.fold((i32::MAX, i32::MIN), |(lo, hi), u| (lo.min(u), hi.max(u)));
        let range = (lo <= hi).then(|| (plan.metres(lo), plan.metres(hi)));
        Surface {
            levels,
            first,
            extent,
            plan: *plan,
            range,
        }
    }

    /// The levels, finest first: level `i` samples every `2^i` lattice units (empty where a
    /// window's surface did not decode it).
    pub fn levels(&self) -> &[LevelRaster] {
        &self.levels
    }

    /// The data's lattice rectangle `(x0, y0, x1, y1)` (finest units, inclusive) on every face:
    /// the surface answers up to half a sample beyond it.
    pub fn extent(&self) -> (i64, i64, i64, i64) {
        self.extent
    }

    /// Bytes of decoded samples held (4 a sample).
    pub fn bytes(&self) -> usize {
        let blocks = self.levels.iter().flat_map(|l| &l.blocks);
        blocks.map(|b| b.units.len() * size_of::<i32>()).sum()
    }

    /// Smallest and largest decoded height, metres (of the window only, for a window's
    /// surface); `None` when nothing holds data.
    pub fn range(&self) -> Option<(f64, f64)> {
        self.range
    }

    /// The height, metres, at lattice position `(x, y)` of `face` (finest-level units), from
    /// the level of step `2^coarsen` (clamped to the coarsest): the bilinear interpolation of
    /// the four samples around it, the weights of samples without data dropped; and the level
    /// used. Where none of the four was reached, the next coarser level is asked (a
    /// variable-resolution repository's coarse parts). `None` outside the data (more than half
    /// a finest sample beyond its edge samples), where the nodata mask marks all four, or
    /// where no level has data. A window's surface answers inside its window, from its first
    /// level on (a finer `coarsen` is taken as that level).
    pub fn height(&self, face: u8, x: f64, y: f64, coarsen: usize) -> Option<(f64, u8)> {
        let (x0, y0, x1, y1) = self.extent;
        let (x0, y0, x1, y1) = (x0 as f64, y0 as f64, x1 as f64, y1 as f64);
        if !(x0 - 0.5..=x1 + 0.5).contains(&x) || !(y0 - 0.5..=y1 + 0.5).contains(&y) {
            return None;
        }
        let (x, y) = (x.clamp(x0, x1), y.clamp(y0, y1));
        debug_assert!(coarsen >= self.first || self.first >= self.levels.len() - 1);
        let from = coarsen.max(self.first).min(self.levels.len() - 1);
        for l in &self.levels[from..] {
            match l.sample(face, x, y) {
                LevelSample::Value(u) => {
                    return Some((self.plan.offset + u * self.plan.unit, l.level));
                }
                LevelSample::Masked => return None,
                LevelSample::Unreached => {}
            }
        }
        None
    }
}
