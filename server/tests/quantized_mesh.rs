//! Quantized-mesh tiles over real HTTP on 127.0.0.1, read back by a decoder written here from
//! the quantized-mesh-1.0 specification (not the encoder's code): header, zig-zag delta
//! vertices, high-water-mark indices, edge lists and extensions; every vertex inside the
//! header's ranges and bounding sphere, the edge lists exactly the vertices on the tile's
//! borders, neighbours' shared edges identical, heights within the stated bound of the input.

use std::io::Read;

use cbdam_codec::geodesy::Geodetic;
use cbdam_codec::geodesy::LatLon;
use cbdam_codec::geodesy::cube_map::lat_lon_to_face_st;
use cbdam_codec::hierarchy::{EncodeOptions, PlanetGrid, encode_planet};
use cbdam_codec::quant::QuantPlan;
use cbdam_codec::repository::{Repository, serialize};
use serde_json::Value;

use crate::mesh_error::compare_mesh;
use crate::tiles::{Dem, get_json, serve, utm_dem};
use crate::util::{Running, client, error_body};

pub(crate) const ACCEPT_ALL: &str = "application/vnd.quantized-mesh;extensions=octvertexnormals-metadata,application/octet-stream;q=0.9";

/// One decoded tile.
#[derive(Debug)]
pub(crate) struct Qm {
    pub(crate) min_h: f64,
    pub(crate) max_h: f64,
    sphere: ([f64; 3], f64),
    occlusion: [f64; 3],
    pub(crate) u: Vec<u16>,
    pub(crate) v: Vec<u16>,
    h: Vec<u16>,
    pub(crate) triangles: Vec<u32>,
    /// West, south, east, north.
    edges: [Vec<u32>; 4],
    extensions: Vec<(u8, Vec<u8>)>,
    /// The response's `cbdam-level` and `cbdam-triangles-over-threshold` headers.
    pub(crate) level: u8,
    pub(crate) over_threshold: usize,
}

struct Reader<'a> {
    b: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn take(&mut self, n: usize) -> &[u8] {
        assert!(
            self.at + n <= self.b.len(),
            "tile truncated at byte {}",
            self.at
        );
        self.at += n;
        &self.b[self.at - n..self.at]
    }
    fn f64(&mut self) -> f64 {
        f64::from_le_bytes(self.take(8).try_into().unwrap())
    }
    fn f32(&mut self) -> f64 {
        f64::from(f32::from_le_bytes(self.take(4).try_into().unwrap()))
    }
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.take(4).try_into().unwrap())
    }
    fn u16(&mut self) -> u16 {
        u16::from_le_bytes(self.take(2).try_into().unwrap())
    }
    fn index(&mut self, wide: bool) -> u32 {
        if wide {
            self.u32()
        } else {
            u32::from(self.u16())
        }
    }
    fn xyz(&mut self) -> [f64; 3] {
        [self.f64(), self.f64(), self.f64()]
    }
}

/// Reads a quantized-mesh-1.0 tile.
fn read_qm(b: &[u8]) -> Qm {
    let mut r = Reader { b, at: 0 };
    let _centre = r.xyz();
    let (min_h, max_h) = (r.f32(), r.f32());
    let sphere = (r.xyz(), r.f64());
    let occlusion = r.xyz();
    assert_eq!(r.at, 88);
    let n = r.u32() as usize;
    let mut arrays = [vec![], vec![], vec![]];
    for a in &mut arrays {
        let mut value = 0i32;
        for _ in 0..n {
            let zz = i32::from(r.u16());
            value += (zz >> 1) ^ -(zz & 1);
            a.push(u16::try_from(value).expect("a quantized value within 0…65535"));
        }
    }
    let [u, v, h] = arrays;
    let wide = n > 65_536;
    while !r.at.is_multiple_of(if wide { 4 } else { 2 }) {
        r.take(1);
    }
    let triangle_count = r.u32() as usize;
    let mut highest = 0u32;
    let triangles = (0..3 * triangle_count)
        .map(|_| {
            let code = r.index(wide);
            assert!(code <= highest, "high-water mark exceeded");
            let k = highest - code;
            if code == 0 {
                highest += 1;
            }
            k
        })
        .collect();
    let edges = std::array::from_fn(|_| {
        let count = r.u32() as usize;
        (0..count).map(|_| r.index(wide)).collect()
    });
    let mut extensions = Vec::new();
    while r.at < b.len() {
        let id = r.take(1)[0];
        let len = r.u32() as usize;
        extensions.push((id, r.take(len).to_vec()));
    }
    Qm {
        min_h,
        max_h,
        sphere,
        occlusion,
        u,
        v,
        h,
        triangles,
        edges,
        extensions,
        level: 0,
        over_threshold: 0,
    }
}

