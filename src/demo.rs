//! `cbdam demo`: the whole pipeline on the bundled SRTM tile, over HTTP on loopback — build (once),
//! serve, then the client against the server: the replay statistics of a flight and offscreen
//! frames rendered from what the client fetched, then the interactive viewer on the same URL
//! when a display is available. `--planet`: the same on a planet built from the bundled ETOPO5
//! global DEM with the bundled SRTM and Jacksboro tiles as insets. The flight's frames are also
//! written as one video ([`video`]).

mod video;

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use cbdam_server::{AppState, Config, RepoSpec};

use crate::{AlphaArg, BuildArgs, CoderArg, DemoArgs, RenderArgs, ReplayArgs, ViewArgs};

/// Frames per second of the flight (replay, frames and video).
const FPS: f64 = 30.0;

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
        let (inputs, max_error, planet_level) = if args.planet {
            eprintln!(
                "demo: building the planet {} from the bundled ETOPO5 (5′) with the SRTM and \
                 Jacksboro tiles (3″) as insets at their own spacing (K = 11, 0.0007° lattice, \
                 held in tiles: every point around the insets, every 64th elsewhere), ε = 4 m",
                repo.display()
            );
            let data = |f: &str| root.join("data").join(f);
            (
                vec![
                    data("etopo5_global.tif"),
                    data("srtm3_demcompare.tif"),
                    data("jacksboro_mpl.tif"),
                ],
                4.0,
                None,
            )
        } else {
            eprintln!(
                "demo: building {} from the bundled SRTM tile, ε = 1 m",
                repo.display()
            );
            (vec![root.join("data/srtm3_demcompare.tif")], 1.0, None)
        };
        crate::build::run(&BuildArgs {
            inputs,
            size: None,
            memory_limit: None,
            output: repo.clone(),
            max_error,
            diamond_size: 65,
            extra_levels: cbdam_builder::ExtraLevels::Auto,
            threads: None,
            coder: CoderArg::AdaptiveTokens,
            alpha: AlphaArg::One,
            quantum: None,
            nodata: None,
            georef: crate::GeorefArgs::default(),
            block_plan: None,
            planet: args.planet,
            planet_level,
            quiet: false,
            timings: false,
            colour: false,
            like: None,
        })?;
    }

    // The server runs on its own runtime thread for the whole demo.
    let spec: RepoSpec = format!("{name}={}", repo.display()).parse()?;
    let state = AppState::open(&[spec], Config::default())?;
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .context("starting the server runtime")?;
    let listener = rt
        .block_on(tokio::net::TcpListener::bind("127.0.0.1:0"))
        .context("binding a loopback port")?;
    let addr = listener.local_addr()?;
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let server = rt.spawn(cbdam_server::run(listener, state, async {
        let _ = stopped.await;
    }));
    let url = format!("http://{addr}/v1/repos/{name}");
    eprintln!("demo: serving {} at {url}", repo.display());

    let flight = root
        .join("data/flights")
        .join(args.flight.as_deref().unwrap_or(if args.planet {
            "planet/descent.json"
        } else {
            "descent.json"
        }));
    let csv = out.join("replay.csv");
    let frames = out.join("frames");
    let overview = out.join("overview.png");
    let t = Instant::now();
    let result = (|| -> Result<()> {
        eprintln!("demo: replaying {} over HTTP", flight.display());
        crate::replay::run(&ReplayArgs {
            repo: url.clone(),
            path: flight.clone(),
            size: (1920, 1080),
            pixel_error: 1.0,
            budget_ms: 2.0,
            out: csv.clone(),
            fps: FPS,
            max_settle_frames: 600,
            detail: false,
            cut_mib: 1024,
            colour: None,
            paced: false,
            no_decode_ahead: false,
        })?;
        let render = |output: Option<PathBuf>, path: Option<PathBuf>, out_dir: Option<PathBuf>| {
            crate::render::run(&RenderArgs {
                repo: PathBuf::from(&url),
                size: args.size,
                output,
                path,
                out_dir,
                fps: FPS,
                budget_ms: 2.0,
                max_frames: args.max_frames,
                camera: None,
                geo: None,
                pixel_error: 1.0,
                wireframe: false,
                levels: false,
                exaggeration: 1.0,
                pool_mib: None,
                colour: None,
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
        render(None, Some(flight.clone()), Some(frames.clone()))?;
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
        if args.no_view {
            return Ok(());
        }
        if !display_available() {
            eprintln!(
                "demo: no display (DISPLAY / WAYLAND_DISPLAY unset), so no viewer; \
                 the outputs above are offscreen renders"
            );
            return Ok(());
        }
        eprintln!("demo: opening the viewer on {url} (Esc quits; the server stops with it)");
        let viewed = crate::view::run(&ViewArgs {
            repo: PathBuf::from(&url),
            size: (1280, 720),
            pixel_error: 1.0,
            budget_ms: 2.0,
            no_vsync: false,
            max_frames: args.view_frames,
            screenshot: None,
            wireframe: false,
            levels: false,
            exaggeration: 1.0,
            pool_mib: None,
            colour: None,
        });
        // The offscreen outputs are made; a display that cannot take a window is not a
        // failure of the demo.
        match viewed {
            Ok(()) => eprintln!("demo: viewer closed"),
            Err(e) => eprintln!("demo: the viewer could not run: {e:#}"),
        }
        Ok(())
    })();
    let _ = stop.send(());
    let _ = rt.block_on(server);
    result
}

fn display_available() -> bool {
    ["DISPLAY", "WAYLAND_DISPLAY"]
        .iter()
        .any(|v| std::env::var_os(v).is_some_and(|s| !s.is_empty()))
}
