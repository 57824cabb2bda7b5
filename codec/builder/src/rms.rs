//! `cbdam build --rms-error E`: the coarsest quantizer whose reconstruction of the finest level
//! has a root-mean-square error of at most `E` over every valid sample, measured, not assumed.
//!
//! The quantizer is one step for the whole hierarchy (the maximum-error build's): what this
//! chooses is its maximum error, the largest of a ladder of candidates `E · 2^(i/8)` (capped by
//! `--max-error` when given) whose encode, decoded again, meets the RMS bound. RMS error is not
//! monotone in the step, so the ladder is searched by bisection and only candidates that were
//! encoded and measured are kept; the smallest, `min(E, cap)`, always meets it (an RMS error
//! is at most the maximum error). The build then encodes with the chosen candidate exactly as
//! the trial did (the encode is deterministic), and the header records the bound and the RMS
//! error measured ([`RmsBound`]).
//!
//! On lattice data (whole metres, decimetres) the maximum-error steps are odd multiples of the
//! data's quantum `q` (a maximum error of 1 m on whole metres is a step of 3 m), and the next
//! one up (5 m) usually breaks an RMS bound the first (RMS 0.8 m) leaves slack under. Unless
//! `--quantum` is given, the ladder is therefore also searched on a unit of `q / 8`, whose steps
//! fall between them, and the build keeps whichever of the two choices codes smaller.

use cbdam_codec::hierarchy::{Encoded, NoJournal, reconstruct_finest_with_validity};
use cbdam_codec::quant::{LevelQuantizers, QuantPlan, RmsBound};
use cbdam_codec::samples::{Dem, detect_quantum};

use crate::encode::{ExtraLevels, encode_prepared, with_coarser_roots_if_smaller};
use crate::error::{Context, Result, bail};
use crate::input::{Format, ReadOptions, read_dem};
use crate::plan::is_raw_path;
use crate::progress::NoProgress;
use crate::{BuildOptions, prepare_elevation};

/// Rungs of the candidate ladder per octave of maximum error.
const RUNGS_PER_OCTAVE: i32 = 8;
/// The finer unit the ladder is also searched on, as a fraction of the data's quantum.
const FINER_UNIT: f64 = 8.0;
/// The ladder's top: `E · 2^MAX_OCTAVES`. An RMS error far below the maximum error needs most
/// residuals well inside the dead zone; beyond 16 E the rate hardly falls further.
const MAX_OCTAVES: i32 = 4;

/// What `--rms-error` chose: the maximum error to build with, the unit to build on (`None`:
/// the data's own), and the bound to record.
pub(crate) struct RmsChoice {
    pub max_error: f64,
    pub quantum: Option<f64>,
    pub bound: RmsBound,
    /// A quantizer per level that meets the bound in fewer bytes ([`crate::rms_levels`]), and
    /// the level pairs above the smallest hierarchy it was allocated for.
    pub levels: Option<(LevelQuantizers, u32)>,
}

/// The quantizer for `--rms-error target` (`opts.max_error` is the cap, infinite when none was
/// given): the ladder searched on the data's unit and, for lattice data without `--quantum`,
/// on a finer one; the smaller coding wins.
pub(crate) fn choose(opts: &BuildOptions, target: f64) -> Result<RmsChoice> {
    if !(target.is_finite() && target > 0.0) {
        bail!("--rms-error must be a positive number of metres, not {target}");
    }
    if opts.inputs.len() != 1 || opts.block_plan.is_some() {
        bail!(
            "--rms-error needs one input DEM built in memory (not tiles, a mosaic or a block \
             plan): the RMS error is measured on the whole decoded surface"
        );
    }
    let cap = opts.max_error;
    if cap.is_nan() || cap <= 0.0 {
        bail!("--max-error must be a positive number of metres, not {cap}");
    }
    let dem = read_input(opts)?;
    let own = search_ladder(opts, &dem, target)?;
    let finer = match (opts.quantum, detect_quantum(&dem)) {
        (None, Some(q)) => {
            let finer = BuildOptions {
                quantum: Some(q / FINER_UNIT),
                ..opts.clone()
            };
            // The finer unit is an offer, not a requirement: where the data does not sit on
            // it (a quantum detected within float rounding), the data's own unit stands.
            search_ladder(&finer, &dem, target).ok()
        }
        _ => None,
    };
    let mut choice = match finer {
        Some(f) if f.bytes < own.bytes => f.choice,
        _ => own.choice,
    };
    let uniform = BuildOptions {
        max_error: choice.max_error,
        quantum: choice.quantum,
        rms_error: None,
        ..opts.clone()
    };
    if let Some(p) = crate::rms_levels::allocate(&uniform, &dem, target, cap)? {
        choice.levels = Some((p.levels, p.extra_level_pairs));
        choice.bound.measured = p.measured;
    }
    Ok(choice)
}

