//! `cbdam bench codec`: bits per sample, verified error and throughput on real DEMs.
//!
//! [`measure`] is the one place where the codec is timed and its error verified; `cbdam bench
//! report` calls it too, so both commands measure the same thing the same way.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use cbdam_builder::input::{ReadOptions, read_dem};
use cbdam_codec::entropy::CoderKind;
use cbdam_codec::hierarchy::{
    EncodeOptions, Encoded, Encoder, reconstruct_finest, verify, walk, walk_all_batches,
};
use cbdam_codec::lifting::Alpha;
use cbdam_codec::quant::{HeightGrid, QuantPlan};
use cbdam_codec::repository::serialize;
use cbdam_codec::samples::Dem;
use clap::{Args, ValueEnum};

use crate::flags;

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

/// Rate, verified maximum error and speed of the codec on DEM files (default: the bundled
/// samples), as a Markdown table.
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
    #[command(flatten)]
    diamond_size: flags::DiamondSize,
    /// Level pairs above the smallest covering hierarchy (coarser roots).
    #[arg(long, default_value_t = EncodeOptions::default().extra_level_pairs)]
    extra_levels: u32,
    /// Timed repetitions; the median is reported.
    #[arg(long, default_value_t = 3)]
    runs: usize,
    /// Worker threads for encoding and decoding.
    #[arg(long, default_value_t = 1)]
    threads: usize,
}

/// Median of repeated timings (the upper median for an even count).
pub fn median(mut v: Vec<Duration>) -> Duration {
    v.sort();
    v[v.len() / 2]
}

/// The files in `dir` whose extension is one of `extensions`, sorted by name.
pub fn files_with(dir: &Path, extensions: &[&str]) -> Result<Vec<PathBuf>> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("reading {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.extension()
                .is_some_and(|e| extensions.iter().any(|x| e == *x))
        })
        .collect();
    v.sort();
    Ok(v)
}

/// The bundled DEMs in `data/` whose extension is one of `extensions`, sorted by name.
pub fn bundled_inputs(extensions: &[&str]) -> Result<Vec<PathBuf>> {
    files_with(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("data"),
        extensions,
    )
}

/// One verified measurement of the codec on one DEM at one tolerance.
#[derive(Clone, Debug)]
pub struct Measurement {
    /// Width × height (nodata included): the denominator of every rate and throughput.
    pub samples: usize,
    /// Coded root field.
    pub roots_bytes: usize,
    /// Coded records, all of them.
    pub records_bytes: usize,
    /// Number of records.
    pub records: usize,
    /// Serialised record index.
    pub index_bytes: usize,
    /// The whole repository file as `cbdam build` writes it (header and checksums included).
    pub file_bytes: usize,
    /// Largest |decoded − input| over valid samples at the finest level, metres.
    pub max_err: f64,
    /// Root mean square of the same differences, metres.
    pub rms_err: f64,
    /// Median time of the whole in-memory build: quantization plan, integer grid, encode,
    /// serialisation (no file I/O).
    pub build: Duration,
    /// Median time of the encode alone (within the same runs as `build`).
    pub encode: Duration,
    /// Median time to decode every record and synthesise every diamond, on the measurement's
    /// pool (one thread unless `--threads` says more).
    pub decode: Duration,
    /// The encode and the decode on every core ([`on_all_cores`]), when measured.
    pub all_cores: Option<AllCores>,
}

/// Encode and decode times with a pool of every core: what `cbdam build` and `cbdam extract`
/// use by default.
#[derive(Clone, Copy, Debug)]
pub struct AllCores {
    /// Worker threads of the pool.
    pub threads: usize,
    /// Median time of the encode alone.
    pub encode: Duration,
    /// Median time to decode every record and synthesise every diamond, a batch of the walk's
    /// diamonds at a time in parallel (`walk_all_batches`, as `cbdam extract` decodes).
    pub decode: Duration,
}

impl Measurement {
    /// Roots, records and index: the coded hierarchy without the container.
    pub fn payload_bytes(&self) -> usize {
        self.roots_bytes + self.records_bytes + self.index_bytes
    }

    pub fn payload_bps(&self) -> f64 {
        self.payload_bytes() as f64 * 8.0 / self.samples as f64
    }

    pub fn file_bps(&self) -> f64 {
        self.file_bytes as f64 * 8.0 / self.samples as f64
    }

    /// Million samples per second for a duration over this DEM.
    pub fn msps(&self, d: Duration) -> f64 {
        self.samples as f64 / d.as_secs_f64() / 1e6
    }
}

