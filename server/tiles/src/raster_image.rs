//! The image files raster-dem tiles travel in: PNG or lossless WebP (both read by MapLibre's
//! `raster-dem` source). Both hold the same RGBA pixels, bit for bit: WebP is written by the
//! `image-webp` crate's lossless (VP8L) encoder, which keeps every channel of every pixel,
//! the colour of transparent ones included.

use crate::TilesError;

/// The file format of a raster tile.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum ImageFormat {
    /// PNG (RGB, or RGBA when some pixel has no data).
    #[default]
    Png,
    /// Lossless WebP (VP8L; with an alpha channel when some pixel has no data).
    Webp,
}

impl ImageFormat {
    /// The file extension, without its dot (`png`, `webp`), as in tile URLs.
    pub fn extension(self) -> &'static str {
        match self {
            ImageFormat::Png => "png",
            ImageFormat::Webp => "webp",
        }
    }

    /// The media type (`Content-Type`).
    pub fn media_type(self) -> &'static str {
        match self {
            ImageFormat::Png => "image/png",
            ImageFormat::Webp => "image/webp",
        }
    }

    /// The format named `text` (`png`, `webp`), or an error naming the ones there are.
    pub fn parse(text: &str) -> Result<ImageFormat, TilesError> {
        match text {
            "png" => Ok(ImageFormat::Png),
            "webp" => Ok(ImageFormat::Webp),
            other => Err(TilesError::BadTile(format!(
                "image format {other:?}: raster tiles are png or webp"
            ))),
        }
    }

    /// `rgba` (`size × size` pixels) in this format; RGB only when `alpha` is false (every
    /// pixel opaque).
    pub fn write(self, rgba: &[u8], size: u32, alpha: bool) -> Result<Vec<u8>, TilesError> {
        match self {
            ImageFormat::Png => write_png(rgba, size, alpha),
            ImageFormat::Webp => write_webp(rgba, size, alpha),
        }
    }
}

/// A PNG of `rgba` pixels, RGB when no pixel is transparent.
fn write_png(rgba: &[u8], tile: u32, alpha: bool) -> Result<Vec<u8>, TilesError> {
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, tile, tile);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(png::Compression::Fast);
    let internal = |e: png::EncodingError| TilesError::Internal(format!("writing a PNG: {e}"));
    if alpha {
        enc.set_color(png::ColorType::Rgba);
        let mut w = enc.write_header().map_err(internal)?;
        w.write_image_data(rgba).map_err(internal)?;
    } else {
        enc.set_color(png::ColorType::Rgb);
        let mut w = enc.write_header().map_err(internal)?;
        w.write_image_data(&rgb_of(rgba)).map_err(internal)?;
    }
    Ok(out)
}

/// A lossless WebP of `rgba` pixels, without an alpha channel when no pixel is transparent.
fn write_webp(rgba: &[u8], tile: u32, alpha: bool) -> Result<Vec<u8>, TilesError> {
    use image_webp::{ColorType, WebPEncoder};
    let expected = tile as usize * tile as usize * 4;
    if rgba.len() != expected {
        // The encoder panics on a wrong size; say so instead.
        return Err(TilesError::Internal(format!(
            "writing a WebP: {} bytes of pixels for a {tile}-pixel tile (want {expected})",
            rgba.len()
        )));
    }
    let mut out = Vec::new();
    let written = if alpha {
        WebPEncoder::new(&mut out).encode(rgba, tile, tile, ColorType::Rgba8)
    } else {
        WebPEncoder::new(&mut out).encode(&rgb_of(rgba), tile, tile, ColorType::Rgb8)
    };
    written.map_err(|e| TilesError::Internal(format!("writing a WebP: {e}")))?;
    Ok(out)
}

fn rgb_of(rgba: &[u8]) -> Vec<u8> {
    rgba.chunks_exact(4)
        .flat_map(|p| [p[0], p[1], p[2]])
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Pixels with every channel value, some transparent with a colour of their own.
    fn pixels(size: u32, transparent: bool) -> Vec<u8> {
        let mut rgba = Vec::new();
        for i in 0..size * size {
            let v = i.wrapping_mul(2_654_435_761);
            let a = if transparent && i % 7 == 3 { 0 } else { 255 };
            rgba.extend_from_slice(&[(v >> 24) as u8, (v >> 16) as u8, i as u8, a]);
        }
        rgba
    }

    /// The WebP decodes (the `image-webp` decoder; the browser check decodes with Chromium's
    /// libwebp) to the very RGBA pixels written, the colour of transparent pixels included.
    #[test]
    fn webp_holds_every_pixel_exactly() {
        for (size, alpha) in [(256, false), (256, true), (64, true)] {
            let rgba = pixels(size, alpha);
            let webp = ImageFormat::Webp.write(&rgba, size, alpha).unwrap();
            let mut dec = image_webp::WebPDecoder::new(std::io::Cursor::new(&webp)).unwrap();
            assert_eq!(dec.dimensions(), (size, size));
            assert_eq!(dec.has_alpha(), alpha);
            let mut out = vec![0u8; dec.output_buffer_size().unwrap()];
            dec.read_image(&mut out).unwrap();
            let back = if alpha {
                out
            } else {
                out.chunks_exact(3)
                    .flat_map(|p| [p[0], p[1], p[2], 255])
                    .collect()
            };
            assert!(back == rgba, "{size} px, alpha {alpha}: pixels differ");
        }
    }

    #[test]
    fn a_wrong_pixel_count_is_an_error_not_a_panic() {
        let e = ImageFormat::Webp.write(&[0; 12], 2, true).unwrap_err();
        assert!(e.to_string().contains("want 16"), "{e}");
        assert!(ImageFormat::parse("jpeg").is_err());
        assert_eq!(ImageFormat::parse("webp").unwrap(), ImageFormat::Webp);
    }
}
