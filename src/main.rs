//! `cbdam`: build, serve and view C-BDAM terrain repositories.
//!
//! Only this file turns errors into exit codes: 0 success, 1 failure (the message names the
//! problem), 2 bad usage (clap's own code).

mod bench_codec;

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

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
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
