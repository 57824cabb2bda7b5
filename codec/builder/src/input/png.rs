//! PNG height maps: 16-bit grayscale with a linear mapping, and Mapbox Terrain-RGB.

use std::fs::File;
use std::io::{BufReader, ErrorKind};
use std::path::Path;

use png::{BitDepth, ColorType, Decoder, DecodingError, Transformations};

use super::{Dem, Format, Limits, SampleType};
use cbdam_codec::CodecError;

/// Decoded pixels with the header facts the readers need.
struct Image {
    width: usize,
    height: usize,
    color: ColorType,
    depth: BitDepth,
    line_size: usize,
    bytes: Vec<u8>,
}

/// Opens a decoder that expands nothing: the readers want the stored samples, and a palette or
/// low bit depth silently widened to 8-bit RGB would masquerade as Terrain-RGB.
fn decoder(path: &Path, limits: &Limits) -> Result<Decoder<BufReader<File>>, CodecError> {
    let file = BufReader::new(File::open(path)?);
    // 8 bytes per declared sample is already more than any PNG layout we accept needs; our own
    // sample bound is checked against the header before the pixels are read.
    let bytes = limits.max_samples.saturating_mul(8);
    let mut dec = Decoder::new_with_limits(file, png::Limits { bytes });
    dec.set_transformations(Transformations::IDENTITY);
    Ok(dec)
}

fn read_image(path: &Path, limits: &Limits) -> Result<Image, CodecError> {
    let mut dec = decoder(path, limits)?;
    let (width, height) = {
        let info = dec.read_header_info().map_err(png_err)?;
        (info.width as usize, info.height as usize)
    };
    limits.check(width, height)?;
    let mut reader = dec.read_info().map_err(png_err)?;
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| CodecError::limit("PNG image too large for this platform"))?;
    let mut bytes = vec![0u8; size];
    let out = reader.next_frame(&mut bytes).map_err(png_err)?;
    Ok(Image {
        width,
        height,
        color: out.color_type,
        depth: out.bit_depth,
        line_size: out.line_size,
        bytes,
    })
}

/// Chooses between the two PNG formats from the header, for files given without a format.
pub(super) fn detect(path: &Path) -> Result<Format, CodecError> {
    let mut dec = decoder(path, &Limits::default())?;
    let info = dec.read_header_info().map_err(png_err)?;
    match (info.color_type, info.bit_depth) {
        (ColorType::Grayscale, BitDepth::Sixteen) => Ok(Format::Png16 {
            scale: 1.0,
            offset: 0.0,
        }),
        (ColorType::Rgb | ColorType::Rgba, BitDepth::Eight) => Ok(Format::TerrainRgb),
        (c, d) => Err(unsupported_layout(
            c,
            d,
            "16-bit grayscale or 8-bit RGB/RGBA",
        )),
    }
}

fn unsupported_layout(c: ColorType, d: BitDepth, wanted: &str) -> CodecError {
    CodecError::unsupported(format!(
        "PNG colour type {c:?} at {} bits per sample is not supported (expected {wanted})",
        d as u8
    ))
}

/// Reads a 16-bit grayscale PNG as `offset + scale * value`.
pub(super) fn read_png16(
    path: &Path,
    scale: f64,
    offset: f64,
    limits: &Limits,
) -> Result<Dem, CodecError> {
    if !(scale.is_finite() && scale != 0.0 && offset.is_finite()) {
        return Err(CodecError::invalid(format!(
            "PNG height mapping needs a finite non-zero scale and a finite offset, got scale \
             {scale}, offset {offset}"
        )));
    }
    let img = read_image(path, limits)?;
    if (img.color, img.depth) != (ColorType::Grayscale, BitDepth::Sixteen) {
        return Err(unsupported_layout(img.color, img.depth, "16-bit grayscale"));
    }
    let map = linear_map(scale, offset);
    let mut values = Vec::with_capacity(img.width * img.height);
    for row in img.bytes.chunks_exact(img.line_size).take(img.height) {
        values.extend(
            row[..img.width * 2]
                .chunks_exact(2)
                .map(|b| map(u16::from_be_bytes([b[0], b[1]]))),
        );
    }
    let identity = scale == 1.0 && offset == 0.0;
    Ok(Dem {
        width: img.width,
        height: img.height,
        values,
        sample_type: if identity {
            SampleType::U16
        } else {
            SampleType::F64
        },
        nodata: None,
        georef: None,
    })
}

/// `offset + scale * v`, computed so that decimal scales give exactly-rounded decimals.
///
/// Scales are nearly always 1/k (0.1, 0.01, 0.5): `v * 0.1` is not the double nearest to
/// `v / 10` (3 * 0.1 = 0.30000000000000004), which would make the heights look off-lattice to
/// [`super::detect_quantum`]. Dividing the integer count by k rounds once and lands on it.
fn linear_map(scale: f64, offset: f64) -> impl Fn(u16) -> f64 {
    let k = (1.0 / scale).round();
    let off_k = offset * k;
    let exact = (1.0..1e9).contains(&k)
        && 1.0 / k == scale
        && off_k.fract() == 0.0
        && off_k.abs() < 2f64.powi(52);
    move |v| {
        if exact {
            (off_k + f64::from(v)) / k
        } else {
            offset + scale * f64::from(v)
        }
    }
}

/// Reads a Mapbox Terrain-RGB PNG; alpha, when present, is ignored.
pub(super) fn read_terrain_rgb(path: &Path, limits: &Limits) -> Result<Dem, CodecError> {
    let img = read_image(path, limits)?;
    let channels = match (img.color, img.depth) {
        (ColorType::Rgb, BitDepth::Eight) => 3,
        (ColorType::Rgba, BitDepth::Eight) => 4,
        (c, d) => return Err(unsupported_layout(c, d, "8-bit RGB or RGBA")),
    };
    let mut values = Vec::with_capacity(img.width * img.height);
    for row in img.bytes.chunks_exact(img.line_size).take(img.height) {
        values.extend(row[..img.width * channels].chunks_exact(channels).map(|p| {
            let code = i64::from(p[0]) << 16 | i64::from(p[1]) << 8 | i64::from(p[2]);
            // Integer tenths, divided once: the exactly-rounded decimal height.
            (code - 100_000) as f64 / 10.0
        }));
    }
    Ok(Dem {
        width: img.width,
        height: img.height,
        values,
        // The heights are decimals of tenths; only an f64 holds their exactly-rounded value.
        sample_type: SampleType::F64,
        nodata: None,
        georef: None,
    })
}

pub(super) fn png_err(e: DecodingError) -> CodecError {
    match e {
        DecodingError::IoError(io) if io.kind() == ErrorKind::UnexpectedEof => {
            CodecError::truncated(format!("PNG ends early: {io}"))
        }
        DecodingError::IoError(io) => CodecError::Io(io),
        DecodingError::Format(f) => CodecError::corrupt(format!("PNG: {f}")),
        DecodingError::LimitsExceeded => CodecError::limit("PNG decoder memory limit exceeded"),
        other => CodecError::corrupt(format!("PNG: {other}")),
    }
}
