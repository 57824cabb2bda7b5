//! GeoTIFF through the `tiff` crate, plus the GeoTIFF and GDAL tags it leaves to us.
//!
//! `tiff` 0.11 decodes strips and tiles, classic TIFF and BigTIFF, the horizontal predictor and
//! the floating-point predictor (predictor 3, including the padded edge tiles where the predictor
//! shuffles padding bytes into the row). What it does not do is refuse what a DEM reader must
//! refuse, so the tags are checked here first: anything but a single band of 8/16/32-bit
//! integers or 32/64-bit floats, compressed with none, LZW, Deflate or PackBits, is reported as
//! unsupported by name rather than decoded into something that is not a height field. Predictor
//! codes other than 1-3 exist in no specification; the crate refuses them when opening, as corrupt.
//!
//! The samples themselves are decoded by [`super::geotiff_stream`], on top of the [`Header`]
//! read here; this module does not depend on it.

use std::fs::File;
use std::io::{BufReader, ErrorKind};
use std::path::Path;

use tiff::decoder::{ChunkType, Decoder};
use tiff::tags::Tag;
use tiff::{TiffError, TiffUnsupportedError};

use super::{GeoRef, Limits, SampleType};
use cbdam_codec::CodecError;

use super::geokeys::{
    KEY_GEOGRAPHIC_TYPE, KEY_PROJECTED_CS_TYPE, KEY_RASTER_TYPE, KEY_VERTICAL_UNITS,
    RASTER_PIXEL_IS_POINT, UNIT_FOOT, UNIT_METRE, UNIT_US_SURVEY_FOOT, USER_DEFINED,
};

/// What a GeoTIFF's tags say about its samples and their layout, checked: one band of a
/// supported type, a supported compression, every chunk inside the file.
#[derive(Clone, Debug)]
pub(super) struct Header {
    pub(super) width: usize,
    pub(super) height: usize,
    pub(super) sample_type: SampleType,
    pub(super) nodata: Option<f64>,
    pub(super) georef: Option<GeoRef>,
    /// Tiles rather than strips; a strip is handled as a tile as wide as the image.
    pub(super) tiled: bool,
    pub(super) chunk_width: usize,
    /// Rows per chunk (at most the image height).
    pub(super) chunk_height: usize,
    pub(super) chunks_across: usize,
    pub(super) chunks_down: usize,
}

impl Header {
    pub(super) fn read(path: &Path, limits: &Limits) -> Result<Self, CodecError> {
        let file_len = super::file_len(path)?;
        let file = BufReader::new(File::open(path)?);
        let mut dec = Decoder::new(file).map_err(tiff_err)?;
        let (w, h) = dec.dimensions().map_err(tiff_err)?;
        let (width, height) = (w as usize, h as usize);
        limits.check(width, height)?;

        let sample_type = check_layout(&mut dec)?;
        let tiled = dec.get_chunk_type() == ChunkType::Tile;
        let (cw, ch) = dec.chunk_dimensions();
        let (chunk_width, chunk_height) = (cw as usize, (ch as usize).min(height));
        if chunk_width == 0 || chunk_height == 0 {
            return Err(CodecError::corrupt(format!(
                "TIFF chunks of {cw} x {ch} samples"
            )));
        }
        let (chunks_across, chunks_down) =
            (width.div_ceil(chunk_width), height.div_ceil(chunk_height));
        check_chunks_in_file(&mut dec, file_len, chunks_across * chunks_down)?;
        let nodata = read_nodata(&mut dec)?.map(|v| fit_nodata(v, sample_type));
        check_vertical_units(&mut dec)?;
        let georef = read_georef(&mut dec)?;
        Ok(Self {
            width,
            height,
            sample_type,
            nodata,
            georef,
            tiled,
            chunk_width,
            chunk_height,
            chunks_across,
            chunks_down,
        })
    }

    /// Where chunk `index` lies: `(first column, first row, columns, rows)` of its data, the
    /// padding of edge tiles and of the last strip excluded.
    pub(super) fn chunk_rect(&self, index: usize) -> (usize, usize, usize, usize) {
        let (c, r) = (index % self.chunks_across, index / self.chunks_across);
        let (x0, y0) = (c * self.chunk_width, r * self.chunk_height);
        (
            x0,
            y0,
            self.chunk_width.min(self.width - x0),
            self.chunk_height.min(self.height - y0),
        )
    }

