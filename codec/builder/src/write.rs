//! DEM writers of `cbdam extract`: a single-band GeoTIFF with georeferencing and nodata, or
//! headerless little-endian floats.

use std::io::{BufWriter, Seek, Write};

use crate::input::geokeys::{
    KEY_GEOGRAPHIC_TYPE, KEY_MODEL_TYPE, KEY_PROJECTED_CS_TYPE, KEY_RASTER_TYPE, MODEL_GEOGRAPHIC,
    MODEL_PROJECTED, RASTER_PIXEL_IS_AREA, RASTER_PIXEL_IS_POINT,
};
use cbdam_codec::repository::GeoRef;
use rayon::prelude::*;
use tiff::encoder::{TiffEncoder, colortype};
use tiff::tags::Tag;

use crate::error::{BuildError, Result};

/// A raster to write: heights in metres (float64, or already rounded to float32), row-major,
/// row 0 = north.
pub struct Raster<T = f64> {
    /// Samples per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// `width × height` heights.
    pub values: Vec<T>,
    /// Georeferencing of sample (0, 0) and the spacing, if any.
    pub georef: Option<GeoRef>,
}

/// Writes `r` as a single-band float GeoTIFF (float64 samples with `float64`, else float32):
/// pixel scale, tie point, GeoKeys (raster type, EPSG) and GDAL_NODATA.
pub fn write_geotiff<W: Write + Seek>(
    out: W,
    r: &Raster,
    nodata: Option<f64>,
    float64: bool,
) -> Result<()> {
    if !float64 {
        // In parallel: on a whole-file extract this is a pass over hundreds of megabytes.
        let f32s = Raster {
            width: r.width,
            height: r.height,
            values: r.values.par_iter().map(|&x| x as f32).collect(),
            georef: r.georef.clone(),
        };
        return write_geotiff_f32(out, &f32s, nodata);
    }
    let (w, h) = tiff_size(r.width, r.height)?;
    let mut enc = TiffEncoder::new(BufWriter::new(out))?;
    let mut img = enc.new_image::<colortype::Gray64Float>(w, h)?;
    write_geo_tags(img.encoder(), r.georef.as_ref(), nodata)?;
    img.write_data(&r.values)?;
    Ok(())
}

/// Writes `r`'s float32 samples as a single-band GeoTIFF: the same file [`write_geotiff`] writes
/// without `float64` for the same heights rounded to float32, without a float64 raster first.
pub fn write_geotiff_f32<W: Write + Seek>(
    out: W,
    r: &Raster<f32>,
    nodata: Option<f64>,
) -> Result<()> {
    let (w, h) = tiff_size(r.width, r.height)?;
    let mut enc = TiffEncoder::new(BufWriter::new(out))?;
    let mut img = enc.new_image::<colortype::Gray32Float>(w, h)?;
    write_geo_tags(img.encoder(), r.georef.as_ref(), nodata)?;
    img.write_data(&r.values)?;
    Ok(())
}

/// A raster's size as TIFF's 32-bit width and height, or an error naming it.
fn tiff_size(width: usize, height: usize) -> Result<(u32, u32)> {
    let dim = |v: usize| {
        u32::try_from(v).map_err(|_| {
            BuildError::Invalid(format!("a {width}×{height} raster is too large for a TIFF"))
        })
    };
    Ok((dim(width)?, dim(height)?))
}

/// Writes `width × height` int16 samples (row-major, row 0 north) as a single-band GeoTIFF with
/// the same tags as [`write_geotiff`], in strips of about 1 MB, Deflate-compressed with
/// `deflate`: tiles like SRTM's and GLO-30's, for the benchmarks and tests of tile mosaics.
pub fn write_geotiff_i16<W: Write + Seek>(
    out: W,
    (width, height): (usize, usize),
    values: &[i16],
    georef: Option<&GeoRef>,
    nodata: Option<f64>,
    deflate: bool,
) -> Result<()> {
    use tiff::encoder::Compression;
    use tiff::encoder::compression::DeflateLevel;
    if values.len() != width.saturating_mul(height) {
        return Err(BuildError::Invalid(format!(
            "{} samples for a {width}×{height} raster",
            values.len()
        )));
    }
    let dim = |v: usize| {
        u32::try_from(v).map_err(|_| {
            BuildError::Invalid(format!("a {width}×{height} raster is too large for a TIFF"))
        })
    };
    let mut enc = TiffEncoder::new(BufWriter::new(out))?.with_compression(if deflate {
        Compression::Deflate(DeflateLevel::Fast)
    } else {
        Compression::Uncompressed
    });
    let mut img = enc.new_image::<colortype::GrayI16>(dim(width)?, dim(height)?)?;
    write_geo_tags(img.encoder(), georef, nodata)?;
    img.write_data(values)?;
    Ok(())
}