impl Qm {
    /// Latitude and longitude of vertex `k` of tile `z/x/y` at the 64-cell grid position its
    /// u/v rounds (where the server took its height; u/v are that position quantized, at most
    /// 1/65 534 of the tile off).
    fn grid_lat_lon(&self, k: usize, (z, x, y): (u32, u32, u32)) -> (f64, f64) {
        let size = 180.0 / f64::from(1u32 << z);
        let (w, s) = (-180.0 + f64::from(x) * size, -90.0 + f64::from(y) * size);
        let cell = |q: u16| (f64::from(q) * 64.0 / 32767.0).round() / 64.0;
        (s + cell(self.v[k]) * size, w + cell(self.u[k]) * size)
    }
    pub(crate) fn height(&self, k: usize) -> f64 {
        self.min_h + f64::from(self.h[k]) / 32767.0 * (self.max_h - self.min_h)
    }
    /// Latitude and longitude of vertex `k` of tile `z/x/y`.
    fn lat_lon(&self, k: usize, (z, x, y): (u32, u32, u32)) -> (f64, f64) {
        let size = 180.0 / f64::from(1u32 << z);
        let (w, s) = (-180.0 + f64::from(x) * size, -90.0 + f64::from(y) * size);
        (
            s + f64::from(self.v[k]) / 32767.0 * size,
            w + f64::from(self.u[k]) / 32767.0 * size,
        )
    }
}

/// Fetches and decodes tile `z/x/y`, checking the transfer headers; `accept` asks for
/// extensions.
pub(crate) async fn fetch(s: &Running, name: &str, (z, x, y): (u32, u32, u32), accept: &str) -> Qm {
    let url = s.url(&format!(
        "/v1/repos/{name}/quantized-mesh/{z}/{x}/{y}.terrain?v=1.0.0"
    ));
    let r = client()
        .get(&url)
        .header("accept", accept)
        .header("accept-encoding", "gzip")
        .header("origin", "http://example.org")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200, "{url}");
    let h = r.headers().clone();
    assert_eq!(h["content-encoding"], "gzip");
    // `Accept` picks the extensions, `Accept-Encoding` the gzip: caches key on both.
    let vary = h["vary"].to_str().unwrap().to_ascii_lowercase();
    let tokens: Vec<&str> = vary.split(',').map(str::trim).collect();
    assert!(
        tokens.contains(&"accept") && tokens.contains(&"accept-encoding"),
        "{vary}"
    );
    assert_eq!(h["access-control-allow-origin"], "*");
    let etag = h["etag"].clone();
    let mut raw = Vec::new();
    flate2::read::GzDecoder::new(&r.bytes().await.unwrap()[..])
        .read_to_end(&mut raw)
        .unwrap();
    // The same tile again, revalidated.
    let again = client()
        .get(&url)
        .header("accept", accept)
        .header("accept-encoding", "gzip")
        .header("if-none-match", etag)
        .send()
        .await
        .unwrap();
    assert_eq!(again.status(), 304);
    // Without gzip: the same bytes, unpacked from the tile kept.
    let plain = client().get(&url).header("accept", accept).send().await;
    let plain = plain.unwrap();
    assert!(plain.headers().get("content-encoding").is_none(), "{url}");
    assert!(
        plain.bytes().await.unwrap() == raw,
        "{url}: the bytes without gzip differ"
    );
    assert_eq!(h["cbdam-clamped-vertices"], "0", "{url}: vertices clamped");
    let header = |name: &str| h[name].to_str().unwrap().parse::<usize>().unwrap();
    Qm {
        level: header("cbdam-level") as u8,
        over_threshold: header("cbdam-triangles-over-threshold"),
        ..read_qm(&raw)
    }
}

/// Whether `layer.json`'s `available` lists tile `z/x/y`.
pub(crate) fn listed(layer: &Value, (z, x, y): (u32, u32, u32)) -> bool {
    let at = |r: &Value, k: &str| r[k].as_u64().unwrap() as u32;
    layer["available"][z as usize]
        .as_array()
        .unwrap()
        .iter()
        .any(|r| {
            (at(r, "startX")..=at(r, "endX")).contains(&x)
                && (at(r, "startY")..=at(r, "endY")).contains(&y)
        })
}

