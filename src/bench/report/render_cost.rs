//! "Rendering cost against error": the client's refinement loop (`cbdam replay`, the same code)
//! over the example flights at several pixel-error targets, on one repository built by the
//! report. Triangles per frame, CPU ms per frame and bytes read are what a viewer pays for a
//! tighter target; the screen-space error actually reached is reported next to each point.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use cbdam_client::access::LocalSource;
use cbdam_client::flight::Flight;
use cbdam_client::refine::{RefineConfig, Refiner};
use cbdam_client::stats::percentile;
use cbdam_codec::hierarchy::{EncodeOptions, Encoder};
use cbdam_codec::quant::{HeightGrid, QuantPlan};
use cbdam_codec::repository::{Repository, serialize};
use cbdam_codec::samples::Dem;

use crate::replay::{ReplayPacing, fly};

/// The viewport of every run: the 1920×1080.
pub const VIEWPORT: (u32, u32) = (1920, 1080);
/// Flight frames per second of flight time (as `cbdam replay`'s default).
const FPS: f64 = 30.0;
/// The refinement budget per frame, ms (the client's default).
const BUDGET_MS: f64 = 2.0;
/// Settling frames after the flight at most, before a run counts as not converged.
const MAX_SETTLE_FRAMES: usize = 600;

/// One (flight, pixel-error target) run.
#[derive(Clone, Debug)]
pub struct CostPoint {
    pub flight: String,
    pub pixel_error: f64,
    pub frames: usize,
    pub cpu_ms_median: f64,
    pub cpu_ms_p99: f64,
    pub triangles_median: u64,
    pub bytes_flight: u64,
    /// Median over the flight frames of the cut's largest screen-space error (budget-limited
    /// frames can be above the target).
    pub error_px_median: f64,
    /// The converged cut's largest screen-space error, or `None` if it did not converge.
    pub converged_error_px: Option<f64>,
    pub converged_triangles: u64,
}

/// The flights to fly: every `*.json` in `dir`, sorted by name.
pub fn flights_in(dir: &Path) -> Result<Vec<PathBuf>> {
    crate::bench::codec::files_with(dir, &["json"])
        .with_context(|| format!("reading the flights folder {}", dir.display()))
}

/// Builds `dem` at `eps` (written to `out_dir/NAME.cbdam` so a user can replay or render the
/// same repository), then flies every flight at every target, one CSV per run in `out_dir`.
pub fn measure(
    dem: &Dem,
    name: &str,
    eps: f64,
    flights: &[PathBuf],
    pixel_errors: &[f64],
    out_dir: &Path,
) -> Result<Vec<CostPoint>> {
    std::fs::create_dir_all(out_dir).with_context(|| format!("creating {}", out_dir.display()))?;
    let plan = QuantPlan::for_dem(dem, eps, None)?;
    let grid = HeightGrid::from_dem(dem, &plan)?;
    let encoded = Encoder::new(&grid, plan.quantizer, &EncodeOptions::default()).encode()?;
    let bytes = serialize(&encoded, &plan, dem.georef.as_ref(), dem.nodata)?;
    let repo_path = out_dir.join(format!("{name}.cbdam"));
    std::fs::write(&repo_path, &bytes)
        .with_context(|| format!("writing {}", repo_path.display()))?;
    let repo = Arc::new(Repository::from_bytes(bytes)?);

    let mut points = Vec::new();
    for path in flights {
        let flight = Flight::load(path).with_context(|| format!("loading {}", path.display()))?;
        let flight_name = path
            .file_stem()
            .unwrap_or_default()
            .to_string_lossy()
            .into_owned();
        for &px in pixel_errors {
            let config = RefineConfig {
                pixel_error: px,
                budget: Some(Duration::from_secs_f64(BUDGET_MS / 1e3)),
                ..RefineConfig::default()
            };
            // A fresh source and refiner per run: nothing cached from the previous target.
            let mut refiner = Refiner::new(LocalSource::new(repo.clone()), config)?;
            let pacing = ReplayPacing {
                fps: FPS,
                size: VIEWPORT,
                max_settle_frames: MAX_SETTLE_FRAMES,
                paced: false,
            };
            let csv = out_dir.join(format!("{flight_name}_{px}px.csv"));
            let run = fly(&flight, &mut refiner, &pacing, &csv)?;
            let cpu = run.flight_cpu_sorted();
            let tris = run.flight_triangles_sorted();
            let mut err: Vec<f64> = run.flight().iter().map(|s| s.max_screen_error_px).collect();
            err.sort_by(f64::total_cmp);
            let last = run.last();
            let point = CostPoint {
                flight: flight_name.clone(),
                pixel_error: px,
                frames: run.flight_frames,
                cpu_ms_median: percentile(&cpu, 0.5),
                cpu_ms_p99: percentile(&cpu, 0.99),
                triangles_median: percentile(&tris, 0.5),
                bytes_flight: run.flight_bytes(),
                error_px_median: percentile(&err, 0.5),
                converged_error_px: run.converged_after.map(|_| last.max_screen_error_px),
                converged_triangles: last.triangles,
            };
            eprintln!(
                "{flight_name} {px} px: CPU ms median {:.3} p99 {:.3}, {} triangles/frame, \
                 {} bytes, error median {:.2} px",
                point.cpu_ms_median,
                point.cpu_ms_p99,
                point.triangles_median,
                point.bytes_flight,
                point.error_px_median
            );
            points.push(point);
        }
    }
    Ok(points)
}