    /// Decoder limits for one chunk at a time: our own size bound was checked when reading the
    /// header, and the crate's default 256 MiB buffer limit would only refuse a legitimate file
    /// stored as one huge strip.
    pub(super) fn decoder_limits(&self) -> tiff::decoder::Limits {
        let mut tl = tiff::decoder::Limits::default();
        let chunk = self.chunk_width.saturating_mul(self.chunk_height);
        tl.decoding_buffer_size = chunk.saturating_mul(8).max(tl.decoding_buffer_size);
        tl.intermediate_buffer_size = usize::MAX;
        tl.ifd_value_size = 64 << 20;
        tl
    }
}

/// Refuses everything that is not one band of a plain numeric type, naming what was found.
fn check_layout<R: std::io::Read + std::io::Seek>(
    dec: &mut Decoder<R>,
) -> Result<SampleType, CodecError> {
    let samples: u16 = dec
        .find_tag_unsigned(Tag::SamplesPerPixel)
        .map_err(tiff_err)?
        .unwrap_or(1);
    if samples != 1 {
        return Err(CodecError::unsupported(format!(
            "TIFF with {samples} bands (SamplesPerPixel) is not supported; a DEM must have one band"
        )));
    }

    let compression: u16 = dec
        .find_tag_unsigned(Tag::Compression)
        .map_err(tiff_err)?
        .unwrap_or(1);
    // JPEG and the fax codings are lossy or bilevel: decoding them would hand back something
    // that is not the stored height field, even though the `tiff` crate could.
    if !matches!(compression, 1 | 5 | 8 | 32946 | 32773) {
        return Err(CodecError::unsupported(format!(
            "TIFF compression {} ({compression}) is not supported (supported: none, LZW, \
             Deflate, PackBits)",
            compression_name(compression)
        )));
    }

    let photometric: Option<u16> = dec
        .find_tag_unsigned(Tag::PhotometricInterpretation)
        .map_err(tiff_err)?;
    // The `tiff` crate "inverts" WhiteIsZero images (1.0 - v for floats), which would silently
    // change heights; GDAL ignores the tag for data values, but guessing wrong is worse than
    // refusing.
    if photometric == Some(0) {
        return Err(CodecError::unsupported(
            "TIFF photometric interpretation WhiteIsZero (0) is not supported for DEMs",
        ));
    }

    let bits: u16 = dec
        .find_tag_unsigned(Tag::BitsPerSample)
        .map_err(tiff_err)?
        .unwrap_or(1);
    let format: u16 = dec
        .find_tag_unsigned(Tag::SampleFormat)
        .map_err(tiff_err)?
        .unwrap_or(1);
    Ok(match (format, bits) {
        (1, 8) => SampleType::U8,
        (1, 16) => SampleType::U16,
        (1, 32) => SampleType::U32,
        (2, 8) => SampleType::I8,
        (2, 16) => SampleType::I16,
        (2, 32) => SampleType::I32,
        (3, 32) => SampleType::F32,
        (3, 64) => SampleType::F64,
        _ => {
            let kind = match format {
                1 => "unsigned integer",
                2 => "signed integer",
                3 => "floating point",
                4 => "untyped (void)",
                5 => "complex integer",
                6 => "complex floating point",
                _ => "unknown",
            };
            return Err(CodecError::unsupported(format!(
                "TIFF sample format {bits}-bit {kind} (SampleFormat {format}) is not supported \
                 (supported: 8/16/32-bit integers, 32/64-bit floats)"
            )));
        }
    })
}

fn compression_name(code: u16) -> &'static str {
    match code {
        2 => "CCITT RLE",
        3 => "CCITT Group 3 fax",
        4 => "CCITT Group 4 fax",
        6 => "old-style JPEG",
        7 => "JPEG",
        34661 => "JBIG",
        34712 => "JPEG 2000",
        34887 => "LERC",
        34925 => "LZMA",
        50000 => "Zstandard",
        50001 => "WebP",
        50002 => "JPEG XL",
        _ => "unknown",
    }
}