/// What holds for every tile by itself.
pub(crate) fn check_tile(t: &Qm, zxy: (u32, u32, u32)) {
    let n = t.u.len();
    assert!(n > 0 && !t.triangles.is_empty());
    assert!(t.min_h <= t.max_h);
    for k in 0..n {
        assert!(
            t.u[k] <= 32767 && t.v[k] <= 32767 && t.h[k] <= 32767,
            "vertex {k}"
        );
        let (lat, lon) = t.lat_lon(k, zxy);
        let p = Geodetic::new(lat, lon, t.height(k)).to_ecef();
        let (c, radius) = t.sphere;
        let d = ((p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) + (p[2] - c[2]).powi(2)).sqrt();
        assert!(
            d <= radius * (1.0 + 1e-9) + 1e-3,
            "vertex {k} outside the bounding sphere"
        );
    }
    for tri in t.triangles.chunks_exact(3) {
        assert!(tri.iter().all(|&k| (k as usize) < n));
        let [a, b, c] = [tri[0], tri[1], tri[2]].map(|k| {
            let k = k as usize;
            (f64::from(t.u[k]), f64::from(t.v[k]))
        });
        let cross = (b.0 - a.0) * (c.1 - a.1) - (b.1 - a.1) * (c.0 - a.0);
        assert!(cross > 0.0, "triangle {tri:?} is not counter-clockwise");
    }
    let on = |f: &dyn Fn(usize) -> bool| -> Vec<u32> {
        (0..n).filter(|&k| f(k)).map(|k| k as u32).collect()
    };
    let expected = [
        on(&|k| t.u[k] == 0),
        on(&|k| t.v[k] == 0),
        on(&|k| t.u[k] == 32767),
        on(&|k| t.v[k] == 32767),
    ];
    for (side, (got, want)) in t.edges.iter().zip(&expected).enumerate() {
        let mut got = got.clone();
        got.sort_unstable();
        assert_eq!(&got, want, "edge list {side}");
    }
    if zxy.0 >= 1 {
        let m = t.occlusion.iter().map(|c| c * c).sum::<f64>().sqrt();
        assert!(
            m.is_finite() && m >= 1.0,
            "horizon occlusion point {:?}",
            t.occlusion
        );
    }
}

/// The `(v, height step)` pairs of one edge list, sorted.
pub(crate) fn edge(t: &Qm, side: usize) -> Vec<(u16, u16)> {
    let mut e: Vec<(u16, u16)> = t.edges[side]
        .iter()
        .map(|&k| {
            let k = k as usize;
            if side.is_multiple_of(2) {
                (t.v[k], t.h[k])
            } else {
                (t.u[k], t.h[k])
            }
        })
        .collect();
    e.sort_unstable();
    e
}

/// The JSON of a tile's metadata extension (id 4: a u32 length, then the JSON).
fn metadata(t: &Qm) -> Value {
    let (_, bytes) = t
        .extensions
        .iter()
        .find(|e| e.0 == 4)
        .expect("a metadata extension");
    let len = u32::from_le_bytes(bytes[..4].try_into().unwrap()) as usize;
    assert_eq!(bytes.len(), 4 + len);
    serde_json::from_slice(&bytes[4..]).unwrap()
}

/// The tile of level `z` holding a geodetic point.
pub(crate) fn tile_at(z: u32, lat: f64, lon: f64) -> (u32, u32, u32) {
    let size = 180.0 / f64::from(1u32 << z);
    (
        z,
        ((lon + 180.0) / size) as u32,
        ((lat + 90.0) / size) as u32,
    )
}

/// Compares every vertex with the input where it has data around; returns how many.
fn check_heights(t: &Qm, zxy: (u32, u32, u32), dem: &Dem, bound: f64) -> usize {
    let mut compared = 0;
    for k in 0..t.u.len() {
        let (lat, lon) = t.lat_lon(k, zxy);
        if let Ok(expected) = dem.bilinear(lat, lon) {
            let got = t.height(k);
            assert!(
                (got - expected).abs() <= bound + 1e-6,
                "vertex {k} of {zxy:?}: {got} m against the input's {expected} m, bound {bound}"
            );
            compared += 1;
        }
    }
    compared
}

