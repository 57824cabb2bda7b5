//! Web-map tiles over real HTTP on 127.0.0.1: terrarium / terrain-RGB PNGs decoded with the
//! `png` crate, quantized-mesh tiles decoded by a reader written here from the specification
//! (not the encoder's code), every height compared with the input DEM within the bound the
//! server states.

use cbdam_codec::geodesy::{LatLon, Utm};
use cbdam_codec::repository::{GeoRef, Repository};
use cbdam_server::{AppState, Config};
use serde_json::Value;

use crate::util::{Running, client, json, start};

#[path = "../tiles/tests/common/rough_dem.rs"]
mod rough_dem;

pub(crate) use rough_dem::{EPSILON, NODATA};

/// A DEM, its georeferencing and the repository built from it.
pub(crate) struct Dem {
    w: usize,
    h: usize,
    metres: Vec<f64>,
    pub(crate) georef: GeoRef,
}

impl Dem {
    /// Rough terrain with a nodata hole, `w × h` samples.
    fn rough(w: usize, h: usize, georef: GeoRef) -> Dem {
        Dem {
            w,
            h,
            metres: rough_dem::rough_metres(w, h),
            georef,
        }
    }

    pub(crate) fn repository(&self) -> Repository {
        rough_dem::repository(self.w, self.h, &self.metres, &self.georef)
    }

    /// Lattice column / row of a geodetic point (sample centres at integers).
    pub(crate) fn lattice(&self, lat: f64, lon: f64) -> (f64, f64) {
        let g = &self.georef;
        let (mx, my) = match g.epsg {
            Some(4326) => (lon, lat),
            Some(code) => Utm::from_epsg(code).unwrap().forward(LatLon { lat, lon }),
            None => unreachable!(),
        };
        let half = if g.pixel_is_area { 0.5 } else { 0.0 };
        (
            (mx - g.origin_x) / g.pixel_x - half,
            (g.origin_y - my) / g.pixel_y - half,
        )
    }

    /// The input's bilinear interpolation at a geodetic point, when all four samples around it
    /// hold data and it lies inside the data; `Err(true)` when it lies clearly outside the
    /// data (more than a sample beyond it).
    pub(crate) fn bilinear(&self, lat: f64, lon: f64) -> Result<f64, bool> {
        let (x, y) = self.lattice(lat, lon);
        let (wm, hm) = ((self.w - 1) as f64, (self.h - 1) as f64);
        if x < -1.0 || y < -1.0 || x > wm + 1.0 || y > hm + 1.0 {
            return Err(true);
        }
        if x < 0.0 || y < 0.0 || x >= wm || y >= hm {
            return Err(false);
        }
        let (c, r) = (x.floor() as usize, y.floor() as usize);
        let (tx, ty) = (x - c as f64, y - r as f64);
        let at = |c: usize, r: usize| self.metres[r * self.w + c];
        let v = [at(c, r), at(c + 1, r), at(c, r + 1), at(c + 1, r + 1)];
        if v.contains(&NODATA) {
            return Err(false);
        }
        Ok((1.0 - ty) * ((1.0 - tx) * v[0] + tx * v[1]) + ty * ((1.0 - tx) * v[2] + tx * v[3]))
    }
}

pub(crate) fn utm_dem() -> Dem {
    Dem::rough(
        70,
        50,
        GeoRef {
            epsg: Some(32632),
            origin_x: 400_000.0,
            origin_y: 5_100_000.0,
            pixel_x: 30.0,
            pixel_y: 30.0,
            pixel_is_area: true,
            wkt: None,
        },
    )
}

pub(crate) fn geographic_dem() -> Dem {
    Dem::rough(
        64,
        48,
        GeoRef {
            epsg: Some(4326),
            origin_x: 7.0,
            origin_y: 46.0,
            pixel_x: 1.0 / 1200.0,
            pixel_y: 1.0 / 1200.0,
            pixel_is_area: false,
            wkt: None,
        },
    )
}

pub(crate) async fn serve(repos: Vec<(&str, Repository)>) -> Running {
    let repos = repos.into_iter().map(|(n, r)| (n.to_string(), r)).collect();
    start(AppState::new(repos, Config::default()).unwrap()).await
}

pub(crate) async fn get_json(s: &Running, path: &str) -> Value {
    let r = client().get(s.url(path)).send().await.unwrap();
    assert_eq!(r.status(), 200, "{path}");
    json(r).await
}

