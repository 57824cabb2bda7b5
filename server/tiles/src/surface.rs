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
use cbdam_codec::hierarchy::{Encoded, walk_all_with_validity};
use cbdam_codec::quant::QuantPlan;

/// A sample no decoded diamond reaches (outside the data, or a level finer than a
/// variable-resolution repository's data there).
pub const NO_DATA: i32 = i32::MIN;
/// A sample the repository's nodata mask marks: the input had no data there.
pub const MASKED: i32 = i32::MIN + 1;

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

/// The samples of one even level inside a window, face after face, row after row (row 0 =
/// lattice y0, north on a plane), in the repository's integer units ([`NO_DATA`] or
/// [`MASKED`] where none).
#[derive(Clone, Debug, PartialEq)]
pub struct LevelRaster {
    /// The level.
    pub level: u8,
    /// Lattice units between neighbouring samples: `2^((finest − level)/2)`.
    pub step: i64,
    /// Lattice position of sample (0, 0): the window's corner rounded up to a multiple of step.
    pub x0: i64,
    /// See `x0`.
    pub y0: i64,
    /// Samples a row.
    pub width: usize,
    /// Rows a face.
    pub height: usize,
    /// Faces (1 on a plane, 6 on a planet).
    pub faces: usize,
    /// `faces · height · width` heights, units.
    pub units: Vec<i32>,
}

impl LevelRaster {
    /// The sample at raster column `c`, row `r` of `face`.
    #[inline]
    pub fn at(&self, face: usize, c: usize, r: usize) -> i32 {
        self.units[(face * self.height + r) * self.width + c]
    }
}

/// Why a window cannot be decoded.
fn check_window(domain: &Domain, w: &LevelWindow) -> Result<i64, CodecError> {
    let finest = domain.finest_level();
    if !w.level.is_multiple_of(2) || w.level > finest {
        return Err(CodecError::invalid(format!(
            "level {}: only even levels 0, 2, …, {finest} are axis-aligned grids",
            w.level
        )));
    }
    Ok(1i64 << ((finest - w.level) / 2))
}

/// Decodes the levels `windows` ask for in one walk of the hierarchy.
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
    let mut rasters = Vec::with_capacity(windows.len());
    // Per level, the raster it fills (at most one window per level).
    let mut of_level: Vec<Option<usize>> = vec![None; domain.finest_level() as usize + 1];
    for w in windows {
        let step = check_window(&domain, w)?;
        let first = |lo: i64| (lo + step - 1).div_euclid(step) * step;
        let (x0, y0) = (first(w.x0), first(w.y0));
        if x0 > w.x1 || y0 > w.y1 || of_level[w.level as usize].is_some() {
            return Err(CodecError::invalid(format!(
                "level {}: an empty or repeated window",
                w.level
            )));
        }
        let (width, height) = (
            ((w.x1 - x0) / step + 1) as usize,
            ((w.y1 - y0) / step + 1) as usize,
        );
        let faces = usize::from(domain.faces());
        of_level[w.level as usize] = Some(rasters.len());
        rasters.push(LevelRaster {
            level: w.level,
            step,
            x0,
            y0,
            width,
            height,
            faces,
            units: vec![NO_DATA; faces * width * height],
        });
    }
    let layout = *domain.layout();
    let n = layout.n();
    walk_all_with_validity(encoded, |id, grid, valid| {
        let Some(k) = of_level[id.level as usize] else {
            return;
        };
        let raster = &mut rasters[k];
        let g = layout.grid(id);
        for j in 0..n {
            for i in 0..n {
                let value = match valid.is_none_or(|v| v[j * n + i]) {
                    true => grid[j * n + i],
                    false => MASKED,
                };
                let (x, y) = g.point(i as i64, j as i64);
                put(&domain, raster, id.face, (x, y), value);
            }
        }
    })?;
    Ok(rasters)
}

/// Writes `value` at lattice point `p` of `face` into `raster`, on every face holding it, if
/// it lies in the window and holds data.
fn put(domain: &Domain, raster: &mut LevelRaster, face: u8, p: (i64, i64), value: i32) {
    let mut write = |face: u8, x: i64, y: i64| {
        if !domain.holds_data(face, x, y) {
            return;
        }
        let (dx, dy) = (x - raster.x0, y - raster.y0);
        if dx < 0 || dy < 0 {
            return;
        }
        let (c, r) = ((dx / raster.step) as usize, (dy / raster.step) as usize);
        if c < raster.width && r < raster.height {
            let i = (usize::from(face) * raster.height + r) * raster.width + c;
            // A value seen through one diamond is not taken back by another's mask.
            if value != MASKED || raster.units[i] == NO_DATA {
                raster.units[i] = value;
            }
        }
    };
    match domain.cube() {
        None => write(face, p.0, p.1),
        Some(cube) => {
            let Some(canonical) = domain.canonical_point(face, p.0, p.1) else {
                return;
            };
            let (reps, len) = cube.representations(canonical);
            for q in &reps[..len] {
                write(q.face, q.x, q.y);
            }
        }
    }
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
            .flat_map(|l| l.units.iter().copied())
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
            match bilinear(l, usize::from(face), x, y) {
                Sample::Value(u) => return Some((self.plan.offset + u * self.plan.unit, l.level)),
                Sample::Masked => return None,
                Sample::Unreached => {}
            }
        }
        None
    }
}

/// What a level says at a point.
enum Sample {
    /// The interpolated height, units.
    Value(f64),
    /// The input had no data around the point.
    Masked,
    /// The level has no decoded sample around the point.
    Unreached,
}

/// Bilinear interpolation (units, fractional) in `l` at lattice `(x, y)` of `face`, which
/// lies within the level's window.
fn bilinear(l: &LevelRaster, face: usize, x: f64, y: f64) -> Sample {
    if face >= l.faces || l.width == 0 || l.height == 0 {
        return Sample::Unreached;
    }
    let step = l.step as f64;
    let (wm, hm) = ((l.width - 1) as f64, (l.height - 1) as f64);
    let cx = ((x - l.x0 as f64) / step).clamp(0.0, wm);
    let cy = ((y - l.y0 as f64) / step).clamp(0.0, hm);
    let c = (cx.floor() as usize).min(l.width.saturating_sub(2));
    let r = (cy.floor() as usize).min(l.height.saturating_sub(2));
    let (tx, ty) = (cx - c as f64, cy - r as f64);
    let (c1, r1) = ((c + 1).min(l.width - 1), (r + 1).min(l.height - 1));
    let corners = [
        (c, r, (1.0 - tx) * (1.0 - ty)),
        (c1, r, tx * (1.0 - ty)),
        (c, r1, (1.0 - tx) * ty),
        (c1, r1, tx * ty),
    ];
    let (mut sum, mut weight, mut masked) = (0.0, 0.0, false);
    for (c, r, w) in corners {
        match l.at(face, c, r) {
            NO_DATA => {}
            MASKED => masked = true,
            u if w > 0.0 => {
                sum += w * f64::from(u);
                weight += w;
            }
            _ => {}
        }
    }
    // A point exactly on a sample without data has weight only there: no data.
    if weight > 1e-12 {
        Sample::Value(sum / weight)
    } else if masked {
        Sample::Masked
    } else {
        Sample::Unreached
    }
}
