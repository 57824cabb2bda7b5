//! `cbdam`: build, serve and view C-BDAM terrain repositories.
//!
//! Only this file turns errors into exit codes: 0 success, 1 failure (the message names the
//! problem), 2 bad usage (clap's own code).

mod bench_build;
mod bench_codec;
mod bench_network;
mod bench_report;
mod bench_serve;
mod build;
mod demo;
mod extract;
mod flags;
mod inspect;
mod link;
mod render;
mod replay;
mod serve;
mod session;
mod shard;
mod synth;
mod verify;
mod view;
mod web_export;

use std::net::SocketAddr;
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
    /// Build a repository from one DEM, or from several at power-of-two spacings (one
    /// variable-resolution dataset), in parallel, within a memory limit.
    Build(BuildArgs),
    /// Print a repository's header, per-level record counts and sizes, and error range.
    Inspect(InspectArgs),
    /// Rewrite a repository of an older format version in the current one (version 1 → 2: a
    /// range-coded record index, smaller on smooth terrain); heights, records and errors are
    /// unchanged. The output is written atomically and may be the input itself.
    Upgrade(UpgradeArgs),
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
    /// Serve repositories over HTTP/1.1 and HTTP/2 (cleartext): per-diamond records, batches,
    /// the header as JSON, the raw file with range requests, and Prometheus metrics.
    ///
    /// Endpoints and the batch framing: docs/FORMAT.md, "HTTP API". Logs go to stderr,
    /// filtered by RUST_LOG (default info, one line per request). Stops on SIGINT/SIGTERM after
    /// the requests in flight finish.
    Serve(ServeArgs),
    /// Write the browser viewer as static files into DIR, for any static server that honours
    /// Range requests: open DIR/index.html?repo=URL of a `.cbdam` file (or, with --repo, just
    /// index.html; --colour adds a colour repository draped over it, as `?colour=URL` does).
    ///
    /// The viewer's files come from the bundle scripts/web-build.sh writes (target/web-bundle):
    /// --bundle DIR, else $CBDAM_WEB_BUNDLE, else target/web-bundle in the working directory,
    /// else web-bundle beside or above the cbdam binary.
    WebExport(WebExportArgs),
    /// Emulate a slower, longer network link in front of a server: a loopback TCP proxy that
    /// forwards connections on --listen to --to with a one-way delay each way, downstream and
    /// upstream rate caps shared by all connections, optional jitter and connection resets.
    ///
    /// Profiles (rates in bits/s, delays one way): adsl 1.2M down / 256k up, 30 ms; dsl10 10M /
    /// 1M, 25 ms; fibre 100M / 100M, 10 ms; mobile 5M / 1M, 60 ms ±10 ms, 1 % of connections
    /// reset; custom: give --down, --up and --delay-ms. Any flag overrides the profile. Prints
    /// the counters every --interval seconds with traffic; Ctrl-C (or SIGTERM) stops it.
    Link(LinkArgs),
    /// Run the client's refinement loop over a camera flight without drawing: one CSV row per
    /// frame, then hold the camera still until the cut converges, and print a summary.
    Replay(ReplayArgs),
    /// Render offscreen to PNG: one frame, or every frame of a camera flight (lavapipe works
    /// where there is no GPU).
    ///
    /// The cut is the streaming client's: the time-critical refinement loop of `cbdam replay`
    /// over the local repository. For one frame (-o) it runs with an unlimited budget until the
    /// cut converges for the view (every diamond in it within --pixel-error), then draws it. With
    /// --path it flies the camera path at --fps with the real per-frame --budget-ms, as replay
    /// does, and writes each frame to --out-dir/frame_NNNNN.png. Prints the frame time and
    /// triangle count (with --path, median and p99 refine and render times).
    Render(RenderArgs),
    /// Open a window onto a repository (file or URL): orbit and fly cameras, the pixel-error
    /// target and debug views on keys, and a HUD with frame rate, triangle rate, cut size, cache
    /// use and network traffic.
    ///
    /// Every frame runs one step of the refinement loop within --budget-ms (remote records arrive
    /// in the background, so the window never waits for the network) and draws the cut with the
    /// renderer of `cbdam render`, starting from the same overview. With --max-frames it stops
    /// after that many frames, printing the frame-time median and p99 and the triangle rate;
    /// --screenshot saves the last frame on exit (scripts, tests). Needs a display: an X11
    /// server, or Xvfb.
    #[command(after_help = view::KEY_HELP)]
    View(ViewArgs),
    /// The whole pipeline on the bundled SRTM tile: builds a repository (once), serves it on
    /// loopback, replays a flight against the server over HTTP and renders an overview and the
    /// flight's frames offscreen from what the client fetched; prints where the outputs are.
    Demo(DemoArgs),
    /// A build split into steps that run as separate processes, on other machines (Dask, a
    /// Kubernetes Indexed Job, a Slurm array), merged into the repository `cbdam build` writes
    /// with the same arguments, byte for byte: plan, apex, run each shard, merge
    /// (docs/SHARDING.md).
    #[command(subcommand)]
    Shard(shard::ShardCommand),
    /// Measure the codec and other parts of the pipeline.
    #[command(subcommand)]
    Bench(BenchCommand),
    /// Write a synthetic fractal terrain (deterministic diamond-square) as raw little-endian
    /// float32, for benchmarks.
    #[command(hide = true)]
    Synth(SynthArgs),
}