/// Builds `dem` at tolerance `eps` `runs` times on `pool`, decodes it `runs` times, and checks
/// the guarantee; fails if any level or any valid sample is beyond `eps`.
pub fn measure(
    dem: &Dem,
    eps: f64,
    opts: &EncodeOptions,
    runs: usize,
    pool: &rayon::ThreadPool,
) -> Result<Measurement> {
    if runs == 0 {
        bail!("at least one run is needed");
    }
    let mut build_times = Vec::new();
    let mut enc_times = Vec::new();
    let mut built: Option<(QuantPlan, HeightGrid, Encoded, usize)> = None;
    for _ in 0..runs {
        let t = Instant::now();
        let plan = QuantPlan::for_dem(dem, eps, None)?;
        let grid = HeightGrid::from_dem(dem, &plan)?;
        let te = Instant::now();
        let e = pool.install(|| Encoder::new(&grid, plan.quantizer, opts).encode())?;
        enc_times.push(te.elapsed());
        let file = serialize(&e, &plan, dem.georef.as_ref(), dem.nodata)?;
        build_times.push(t.elapsed());
        built = Some((plan, grid, e, file.len()));
    }
    let (plan, grid, encoded, file_bytes) = built.expect("runs ≥ 1");
    // On `pool` too: the walk decodes each level's diamonds in parallel on the pool it runs in,
    // and outside one that is rayon's global pool of every core.
    let mut dec_times = Vec::new();
    for _ in 0..runs {
        let t = Instant::now();
        pool.install(|| {
            walk(&encoded, |_, p| {
                std::hint::black_box(p);
            })
        })?;
        dec_times.push(t.elapsed());
    }
    // The guarantee, checked every time: every level in integer units, and the finest level
    // against the file's own values in metres.
    let report = verify(&encoded, &grid)?;
    if !report.within_bound() {
        bail!("ε={eps}: L∞ bound violated: {report:?}");
    }
    let finest = reconstruct_finest(&encoded)?;
    let (mut max_err, mut sum_sq, mut valid) = (0f64, 0f64, 0usize);
    for (i, &n) in finest.iter().enumerate() {
        if grid.valid[i] {
            let d = (plan.metres(n) - dem.values[i]).abs();
            max_err = max_err.max(d);
            sum_sq += d * d;
            valid += 1;
        }
    }
    // f64 evaluation of offset + n·u is good to ~1e-16 relative; the bound itself was checked
    // exactly in integers by `verify` above.
    if max_err > eps * (1.0 + 1e-12) {
        bail!("ε={eps}: sample error {max_err} m exceeds the tolerance");
    }
    Ok(Measurement {
        samples: dem.width * dem.height,
        roots_bytes: encoded.roots.len(),
        records_bytes: encoded.records.iter().map(|r| r.bytes.len()).sum(),
        records: encoded.records.len(),
        index_bytes: encoded.index_bytes().len(),
        file_bytes,
        max_err,
        rms_err: (sum_sq / valid.max(1) as f64).sqrt(),
        build: median(build_times),
        encode: median(enc_times),
        decode: median(dec_times),
        all_cores: None,
    })
}

/// The encode and decode of `dem` at `eps` timed `runs` times each on `pool` (every core): the
/// same encode [`measure`] verified, so only the times are taken here.
pub fn on_all_cores(
    dem: &Dem,
    eps: f64,
    opts: &EncodeOptions,
    runs: usize,
    pool: &rayon::ThreadPool,
) -> Result<AllCores> {
    let plan = QuantPlan::for_dem(dem, eps, None)?;
    let grid = HeightGrid::from_dem(dem, &plan)?;
    let (mut enc_times, mut dec_times) = (Vec::new(), Vec::new());
    let mut encoded = None;
    for _ in 0..runs.max(1) {
        let t = Instant::now();
        encoded = Some(pool.install(|| Encoder::new(&grid, plan.quantizer, opts).encode())?);
        enc_times.push(t.elapsed());
    }
    let encoded = encoded.expect("runs ≥ 1");
    for _ in 0..runs.max(1) {
        let t = Instant::now();
        pool.install(|| {
            walk_all_batches(&encoded, |batch| {
                std::hint::black_box(batch);
            })
        })?;
        dec_times.push(t.elapsed());
    }
    Ok(AllCores {
        threads: pool.current_num_threads(),
        encode: median(enc_times),
        decode: median(dec_times),
    })
}

pub fn run(args: &BenchCodecArgs) -> Result<()> {
    if args.runs == 0 {
        bail!("--runs must be at least 1");
    }
    let inputs = if args.inputs.is_empty() {
        bundled_inputs(&["tif"])?
    } else {
        args.inputs.clone()
    };
    let alphas: Vec<Alpha> = match args.alpha {
        Which::Default => vec![Alpha::One],
        Which::Other => vec![Alpha::Half],
        Which::Both => vec![Alpha::One, Alpha::Half],
    };
    let coders: Vec<CoderKind> = match args.coder {
        Which::Default => vec![CoderKind::AdaptiveTokens],
        Which::Other => vec![CoderKind::Adaptive, CoderKind::EliasGamma],
        Which::Both => vec![
            CoderKind::AdaptiveTokens,
            CoderKind::Adaptive,
            CoderKind::EliasGamma,
        ],
    };
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(args.threads.max(1))
        .build()?;
    println!(
        "| dataset | ε (m) | α | coder | bits/sample | roots B | records | index B | verified max err (m) | encode MS/s | decode MS/s |"
    );
    println!("|---|---:|---|---|---:|---:|---:|---:|---:|---:|---:|");
    for path in &inputs {
        let dem = read_dem(path, &ReadOptions::default())
            .with_context(|| format!("reading {}", path.display()))?;
        let name = path.file_stem().unwrap_or_default().to_string_lossy();
        for &eps in &args.max_error {
            for &alpha in &alphas {
                for &coder in &coders {
                    let opts = EncodeOptions {
                        n: args.diamond_size.value,
                        alpha,
                        coder,
                        extra_level_pairs: args.extra_levels,
                    };
                    let m = measure(&dem, eps, &opts, args.runs, &pool)
                        .with_context(|| name.to_string())?;
                    // The whole hierarchy: root field, records and their index (the container's
                    // fixed-size header is not counted).
                    println!(
                        "| {name} | {eps} | {} | {} | {:.3} | {} | {} | {} | {:.4} | {:.1} | {:.1} |",
                        if alpha == Alpha::One { "1" } else { "½" },
                        coder.name(),
                        m.payload_bps(),
                        m.roots_bytes,
                        m.records,
                        m.index_bytes,
                        m.max_err,
                        m.msps(m.encode),
                        m.msps(m.decode),
                    );
                }
            }
        }
    }
    Ok(())
}