/// The Web Mercator tile holding a geodetic point at zoom `z`.
fn mercator_tile(z: u32, lat: f64, lon: f64) -> (u32, u32) {
    let n = f64::from(1u32 << z);
    let x = ((lon + 180.0) / 360.0 * n).floor() as u32;
    let lat = lat.to_radians();
    let y = ((1.0 - lat.tan().asinh() / std::f64::consts::PI) / 2.0 * n).floor() as u32;
    (x, y)
}

/// Decodes a PNG into RGBA pixels.
fn decode_png(bytes: &[u8]) -> (u32, Vec<[u8; 4]>) {
    let mut dec = png::Decoder::new(std::io::Cursor::new(bytes))
        .read_info()
        .unwrap();
    let mut buf = vec![0; dec.output_buffer_size().unwrap()];
    let info = dec.next_frame(&mut buf).unwrap();
    let px = match info.color_type {
        png::ColorType::Rgb => buf
            .chunks_exact(3)
            .map(|p| [p[0], p[1], p[2], 255])
            .collect(),
        png::ColorType::Rgba => buf
            .chunks_exact(4)
            .map(|p| [p[0], p[1], p[2], p[3]])
            .collect(),
        c => panic!("unexpected colour type {c:?}"),
    };
    (info.width, px)
}

/// The clients' formulas.
fn decode_height(format: &str, [r, g, b, _]: [u8; 4]) -> f64 {
    let [r, g, b] = [r, g, b].map(f64::from);
    match format {
        "terrarium" => r * 256.0 + g + b / 256.0 - 32768.0,
        _ => -10000.0 + (r * 65536.0 + g * 256.0 + b) * 0.1,
    }
}

/// Fetches the raster tile holding the data's centre at the TileJSON's maxzoom and checks
/// every pixel against the input: within the stated bound where the input has data around
/// it, transparent well outside the data. Returns how many pixels were compared.
async fn check_raster(s: &Running, dem: &Dem, format: &str, tile: u32) -> usize {
    let query = if tile == 256 { "?tile=256" } else { "" };
    let tj = get_json(s, &format!("/v1/repos/d/{format}/tiles.json{query}")).await;
    assert_eq!(tj["tilejson"], "3.0.0");
    assert_eq!(tj["tileSize"], tile);
    let encoding = if format == "terrarium" {
        "terrarium"
    } else {
        "mapbox"
    };
    assert_eq!(tj["encoding"], encoding);
    let bound = tj["cbdam"]["pixel_bound_m"].as_f64().unwrap();
    let step = tj["cbdam"]["encoding_step_m"].as_f64().unwrap();
    assert!(bound > 0.5 * step && bound <= EPSILON + step, "{bound}");
    let z = tj["maxzoom"].as_u64().unwrap() as u32;
    let b: Vec<f64> = serde_json::from_value(tj["bounds"].clone()).unwrap();
    let (lat, lon) = (0.5 * (b[1] + b[3]), 0.5 * (b[0] + b[2]));
    let (x, y) = mercator_tile(z, lat, lon);
    let template = tj["tiles"][0].as_str().unwrap();
    assert!(
        template.starts_with(&s.url("/v1/repos/d/")),
        "absolute: {template}"
    );
    let template = template.strip_prefix(&s.base).unwrap();
    let url = template
        .replace("{z}", &z.to_string())
        .replace("{x}", &x.to_string())
        .replace("{y}", &y.to_string());
    let r = client().get(s.url(&url)).send().await.unwrap();
    assert_eq!(r.status(), 200, "{url}");
    assert_eq!(r.headers()["content-type"], "image/png");
    let (size, px) = decode_png(&r.bytes().await.unwrap());
    assert_eq!(size, tile);
    let n = f64::from(1u32 << z);
    let (mut compared, mut outside) = (0, 0);
    for (i, p) in px.iter().enumerate() {
        let (col, row) = ((i as u32 % tile) as f64, (i as u32 / tile) as f64);
        let lon = (f64::from(x) + (col + 0.5) / f64::from(tile)) / n * 360.0 - 180.0;
        let yn = (f64::from(y) + (row + 0.5) / f64::from(tile)) / n;
        let lat = (std::f64::consts::PI * (1.0 - 2.0 * yn))
            .sinh()
            .atan()
            .to_degrees();
        match dem.bilinear(lat, lon) {
            Ok(expected) => {
                assert_eq!(p[3], 255, "pixel {col},{row} holds data");
                let got = decode_height(format, *p);
                assert!(
                    (got - expected).abs() <= bound + 1e-9,
                    "{format} pixel {col},{row}: {got} against the input's {expected}, bound {bound}"
                );
                compared += 1;
            }
            Err(true) => {
                assert_eq!(p[3], 0, "pixel {col},{row} outside the data is transparent");
                assert!(
                    decode_height(format, *p).abs() <= step,
                    "nodata encodes 0 m"
                );
                outside += 1;
            }
            Err(false) => {}
        }
    }
    assert!(outside > 0, "the tile reaches past the data");
    compared
}

