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

use crate::tiles::{Dem, get_json, serve, utm_dem};
use crate::util::{Running, client, error_body};

const ACCEPT_ALL: &str = "application/vnd.quantized-mesh;extensions=octvertexnormals-metadata,application/octet-stream;q=0.9";

/// One decoded tile.
#[derive(Debug)]
struct Qm {
    min_h: f64,
    max_h: f64,
    sphere: ([f64; 3], f64),
    occlusion: [f64; 3],
    u: Vec<u16>,
    v: Vec<u16>,
    h: Vec<u16>,
    triangles: Vec<u32>,
    /// West, south, east, north.
    edges: [Vec<u32>; 4],
    extensions: Vec<(u8, Vec<u8>)>,
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
    }
}

impl Qm {
    fn height(&self, k: usize) -> f64 {
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
async fn fetch(s: &Running, name: &str, (z, x, y): (u32, u32, u32), accept: &str) -> Qm {
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
    assert!(h["vary"].to_str().unwrap().contains("accept"));
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
    read_qm(&raw)
}

/// What holds for every tile by itself.
fn check_tile(t: &Qm, zxy: (u32, u32, u32)) {
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
fn edge(t: &Qm, side: usize) -> Vec<(u16, u16)> {
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
fn tile_at(z: u32, lat: f64, lon: f64) -> (u32, u32, u32) {
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
    let avail = &layer["available"][max as usize][0];
    let in_range = |x: u32| {
        x >= avail["startX"].as_u64().unwrap() as u32 && x <= avail["endX"].as_u64().unwrap() as u32
    };
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
    assert!(compared > 1000, "only {compared} vertices compared");
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
    let below = &layer["available"][coarse.0 as usize + 1][0];
    for c in children {
        for (k, lo, hi) in [("startX", "startX", "endX"), ("startY", "startY", "endY")] {
            let v = c[k].as_u64().unwrap();
            assert!(v >= below[lo].as_u64().unwrap() && v <= below[hi].as_u64().unwrap());
        }
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
