//! The samples of one even level inside a window of a planar repository's data, and where they
//! lie: what `cbdam extract` writes and the Python package's `read` returns.

use super::GeoRef;
use crate::hierarchy::CodecParams;

/// The samples to read: the lattice points of one even level inside the window, from
/// `(x0, y0)` to at most `(x1, y1)`, `step` input samples apart (lattice x = column, y = row of
/// the data, row 0 north).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LevelGrid {
    /// The level.
    pub level: u8,
    /// Spacing of its samples, input samples.
    pub step: i64,
    /// The first sample, lattice units.
    pub x0: i64,
    /// The first sample, lattice units.
    pub y0: i64,
    /// The window's last column, lattice units (the last sample is at most this).
    pub x1: i64,
    /// The window's last row, lattice units.
    pub y1: i64,
    /// Samples per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
}

impl LevelGrid {
    /// The samples of `level` (default: the finest) inside the inclusive data window `rect`
    /// (default: the whole data rectangle), checked: only even levels are axis-aligned grids.
    /// `flag` names the level argument in messages (`--level`, `level=`).
    pub fn new(
        params: &CodecParams,
        level: Option<u8>,
        rect: Option<(i64, i64, i64, i64)>,
        flag: &str,
    ) -> Result<LevelGrid, String> {
        let finest = params.layout().finest_level();
        let level = level.unwrap_or(finest);
        if !level.is_multiple_of(2) || level > finest {
            return Err(format!(
                "{flag} {level}: only even levels 0, 2, …, {finest} are axis-aligned grids in \
                 this repository (the finest is {finest})"
            ));
        }
        // Lattice spacing of the level's samples: level 2m samples every 2^(K−m) input samples.
        let step = 1i64 << ((finest - level) / 2);
        let (w, h) = (
            i64::from(params.domain.data().width),
            i64::from(params.domain.data().height),
        );
        let window = rect.unwrap_or((0, 0, w - 1, h - 1));
        // The level's lattice points inside the window: multiples of `step`.
        let first = |lo: i64| (lo + step - 1).div_euclid(step) * step;
        let (x0, y0) = (first(window.0), first(window.1));
        if x0 > window.2 || y0 > window.3 {
            return Err(format!(
                "the bounding box holds no sample of level {level} (spacing {step} input samples)"
            ));
        }
        Ok(LevelGrid {
            level,
            step,
            x0,
            y0,
            x1: window.2,
            y1: window.3,
            width: ((window.2 - x0) / step + 1) as usize,
            height: ((window.3 - y0) / step + 1) as usize,
        })
    }

    /// Where the samples lie: the repository's `g` for raster point (0, 0) at lattice point
    /// `(x0, y0)` and a spacing of `step` samples.
    pub fn georef(&self, g: &GeoRef) -> GeoRef {
        // A PixelIsArea origin is the outer corner of a cell `step` samples wide centred on the
        // first sample.
        let half = if g.pixel_is_area { 0.5 } else { 0.0 };
        let (sx, sy) = (self.step as f64, self.step as f64);
        GeoRef {
            origin_x: g.origin_x + (self.x0 as f64 + half - half * sx) * g.pixel_x,
            origin_y: g.origin_y - (self.y0 as f64 + half - half * sy) * g.pixel_y,
            pixel_x: g.pixel_x * sx,
            pixel_y: g.pixel_y * sy,
            ..g.clone()
        }
    }

    /// The output index of lattice point `(x, y)`, when it is one of the samples.
    pub fn index_of(&self, x: i64, y: i64) -> Option<usize> {
        if x < self.x0 || y < self.y0 || x > self.x1 || y > self.y1 {
            return None;
        }
        let (dx, dy) = (x - self.x0, y - self.y0);
        if dx % self.step != 0 || dy % self.step != 0 {
            return None;
        }
        Some((dy / self.step) as usize * self.width + (dx / self.step) as usize)
    }
}

/// The inclusive lattice window `(x0, y0, x1, y1)` of the data samples inside `b` =
/// `[minx, miny, maxx, maxy]`, clipped to the `w × h` data. With georeferencing `b` is in CRS
/// units and a sample is inside when its centre is; without, it is in column / row indices
/// (row 0 = north). `flag` names the argument in messages (`--bbox`, `bbox=`).
pub fn bbox_window(
    b: &[f64],
    georef: Option<&GeoRef>,
    w: i64,
    h: i64,
    flag: &str,
) -> Result<(i64, i64, i64, i64), String> {
    let [minx, miny, maxx, maxy] = b else {
        return Err(format!(
            "{flag} takes four numbers MINX,MINY,MAXX,MAXY, not {}",
            b.len()
        ));
    };
    if !b.iter().all(|v| v.is_finite()) {
        return Err(format!("{flag} holds a non-finite number"));
    }
    if minx > maxx || miny > maxy {
        return Err(format!(
            "{flag} is inverted: MINX must not exceed MAXX, nor MINY MAXY"
        ));
    }
    // Sample (c, r) has its centre at (ox + (c + half)·px, oy − (r + half)·py); solve for c and r.
    let (ox, oy, px, py, half) = match georef {
        Some(g) => (
            g.origin_x,
            g.origin_y,
            g.pixel_x,
            g.pixel_y,
            if g.pixel_is_area { 0.5 } else { 0.0 },
        ),
        // Pixel coordinates: x = column, y = row.
        None => (0.0, 0.0, 1.0, -1.0, 0.0),
    };
    let range = |a: f64, b: f64| {
        let (lo, hi) = (a.min(b), a.max(b));
        (lo.ceil(), hi.floor())
    };
    let (c0, c1) = range((minx - ox) / px - half, (maxx - ox) / px - half);
    let (r0, r1) = range((oy - maxy) / py - half, (oy - miny) / py - half);
    let (c0, r0) = (c0.max(0.0), r0.max(0.0));
    let (c1, r1) = (c1.min((w - 1) as f64), r1.min((h - 1) as f64));
    if c0 > c1 || r0 > r1 {
        return Err(format!(
            "{flag} {minx},{miny},{maxx},{maxy} holds no sample of the data ({})",
            data_span(georef, w, h, half)
        ));
    }
    Ok((c0 as i64, r0 as i64, c1 as i64, r1 as i64))
}

/// Where the data's sample centres lie, for messages.
fn data_span(georef: Option<&GeoRef>, w: i64, h: i64, half: f64) -> String {
    match georef {
        Some(g) => {
            let xs = [
                g.origin_x + half * g.pixel_x,
                g.origin_x + ((w - 1) as f64 + half) * g.pixel_x,
            ];
            let ys = [
                g.origin_y - half * g.pixel_y,
                g.origin_y - ((h - 1) as f64 + half) * g.pixel_y,
            ];
            format!(
                "sample centres span x {} … {}, y {} … {}",
                xs[0].min(xs[1]),
                xs[0].max(xs[1]),
                ys[0].min(ys[1]),
                ys[0].max(ys[1])
            )
        }
        None => format!(
            "no georeferencing: columns 0 … {}, rows 0 … {}",
            w - 1,
            h - 1
        ),
    }
}