#[tokio::test]
async fn raster_tiles_hold_the_input_within_the_stated_bound() {
    for dem in [utm_dem(), geographic_dem()] {
        let s = serve(vec![("d", dem.repository())]).await;
        for (format, tile) in [("terrarium", 512), ("terrain-rgb", 512), ("terrarium", 256)] {
            let compared = check_raster(&s, &dem, format, tile).await;
            // Most of the data's 3 000-odd samples' cells are covered by the tile's pixels.
            assert!(compared > 1000, "{format}: only {compared} pixels compared");
        }
        s.stop().await;
    }
}

/// Terrain-RGB holds nothing below −10 000 m: every pixel with data of a tile of a trench
/// (heights −10 140 … −10 030 m) is clamped to −10 000 m and counted in `cbdam-clamped-pixels`;
/// terrarium holds the same heights within the stated bound, none clamped.
#[tokio::test]
async fn terrain_rgb_clamps_a_trench_and_counts_the_pixels() {
    let mut dem = geographic_dem();
    for m in dem.metres.iter_mut().filter(|m| **m != NODATA) {
        *m -= 10_400.0;
    }
    let range = (-10_300.0, -9_900.0);
    let repo = rough_dem::repository_between(dem.w, dem.h, &dem.metres, &dem.georef, range);
    let s = serve(vec![("d", repo)]).await;
    assert!(check_raster(&s, &dem, "terrarium", 512).await > 1000);
    let tj = get_json(&s, "/v1/repos/d/terrain-rgb/tiles.json").await;
    assert_eq!(tj["cbdam"]["encoding_range_m"][0], -10_000.0);
    assert!(tj["cbdam"]["clamped"].as_str().unwrap().contains("clamped"));
    let z = tj["maxzoom"].as_u64().unwrap() as u32;
    let b: Vec<f64> = serde_json::from_value(tj["bounds"].clone()).unwrap();
    let (x, y) = mercator_tile(z, 0.5 * (b[1] + b[3]), 0.5 * (b[0] + b[2]));
    for (format, all_clamped) in [("terrain-rgb", true), ("terrarium", false)] {
        let url = s.url(&format!("/v1/repos/d/{format}/{z}/{x}/{y}.png"));
        let r = client().get(&url).send().await.unwrap();
        assert_eq!(r.status(), 200, "{url}");
        let clamped: usize = r.headers()["cbdam-clamped-pixels"]
            .to_str()
            .unwrap()
            .parse()
            .unwrap();
        let (_, px) = decode_png(&r.bytes().await.unwrap());
        let with_data: Vec<_> = px.iter().filter(|p| p[3] == 255).collect();
        assert!(
            with_data.len() > 1000,
            "{format}: {} pixels",
            with_data.len()
        );
        if all_clamped {
            assert_eq!(clamped, with_data.len(), "{format}: clamped pixels counted");
            assert!(
                with_data
                    .iter()
                    .all(|p| decode_height(format, **p) == -10_000.0)
            );
        } else {
            assert_eq!(clamped, 0, "{format}");
        }
    }
    s.stop().await;
}

/// The server's limit on decoded samples binds only a repository decoded whole (one without
/// records); one with records past it is still served as tiles, each decoded from a window.
#[tokio::test]
async fn repositories_with_records_are_tiled_from_windows_past_the_sample_limit() {
    let config = Config {
        max_tile_samples: 1000,
        ..Config::default()
    };
    let repos = vec![("d".to_string(), utm_dem().repository())];
    let s = start(AppState::new(repos, config).unwrap()).await;
    for path in [
        "/v1/repos/d/terrarium/tiles.json",
        "/v1/repos/d/quantized-mesh/layer.json",
        "/v1/repos/d/quantized-mesh/0/1/0.terrain",
    ] {
        let r = client().get(s.url(path)).send().await.unwrap();
        assert_eq!(r.status(), 200, "{path}");
    }
    s.stop().await;
}