/// A strip or tile reaching past the end of the file is the usual sign of an interrupted
/// download; saying so beats the decompressor's "unexpected end of stream" in the middle of it.
pub(super) fn check_chunks_in_file<R: std::io::Read + std::io::Seek>(
    dec: &mut Decoder<R>,
    file_len: u64,
    expected: usize,
) -> Result<(), CodecError> {
    let tiled = dec.find_tag(Tag::TileOffsets).map_err(tiff_err)?.is_some();
    let (offsets_tag, counts_tag, what) = if tiled {
        (Tag::TileOffsets, Tag::TileByteCounts, "tile")
    } else {
        (Tag::StripOffsets, Tag::StripByteCounts, "strip")
    };
    let offsets: Vec<u64> = dec
        .find_tag_unsigned_vec(offsets_tag)
        .map_err(tiff_err)?
        .unwrap_or_default();
    let counts: Vec<u64> = dec
        .find_tag_unsigned_vec(counts_tag)
        .map_err(tiff_err)?
        .unwrap_or_default();
    if offsets.len() < expected || counts.len() < expected {
        return Err(CodecError::corrupt(format!(
            "TIFF lists {} {what} offsets and {} byte counts but the image has {expected} {what}s",
            offsets.len(),
            counts.len()
        )));
    }
    for (i, (&off, &len)) in offsets.iter().zip(&counts).enumerate() {
        let end = off.saturating_add(len);
        if end > file_len {
            return Err(CodecError::truncated(format!(
                "TIFF {what} {i} ends at byte {end} but the file has only {file_len} bytes"
            )));
        }
    }
    Ok(())
}

fn read_nodata<R: std::io::Read + std::io::Seek>(
    dec: &mut Decoder<R>,
) -> Result<Option<f64>, CodecError> {
    let Some(value) = dec.find_tag(Tag::GdalNodata).map_err(tiff_err)? else {
        return Ok(None);
    };
    let text = value
        .into_string()
        .map_err(|_| CodecError::corrupt("TIFF GDAL_NODATA tag is not ASCII"))?;
    let text = text.trim_matches(|c: char| c == '\0' || c.is_whitespace());
    text.parse::<f64>()
        .map(Some)
        .map_err(|_| CodecError::corrupt(format!("TIFF GDAL_NODATA tag '{text}' is not a number")))
}

/// GDAL writes the nodata tag as decimal text, which need not round-trip to the band's type:
/// the common float32 "lowest value" is written as `-3.402823e+38`, seven digits, which is not
/// `f32::MIN`. Like GDAL, snap near-±`f32::MAX` to it and round other float32 nodata to `f32`, so
/// that comparing samples with the nodata value finds the samples the writer meant.
fn fit_nodata(v: f64, ty: SampleType) -> f64 {
    if ty != SampleType::F32 || !v.is_finite() {
        return v;
    }
    let max = f64::from(f32::MAX);
    if (v.abs() - max).abs() <= max * 1e-6 {
        v.signum() * max
    } else {
        f64::from(v as f32)
    }
}

/// The GeoKeys whose value is the short itself (location 0), as `(key, value)`: the keys read
/// here are all of that kind. No GeoKeyDirectoryTag: none.
fn geo_keys<R: std::io::Read + std::io::Seek>(
    dec: &mut Decoder<R>,
) -> Result<Vec<(u16, u16)>, CodecError> {
    let Some(v) = dec.find_tag(Tag::GeoKeyDirectoryTag).map_err(tiff_err)? else {
        return Ok(Vec::new());
    };
    let keys = v
        .into_u16_vec()
        .map_err(|_| CodecError::corrupt("GeoKeyDirectoryTag does not hold shorts"))?;
    if keys.len() < 4 {
        return Err(CodecError::corrupt(
            "GeoKeyDirectoryTag shorter than its header",
        ));
    }
    let count = keys[3] as usize;
    let entries = keys[4..].chunks_exact(4).take(count);
    if entries.len() < count {
        return Err(CodecError::corrupt(format!(
            "GeoKeyDirectoryTag declares {count} keys but holds {}",
            (keys.len() - 4) / 4
        )));
    }
    Ok(entries
        .filter(|e| e[1] == 0)
        .map(|e| (e[0], e[3]))
        .collect())
}

