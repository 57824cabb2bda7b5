//! `cbdam render` (one offscreen frame to PNG) and `cbdam bench render` (frame times).

use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use cbdam_client::camera::Camera;
use cbdam_client::draw::select::screen_error_cut;
use cbdam_client::draw::{CacheConfig, Gpu, RenderOptions, Renderer, exaggerated};
use cbdam_client::patch::decode_cut;
use cbdam_client::world::World;
use cbdam_codec::repository::Repository;
use glam::DVec3;

use crate::{BenchRenderArgs, RenderArgs};

/// Parses `WIDTHxHEIGHT`.
pub fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X', '×'])
        .ok_or_else(|| format!("size {s:?} is not WIDTHxHEIGHT"))?;
    let parse = |t: &str| {
        t.trim()
            .parse::<u32>()
            .ok()
            .filter(|&v| (1..=16384).contains(&v))
            .ok_or_else(|| format!("size {s:?}: {t:?} is not a whole number from 1 to 16384"))
    };
    Ok((parse(w)?, parse(h)?))
}

/// A camera from `eye_x,eye_y,eye_z,target_x,target_y,target_z`, or the overview.
fn camera(world: &World, spec: Option<&[f64]>, size: (u32, u32)) -> Result<Camera> {
    let Some(v) = spec else {
        return Ok(Camera::overview(world, size));
    };
    if v.len() != 6 || v.iter().any(|x| !x.is_finite()) {
        bail!("--camera wants six finite numbers eye_x,eye_y,eye_z,target_x,target_y,target_z");
    }
    let (eye, target) = (DVec3::new(v[0], v[1], v[2]), DVec3::new(v[3], v[4], v[5]));
    if (target - eye).length() < 1e-6 {
        bail!("--camera: eye and target coincide");
    }
    Ok(Camera::looking_at(
        world,
        eye,
        target,
        45f64.to_radians(),
        size,
    ))
}

/// A low oblique view: from the south-south-west, 12° above the horizon, close enough that the
/// near terrain is much finer than the far (the adaptive case).
pub fn low_oblique(world: &World, size: (u32, u32)) -> Camera {
    let (lo, hi) = world.data_box();
    let centre = (lo + hi) * 0.5;
    let span = (hi - lo).x.max((hi - lo).y);
    let (az, el) = (200f64.to_radians(), 12f64.to_radians());
    let dir = DVec3::new(az.sin() * el.cos(), -az.cos() * el.cos(), el.sin());
    let eye = centre + dir * span * 0.55;
    let eye = DVec3::new(eye.x, eye.y, eye.z.max(hi.z + 0.02 * span));
    Camera::looking_at(world, eye, centre, 45f64.to_radians(), size)
}

fn open(path: &Path, exaggeration: f64) -> Result<(Repository, World)> {
    if !(exaggeration.is_finite() && exaggeration > 0.0) {
        bail!("--exaggeration must be a positive number, not {exaggeration}");
    }
    let repo = Repository::open(path).with_context(|| format!("opening {}", path.display()))?;
    let world = exaggerated(&World::of_repository(&repo), exaggeration);
    Ok((repo, world))
}

fn cache_config(pool_mib: Option<u64>) -> CacheConfig {
    CacheConfig {
        pool_bytes: pool_mib.map(|m| m << 20),
        ..CacheConfig::default()
    }
}

pub fn run(args: &RenderArgs) -> Result<()> {
    if !(args.pixel_error.is_finite() && args.pixel_error > 0.0) {
        bail!("--pixel-error must be a positive number of pixels");
    }
    let (repo, world) = open(&args.repo, args.exaggeration)?;
    let cam = camera(&world, args.camera.as_deref(), args.size)?;
    let t = Instant::now();
    let cut = screen_error_cut(&repo, &world, &cam, args.pixel_error);
    let select_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let patches = decode_cut(&repo, &cut)?;
    let decode_s = t.elapsed().as_secs_f64();
    let gpu = Gpu::headless()?;
    let adapter = gpu.describe();
    let mut renderer = Renderer::new(gpu, world, cache_config(args.pool_mib))?;
    let options = RenderOptions {
        wireframe: args.wireframe,
        level_colours: args.levels,
        ..RenderOptions::default()
    };
    let frame = renderer.render(&cam, &patches, &options)?;
    let png = frame.to_png()?;
    cbdam_codec::atomic::write_atomically::<anyhow::Error>(&args.output, |f| {
        use std::io::Write;
        f.write_all(&png)?;
        Ok(())
    })
    .with_context(|| format!("writing {}", args.output.display()))?;
    let s = frame.stats;
    println!(
        "{}: {}×{}, {} half-patches drawn of {} ({} culled, {} not resident), {:.3} M triangles, \
         {} draw calls; cut {:.3} s, decode {:.3} s, frame {:.1} ms ({:.1} M triangles/s) on {}",
        args.output.display(),
        frame.width,
        frame.height,
        s.drawn,
        s.patches,
        s.culled,
        s.missing,
        s.triangles as f64 / 1e6,
        s.draw_calls,
        select_s,
        decode_s,
        (s.prepare_s + s.gpu_s) * 1e3,
        s.triangles as f64 / (s.prepare_s + s.gpu_s) / 1e6,
        adapter,
    );
    eprintln!(
        "eye {:.1},{:.1},{:.1} target {:.1},{:.1},{:.1} (world metres: x east, y north of the \
         data's north-west corner, z height)",
        cam.eye.x, cam.eye.y, cam.eye.z, cam.target.x, cam.target.y, cam.target.z
    );
    Ok(())
}

pub fn bench(args: &BenchRenderArgs) -> Result<()> {
    if args.runs == 0 {
        bail!("--runs must be at least 1");
    }
    let gpu_name = Gpu::headless()?.describe();
    println!(
        "{gpu_name}, {}×{}, {} px, median of {} frames after one warm-up frame (uploads)\n",
        args.size.0, args.size.1, args.pixel_error, args.runs
    );
    println!(
        "| repository | view | half-patches | M triangles | first frame ms | frame ms | M triangles/s |"
    );
    println!("|---|---|---:|---:|---:|---:|---:|");
    for path in &args.repos {
        let (repo, world) = open(path, 1.0)?;
        let mut renderer = Renderer::new(Gpu::headless()?, world, cache_config(None))?;
        for (view, cam) in [
            ("overview", Camera::overview(&world, args.size)),
            ("low oblique", low_oblique(&world, args.size)),
        ] {
            let cut = screen_error_cut(&repo, &world, &cam, args.pixel_error);
            let patches = decode_cut(&repo, &cut)?;
            let options = RenderOptions::default();
            let first = renderer.render(&cam, &patches, &options)?.stats;
            let mut times = Vec::with_capacity(args.runs);
            let mut last = first;
            for _ in 0..args.runs {
                last = renderer.render(&cam, &patches, &options)?.stats;
                times.push(last.prepare_s + last.gpu_s);
            }
            times.sort_by(f64::total_cmp);
            let median = times[times.len() / 2];
            println!(
                "| {} | {view} | {} | {:.3} | {:.1} | {:.1} | {:.1} |",
                path.file_name().unwrap_or_default().to_string_lossy(),
                last.drawn,
                last.triangles as f64 / 1e6,
                (first.prepare_s + first.gpu_s) * 1e3,
                median * 1e3,
                last.triangles as f64 / median / 1e6,
            );
        }
    }
    Ok(())
}
