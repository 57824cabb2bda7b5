//! One even level's decoded samples over rectangles of a domain's faces, and the height at any
//! lattice position among them by bilinear interpolation: what web-map tiles (`cbdam-tiles`,
//! every face whole) and the Python reader's `sample_geo` / `read_geo` (the rectangles around
//! the points asked for) sample a surface with.
//!
//! Fill a raster with [`LevelRaster::put_diamond`] from a walk's visits (the whole walk, or a
//! windowed decode of the same level): on a planet a grid point is written to every face that
//! holds it, so a position on or next to a face edge interpolates on one face alone.

use super::{DiamondId, FaceRect};
use crate::CodecError;
use crate::geometry::Domain;

/// A sample no decoded diamond reaches (outside the data, or a level finer than a
/// variable-resolution repository's data there).
pub const NO_DATA: i32 = i32::MIN;
/// A sample the repository's nodata mask marks: the input had no data there.
pub const MASKED: i32 = i32::MIN + 1;

/// The samples of one level over a rectangle of one face, row after row (row 0 = lattice
/// `y0`), in the repository's integer units ([`NO_DATA`] or [`MASKED`] where none).
#[derive(Clone, Debug, PartialEq)]
pub struct FaceBlock {
    /// The face.
    pub face: u8,
    /// Lattice position of sample (0, 0): the rectangle's corner rounded up to a multiple of
    /// the level's step.
    pub x0: i64,
    /// See `x0`.
    pub y0: i64,
    /// Samples a row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// `height · width` heights, units.
    pub units: Vec<i32>,
}

/// One even level's samples over at most one rectangle of each face.
#[derive(Clone, Debug, PartialEq)]
pub struct LevelRaster {
    /// The level.
    pub level: u8,
    /// Lattice units between neighbouring samples: `2^((finest − level)/2)`.
    pub step: i64,
    /// The faces' blocks, in the order asked.
    pub blocks: Vec<FaceBlock>,
}

/// What a level says at a point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LevelSample {
    /// The interpolated height, units (fractional).
    Value(f64),
    /// The input had no data around the point.
    Masked,
    /// The level has no decoded sample around the point.
    Unreached,
}

impl LevelRaster {
    /// An empty raster ([`NO_DATA`] everywhere) of even `level` over `rects`: `(face, (x0, y0,
    /// x1, y1))`, inclusive lattice units, at most one a face. Refuses an odd level or one past
    /// the finest, and a rectangle holding no sample of the level.
    pub fn new(domain: &Domain, level: u8, rects: &[FaceRect]) -> Result<LevelRaster, CodecError> {
        let finest = domain.finest_level();
        if !level.is_multiple_of(2) || level > finest {
            return Err(CodecError::invalid(format!(
                "level {level}: only even levels 0, 2, …, {finest} are axis-aligned grids"
            )));
        }
        let step = 1i64 << ((finest - level) / 2);
        let first = |lo: i64| (lo + step - 1).div_euclid(step) * step;
        let mut blocks: Vec<FaceBlock> = Vec::with_capacity(rects.len());
        for &(face, (x0, y0, x1, y1)) in rects {
            let (bx, by) = (first(x0), first(y0));
            if bx > x1 || by > y1 || blocks.iter().any(|b| b.face == face) {
                return Err(CodecError::invalid(format!(
                    "level {level}: an empty or repeated window on face {face}"
                )));
            }
            let (width, height) = (
                ((x1 - bx) / step + 1) as usize,
                ((y1 - by) / step + 1) as usize,
            );
            blocks.push(FaceBlock {
                face,
                x0: bx,
                y0: by,
                width,
                height,
                units: vec![NO_DATA; width * height],
            });
        }
        Ok(LevelRaster {
            level,
            step,
            blocks,
        })
    }

    /// The block of `face`, if the raster has one.
    pub fn block(&self, face: u8) -> Option<&FaceBlock> {
        self.blocks.iter().find(|b| b.face == face)
    }

    /// Every sample's units, block after block.
    pub fn units(&self) -> impl Iterator<Item = i32> + '_ {
        self.blocks.iter().flat_map(|b| b.units.iter().copied())
    }

    /// Writes the grid points of diamond `id` of this level (its `grid` of heights and
    /// `valid`ity, as a walk visits it) that fall in the raster.
    pub fn put_diamond(
        &mut self,
        domain: &Domain,
        id: DiamondId,
        grid: &[i32],
        valid: Option<&[bool]>,
    ) {
        if id.level != self.level {
            return;
        }
        let layout = domain.layout();
        let (n, g) = (layout.n(), layout.grid(id));
        for j in 0..n {
            for i in 0..n {
                let value = match valid.is_none_or(|v| v[j * n + i]) {
                    true => grid[j * n + i],
                    false => MASKED,
                };
                self.put(domain, id.face, g.point(i as i64, j as i64), value);
            }
        }
    }

    /// Writes `value` at lattice point `p` of `face` into the raster, on every face holding
    /// it, if it lies in a block and holds data.
    fn put(&mut self, domain: &Domain, face: u8, p: (i64, i64), value: i32) {
        let step = self.step;
        let mut write = |face: u8, x: i64, y: i64| {
            if !domain.holds_data(face, x, y) {
                return;
            }
            let Some(b) = self.blocks.iter_mut().find(|b| b.face == face) else {
                return;
            };
            let (dx, dy) = (x - b.x0, y - b.y0);
            if dx < 0 || dy < 0 {
                return;
            }
            let (c, r) = ((dx / step) as usize, (dy / step) as usize);
            if c < b.width && r < b.height {
                let i = r * b.width + c;
                // A value seen through one diamond is not taken back by another's mask.
                if value != MASKED || b.units[i] == NO_DATA {
                    b.units[i] = value;
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

    /// Bilinear interpolation (units, fractional) at lattice `(x, y)` of `face` between the four
    /// samples of the level around it (clamped into the face's block): the weights of samples
    /// without data are dropped; a point whose weighted samples all lack data is [`LevelSample::
    /// Masked`] if the nodata mask marks one of them, else [`LevelSample::Unreached`] (also on a
    /// face without a block).
    pub fn sample(&self, face: u8, x: f64, y: f64) -> LevelSample {
        let Some(b) = self.block(face) else {
            return LevelSample::Unreached;
        };
        let step = self.step as f64;
        let (wm, hm) = ((b.width - 1) as f64, (b.height - 1) as f64);
        let cx = ((x - b.x0 as f64) / step).clamp(0.0, wm);
        let cy = ((y - b.y0 as f64) / step).clamp(0.0, hm);
        let c = (cx.floor() as usize).min(b.width.saturating_sub(2));
        let r = (cy.floor() as usize).min(b.height.saturating_sub(2));
        let (tx, ty) = (cx - c as f64, cy - r as f64);
        let (c1, r1) = ((c + 1).min(b.width - 1), (r + 1).min(b.height - 1));
        let corners = [
            (c, r, (1.0 - tx) * (1.0 - ty)),
            (c1, r, tx * (1.0 - ty)),
            (c, r1, (1.0 - tx) * ty),
            (c1, r1, tx * ty),
        ];
        let (mut sum, mut weight, mut masked) = (0.0, 0.0, false);
        for (c, r, w) in corners {
            match b.units[r * b.width + c] {
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
            LevelSample::Value(sum / weight)
        } else if masked {
            LevelSample::Masked
        } else {
            LevelSample::Unreached
        }
    }
}
