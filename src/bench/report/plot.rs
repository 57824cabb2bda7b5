//! SVG plots: per dataset, bits/sample, build throughput and decode throughput against ε, every
//! codec one series, both axes logarithmic (rates span 0.01…20 bits, tolerances 0.05…10 m).

use std::path::Path;

use anyhow::{Result, anyhow};
use plotters::prelude::*;

/// One codec's points: (ε, bits/sample, encode MS/s, decode MS/s).
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64, f64, f64)>,
}

fn span(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = values
        .filter(|v| v.is_finite() && *v > 0.0)
        .fold((f64::INFINITY, 0f64), |(lo, hi), v| (lo.min(v), hi.max(v)));
    if lo > hi {
        (0.1, 1.0)
    } else {
        // A margin on the log scale so that extreme points are not on the frame.
        (lo / 1.3, hi * 1.3)
    }
}

/// A tick label with three significant digits and no trailing zeros (0.05, 1.5, 20, 300).
pub(crate) fn tick(v: f64) -> String {
    if v <= 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let decimals = (2 - v.log10().floor() as i32).max(0) as usize;
    let s = format!("{v:.decimals$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

/// A linear-axis label: 0, 0.25, 350k, 1.2M.
fn si(v: f64) -> String {
    if v.abs() >= 1e6 {
        format!("{}M", tick(v / 1e6))
    } else if v.abs() >= 1e4 {
        format!("{}k", tick(v / 1e3))
    } else if v == 0.0 {
        "0".into()
    } else {
        tick(v)
    }
}

/// The series legend, drawn on a plot's first panel.
fn legend<'a, DB: DrawingBackend + 'a, CT: CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(SeriesLabelPosition::UpperRight)
        .draw()
}

pub fn dataset(path: &Path, title: &str, series: &[Series]) -> Result<()> {
    let err = |e: &dyn std::fmt::Debug| anyhow!("plotting {}: {e:?}", path.display());
    let root = SVGBackend::new(path, (1500, 480)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let root = root
        .titled(title, ("sans-serif", 22))
        .map_err(|e| err(&e))?;
    let panels = root.split_evenly((1, 3));
    let (x_lo, x_hi) = span(series.iter().flat_map(|s| s.points.iter().map(|p| p.0)));
    type Pick = fn(&(f64, f64, f64, f64)) -> f64;
    let what: [(&str, Pick); 3] = [
        ("bits per sample", |p| p.1),
        ("build / encode, M samples/s", |p| p.2),
        ("decode, M samples/s", |p| p.3),
    ];
    for (k, (panel, (label, pick))) in panels.iter().zip(what).enumerate() {
        let (y_lo, y_hi) = span(series.iter().flat_map(|s| s.points.iter().map(pick)));
        let mut chart = ChartBuilder::on(panel)
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d((x_lo..x_hi).log_scale(), (y_lo..y_hi).log_scale())
            .map_err(|e| err(&e))?;
        chart
            .configure_mesh()
            .x_desc("max error ε (m)")
            .y_desc(label)
            .x_label_formatter(&|v| tick(*v))
            .y_label_formatter(&|v| tick(*v))
            .draw()
            .map_err(|e| err(&e))?;
        for (i, s) in series.iter().enumerate() {
            let color = Palette99::pick(i).to_rgba();
            let pts: Vec<(f64, f64)> = s
                .points
                .iter()
                .map(|p| (p.0, pick(p)))
                .filter(|p| p.1 > 0.0 && p.1.is_finite())
                .collect();
            let width = if i == 0 { 3 } else { 1 };
            let line = chart
                .draw_series(LineSeries::new(pts.clone(), color.stroke_width(width)))
                .map_err(|e| err(&e))?;
            if k == 0 {
                line.label(s.name.as_str()).legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(width))
                });
            }
            chart
                .draw_series(pts.iter().map(|&p| Circle::new(p, 3, color.filled())))
                .map_err(|e| err(&e))?;
        }
        if k == 0 {
            legend(&mut chart).map_err(|e| err(&e))?;
        }
    }
    root.present().map_err(|e| err(&e))?;
    Ok(())
}

/// What a rendering-cost panel shows of a point: its value and, where it has one, a second
/// (dashed) value.
type Pick = fn(&super::render_cost::CostPoint) -> (f64, Option<f64>);

