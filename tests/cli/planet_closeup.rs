//! A close-up 100 m above the ground over an inset: the planet built from the inset
//! (`cbdam build --planet`) and the plane built from the same file (`cbdam build`), each drawn
//! from the same geodetic camera, give the same picture — the same distance to the ground in
//! every pixel within what honestly differs, and the same colours.
//!
//! **The inset.** A synthetic EPSG:4326 GeoTIFF (pixel-is-area, 16 × 16 samples) whose spacing
//! is the planet lattice's mean spacing at `--planet-level 4` (N = 65: 90°/1024 ≈ 0.088°, 9.8 km),
//! so the planet is as fine as the inset; a finer inset would need a finer lattice over the
//! whole Earth (6·S² points: 1.0·10¹¹ at 3″), which a test cannot afford. The relief is linear in
//! latitude and longitude (slopes of about 2 % north and 3 % east, heights 600–5600 m), which
//! both builds represent exactly: the plane's frame is linear in latitude and longitude and its
//! triangles interpolate linearly, and the planet's bilinear resampling reproduces a linear
//! function at every lattice point. What the two surfaces still differ by is bounded below.
//!
//! **The plane's frame of a geographic input** (`World::new`): lattice point `(c, r)` is sample
//! `(c, r)` of the file, at the sample centre — longitude `lon₀ + c·Δlon`, latitude
//! `lat₀ − r·Δlat`, where `(lon₀, lat₀)` is the first sample's centre (half a pixel in from the
//! GeoTIFF's corner when pixels are areas); world `x = c·Δlon·111 195 m·cos φc` east and
//! `y = −r·Δlat·111 195 m` north, `φc` the raster's central latitude; `z` the height as the file
//! gives it. So a geodetic position `(φ, λ, h)` is the plane's
//! `((λ − lon₀)/Δlon · step_x, −(lat₀ − φ)/Δlat · step_y, h)`, and the planet's camera at
//! `--geo φ,λ,h` (height above the ellipsoid, the same metres the heights are in) is the plane's
//! camera there with the same heading and pitch (the plane's x, y, z are east, north, up).
//!
//! **What honestly differs**, per pixel, as a height difference `δh` of the ground the ray
//! meets (a height difference moves the hit along the ray by `δh / sin β`, `β` the angle
//! between the ray and the ground):
//! - each build's L∞ bound (`--max-error`, 0.25 m each), and the planet lattice's resampling
//!   error against the inset's samples, as the build reports it (the map from face coordinates
//!   to latitude and longitude is not linear, so the planet's triangles bend the linear relief
//!   slightly);
//! - curvature: the planet's ground falls away below the tangent plane at the eye, the plane's
//!   does not. The eye is put above a planet lattice vertex, so within the first cell the
//!   planet's flat triangle falls by `d·L/2R` at `d` metres (the chord to the next vertex, `L`
//!   away, ends `L²/2R` down), beyond it by `d²/2R` plus a chord's sag `L²/8R`: at most
//!   `d·max(L, d)/2R + L²/8R` (`L`: the longest cell side, 1.3 × the mean spacing);
//! - the plane's metres per degree (111 195 m, the mean) are not WGS84's at this latitude
//!   (0.2–0.3 % off): on the 3 % slope that is 0.01 % of the distance in height, in the bound
//!   as `10⁻³·d`.
//!
//! The colours use one ramp for both (the renderer's `World` given the same height range) and
//! the same sun in the local east-north-up frame: 99 % of pixels within 3 levels per channel
//! (what the triangles' different diagonals, interpolation and the 0.25 m height steps leave
//! on a smooth ramp).
//!
//! Mutations that this test was measured to catch: the plane's camera half a sample off (the
//! corner taken for the first sample's centre); the planet camera at the geocentric latitude.

use std::path::Path;
use std::sync::Arc;

use cbdam_builder::write::{Raster, write_geotiff};
use cbdam_client::access::LocalSource;
use cbdam_client::camera::Camera;
use cbdam_client::refine::{RefineConfig, Refiner};
use cbdam_client::world::World;
use cbdam_codec::geodesy::cube_map::lat_lon_to_face_st;
use cbdam_codec::geodesy::{LatLon, lattice_lat_lon, wgs84};
use cbdam_codec::geometry::Domain;
use cbdam_codec::repository::GeoRef;
use cbdam_codec::repository::Repository;
use cbdam_render::{CacheConfig, Frame, Gpu, RenderOptions, Renderer};
use glam::{DVec3, DVec4};

use crate::util::{cbdam, s, stderr};

/// The planet's diamond side and level pairs: `S = 64·16 = 1024` steps per face side.
const N: usize = 65;
const K: u32 = 4;
/// The inset's spacing: the lattice's mean spacing, degrees.
const SPACING: f64 = 90.0 / 1024.0;
/// Samples per side of the inset.
const SAMPLES: usize = 16;
/// North-west corner of the inset's first pixel (pixel-is-area), degrees.
const WEST: f64 = 40.2;
const NORTH: f64 = 41.0;
/// Tolerance of both builds, metres.
const MAX_ERROR: f64 = 0.25;
/// Height of the eye above the ground, metres.
const ABOVE: f64 = 100.0;
/// The view: heading (clockwise from north) and pitch (negative down), degrees.
const HEADING: f64 = 30.0;
const PITCH: f64 = -35.0;
const SIZE: (u32, u32) = (192, 144);

