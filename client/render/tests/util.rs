//! Shared set-up of the renderer's tests: repositories built from the bundled DEMs, a GPU
//! device (lavapipe where there is no GPU), and geometry helpers.
#![allow(dead_code)]

use std::path::PathBuf;
use std::sync::{Arc, OnceLock};

use cbdam_builder::input::{ReadOptions, read_dem};
use cbdam_client::access::LocalSource;
use cbdam_client::camera::Camera;
use cbdam_client::patch::HalfPatch;
use cbdam_client::refine::{RefineConfig, Refiner};
use cbdam_client::world::World;
use cbdam_codec::geometry::Cut;
use cbdam_codec::hierarchy::{EncodeOptions, Encoder};
use cbdam_codec::lifting::Alpha;
use cbdam_codec::quant::{HeightGrid, QuantPlan};
use cbdam_codec::repository::{Repository, serialize};
use cbdam_render::{CacheConfig, Gpu, Renderer};
use glam::{DVec3, DVec4};

/// The bundled DEM `name` (in the workspace's `data/`).
pub fn data(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../..")
        .join("data")
        .join(name)
}

/// A repository of a bundled DEM with diamond side `n`, built in memory.
pub fn repository(name: &str, max_error: f64, n: usize) -> Repository {
    repository_with_alpha(name, max_error, n, Alpha::One)
}

/// [`repository`] with the lifting weight `alpha`.
pub fn repository_with_alpha(name: &str, max_error: f64, n: usize, alpha: Alpha) -> Repository {
    let dem = read_dem(&data(name), &ReadOptions::default()).unwrap();
    let plan = QuantPlan::for_dem(&dem, max_error, None).unwrap();
    let grid = HeightGrid::from_dem(&dem, &plan).unwrap();
    let opts = EncodeOptions {
        n,
        alpha,
        ..EncodeOptions::default()
    };
    let enc = Encoder::new(&grid, plan.quantizer, &opts).encode().unwrap();
    let bytes = serialize(&enc, &plan, dem.georef.as_ref(), dem.nodata).unwrap();
    Repository::from_bytes(bytes).unwrap()
}

/// Jacksboro (403 × 344, 3″) with 17-point diamonds: 11 levels, so cuts can mix many.
pub fn jacksboro() -> &'static Arc<Repository> {
    static REPO: OnceLock<Arc<Repository>> = OnceLock::new();
    REPO.get_or_init(|| Arc::new(repository("jacksboro_mpl.tif", 1.0, 17)))
}

/// [`jacksboro`] with the α = ½ lifting weight (its own analysis filter and vertex bands).
pub fn jacksboro_half() -> &'static Arc<Repository> {
    static REPO: OnceLock<Arc<Repository>> = OnceLock::new();
    REPO.get_or_init(|| {
        Arc::new(repository_with_alpha(
            "jacksboro_mpl.tif",
            1.0,
            17,
            Alpha::Half,
        ))
    })
}

/// The cut the streaming client's refinement loop settles on for `cam` at `pixel_error` with an
/// unlimited budget (what `cbdam render` draws), and its drawn half-patches.
pub fn refined_cut(
    repo: &Arc<Repository>,
    cam: &Camera,
    pixel_error: f64,
) -> (Cut, Vec<Arc<HalfPatch>>) {
    let config = RefineConfig {
        pixel_error,
        budget: None,
        ..RefineConfig::default()
    };
    let mut refiner = Refiner::new(LocalSource::new(repo.clone()), config).unwrap();
    let stats = refiner.settle(cam, 16);
    assert!(stats.converged, "{stats:?}");
    (refiner.cut().clone(), refiner.drawn().cloned().collect())
}

/// A device, or a failure that says what to install. Tests that render must not silently pass
/// where nothing can render: scripts/test.sh installs lavapipe, and a bare `cargo test` on a
/// machine without any Vulkan driver fails here with the command to run.
pub fn gpu() -> Gpu {
    match Gpu::headless() {
        Ok(g) => g,
        Err(e) => panic!("{e} (scripts/test.sh does this for you)"),
    }
}

/// A renderer for `repo` with an ample cache.
pub fn renderer(repo: &Repository) -> Renderer {
    Renderer::new(gpu(), World::of_repository(repo), CacheConfig::default()).unwrap()
}

/// A camera at `eye` looking at `target`, 45° field of view.
pub fn camera(world: &World, eye: DVec3, target: DVec3, size: (u32, u32)) -> Camera {
    Camera::looking_at(world, eye, target, 45f64.to_radians(), size)
}

/// A camera at `elevation_deg` above the horizon from azimuth `azimuth_deg` (0 = from the
/// south, 90 = from the east), `distance` metres from the data's centre at mean height.
pub fn orbit(
    world: &World,
    azimuth_deg: f64,
    elevation_deg: f64,
    distance: f64,
    size: (u32, u32),
) -> Camera {
    let (lo, hi) = world.bounds();
    let centre = (lo + hi) * 0.5;
    let (az, el) = (azimuth_deg.to_radians(), elevation_deg.to_radians());
    let dir = DVec3::new(az.sin() * el.cos(), -az.cos() * el.cos(), el.sin());
    camera(world, centre + dir * distance, centre, size)
}