/// Arguments of the hidden `cbdam synth`.
#[derive(Args, Debug)]
pub struct SynthArgs {
    /// Side of the square grid in samples.
    #[arg(long)]
    size: usize,
    /// Output raw float32 file.
    #[arg(short, long)]
    output: PathBuf,
    /// Seed of the pseudo-random displacements.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Write a float32 BigTIFF (strips of 16 rows) instead of raw float32.
    #[arg(long, value_enum)]
    tiff: Option<TiffArg>,
    /// With --tiff: heights rounded to whole metres as an int16 GeoTIFF (strips of about 1 MB),
    /// georeferenced at 30 m in EPSG:32632.
    #[arg(long, requires = "tiff")]
    int16: bool,
    /// With --int16: OUTPUT is a new directory of N × N tiles of the grid sharing their edge
    /// rows and columns (as SRTM's do), `rRRRcCCC.tif`; --size must be N·t + 1.
    #[arg(long, value_name = "N", requires = "int16")]
    tiles: Option<usize>,
    /// With --tiles: every tile is the same (t+1)² terrain, mirrored across each tile edge (so
    /// neighbours agree on their shared rows and columns), generated in the memory of one tile
    /// instead of the whole grid's: for mosaics larger than memory (the 4.3 G-sample benchmark
    /// of scripts/bench-tiles.sh). The grid is then periodic, not one terrain.
    #[arg(long, requires = "tiles")]
    mirrored: bool,
}

/// Compression of `cbdam synth --tiff`.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum TiffArg {
    /// Uncompressed.
    Plain,
    /// Deflate (fast level).
    Deflate,
}

#[derive(Subcommand)]
enum BenchCommand {
    /// Rate, verified maximum error and speed of the codec on DEM files (default: the bundled
    /// samples), as a Markdown table.
    Codec(BenchCodecArgs),
    /// Load test of the HTTP server: concurrent clients fetching random stored diamonds, one per
    /// request and in batches, over loopback; records/s, MB/s and latency as a Markdown table.
    Serve(BenchServeArgs),
    /// Build throughput (million input samples per second, median of runs) and peak resident
    /// memory of `cbdam build` on DEM files (default: the bundled samples) and a synthetic
    /// fractal terrain, as a Markdown table.
    Build(BenchBuildArgs),
    /// Offscreen frame time and triangle rate of the renderer on repositories, overview and a
    /// low oblique view, as a Markdown table.
    Render(BenchRenderArgs),
    /// Rate–distortion and time-against-error report: every bundled DEM and a synthetic fractal
    /// terrain at a ladder of tolerances, optionally beside peer codecs (SZ3, ZFP, LERC,
    /// JPEG-LS, zstd) measured in the same run; writes report.md and SVG plots.
    Report(BenchReportArgs),
    /// Remote browsing over emulated links: each flight replayed in real time against the local
    /// file and, for each link profile (adsl, dsl10, fibre, mobile), through a loopback shaping
    /// proxy against `cbdam serve` (batched) and against a static file server (range requests);
    /// bytes fetched against bytes the cuts used, requests per second, frames at the pixel
    /// target, seconds from the camera stopping to the target, frames over budget. Writes
    /// network.md, network.json, per-run CSVs and an SVG of screen error over time.
    Network(BenchNetworkArgs),
}

/// Serve repositories over HTTP.
#[derive(Args, Debug)]
pub struct ServeArgs {
    /// Repositories: PATH (served under its file stem) or NAME=PATH. Names may use
    /// A-Z a-z 0-9 . _ - and must be unique.
    #[arg(required = true, value_name = "REPO")]
    repos: Vec<String>,
    /// Address to listen on.
    #[arg(long, default_value = "127.0.0.1:8080")]
    addr: SocketAddr,
    /// Most diamond ids in one batch request (more: 413).
    #[arg(long, default_value_t = 4096)]
    max_batch: usize,
    /// Largest request body, bytes (more: 413).
    #[arg(long, default_value_t = 1 << 20)]
    max_body: usize,
    /// Access-Control-Allow-Origin: `*` or a comma-separated list of origins.
    #[arg(long, default_value = "*")]
    cors_origin: String,
    /// Time allowed for one request, seconds (then 408).
    #[arg(long, default_value_t = 30.0)]
    timeout: f64,
    /// Time a connection has to send a request's headers, seconds: from its accept for the
    /// first request, from the last answer for the next (an idle keep-alive connection is
    /// closed then).
    #[arg(long, default_value_t = 10.0)]
    header_timeout: f64,
    /// A connection that moves no byte either way for this long is closed, seconds (an idle
    /// HTTP/2 connection, a client that does not read its answer).
    #[arg(long, default_value_t = 60.0)]
    idle_timeout: f64,
    /// Most connections open at once (fewer if the file-descriptor limit is lower): one more
    /// closes the least recently active connection of the client address holding the most.
    #[arg(long, default_value_t = 10_000)]
    max_connections: usize,
    /// The browser viewer's files (the bundle `scripts/web-build.sh` writes, e.g.
    /// target/web-bundle): `/` then links every repository to the viewer, served under
    /// `/viewer/HASH/`. Without it `/` only lists the repositories.
    #[arg(long, value_name = "DIR")]
    web: Option<std::path::PathBuf>,
    /// Worker threads (default: one per core).
    #[arg(long)]
    threads: Option<usize>,
}

