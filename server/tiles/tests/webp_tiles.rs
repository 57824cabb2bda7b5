//! WebP raster tiles hold the very pixels of the PNG tiles: every raster tile of a plane with
//! a nodata hole (transparent pixels), both encodings, both sizes, is decoded from its PNG (the
//! `png` crate) and from its WebP (the `image-webp` decoder; the browser check,
//! `scripts/web_maps_check.py`, decodes them again with Chromium's) to identical RGBA.

#[path = "common/rough_dem.rs"]
mod rough_dem;

use cbdam_codec::repository::GeoRef;
use cbdam_tiles::{Encoding, ImageFormat, Scheme, Tiler};

/// A PNG's pixels as RGBA.
fn png_rgba(bytes: &[u8]) -> Vec<u8> {
    let mut reader = png::Decoder::new(std::io::Cursor::new(bytes))
        .read_info()
        .unwrap();
    let mut buf = vec![0u8; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    buf.truncate(info.buffer_size());
    match info.color_type {
        png::ColorType::Rgba => buf,
        png::ColorType::Rgb => buf
            .chunks_exact(3)
            .flat_map(|p| [p[0], p[1], p[2], 255])
            .collect(),
        other => panic!("a PNG tile of colour type {other:?}"),
    }
}

/// A WebP's pixels as RGBA, and whether it has an alpha channel.
fn webp_rgba(bytes: &[u8]) -> (Vec<u8>, bool) {
    let mut dec = image_webp::WebPDecoder::new(std::io::Cursor::new(bytes)).unwrap();
    let alpha = dec.has_alpha();
    let mut buf = vec![0u8; dec.output_buffer_size().unwrap()];
    dec.read_image(&mut buf).unwrap();
    if alpha {
        return (buf, true);
    }
    let rgba = buf
        .chunks_exact(3)
        .flat_map(|p| [p[0], p[1], p[2], 255])
        .collect();
    (rgba, false)
}

#[test]
fn webp_tiles_hold_the_png_tiles_pixels_exactly() {
    let (w, h) = (160, 120);
    let georef = GeoRef {
        epsg: Some(4326),
        origin_x: 7.0,
        origin_y: 46.0,
        pixel_x: 1.0 / 1200.0,
        pixel_y: 1.0 / 1200.0,
        pixel_is_area: false,
        wkt: None,
    };
    let repo = rough_dem::repository(w, h, &rough_dem::rough_metres(w, h), &georef);
    let tiler = Tiler::new(repo.head(), repo.to_encoded().unwrap()).unwrap();
    let (mut compared, mut with_nodata, mut png_bytes, mut webp_bytes) = (0, 0, 0, 0);
    for tile in [256, 512] {
        let max = tiler.raster_max_zoom(tile);
        for z in max.saturating_sub(2)..=max {
            let (x0, y0, x1, y1) = Scheme::WebMercator.range(z, tiler.bounds()).unwrap();
            for (x, y) in (x0..=x1).flat_map(|x| (y0..=y1).map(move |y| (x, y))) {
                for enc in [Encoding::Terrarium, Encoding::TerrainRgb] {
                    let zxy = (u32::from(z), x, y);
                    let png = tiler.raster(zxy, tile, (enc, ImageFormat::Png)).unwrap();
                    let webp = tiler.raster(zxy, tile, (enc, ImageFormat::Webp)).unwrap();
                    assert!(webp.image.starts_with(b"RIFF"), "{zxy:?}: not a WebP");
                    let (rgba, alpha) = webp_rgba(&webp.image);
                    assert_eq!(alpha, png.nodata > 0, "{zxy:?} {enc:?}: alpha channel");
                    assert!(
                        rgba == png_rgba(&png.image),
                        "tile {zxy:?} ({tile} px, {enc:?}): WebP pixels differ from the PNG's"
                    );
                    assert_eq!(
                        (webp.nodata, webp.clamped, webp.level),
                        (png.nodata, png.clamped, png.level)
                    );
                    compared += 1;
                    with_nodata += usize::from(png.nodata > 0);
                    png_bytes += png.image.len();
                    webp_bytes += webp.image.len();
                }
            }
        }
    }
    assert!(compared >= 20, "only {compared} tiles compared");
    assert!(
        with_nodata >= 2,
        "only {with_nodata} tiles with transparent pixels"
    );
    eprintln!("{compared} tiles: PNG {png_bytes} bytes, WebP {webp_bytes} bytes");
}
