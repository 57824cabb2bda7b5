//! `cbdam`: build, serve and view C-BDAM terrain repositories.
//!
//! Only this file turns errors into exit codes: 0 success, 1 failure (the message names the
//! problem), 2 bad usage (clap's own code).

mod bench_codec;
mod bench_report;
mod build;
mod extract;
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
    /// Build a repository from one DEM, in memory (multiple inputs and out-of-core building are
    /// not implemented yet).
    Build(BuildArgs),
    /// Print a repository's header, per-level record counts and sizes, and error range.
    Inspect(InspectArgs),
    /// Check every checksum, decode everything and compare with the input DEM.
    Verify(VerifyArgs),
    /// Decode a repository back to a DEM (GeoTIFF or raw float), whole or a window, at the
    /// finest or a coarser level.
    ///
    /// Heights are metres (`offset + n·unit`). By default they are written as float32, which
    /// rounds each decoded height to the nearest float32: that adds at most half a float32 ulp of
    /// the value (about 0.5 mm at 9 000 m, 0.015 mm at 500 m) to the repository's error bound. With
    /// --float64 the decoded heights are written exactly and the bound holds as stated.
    ///
    /// The repository keeps the data rectangle but not the per-sample nodata mask (nodata samples
    /// are "don't care" to the encoder), so decoded heights are written for every sample inside the
    /// rectangle, nodata samples of the input included, whose values there are arbitrary. Only
    /// samples in regions with no valid input sample nearby (no stored diamond) are written as the
    /// recorded nodata value (NaN when the repository recorded none).
    Extract(ExtractArgs),
    /// Measure the codec and other parts of the pipeline.
    #[command(subcommand)]
    Bench(BenchCommand),
}

#[derive(Subcommand)]
enum BenchCommand {
    /// Rate, verified maximum error and speed of the codec on DEM files (default: the bundled
    /// samples), as a Markdown table.
    Codec(BenchCodecArgs),
    /// Rate–distortion and time-against-error report: every bundled DEM and a synthetic fractal
    /// terrain at a ladder of tolerances, optionally beside peer codecs (SZ3, ZFP, LERC,
    /// JPEG-LS, zstd) measured in the same run; writes report.md and SVG plots.
    Report(BenchReportArgs),
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

/// Arguments of `cbdam bench report`.
#[derive(Args, Debug)]
pub struct BenchReportArgs {
    /// DEM files. Default: every .tif and .png in data/.
    inputs: Vec<PathBuf>,
    /// Output directory (created): report.md, results.json, plots/*.svg.
    #[arg(long, default_value = "bench-report")]
    out: PathBuf,
    /// Small and fast: one run per point and a 257² synthetic terrain unless given explicitly.
    #[arg(long)]
    quick: bool,
    /// Also measure the peer codecs (bench/peers.py in a Python venv; skipped with a message
    /// when Python or pip is unavailable).
    #[arg(long)]
    peers: bool,
    /// Tolerances ε, metres, comma-separated.
    #[arg(long, value_delimiter = ',', default_values_t = vec![0.05, 0.1, 0.25, 0.5, 1.0, 2.0, 5.0, 10.0])]
    max_error: Vec<f64>,
    /// Timed repetitions per point; medians are reported (default 3, 1 with --quick).
    #[arg(long)]
    runs: Option<usize>,
    /// Side of the synthetic fractal terrain (2^k + 1; 0 for none; default 4097, 257 with
    /// --quick).
    #[arg(long)]
    synthetic: Option<usize>,
    /// Worker threads for building (default 1, as the peers are single-threaded; the decode is
    /// single-threaded by construction).
    #[arg(long, default_value_t = 1)]
    threads: usize,
    /// Python virtual environment for the peers (default ~/.cache/cbdam-bench-venv).
    #[arg(long)]
    venv: Option<PathBuf>,
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
/// The whole DEM is read and encoded in memory. Progress goes to stderr: a bar with ETA on a
/// terminal, a line per quarter otherwise, nothing with --quiet. Multiple inputs (mosaics) and
/// out-of-core building for DEMs larger than memory are later work.
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

/// Output format of `cbdam extract`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum ExtractFormat {
    /// Single-band GeoTIFF with pixel scale, tie point, GeoKeys (raster type, EPSG) and
    /// GDAL_NODATA.
    Geotiff,
    /// Headerless little-endian floats, row 0 = north, plus a JSON sidecar (the output path with
    /// its extension replaced by `.json`): size, georeferencing, unit, nodata, ε.
    Raw,
}

/// Decode a repository to a DEM file (documented on [`Command::Extract`], which clap shows).
#[derive(Args, Debug)]
pub struct ExtractArgs {
    /// Repository file.
    repo: PathBuf,
    /// Output file (written atomically: a temporary file renamed into place).
    #[arg(short, long)]
    output: PathBuf,
    /// Window MINX,MINY,MAXX,MAXY: the samples whose centres lie inside it, clipped to the data.
    /// In the repository's CRS units when it is georeferenced; otherwise column and row indices
    /// (x = column, y = row, row 0 = north). Default: the whole data rectangle.
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true, num_args = 1)]
    bbox: Option<Vec<f64>>,
    /// Decode level L instead of the finest. Only even levels are axis-aligned grids, so L must
    /// be even; level L samples every 2^((finest − L)/2) input samples (the lattice points that
    /// are multiples of that spacing). With --alpha 0.5 repositories coarse levels are
    /// low-pass filtered, not subsampled. `cbdam inspect` lists the levels.
    #[arg(long)]
    level: Option<u8>,
    /// Output format.
    #[arg(long, value_enum, default_value_t = ExtractFormat::Geotiff)]
    format: ExtractFormat,
    /// Write float64 samples: the decoded heights exactly, without float32 rounding.
    #[arg(long)]
    float64: bool,
    /// Print nothing on success.
    #[arg(long)]
    quiet: bool,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Build(args) => build::run(&args),
        Command::Inspect(args) => inspect::run(&args),
        Command::Verify(args) => verify::run(&args),
        Command::Extract(args) => extract::run(&args),
        Command::Bench(BenchCommand::Codec(args)) => bench_codec::run(&args),
        Command::Bench(BenchCommand::Report(args)) => bench_report::run(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("cbdam: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
