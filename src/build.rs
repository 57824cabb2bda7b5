//! `cbdam build`: the arguments become one [`BuildOptions`], [`cbdam_builder::build`] does the
//! work, and this prints progress (a bar with ETA on a terminal, a line per quarter otherwise,
//! nothing with `--quiet`), the summary and, with `--timings`, the stage times.

use std::io::IsTerminal;
use std::sync::Mutex;
use std::time::Instant;

use anyhow::Result;
use cbdam_builder::journal::Resumed;
use cbdam_builder::{
    BuildOptions, BuildSummary, ColourSummary, ElevationSummary, Progress, ProgressEvent, Stage,
    planet::PlanetSummary,
};
use cbdam_codec::entropy::CoderKind;
use cbdam_codec::lifting::Alpha;
use indicatif::{ProgressBar, ProgressStyle};

use crate::{AlphaArg, BuildArgs, CoderArg};

pub use cbdam_builder::ExtraLevels;

/// Parses `--extra-levels`: `auto` or a number of level pairs, at most
/// [`ExtraLevels::MAX`]: each quadruples the domain's area, and with it the encoder's
/// reconstruction field (4 bytes a lattice point).
pub fn parse_extra_levels(text: &str) -> Result<ExtraLevels, String> {
    if text.eq_ignore_ascii_case("auto") {
        return Ok(ExtraLevels::Auto);
    }
    match text.parse::<u32>() {
        Ok(n) if n <= ExtraLevels::MAX => Ok(ExtraLevels::Fixed(n)),
        _ => Err(format!(
            "{text:?} is neither `auto` nor a number of level pairs from 0 to {}",
            ExtraLevels::MAX
        )),
    }
}

/// The build's options from the command line: the one place its flags become library types.
pub fn options(args: &BuildArgs) -> Result<BuildOptions> {
    let assign_georef = args.georef.assigned()?;
    Ok(BuildOptions {
        inputs: args.inputs.clone(),
        output: args.output.clone(),
        max_error: args.max_error,
        raw_size: args.size,
        memory_limit: args.memory_limit.map(|b| b.0),
        colour: args.colour,
        like: args.like.clone(),
        diamond_size: args.diamond_size,
        extra_levels: args.extra_levels,
        alpha: match args.alpha {
            AlphaArg::One => Alpha::One,
            AlphaArg::Half => Alpha::Half,
        },
        coder: match args.coder {
            CoderArg::Adaptive => CoderKind::Adaptive,
            CoderArg::AdaptiveTokens => CoderKind::AdaptiveTokens,
            CoderArg::EliasGamma => CoderKind::EliasGamma,
        },
        threads: args.threads,
        quantum: args.quantum,
        nodata: args.nodata,
        assign_georef,
        block_plan: args.block_plan,
        planet: args.planet.then_some(args.planet_level),
    })
}

/// Parses `--block-plan CUT,SIDE`.
pub fn parse_block_plan(text: &str) -> Result<cbdam_codec::hierarchy::BlockPlan, String> {
    let bad = || format!("{text:?}: expected CUT,SIDE (a level and a block side in lattice units)");
    let (cut, side) = text.split_once(',').ok_or_else(bad)?;
    let cut_level = cut.trim().parse::<u8>().map_err(|_| bad())?;
    let block_side = side.trim().parse::<i64>().map_err(|_| bad())?;
    if block_side < 1 {
        return Err(bad());
    }
    Ok(cbdam_codec::hierarchy::BlockPlan {
        cut_level,
        block_side,
    })
}

pub fn run(args: &BuildArgs) -> Result<()> {
    let start = Instant::now();
    let progress = Bars::new(args.quiet);
    let summary = cbdam_builder::build(&options(args)?, &progress);
    progress.finish();
    match summary? {
        BuildSummary::Elevation(s) => print_elevation(args, &s, start),
        BuildSummary::Colour(s) => print_colour(args, &s, start),
        BuildSummary::Planet(s) => print_planet(args, &s, start),
    }
}

