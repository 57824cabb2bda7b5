//! Tiles made from windows (a tile decodes only the records within reach of its pixels or
//! vertices: a plane's `Surface::decode_window`, a planet's `Surface::decode_faces`) are byte
//! for byte the tiles made from the whole decoded surface (`Surface::decode`): every raster
//! tile of every zoom, both encodings, both sizes, and every available quantized-mesh tile, on
//! an EPSG:4326 plane and a UTM one with a nodata hole, and on a planet. The mesh tiles are
//! also those of a tiler that shares no work between neighbouring tiles
//! (`Tiler::without_sharing`), whatever order the tiles are asked in; a mesh tile asked again
//! is the one kept (its gzip).

#[path = "common/rough_dem.rs"]
mod rough_dem;

use cbdam_codec::hierarchy::{EncodeOptions, PlanetGrid, encode_planet};
use cbdam_codec::quant::QuantPlan;
use cbdam_codec::repository::{GeoRef, Repository, serialize};
use cbdam_tiles::{Encoding, ImageFormat, Scheme, Tiler};

/// Rough terrain, `w × h` samples, with a nodata hole, as a repository within 0.25 m.
fn repository(w: usize, h: usize, georef: GeoRef) -> Repository {
    rough_dem::repository(w, h, &rough_dem::rough_metres(w, h), &georef)
}

/// `bytes` gunzipped.
fn gunzip(bytes: &[u8]) -> Vec<u8> {
    use std::io::Read;
    let mut out = Vec::new();
    flate2::read::GzDecoder::new(bytes)
        .read_to_end(&mut out)
        .unwrap();
    out
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
                    let png = (enc, ImageFormat::Png);
                    let a = whole.raster((u32::from(z), x, y), tile, png).unwrap();
                    let b = windows.raster((u32::from(z), x, y), tile, png).unwrap();
                    assert!(
                        a.image == b.image,
                        "tile {z}/{x}/{y} ({tile} px, {enc:?}) differs"
                    );
                    assert_eq!((a.nodata, a.level), (b.nodata, b.level));
                    compared += 1;
                }
            }
        }
    }
    compared + same_meshes(repo, &whole, &windows)
}

/// Every available quantized-mesh tile, with normals and metadata, of both tilers and of one
/// sharing no work between tiles. The two sharing tilers are asked in opposite orders (each
/// tile's neighbours' shared work made by different neighbours first), and asked twice (the
/// second answer from the tiles kept).
fn same_meshes(repo: &Repository, whole: &Tiler, windows: &Tiler) -> usize {
    let alone = Tiler::new(repo.head(), repo.to_encoded().unwrap())
        .unwrap()
        .without_sharing();
    alone.surface().unwrap();
    let tiles = whole.available().tiles();
    let zxy = |t: &cbdam_tiles::TileId| (u32::from(t.z), t.x, t.y);
    let backwards: Vec<_> = tiles
        .iter()
        .rev()
        .map(|t| windows.mesh(zxy(t), true, true))
        .collect();
    for (t, b) in tiles.iter().zip(backwards.into_iter().rev()) {
        let zxy = zxy(t);
        let (a, b) = (whole.mesh(zxy, true, true).unwrap(), b.unwrap());
        let c = alone.mesh(zxy, true, true).unwrap();
        assert!(
            a.gzipped == c.gzipped,
            "mesh tile {zxy:?} differs from the unshared one"
        );
        assert!(
            b.gzipped == c.gzipped,
            "window mesh tile {zxy:?} differs from the unshared one"
        );
        assert_eq!((a.level, a.clamped), (b.level, 0));
        assert_eq!(
            (a.deviation, a.over_threshold),
            (c.deviation, c.over_threshold)
        );
        let again = whole.mesh(zxy, true, true).unwrap();
        assert!(
            std::sync::Arc::ptr_eq(&again, &a),
            "mesh tile {zxy:?} asked again is made again, not the one kept"
        );
        assert!(
            gunzip(&a.gzipped) == a.bytes() && a.bytes().len() > 88,
            "mesh tile {zxy:?}: its bytes are not its gzip's"
        );
    }
    tiles.len()
}

#[test]
fn window_tiles_are_the_whole_surfaces_tiles_on_a_planet() {
    let plan = QuantPlan::new(0.5, Some(0.5), -2000.0, 2000.0).unwrap();
    let (n, k) = (9usize, 4u32);
    let side = ((n - 1) << k) as f64;
    let grid = PlanetGrid::from_fn(n, k, |p| {
        let (s, t) = (p.x as f64 / side, p.y as f64 / side);
        let h = 300.0 * f64::from(p.face) - 500.0 + 400.0 * (9.0 * s).sin() * (7.0 * t).cos();
        Some(((h - plan.offset) / plan.unit).round() as i32)
    })
    .unwrap();
    let opts = EncodeOptions {
        n,
        ..EncodeOptions::default()
    };
    let enc = encode_planet(&grid, plan.quantizer, &opts).unwrap();
    let repo = Repository::from_bytes(serialize(&enc, &plan, None, None).unwrap()).unwrap();
    let compared = same_tiles(&repo);
    assert!(compared >= 40, "only {compared} tiles compared");
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

/// Cold mesh tiles asked by 8 threads at once, each in its own order, read their group's window
/// (decoded once a group, not once a tile) and are byte for byte the tiles of a tiler sharing
/// nothing; so are those of a tiler keeping no window, and of one allowed to wait for the whole
/// surface (a small one: it decodes no window at all).
#[test]
fn cold_mesh_tiles_share_their_groups_window_and_keep_their_bytes() {
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
    let tiler = |cache: usize, whole: bool| {
        Tiler::new(repo.head(), repo.to_encoded().unwrap())
            .unwrap()
            .with_memory(cache, whole)
    };
    let alone = Tiler::new(repo.head(), repo.to_encoded().unwrap())
        .unwrap()
        .without_sharing();
    alone.surface().unwrap();
    let tiles = alone.available().tiles();
    let zxy = |t: &cbdam_tiles::TileId| (u32::from(t.z), t.x, t.y);
    let shift = cbdam_tiles::tiler::GROUP_SHIFT;
    let mut groups: Vec<_> = (tiles.iter())
        .map(|t| (t.z, t.x >> shift, t.y >> shift))
        .collect();
    groups.sort();
    groups.dedup();
    for (cache, whole) in [(64 << 20, false), (0, false), (64 << 20, true)] {
        let cold = tiler(cache, whole);
        std::thread::scope(|s| {
            for k in 0..8 {
                let (cold, tiles, alone) = (&cold, &tiles, &alone);
                s.spawn(move || {
                    for i in 0..tiles.len() {
                        let t = zxy(&tiles[(i * 7 + k * 5) % tiles.len()]);
                        let (a, b) = (alone.mesh(t, true, true), cold.mesh(t, true, true));
                        assert!(
                            a.unwrap().gzipped == b.unwrap().gzipped,
                            "cold mesh tile {t:?} (cache {cache}, whole {whole}) differs"
                        );
                    }
                });
            }
        });
        let decodes = cold.windows().decodes();
        match (cache, whole) {
            (0, _) => assert_eq!(cold.windows().bytes(), 0, "a window kept past the bound"),
            (_, true) => assert_eq!(decodes, 0, "a window decoded beside the whole surface"),
            _ => assert!(
                (1..=groups.len()).contains(&decodes),
                "{decodes} windows decoded for {} tiles in {} groups",
                tiles.len(),
                groups.len()
            ),
        }
    }
    assert!(
        groups.len() < tiles.len(),
        "{} tiles, {} groups",
        tiles.len(),
        groups.len()
    );
}