/// The ladder's winner on one unit, with its coded size.
struct Searched {
    choice: RmsChoice,
    bytes: usize,
}

/// The last rung of the ladder on `opts`'s unit whose build meets the RMS bound.
fn search_ladder(opts: &BuildOptions, dem: &Dem, target: f64) -> Result<Searched> {
    let ladder: Vec<f64> = (0..=RUNGS_PER_OCTAVE * MAX_OCTAVES)
        .map(|i| {
            (target * 2f64.powf(f64::from(i) / f64::from(RUNGS_PER_OCTAVE))).min(opts.max_error)
        })
        .collect();
    let measure = |max_error: f64| -> Result<(f64, usize)> {
        let trial = BuildOptions {
            max_error,
            rms_error: None,
            ..opts.clone()
        };
        let (encoded, plan) = encode_in_memory(&trial)?;
        Ok((rms_error(&encoded, &plan, dem)?, encoded.payload_bytes()))
    };
    // Bisection for the last rung that meets the bound: `lo` is known to meet it.
    let (mut lo, mut hi) = (0usize, ladder.len());
    let mut best = measure(ladder[0])?;
    if best.0 > target {
        bail!(
            "the build at a maximum error of {} m has an RMS error of {} m, over \
             --rms-error {target} m (the float quantizer's pre-rounding); lower --max-error",
            ladder[0],
            best.0
        );
    }
    while hi - lo > 1 {
        let mid = (lo + hi) / 2;
        if ladder[mid] == ladder[lo] {
            // Capped: every rung from here on is the cap.
            hi = mid;
            continue;
        }
        let trial = measure(ladder[mid])?;
        if trial.0 <= target {
            (lo, best) = (mid, trial);
        } else {
            hi = mid;
        }
    }
    Ok(Searched {
        choice: RmsChoice {
            max_error: ladder[lo],
            quantum: opts.quantum,
            bound: RmsBound {
                target,
                measured: best.0,
            },
            levels: None,
        },
        bytes: best.1,
    })
}

/// The one input as floats in metres, read as the build reads it (its nodata override, raw
/// float32 of `--size`).
fn read_input(opts: &BuildOptions) -> Result<Dem> {
    let path = &opts.inputs[0];
    let mut read = ReadOptions {
        nodata: opts.nodata,
        ..ReadOptions::default()
    };
    if let Some((width, height)) = opts.raw_size {
        read.format = Some(Format::RawF32 { width, height });
    } else if is_raw_path(path) {
        bail!("{}: a raw float32 input needs --size", path.display());
    }
    read_dem(path, &read).with_context(|| format!("reading {}", path.display()))
}

/// Encodes `opts`'s input as [`crate::build_elevation`] does, without writing it.
fn encode_in_memory(opts: &BuildOptions) -> Result<(Encoded, QuantPlan)> {
    let prepared = prepare_elevation(opts, &NoProgress, None)?;
    let (input, enc_opts) = (&prepared.input, &prepared.enc_opts);
    let encoded = encode_prepared(
        input,
        prepared.resolution.as_ref(),
        enc_opts,
        &prepared.storage,
        &NoJournal,
        opts.threads,
        &|_, _| {},
    )?;
    let encoded = if opts.extra_levels == ExtraLevels::Auto && prepared.resolution.is_none() {
        with_coarser_roots_if_smaller(input, encoded, enc_opts, prepared.limit, opts.threads)?.0
    } else {
        encoded
    };
    Ok((encoded, input.plan))
}

/// The root-mean-square of `decoded − input` over the input's valid samples at the finest
/// level, metres.
pub fn rms_error(encoded: &Encoded, plan: &QuantPlan, dem: &Dem) -> Result<f64> {
    let (finest, _) = reconstruct_finest_with_validity(encoded)?;
    if finest.len() != dem.values.len() {
        bail!("the decoded surface and the input differ in size");
    }
    let (mut sum, mut count) = (0f64, 0u64);
    for (&n, &v) in finest.iter().zip(&dem.values) {
        if v.is_nan() || dem.nodata == Some(v) {
            continue;
        }
        let e = plan.metres(n) - v;
        sum += e * e;
        count += 1;
    }
    if count == 0 {
        bail!("the input has no valid sample to measure an RMS error on");
    }
    Ok((sum / count as f64).sqrt())
}
