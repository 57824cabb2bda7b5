//! `cbdam build`: the arguments become one [`BuildOptions`], [`cbdam_builder::build`] does the
//! work, and this prints progress (a bar with ETA on a terminal, a line per quarter otherwise,
//! nothing with `--quiet`), the summary and, with `--timings`, the stage times.

use std::io::IsTerminal;
use std::path::PathBuf;
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
use clap::{Args, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};

use crate::flags;

pub use cbdam_builder::ExtraLevels;

/// Entropy coder of `cbdam build`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum CoderArg {
    /// Bitwise adaptive binary arithmetic coder (about 1 % smaller, slower to decode).
    Adaptive,
    /// Adaptive token coder: the bitwise coder's contexts, a binarisation made for fast
    /// decoding (the default).
    AdaptiveTokens,
    /// Elias-gamma codes (simpler, faster to decode).
    EliasGamma,
    /// Golomb–Rice codes with a per-band parameter table, no arithmetic coding: the fastest
    /// to decode, larger files (docs/FORMAT.md).
    FastRice,
    /// The adaptive token coder with each cell's context also seeing the spread of its four
    /// corners on the diamond's grid: smaller files (docs/FORMAT.md, coder id 4).
    AdaptiveGrid,
    /// `adaptive-grid` with each band's indices predicted from their decoded neighbours in the
    /// band, the predictor chosen per band (docs/FORMAT.md, coder id 5).
    #[value(name = "adaptive-inband")]
    AdaptiveInBand,
}

impl CoderArg {
    /// The codec's coder this flag value names.
    pub(crate) fn kind(self) -> CoderKind {
        match self {
            CoderArg::Adaptive => CoderKind::Adaptive,
            CoderArg::AdaptiveTokens => CoderKind::AdaptiveTokens,
            CoderArg::EliasGamma => CoderKind::EliasGamma,
            CoderArg::FastRice => CoderKind::FastRice,
            CoderArg::AdaptiveGrid => CoderKind::AdaptiveGrid,
            CoderArg::AdaptiveInBand => CoderKind::AdaptiveInBand,
        }
    }
}

/// Lifting weight of `cbdam build`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum AlphaArg {
    /// α = 1: the coarse levels are subsamples of the input.
    #[value(name = "1")]
    One,
    /// α = ½: the coarse levels are low-pass filtered.
    #[value(name = "0.5")]
    Half,
}