/// Arguments of `cbdam web-export` (documented on [`Command::WebExport`]).
#[derive(Args, Debug)]
pub struct WebExportArgs {
    /// Folder to write (created if needed; files of the same names are replaced).
    #[arg(value_name = "DIR")]
    dir: PathBuf,
    /// The repository the page opens without `?repo=`: a .cbdam file (copied into DIR) or an
    /// http(s) URL of one (its server must honour Range requests and allow the page's origin).
    #[arg(long, value_name = "FILE_OR_URL")]
    repo: Option<String>,
    /// A colour repository the page drapes over --repo without `?colour=` (built by `cbdam
    /// build IMAGE --colour --like REPO`): a .cbdam file (copied into DIR; checked to pair with
    /// --repo) or an http(s) URL.
    #[arg(long, value_name = "FILE_OR_URL", requires = "repo")]
    colour: Option<String>,
    /// The viewer's bundle (default: found as the command's help says).
    #[arg(long, value_name = "DIR")]
    bundle: Option<PathBuf>,
}

/// Arguments of `cbdam link` (documented on [`Command::Link`]).
#[derive(Args, Debug)]
pub struct LinkArgs {
    /// Link profile: adsl, dsl10, fibre, mobile or custom.
    #[arg(long)]
    profile: String,
    /// Address to listen on (port 0: any free port, printed).
    #[arg(long, default_value = "127.0.0.1:9000")]
    listen: SocketAddr,
    /// Upstream server to forward each connection to, e.g. the address of `cbdam serve`.
    #[arg(long)]
    to: SocketAddr,
    /// Downstream rate cap (server → client), bits/s with k, M or G (e.g. 1.2M).
    #[arg(long, value_name = "RATE")]
    down: Option<flags::BitRate>,
    /// Upstream rate cap (client → server), bits/s with k, M or G (e.g. 256k).
    #[arg(long, value_name = "RATE")]
    up: Option<flags::BitRate>,
    /// One-way delay each direction, ms (the round trip is twice this).
    #[arg(long, allow_hyphen_values = true)]
    delay_ms: Option<f64>,
    /// Jitter, ms: each piece's delay varies uniformly by ± this (bytes are never reordered).
    #[arg(long, allow_hyphen_values = true)]
    jitter_ms: Option<f64>,
    /// Probability that a connection is reset (within its first 64 KiB, or at its end).
    #[arg(long, allow_hyphen_values = true)]
    reset_prob: Option<f64>,
    /// Seed of the reset and jitter draws.
    #[arg(long)]
    seed: Option<u64>,
    /// Seconds between counter lines (0: only the totals when stopped).
    #[arg(long, default_value_t = 1.0, allow_hyphen_values = true)]
    interval: f64,
}

/// Load-test the HTTP server in-process.
#[derive(Args, Debug)]
pub struct BenchServeArgs {
    /// Repository to serve. Default: built from data/srtm3_demcompare.tif at ε = 1 m into a
    /// temporary directory.
    repo: Option<PathBuf>,
    /// Concurrent clients, each on its own keep-alive HTTP/1.1 connection.
    #[arg(long, default_value_t = 64)]
    clients: usize,
    /// Seconds per measured run.
    #[arg(long, default_value_t = 5.0)]
    seconds: f64,
    /// Most requests per run (the other bound besides --seconds).
    #[arg(long, default_value_t = 5_000_000)]
    max_requests: u64,
    /// Ids per batch request (0: skip the batched runs).
    #[arg(long, default_value_t = 64)]
    batch: usize,
    /// Runs per mode; the median run (by records/s) is reported.
    #[arg(long, default_value_t = 3)]
    runs: usize,
    /// Server worker threads.
    #[arg(long, default_value_t = 1)]
    server_threads: usize,
    /// Load-generator worker threads (its own runtime, so the two do not share a scheduler).
    #[arg(long, default_value_t = 1)]
    client_threads: usize,
}

