//! `cbdam bench build`: throughput and peak memory of the whole build pipeline.
//!
//! Each run is what `cbdam build` does after parsing its arguments: read, plan, quantize,
//! encode in parallel, write the repository (to a temporary directory). Throughput is input
//! samples over the median wall time. Peak memory is the process's resident high-water mark
//! (`VmHWM`), reset before each dataset through `/proc/self/clear_refs`, so each row shows its
//! own peak; mapped temporaries count while resident.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Result, bail};
use cbdam_codec::hierarchy::EncodeOptions;
use cbdam_codec::repository::write_repository;
use clap::Args;

use cbdam_builder::encode::{encode_prepared, with_coarser_roots_if_smaller};
use cbdam_builder::plan::{InputSpec, Temporaries, default_memory_limit, prepare, storage_for};

use crate::flags;

/// Build throughput (million input samples per second, median of runs) and peak resident
/// memory of `cbdam build` on DEM files (default: the bundled samples) and a synthetic
/// fractal terrain, as a Markdown table.
#[derive(Args, Debug)]
pub struct BenchBuildArgs {
    /// DEM files (GeoTIFF, .hgt, ASCII grid, PNG). Default: every .tif in data/.
    inputs: Vec<PathBuf>,
    /// Side of a synthetic square fractal terrain to add (0: none), e.g. 16385.
    #[arg(long, default_value_t = 4097)]
    synthetic: usize,
    /// Maximum error, metres.
    #[arg(long, default_value_t = 1.0, value_parser = flags::positive_finite)]
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

/// Resets the resident high-water mark (Linux ≥ 4.0); false where that is not possible.
fn reset_peak() -> bool {
    std::fs::write("/proc/self/clear_refs", "5").is_ok()
}

/// The resident high-water mark in bytes, if the platform reports it.
fn peak_rss() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

/// One timed build of `path` into `out`, as `cbdam build` does it: the input samples and where
/// the encoder's temporaries were kept.
fn build_once(
    path: &Path,
    raw_size: Option<(usize, usize)>,
    args: &BenchBuildArgs,
    limit: u64,
    out: &Path,
) -> Result<(usize, Temporaries)> {
    let opts = EncodeOptions::default();
    let input = prepare(&InputSpec {
        path,
        raw_size,
        nodata: None,
        quantum: None,
        max_error: args.max_error,
        memory_limit: limit,
        lattice_dir: None,
    })?;
    let storage = storage_for(&input.grid, None, &opts, limit)?;
    let enc = encode_prepared(
        &input,
        None,
        &opts,
        &storage,
        &cbdam_codec::hierarchy::NoJournal,
        args.threads,
        &|_, _| {},
    )?;
    // What `cbdam build` does by default (`--extra-levels auto`), timed with the rest.
    let (enc, _) = with_coarser_roots_if_smaller(&input, enc, &opts, limit, args.threads)?;
    write_repository(out, &enc, &input.plan, input.georef.as_ref(), input.nodata)?;
    Ok((input.grid.width * input.grid.height, storage))
}

pub fn run(args: &BenchBuildArgs) -> Result<()> {
    if args.runs == 0 {
        bail!("--runs must be at least 1");
    }
    let limit = args.memory_limit.map_or_else(default_memory_limit, |b| b.0);
    let tmp = tempfile::tempdir()?;
    let mut inputs: Vec<(PathBuf, Option<(usize, usize)>)> = if args.inputs.is_empty() {
        super::codec::bundled_inputs(&["tif"])?
            .into_iter()
            .map(|p| (p, None))
            .collect()
    } else {
        args.inputs.iter().map(|p| (p.clone(), None)).collect()
    };
    if args.synthetic > 1 {
        let s = args.synthetic;
        let path = tmp.path().join(format!("synthetic_{s}.f32"));
        crate::synth::write(&path, s, 1)?;
        inputs.push((path, Some((s, s))));
    }
    let threads = args.threads.unwrap_or_else(rayon::current_num_threads);
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    println!(
        "{threads} threads, ε = {} m, median of {} runs, load average before: {}",
        args.max_error,
        args.runs,
        load.split_whitespace()
            .take(3)
            .collect::<Vec<_>>()
            .join(" ")
    );
    println!();
    println!(
        "| dataset | samples | temporaries | bits/sample | median s | M samples/s | peak RSS MiB |"
    );
    println!("|---|---:|---|---:|---:|---:|---:|");
    let out = tmp.path().join("bench.cbdam");
    for (path, raw_size) in &inputs {
        let can_reset = reset_peak();
        let mut times = Vec::new();
        let mut summary = None;
        for _ in 0..args.runs {
            let t = Instant::now();
            let (samples, storage) = build_once(path, *raw_size, args, limit, &out)?;
            times.push(t.elapsed());
            let bits = std::fs::metadata(&out)?.len() as f64 * 8.0 / samples as f64;
            summary = Some((samples, bits, storage));
        }
        let (samples, bits, storage) = summary.expect("at least one run");
        times.sort();
        let median: Duration = times[times.len() / 2];
        let peak = if can_reset { peak_rss() } else { None };
        let name = path.file_stem().unwrap_or_default().to_string_lossy();
        println!(
            "| {name} | {samples} | {} | {bits:.3} | {:.2} | {:.2} | {} |",
            storage.describe(),
            median.as_secs_f64(),
            samples as f64 / median.as_secs_f64() / 1e6,
            peak.map_or("n/a".to_string(), |b| format!(
                "{:.0}",
                b as f64 / 1048576.0
            )),
        );
    }
    Ok(())
}
