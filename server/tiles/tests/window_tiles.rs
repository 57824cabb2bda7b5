//! Raster tiles made from windows (a plane's tile decodes only the records within reach of its
//! pixels, `Surface::decode_window`) are byte for byte the tiles made from the whole decoded
//! surface (`Surface::decode`), for every tile of every zoom, both encodings, both sizes, on an
//! EPSG:4326 plane and a UTM one, with a nodata hole.

use cbdam_codec::hierarchy::{EncodeOptions, Encoder};
use cbdam_codec::quant::{HeightGrid, QuantPlan};
use cbdam_codec::repository::{GeoRef, Repository, serialize};
use cbdam_tiles::{Encoding, Scheme, Tiler};

const NODATA: f64 = -9999.0;

/// Rough terrain, `w × h` samples, with a nodata hole, as a repository within 0.25 m.
fn repository(w: usize, h: usize, georef: GeoRef) -> Repository {
    let metres: Vec<f64> = (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as f64, (i / w) as f64);
            if (x - 0.7 * w as f64).hypot(y - 0.3 * h as f64) < 3.0 {
                return NODATA;
            }
            let noise = ((i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 58) as f64 / 8.0;
            300.0 + 40.0 * (x / 6.0).sin() * (y / 9.0).cos() + 0.3 * x + noise
        })
        .collect();
    let plan = QuantPlan::new(0.25, None, 200.0, 400.0).unwrap();
    let grid = HeightGrid::from_metres(w, h, &metres, Some(NODATA), &plan).unwrap();
    let opts = EncodeOptions {
        n: 9,
        ..EncodeOptions::default()
    };
    let enc = Encoder::new(&grid, plan.quantizer, &opts).encode().unwrap();
    let bytes = serialize(&enc, &plan, Some(&georef), Some(NODATA)).unwrap();
    Repository::from_bytes(bytes).unwrap()
}

/// Every raster tile of `repo`, made by a tiler that decoded the whole surface first and by
/// one that decodes windows, must be the same bytes; returns how many were compared.
fn same_tiles(repo: &Repository) -> usize {
    let whole = Tiler::new(repo.head(), repo.to_encoded().unwrap()).unwrap();
    whole.surface().unwrap();
    let windows = Tiler::new(repo.head(), repo.to_encoded().unwrap()).unwrap();
    let mut compared = 0;
    for tile in [256, 512] {
        for z in 0..=whole.raster_max_zoom(tile) {
            let Some((x0, y0, x1, y1)) = Scheme::WebMercator.range(z, whole.bounds()) else {
                continue;
            };
            for (x, y) in (x0..=x1).flat_map(|x| (y0..=y1).map(move |y| (x, y))) {
                for enc in [Encoding::Terrarium, Encoding::TerrainRgb] {
                    let a = whole.raster((u32::from(z), x, y), tile, enc).unwrap();
                    let b = windows.raster((u32::from(z), x, y), tile, enc).unwrap();
                    assert!(
                        a.png == b.png,
                        "tile {z}/{x}/{y} ({tile} px, {enc:?}) differs"
                    );
                    assert_eq!((a.nodata, a.level), (b.nodata, b.level));
                    compared += 1;
                }
            }
        }
    }
    compared
}

#[test]
fn window_tiles_are_the_whole_surfaces_tiles_on_a_geographic_plane() {
    let repo = repository(
        160,
        120,
        GeoRef {
            epsg: Some(4326),
            origin_x: 7.0,
            origin_y: 46.0,
            pixel_x: 1.0 / 1200.0,
            pixel_y: 1.0 / 1200.0,
            pixel_is_area: false,
            wkt: None,
        },
    );
    let compared = same_tiles(&repo);
    assert!(compared >= 40, "only {compared} tiles compared");
}

#[test]
fn window_tiles_are_the_whole_surfaces_tiles_on_a_utm_plane() {
    let repo = repository(
        120,
        100,
        GeoRef {
            epsg: Some(32632),
            origin_x: 400_000.0,
            origin_y: 5_100_000.0,
            pixel_x: 30.0,
            pixel_y: 30.0,
            pixel_is_area: true,
            wkt: None,
        },
    );
    let compared = same_tiles(&repo);
    assert!(compared >= 40, "only {compared} tiles compared");
}