/// Refuses elevations whose VerticalUnitsGeoKey names a unit other than the metre: heights and
/// the error bound are metres throughout (the repository header's vertical unit is 0, metres),
/// so a DEM in feet would be coded with a bound in feet and drawn 3.28× too tall. Converting
/// in the reader is not done: it would take integer-foot data off its value lattice.
fn check_vertical_units<R: std::io::Read + std::io::Seek>(
    dec: &mut Decoder<R>,
) -> Result<(), CodecError> {
    for (key, value) in geo_keys(dec)? {
        if key == KEY_VERTICAL_UNITS && !matches!(value, 0 | UNIT_METRE | USER_DEFINED) {
            let name = match value {
                UNIT_FOOT => " (foot)",
                UNIT_US_SURVEY_FOOT => " (US survey foot)",
                _ => "",
            };
            return Err(CodecError::unsupported(format!(
                "GeoTIFF VerticalUnitsGeoKey is EPSG unit {value}{name}: heights must be in \
                 metres (convert the DEM first, e.g. gdal_calc.py --calc=\"A*0.3048\")"
            )));
        }
    }
    Ok(())
}

pub(super) fn read_georef<R: std::io::Read + std::io::Seek>(
    dec: &mut Decoder<R>,
) -> Result<Option<GeoRef>, CodecError> {
    let f64s = |dec: &mut Decoder<R>, tag: Tag| -> Result<Option<Vec<f64>>, CodecError> {
        match dec.find_tag(tag).map_err(tiff_err)? {
            None => Ok(None),
            Some(v) => v.into_f64_vec().map(Some).map_err(|_| {
                CodecError::corrupt(format!("GeoTIFF tag {tag:?} does not hold doubles"))
            }),
        }
    };
    let scale = f64s(dec, Tag::ModelPixelScaleTag)?;
    let tiepoint = f64s(dec, Tag::ModelTiepointTag)?;
    let transform = f64s(dec, Tag::ModelTransformationTag)?;
    let keys = geo_keys(dec)?;

    let (origin_x, origin_y, pixel_x, pixel_y) = match (scale, tiepoint, transform) {
        (Some(s), Some(t), _) if s.len() >= 2 && t.len() >= 6 => {
            // The tiepoint ties raster point (i, j) to model (x, y); move it back to (0, 0).
            let (i, j, x, y) = (t[0], t[1], t[3], t[4]);
            (x - i * s[0], y + j * s[1], s[0], s[1])
        }
        (_, _, Some(m)) if m.len() >= 16 => {
            if m[1] != 0.0 || m[4] != 0.0 {
                return Err(CodecError::unsupported(
                    "GeoTIFF ModelTransformationTag with rotation or shear is not supported",
                ));
            }
            (m[3], m[7], m[0], -m[5])
        }
        _ => return Ok(None),
    };

    let mut epsg = None;
    let mut geographic = None;
    let mut pixel_is_area = true;
    for (key, value) in keys {
        match key {
            KEY_RASTER_TYPE => pixel_is_area = value != RASTER_PIXEL_IS_POINT,
            KEY_PROJECTED_CS_TYPE if value != 0 && value != USER_DEFINED => {
                epsg = Some(u32::from(value));
            }
            KEY_GEOGRAPHIC_TYPE if value != 0 && value != USER_DEFINED => {
                geographic = Some(u32::from(value));
            }
            _ => {}
        }
    }
    // A projected CRS also names the datum's geographic CRS; the projected one is where the
    // grid's coordinates live.
    Ok(Some(GeoRef {
        epsg: epsg.or(geographic),
        origin_x,
        origin_y,
        pixel_x,
        pixel_y,
        pixel_is_area,
        // GeoKeys name CRSs by code; a `.prj` beside the file is read by `read_dem`.
        wkt: None,
    }))
}

pub(super) fn tiff_err(e: TiffError) -> CodecError {
    match e {
        TiffError::IoError(io) if io.kind() == ErrorKind::UnexpectedEof => {
            CodecError::truncated(format!("TIFF ends early: {io}"))
        }
        TiffError::IoError(io) if io.kind() == ErrorKind::InvalidData => {
            CodecError::corrupt(format!("TIFF data: {io}"))
        }
        TiffError::IoError(io) => CodecError::Io(io),
        TiffError::FormatError(f) => CodecError::corrupt(format!("TIFF: {f}")),
        TiffError::UnsupportedError(u) => unsupported(u),
        TiffError::LimitsExceeded => CodecError::limit("TIFF decoder limits exceeded"),
        other => CodecError::corrupt(format!("TIFF: {other}")),
    }
}

fn unsupported(u: TiffUnsupportedError) -> CodecError {
    CodecError::unsupported(format!("TIFF feature: {u}"))
}