/// The section's Markdown body.
pub fn section(points: &[CostPoint], what: &str, plot: Option<&str>) -> Result<String> {
    if points.is_empty() {
        bail!("no rendering-cost runs to report");
    }
    let pixels = f64::from(VIEWPORT.0) * f64::from(VIEWPORT.1);
    let mut out = String::new();
    writeln!(
        out,
        "{what}, viewport {}×{}, refinement budget {BUDGET_MS} ms per frame, {FPS} frames per \
         second of flight, the refinement loop of `cbdam replay` on the local (memory-mapped) \
         repository; CPU is the refining thread's CPU time per flight frame (decoding runs on \
         worker threads). \"Error\" is the largest screen-space error of the cut in the frustum: \
         the median over the flight frames, and after the camera stops and the cut converges.\n",
        VIEWPORT.0, VIEWPORT.1
    )?;
    out += "| flight | target (px) | frames | CPU ms median | CPU ms p99 | triangles / frame (median) \
            | triangles / pixel | KB read in flight | error (px), flight median | error (px), converged \
            | triangles, converged |\n\
            |---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n";
    for p in points {
        writeln!(
            out,
            "| {} | {} | {} | {:.3} | {:.3} | {} | {:.3} | {:.1} | {:.2} | {} | {} |",
            p.flight,
            p.pixel_error,
            p.frames,
            p.cpu_ms_median,
            p.cpu_ms_p99,
            p.triangles_median,
            p.triangles_median as f64 / pixels,
            p.bytes_flight as f64 / 1e3,
            p.error_px_median,
            p.converged_error_px
                .map_or_else(|| "not converged".into(), |e| format!("{e:.2}")),
            p.converged_triangles,
        )?;
    }
    if let Some(plot) = plot {
        writeln!(
            out,
            "\n![rendering cost against the pixel-error target]({plot})"
        )?;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(flight: &str, px: f64, converged: Option<f64>) -> CostPoint {
        CostPoint {
            flight: flight.into(),
            pixel_error: px,
            frames: 451,
            cpu_ms_median: 0.25,
            cpu_ms_p99: 1.5,
            triangles_median: 207_360,
            bytes_flight: 12_345,
            error_px_median: 0.8,
            converged_error_px: converged,
            converged_triangles: 99,
        }
    }

    #[test]
    fn table_rows() {
        assert!(section(&[], "x", None).is_err());
        let s = section(
            &[
                point("descent", 1.0, Some(0.75)),
                point("low_pass", 0.5, None),
            ],
            "SRTM",
            Some("plots/render_cost.svg"),
        )
        .unwrap();
        // 207 360 triangles over 1920×1080 pixels is 0.1 per pixel.
        assert!(
            s.contains(
                "| descent | 1 | 451 | 0.250 | 1.500 | 207360 | 0.100 | 12.3 | 0.80 | 0.75 | 99 |"
            ),
            "{s}"
        );
        assert!(s.contains("| low_pass | 0.5 |") && s.contains("| not converged |"));
        assert!(s.contains("(plots/render_cost.svg)"));
    }
}
