//! Colour images for colour repositories: 8-bit RGB or RGBA PNG, 8-bit RGB(A) GeoTIFF (chunky).
//! Anything else — greyscale, palette, 16-bit, planar — is refused by name rather than
//! converted, so that what is coded is exactly what the file stores.

use std::fs::File;
use std::io::BufReader;
use std::path::Path;

use png::{BitDepth, ColorType, Transformations};
use tiff::decoder::{Decoder as TiffDecoder, DecodingResult};
use tiff::tags::Tag;

use super::Limits;
use super::geotiff::{check_chunks_in_file, read_georef, tiff_err};
use super::png::png_err;
use cbdam_codec::CodecError;
use cbdam_codec::colour::RgbImage;

/// Reads an 8-bit RGB(A) PNG or GeoTIFF (by extension; `.tif`/`.tiff` are TIFF, everything else
/// is tried as PNG). Alpha is dropped; GeoTIFF georeferencing is kept.
pub fn read_rgb(path: &Path, limits: &Limits) -> Result<RgbImage, CodecError> {
    cbdam_codec::files::check_regular_file(path)?;
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("tif" | "tiff") => read_tiff(path, limits),
        _ => read_png(path, limits),
    }
}

fn to_pixels(bytes: &[u8], channels: usize, n: usize) -> Result<Vec<[u8; 3]>, CodecError> {
    if bytes.len() < n * channels {
        return Err(CodecError::truncated(format!(
            "image holds {} bytes for {n} pixels of {channels} bytes",
            bytes.len()
        )));
    }
    Ok(bytes
        .chunks_exact(channels)
        .take(n)
        .map(|p| [p[0], p[1], p[2]])
        .collect())
}

fn read_png(path: &Path, limits: &Limits) -> Result<RgbImage, CodecError> {
    let file = BufReader::new(File::open(path)?);
    let mut dec = png::Decoder::new_with_limits(
        file,
        png::Limits {
            bytes: limits.max_samples.saturating_mul(4),
        },
    );
    dec.set_transformations(Transformations::IDENTITY);
    let (width, height, color, depth) = {
        let info = dec.read_header_info().map_err(png_err)?;
        (
            info.width as usize,
            info.height as usize,
            info.color_type,
            info.bit_depth,
        )
    };
    let channels = match color {
        ColorType::Rgb => 3,
        ColorType::Rgba => 4,
        ColorType::Grayscale | ColorType::GrayscaleAlpha => {
            return Err(CodecError::unsupported(
                "greyscale PNG: a colour image must be 8-bit RGB or RGBA",
            ));
        }
        ColorType::Indexed => {
            return Err(CodecError::unsupported(
                "palette PNG: a colour image must be 8-bit RGB or RGBA (expand the palette first)",
            ));
        }
    };
    if depth != BitDepth::Eight {
        return Err(CodecError::unsupported(format!(
            "{}-bit PNG: a colour image must have 8 bits per component",
            depth as u8
        )));
    }
    let n = limits.check(width, height)?;
    let mut reader = dec.read_info().map_err(png_err)?;
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| CodecError::limit("PNG image too large for this platform"))?;
    let mut bytes = vec![0u8; size];
    let out = reader.next_frame(&mut bytes).map_err(png_err)?;
    // Rows are packed for 8-bit RGB(A): line size is width × channels.
    debug_assert_eq!(out.line_size, width * channels);
    Ok(RgbImage {
        width,
        height,
        pixels: to_pixels(&bytes, channels, n)?,
        georef: None,
    })
}

fn read_tiff(path: &Path, limits: &Limits) -> Result<RgbImage, CodecError> {
    let file_len = std::fs::metadata(path)?.len();
    let file = BufReader::new(File::open(path)?);
    let mut dec = TiffDecoder::new(file).map_err(tiff_err)?;
    let (w, h) = dec.dimensions().map_err(tiff_err)?;
    let (width, height) = (w as usize, h as usize);
    let n = limits.check(width, height)?;
    let tag = |dec: &mut TiffDecoder<_>, t: Tag, default: u16| -> Result<u16, CodecError> {
        Ok(dec
            .find_tag_unsigned(t)
            .map_err(tiff_err)?
            .unwrap_or(default))
    };
    let samples = tag(&mut dec, Tag::SamplesPerPixel, 1)?;
    let bits = tag(&mut dec, Tag::BitsPerSample, 1)?;
    let planar = tag(&mut dec, Tag::PlanarConfiguration, 1)?;
    let photometric = tag(&mut dec, Tag::PhotometricInterpretation, 1)?;
    let format = tag(&mut dec, Tag::SampleFormat, 1)?;
    if samples < 3 || photometric != 2 {
        return Err(CodecError::unsupported(format!(
            "TIFF with {samples} band(s), photometric interpretation {photometric}: a colour \
             image must be RGB (3 or 4 bands, PhotometricInterpretation 2)"
        )));
    }
    if samples > 4 {
        return Err(CodecError::unsupported(format!(
            "TIFF with {samples} bands: a colour image has RGB or RGBA"
        )));
    }
    if bits != 8 || format != 1 {
        return Err(CodecError::unsupported(format!(
            "TIFF with {bits}-bit samples of format {format}: a colour image must have 8-bit \
             unsigned components"
        )));
    }
    if planar != 1 {
        return Err(CodecError::unsupported(
            "planar TIFF (PlanarConfiguration 2): a colour image must be chunky (interleaved RGB)",
        ));
    }
    let (cw, ch) = dec.chunk_dimensions();
    if cw == 0 || ch == 0 {
        return Err(CodecError::corrupt(format!(
            "TIFF chunks of {cw} x {ch} pixels"
        )));
    }
    // Strips may be taller than the image (RowsPerStrip defaults to 2^32 - 1).
    let chunk_h = (ch as usize).min(height);
    let chunks = width.div_ceil(cw as usize) * height.div_ceil(chunk_h.max(1));
    check_chunks_in_file(&mut dec, file_len, chunks)?;
    let mut tl = tiff::decoder::Limits::default();
    tl.decoding_buffer_size = n.saturating_mul(4).max(tl.decoding_buffer_size);
    tl.intermediate_buffer_size = usize::MAX;
    tl.ifd_value_size = 64 << 20;
    let mut dec = dec.with_limits(tl);
    let georef = read_georef(&mut dec)?;
    let bytes = match dec.read_image().map_err(tiff_err)? {
        DecodingResult::U8(v) => v,
        _ => {
            return Err(CodecError::unsupported(
                "TIFF did not decode to 8-bit samples",
            ));
        }
    };
    Ok(RgbImage {
        width,
        height,
        pixels: to_pixels(&bytes, usize::from(samples), n)?,
        georef,
    })
}