#[tokio::test]
async fn quantized_mesh_tiles_decode_and_hold_the_input() {
    let dem = utm_dem();
    let s = serve(vec![("d", dem.repository())]).await;
    let layer = get_json(&s, "/v1/repos/d/quantized-mesh/layer.json").await;
    assert_eq!(layer["format"], "quantized-mesh-1.0");
    assert_eq!(layer["scheme"], "tms");
    assert_eq!(layer["projection"], "EPSG:4326");
    assert_eq!(layer["tiles"][0], "{z}/{x}/{y}.terrain?v={version}");
    assert_eq!(layer["tilejson"], "2.1.0");
    let extensions = serde_json::json!(["octvertexnormals", "metadata"]);
    assert_eq!(layer["extensions"], extensions);
    assert!(layer["attribution"].as_str().is_some_and(|a| !a.is_empty()));
    // A plane records no vertical datum: served as stored, and `layer.json` says so.
    assert_eq!(layer["cbdam"]["height_datum"], "unknown");
    assert_eq!(layer["cbdam"]["geoid_error_m"], 0.0);
    // CesiumJS reads the metadata extension's availability only with this set.
    assert_eq!(layer["metadataAvailability"], 1);
    assert_eq!(
        layer["available"][0],
        serde_json::json!([{"startX": 0, "startY": 0, "endX": 1, "endY": 0}]),
        "both root tiles"
    );
    let max = layer["maxzoom"].as_u64().unwrap() as u32;
    assert_eq!(layer["available"].as_array().unwrap().len() as u32, max + 1);
    let bound = layer["cbdam"]["vertex_bound_m"].as_f64().unwrap();
    let b: Vec<f64> = serde_json::from_value(layer["bounds"].clone()).unwrap();
    let (lat, lon) = (0.5 * (b[1] + b[3]), 0.5 * (b[0] + b[2]));
    let a = tile_at(max, lat, lon);
    // The neighbour east, or west when the data ends there.
    let in_range = |x: u32| listed(&layer, (max, x, a.2));
    let (west, east) = if in_range(a.1 + 1) {
        (a, (max, a.1 + 1, a.2))
    } else {
        ((max, a.1 - 1, a.2), a)
    };
    assert!(
        in_range(west.1) && in_range(east.1),
        "two neighbouring tiles hold data"
    );
    let (tw, te) = (
        fetch(&s, "d", west, ACCEPT_ALL).await,
        fetch(&s, "d", east, ACCEPT_ALL).await,
    );
    check_tile(&tw, west);
    check_tile(&te, east);
    assert_eq!(
        edge(&tw, 2),
        edge(&te, 0),
        "the shared edge differs between neighbours"
    );
    let compared = check_heights(&tw, west, &dem, bound) + check_heights(&te, east, &dem, bound);
    assert!(compared > 300, "only {compared} vertices compared");
    // Extensions: normals (2 bytes a vertex) and metadata, as asked for.
    let ids: Vec<u8> = tw.extensions.iter().map(|e| e.0).collect();
    assert_eq!(ids, [1, 4]);
    assert_eq!(tw.extensions[0].1.len(), 2 * tw.u.len());
    let meta = metadata(&tw);
    // At maxzoom there is no level below to list.
    assert_eq!(meta["available"], serde_json::json!([]));
    assert_eq!(meta["cbdam"]["vertex_bound_m"].as_f64().unwrap(), bound);
    let plain = fetch(&s, "d", west, "application/octet-stream").await;
    assert!(plain.extensions.is_empty(), "no extension unless asked for");
    // A coarser level comes from a coarser repository level.
    let coarse = tile_at(max - 3, lat, lon);
    let tc = fetch(&s, "d", coarse, ACCEPT_ALL).await;
    check_tile(&tc, coarse);
    // Its metadata lists the children that hold data: those `available` lists one level down.
    let meta = metadata(&tc);
    let children = meta["available"][0].as_array().unwrap();
    assert!(!children.is_empty());
    for c in children {
        let (x, y) = (c["startX"].as_u64().unwrap(), c["startY"].as_u64().unwrap());
        assert!(
            listed(&layer, (coarse.0 + 1, x as u32, y as u32)),
            "child {c}"
        );
    }
    // A root tile far from the data exists (CesiumJS asks for both) and lies at 0 m.
    let far = fetch(&s, "d", (0, 0, 0), ACCEPT_ALL).await;
    check_tile(&far, (0, 0, 0));
    assert!((0..far.u.len()).all(|k| far.height(k).abs() <= 1.0));
    s.stop().await;
}

