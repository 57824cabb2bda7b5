//! `cbdam demo`: the whole pipeline on the bundled SRTM tile, over HTTP on loopback — build (once),
//! serve, then the client against the server: the replay statistics of a flight and offscreen
//! frames rendered from what the client fetched, then the interactive viewer on the same URL
//! when a display is available. `--planet`: the same on a planet built from the bundled ETOPO5
//! global DEM with the bundled SRTM and Jacksboro tiles as insets.

use std::path::{Path, PathBuf};
use std::time::Instant;

mod video;

use anyhow::{Context, Result};
use cbdam_server::{AppState, Config, RepoSpec};
use clap::Args;

use crate::build::{AlphaArg, BuildArgs, CoderArg};
use crate::flags;
use crate::render::RenderArgs;
use crate::replay::ReplayArgs;
use crate::view::ViewArgs;

/// Frames per second of the flight (replay, frames and video).
const FPS: f64 = 30.0;

/// The surface as the viewers draw it by default: no wireframe, coloured by height, no
/// exaggeration.
const DEFAULT_LOOK: flags::Look = flags::Look {
    wireframe: false,
    levels: false,
    exaggeration: 1.0,
};

/// The whole pipeline on the bundled SRTM tile: builds a repository (once), serves it on
/// loopback, replays a flight against the server over HTTP and renders an overview and the
/// flight's frames offscreen from what the client fetched, and writes the flight as one video
/// (MP4 where ffmpeg is on the PATH, else an animated PNG); prints where the outputs are.
#[derive(Args, Debug)]
pub struct DemoArgs {
    /// Where the repository, CSV, PNGs and the video go.
    #[arg(long, default_value = "demo-out")]
    out_dir: PathBuf,
    /// Flight from data/flights/ (default descent.json; with --planet planet/descent.json).
    #[arg(long)]
    flight: Option<String>,
    /// A planet instead of the SRTM tile: the bundled ETOPO5 global DEM with the bundled SRTM and
    /// Jacksboro tiles as insets, resampled onto the cube-sphere on WGS84 at the insets' own 3″
    /// (K = 11, 0.0007° lattice), served, and flown from orbit down to the SRTM tile's summit.
    #[arg(long)]
    planet: bool,
    /// Size of the rendered frames.
    #[arg(long, value_parser = flags::Size2::pixels, default_value = "640x360")]
    size: (u32, u32),
    /// Render at most this many frames of the flight (all by default).
    #[arg(long)]
    max_frames: Option<u64>,
    /// Do not open the interactive viewer at the end (it opens when a display is available:
    /// DISPLAY or WAYLAND_DISPLAY set).
    #[arg(long)]
    no_view: bool,
    /// Close the viewer after this many frames (for scripts and tests; by default it stays open
    /// until Esc).
    #[arg(long)]
    view_frames: Option<u64>,
}

pub fn run(args: &DemoArgs) -> Result<()> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let out = &args.out_dir;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let (name, repo) = if args.planet {
        ("earth", out.join("earth.cbdam"))
    } else {
        ("srtm", out.join("srtm.cbdam"))
    };
    if repo.exists() {
        eprintln!("demo: using {} (delete it to rebuild)", repo.display());
    } else {
        build_repository(root, &repo, args.planet)?;
    }
    let server = LoopbackServer::start(name, &repo)?;
    let flight = root
        .join("data/flights")
        .join(args.flight.as_deref().unwrap_or(if args.planet {
            "planet/descent.json"
        } else {
            "descent.json"
        }));
    let result =
        fly_over_http(args, &server.url, &repo, &flight).map(|()| open_viewer(args, &server.url));
    server.stop();
    result
}

/// Builds the demo's repository `repo` from the bundled data: the SRTM tile, or with `planet`
/// the ETOPO5 globe with the SRTM and Jacksboro tiles as insets.
fn build_repository(root: &Path, repo: &Path, planet: bool) -> Result<()> {
    let data = |f: &str| root.join("data").join(f);
    let (inputs, max_error) = if planet {
        eprintln!(
            "demo: building the planet {} from the bundled ETOPO5 (5′) with the SRTM and \
             Jacksboro tiles (3″) as insets at their own spacing (K = 11, 0.0007° lattice, \
             held in tiles: every point around the insets, every 64th elsewhere), ε = 4 m",
            repo.display()
        );
        let tiles = [
            "etopo5_global.tif",
            "srtm3_demcompare.tif",
            "jacksboro_mpl.tif",
        ];
        (tiles.map(data).to_vec(), 4.0)
    } else {
        eprintln!(
            "demo: building {} from the bundled SRTM tile, ε = 1 m",
            repo.display()
        );
        (vec![data("srtm3_demcompare.tif")], 1.0)
    };
    crate::build::run(&BuildArgs {
        inputs,
        size: None,
        memory_limit: None,
        output: repo.to_path_buf(),
        max_error: Some(max_error),
        rms_error: None,
        diamond_size: flags::DiamondSize { value: 65 },
        extra_levels: cbdam_builder::ExtraLevels::Auto,
        threads: None,
        coder: CoderArg::AdaptiveTokens,
        alpha: AlphaArg::One,
        quantum: None,
        nodata: None,
        georef: flags::GeorefArgs::default(),
        block_plan: None,
        planet,
        planet_level: None,
        quiet: flags::Quiet { value: false },
        timings: false,
        colour: false,
        like: None,
    })
}

