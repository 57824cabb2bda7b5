//! The SVG of `cbdam bench network`: the cut's largest screen-space error against wall time, a
//! panel per (flight, profile), a series per server (and the local file for reference), with
//! the pixel target and the moment the camera stops marked.

use std::path::Path;

use anyhow::{Result, anyhow};
use plotters::prelude::*;

use crate::bench::report::plot::tick;

/// One line: its name and (wall seconds, error px) points.
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
    /// Wall second at which the camera stopped in this run.
    pub stop_s: f64,
}

/// One panel.
pub struct Panel {
    pub title: String,
    pub series: Vec<Series>,
}

/// Errors below this are drawn at it (a log axis has no 0; 0 means nothing left to refine).
const FLOOR_PX: f64 = 0.1;

/// Colour of a series by name, stable across panels.
fn colour(name: &str) -> RGBAColor {
    match name {
        n if n.starts_with("local") => RGBColor(110, 110, 110).to_rgba(),
        n if n.starts_with("serve") => RGBColor(31, 119, 180).to_rgba(),
        n if n.starts_with("static") => RGBColor(214, 39, 40).to_rgba(),
        _ => RGBColor(44, 160, 44).to_rgba(),
    }
}

/// The points a line needs: of each run of equal values only the first and the last (the
/// error holds still for seconds while data is awaited; the SVG need not repeat it per frame).
fn thin(points: impl Iterator<Item = (f64, f64)>) -> Vec<(f64, f64)> {
    let mut out: Vec<(f64, f64)> = Vec::new();
    for p in points {
        let n = out.len();
        if n >= 2 && out[n - 1].1 == p.1 && out[n - 2].1 == p.1 {
            out[n - 1] = p;
        } else {
            out.push(p);
        }
    }
    out
}

/// The top of every panel's error axis: half again above the largest finite error, and at least
/// ten times the target.
fn error_top(panels: &[Panel], target_px: f64) -> f64 {
    panels
        .iter()
        .flat_map(|p| p.series.iter().flat_map(|s| s.points.iter().map(|q| q.1)))
        .filter(|v| v.is_finite())
        .fold(target_px * 10.0, f64::max)
        * 1.5
}

/// The latest wall time of any series of `panel`, and at least one second.
fn last_second(panel: &Panel) -> f64 {
    panel
        .series
        .iter()
        .flat_map(|s| s.points.iter().map(|q| q.0))
        .fold(1.0, f64::max)
}

/// Draws `panels` in a grid of `columns`, to `path`.
pub fn screen_error(
    path: &Path,
    title: &str,
    panels: &[Panel],
    columns: usize,
    target_px: f64,
) -> Result<()> {
    let err = |e: &dyn std::fmt::Debug| anyhow!("plotting {}: {e:?}", path.display());
    let columns = columns.max(1);
    let rows = panels.len().div_ceil(columns).max(1);
    // Wide enough for the title even with one column.
    let size = ((440 * columns as u32).max(900), 40 + 330 * rows as u32);
    let root = SVGBackend::new(path, size).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let root = root
        .titled(title, ("sans-serif", 20))
        .map_err(|e| err(&e))?;
    let y_hi = error_top(panels, target_px);
    for (panel, area) in panels.iter().zip(root.split_evenly((rows, columns))) {
        let x_hi = last_second(panel);
        let mut chart = ChartBuilder::on(&area)
            .caption(&panel.title, ("sans-serif", 15))
            .margin(10)
            .x_label_area_size(34)
            .y_label_area_size(50)
            .build_cartesian_2d(0.0..x_hi * 1.02, (FLOOR_PX..y_hi).log_scale())
            .map_err(|e| err(&e))?;
        chart
            .configure_mesh()
            .x_desc("wall time (s)")
            .y_desc("max screen error (px)")
            .y_label_formatter(&|v| tick(*v))
            .draw()
            .map_err(|e| err(&e))?;
        chart
            .draw_series(DashedLineSeries::new(
                [(0.0, target_px), (x_hi * 1.02, target_px)],
                5,
                4,
                BLACK.stroke_width(1),
            ))
            .map_err(|e| err(&e))?;
        for s in &panel.series {
            let c = colour(&s.name);
            chart
                .draw_series(DashedLineSeries::new(
                    [(s.stop_s, FLOOR_PX), (s.stop_s, y_hi)],
                    3,
                    5,
                    c.stroke_width(1),
                ))
                .map_err(|e| err(&e))?;
            let pts = thin(
                s.points
                    .iter()
                    .map(|&(x, y)| (x, if y.is_finite() { y.max(FLOOR_PX) } else { y_hi })),
            );
            chart
                .draw_series(LineSeries::new(pts, c.stroke_width(2)))
                .map_err(|e| err(&e))?
                .label(s.name.as_str())
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 18, y)], c.stroke_width(2))
                });
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .position(SeriesLabelPosition::UpperRight)
            .draw()
            .map_err(|e| err(&e))?;
    }
    root.present().map_err(|e| err(&e))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::thin;

    #[test]
    fn runs_of_equal_values_keep_their_ends() {
        let p = [
            (0.0, 5.0),
            (1.0, 3.0),
            (2.0, 3.0),
            (3.0, 3.0),
            (4.0, 3.0),
            (5.0, 1.0),
        ];
        assert_eq!(
            thin(p.into_iter()),
            vec![(0.0, 5.0), (1.0, 3.0), (4.0, 3.0), (5.0, 1.0)]
        );
        assert_eq!(thin([(0.0, 2.0)].into_iter()), vec![(0.0, 2.0)]);
        assert!(thin(std::iter::empty()).is_empty());
    }
}