#[tokio::test]
async fn quantized_mesh_errors() {
    let s = serve(vec![("d", utm_dem().repository())]).await;
    let layer = get_json(&s, "/v1/repos/d/quantized-mesh/layer.json").await;
    let max = layer["maxzoom"].as_u64().unwrap();
    let get = |path: String| client().get(s.url(&path)).send();
    let base = "/v1/repos/d/quantized-mesh";
    for (path, status) in [
        (format!("{base}/{max}/0/0.terrain"), 404),
        (format!("{base}/{}/0/0.terrain", max + 1), 404),
        (format!("{base}/1/0/2.terrain"), 400),
        (format!("{base}/1/4/0.terrain"), 400),
        (format!("{base}/1/a/0.terrain"), 400),
        (format!("{base}/1/0/0.png"), 400),
        (format!("{base}/99/0/0.terrain"), 400),
        (
            "/v1/repos/nope/quantized-mesh/0/0/0.terrain".to_string(),
            404,
        ),
        ("/v1/repos/d/terrarium/0/0/0.png?tile=300".to_string(), 400),
        ("/v1/repos/d/terrarium/2/4/0.png".to_string(), 400),
        ("/v1/repos/d/terrarium/5/0/0.png".to_string(), 404),
        (format!("/v1/repos/d/terrain-rgb/{}/0/0.png", max + 10), 404),
    ] {
        let msg = error_body(get(path.clone()).await.unwrap(), status).await;
        assert!(!msg.is_empty(), "{path}");
    }
    s.stop().await;
}

#[tokio::test]
async fn other_crss_are_refused_by_name() {
    let mut dem = utm_dem();
    dem.georef.epsg = Some(3857);
    let s = serve(vec![("d", dem.repository())]).await;
    for path in [
        "quantized-mesh/layer.json",
        "terrarium/tiles.json",
        "terrain-rgb/0/0/0.png",
    ] {
        let r = client()
            .get(s.url(&format!("/v1/repos/d/{path}")))
            .send()
            .await
            .unwrap();
        let msg = error_body(r, 404).await;
        assert!(msg.contains("EPSG:3857"), "{path}: {msg}");
    }
    s.stop().await;
}

/// A small planet whose heights are a smooth function of the face point.
fn planet() -> (Repository, QuantPlan, i64, impl Fn(u8, i64, i64) -> f64) {
    let plan = QuantPlan::new(0.5, Some(0.5), -2000.0, 2000.0).unwrap();
    let (n, k) = (9usize, 2u32);
    let side = ((n - 1) << k) as i64;
    let height = move |face: u8, x: i64, y: i64| -> f64 {
        let (s, t) = (x as f64 / side as f64, y as f64 / side as f64);
        300.0 * f64::from(face) - 500.0 + 400.0 * (5.0 * s).sin() * (3.0 * t).cos()
    };
    let grid = PlanetGrid::from_fn(n, k, |p| {
        Some(((height(p.face, p.x, p.y) - plan.offset) / plan.unit).round() as i32)
    })
    .unwrap();
    let opts = EncodeOptions {
        n,
        ..EncodeOptions::default()
    };
    let enc = encode_planet(&grid, plan.quantizer, &opts).unwrap();
    let repo = Repository::from_bytes(serialize(&enc, &plan, None, None).unwrap()).unwrap();
    (repo, plan, side, height)
}