/// Arguments of `cbdam bench build`.
#[derive(Args, Debug)]
pub struct BenchBuildArgs {
    /// DEM files (GeoTIFF, .hgt, ASCII grid, PNG). Default: every .tif in data/.
    inputs: Vec<PathBuf>,
    /// Side of a synthetic square fractal terrain to add (0: none), e.g. 16385.
    #[arg(long, default_value_t = 4097)]
    synthetic: usize,
    /// Maximum error, metres.
    #[arg(long, default_value_t = 1.0)]
    max_error: f64,
    /// Timed repetitions; the median is reported.
    #[arg(long, default_value_t = 3)]
    runs: usize,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Memory limit as for `cbdam build --memory-limit`.
    #[arg(long, value_name = "SIZE")]
    memory_limit: Option<flags::ByteSize>,
}

/// Render one frame of a repository (documented on [`Command::Render`]).
#[derive(Args, Debug)]
pub struct RenderArgs {
    /// Repository file, or its URL: http://HOST:PORT/v1/repos/NAME (cbdam serve),
    /// http://HOST:PORT/ (a server with one repository), or a .cbdam file on any server that
    /// honours range requests.
    repo: PathBuf,
    /// Image size WIDTHxHEIGHT.
    #[arg(long, value_parser = flags::Size2::pixels, default_value = "1920x1080")]
    size: (u32, u32),
    /// Output PNG (written atomically).
    #[arg(short, long, required_unless_present = "path", conflicts_with = "path")]
    output: Option<PathBuf>,
    /// Render every frame of this camera flight (JSON, as for `cbdam replay`) instead of one.
    #[arg(long, requires = "out_dir", conflicts_with = "camera")]
    path: Option<PathBuf>,
    /// With --path: directory for frame_00000.png, frame_00001.png, … (created if missing;
    /// each written atomically).
    #[arg(long, requires = "path")]
    out_dir: Option<PathBuf>,
    /// With --path: frames per second of flight.
    #[arg(long, default_value_t = 30.0, requires = "path")]
    fps: f64,
    /// With --path: refinement time budget per frame, ms (0 = unlimited).
    #[arg(long, default_value_t = 2.0, requires = "path")]
    budget_ms: f64,
    /// With --path: stop after this many frames.
    #[arg(long, requires = "path")]
    max_frames: Option<u64>,
    /// Camera eye_x,eye_y,eye_z,target_x,target_y,target_z in world metres: x east and y north
    /// of the data's north-west corner (so y is negative over the data), z height. Default: an
    /// overview of the whole data from the south.
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true, num_args = 1)]
    camera: Option<Vec<f64>>,
    /// A planet's camera: LAT,LON,HEIGHT_M[,HEADING_DEG,PITCH_DEG], geodetic degrees, height in
    /// metres above the WGS84 ellipsoid, heading clockwise from north (default 0), pitch
    /// negative when looking down (default -30). Without it (and --camera) a planet is shown
    /// whole, centred.
    #[arg(long, value_parser = flags::GeoView::parse, allow_hyphen_values = true,
          conflicts_with_all = ["camera", "path"])]
    geo: Option<flags::GeoView>,
    /// Screen-space error target, pixels.
    #[arg(long, default_value_t = 1.0, allow_hyphen_values = true)]
    pixel_error: f64,
    /// Draw triangle edges over the surface.
    #[arg(long)]
    wireframe: bool,
    /// Colour by diamond level instead of height.
    #[arg(long)]
    levels: bool,
    /// Vertical exaggeration (heights and the camera's z are scaled by it).
    #[arg(long, default_value_t = 1.0, allow_hyphen_values = true)]
    exaggeration: f64,
    /// GPU height pool, MiB (default: 256 or what the adapter allows).
    #[arg(long)]
    pool_mib: Option<u64>,
    /// Drape this colour repository (`cbdam build IMG --colour --like REPO`), file or URL, over
    /// the terrain: hillshaded colour instead of the height ramp.
    #[arg(long, value_name = "COLOUR_REPO_OR_URL")]
    colour: Option<String>,
    /// Without --path: also write the cut's refined diamonds to this file, one id (`L-x-y`) a
    /// line, sorted as text (the browser viewer's test compares its cut with it).
    #[arg(long, value_name = "FILE")]
    cut_out: Option<PathBuf>,
}

/// Open the interactive viewer (documented on [`Command::View`]).
#[derive(Args, Debug)]
pub struct ViewArgs {
    /// Repository file, or its URL (as for `cbdam render`).
    repo: PathBuf,
    /// Initial window size WIDTHxHEIGHT, pixels.
    #[arg(long, value_parser = flags::Size2::pixels, default_value = "1280x720")]
    size: (u32, u32),
    /// Screen-space error target, pixels (+/- halve and double it).
    #[arg(long, default_value_t = 1.0, allow_hyphen_values = true)]
    pixel_error: f64,
    /// Refinement time budget per frame, ms.
    #[arg(long, default_value_t = 2.0, allow_hyphen_values = true)]
    budget_ms: f64,
    /// Present as fast as possible (immediate or mailbox) instead of waiting for vsync.
    #[arg(long)]
    no_vsync: bool,
    /// Quit after this many frames.
    #[arg(long)]
    max_frames: Option<u64>,
    /// Save the last frame (with the HUD) to this PNG when the viewer stops.
    #[arg(long)]
    screenshot: Option<PathBuf>,
    /// Start with the wireframe on.
    #[arg(long)]
    wireframe: bool,
    /// Start colouring by diamond level.
    #[arg(long)]
    levels: bool,
    /// Vertical exaggeration.
    #[arg(long, default_value_t = 1.0, allow_hyphen_values = true)]
    exaggeration: f64,
    /// GPU height pool, MiB (default: 256 or what the adapter allows).
    #[arg(long)]
    pool_mib: Option<u64>,
    /// Drape this colour repository (`cbdam build IMG --colour --like REPO`), file or URL, over
    /// the terrain: hillshaded colour instead of the height ramp.
    #[arg(long, value_name = "COLOUR_REPO_OR_URL")]
    colour: Option<String>,
}

