//! Planets (cube-sphere repositories) in the Python reader: heights at geodetic latitudes and
//! longitudes (`sample_geo`) and on a latitude/longitude grid (`read_geo`). Each point is put
//! on its face by the codec's `geodesy::cube_map` and interpolated bilinearly in that face's
//! lattice by the codec's `LevelRaster::sample` — the same two steps as web-map tiles of a
//! planet (`cbdam-tiles`) — from a windowed decode of the faces' rectangles around the points.

use cbdam_codec::geodesy::LatLon;
use cbdam_codec::geodesy::cube_map::lat_lon_to_face_st;
use cbdam_codec::hierarchy::{FaceRect, FaceWindows, LevelRaster, LevelSample};
use cbdam_codec::repository::RepositoryHead;
use rayon::prelude::*;

use crate::errors::{PyCbdamError, Result};
use crate::source::{Sample, Source};

/// The most samples one `read_geo` returns (4 GiB of float64).
const MAX_GEO_SAMPLES: usize = 1 << 29;

/// A latitude/longitude grid: `width × height` cells of `resolution` degrees from the
/// north-west corner `(west, north)`, each sampled at its centre (row 0 north).
#[derive(Clone, Copy, Debug)]
pub struct GeoGrid {
    /// Longitude of the western edge, degrees.
    pub west: f64,
    /// Latitude of the northern edge, degrees.
    pub north: f64,
    /// Cell size, degrees.
    pub resolution: f64,
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
}

impl GeoGrid {
    /// The cells of `bbox = (west, south, east, north)` at `resolution` degrees, checked: a box
    /// on the globe (south < north within ±90°, west < east at most 360° apart) whose sides
    /// are whole numbers of cells.
    pub fn new(bbox: &[f64], resolution: f64) -> Result<GeoGrid> {
        let bad = |why: String| Err(PyCbdamError::Input(why));
        let &[west, south, east, north] = bbox else {
            return bad(format!(
                "bbox= has {} numbers; give (west, south, east, north) in degrees",
                bbox.len()
            ));
        };
        if !(resolution.is_finite() && resolution > 0.0) {
            return bad(format!(
                "resolution={resolution}: must be a positive number of degrees"
            ));
        }
        if bbox.iter().any(|v| !v.is_finite()) || south >= north || west >= east {
            return bad(format!(
                "bbox=({west}, {south}, {east}, {north}): give (west, south, east, north) with \
                 west < east and south < north, in degrees"
            ));
        }
        if south < -90.0 || north > 90.0 || east - west > 360.0 {
            return bad(format!(
                "bbox=({west}, {south}, {east}, {north}) is not on the globe: latitudes within \
                 ±90°, at most 360° of longitude"
            ));
        }
        let cells = |span: f64, what: &str| -> Result<usize> {
            let n = span / resolution;
            let whole = n.round();
            if whole < 1.0 || (n - whole).abs() > 1e-6 * whole.max(1.0) {
                return Err(PyCbdamError::Input(format!(
                    "bbox= is {span}° {what}, not a whole number of cells of resolution={resolution}°"
                )));
            }
            Ok(whole as usize)
        };
        let (width, height) = (cells(east - west, "wide")?, cells(north - south, "tall")?);
        if width.saturating_mul(height) > MAX_GEO_SAMPLES {
            return bad(format!(
                "bbox= at resolution={resolution}° is {width} × {height} samples, more than \
                 {MAX_GEO_SAMPLES} in one read: read it in parts or coarser"
            ));
        }
        Ok(GeoGrid {
            west,
            north,
            resolution,
            width,
            height,
        })
    }

    /// Every cell centre `(lon, lat)`, row after row from the north.
    pub fn points(&self) -> Vec<(f64, f64)> {
        let r = self.resolution;
        (0..self.height)
            .flat_map(|row| {
                let lat = self.north - (row as f64 + 0.5) * r;
                (0..self.width).map(move |col| (self.west + (col as f64 + 0.5) * r, lat))
            })
            .collect()
    }
}

/// The coarsest even level whose mean sample spacing (a face's 90° over its samples) is at most
/// `resolution` degrees; the finest when none is.
pub fn level_for(head: &RepositoryHead, resolution: f64) -> u8 {
    let layout = head.params().layout();
    let finest = layout.finest_level();
    let side = head.params().domain.cube().map_or(1, |c| c.side()) as f64;
    (0..=finest)
        .step_by(2)
        .find(|&level| {
            let step = (1u64 << ((finest - level) / 2)) as f64;
            90.0 * step / side <= resolution
        })
        .unwrap_or(finest)
}