/// The relief, metres: linear in latitude and longitude.
fn relief(ll: LatLon) -> f64 {
    3000.0 + 1900.0 * (ll.lat - 40.4) + 2700.0 * (ll.lon - 40.9)
}

/// The centre of sample `(c, r)` of the inset.
fn sample_centre(c: f64, r: f64) -> LatLon {
    LatLon {
        lat: NORTH - (r + 0.5) * SPACING,
        lon: WEST + (c + 0.5) * SPACING,
    }
}

fn write_inset(path: &Path) {
    let values = (0..SAMPLES * SAMPLES)
        .map(|i| relief(sample_centre((i % SAMPLES) as f64, (i / SAMPLES) as f64)))
        .collect();
    let raster = Raster {
        width: SAMPLES,
        height: SAMPLES,
        values,
        georef: Some(GeoRef {
            epsg: Some(4326),
            origin_x: WEST,
            origin_y: NORTH,
            pixel_x: SPACING,
            pixel_y: SPACING,
            pixel_is_area: true,
            wkt: None,
        }),
    };
    write_geotiff(std::fs::File::create(path).unwrap(), &raster, None, false).unwrap();
}

/// The plane's world position of geodetic `ll` at `h` metres (see the module documentation).
fn on_plane(world: &World, ll: LatLon, h: f64) -> DVec3 {
    let first = sample_centre(0.0, 0.0);
    let (c, r) = (
        (ll.lon - first.lon) / SPACING,
        (first.lat - ll.lat) / SPACING,
    );
    let (step_x, _) = world.lattice_vector(1, 0);
    let (_, step_y) = world.lattice_vector(0, 1);
    DVec3::new(c * step_x, r * step_y, h)
}

fn build(args: &[&str]) -> Arc<Repository> {
    let o = cbdam(args);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = args[args.iter().position(|a| *a == "-o").unwrap() + 1];
    Arc::new(Repository::open(Path::new(out)).unwrap())
}

/// The converged cut for `cam` drawn with `world` (its height range sets the colour ramp),
/// colour and depth read back.
fn draw(repo: &Arc<Repository>, world: World, cam: &Camera) -> Frame {
    let config = RefineConfig {
        pixel_error: 1.0,
        budget: None,
        ..RefineConfig::default()
    };
    let mut refiner = Refiner::new(LocalSource::new(repo.clone()), config).unwrap();
    let stats = refiner.settle(cam, 16);
    assert!(stats.converged, "{stats:?}");
    let patches: Vec<_> = refiner.drawn().cloned().collect();
    let gpu = Gpu::headless().expect("a GPU or lavapipe (scripts/test.sh installs it)");
    let mut renderer = Renderer::new(gpu, world, CacheConfig::default()).unwrap();
    let options = RenderOptions {
        read_depth: true,
        ..RenderOptions::default()
    };
    renderer.render(cam, &patches, &options).unwrap()
}

/// Distance from the eye to what pixel `(x, y)` shows, from the depth buffer (view space, so
/// no large world coordinates enter), and the ray's direction in view space.
fn distance(cam: &Camera, frame: &Frame, x: u32, y: u32) -> Option<(f64, DVec3)> {
    let d = f64::from(frame.depth.as_ref().unwrap()[(y * frame.width + x) as usize]);
    let background = if cam.reversed_z() { 0.0 } else { 1.0 };
    if d == background {
        return None;
    }
    let ndc_x = (f64::from(x) + 0.5) / f64::from(cam.width) * 2.0 - 1.0;
    let ndc_y = 1.0 - (f64::from(y) + 0.5) / f64::from(cam.height) * 2.0;
    let p = cam.projection().inverse() * DVec4::new(ndc_x, ndc_y, d, 1.0);
    let p = p.truncate() / p.w;
    Some((p.length(), p.normalize()))
}

