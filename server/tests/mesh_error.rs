//! The error quantized-mesh tiles state between their vertices, checked with the tests' own
//! decoder (`quantized_mesh.rs`) against the repository level each tile samples, decoded here
//! with the codec's hierarchy walk (not the tiles crate): at random points of several tiles of
//! several levels, on a UTM plane and on a planet, the mesh is within the level's stated
//! triangulation threshold plus half the height step; neighbours share identical edges.

use cbdam_codec::geodesy::LatLon;
use cbdam_codec::geodesy::cube_map::lat_lon_to_face_st;
use cbdam_codec::hierarchy::{
    EncodeOptions, LevelRaster, LevelSample, PlanetGrid, encode_planet, walk_all_with_validity,
};
use cbdam_codec::quant::QuantPlan;
use cbdam_codec::repository::{Repository, serialize};
use serde_json::Value;

use crate::quantized_mesh::{ACCEPT_ALL, Qm, check_tile, edge, fetch, listed, tile_at};
use crate::tiles::{get_json, serve, utm_dem};
use crate::util::Running;

/// One level of a repository, decoded whole, and its quantization.
struct Level {
    raster: LevelRaster,
    plan: QuantPlan,
    /// A plane's samples, columns and rows (`None`: a planet).
    plane: Option<(f64, f64)>,
}

impl Level {
    fn of(repo: &Repository, level: u8) -> Level {
        let encoded = repo.to_encoded().unwrap();
        let domain = encoded.params.domain;
        let (w, h) = domain.data().size();
        let rects: Vec<_> = (0..domain.faces())
            .map(|f| (f, (0, 0, w as i64 - 1, h as i64 - 1)))
            .collect();
        let mut raster = LevelRaster::new(&domain, level, &rects).unwrap();
        walk_all_with_validity(&encoded, |id, grid, valid| {
            if id.level == level {
                raster.put_diamond(&domain, id, grid, valid);
            }
        })
        .unwrap();
        Level {
            raster,
            plan: *repo.head().plan(),
            plane: (domain.faces() == 1).then_some((w as f64, h as f64)),
        }
    }

    /// The level's surface at lattice `(x, y)` of `face`, metres, where it holds data (on a
    /// plane, up to half a sample beyond its edge samples).
    fn at(&self, face: u8, x: f64, y: f64) -> Option<f64> {
        if let Some((w, h)) = self.plane
            && (!(-0.5..=w - 0.5).contains(&x) || !(-0.5..=h - 0.5).contains(&y))
        {
            return None;
        }
        match self.raster.sample(face, x, y) {
            LevelSample::Value(u) => Some(self.plan.offset + u * self.plan.unit),
            _ => None,
        }
    }
}

/// A tile's vertices at their 64-cell grid positions (where the server took their heights).
fn grid_vertices(t: &Qm) -> Vec<(f64, f64, f64)> {
    let cell = |q: u16| (f64::from(q) * 64.0 / 32767.0).round();
    (0..t.u.len())
        .map(|k| (cell(t.u[k]), cell(t.v[k]), t.height(k)))
        .collect()
}

/// The mesh's height at grid position `(gx, gy)` (0…64 across the tile), and its triangle's
/// vertices.
fn mesh_at(t: &Qm, vertices: &[(f64, f64, f64)], gx: f64, gy: f64) -> Option<(f64, [usize; 3])> {
    for tri in t.triangles.chunks_exact(3) {
        let k = [tri[0] as usize, tri[1] as usize, tri[2] as usize];
        let [a, b, c] = k.map(|k| vertices[k]);
        let det = (b.0 - a.0) * (c.1 - a.1) - (b.1 - a.1) * (c.0 - a.0);
        let l1 = ((gx - a.0) * (c.1 - a.1) - (gy - a.1) * (c.0 - a.0)) / det;
        let l2 = ((b.0 - a.0) * (gy - a.1) - (b.1 - a.1) * (gx - a.0)) / det;
        let l0 = 1.0 - l1 - l2;
        if l0 >= -1e-12 && l1 >= -1e-12 && l2 >= -1e-12 {
            return Some((l0 * a.2 + l1 * b.2 + l2 * c.2, k));
        }
    }
    None
}

/// Where the repository has data (a latitude / longitude): a plane's vertices outside it stand
/// at 0 m, and the triangles reaching them are not compared.
pub(crate) type HasData<'a> = &'a dyn Fn(f64, f64) -> bool;