/// The world-space ray (origin, unit direction) through the centre of pixel `(x, y)`.
pub fn pixel_ray(cam: &Camera, x: u32, y: u32) -> (DVec3, DVec3) {
    let inv = (cam.projection() * cam.view()).inverse();
    let ndc_x = (f64::from(x) + 0.5) / f64::from(cam.width) * 2.0 - 1.0;
    let ndc_y = 1.0 - (f64::from(y) + 0.5) / f64::from(cam.height) * 2.0;
    let unproject = |z: f64| {
        let p = inv * DVec4::new(ndc_x, ndc_y, z, 1.0);
        p.truncate() / p.w
    };
    let (a, b) = (unproject(0.0), unproject(1.0));
    (a, (b - a).normalize())
}

/// The world point at depth-buffer value `depth` of pixel `(x, y)`.
pub fn unproject(cam: &Camera, x: u32, y: u32, depth: f64) -> DVec3 {
    let inv = (cam.projection() * cam.view()).inverse();
    let ndc_x = (f64::from(x) + 0.5) / f64::from(cam.width) * 2.0 - 1.0;
    let ndc_y = 1.0 - (f64::from(y) + 0.5) / f64::from(cam.height) * 2.0;
    let p = inv * DVec4::new(ndc_x, ndc_y, depth, 1.0);
    p.truncate() / p.w
}

/// Lowest and highest height in metres of the drawn patches.
pub fn height_range(world: &World, patches: &[HalfPatch]) -> (f64, f64) {
    let (lo, hi) = patches
        .iter()
        .flat_map(|p| p.heights.iter())
        .fold((i32::MAX, i32::MIN), |(a, b), &h| (a.min(h), b.max(h)));
    (world.height(lo), world.height(hi))
}

/// A random cut: `count` random stored diamonds refined, parents forced by `Cut::refine`. The
/// level is drawn uniformly first, so coarse levels are picked as often as fine ones (stored
/// diamonds are mostly fine, and refining one forces its whole ancestry): the cut then mixes
/// as many levels side by side as the DAG allows.
pub fn random_cut(repo: &Repository, count: usize, seed: u64) -> Cut {
    let domain = repo.head().params().domain;
    let layout = *domain.layout();
    let mut by_level: Vec<Vec<_>> = vec![Vec::new(); usize::from(layout.finest_level())];
    for e in repo.head().entries() {
        if let Some(l) = by_level.get_mut(usize::from(e.id.level)) {
            l.push(e.id);
        }
    }
    by_level.retain(|l| !l.is_empty());
    let mut cut = Cut::new();
    let mut state = seed;
    let mut next = || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 33) as usize
    };
    for _ in 0..count {
        let level = &by_level[next() % by_level.len()];
        cut.refine(&domain, level[next() % level.len()]);
    }
    cut
}

/// Writes `png` to the test's scratch directory (under the cargo target directory) for looking at
/// after a failure; returns the path.
pub fn save(name: &str, png: &[u8]) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("render-tests");
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join(name);
    std::fs::write(&path, png).unwrap();
    path
}

/// The full-resolution cut: every stored diamond refined, so the finest level is drawn wherever
/// there is data. The reference that adaptive cuts are compared with.
pub fn full_resolution_cut(repo: &Repository) -> Cut {
    let domain = repo.head().params().domain;
    let mut cut = Cut::new();
    for e in repo.head().entries() {
        cut.refine(&domain, e.id);
    }
    cut
}

/// A smooth synthetic 129 × 113 DEM with nodata: a disc, a strip, and scattered single samples
/// (about 15 % in all), built with 17-point diamonds at ε = 0.5 m. Returns the repository and
/// the input's validity (row-major, `true` = data).
pub fn holed() -> &'static (Arc<Repository>, Vec<bool>) {
    static REPO: OnceLock<(Arc<Repository>, Vec<bool>)> = OnceLock::new();
    REPO.get_or_init(|| {
        let (w, h) = (129usize, 113usize);
        let metres: Vec<f64> = (0..w * h)
            .map(|k| {
                let (x, y) = ((k % w) as f64, (k / w) as f64);
                120.0 + 30.0 * (x / 17.0).sin() * (y / 23.0).cos() + 0.2 * x
            })
            .collect();
        let valid: Vec<bool> = (0..w * h)
            .map(|k| {
                let (x, y) = ((k % w) as i64, (k / w) as i64);
                let disc = (x - 70).pow(2) + (y - 50).pow(2) < 18 * 18;
                let strip = (20..26).contains(&x) && y > 60;
                let scattered = k % 211 == 0;
                !(disc || strip || scattered)
            })
            .collect();
        let plan = QuantPlan::new(0.5, None, 80.0, 160.0).unwrap();
        let mut grid = HeightGrid::from_metres(w, h, &metres, None, &plan).unwrap();
        grid.valid.copy_from_slice(&valid);
        let opts = EncodeOptions {
            n: 17,
            ..EncodeOptions::default()
        };
        let enc = Encoder::new(&grid, plan.quantizer, &opts).encode().unwrap();
        let bytes = serialize(&enc, &plan, None, None).unwrap();
        (Arc::new(Repository::from_bytes(bytes).unwrap()), valid)
    })
}