#[tokio::test]
async fn planets_are_tiled_whole_with_matching_root_edges() {
    let (repo, plan, side, height) = planet();
    let s = serve(vec![("p", repo)]).await;
    let layer = get_json(&s, "/v1/repos/p/quantized-mesh/layer.json").await;
    assert_eq!(layer["available"][0][0]["endX"], 1, "two root tiles");
    let (w, e) = (
        fetch(&s, "p", (0, 0, 0), ACCEPT_ALL).await,
        fetch(&s, "p", (0, 1, 0), ACCEPT_ALL).await,
    );
    check_tile(&w, (0, 0, 0));
    check_tile(&e, (0, 1, 0));
    assert_eq!(
        edge(&w, 2),
        edge(&e, 0),
        "the root tiles differ along longitude 0"
    );
    // Terrarium pixels against the planet's own heights, bilinear on the face lattice.
    let tj = get_json(&s, "/v1/repos/p/terrarium/tiles.json").await;
    let bound = tj["cbdam"]["pixel_bound_m"].as_f64().unwrap();
    let r = client()
        .get(s.url("/v1/repos/p/terrarium/0/0/0.png"))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    let mut dec = png::Decoder::new(std::io::Cursor::new(r.bytes().await.unwrap()))
        .read_info()
        .unwrap();
    let mut buf = vec![0; dec.output_buffer_size().unwrap()];
    let info = dec.next_frame(&mut buf).unwrap();
    assert_eq!(
        info.color_type,
        png::ColorType::Rgb,
        "a planet has data everywhere"
    );
    let size = info.width as usize;
    let domain = cbdam_codec::geometry::Domain::cube_sphere(9, 2).unwrap();
    let mut compared = 0;
    for (i, p) in buf.chunks_exact(3).enumerate().step_by(7) {
        let (col, row) = ((i % size) as f64 + 0.5, (i / size) as f64 + 0.5);
        let lon = col / size as f64 * 360.0 - 180.0;
        let lat = (std::f64::consts::PI * (1.0 - 2.0 * row / size as f64))
            .sinh()
            .atan()
            .to_degrees();
        let (face, fs, ft) = lat_lon_to_face_st(LatLon { lat, lon });
        let (x, y) = (fs * side as f64, ft * side as f64);
        let (c, r0) = (
            (x.floor() as i64).min(side - 1),
            (y.floor() as i64).min(side - 1),
        );
        let (tx, ty) = (x - c as f64, y - r0 as f64);
        // The planet's value at a face-edge point is its canonical face's (`from_fn`).
        let q = |c, r| {
            let p = domain.canonical_point(face, c, r).unwrap();
            plan.metres(((height(p.face, p.x, p.y) - plan.offset) / plan.unit).round() as i32)
        };
        let expected = (1.0 - ty) * ((1.0 - tx) * q(c, r0) + tx * q(c + 1, r0))
            + ty * ((1.0 - tx) * q(c, r0 + 1) + tx * q(c + 1, r0 + 1));
        let got = f64::from(p[0]) * 256.0 + f64::from(p[1]) + f64::from(p[2]) / 256.0 - 32768.0;
        assert!(
            (got - expected).abs() <= bound + 1e-9,
            "pixel {i}: {got} against {expected}"
        );
        compared += 1;
    }
    assert!(compared > 30_000, "{compared}");
    s.stop().await;
}

/// A variable-resolution planet: samples every 4 lattice steps (a coarse input) everywhere
/// but around a hill on face 0, where every lattice point is one (an inset), so that its records
/// stop 4 levels above the finest away from the hill.
fn island_planet() -> (Repository, QuantPlan, impl Fn(u8, i64, i64) -> f64) {
    use cbdam_codec::hierarchy::Resolution;
    use cbdam_codec::hierarchy::resolution::COARSE_ONLY;
    let plan = QuantPlan::new(0.5, Some(0.5), -100.0, 2000.0).unwrap();
    let (n, k) = (17usize, 4u32);
    let side = ((n - 1) << k) as i64;
    let domain = cbdam_codec::geometry::Domain::cube_sphere(n, k).unwrap();
    let height = move |face: u8, x: i64, y: i64| -> f64 {
        let (s, t) = (x as f64 / side as f64 - 0.4, y as f64 / side as f64 - 0.6);
        let r2 = (s * s + t * t) / 0.01;
        let wave = 30.0 * (7.0 * s).sin() * (5.0 * t + f64::from(face)).cos();
        if face != 0 || r2 >= 1.0 {
            return wave;
        }
        wave + 1500.0 * (1.0 - r2).powi(2) + 80.0 * (40.0 * s).sin() * (30.0 * t).cos() * (1.0 - r2)
    };
    let class = move |p: cbdam_codec::geometry::FacePoint| {
        let (s, t) = (
            p.x as f64 / side as f64 - 0.4,
            p.y as f64 / side as f64 - 0.6,
        );
        if p.face == 0 && (s * s + t * t) < 0.02 {
            0
        } else if p.x % 4 == 0 && p.y % 4 == 0 {
            2
        } else {
            COARSE_ONLY
        }
    };
    let grid = PlanetGrid::from_fn(n, k, |p| {
        (class(p) < 32)
            .then(|| ((height(p.face, p.x, p.y) - plan.offset) / plan.unit).round() as i32)
    })
    .unwrap();
    let classes: Vec<Resolution> = (0..6u8)
        .map(|f| Resolution {
            class: (0..=side)
                .flat_map(|y| (0..=side).map(move |x| (x, y)))
                .map(|(x, y)| class(domain.canonical_point(f, x, y).unwrap()))
                .collect(),
        })
        .collect();
    let grid = grid.with_classes(classes).unwrap();
    let opts = EncodeOptions {
        n,
        ..EncodeOptions::default()
    };
    let enc = encode_planet(&grid, plan.quantizer, &opts).unwrap();
    let repo = Repository::from_bytes(serialize(&enc, &plan, None, None).unwrap()).unwrap();
    (repo, plan, height)
}

