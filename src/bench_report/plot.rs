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
fn tick(v: f64) -> String {
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
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK)
                .position(SeriesLabelPosition::UpperRight)
                .draw()
                .map_err(|e| err(&e))?;
        }
    }
    root.present().map_err(|e| err(&e))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::tick;

    #[test]
    fn ticks() {
        assert_eq!(tick(0.05), "0.05");
        assert_eq!(tick(1.0), "1");
        assert_eq!(tick(2.5), "2.5");
        assert_eq!(tick(10.0), "10");
        assert_eq!(tick(123.4), "123");
        assert_eq!(tick(0.0123), "0.0123");
    }
}