/// Build a repository from one DEM, or from several at power-of-two spacings (one
/// variable-resolution dataset), in parallel, within a memory limit.
#[derive(Args, Debug)]
pub struct BuildArgs {
    /// DEM files (GeoTIFF, .hgt, ASCII grid, PNG, or one raw float32 with --size); several
    /// georeferenced ones at power-of-two spacings make one variable-resolution dataset.
    ///
    /// Tiles: an input may also be a directory (every .tif, .tiff, .hgt, .asc and .png in it,
    /// sorted by name, not recursive), a glob (`*`, `?`, `[...]` in the last path component;
    /// quote it), @LIST (one path a line, relative to the list file; blank lines and `#`
    /// comments skipped) or a GDAL VRT mosaic as gdalbuildvrt writes it (whole tiles placed by
    /// SrcRect/DstRect without scaling, one band, NoDataValue; any other element or attribute
    /// is refused by name). Tiles of one spacing that overlap (shared edge rows, as in SRTM)
    /// must agree there, or the build names the two tiles that disagree and by how much. Any
    /// number of tiles: they are placed from their headers and read a band of rows at a time.
    #[arg(required = true, num_args = 1..)]
    pub(crate) inputs: Vec<PathBuf>,
    /// The input is headerless little-endian float32, WIDTHxHEIGHT samples, row 0 north
    /// (streamed: never held in memory as floats).
    #[arg(long, value_name = "WIDTHxHEIGHT", value_parser = flags::Size2::samples)]
    pub(crate) size: Option<(usize, usize)>,
    /// Memory budget, e.g. 2G or 512M (K, M, G, T are powers of 1024). Above it, the encoder's
    /// reconstruction field is a memory-mapped temporary file instead of anonymous memory.
    /// Default: half of physical memory.
    #[arg(long, value_name = "SIZE")]
    pub(crate) memory_limit: Option<flags::ByteSize>,
    /// Output repository (written atomically: a temporary file renamed into place).
    #[arg(short, long)]
    pub(crate) output: PathBuf,
    /// Guaranteed maximum error of every reconstructed sample, metres; with --colour, whole
    /// 8-bit levels bounding every decoded R, G and B component (0 = lossless). With
    /// --rms-error, a cap on the maximum error (both bounds hold).
    #[arg(
        long,
        allow_hyphen_values = true,
        required_unless_present = "rms_error"
    )]
    pub(crate) max_error: Option<f64>,
    /// Bound the root-mean-square error of the finest level over every valid sample instead,
    /// metres: the build picks the coarsest quantizer whose decoded surface, measured, meets
    /// it (one input DEM only; several trial encodes). The header records the bound and the
    /// RMS error measured; `verify` checks it.
    #[arg(long, allow_hyphen_values = true, conflicts_with_all = ["colour", "planet"])]
    pub(crate) rms_error: Option<f64>,
    /// The input is an 8-bit RGB/RGBA PNG or RGB GeoTIFF: build a colour repository (YCoCg-R,
    /// each component coded like elevation) to drape over an elevation repository.
    #[arg(long)]
    pub(crate) colour: bool,
    /// With --colour: lay the colour over this elevation repository's domain (its diamond size
    /// and roots; the image must be (W − 1)·2^m + 1 × (H − 1)·2^m + 1 of its W × H samples; a
    /// PNG gets its georeferencing, scaled).
    #[arg(long, value_name = "ELEVATION.cbdam")]
    pub(crate) like: Option<PathBuf>,
    #[command(flatten)]
    pub(crate) diamond_size: flags::DiamondSize,
    /// Level pairs above the smallest hierarchy that covers the data: each makes the roots 4×
    /// sparser and codes the terrain between them as residuals instead. `auto` tries one more
    /// where the root field is most of the repository (small or smooth inputs at loose
    /// tolerances) and keeps the smaller file.
    #[arg(long, default_value = "auto", value_parser = parse_extra_levels)]
    pub(crate) extra_levels: ExtraLevels,
    /// Worker threads for encoding (default: all cores).
    #[arg(long)]
    pub(crate) threads: Option<usize>,
    /// Entropy coder.
    #[arg(long, value_enum, default_value_t = CoderArg::AdaptiveTokens)]
    pub(crate) coder: CoderArg,
    /// Lifting weight α.
    #[arg(long, value_enum, default_value_t = AlphaArg::One)]
    pub(crate) alpha: AlphaArg,
    /// The data's value quantum in metres (default: detected from the samples).
    #[arg(long)]
    pub(crate) quantum: Option<f64>,
    /// Nodata value, overriding the file's own.
    #[arg(long, allow_hyphen_values = true)]
    pub(crate) nodata: Option<f64>,
    #[command(flatten)]
    pub(crate) georef: flags::GeorefArgs,
    /// Benchmarks: encode the levels from CUT down in blocks SIDE lattice units across (with a
    /// journal), whatever the input's size and the memory limit would choose.
    #[arg(long, value_name = "CUT,SIDE", hide = true, value_parser = parse_block_plan)]
    pub(crate) block_plan: Option<cbdam_codec::hierarchy::BlockPlan>,
    /// Build a planet: the inputs (EPSG:4326 latitude/longitude GeoTIFFs, SRTM .hgt, UTM zones)
    /// resampled onto the cube-sphere lattice on WGS84 (docs/PLANET.md) — bilinear where the
    /// lattice is finer than an input, area-averaged where coarser, the finest input winning
    /// where they overlap. The lattice is the coarsest as fine as the finest input, within
    /// --memory-limit (about 40 bytes per lattice point); the summary says when the limit made
    /// it coarser, and how far the lattice is from each input's samples. The inputs are read
    /// when the resampling asks for them, keeping at most an eighth of --memory-limit of them.
    #[arg(long)]
    pub(crate) planet: bool,
    /// With --planet: the lattice's level pairs K (faces of (N − 1)·2^K steps, a mean spacing of
    /// 90°/((N − 1)·2^K)) instead of the one the finest input asks for.
    #[arg(long, value_name = "K", requires = "planet")]
    pub(crate) planet_level: Option<u32>,
    #[command(flatten)]
    pub(crate) quiet: flags::Quiet,
    /// Print the wall time of each stage (read and plan, quantize, encode, write) to stderr.
    #[arg(long)]
    pub(crate) timings: bool,
}

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
        max_error: args.max_error.unwrap_or(f64::INFINITY),
        rms_error: args.rms_error,
        raw_size: args.size,
        memory_limit: args.memory_limit.map(|b| b.0),
        colour: args.colour,
        like: args.like.clone(),
        diamond_size: args.diamond_size.value,
        extra_levels: args.extra_levels,
        alpha: match args.alpha {
            AlphaArg::One => Alpha::One,
            AlphaArg::Half => Alpha::Half,
        },
        coder: args.coder.kind(),
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
    let progress = Bars::new(args.quiet.value);
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
    if !args.quiet.value {
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
             max error {} (unit {} m, k = {}){}, {:.2} s",
            args.output.display(),
            s.width,
            s.height,
            s.valid,
            bytes,
            bytes as f64 * 8.0 / (s.width * s.height) as f64,
            s.records,
            plan.bound_text(),
            plan.unit,
            plan.quantizer.k(),
            plan.rms.map_or(String::new(), |r| format!(
                ", RMS error {:.4} m (bound {} m)",
                r.measured, r.target
            )),
            start.elapsed().as_secs_f64()
        );
    }
    Ok(())
}