/// The GeoTIFF tags `codec/src/input/geotiff.rs` reads back: pixel scale, one tie point at
/// raster (0, 0), model and raster type, the EPSG code, and GDAL's nodata text.
fn write_geo_tags<W: Write + Seek, K: tiff::encoder::TiffKind>(
    dir: &mut tiff::encoder::DirectoryEncoder<'_, W, K>,
    georef: Option<&GeoRef>,
    nodata: Option<f64>,
) -> Result<()> {
    if let Some(g) = georef {
        dir.write_tag(Tag::ModelPixelScaleTag, &[g.pixel_x, g.pixel_y, 0.0][..])?;
        dir.write_tag(
            Tag::ModelTiepointTag,
            &[0.0, 0.0, 0.0, g.origin_x, g.origin_y, 0.0][..],
        )?;
        let raster = if g.pixel_is_area {
            RASTER_PIXEL_IS_AREA
        } else {
            RASTER_PIXEL_IS_POINT
        };
        let mut keys: Vec<[u16; 2]> = Vec::new();
        // EPSG codes above 65535 do not fit a GeoKey short; the CRS is then left unnamed, as it
        // is for repositories built without one.
        match g.epsg.and_then(|e| u16::try_from(e).ok()) {
            // 4000…4999 holds the geographic 2-D CRSs (4326 and kin).
            Some(e) if (4000..5000).contains(&e) => {
                keys.push([KEY_MODEL_TYPE, MODEL_GEOGRAPHIC]);
                keys.push([KEY_RASTER_TYPE, raster]);
                keys.push([KEY_GEOGRAPHIC_TYPE, e]);
            }
            Some(e) => {
                keys.push([KEY_MODEL_TYPE, MODEL_PROJECTED]);
                keys.push([KEY_RASTER_TYPE, raster]);
                keys.push([KEY_PROJECTED_CS_TYPE, e]);
            }
            None => keys.push([KEY_RASTER_TYPE, raster]),
        }
        // Header: directory version 1, revision 1.0, key count; then key, location 0 (value
        // inline), count 1, value — keys sorted ascending, as the specification requires.
        let mut dirv: Vec<u16> = vec![1, 1, 0, keys.len() as u16];
        for [k, v] in keys {
            dirv.extend_from_slice(&[k, 0, 1, v]);
        }
        dir.write_tag(Tag::GeoKeyDirectoryTag, &dirv[..])?;
    }
    if let Some(nd) = nodata {
        // Rust's shortest round-trip formatting: the reader parses back the same f64.
        dir.write_tag(Tag::GdalNodata, format!("{nd}").as_str())?;
    }
    Ok(())
}

/// Writes `r`'s samples as headerless little-endian float64 (with `float64`) or float32.
pub fn write_raw<W: Write>(out: W, r: &Raster, float64: bool) -> Result<()> {
    let mut out = BufWriter::new(out);
    for &v in &r.values {
        if float64 {
            out.write_all(&v.to_le_bytes())?;
        } else {
            out.write_all(&(v as f32).to_le_bytes())?;
        }
    }
    out.flush()?;
    Ok(())
}

/// Writes `r`'s float32 samples as headerless little-endian float32: [`write_raw`]'s bytes
/// without `float64` for the same heights rounded to float32.
pub fn write_raw_f32<W: Write>(out: W, r: &Raster<f32>) -> Result<()> {
    let mut out = BufWriter::new(out);
    for &v in &r.values {
        out.write_all(&v.to_le_bytes())?;
    }
    out.flush()?;
    Ok(())
}
