//! The mosaic assembled from its inputs' headers: every input opened, checked against the
//! others (one CRS, power-of-two spacings, samples on the lattice) and placed, nothing decoded.

use super::{
    BLOCK_POINTS, BUCKET_ROWS, Mosaic, NO_WINNER, ORIGIN_TOLERANCE, Placement, RATIO_TOLERANCE,
    bytes_in_memory, lattice_storage,
};
use crate::band_cache::BandCache;
use crate::error::{Context, Result, bail};
use crate::input::{ReadOptions, TileReader};
use crate::tiles::{Tile, VrtPlacement};
use cbdam_codec::repository::GeoRef;
use cbdam_codec::samples::SampleType;
use std::path::{Path, PathBuf};

/// Sample-centre position of raster point (0, 0), so that PixelIsArea and PixelIsPoint inputs
/// mix.
fn centre(g: &GeoRef) -> (f64, f64) {
    let half = if g.pixel_is_area { 0.5 } else { 0.0 };
    (g.origin_x + half * g.pixel_x, g.origin_y - half * g.pixel_y)
}

fn describe(p: &Path, g: &GeoRef) -> String {
    let (cx, cy) = centre(g);
    format!(
        "{} (spacing {} × {}, first sample centre at ({cx}, {cy}))",
        p.display(),
        g.pixel_x,
        g.pixel_y
    )
}

/// Reads `paths` and places them on one lattice; refuses (before allocating it) a lattice whose
/// build would need more than `memory_limit` bytes.
pub fn mosaic(paths: &[PathBuf], opts: &ReadOptions, memory_limit: u64) -> Result<Mosaic> {
    let tiles: Vec<Tile> = paths.iter().map(Tile::file).collect();
    mosaic_tiles(&tiles, opts, memory_limit)
}

/// Checks a tile read through a VRT against where the VRT places it (its size `width × height`
/// and its own georeferencing `georef`), and gives it the VRT's georeferencing where it has
/// none of its own.
pub(crate) fn place_vrt_tile(
    path: &Path,
    (width, height): (usize, usize),
    georef: &mut Option<GeoRef>,
    v: &VrtPlacement,
) -> Result<()> {
    if (width, height) != (v.width, v.height) {
        bail!(
            "{}: <SrcRect>/<DstRect> of {} are {}×{} but the tile is {}×{}: only whole tiles \
             placed without scaling are supported",
            v.vrt.display(),
            path.display(),
            v.width,
            v.height,
            width,
            height
        );
    }
    let Some(g) = georef.as_ref() else {
        *georef = Some(v.georef.clone());
        return Ok(());
    };
    let want = &v.georef;
    let close = |a: f64, b: f64| (a - b).abs() <= RATIO_TOLERANCE * b.abs();
    let (cx, cy) = centre(g);
    let (wx, wy) = centre(want);
    let (ox, oy) = ((cx - wx) / want.pixel_x, (cy - wy) / want.pixel_y);
    if !close(g.pixel_x, want.pixel_x)
        || !close(g.pixel_y, want.pixel_y)
        || ox.abs() > ORIGIN_TOLERANCE
        || oy.abs() > ORIGIN_TOLERANCE
    {
        bail!(
            "{} places {} with spacing {} × {} and its first sample centre at ({wx}, {wy}), but \
             the tile's own georeferencing says {} × {} and ({cx}, {cy}) ({ox:.4} × {oy:.4} \
             samples off): fix the VRT or the tile",
            v.vrt.display(),
            path.display(),
            want.pixel_x,
            want.pixel_y,
            g.pixel_x,
            g.pixel_y
        );
    }
    if let (Some(a), Some(b)) = (g.epsg, want.epsg)
        && a != b
    {
        bail!(
            "{}: its SRS is EPSG:{b} but {} is in EPSG:{a}",
            v.vrt.display(),
            path.display()
        );
    }
    Ok(())
}