fn print_planet(args: &BuildArgs, s: &PlanetSummary, start: Instant) -> Result<()> {
    if args.timings {
        print_planet_timings(s, start);
    }
    if args.quiet.value {
        return Ok(());
    }
    let bytes = std::fs::metadata(&args.output)?.len();
    let plan = &s.plan;
    println!(
        "{}: planet (cube-sphere on WGS84), N = {}, K = {} ({:.4}° mean lattice spacing), {} \
         lattice points ({} with data), {} bytes, {:.3} bits/point, {} records, max error {} \
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
        plan.bound_text(),
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
    if s.level_pairs < s.finest_input_level_pairs {
        println!(
            "  --planet-level {} is coarser than the finest input asks (K = {}): its samples are \
             area-averaged on a {:.4}° lattice",
            s.level_pairs, s.finest_input_level_pairs, s.lattice_deg
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

/// `--timings` of a planet build: the stages, the input reads and the blocks (stderr).
fn print_planet_timings(s: &PlanetSummary, start: Instant) {
    eprintln!(
        "{} M lattice points/s)",
        timings(&s.stages, start, s.lattice_points.min(s.held_points))
    );
    eprintln!(
        "inputs read from their files {} times ({} inputs; once for the height range, then \
         when the resampling asks for one its cache has let go)",
        s.inputs_read,
        s.resampling.len()
    );
    if !s.reads.is_empty() {
        let steps: Vec<String> = s
            .reads
            .iter()
            .map(|(step, n)| format!("{step} {n}"))
            .collect();
        eprintln!("inputs read by each step: {}", steps.join(", "));
    }
    if let Some((blocks, tiles)) = s.blocks {
        eprintln!("encoded in {blocks} blocks of the lattice's {tiles} tiles");
    }
    if !s.painted.is_empty() {
        let steps: Vec<String> = s
            .painted
            .iter()
            .map(|(step, n)| format!("{step} {:.1} M", *n as f64 / 1e6))
            .collect();
        eprintln!(
            "lattice points painted (resampled from the inputs; again counts again): {}",
            steps.join(", ")
        );
        eprintln!(
            "lattice points the outline proved to take a fine input's valid sample, not painted: \
             {:.1} M",
            s.outline_covered as f64 / 1e6
        );
    }
    if !s.peaks.is_empty() {
        let steps: Vec<String> = s
            .peaks
            .iter()
            .map(|(step, b)| format!("{step} {:.1} MiB", *b as f64 / (1u64 << 20) as f64))
            .collect();
        eprintln!("peak resident memory after each step: {}", steps.join(", "));
    }
    if !s.cpu.is_empty() {
        let steps: Vec<String> = s
            .cpu
            .iter()
            .map(|(step, (user, sys))| format!("{step} {user:.2} + {sys:.2} s"))
            .collect();
        eprintln!("CPU of each step (user + system): {}", steps.join(", "));
    }
}

fn print_colour(args: &BuildArgs, s: &ColourSummary, start: Instant) -> Result<()> {
    if !args.quiet.value {
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

    /// Printed even with `--quiet`: the build does something other than asked.
    fn warning(&self, message: &str) {
        eprintln!("warning: {message}");
    }

    fn resumed(&self, r: &Resumed) {
        if matches!(self, Bars::Quiet) {
            return;
        }
        match r {
            Resumed::Fresh => {}
            Resumed::Continuing { blocks, damaged } => {
                eprintln!(
                    "resuming: {blocks} blocks finished by an earlier run of this build are kept \
                     (from OUTPUT.journal/)"
                );
                if *damaged > 0 {
                    eprintln!(
                        "resuming: {damaged} damaged block files in OUTPUT.journal/ were removed; \
                         their blocks are encoded again"
                    );
                }
            }
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