/// The top of a rendering-cost panel's linear axis: 15 % above the largest finite value `pick`
/// gives.
fn y_top(points: &[super::render_cost::CostPoint], pick: Pick) -> f64 {
    points
        .iter()
        .flat_map(|p| {
            let (a, b) = pick(p);
            [Some(a), b].into_iter().flatten()
        })
        .filter(|v| v.is_finite())
        .fold(0f64, f64::max)
        .max(1e-9)
        * 1.15
}

/// The rendering-cost plot: triangles per frame, CPU ms per frame (median, dashed p99) and KB
/// read during the flight against the pixel-error target, one series per flight. Both axes
/// logarithmic: targets span 0.5…8 px and costs fall roughly with their square.
pub fn render_cost(
    path: &Path,
    title: &str,
    points: &[super::render_cost::CostPoint],
) -> Result<()> {
    let err = |e: &dyn std::fmt::Debug| anyhow!("plotting {}: {e:?}", path.display());
    let root = SVGBackend::new(path, (1500, 480)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let root = root
        .titled(title, ("sans-serif", 22))
        .map_err(|e| err(&e))?;
    let panels = root.split_evenly((1, 3));
    let mut flights: Vec<&str> = points.iter().map(|p| p.flight.as_str()).collect();
    flights.dedup();
    let (x_lo, x_hi) = span(points.iter().map(|p| p.pixel_error));
    let what: [(&str, Pick); 3] = [
        ("triangles per frame (median)", |p| {
            (p.triangles_median as f64, None)
        }),
        ("CPU ms per frame (median, p99 dashed)", |p| {
            (p.cpu_ms_median, Some(p.cpu_ms_p99))
        }),
        ("KB read during the flight", |p| {
            (p.bytes_flight as f64 / 1e3, None)
        }),
    ];
    for (k, (panel, (label, pick))) in panels.iter().zip(what).enumerate() {
        // Linear from zero: a factor of 2–4 over the range, where a log axis would show no
        // labelled tick at all.
        let y_hi = y_top(points, pick);
        let mut chart = ChartBuilder::on(panel)
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d((x_lo..x_hi).log_scale(), 0.0..y_hi)
            .map_err(|e| err(&e))?;
        chart
            .configure_mesh()
            .x_desc("pixel-error target (px)")
            .y_desc(label)
            .x_label_formatter(&|v| tick(*v))
            .y_label_formatter(&|v| si(*v))
            .draw()
            .map_err(|e| err(&e))?;
        for (i, flight) in flights.iter().enumerate() {
            let color = Palette99::pick(i).to_rgba();
            let of = || points.iter().filter(move |p| p.flight == *flight);
            let main: Vec<(f64, f64)> = of()
                .map(|p| (p.pixel_error, pick(p).0))
                .filter(|p| p.1 > 0.0 && p.1.is_finite())
                .collect();
            let line = chart
                .draw_series(LineSeries::new(main.clone(), color.stroke_width(2)))
                .map_err(|e| err(&e))?;
            if k == 0 {
                line.label(*flight).legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(2))
                });
            }
            chart
                .draw_series(main.iter().map(|&p| Circle::new(p, 3, color.filled())))
                .map_err(|e| err(&e))?;
            let second: Vec<(f64, f64)> = of()
                .filter_map(|p| pick(p).1.map(|v| (p.pixel_error, v)))
                .filter(|p| p.1 > 0.0 && p.1.is_finite())
                .collect();
            if !second.is_empty() {
                chart
                    .draw_series(DashedLineSeries::new(second, 6, 4, color.stroke_width(1)))
                    .map_err(|e| err(&e))?;
            }
        }
        if k == 0 {
            legend(&mut chart).map_err(|e| err(&e))?;
        }
    }
    root.present().map_err(|e| err(&e))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::{si, tick};

    #[test]
    fn ticks() {
        assert_eq!(tick(0.05), "0.05");
        assert_eq!(tick(1.0), "1");
        assert_eq!(tick(2.5), "2.5");
        assert_eq!(tick(10.0), "10");
        assert_eq!(tick(123.4), "123");
        assert_eq!(tick(0.0123), "0.0123");
        assert_eq!(si(0.0), "0");
        assert_eq!(si(0.25), "0.25");
        assert_eq!(si(350_000.0), "350k");
        assert_eq!(si(1_250_000.0), "1.25M");
    }
}