/// Tile requests and their documents are counted under their own `/metrics` endpoint,
/// `tiles`, with their statuses; nothing of them under `other`.
#[tokio::test]
async fn tile_requests_are_counted_as_tiles_in_metrics() {
    let dem = geographic_dem();
    let s = serve(vec![("d", dem.repository())]).await;
    let tj = get_json(&s, "/v1/repos/d/terrarium/tiles.json").await;
    let z = tj["maxzoom"].as_u64().unwrap() as u32;
    let b: Vec<f64> = serde_json::from_value(tj["bounds"].clone()).unwrap();
    let (x, y) = mercator_tile(z, 0.5 * (b[1] + b[3]), 0.5 * (b[0] + b[2]));
    let paths = [
        (format!("/v1/repos/d/terrarium/{z}/{x}/{y}.png"), 200),
        ("/v1/repos/d/quantized-mesh/layer.json".to_string(), 200),
        ("/v1/repos/d/quantized-mesh/0/0/0.terrain".to_string(), 200),
        (format!("/v1/repos/d/terrain-rgb/{z}/0/0.png"), 404),
        ("/v1/repos/d/terrarium/1/9/9.png".to_string(), 400),
    ];
    for (path, status) in &paths {
        let r = client().get(s.url(path)).send().await.unwrap();
        assert_eq!(r.status(), *status, "{path}");
    }
    let r = client().get(s.url("/metrics")).send().await.unwrap();
    let text = r.text().await.unwrap();
    let count = |endpoint: &str, status: &str| -> u64 {
        let key =
            format!("cbdam_http_requests_total{{endpoint=\"{endpoint}\",status=\"{status}\"}} ");
        text.lines()
            .find_map(|l| l.strip_prefix(&key))
            .map_or(0, |v| v.parse().unwrap())
    };
    assert_eq!(count("tiles", "200"), 4, "{text}");
    assert_eq!(count("tiles", "404"), 1);
    assert_eq!(count("tiles", "400"), 1);
    assert_eq!(
        count("other", "200") + count("other", "404") + count("other", "400"),
        0
    );
    s.stop().await;
}

/// Decodes a WebP into RGBA pixels (the `image-webp` decoder).
fn decode_webp(bytes: &[u8]) -> (u32, Vec<[u8; 4]>) {
    let mut dec = image_webp::WebPDecoder::new(std::io::Cursor::new(bytes)).unwrap();
    let mut buf = vec![0; dec.output_buffer_size().unwrap()];
    dec.read_image(&mut buf).unwrap();
    let px = if dec.has_alpha() {
        buf.chunks_exact(4)
            .map(|p| [p[0], p[1], p[2], p[3]])
            .collect()
    } else {
        buf.chunks_exact(3)
            .map(|p| [p[0], p[1], p[2], 255])
            .collect()
    };
    (dec.dimensions().0, px)
}

/// `tiles.json?format=webp` points at `.webp` tiles, served as `image/webp` with the very
/// pixels of the PNG tile (transparent ones included); other formats are a 400 naming them.
#[tokio::test]
async fn webp_tiles_hold_the_png_tiles_pixels() {
    let dem = geographic_dem();
    let s = serve(vec![("d", dem.repository())]).await;
    for format in ["terrarium", "terrain-rgb"] {
        let tj = get_json(&s, &format!("/v1/repos/d/{format}/tiles.json?format=webp")).await;
        let template = tj["tiles"][0].as_str().unwrap();
        assert!(template.ends_with("/{z}/{x}/{y}.webp"), "{template}");
        let z = tj["maxzoom"].as_u64().unwrap() as u32;
        let b: Vec<f64> = serde_json::from_value(tj["bounds"].clone()).unwrap();
        let (x, y) = mercator_tile(z, 0.5 * (b[1] + b[3]), 0.5 * (b[0] + b[2]));
        let get =
            |ext: &str| client().get(s.url(&format!("/v1/repos/d/{format}/{z}/{x}/{y}.{ext}")));
        let webp = get("webp").send().await.unwrap();
        assert_eq!(webp.status(), 200);
        assert_eq!(webp.headers()["content-type"], "image/webp");
        let webp = webp.bytes().await.unwrap();
        let png = get("png").send().await.unwrap().bytes().await.unwrap();
        let (size, png_px) = decode_png(&png);
        assert_eq!(decode_webp(&webp), (size, png_px.clone()));
        assert!(
            png_px.iter().any(|p| p[3] == 0),
            "the tile has transparent pixels"
        );
    }
    for (path, says) in [
        ("/v1/repos/d/terrarium/tiles.json?format=gif", "png or webp"),
        ("/v1/repos/d/terrarium/0/0/0.gif", "z/x/y.webp"),
    ] {
        let r = client().get(s.url(path)).send().await.unwrap();
        assert_eq!(r.status(), 400, "{path}");
        let text = r.text().await.unwrap();
        assert!(text.contains(says), "{path}: {text}");
    }
    s.stop().await;
}