/// Compares tile `zxy`'s mesh at `points` random grid positions with `surface` (metres at a
/// latitude / longitude, `None`: not compared) within `bound`; points whose triangle has a
/// vertex without data are skipped. Returns the largest difference and how many compared.
pub(crate) fn compare_mesh(
    t: &Qm,
    (z, x, y): (u32, u32, u32),
    (surface, has_data): (&dyn Fn(f64, f64) -> Option<f64>, HasData<'_>),
    bound: f64,
    points: usize,
) -> (f64, usize) {
    let size = 180.0 / f64::from(1u32 << z);
    let lat_lon = |gx: f64, gy: f64| {
        let lat = -90.0 + (f64::from(y) + gy / 64.0) * size;
        (lat, -180.0 + (f64::from(x) + gx / 64.0) * size)
    };
    let vertices = grid_vertices(t);
    let mut seed = 0x2545_F491_4F6C_DD1Du64 ^ u64::from(z * 1_000_003 + x * 7 + y);
    let mut random = || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        (seed >> 11) as f64 / (1u64 << 53) as f64 * 64.0
    };
    let (mut worst, mut compared) = (0.0f64, 0);
    for _ in 0..points {
        let (gx, gy) = (random(), random());
        let (mesh, corners) = mesh_at(t, &vertices, gx, gy).expect("the triangles cover the tile");
        let vertex_data = |k: usize| {
            let (lat, lon) = lat_lon(vertices[k].0, vertices[k].1);
            has_data(lat, lon)
        };
        let (lat, lon) = lat_lon(gx, gy);
        let Some(expected) = surface(lat, lon) else {
            continue;
        };
        if !corners.iter().all(|&k| vertex_data(k)) {
            continue;
        }
        let d = (mesh - expected).abs();
        assert!(
            d <= bound + 1e-6,
            "tile {z}/{x}/{y} at grid ({gx:.3}, {gy:.3}): mesh {mesh} m, the repository's \
             level {expected} m, bound {bound} m"
        );
        worst = worst.max(d);
        compared += 1;
    }
    (worst, compared)
}

/// The bound at level `z`: CesiumJS's geometric error for a level-`z` tile of the geographic
/// scheme (`getEstimatedLevelZeroGeometricErrorForAHeightmap(WGS84, 65, 0.25) / 2^z`), which
/// the stated triangulation threshold plus half the height step must not pass.
fn level_bound(layer: &Value, z: u32) -> f64 {
    let cesium =
        6_378_137.0 * 2.0 * std::f64::consts::PI * 0.25 / (65.0 * 2.0) / f64::from(1u32 << z);
    let c = &layer["cbdam"];
    let stated = c["triangulation_threshold_m"][z as usize].as_f64().unwrap()
        + 0.5 * c["height_step_m"].as_f64().unwrap();
    assert!(
        stated <= cesium + 1e-9,
        "level {z}: {stated} m stated, CesiumJS's {cesium} m"
    );
    cesium
}

/// Fetches `zxy` and its east and north neighbours (where listed), checks each tile and the
/// shared edges; returns the tile.
async fn tile_and_neighbours(s: &Running, name: &str, layer: &Value, zxy: (u32, u32, u32)) -> Qm {
    let t = fetch(s, name, zxy, ACCEPT_ALL).await;
    check_tile(&t, zxy);
    let (z, x, y) = zxy;
    let (east, north) = ((z, (x + 1) % (2u32 << z), y), (z, x, y + 1));
    if listed(layer, east) {
        let e = fetch(s, name, east, ACCEPT_ALL).await;
        check_tile(&e, east);
        assert_eq!(edge(&t, 2), edge(&e, 0), "{zxy:?}: the east edge differs");
    }
    if y + 1 < (1 << z) && listed(layer, north) {
        let n = fetch(s, name, north, ACCEPT_ALL).await;
        check_tile(&n, north);
        assert_eq!(edge(&t, 3), edge(&n, 1), "{zxy:?}: the north edge differs");
    }
    t
}

