//! `cbdam bench report --rms E`: C-BDAM's other error control beside the maximum error. Every
//! input is built twice as `cbdam build` builds it — within a maximum error of `E` and within
//! a root-mean-square error of `E` (`--rms-error E`) — and both files are checked against the
//! input the way `cbdam verify --against` checks them, so each row's errors are measured on
//! the files the rates come from.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use cbdam_builder::verify::{DemComparison, compare_dem};
use cbdam_builder::{BuildOptions, NoProgress, build};
use cbdam_codec::repository::Repository;

/// One input built both ways.
pub struct RmsRow {
    pub dataset: String,
    pub samples: usize,
    /// The `--max-error E` build: file bytes, and its errors measured against the input.
    pub max_bytes: u64,
    pub max_build: Errors,
    /// The `--rms-error E` build.
    pub rms_bytes: u64,
    pub rms_build: Errors,
}

/// A build's errors against its input, metres, over the valid samples of the finest level.
#[derive(Clone, Copy)]
pub struct Errors {
    pub max: f64,
    pub rms: f64,
}

impl RmsRow {
    fn bps(&self, bytes: u64) -> f64 {
        bytes as f64 * 8.0 / self.samples as f64
    }
}

/// Builds and checks every input at maximum error `e` and at RMS error `e`, in `dir`.
pub fn measure(inputs: &[PathBuf], e: f64, dir: &Path) -> Result<Vec<RmsRow>> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let mut rows = Vec::new();
    for input in inputs {
        let name = input
            .file_name()
            .unwrap_or_default()
            .to_string_lossy()
            .into_owned();
        let (max_bytes, max_check) = built(input, &dir.join(format!("{name}.max.cbdam")), e, None)?;
        let (rms_bytes, rms_check) =
            built(input, &dir.join(format!("{name}.rms.cbdam")), e, Some(e))?;
        eprintln!(
            "{name}: RMS {e} m build {rms_bytes} B (RMS {:.4} m, max {:.4} m) against max {e} m \
             build {max_bytes} B",
            rms_check.rms_error, rms_check.max_error
        );
        rows.push(RmsRow {
            dataset: name,
            samples: max_check.samples,
            max_bytes,
            max_build: errors(&max_check),
            rms_bytes,
            rms_build: errors(&rms_check),
        });
    }
    Ok(rows)
}

fn errors(c: &DemComparison) -> Errors {
    Errors {
        max: c.max_error,
        rms: c.rms_error,
    }
}

/// `input` built into `out` within maximum error `max_error` or, with `rms`, within that RMS
/// error (no maximum-error cap), then checked against `input`: its size and the comparison.
fn built(
    input: &Path,
    out: &Path,
    max_error: f64,
    rms: Option<f64>,
) -> Result<(u64, DemComparison)> {
    let mut opts = BuildOptions::new(vec![input.to_path_buf()], out.to_path_buf(), max_error);
    if rms.is_some() {
        opts.max_error = f64::INFINITY;
        opts.rms_error = rms;
    }
    build(&opts, &NoProgress).with_context(|| format!("building {}", out.display()))?;
    let bytes = std::fs::metadata(out)?.len();
    let repo = Repository::open(out).with_context(|| format!("opening {}", out.display()))?;
    let check = compare_dem(&repo, input)?;
    check
        .check()
        .with_context(|| format!("{} against {}", out.display(), input.display()))?;
    Ok((bytes, check))
}

/// The report's section: bits per sample of both builds and their ratio, with the errors
/// measured.
pub fn section(rows: &[RmsRow], e: f64) -> Result<String> {
    let mut md = String::new();
    writeln!(
        md,
        "`cbdam build --rms-error {e}` against `cbdam build --max-error {e}` (whole files; \
         errors of the finest level against the input over its valid samples, as `cbdam verify \
         --against` measures them — both files pass it). The paper's ratio at 1 m on Puget \
         Sound is 0.28 / 0.61 = 0.46.\n"
    )?;
    writeln!(
        md,
        "| dataset | max {e} m: bits/sample | max {e} m: max / RMS error (m) | RMS {e} m: \
         bits/sample | RMS {e} m: max / RMS error (m) | RMS ÷ max |\n|---|---:|---:|---:|---:|---:|"
    )?;
    for r in rows {
        writeln!(
            md,
            "| {} | {:.3} | {:.3} / {:.3} | {:.3} | {:.3} / {:.3} | {:.3} |",
            r.dataset,
            r.bps(r.max_bytes),
            r.max_build.max,
            r.max_build.rms,
            r.bps(r.rms_bytes),
            r.rms_build.max,
            r.rms_build.rms,
            r.rms_bytes as f64 / r.max_bytes as f64
        )?;
    }
    Ok(md)
}