/// `timings: STAGE T s, …, total T s (R` — the stage times of `--timings` and the rate of
/// `count` units over the whole run; the caller names the unit and closes the parenthesis.
fn timings(stages: &[(&'static str, std::time::Duration)], start: Instant, count: u64) -> String {
    let total = start.elapsed().as_secs_f64();
    let parts: Vec<String> = stages
        .iter()
        .map(|(name, d)| format!("{name} {:.3} s", d.as_secs_f64()))
        .collect();
    format!(
        "timings: {}, total {total:.3} s ({:.2}",
        parts.join(", "),
        count as f64 / total / 1e6
    )
}

fn print_elevation(args: &BuildArgs, s: &ElevationSummary, start: Instant) -> Result<()> {
    if args.timings {
        eprintln!(
            "{} M samples/s); reconstruction in {}",
            timings(&s.stages, start, (s.width * s.height) as u64),
            s.temporaries
        );
    }
    if !args.quiet {
        if s.lattice_mapped {
            eprintln!(
                "the {}×{} lattice went to memory-mapped temporary files, to stay under \
                 --memory-limit",
                s.width, s.height
            );
        }
        let bytes = std::fs::metadata(&args.output)?.len();
        let plan = &s.plan;
        println!(
            "{}: {}×{} samples ({} valid), {} bytes, {:.3} bits/sample, {} records, \
             max error {} m (unit {} m, k = {}), {:.2} s",
            args.output.display(),
            s.width,
            s.height,
            s.valid,
            bytes,
            bytes as f64 * 8.0 / (s.width * s.height) as f64,
            s.records,
            plan.max_error(),
            plan.unit,
            plan.quantizer.k(),
            start.elapsed().as_secs_f64()
        );
    }
    Ok(())
}

fn print_planet(args: &BuildArgs, s: &PlanetSummary, start: Instant) -> Result<()> {
    if args.timings {
        eprintln!(
            "{} M lattice points/s)",
            timings(&s.stages, start, s.lattice_points.min(s.held_points))
        );
    }
    if args.quiet {
        return Ok(());
    }
    let bytes = std::fs::metadata(&args.output)?.len();
    let plan = &s.plan;
    println!(
        "{}: planet (cube-sphere on WGS84), N = {}, K = {} ({:.4}° mean lattice spacing), {} \
         lattice points ({} with data), {} bytes, {:.3} bits/point, {} records, max error {} m \
         against the resampled lattice (unit {} m, k = {}), {:.2} s",
        args.output.display(),
        s.n,
        s.level_pairs,
        s.lattice_deg,
        s.lattice_points,
        s.valid,
        bytes,
        bytes as f64 * 8.0 / s.valid.max(1) as f64,
        s.records,
        plan.max_error(),
        plan.unit,
        plan.quantizer.k(),
        start.elapsed().as_secs_f64()
    );
    if s.held_points < s.lattice_points {
        println!(
            "  the build held {} of the lattice's points ({:.3} %): every point around the finest \
             inputs, every 2^s-th where only inputs of stride 2^s lie",
            s.held_points,
            100.0 * s.held_points as f64 / s.lattice_points as f64
        );
    }
    if s.capped {
        println!(
            "  the memory limit capped the lattice: the finest input is finer than {:.4}°, its \
             samples are area-averaged (--memory-limit or --planet-level to change)",
            s.lattice_deg
        );
    }
    for r in &s.resampling {
        if r.stride > 0 {
            println!(
                "  {} is coarser than the lattice: sampled on every {}-step lattice point, its \
                 region ends the hierarchy at level {} of {} (variable resolution)",
                r.path.display(),
                1u32 << r.stride,
                2 * s.level_pairs - 2 * r.stride,
                2 * s.level_pairs
            );
        }
        println!(
            "  resampling error of {}: max {:.3} m{}, rms {:.3} m over {} of its {} samples \
             (the others lie where a finer input won)",
            r.path.display(),
            r.max_error,
            r.worst_at.map_or(String::new(), |p| format!(
                " (at {:.4}°, {:.4}°)",
                p.lat, p.lon
            )),
            r.rms_error,
            r.compared,
            r.samples
        );
    }
    Ok(())
}

fn print_colour(args: &BuildArgs, s: &ColourSummary, start: Instant) -> Result<()> {
    if !args.quiet {
        let bytes = std::fs::metadata(&args.output)?.len();
        let px = s.width * s.height;
        println!(
            "{}: colour, {}×{} pixels, {} bytes, {:.3} bits/pixel, {} records, max error \
             {} levels (YCoCg k = {}: R, G, B within {:?}), {:.2} s",
            args.output.display(),
            s.width,
            s.height,
            bytes,
            bytes as f64 * 8.0 / px as f64,
            s.records,
            s.max_error,
            s.plan.quantizer.k(),
            s.rgb_bound,
            start.elapsed().as_secs_f64()
        );
    }
    Ok(())
}

/// Progress of the encode: a bar with ETA on a terminal, a log line per quarter otherwise (so
/// CI logs and pipes stay readable), nothing with `--quiet`.
enum Bars {
    Quiet,
    Bar(ProgressBar),
    Log(Mutex<usize>),
}

impl Bars {
    fn new(quiet: bool) -> Self {
        if quiet {
            Bars::Quiet
        } else if std::io::stderr().is_terminal() {
            let bar = ProgressBar::new(0);
            bar.set_style(
                ProgressStyle::with_template(
                    "encoding {bar:40} {percent:>3}%, {elapsed} elapsed, ETA {eta}",
                )
                .expect("static template"),
            );
            Bars::Bar(bar)
        } else {
            Bars::Log(Mutex::new(0))
        }
    }

    fn finish(&self) {
        if let Bars::Bar(bar) = self {
            bar.finish_and_clear();
        }
    }
}

impl Progress for Bars {
    fn event(&self, e: ProgressEvent) {
        match e.stage {
            Stage::Prepare => {}
            Stage::Encode => self.encoded(e.done, e.total),
            // The encode is over: the bar goes.
            Stage::EncodeCoarserRoots | Stage::Write => self.finish(),
        }
    }

    fn resumed(&self, r: &Resumed) {
        if matches!(self, Bars::Quiet) {
            return;
        }
        match r {
            Resumed::Fresh => {}
            Resumed::Continuing { blocks } => eprintln!(
                "resuming: {blocks} blocks finished by an earlier run of this build are kept \
                 (from OUTPUT.journal/)"
            ),
            Resumed::StartedOver { changed } => eprintln!(
                "starting over: the earlier run's journal was for other inputs or arguments \
                 ({changed})"
            ),
        }
    }
}

impl Bars {
    fn encoded(&self, done: usize, total: usize) {
        match self {
            Bars::Quiet => {}
            Bars::Bar(bar) => {
                bar.set_length(total as u64);
                bar.set_position(done as u64);
            }
            Bars::Log(logged) => {
                let q = done * 4 / total.max(1);
                // Workers report concurrently: log every quarter crossed, once and in order.
                let mut logged = logged.lock().unwrap_or_else(|e| e.into_inner());
                while *logged < q.min(4) {
                    *logged += 1;
                    eprintln!("encoding: {}% done", *logged * 25);
                }
            }
        }
    }
}
