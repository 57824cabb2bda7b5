//! `cbdam`: build, serve and view C-BDAM terrain repositories.
//!
//! Only this file turns errors into exit codes: 0 success, 1 failure (the message names the
//! problem), 2 bad usage (clap's own code).

mod bench_codec;
mod build;
mod inspect;
mod verify;

use std::path::PathBuf;
use std::process::ExitCode;

use cbdam_codec::hierarchy::EncodeOptions;
use clap::{Args, Parser, Subcommand, ValueEnum};

#[derive(Parser)]
#[command(
    name = "cbdam",
    version,
    about = "Compressed Batched Dynamic Adaptive Meshes: terrain with a guaranteed maximum error"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Build a repository from one DEM, in memory (multiple inputs, out-of-core building and a
    /// progress bar are not implemented yet).
    Build(BuildArgs),
    /// Print a repository's header, per-level record counts and sizes, and error range.
    Inspect(InspectArgs),
    /// Check every checksum, decode everything and compare with the input DEM.
    Verify(VerifyArgs),
    /// Measure the codec and other parts of the pipeline.
    #[command(subcommand)]
    Bench(BenchCommand),
}

#[derive(Subcommand)]
enum BenchCommand {
    /// Rate, verified maximum error and speed of the codec on DEM files (default: the bundled
    /// samples), as a Markdown table.
    Codec(BenchCodecArgs),
}

/// Which value(s) of a two-way option to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Which {
    /// The first (α = 1 / adaptive coder): the defaults.
    Default,
    /// The other (α = ½ / Elias-gamma coder).
    Other,
    /// Both.
    Both,
}

#[derive(Args, Debug)]
pub struct BenchCodecArgs {
    /// DEM files (GeoTIFF, .hgt, ASCII grid, PNG). Default: every .tif in data/.
    inputs: Vec<PathBuf>,
    /// Maximum errors to measure, metres, comma-separated.
    #[arg(long, value_delimiter = ',', default_values_t = vec![0.5, 1.0, 2.0, 5.0])]
    max_error: Vec<f64>,
    /// Lifting weight: default α = 1, other α = ½.
    #[arg(long, value_enum, default_value_t = Which::Default)]
    alpha: Which,
    /// Entropy coder: default adaptive, other Elias-gamma.
    #[arg(long, value_enum, default_value_t = Which::Both)]
    coder: Which,
    /// Diamond grid side N (2^k + 1).
    #[arg(long, default_value_t = 65)]
    diamond_size: usize,
    /// Level pairs above the smallest covering hierarchy (coarser roots).
    #[arg(long, default_value_t = EncodeOptions::default().extra_level_pairs)]
    extra_levels: u32,
    /// Timed repetitions; the median is reported.
    #[arg(long, default_value_t = 3)]
    runs: usize,
    /// Worker threads for encoding (the decode is single-threaded by construction).
    #[arg(long, default_value_t = 1)]
    threads: usize,
}

/// Entropy coder of `cbdam build`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum CoderArg {
    /// Adaptive binary arithmetic coder (smaller).
    Adaptive,
    /// Elias-gamma codes (simpler, faster to decode).
    EliasGamma,
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

/// Build a repository from one DEM file.
///
/// The whole DEM is read and encoded in memory. Multiple inputs (mosaics), out-of-core building
/// for DEMs larger than memory and a progress bar are later work.
#[derive(Args, Debug)]
pub struct BuildArgs {
    /// DEM file (GeoTIFF, .hgt, ASCII grid, PNG).
    input: PathBuf,
    /// Output repository (written atomically: a temporary file renamed into place).
    #[arg(short, long)]
    output: PathBuf,
    /// Guaranteed maximum error of every reconstructed sample, metres.
    #[arg(long, allow_hyphen_values = true)]
    max_error: f64,
    /// Diamond grid side N (2^k + 1).
    #[arg(long, default_value_t = 65)]
    diamond_size: usize,
    /// Worker threads for encoding (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Entropy coder.
    #[arg(long, value_enum, default_value_t = CoderArg::Adaptive)]
    coder: CoderArg,
    /// Lifting weight α.
    #[arg(long, value_enum, default_value_t = AlphaArg::One)]
    alpha: AlphaArg,
    /// The data's value quantum in metres (default: detected from the samples).
    #[arg(long)]
    quantum: Option<f64>,
    /// Nodata value, overriding the file's own.
    #[arg(long, allow_hyphen_values = true)]
    nodata: Option<f64>,
    /// Print nothing on success.
    #[arg(long)]
    quiet: bool,
}

/// Describe a repository.
#[derive(Args, Debug)]
pub struct InspectArgs {
    /// Repository file.
    repo: PathBuf,
    /// Machine-readable output.
    #[arg(long)]
    json: bool,
}

/// Verify a repository against the DEM it was built from.
#[derive(Args, Debug)]
pub struct VerifyArgs {
    /// Repository file.
    repo: PathBuf,
    /// The input DEM.
    #[arg(long)]
    against: PathBuf,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Build(args) => build::run(&args),
        Command::Inspect(args) => inspect::run(&args),
        Command::Verify(args) => verify::run(&args),
        Command::Bench(BenchCommand::Codec(args)) => bench_codec::run(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("cbdam: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