/// Time offscreen frames.
#[derive(Args, Debug)]
pub struct BenchRenderArgs {
    /// Repository files.
    #[arg(required = true)]
    repos: Vec<PathBuf>,
    /// Image size WIDTHxHEIGHT.
    #[arg(long, value_parser = flags::Size2::pixels, default_value = "1920x1080")]
    size: (u32, u32),
    /// Screen-space error target, pixels.
    #[arg(long, default_value_t = 1.0)]
    pixel_error: f64,
    /// Timed frames per view; the median is reported.
    #[arg(long, default_value_t = 5)]
    runs: usize,
    /// Also fly this camera path (repeatable, e.g. data/flights/*.json): every frame refines
    /// within --budget-ms and is drawn; frame time percentiles and triangle rate are reported.
    #[arg(long = "flight", value_name = "FLIGHT.json")]
    flights: Vec<PathBuf>,
    /// Frames per second of flight time.
    #[arg(long, default_value_t = 30.0)]
    fps: f64,
    /// Refinement time budget per flight frame, ms.
    #[arg(long, default_value_t = 2.0)]
    budget_ms: f64,
    /// At most this many frames per flight.
    #[arg(long)]
    max_frames: Option<u64>,
    /// Drape this colour repository over each repository too and time both (the colour must
    /// match every repository given).
    #[arg(long, value_name = "COLOUR_REPO")]
    colour: Option<PathBuf>,
}

/// Arguments of `cbdam demo`.
#[derive(Args, Debug)]
pub struct DemoArgs {
    /// Where the repository, CSV and PNGs go.
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
    /// Entropy coder: default adaptive-tokens; other the bitwise adaptive and Elias-gamma
    /// coders; both all three.
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
    /// Output directory (created): report.md, results.json, plots/*.svg, replay/ (the
    /// rendering-cost repository and per-frame CSVs).
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
    /// Rendering cost: the flights (every *.json in this folder; default data/flights).
    #[arg(long)]
    flights: Option<PathBuf>,
    /// Rendering cost: pixel-error targets, comma-separated (default 0.5,1,2,4,8; 1,4 with
    /// --quick).
    #[arg(long, value_delimiter = ',')]
    pixel_errors: Option<Vec<f64>>,
    /// Rendering cost: the dataset to fly over, by its name in the report (default the SRTM
    /// sample when it is an input, else the first input).
    #[arg(long)]
    render_dem: Option<String>,
}

/// Arguments of `cbdam bench network` (documented on [`BenchCommand::Network`]).
#[derive(Args, Debug)]
pub struct BenchNetworkArgs {
    /// Link profiles, comma-separated: adsl, dsl10, fibre, mobile.
    #[arg(long, value_delimiter = ',', default_value = "adsl,dsl10,fibre,mobile")]
    profiles: Vec<String>,
    /// Flights (JSON, as for `cbdam replay`). Default: every data/flights/*.json.
    #[arg(long, num_args = 1.., value_name = "FLIGHT.json")]
    flights: Vec<PathBuf>,
    /// Servers, comma-separated: serve (`cbdam serve`, batched requests), static (its raw file
    /// route read with range requests, as from any static server).
    #[arg(
        long,
        value_delimiter = ',',
        value_enum,
        default_value = "serve,static"
    )]
    servers: Vec<bench_network::ServerKind>,
    /// Viewport WIDTHxHEIGHT, pixels.
    #[arg(long, default_value = "1920x1080", value_parser = flags::Size2::pixels)]
    size: (u32, u32),
    /// Target screen-space error, pixels.
    #[arg(long, default_value_t = 1.0)]
    pixel_error: f64,
    /// Refinement time budget per frame, ms (0: unlimited).
    #[arg(long, default_value_t = 2.0)]
    budget_ms: f64,
    /// Frames per second: the flight's and the settling frames' pace in real time.
    #[arg(long, default_value_t = 30.0)]
    fps: f64,
    /// After the flight, at most this many seconds with the camera still, waiting for the cut to
    /// converge.
    #[arg(long, default_value_t = 30.0)]
    max_settle_s: f64,
    /// Repository to serve. Default: a synthetic fractal terrain of --synth-size² built at
    /// ε = 1 m (as `cbdam synth` and `cbdam build` make it), kept in --out and reused.
    #[arg(long)]
    repo: Option<PathBuf>,
    /// Side of the default synthetic terrain, samples.
    #[arg(long, default_value_t = 4097)]
    synth_size: usize,
    /// Override every profile's probability of resetting a connection.
    #[arg(long)]
    reset_prob: Option<f64>,
    /// Seed of the links' reset and jitter draws.
    #[arg(long)]
    seed: Option<u64>,
    /// When the client prefetches: off, always (alongside what the view needs, at a lower
    /// priority), when-idle (only in frames whose cut wants no record).
    #[arg(long, value_enum, default_value = "when-idle")]
    prefetch: PrefetchArg,
    /// The order records are asked for in: screen-error (the worst first), error-per-byte (the
    /// most screen error removed per byte first).
    #[arg(long, value_enum, default_value = "screen-error")]
    fetch_order: FetchOrderArg,
    /// Ask only for the records of the cut's most urgent candidates beyond what each frame
    /// refined: as many as the loop refines in a second, and at least this many (0: all;
    /// default: the viewer's, 128).
    #[arg(long)]
    want_limit: Option<usize>,
    /// Most records a frame prefetches (0: no limit; default: the viewer's, 32).
    #[arg(long)]
    prefetch_limit: Option<usize>,
    /// Output directory (created): network.md, network.json, csv/, plots/.
    #[arg(long, default_value = "bench-network")]
    out: PathBuf,
}