/// [`mosaic`] of tiles ([`crate::tiles`]): plain files, or tiles a VRT places (checked against
/// their own georeferencing, which they keep; a tile without one takes the VRT's). Only the
/// tiles' headers are read here: every check of where the tiles lie is made before any sample
/// is decoded; the checks that need the samples (each tile has a valid one; inputs of the same
/// spacing that overlap hold the same valid samples there) are made by [`Mosaic::survey`].
/// Decoded rows are kept in a cache of at most half of what `memory_limit` leaves beside the
/// lattice ([`bytes_in_memory`]).
pub fn mosaic_tiles(tiles: &[Tile], opts: &ReadOptions, memory_limit: u64) -> Result<Mosaic> {
    if tiles.is_empty() {
        bail!("no input given");
    }
    if tiles.len() > NO_WINNER as usize {
        bail!(
            "{} inputs: at most {NO_WINNER} can be combined",
            tiles.len()
        );
    }
    let dems = open_tiles(tiles, opts)?;
    check_one_crs(&dems)?;
    // The finest input sets the lattice; ties go to the first listed.
    let fine = (0..dems.len())
        .min_by(|&a, &b| dems[a].2.pixel_x.total_cmp(&dems[b].2.pixel_x))
        .expect("at least one input");
    let fine_georef = dems[fine].2.clone();
    let (fx, fy) = (fine_georef.pixel_x, fine_georef.pixel_y);
    let (fcx, fcy) = centre(&fine_georef);
    let placed = place_on_finest(&dems, fine)?;
    let coarsest = (0..placed.len())
        .max_by_key(|&k| placed[k].2)
        .expect("at least one input");
    check_strides(&dems, &placed, coarsest)?;
    let (origin_x, origin_y) = lattice_origin(&placed, coarsest);
    let mut width = 0usize;
    let mut height = 0usize;
    let mut inputs = Vec::new();
    for ((path, reader, _), &(ox, oy, log2)) in dems.into_iter().zip(&placed) {
        let p = Placement {
            path,
            x0: (ox - origin_x) as usize,
            y0: (oy - origin_y) as usize,
            log2,
            width: reader.width(),
            height: reader.height(),
            sample_type: reader.sample_type(),
            nodata: reader.nodata(),
            band_rows: reader.band_rows(),
            reader,
        };
        width = width.max(p.last_col() + 1);
        height = height.max(p.last_row() + 1);
        inputs.push(p);
    }
    // The lattice's own arrays stay in memory when they fit half the limit, else they are
    // mapped; the inputs are read a band of rows at a time.
    let lattice = lattice_storage(width, height, memory_limit);
    let need = bytes_in_memory(width, height, &lattice);
    let mut buckets = vec![Vec::new(); height.div_ceil(BUCKET_ROWS)];
    for (k, p) in inputs.iter().enumerate() {
        for bucket in &mut buckets[p.y0 / BUCKET_ROWS..=p.last_row() / BUCKET_ROWS] {
            bucket.push(k as u32);
        }
    }
    let sample_type = common_sample_type(&inputs);
    let fine_geo = fine_georef;
    let half = if fine_geo.pixel_is_area { 0.5 } else { 0.0 };
    let georef = GeoRef {
        origin_x: fcx + (origin_x as f64 - half) * fx,
        origin_y: fcy - (origin_y as f64 - half) * fy,
        ..fine_geo
    };
    Ok(Mosaic {
        width,
        height,
        georef,
        sample_type,
        inputs,
        buckets,
        cache: BandCache::new(memory_limit.saturating_sub(need) / 2),
        block_points: BLOCK_POINTS,
        lattice,
    })
}

/// The type every input's samples fit exactly: theirs when they agree, else `i32` for integers
/// and `f64` for anything else.
fn common_sample_type(inputs: &[Placement]) -> SampleType {
    let types: Vec<SampleType> = inputs.iter().map(|p| p.sample_type).collect();
    if types.iter().all(|&t| t == types[0]) {
        types[0]
    } else if types.iter().all(|t| t.is_integer()) {
        SampleType::I32
    } else {
        SampleType::F64
    }
}

/// An input tile opened: its path, its reader, and where it lies.
type OpenTile = (PathBuf, TileReader, GeoRef);

/// Opens every tile, each with its georeferencing (a VRT's placement over the file's own), and
/// refuses one without georeferencing, with a spacing that is not positive or without samples.
fn open_tiles(tiles: &[Tile], opts: &ReadOptions) -> Result<Vec<OpenTile>> {
    let mut dems: Vec<OpenTile> = Vec::with_capacity(tiles.len());
    for tile in tiles {
        let path = &tile.path;
        let tile_opts = ReadOptions {
            nodata: opts.nodata.or(tile.vrt.as_ref().and_then(|v| v.nodata)),
            ..opts.clone()
        };
        let reader = TileReader::open(path, &tile_opts)
            .with_context(|| format!("reading {}", path.display()))?;
        let mut georef = reader.georef().cloned();
        if let Some(v) = &tile.vrt {
            place_vrt_tile(path, (reader.width(), reader.height()), &mut georef, v)?;
        }
        let Some(g) = georef else {
            bail!(
                "{} has no georeferencing (GeoTIFF tie point and pixel scale, or an .hgt/.asc \
                 position): several inputs are combined by where they lie, so each needs one",
                path.display()
            );
        };
        if !(g.pixel_x > 0.0 && g.pixel_y > 0.0) {
            bail!(
                "{}: sample spacing {} × {} is not positive (only north-up grids are combined)",
                path.display(),
                g.pixel_x,
                g.pixel_y
            );
        }
        if reader.width() == 0 || reader.height() == 0 {
            bail!("{} has no valid sample (all nodata or NaN)", path.display());
        }
        dems.push((path.clone(), reader, g));
    }
    Ok(dems)
}