#[tokio::test]
async fn plane_meshes_keep_the_level_error_between_vertices() {
    let dem = utm_dem();
    let repo = dem.repository();
    let s = serve(vec![("d", dem.repository())]).await;
    let layer = get_json(&s, "/v1/repos/d/quantized-mesh/layer.json").await;
    let max = layer["maxzoom"].as_u64().unwrap() as u32;
    let b: Vec<f64> = serde_json::from_value(layer["bounds"].clone()).unwrap();
    let (lat, lon) = (0.5 * (b[1] + b[3]), 0.5 * (b[0] + b[2]));
    let mut refined = 0;
    for z in [max, max - 1, max - 2, max - 3] {
        let zxy = tile_at(z, lat, lon);
        let t = tile_and_neighbours(&s, "d", &layer, zxy).await;
        let level = Level::of(&repo, t.level);
        let surface = |lat: f64, lon: f64| {
            let (x, y) = dem.lattice(lat, lon);
            level.at(0, x, y)
        };
        let bound = level_bound(&layer, z);
        let has_data = |lat: f64, lon: f64| surface(lat, lon).is_some();
        let (worst, compared) = compare_mesh(&t, zxy, (&surface, &has_data), bound, 20_000);
        assert!(compared > 300, "{zxy:?}: only {compared} points compared");
        assert_eq!(t.over_threshold, 0, "{zxy:?}");
        // The cut is adaptive: fewer vertices than the whole grid wherever it can be.
        assert!(t.u.len() < 65 * 65, "{zxy:?}: {} vertices", t.u.len());
        refined += usize::from(t.u.len() > 4 * 65);
        eprintln!(
            "{zxy:?}: {} vertices, worst {worst:.3} m of {bound:.3} m",
            t.u.len()
        );
    }
    assert!(
        refined >= 2,
        "the threshold bound the cut at {refined} levels only"
    );
    s.stop().await;
}

/// A planet with 30 km relief (so that CesiumJS's level error, 77 km / 2^z, binds at the few
/// levels a small planet has).
fn relief_planet() -> Repository {
    let plan = QuantPlan::new(0.5, Some(0.5), -40_000.0, 40_000.0).unwrap();
    let (n, k) = (9usize, 4u32);
    let side = ((n - 1) << k) as f64;
    let grid = PlanetGrid::from_fn(n, k, |p| {
        let (s, t) = (p.x as f64 / side, p.y as f64 / side);
        let h = 3000.0 * f64::from(p.face) + 30_000.0 * (13.0 * s).sin() * (9.0 * t).cos();
        Some(((h - plan.offset) / plan.unit).round() as i32)
    })
    .unwrap();
    let opts = EncodeOptions {
        n,
        ..EncodeOptions::default()
    };
    let enc = encode_planet(&grid, plan.quantizer, &opts).unwrap();
    Repository::from_bytes(serialize(&enc, &plan, None, None).unwrap()).unwrap()
}

#[tokio::test]
async fn planet_meshes_keep_the_level_error_between_vertices() {
    let repo = relief_planet();
    let side = repo
        .to_encoded()
        .unwrap()
        .params
        .domain
        .cube()
        .unwrap()
        .side() as f64;
    let s = serve(vec![("p", relief_planet())]).await;
    let layer = get_json(&s, "/v1/repos/p/quantized-mesh/layer.json").await;
    let max = layer["maxzoom"].as_u64().unwrap() as u32;
    let mut refined = 0;
    for z in 0..=max {
        for (lat, lon) in [(20.0, 10.0), (-40.0, 100.0), (70.0, -60.0)] {
            let zxy = tile_at(z, lat, lon);
            let t = tile_and_neighbours(&s, "p", &layer, zxy).await;
            let level = Level::of(&repo, t.level);
            let surface = |lat: f64, lon: f64| {
                let (face, fs, ft) = lat_lon_to_face_st(LatLon { lat, lon });
                level.at(face, fs * side, ft * side)
            };
            let bound = level_bound(&layer, z);
            let everywhere = |_: f64, _: f64| true;
            let (worst, compared) = compare_mesh(&t, zxy, (&surface, &everywhere), bound, 3000);
            assert!(compared > 2000, "{zxy:?}: only {compared} points compared");
            assert_eq!(t.over_threshold, 0, "{zxy:?}");
            refined += usize::from(t.u.len() > 16);
            eprintln!(
                "{zxy:?}: {} vertices, worst {worst:.1} m of {bound:.1} m",
                t.u.len()
            );
        }
    }
    assert!(
        refined >= 3,
        "the threshold bound the cut in {refined} tiles only"
    );
    s.stop().await;
}
