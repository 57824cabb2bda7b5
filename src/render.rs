//! `cbdam render` (one offscreen frame, or a flight's frames, to PNG) and `cbdam bench render`
//! (frame times). Cuts come from the streaming client's refinement loop, as in `cbdam replay`.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use cbdam_client::access::{ColouredSource, DataSource, LocalSource};
use cbdam_client::camera::Camera;
use cbdam_client::flight::Flight;
use cbdam_client::refine::{FrameStats, Refiner};
use cbdam_client::stats::percentile;
use cbdam_client::world::World;
use cbdam_codec::repository::Repository;
use cbdam_render::{CacheConfig, Colouring, Frame, Gpu, RenderOptions, Renderer, write_png};
use clap::Args;
use glam::DVec3;

use crate::flags;
use crate::session::{budget_label, refine_config, terrain_source};

/// Render offscreen to PNG: one frame, or every frame of a camera flight (lavapipe works
/// where there is no GPU).
///
/// The cut is the streaming client's: the time-critical refinement loop of `cbdam replay`
/// over the local repository. For one frame (-o) it runs with an unlimited budget until the
/// cut converges for the view (every diamond in it within --pixel-error), then draws it. With
/// --path it flies the camera path at --fps with the real per-frame --budget-ms, as replay
/// does, and writes each frame to --out-dir/frame_NNNNN.png. Prints the frame time and
/// triangle count (with --path, median and p99 refine and render times).
#[derive(Args, Debug)]
#[command(mut_arg("fps", |a| a
    .help("With --path: frames per second of flight")
    .requires("path")))]
#[command(mut_arg("budget_ms", |a| a
    .help("With --path: refinement time budget per frame, ms (0 = unlimited)")
    .requires("path")))]
pub struct RenderArgs {
    /// Repository file, or its URL: http://HOST:PORT/v1/repos/NAME (cbdam serve),
    /// http://HOST:PORT/ (a server with one repository), or a .cbdam file on any server that
    /// honours range requests.
    pub(crate) repo: PathBuf,
    /// Image size WIDTHxHEIGHT.
    #[arg(long, value_parser = flags::Size2::pixels, default_value = "1920x1080")]
    pub(crate) size: (u32, u32),
    /// Output PNG (written atomically).
    #[arg(short, long, required_unless_present = "path", conflicts_with = "path")]
    pub(crate) output: Option<PathBuf>,
    /// Render every frame of this camera flight (JSON, as for `cbdam replay`) instead of one.
    #[arg(long, requires = "out_dir", conflicts_with = "camera")]
    pub(crate) path: Option<PathBuf>,
    /// With --path: directory for frame_00000.png, frame_00001.png, … (created if missing;
    /// each written atomically).
    #[arg(long, requires = "path")]
    pub(crate) out_dir: Option<PathBuf>,
    #[command(flatten)]
    pub(crate) fps: flags::Fps,
    #[command(flatten)]
    pub(crate) budget_ms: flags::BudgetMs,
    /// With --path: stop after this many frames.
    #[arg(long, requires = "path")]
    pub(crate) max_frames: Option<u64>,
    /// Camera eye_x,eye_y,eye_z,target_x,target_y,target_z in world metres: x east and y north
    /// of the data's north-west corner (so y is negative over the data), z height. Default: an
    /// overview of the whole data from the south.
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true, num_args = 1)]
    pub(crate) camera: Option<Vec<f64>>,
    /// A planet's camera: LAT,LON,HEIGHT_M[,HEADING_DEG,PITCH_DEG], geodetic degrees, height in
    /// metres above the WGS84 ellipsoid, heading clockwise from north (default 0), pitch
    /// negative when looking down (default -30). Without it (and --camera) a planet is shown
    /// whole, centred.
    #[arg(long, value_parser = flags::GeoView::parse, allow_hyphen_values = true,
          conflicts_with_all = ["camera", "path"])]
    pub(crate) geo: Option<flags::GeoView>,
    #[command(flatten)]
    pub(crate) pixel_error: flags::PixelError,
    #[command(flatten)]
    pub(crate) look: flags::Look,
    #[command(flatten)]
    pub(crate) pool_mib: flags::PoolMib,
    #[command(flatten)]
    pub(crate) colour: flags::Colour,
    /// Without --path: also write the cut's refined diamonds to this file, one id (`L-x-y`) a
    /// line, sorted as text (the browser viewer's test compares its cut with it).
    #[arg(long, value_name = "FILE")]
    pub(crate) cut_out: Option<PathBuf>,
}