/// [`cbdam_client::refine::Prefetch`] on the command line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum PrefetchArg {
    Off,
    Always,
    WhenIdle,
}

impl From<PrefetchArg> for cbdam_client::refine::Prefetch {
    fn from(p: PrefetchArg) -> Self {
        match p {
            PrefetchArg::Off => Self::Off,
            PrefetchArg::Always => Self::Always,
            PrefetchArg::WhenIdle => Self::WhenIdle,
        }
    }
}

/// [`cbdam_client::refine::FetchOrder`] on the command line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum FetchOrderArg {
    ScreenError,
    ErrorPerByte,
}

impl From<FetchOrderArg> for cbdam_client::refine::FetchOrder {
    fn from(o: FetchOrderArg) -> Self {
        match o {
            FetchOrderArg::ScreenError => Self::ScreenError,
            FetchOrderArg::ErrorPerByte => Self::ScreenErrorPerByte,
        }
    }
}

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
/// Encoding runs on all cores, level by level. Raw float32 input (--size) is streamed in blocks
/// and never held as floats; other formats are read whole, then quantized to 5 bytes per sample.
/// The encoder keeps one 4-byte reconstruction value per lattice point; when that and the
/// quantized input exceed --memory-limit, the reconstruction goes to a memory-mapped temporary
/// file (in $TMPDIR). Progress goes to stderr: a bar with ETA on a terminal, a line per quarter
/// otherwise, nothing with --quiet.
///
/// Several inputs form one variable-resolution dataset: one lattice at the finest input's
/// spacing over the union of the inputs, placed by their georeferencing; coarser inputs must be
/// 2^j times as coarse and aligned to that lattice (no resampling). Where inputs overlap the
/// finest sample wins; where only coarse data exists the hierarchy stays coarse. This first
/// version holds the whole lattice in memory (about 18 bytes per lattice point) and refuses
/// lattices above --memory-limit.
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
    inputs: Vec<PathBuf>,
    /// The input is headerless little-endian float32, WIDTHxHEIGHT samples, row 0 north
    /// (streamed: never held in memory as floats).
    #[arg(long, value_name = "WIDTHxHEIGHT", value_parser = flags::Size2::samples)]
    size: Option<(usize, usize)>,
    /// Memory budget, e.g. 2G or 512M (K, M, G, T are powers of 1024). Above it, the encoder's
    /// reconstruction field is a memory-mapped temporary file instead of anonymous memory.
    /// Default: half of physical memory.
    #[arg(long, value_name = "SIZE")]
    memory_limit: Option<flags::ByteSize>,
    /// Output repository (written atomically: a temporary file renamed into place).
    #[arg(short, long)]
    output: PathBuf,
    /// Guaranteed maximum error of every reconstructed sample, metres; with --colour, whole
    /// 8-bit levels bounding every decoded R, G and B component (0 = lossless).
    #[arg(long, allow_hyphen_values = true)]
    max_error: f64,
    /// The input is an 8-bit RGB/RGBA PNG or RGB GeoTIFF: build a colour repository (YCoCg-R,
    /// each component coded like elevation) to drape over an elevation repository.
    #[arg(long)]
    colour: bool,
    /// With --colour: lay the colour over this elevation repository's domain (its diamond size
    /// and roots; the image must be (W − 1)·2^m + 1 × (H − 1)·2^m + 1 of its W × H samples; a
    /// PNG gets its georeferencing, scaled).
    #[arg(long, value_name = "ELEVATION.cbdam")]
    like: Option<PathBuf>,
    /// Diamond grid side N (2^k + 1).
    #[arg(long, default_value_t = 65)]
    diamond_size: usize,
    /// Level pairs above the smallest hierarchy that covers the data: each makes the roots 4×
    /// sparser and codes the terrain between them as residuals instead. `auto` tries one more
    /// where the root field is most of the repository (small or smooth inputs at loose
    /// tolerances) and keeps the smaller file.
    #[arg(long, default_value = "auto", value_parser = build::parse_extra_levels)]
    extra_levels: build::ExtraLevels,
    /// Worker threads for encoding (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Entropy coder.
    #[arg(long, value_enum, default_value_t = CoderArg::AdaptiveTokens)]
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
    #[command(flatten)]
    georef: GeorefArgs,
    /// Benchmarks: encode the levels from CUT down in blocks SIDE lattice units across (with a
    /// journal), whatever the input's size and the memory limit would choose.
    #[arg(long, value_name = "CUT,SIDE", hide = true, value_parser = build::parse_block_plan)]
    block_plan: Option<cbdam_codec::hierarchy::BlockPlan>,
    /// Build a planet: the inputs (EPSG:4326 latitude/longitude GeoTIFFs, SRTM .hgt, UTM zones)
    /// resampled onto the cube-sphere lattice on WGS84 (docs/PLANET.md) — bilinear where the
    /// lattice is finer than an input, area-averaged where coarser, the finest input winning
    /// where they overlap. The lattice is the coarsest as fine as the finest input, within
    /// --memory-limit (about 40 bytes per lattice point); the summary says when the limit made
    /// it coarser, and how far the lattice is from each input's samples.
    #[arg(long)]
    planet: bool,
    /// With --planet: the lattice's level pairs K (faces of (N − 1)·2^K steps, a mean spacing of
    /// 90°/((N − 1)·2^K)) instead of the one the finest input asks for.
    #[arg(long, value_name = "K", requires = "planet")]
    planet_level: Option<u32>,
    /// Print nothing on success.
    #[arg(long)]
    quiet: bool,
    /// Print the wall time of each stage (read and plan, quantize, encode, write) to stderr.
    #[arg(long)]
    timings: bool,
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