/// Checks `lats` (each within ±90°, or NaN) and pairs them with `lons`.
pub fn lon_lat_points<'a>(
    lons: impl ExactSizeIterator<Item = &'a f64>,
    lats: impl ExactSizeIterator<Item = &'a f64>,
) -> Result<Vec<(f64, f64)>> {
    if lons.len() != lats.len() {
        return Err(PyCbdamError::Input(format!(
            "lons and lats differ in length ({} and {})",
            lons.len(),
            lats.len()
        )));
    }
    let points: Vec<(f64, f64)> = lons.copied().zip(lats.copied()).collect();
    if let Some(i) = points.iter().position(|p| p.1.abs() > 90.0) {
        return Err(PyCbdamError::Input(format!(
            "lats[{i}] = {} is not a latitude (−90 … 90°)",
            points[i].1
        )));
    }
    Ok(points)
}

/// Heights, metres, at `(lon, lat)` points of a planet, NaN where it has none (or the point is
/// not finite): bilinear in the lattice of `level`, or of the next coarser level where that one
/// has no decoded sample around the point (a variable-resolution planet's coarse parts), as
/// web-map tiles take them. Decodes, per level, the rectangles of the faces around the points.
pub fn heights_at<T: Sample>(
    source: &Source,
    name: &str,
    level: u8,
    points: &[(f64, f64)],
    out: &mut [T],
) -> Result<()> {
    debug_assert_eq!(out.len(), points.len());
    out.fill(T::from_metres(f64::NAN));
    let head = source.head();
    let (domain, plan) = (head.params().domain, *head.plan());
    let Some(cube) = domain.cube() else {
        return Err(PyCbdamError::Unsupported(format!(
            "{name} is planar: read and sample take its CRS coordinates"
        )));
    };
    let side = cube.side() as f64;
    let located: Vec<Option<(u8, f64, f64)>> = points
        .par_iter()
        .map(|&(lon, lat)| {
            (lon.is_finite() && lat.is_finite()).then(|| {
                let (face, s, t) = lat_lon_to_face_st(LatLon { lat, lon });
                (
                    face,
                    (s * side).clamp(0.0, side),
                    (t * side).clamp(0.0, side),
                )
            })
        })
        .collect();
    let mut pending: Vec<usize> = (0..points.len())
        .filter(|&i| located[i].is_some())
        .collect();
    let mut level = level;
    while !pending.is_empty() {
        let raster = decode_around(source, name, level, pending.iter().map(|&i| located[i]))?;
        let samples: Vec<LevelSample> = pending
            .par_iter()
            .map(|&i| {
                let (face, x, y) = located[i].expect("only located points are pending");
                raster.sample(face, x, y)
            })
            .collect();
        let mut unreached = Vec::new();
        for (&i, sample) in pending.iter().zip(samples) {
            match sample {
                LevelSample::Value(u) => out[i] = T::from_metres(plan.offset + u * plan.unit),
                LevelSample::Masked => {}
                LevelSample::Unreached => unreached.push(i),
            }
        }
        if level < 2 {
            break;
        }
        pending = unreached;
        level -= 2;
    }
    Ok(())
}

/// The samples of `level` on each face's rectangle around the located points (the lattice
/// points of the level next to each).
fn decode_around(
    source: &Source,
    name: &str,
    level: u8,
    located: impl Iterator<Item = Option<(u8, f64, f64)>>,
) -> Result<LevelRaster> {
    let head = source.head();
    let domain = head.params().domain;
    let finest = domain.finest_level();
    let step = 1i64 << ((finest - level) / 2);
    let side = domain.cube().map_or(0, |c| c.side());
    let mut rects: [Option<(i64, i64, i64, i64)>; 6] = [None; 6];
    for (face, x, y) in located.flatten() {
        let lo = |v: f64| ((v / step as f64).floor() as i64 * step).clamp(0, side);
        let hi = |v: f64| ((v / step as f64).ceil() as i64 * step).clamp(0, side);
        let r = &mut rects[usize::from(face)];
        *r = Some(match *r {
            None => (lo(x), lo(y), hi(x), hi(y)),
            Some((x0, y0, x1, y1)) => (x0.min(lo(x)), y0.min(lo(y)), x1.max(hi(x)), y1.max(hi(y))),
        });
    }
    let rects: Vec<FaceRect> = (0u8..6)
        .filter_map(|f| rects[usize::from(f)].map(|r| (f, r)))
        .collect();
    let mut raster = LevelRaster::new(&domain, level, &rects)
        .map_err(|e| PyCbdamError::codec(&format!("reading {name}"), &e))?;
    let windows = FaceWindows { level, rects };
    source.decode_faces(&windows, name, |id, grid, valid| {
        raster.put_diamond(&domain, id, grid, valid)
    })?;
    Ok(raster)
}