/// `cbdam serve` of one repository on a loopback port, on its own runtime thread for the whole
/// demo.
struct LoopbackServer {
    /// The repository's URL.
    url: String,
    runtime: tokio::runtime::Runtime,
    stop: tokio::sync::oneshot::Sender<()>,
    server: tokio::task::JoinHandle<Result<(), cbdam_server::ServerError>>,
}

impl LoopbackServer {
    fn start(name: &str, repo: &Path) -> Result<LoopbackServer> {
        let spec: RepoSpec = format!("{name}={}", repo.display()).parse()?;
        let state = AppState::open(&[spec], Config::default())?;
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .enable_all()
            .build()
            .context("starting the server runtime")?;
        let listener = runtime
            .block_on(tokio::net::TcpListener::bind("127.0.0.1:0"))
            .context("binding a loopback port")?;
        let addr = listener.local_addr()?;
        let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
        let server = runtime.spawn(cbdam_server::run(listener, state, async {
            let _ = stopped.await;
        }));
        let url = format!("http://{addr}/v1/repos/{name}");
        eprintln!("demo: serving {} at {url}", repo.display());
        Ok(LoopbackServer {
            url,
            runtime,
            stop,
            server,
        })
    }

    fn stop(self) {
        let _ = self.stop.send(());
        let _ = self.runtime.block_on(self.server);
    }
}

/// The client against the server at `url`: replays `flight` to a CSV, renders an overview and
/// the flight's frames offscreen, and prints where the outputs are.
fn fly_over_http(args: &DemoArgs, url: &str, repo: &Path, flight: &Path) -> Result<()> {
    let out = &args.out_dir;
    let csv = out.join("replay.csv");
    let frames = out.join("frames");
    let overview = out.join("overview.png");
    let t = Instant::now();
    eprintln!("demo: replaying {} over HTTP", flight.display());
    crate::replay::run(&ReplayArgs {
        repo: url.to_string(),
        path: flight.to_path_buf(),
        size: (1920, 1080),
        pixel_error: flags::PixelError { value: 1.0 },
        budget_ms: flags::BudgetMs { value: 2.0 },
        out: csv.clone(),
        fps: flags::Fps { value: FPS },
        max_settle_frames: 600,
        detail: false,
        cut_mib: 1024,
        colour: flags::Colour { value: None },
        paced: false,
        no_decode_ahead: false,
    })?;
    let render = |output: Option<PathBuf>, path: Option<PathBuf>, out_dir: Option<PathBuf>| {
        crate::render::run(&RenderArgs {
            repo: PathBuf::from(url),
            size: args.size,
            output,
            path,
            out_dir,
            fps: flags::Fps { value: FPS },
            budget_ms: flags::BudgetMs { value: 2.0 },
            max_frames: args.max_frames,
            camera: None,
            geo: None,
            pixel_error: flags::PixelError { value: 1.0 },
            look: DEFAULT_LOOK,
            pool_mib: flags::PoolMib { value: None },
            colour: flags::Colour { value: None },
            cut_out: None,
        })
    };
    eprintln!("demo: rendering an overview over HTTP");
    render(Some(overview.clone()), None, None)?;
    eprintln!("demo: rendering the flight's frames over HTTP (offscreen)");
    // Frames of an earlier, longer run would end up in the video.
    for stale in video::frames_in(&frames) {
        std::fs::remove_file(&stale)
            .with_context(|| format!("removing the earlier {}", stale.display()))?;
    }
    render(None, Some(flight.to_path_buf()), Some(frames.clone()))?;
    eprintln!("demo: writing the flight as one video");
    let video = video::write_flight(&frames, FPS, &out.join("flight"))?;
    println!(
        "demo finished in {:.1} s. Outputs:\n  repository      {}\n  replay CSV      {}\n  overview        {}\n  flight frames   {}/frame_*.png\n  flight video    {} ({})",
        t.elapsed().as_secs_f64(),
        repo.display(),
        csv.display(),
        overview.display(),
        frames.display(),
        video.path.display(),
        video.description
    );
    Ok(())
}

/// The interactive viewer on `url`, unless --no-view or there is no display. The offscreen
/// outputs are made; a display that cannot take a window is not a failure of the demo.
fn open_viewer(args: &DemoArgs, url: &str) {
    if args.no_view {
        return;
    }
    if !display_available() {
        eprintln!(
            "demo: no display (DISPLAY / WAYLAND_DISPLAY unset), so no viewer; \
             the outputs above are offscreen renders"
        );
        return;
    }
    eprintln!("demo: opening the viewer on {url} (Esc quits; the server stops with it)");
    let viewed = crate::view::run(&ViewArgs {
        repo: PathBuf::from(url),
        size: (1280, 720),
        pixel_error: flags::PixelError { value: 1.0 },
        budget_ms: 2.0,
        no_vsync: false,
        max_frames: args.view_frames,
        screenshot: None,
        look: DEFAULT_LOOK,
        pool_mib: flags::PoolMib { value: None },
        colour: flags::Colour { value: None },
    });
    match viewed {
        Ok(()) => eprintln!("demo: viewer closed"),
        Err(e) => eprintln!("demo: the viewer could not run: {e:#}"),
    }
}

fn display_available() -> bool {
    ["DISPLAY", "WAYLAND_DISPLAY"]
        .iter()
        .any(|v| std::env::var_os(v).is_some_and(|s| !s.is_empty()))
}