/// Rewrite a repository in the current format version.
#[derive(Args, Debug)]
pub struct UpgradeArgs {
    /// Repository file to read.
    repo: PathBuf,
    /// Where to write the upgraded repository (may be the input).
    #[arg(short, long)]
    output: PathBuf,
}

/// Verify a repository against the DEM it was built from.
#[derive(Args, Debug)]
pub struct VerifyArgs {
    /// Repository file.
    repo: PathBuf,
    /// The input DEM(s), in the order given to `build`: files, directories, globs, @LIST files
    /// or GDAL VRTs of tiles, as `build` takes them.
    #[arg(long, required = true, num_args = 1..)]
    against: Vec<PathBuf>,
    /// Memory to stay within (e.g. 2G, 512M; default half of RAM): a hierarchy from several
    /// inputs, or from one too large to decode whole (26 bytes a sample), is decoded block by
    /// block, the inputs' lattice kept in temporary files above it.
    #[arg(long, value_name = "SIZE")]
    memory_limit: Option<flags::ByteSize>,
    /// Decode blocks of this plan (testing).
    #[arg(long, value_name = "CUT,SIDE", hide = true, value_parser = build::parse_block_plan)]
    block_plan: Option<cbdam_codec::hierarchy::BlockPlan>,
    #[command(flatten)]
    georef: GeorefArgs,
}

/// `--bounds MINX,MINY,MAXX,MAXY --crs EPSG:N`, of `build` and `verify`: georeferencing for an
/// input that carries none.
#[derive(Args, Debug, Default)]
pub struct GeorefArgs {
    /// Georeferences an input that carries none (a raw float32 file, a plain TIFF, one of a
    /// planet's inputs): the outer edges of its raster in the CRS of --crs,
    /// west,south,east,north (GDAL's -te order), e.g. `--bounds -10,40,2,46 --crs EPSG:4326`.
    /// Refused for inputs with their own; among a planet's inputs, for the one that carries
    /// none (`verify --against` takes the same flags to place it again).
    #[arg(
        long,
        value_name = "MINX,MINY,MAXX,MAXY",
        requires = "crs",
        allow_hyphen_values = true
    )]
    bounds: Option<String>,
    /// The CRS of --bounds, as EPSG:N.
    #[arg(long, value_name = "EPSG:N", requires = "bounds")]
    crs: Option<String>,
}