/// `available` follows the records: at `maxzoom` only the tiles over the hill exist, the
/// ocean's stop at a coarser level; listed tiles are a tree and answer 200 (decoded from face
/// windows, within the bound of the planet's heights), others 404.
#[tokio::test]
async fn available_follows_a_variable_resolution_planets_records() {
    let (repo, plan, height) = island_planet();
    let side = 256i64;
    let s = serve(vec![("p", repo)]).await;
    let layer = get_json(&s, "/v1/repos/p/quantized-mesh/layer.json").await;
    let max = layer["maxzoom"].as_u64().unwrap() as u32;
    assert!(max >= 3, "maxzoom {max}");
    let bound = layer["cbdam"]["vertex_bound_m"].as_f64().unwrap();
    let hill = cbdam_codec::geodesy::cube_map::face_st_to_lat_lon(0, 0.4, 0.6);
    let mut counts = Vec::new();
    for z in 0..=max {
        let all: Vec<(u32, u32, u32)> = (0..2u32 << z)
            .flat_map(|x| (0..1u32 << z).map(move |y| (z, x, y)))
            .collect();
        let on: Vec<_> = all.iter().copied().filter(|&t| listed(&layer, t)).collect();
        for &(z, x, y) in &on {
            if z > 0 {
                assert!(
                    listed(&layer, (z - 1, x / 2, y / 2)),
                    "{z}/{x}/{y} without its parent"
                );
            }
        }
        counts.push((on.len(), all.len()));
    }
    let (deep, total) = counts[max as usize];
    assert!(
        deep > 0 && deep * 8 < total,
        "maxzoom lists {deep} of {total} tiles"
    );
    assert_eq!(counts[0].0, 2);
    // A listed maxzoom tile over the hill: decoded, within the bound of the planet's heights.
    let near = tile_at(max, hill.lat, hill.lon);
    assert!(
        listed(&layer, near),
        "the hill's tile {near:?} is not listed"
    );
    let t = fetch(&s, "p", near, ACCEPT_ALL).await;
    check_tile(&t, near);
    // Bilinear between the planet's lattice values: the surface's, within the bound.
    let q = |face: u8, c: i64, r: i64| {
        plan.metres(((height(face, c, r) - plan.offset) / plan.unit).round() as i32)
    };
    let inset = |lat: f64, lon: f64| {
        let (face, fs, ft) = lat_lon_to_face_st(LatLon { lat, lon });
        let (x, y) = (fs * side as f64, ft * side as f64);
        let (c, r) = (x.floor() as i64, y.floor() as i64);
        // Inside the inset (its fine samples), away from its coarse surroundings.
        let (ds, dt) = (fs - 0.4, ft - 0.6);
        if face != 0 || ds * ds + dt * dt >= 0.015 {
            return None;
        }
        let (tx, ty) = (x - c as f64, y - r as f64);
        Some(
            (1.0 - ty) * ((1.0 - tx) * q(face, c, r) + tx * q(face, c + 1, r))
                + ty * ((1.0 - tx) * q(face, c, r + 1) + tx * q(face, c + 1, r + 1)),
        )
    };
    // The vertices in the inset (at this level's error, 9.6 km, perhaps none: the tile's
    // corners lie outside it).
    for k in 0..t.u.len() {
        let (lat, lon) = t.grid_lat_lon(k, near);
        if let Some(expected) = inset(lat, lon) {
            let got = t.height(k);
            assert!(
                (got - expected).abs() <= bound + 1e-6,
                "vertex {k}: {got} m against {expected} m, bound {bound}"
            );
        }
    }
    // Between the vertices: within the level's triangulation threshold more.
    let threshold = layer["cbdam"]["triangulation_threshold_m"][max as usize]
        .as_f64()
        .unwrap();
    let everywhere = |_: f64, _: f64| true;
    let (_, compared) = compare_mesh(&t, near, (&inset, &everywhere), bound + threshold, 20_000);
    assert!(compared > 1000, "{compared} points compared");
    // A maxzoom tile over the ocean is not listed, and answers 404 naming `available`.
    let ocean = tile_at(max, -60.0, -150.0);
    assert!(!listed(&layer, ocean));
    let r = client()
        .get(s.url(&format!(
            "/v1/repos/p/quantized-mesh/{}/{}/{}.terrain",
            ocean.0, ocean.1, ocean.2
        )))
        .send()
        .await
        .unwrap();
    let msg = error_body(r, 404).await;
    assert!(msg.contains("not available"), "{msg}");
    s.stop().await;
}