/// A camera from `eye_x,eye_y,eye_z,target_x,target_y,target_z`, or the framed first view.
fn camera(world: &World, spec: Option<&[f64]>, size: (u32, u32)) -> Result<Camera> {
    let Some(v) = spec else {
        return Ok(Camera::framed(world, size));
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

/// The camera of `--geo` (planets only).
fn geo_camera(world: &World, g: &crate::flags::GeoView, size: (u32, u32)) -> Result<Camera> {
    if !world.is_planet() {
        bail!(
            "--geo needs a planet (a cube-sphere repository, `cbdam build --planet`); this \
             repository is planar: use --camera"
        );
    }
    Ok(Camera::geodetic(
        world,
        (g.lat, g.lon, g.height),
        (g.heading, g.pitch),
        45f64.to_radians(),
        size,
    ))
}

/// A low oblique view: from the south-south-west, 12° above the horizon, close enough that the
/// near terrain is much finer than the far (the adaptive case).
pub(crate) fn low_oblique(world: &World, size: (u32, u32)) -> Camera {
    let (lo, hi) = world.bounds();
    let centre = (lo + hi) * 0.5;
    let span = (hi - lo).x.max((hi - lo).y);
    let (az, el) = (200f64.to_radians(), 12f64.to_radians());
    let dir = DVec3::new(az.sin() * el.cos(), -az.cos() * el.cos(), el.sin());
    let eye = centre + dir * span * 0.55;
    let eye = DVec3::new(eye.x, eye.y, eye.z.max(hi.z + 0.02 * span));
    Camera::looking_at(world, eye, centre, 45f64.to_radians(), size)
}

/// Frames a still view may take to converge with an unlimited budget (one, in practice).
pub(crate) const SETTLE_FRAMES: u32 = 16;

pub(crate) fn open(path: &Path) -> Result<Arc<Repository>> {
    let repo = Repository::open(path).with_context(|| format!("opening {}", path.display()))?;
    Ok(Arc::new(repo))
}

/// The refinement loop over `repo` (with `colour` draped over it when given), with heights
/// exaggerated by `exaggeration`.
pub(crate) fn refiner(
    repo: &Arc<Repository>,
    colour: Option<&Arc<Repository>>,
    pixel_error: f64,
    budget_ms: f64,
    exaggeration: f64,
) -> Result<Refiner<Box<dyn DataSource>>> {
    let config = refine_config(pixel_error, budget_ms, exaggeration);
    let elevation = LocalSource::new(repo.clone());
    let source: Box<dyn DataSource> = match colour {
        Some(c) => Box::new(
            ColouredSource::new(elevation, LocalSource::new(c.clone()))
                .context("draping the colour repository")?,
        ),
        None => Box::new(elevation),
    };
    Refiner::new(source, config).context("starting the refiner")
}

/// Longest a remote render waits for the records its cut needs.
const REMOTE_SETTLE: Duration = Duration::from_secs(60);

pub(crate) fn cache_config(pool_mib: Option<u64>) -> CacheConfig {
    CacheConfig {
        pool_bytes: pool_mib.map(|m| m << 20),
        ..CacheConfig::default()
    }
}

pub fn run(args: &RenderArgs) -> Result<()> {
    let budget_ms = if args.path.is_some() {
        args.budget_ms.value
    } else {
        0.0
    };
    let config = refine_config(args.pixel_error.value, budget_ms, args.look.exaggeration);
    let (source, remote) =
        terrain_source(&args.repo.to_string_lossy(), args.colour.value.as_deref())?;
    let refiner = Refiner::new(source, config).context("starting the refiner")?;
    render_with(args, refiner, remote)
}

/// Waits (in real time) until the cut for `cam` converges with every record it needs fetched.
fn settle_remote<S: DataSource>(refiner: &mut Refiner<S>, cam: &Camera) -> FrameStats {
    let start = Instant::now();
    loop {
        let s = refiner.frame(cam);
        if (s.converged && s.access.in_flight == 0) || start.elapsed() > REMOTE_SETTLE {
            return s;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// Prints the camera's eye and target to stderr: world metres, or on a planet ECEF metres and
/// the eye's latitude, longitude and height.
fn print_camera(world: &World, cam: &Camera) {
    if world.is_planet() {
        let g = cbdam_codec::geodesy::Geodetic::from_ecef(cam.eye.to_array());
        eprintln!(
            "eye {:.1},{:.1},{:.1} target {:.1},{:.1},{:.1} (ECEF metres); eye at lat {:.6}, \
         lon {:.6}, {:.1} m above the ellipsoid",
            cam.eye.x,
            cam.eye.y,
            cam.eye.z,
            cam.target.x,
            cam.target.y,
            cam.target.z,
            g.lat,
            g.lon,
            g.height
        );
    } else {
        eprintln!(
            "eye {:.1},{:.1},{:.1} target {:.1},{:.1},{:.1} (world metres: x east, y north of \
         the data's north-west corner, z height)",
            cam.eye.x, cam.eye.y, cam.eye.z, cam.target.x, cam.target.y, cam.target.z
        );
    }
}

/// Writes the cut's refined diamonds to `file`, one id (`L-x-y`) a line, sorted as text.
fn write_cut<S: DataSource>(refiner: &Refiner<S>, file: &Path) -> Result<()> {
    let mut ids: Vec<String> = refiner.cut().refined().map(|id| id.to_string()).collect();
    ids.sort();
    let text: String = ids.iter().map(|id| format!("{id}\n")).collect();
    std::fs::write(file, text).with_context(|| format!("writing {}", file.display()))
}

/// One frame or a flight, from any source. `remote`: records arrive over the network, so the
/// loop waits for them in real time (single frames) or paces the flight at `--fps`.
fn render_with<S: DataSource>(
    args: &RenderArgs,
    mut refiner: Refiner<S>,
    remote: bool,
) -> Result<()> {
    let world = *refiner.world();
    let options = RenderOptions {
        wireframe: args.look.wireframe,
        level_colours: args.look.levels,
        ..RenderOptions::default()
    };
    if let (Some(path), Some(dir)) = (&args.path, &args.out_dir) {
        return fly(args, path, dir, refiner, &options, remote);
    }
    let output = args
        .output
        .as_deref()
        .expect("clap requires -o without --path");
    let cam = match &args.geo {
        Some(g) => geo_camera(&world, g, args.size)?,
        None => camera(&world, args.camera.as_deref(), args.size)?,
    };
    let t = Instant::now();
    let settled = if remote {
        settle_remote(&mut refiner, &cam)
    } else {
        refiner.settle(&cam, SETTLE_FRAMES)
    };
    let refine_s = t.elapsed().as_secs_f64();
    if !settled.met_target {
        eprintln!(
            "cbdam: warning: the cut did not meet the target in {SETTLE_FRAMES} frames (max \
             error {:.3} px)",
            settled.max_screen_error_px
        );
    }
    for e in refiner.errors() {
        eprintln!("cbdam: warning: {e}");
    }
    if let Some(file) = &args.cut_out {
        write_cut(&refiner, file)?;
    }
    let patches: Vec<_> = refiner.drawn().cloned().collect();
    let gpu = Gpu::headless()?;
    let adapter = gpu.describe();
    let draped = refiner.source().drape().is_some();
    let mut renderer = Renderer::with_colour(
        gpu,
        world,
        cache_config(args.pool_mib.value),
        Colouring::draped_if(draped),
    )?;
    let frame = renderer.render(&cam, &patches, &options)?;
    write_png(output, &frame)?;
    let s = frame.stats;
    println!(
        "{}: {}×{}, {} half-patches drawn of {} ({} culled, {} not resident), {:.3} M triangles, \
         {} draw calls; cut {:.3} s ({} refinement frames, {} diamonds refined, max error {:.3} \
         px), frame {:.1} ms ({:.1} M triangles/s) on {}",
        output.display(),
        frame.width,
        frame.height,
        s.drawn,
        s.patches,
        s.culled,
        s.missing,
        s.triangles as f64 / 1e6,
        s.draw_calls,
        refine_s,
        settled.frame,
        settled.refined,
        settled.max_screen_error_px,
        (s.prepare_s + s.gpu_s) * 1e3,
        s.triangles as f64 / (s.prepare_s + s.gpu_s) / 1e6,
        adapter,
    );
    print_camera(&world, &cam);
    Ok(())
}

/// `cbdam render --path`: every frame of a flight, refined with the per-frame budget.
fn fly<S: DataSource>(
    args: &RenderArgs,
    path: &Path,
    dir: &Path,
    mut refiner: Refiner<S>,
    options: &RenderOptions,
    remote: bool,
) -> Result<()> {
    let flight = Flight::load(path).with_context(|| format!("loading {}", path.display()))?;
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let world = *refiner.world();
    let gpu = Gpu::headless()?;
    let adapter = gpu.describe();
    let draped = refiner.source().drape().is_some();
    let mut renderer = Renderer::with_colour(
        gpu,
        world,
        cache_config(args.pool_mib.value),
        Colouring::draped_if(draped),
    )?;
    let mut frames = (flight.duration() * args.fps.value).ceil() as u64 + 1;
    if let Some(max) = args.max_frames {
        frames = frames.min(max);
    }
    let progress = FrameProgress::new(frames);
    let run = draw_flight(
        &mut refiner,
        &mut renderer,
        &flight,
        FlightPacing {
            fps: args.fps.value,
            frames,
            size: args.size,
            real_time: remote,
        },
        options,
        |i, frame| {
            write_png(&dir.join(format!("frame_{i:05}.png")), frame)?;
            progress.frame_written();
            Ok(())
        },
    )?;
    progress.finish();
    print_flight_figures(args, dir, frames, &adapter, run);
    for e in refiner.errors() {
        eprintln!("cbdam: warning: {e}");
    }
    Ok(())
}

/// The figures of a flight drawn to `dir`: its settings, then the median and p99 of the
/// refinement and render times per frame and the triangles drawn.
fn print_flight_figures(args: &RenderArgs, dir: &Path, frames: u64, adapter: &str, run: FlightRun) {
    let FlightRun {
        mut refine_ms,
        mut render_ms,
        mut tris,
        over,
        max_err,
    } = run;
    refine_ms.sort_by(f64::total_cmp);
    render_ms.sort_by(f64::total_cmp);
    tris.sort_unstable();
    println!(
        "{}: {frames} frames at {} fps, {}×{}, target {} px, budget {}, on {adapter}",
        dir.display(),
        args.fps.value,
        args.size.0,
        args.size.1,
        args.pixel_error.value,
        budget_label(args.budget_ms.value)
    );
    println!(
        "refine ms per frame: median {:.3}, p99 {:.3}; budget exhausted in {over} frames; \
         largest error {max_err:.3} px",
        percentile(&refine_ms, 0.5),
        percentile(&refine_ms, 0.99),
    );
    println!(
        "render ms per frame: median {:.3}, p99 {:.3}",
        percentile(&render_ms, 0.5),
        percentile(&render_ms, 0.99),
    );
    println!(
        "triangles drawn per frame: median {}, max {}",
        percentile(&tris, 0.5),
        tris.last().copied().unwrap_or(0),
    );
}

/// How a flight is stepped: `frames` frames at `fps`, of `size`; `real_time` waits for each
/// frame's due time (records arriving over a network need it).
#[derive(Clone, Copy)]
pub(crate) struct FlightPacing {
    pub(crate) fps: f64,
    pub(crate) frames: u64,
    pub(crate) size: (u32, u32),
    pub(crate) real_time: bool,
}

/// Per-frame figures of one flight: refinement and render (CPU preparation + GPU) ms, triangles
/// drawn, frames that ran out of refinement budget and the largest screen error of any frame.
pub(crate) struct FlightRun {
    pub(crate) refine_ms: Vec<f64>,
    pub(crate) render_ms: Vec<f64>,
    pub(crate) tris: Vec<u64>,
    pub(crate) over: usize,
    pub(crate) max_err: f64,
}

/// Flies `flight`: each frame refines (within the refiner's budget), draws the cut and hands the
/// frame to `each` (which is not timed).
pub(crate) fn draw_flight<S: DataSource>(
    refiner: &mut Refiner<S>,
    renderer: &mut Renderer,
    flight: &Flight,
    pacing: FlightPacing,
    options: &RenderOptions,
    mut each: impl FnMut(u64, &Frame) -> Result<()>,
) -> Result<FlightRun> {
    let world = *refiner.world();
    let mut run = FlightRun {
        refine_ms: Vec::new(),
        render_ms: Vec::new(),
        tris: Vec::new(),
        over: 0,
        max_err: 0.0,
    };
    let start = Instant::now();
    for i in 0..pacing.frames {
        let t = (i as f64 / pacing.fps).min(flight.duration());
        if pacing.real_time {
            let due = Duration::from_secs_f64(i as f64 / pacing.fps);
            std::thread::sleep(due.saturating_sub(start.elapsed()));
        }
        let cam = flight.camera(&world, t, pacing.size);
        let s = refiner.frame(&cam);
        let patches: Vec<_> = refiner.drawn().cloned().collect();
        let frame = renderer.render(&cam, &patches, options)?;
        each(i, &frame)?;
        run.refine_ms.push(s.refine_ms);
        run.render_ms
            .push((frame.stats.prepare_s + frame.stats.gpu_s) * 1e3);
        run.tris.push(frame.stats.triangles);
        run.over += usize::from(s.budget_exhausted);
        run.max_err = run.max_err.max(s.max_screen_error_px);
    }
    Ok(run)
}

/// Progress of a flight's frames on stderr: a bar on a terminal, otherwise a line at each
/// quarter (a log keeps them), so that a long software-rendered flight shows it is moving.
struct FrameProgress {
    bar: indicatif::ProgressBar,
    total: u64,
    written: std::cell::Cell<u64>,
    terminal: bool,
}

impl FrameProgress {
    fn new(total: u64) -> Self {
        use std::io::IsTerminal;
        let terminal = std::io::stderr().is_terminal();
        let bar = if terminal {
            let bar = indicatif::ProgressBar::new(total);
            bar.set_style(
                indicatif::ProgressStyle::with_template(
                    "frames {bar:40} {pos}/{len}, {elapsed} elapsed, ETA {eta}",
                )
                .expect("static template"),
            );
            bar
        } else {
            indicatif::ProgressBar::hidden()
        };
        FrameProgress {
            bar,
            total,
            written: std::cell::Cell::new(0),
            terminal,
        }
    }

    fn frame_written(&self) {
        let done = self.written.get() + 1;
        self.written.set(done);
        self.bar.inc(1);
        let quarter = |n: u64| n * 4 / self.total.max(1);
        if !self.terminal && quarter(done) > quarter(done - 1) {
            eprintln!("rendering: {done} of {} frames", self.total);
        }
    }

    fn finish(&self) {
        self.bar.finish_and_clear();
    }
}
