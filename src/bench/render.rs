//! `cbdam bench render`: offscreen frame time and triangle rate of the renderer, still views and
//! flights, drawn as `cbdam render` draws them.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use cbdam_client::camera::Camera;
use cbdam_client::flight::Flight;
use cbdam_client::stats::percentile;
use cbdam_client::world::World;
use cbdam_render::{Colouring, Gpu, RenderOptions, Renderer};
use clap::Args;

use crate::flags;
use crate::render::{
    FlightPacing, SETTLE_FRAMES, cache_config, draw_flight, low_oblique, open, refiner,
};
use crate::session::budget_label;

/// Offscreen frame time and triangle rate of the renderer on repositories, overview and a
/// low oblique view, as a Markdown table.
#[derive(Args, Debug)]
pub struct BenchRenderArgs {
    /// Repository files.
    #[arg(required = true)]
    repos: Vec<PathBuf>,
    /// Image size WIDTHxHEIGHT.
    #[arg(long, value_parser = flags::Size2::pixels, default_value = "1920x1080")]
    size: (u32, u32),
    #[command(flatten)]
    pixel_error: flags::PixelError,
    /// Timed frames per view; the median is reported.
    #[arg(long, default_value_t = 5)]
    runs: usize,
    /// Also fly this camera path (repeatable, e.g. data/flights/*.json): every frame refines
    /// within --budget-ms and is drawn; frame time percentiles and triangle rate are reported.
    #[arg(long = "flight", value_name = "FLIGHT.json")]
    flights: Vec<PathBuf>,
    #[command(flatten)]
    fps: flags::Fps,
    #[command(flatten)]
    budget_ms: flags::BudgetMs,
    /// At most this many frames per flight.
    #[arg(long)]
    max_frames: Option<u64>,
    /// Drape this colour repository over each repository too and time both (the colour must
    /// match every repository given).
    #[arg(long, value_name = "COLOUR_REPO")]
    colour: Option<PathBuf>,
}

pub fn run(args: &BenchRenderArgs) -> Result<()> {
    if args.runs == 0 {
        bail!("--runs must be at least 1");
    }
    let gpu_name = Gpu::headless()?.describe();
    println!(
        "{gpu_name}, {}×{}, {} px, median of {} frames after one warm-up frame (uploads)\n",
        args.size.0, args.size.1, args.pixel_error.value, args.runs
    );
    println!(
        "| repository | view | half-patches | M triangles | first frame ms | frame ms | M triangles/s |"
    );
    println!("|---|---|---:|---:|---:|---:|---:|");
    let colour = args.colour.as_deref().map(open).transpose()?;
    for path in &args.repos {
        let repo = open(path)?;
        let world = World::of_repository(&repo);
        let mut renderers = vec![(
            Renderer::new(Gpu::headless()?, world, cache_config(None))?,
            None,
        )];
        if let Some(c) = &colour {
            let r = Renderer::with_colour(
                Gpu::headless()?,
                world,
                cache_config(None),
                Colouring::Draped,
            )?;
            renderers.push((r, Some(c)));
        }
        // Plain and draped rows alternate, so that load changes on a shared machine affect both.
        for (view, cam) in [
            ("overview", Camera::overview(&world, args.size)),
            ("low oblique", low_oblique(&world, args.size)),
        ] {
            for (renderer, colour) in &mut renderers {
                let view = if colour.is_some() {
                    format!("{view}, colour")
                } else {
                    view.to_string()
                };
                let mut refiner = refiner(&repo, *colour, args.pixel_error.value, 0.0, 1.0)?;
                refiner.settle(&cam, SETTLE_FRAMES);
                let patches: Vec<_> = refiner.drawn().cloned().collect();
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
                    "| {} | {view} | {} | {:.3} | {:.1} | {:.1} | {:.3} |",
                    path.file_name().unwrap_or_default().to_string_lossy(),
                    last.drawn,
                    last.triangles as f64 / 1e6,
                    (first.prepare_s + first.gpu_s) * 1e3,
                    median * 1e3,
                    last.triangles as f64 / median / 1e6,
                );
            }
        }
    }
    if !args.flights.is_empty() {
        bench_flights(args)?;
    }
    Ok(())
}

/// `bench render --flight`: each flight over each repository, drawn frame by frame as
/// `render --path` does (without writing the frames).
fn bench_flights(args: &BenchRenderArgs) -> Result<()> {
    println!(
        "\nflights: {} fps of flight time, refinement budget {}; frame = CPU preparation + GPU \
         of the draw (refinement is timed apart); triangle rate = median over frames of \
         triangles / frame time\n",
        args.fps.value,
        budget_label(args.budget_ms.value)
    );
    println!(
        "| repository | flight | frames | frame ms median | frame ms p99 | M triangles/frame \
         median | M triangles/s | refine ms p99 |"
    );
    println!("|---|---|---:|---:|---:|---:|---:|---:|");
    for path in &args.repos {
        let repo = open(path)?;
        let world = World::of_repository(&repo);
        for flight_path in &args.flights {
            let flight = Flight::load(flight_path)
                .with_context(|| format!("loading {}", flight_path.display()))?;
            let mut frames = (flight.duration() * args.fps.value).ceil() as u64 + 1;
            if let Some(max) = args.max_frames {
                frames = frames.min(max);
            }
            let mut refiner = refiner(
                &repo,
                None,
                args.pixel_error.value,
                args.budget_ms.value,
                1.0,
            )?;
            let mut renderer = Renderer::new(Gpu::headless()?, world, cache_config(None))?;
            let pacing = FlightPacing {
                fps: args.fps.value,
                frames,
                size: args.size,
                real_time: false,
            };
            let options = RenderOptions::default();
            let mut run = draw_flight(
                &mut refiner,
                &mut renderer,
                &flight,
                pacing,
                &options,
                |_, _| Ok(()),
            )?;
            let mut rate: Vec<f64> = run
                .tris
                .iter()
                .zip(&run.render_ms)
                .map(|(&t, &ms)| t as f64 / (ms / 1e3) / 1e6)
                .collect();
            run.render_ms.sort_by(f64::total_cmp);
            run.refine_ms.sort_by(f64::total_cmp);
            run.tris.sort_unstable();
            rate.sort_by(f64::total_cmp);
            println!(
                "| {} | {} | {frames} | {:.1} | {:.1} | {:.3} | {:.3} | {:.3} |",
                path.file_name().unwrap_or_default().to_string_lossy(),
                flight_path
                    .file_name()
                    .unwrap_or_default()
                    .to_string_lossy(),
                percentile(&run.render_ms, 0.5),
                percentile(&run.render_ms, 0.99),
                percentile(&run.tris, 0.5) as f64 / 1e6,
                percentile(&rate, 0.5),
                percentile(&run.refine_ms, 0.99),
            );
        }
    }
    Ok(())
}