/// Heights of a planet at sea level everywhere (0 m orthometric), built as `cbdam build
/// --planet` records its datum, and the repository.
fn sea_level_planet(dir: &std::path::Path) -> Repository {
    use cbdam_codec::repository::{PlanetProvenance, VerticalDatum, write_planet_repository};
    let plan = QuantPlan::new(0.5, Some(0.5), -100.0, 100.0).unwrap();
    let (n, k) = (9usize, 4u32);
    let grid =
        PlanetGrid::from_fn(n, k, |_| Some((-plan.offset / plan.unit).round() as i32)).unwrap();
    let opts = EncodeOptions {
        n,
        ..EncodeOptions::default()
    };
    let enc = encode_planet(&grid, plan.quantizer, &opts).unwrap();
    let path = dir.join("sea.cbdam");
    let provenance = PlanetProvenance {
        vertical_datum: VerticalDatum::Orthometric,
        resampling_max: 0.0,
        resampling_rms: 0.0,
    };
    write_planet_repository(&path, &enc, &plan, None, &provenance).unwrap();
    Repository::open(&path).unwrap()
}

/// An orthometric repository's Cesium tiles stand on the geoid: at sea level every vertex is
/// EGM96's undulation above the ellipsoid (within the stated bound, which counts the geoid
/// grid's error), `layer.json` says so, and MapLibre's terrarium tiles stay at 0 m.
#[tokio::test]
async fn orthometric_heights_are_raised_onto_the_ellipsoid_for_cesium_only() {
    let dir = tempfile::tempdir().unwrap();
    let s = serve(vec![("p", sea_level_planet(dir.path()))]).await;
    let layer = get_json(&s, "/v1/repos/p/quantized-mesh/layer.json").await;
    assert_eq!(layer["cbdam"]["height_datum"], "ellipsoidal");
    assert_eq!(layer["cbdam"]["repository_datum"], "orthometric");
    let geoid_error = layer["cbdam"]["geoid_error_m"].as_f64().unwrap();
    assert!(geoid_error > 0.0);
    let bound = layer["cbdam"]["vertex_bound_m"].as_f64().unwrap();
    // Over the Indian Ocean's low (about −100 m) and New Guinea's high (about +70 m).
    let mut raised = 0.0f64;
    for (lat, lon) in [(5.0, 78.0), (-5.0, 145.0), (48.86, 2.35)] {
        let zxy = tile_at(2, lat, lon);
        let t = fetch(&s, "p", zxy, ACCEPT_ALL).await;
        check_tile(&t, zxy);
        for k in 0..t.u.len() {
            let (lat, lon) = t.grid_lat_lon(k, zxy);
            let n = cbdam_tiles::geoid::undulation(lat, lon);
            let got = t.height(k);
            assert!(
                (got - n).abs() <= bound - geoid_error + 1e-6,
                "vertex {k}: {got} m, N {n} m"
            );
            raised = raised.max(n.abs());
        }
    }
    // Not all at the ellipsoid: some vertex stands where EGM96 is far from it.
    assert!(raised > 20.0, "the largest |N| at a vertex is {raised} m");
    // MapLibre's terrarium tiles: heights above sea level, unconverted.
    let r = client()
        .get(s.url("/v1/repos/p/terrarium/0/0/0.png"))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    let mut dec = png::Decoder::new(std::io::Cursor::new(r.bytes().await.unwrap()))
        .read_info()
        .unwrap();
    let mut buf = vec![0; dec.output_buffer_size().unwrap()];
    dec.next_frame(&mut buf).unwrap();
    for p in buf.chunks_exact(3) {
        let h = f64::from(p[0]) * 256.0 + f64::from(p[1]) + f64::from(p[2]) / 256.0 - 32768.0;
        assert!(h.abs() <= 0.5 + 1.0 / 512.0, "terrarium pixel at {h} m");
    }
    s.stop().await;
}