#[test]
fn a_close_up_over_an_inset_is_the_same_on_the_planet_and_on_the_plane() {
    let dir = tempfile::tempdir().unwrap();
    let inset = dir.path().join("inset.tif");
    write_inset(&inset);
    let (plane_path, planet_path) = (
        dir.path().join("plane.cbdam"),
        dir.path().join("planet.cbdam"),
    );
    let e = MAX_ERROR.to_string();
    let plane = build(&[
        "build",
        &s(&inset),
        "-o",
        &s(&plane_path),
        "--max-error",
        &e,
        "--quiet",
    ]);
    let planet = build(&[
        "build",
        &s(&inset),
        "--planet",
        "--planet-level",
        &K.to_string(),
        "-o",
        &s(&planet_path),
        "--max-error",
        &e,
        "--quiet",
    ]);
    // Bilinear resampling reproduces the linear relief at every lattice point; measured
    // against the samples in face coordinates it is off by the map's curvature over a cell
    // (about 0.07 m on this 240 m-per-cell slope, from an independent model of the build) and
    // half a height unit. An inset taken to wrap round the globe because its spacing divides
    // 360° gave 5.0 m here (its last column stretched one column east).
    let resampling = planet
        .head()
        .provenance()
        .expect("a planet records its resampling")
        .resampling_max;
    assert!(resampling <= MAX_ERROR, "resampling error {resampling} m");

    // The eye: above the planet lattice vertex nearest the inset's centre.
    let domain = Domain::cube_sphere(N, K).unwrap();
    assert_eq!(planet.head().params().domain, domain);
    let side = domain.cube().unwrap().side() as f64;
    let (face, s_, t_) = lat_lon_to_face_st(sample_centre(7.5, 7.5));
    let (x, y) = ((s_ * side).round() as i64, (t_ * side).round() as i64);
    let ll = lattice_lat_lon(&domain, face, x, y).unwrap();
    let ground = relief(ll);
    let eye_h = ground + ABOVE;

    // One colour ramp for both: the union of their height ranges.
    let plane_world = World::of_repository(&plane);
    let mut planet_world = World::of_repository(&planet);
    let mut common = plane_world;
    common.min_height = plane_world.min_height.min(planet_world.min_height);
    common.max_height = plane_world.max_height.max(planet_world.max_height);
    planet_world.min_height = common.min_height;
    planet_world.max_height = common.max_height;

    let fov = 45f64.to_radians();
    let planet_cam = Camera::geodetic(
        &planet_world,
        (ll.lat, ll.lon, eye_h),
        (HEADING, PITCH),
        fov,
        SIZE,
    );
    let at = on_plane(&plane_world, ll, eye_h);
    let plane_cam = Camera::geodetic(
        &plane_world,
        (at.y, at.x, at.z),
        (HEADING, PITCH),
        fov,
        SIZE,
    );
    let on_planet = draw(&planet, planet_world, &planet_cam);
    let on_the_plane = draw(&plane, common, &plane_cam);

    // The plane's ground normal (the relief is linear: one plane), for the angle of each ray.
    let (sx, _) = plane_world.lattice_vector(1, 0);
    let (_, sy) = plane_world.lattice_vector(0, 1);
    let dh_dx = (relief(LatLon {
        lat: ll.lat,
        lon: ll.lon + SPACING,
    }) - ground)
        / sx;
    let dh_dy = (relief(LatLon {
        lat: ll.lat - SPACING,
        lon: ll.lon,
    }) - ground)
        / sy;
    let ground_normal = DVec3::new(-dh_dx, -dh_dy, 1.0).normalize();
    let view_to_world = plane_cam.view().inverse();

    let r = wgs84::B;
    let cell = 1.3 * std::f64::consts::FRAC_PI_2 * wgs84::A / side;
    let (mut worst, mut compared) = (0.0f64, 0);
    for py in 0..SIZE.1 {
        for px in 0..SIZE.0 {
            let (Some((d_planet, _)), Some((d_plane, ray))) = (
                distance(&planet_cam, &on_planet, px, py),
                distance(&plane_cam, &on_the_plane, px, py),
            ) else {
                panic!("pixel {px},{py}: ground in one image and not the other");
            };
            let ray_world = (view_to_world * ray.extend(0.0)).truncate();
            let sin_beta = ray_world.dot(ground_normal).abs();
            let ground_d = d_plane * (1.0 - ray_world.z * ray_world.z).sqrt();
            let dh = 2.0 * MAX_ERROR
                + resampling
                + ground_d * cell.max(ground_d) / (2.0 * r)
                + cell * cell / (8.0 * r)
                + 1e-3 * ground_d;
            let allowed = dh / sin_beta;
            worst = worst.max((d_planet - d_plane).abs() / allowed);
            compared += 1;
        }
    }
    eprintln!(
        "close-up at lat {:.5} lon {:.5}, {ABOVE} m above {ground:.1} m: {compared} pixels, worst \
         depth difference {worst:.3} of its bound (resampling error {resampling:.3} m)",
        ll.lat, ll.lon
    );
    assert!(worst <= 1.0, "depth differs by {worst:.3} of the bound");

    let mut off = 0;
    let mut most = 0;
    for (a, b) in on_planet.rgba.chunks(4).zip(on_the_plane.rgba.chunks(4)) {
        let d = (0..3).map(|i| a[i].abs_diff(b[i])).max().unwrap();
        most = most.max(d);
        off += usize::from(d > 3);
    }
    let pixels = (SIZE.0 * SIZE.1) as usize;
    eprintln!("colours: {off} of {pixels} pixels differ by more than 3 levels, at most {most}");
    assert!(
        off * 100 <= pixels,
        "{off} of {pixels} pixels differ by more than 3 levels"
    );
}
