//! `cbdam bench codec`: bits per sample, verified error and throughput on real DEMs.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use cbdam_codec::entropy::CoderKind;
use cbdam_codec::hierarchy::{EncodeOptions, Encoded, encode, reconstruct_finest, verify, walk};
use cbdam_codec::input::{ReadOptions, read_dem};
use cbdam_codec::lifting::Alpha;
use cbdam_codec::quant::{HeightGrid, QuantPlan};

use crate::{BenchCodecArgs, Which};

fn median(mut v: Vec<Duration>) -> Duration {
    v.sort();
    v[v.len() / 2]
}

fn default_inputs() -> Result<Vec<PathBuf>> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("data");
    let mut v: Vec<PathBuf> = std::fs::read_dir(&dir)
        .with_context(|| format!("reading {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "tif"))
        .collect();
    v.sort();
    Ok(v)
}

pub fn run(args: &BenchCodecArgs) -> Result<()> {
    if args.runs == 0 {
        bail!("--runs must be at least 1");
    }
    let inputs = if args.inputs.is_empty() {
        default_inputs()?
    } else {
        args.inputs.clone()
    };
    let alphas: Vec<Alpha> = match args.alpha {
        Which::Default => vec![Alpha::One],
        Which::Other => vec![Alpha::Half],
        Which::Both => vec![Alpha::One, Alpha::Half],
    };
    let coders: Vec<CoderKind> = match args.coder {
        Which::Default => vec![CoderKind::Adaptive],
        Which::Other => vec![CoderKind::EliasGamma],
        Which::Both => vec![CoderKind::Adaptive, CoderKind::EliasGamma],
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
        let samples = (dem.width * dem.height) as f64;
        for &eps in &args.max_error {
            let plan = QuantPlan::for_dem(&dem, eps, None)?;
            let grid = HeightGrid::from_dem(&dem, &plan)?;
            for &alpha in &alphas {
                for &coder in &coders {
                    let opts = EncodeOptions {
                        n: args.diamond_size,
                        alpha,
                        coder,
                        extra_level_pairs: args.extra_levels,
                    };
                    let mut enc_times = Vec::new();
                    let mut encoded: Option<Encoded> = None;
                    for _ in 0..args.runs {
                        let t = Instant::now();
                        let e = pool.install(|| encode(&grid, plan.quantizer, &opts))?;
                        enc_times.push(t.elapsed());
                        encoded = Some(e);
                    }
                    let encoded = encoded.expect("runs ≥ 1");
                    let mut dec_times = Vec::new();
                    for _ in 0..args.runs {
                        let t = Instant::now();
                        walk(&encoded, |_, p| {
                            std::hint::black_box(p);
                        })?;
                        dec_times.push(t.elapsed());
                    }
                    // The guarantee, checked every time: every level in integer units, and the
                    // finest level against the file's own values in metres.
                    let report = verify(&encoded, &grid)?;
                    if !report.within_bound() {
                        bail!("{name} ε={eps}: L∞ bound violated: {report:?}");
                    }
                    let finest = reconstruct_finest(&encoded)?;
                    let mut max_err = 0f64;
                    for (i, &n) in finest.iter().enumerate() {
                        if grid.valid[i] {
                            max_err = max_err.max((plan.metres(n) - dem.values[i]).abs());
                        }
                    }
                    // f64 evaluation of offset + n·u is good to ~1e-16 relative; the bound
                    // itself was checked exactly in integers by `verify` above.
                    if max_err > eps * (1.0 + 1e-12) {
                        bail!("{name} ε={eps}: sample error {max_err} m exceeds the tolerance");
                    }
                    // The whole hierarchy: root field, records and their index (the container's
                    // fixed-size header is not counted).
                    let index = encoded.index_bytes().len();
                    let bits = (encoded.payload_bytes() + index) as f64 * 8.0;
                    let ms = |d: Duration| samples / d.as_secs_f64() / 1e6;
                    println!(
                        "| {name} | {eps} | {} | {} | {:.3} | {} | {} | {index} | {:.4} | {:.1} | {:.1} |",
                        if alpha == Alpha::One { "1" } else { "½" },
                        coder.name(),
                        bits / samples,
                        encoded.roots.len(),
                        encoded.records.len(),
                        max_err,
                        ms(median(enc_times)),
                        ms(median(dec_times)),
                    );
                }
            }
        }
    }
    Ok(())
}
