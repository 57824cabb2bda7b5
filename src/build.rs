//! `cbdam build`: one DEM in memory → one repository file.

use std::io::IsTerminal;
use std::sync::Mutex;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use cbdam_codec::entropy::CoderKind;
use cbdam_codec::hierarchy::{EncodeOptions, encode_with_progress};
use cbdam_codec::input::{ReadOptions, read_dem};
use cbdam_codec::lifting::Alpha;
use cbdam_codec::quant::{HeightGrid, QuantPlan};
use cbdam_codec::repository::write_repository;
use indicatif::{ProgressBar, ProgressStyle};

use crate::{AlphaArg, BuildArgs, CoderArg};

pub fn run(args: &BuildArgs) -> Result<()> {
    let start = Instant::now();
    // Cheap argument checks first, so a typo does not cost a DEM read.
    if !(args.max_error.is_finite() && args.max_error > 0.0) {
        bail!(
            "--max-error must be a positive number of metres, not {}",
            args.max_error
        );
    }
    if args.output.is_dir() {
        bail!("output path {} is a directory", args.output.display());
    }
    let opts = ReadOptions {
        nodata: args.nodata,
        ..ReadOptions::default()
    };
    let dem = read_dem(&args.input, &opts)
        .with_context(|| format!("reading {}", args.input.display()))?;
    let Some((lo, hi)) = dem.valid_range() else {
        bail!(
            "{} has no valid sample (all nodata or NaN)",
            args.input.display()
        );
    };
    // A tolerance above the whole height range would let a flat plane stand for the terrain:
    // almost certainly a unit mistake (feet, centimetres) rather than intent.
    if hi > lo && args.max_error > hi - lo {
        bail!(
            "--max-error {} m exceeds the data's height range ({lo} … {hi} m, {} m); \
             is the unit right?",
            args.max_error,
            hi - lo
        );
    }
    let plan = QuantPlan::for_dem(&dem, args.max_error, args.quantum)?;
    let grid = HeightGrid::from_dem(&dem, &plan)?;
    let enc_opts = EncodeOptions {
        n: args.diamond_size,
        alpha: match args.alpha {
            AlphaArg::One => Alpha::One,
            AlphaArg::Half => Alpha::Half,
        },
        coder: match args.coder {
            CoderArg::Adaptive => CoderKind::Adaptive,
            CoderArg::EliasGamma => CoderKind::EliasGamma,
        },
        ..EncodeOptions::default()
    };
    let mut pool = rayon::ThreadPoolBuilder::new();
    if let Some(t) = args.threads {
        if t == 0 {
            bail!("--threads must be at least 1");
        }
        pool = pool.num_threads(t);
    }
    let pool = pool.build()?;
    let progress = Progress::new(args.quiet);
    let encoded = pool.install(|| {
        encode_with_progress(&grid, plan.quantizer, &enc_opts, &|done, total| {
            progress.update(done, total)
        })
    })?;
    progress.finish();
    write_repository(
        &args.output,
        &encoded,
        &plan,
        dem.georef.as_ref(),
        dem.nodata,
    )
    .with_context(|| format!("writing {}", args.output.display()))?;
    if !args.quiet {
        let bytes = std::fs::metadata(&args.output)?.len();
        let samples = dem.width * dem.height;
        println!(
            "{}: {}×{} samples ({} valid), {} bytes, {:.3} bits/sample, {} records, \
             max error {} m (unit {} m, k = {}), {:.2} s",
            args.output.display(),
            dem.width,
            dem.height,
            dem.valid_count(),
            bytes,
            bytes as f64 * 8.0 / samples as f64,
            encoded.records.len(),
            plan.max_error(),
            plan.unit,
            plan.quantizer.k(),
            start.elapsed().as_secs_f64()
        );
    }
    Ok(())
}

/// Progress of the encode: a bar with ETA on a terminal, a log line per quarter otherwise (so CI
/// logs and pipes stay readable), nothing with `--quiet`.
enum Progress {
    Quiet,
    Bar(ProgressBar),
    Log(Mutex<usize>),
}

impl Progress {
    fn new(quiet: bool) -> Self {
        if quiet {
            Progress::Quiet
        } else if std::io::stderr().is_terminal() {
            let bar = ProgressBar::new(0);
            bar.set_style(
                ProgressStyle::with_template(
                    "encoding {bar:40} {percent:>3}%, {elapsed} elapsed, ETA {eta}",
                )
                .expect("static template"),
            );
            Progress::Bar(bar)
        } else {
            Progress::Log(Mutex::new(0))
        }
    }

    fn update(&self, done: usize, total: usize) {
        match self {
            Progress::Quiet => {}
            Progress::Bar(bar) => {
                bar.set_length(total as u64);
                bar.set_position(done as u64);
            }
            Progress::Log(logged) => {
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

    fn finish(&self) {
        if let Progress::Bar(bar) = self {
            bar.finish_and_clear();
        }
    }
}