/// One coordinate reference system: heights and positions of different CRSs cannot share a
/// lattice without reprojection, which this builder does not do.
fn check_one_crs(dems: &[OpenTile]) -> Result<()> {
    let geo = |k: usize| &dems[k].2;
    for k in 1..dems.len() {
        if geo(k).epsg != geo(0).epsg {
            let name =
                |e: Option<u32>| e.map_or("no EPSG code".to_string(), |e| format!("EPSG:{e}"));
            bail!(
                "{} is in {} but {} is in {}: inputs must share one coordinate reference system \
                 (reproject them first)",
                dems[k].0.display(),
                name(geo(k).epsg),
                dems[0].0.display(),
                name(geo(0).epsg)
            );
        }
        // Without an EPSG code the CRS is whatever the `.prj` files define: different texts
        // may name the same CRS, but the builder cannot tell, so it asks rather than guesses.
        if geo(k).epsg.is_none()
            && let (Some(a), Some(b)) = (&geo(k).wkt, &geo(0).wkt)
            && a != b
        {
            bail!(
                "{} and {} have different CRS definitions (.prj) and no EPSG code: inputs must \
                 share one coordinate reference system (reproject them, or give them the same \
                 .prj)",
                dems[k].0.display(),
                dems[0].0.display()
            );
        }
    }
    Ok(())
}

/// Each input's offset from the finest input (`fine`), in fine samples, and its stride as a
/// power of two: refused unless its spacing is 2^j times the finest and its samples fall on
/// the finest input's sample positions.
fn place_on_finest(dems: &[OpenTile], fine: usize) -> Result<Vec<(i64, i64, u8)>> {
    let geo = |k: usize| &dems[k].2;
    let (fx, fy) = (geo(fine).pixel_x, geo(fine).pixel_y);
    let (fcx, fcy) = centre(geo(fine));
    let mut placed = Vec::new();
    for (k, (path, _, _)) in dems.iter().enumerate() {
        let g = geo(k);
        let (rx, ry) = (g.pixel_x / fx, g.pixel_y / fy);
        let log2 = rx.log2().round();
        let power = (0.0..31.0).contains(&log2) && {
            let p = log2.exp2();
            (rx - p).abs() <= RATIO_TOLERANCE * p && (ry - p).abs() <= RATIO_TOLERANCE * p
        };
        if !power {
            bail!(
                "{} is {rx:.6} × {ry:.6} times as coarse as {}: combined inputs must be \
                 2^j times the finest spacing (1, 2, 4, …) on both axes, so that every coarse \
                 sample is a vertex of the diamond lattice (e.g. SRTM 1″ with 3″ is a ratio of \
                 3, which would need resampling; resample the coarse input to a power-of-two \
                 ratio first)",
                describe(path, g),
                describe(&dems[fine].0, geo(fine))
            );
        }
        let (cx, cy) = centre(g);
        let (ox, oy) = ((cx - fcx) / fx, (fcy - cy) / fy);
        if (ox - ox.round()).abs() > ORIGIN_TOLERANCE || (oy - oy.round()).abs() > ORIGIN_TOLERANCE
        {
            bail!(
                "{} lies {ox:.4} × {oy:.4} samples from {}: its samples must fall on the \
                 finest input's sample positions (a whole number of fine samples apart)",
                describe(path, g),
                describe(&dems[fine].0, geo(fine))
            );
        }
        placed.push((ox.round() as i64, oy.round() as i64, log2 as u8));
    }
    Ok(placed)
}

/// The lattice origin must sit on every input's stride: congruent to the coarsest input's
/// offset modulo its stride, which every other input must agree with modulo its own.
fn check_strides(dems: &[OpenTile], placed: &[(i64, i64, u8)], coarsest: usize) -> Result<()> {
    let geo = |k: usize| &dems[k].2;
    for (k, &(ox, oy, l)) in placed.iter().enumerate() {
        let s = 1i64 << l;
        let (dx, dy) = (
            (ox - placed[coarsest].0).rem_euclid(s),
            (oy - placed[coarsest].1).rem_euclid(s),
        );
        if dx != 0 || dy != 0 {
            bail!(
                "{} and {} are misaligned: with a stride of {s} fine samples, {} must start a \
                 multiple of {s} fine samples from {}, but is {} × {} off (mod {s}); shift or \
                 crop one of them",
                describe(&dems[k].0, geo(k)),
                describe(&dems[coarsest].0, geo(coarsest)),
                dems[k].0.display(),
                dems[coarsest].0.display(),
                dx,
                dy
            );
        }
    }
    Ok(())
}

/// The lattice's origin, in fine samples from the finest input: the lowest point on the
/// coarsest input's stride at or before every input's first sample.
fn lattice_origin(placed: &[(i64, i64, u8)], coarsest: usize) -> (i64, i64) {
    let big = 1i64 << placed[coarsest].2;
    let lowest = |axis: fn(&(i64, i64, u8)) -> i64| {
        let min = placed.iter().map(axis).min().expect("inputs");
        let c = axis(&placed[coarsest]);
        c - (c - min).div_euclid(big) * big
            - if (c - min).rem_euclid(big) == 0 {
                0
            } else {
                big
            }
    };
    (lowest(|p| p.0), lowest(|p| p.1))
}