impl GeorefArgs {
    /// The georeferencing the flags give, checked; `None` without them.
    pub fn assigned(&self) -> anyhow::Result<Option<cbdam_build::assign::AssignedGeoRef>> {
        match (&self.bounds, &self.crs) {
            (Some(b), Some(c)) => Ok(Some(cbdam_build::assign::AssignedGeoRef::parse(b, c)?)),
            _ => Ok(None),
        }
    }
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

/// Replay a flight through the refinement loop (documented on [`Command::Replay`]).
#[derive(Args, Debug)]
pub struct ReplayArgs {
    /// Repository file, or the URL of one (`cbdam serve`'s repository URL or a .cbdam file on
    /// any server that honours Range).
    #[arg(value_name = "REPO_OR_URL")]
    repo: String,
    /// Flight file (JSON keyframes relative to the data's extent; see data/flights/).
    #[arg(long)]
    path: PathBuf,
    /// Viewport WIDTHxHEIGHT, pixels.
    #[arg(long, default_value = "1920x1080", value_parser = flags::Size2::pixels)]
    size: (u32, u32),
    /// Target screen-space error, pixels.
    #[arg(long, default_value_t = 1.0)]
    pixel_error: f64,
    /// Refinement time budget per frame, ms (0: unlimited).
    #[arg(long, default_value_t = 2.0)]
    budget_ms: f64,
    /// Output CSV, one row per frame: frame, t, settling, refine_ms (wall), cpu_ms (CPU time of
    /// the refining thread), decode_ms (worker time), decoded,
    /// max_screen_error_px, met_target, converged, diamonds_in_cut, drawn_halves, triangles,
    /// refinements, coarsenings, budget_exhausted, bytes_fetched (cumulative), requests_issued
    /// (cumulative), requests_in_flight, failures, cut_bytes (decoded diamonds in the cut),
    /// memory_limited (a refinement waited for --cut-mib), then where refine_ms went, step by
    /// step: before_ms (arrivals, a moving view's collection, the refinement heap), loop_ms
    /// (the refinement loop), collect_ms (a collection after the loop), want_ms (choosing
    /// requests), after_ms (largest error, prefetch, posting requests), ahead_ms (planning the
    /// decoding ahead, last in the frame; the column comes before after_ms), and decode_cpu_ms
    /// (of decode_ms, the workers' CPU time: without what they waited for a core; Unix).
    #[arg(long)]
    out: PathBuf,
    /// Frames per second of flight time.
    #[arg(long, default_value_t = 30.0)]
    fps: f64,
    /// After the flight, at most this many frames with the camera still waiting for the cut to
    /// converge.
    #[arg(long, default_value_t = 600)]
    max_settle_frames: usize,
    /// Synthesise procedural detail past the finest stored level.
    #[arg(long)]
    detail: bool,
    /// Drape this colour repository (`cbdam build IMG --colour --like REPO`), file or URL, over
    /// the terrain: its records are fetched and decoded with the elevation's.
    #[arg(long, value_name = "COLOUR_REPO_OR_URL")]
    colour: Option<String>,
    /// Memory for the cut's decoded diamonds, MiB (0: unlimited). At the limit a refinement
    /// goes ahead only by coarsening diamonds of smaller screen error elsewhere.
    #[arg(long, default_value_t = 1024)]
    cut_mib: usize,
    /// Pace the frames at --fps in real time on a local file too (a viewer's timing: the
    /// workers have the time between frames), not back to back.
    #[arg(long)]
    paced: bool,
    /// Do not decode ahead of the cut between frames (the loop before issue 21's pipelining;
    /// for comparisons).
    #[arg(long)]
    no_decode_ahead: bool,
}

/// Lets a closed stdout end the process quietly, as `cbdam inspect … | head` expects, instead of
/// Rust's default of turning the write error into a panic. Only for the subcommands that touch
/// no sockets: a server must see EPIPE on a dropped connection, not die of the signal.
fn default_sigpipe(command: &Command) {
    #[cfg(unix)]
    if matches!(
        command,
        Command::Inspect(_)
            | Command::Upgrade(_)
            | Command::Verify(_)
            | Command::Extract(_)
            | Command::Build(_)
            | Command::Shard(_)
    ) {
        // SAFETY: restoring a signal's default disposition before any thread is started.
        unsafe {
            libc::signal(libc::SIGPIPE, libc::SIG_DFL);
        }
    }
    #[cfg(not(unix))]
    let _ = command;
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    default_sigpipe(&cli.command);
    let result = match cli.command {
        Command::Build(args) => build::run(&args),
        Command::Shard(command) => shard::run(&command),
        Command::Inspect(args) => inspect::run(&args),
        Command::Upgrade(args) => inspect::upgrade(&args),
        Command::Verify(args) => verify::run(&args),
        Command::Extract(args) => extract::run(&args),
        Command::Serve(args) => serve::run(&args),
        Command::WebExport(args) => web_export::run(&args),
        Command::Link(args) => link::run(&args),
        Command::Replay(args) => replay::run(&args),
        Command::Demo(args) => demo::run(&args),
        Command::Bench(BenchCommand::Codec(args)) => bench_codec::run(&args),
        Command::Bench(BenchCommand::Serve(args)) => bench_serve::run(&args),
        Command::Bench(BenchCommand::Build(args)) => bench_build::run(&args),
        Command::Synth(args) => synth::run(&args),
        Command::Render(args) => render::run(&args),
        Command::View(args) => view::run(&args),
        Command::Bench(BenchCommand::Render(args)) => render::bench(&args),
        Command::Bench(BenchCommand::Report(args)) => bench_report::run(&args),
        Command::Bench(BenchCommand::Network(args)) => bench_network::run(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("cbdam: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
