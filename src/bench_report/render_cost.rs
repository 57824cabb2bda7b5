//! "Rendering cost against error": summarises `cbdam replay`'s per-frame CSVs.
//!
//! `cbdam replay` (issue 5) writes one CSV per run with a header naming at least `refine_ms`,
//! `triangles`, `bytes_fetched` and `max_screen_error_px`. Until the report is given such files
//! the section says it was not measured; it never invents figures.

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::{Context, Result, bail};

const COLUMNS: [&str; 4] = [
    "refine_ms",
    "triangles",
    "bytes_fetched",
    "max_screen_error_px",
];

use crate::replay::percentile;

/// The section's Markdown body for `csvs` (each labelled, e.g. by its ε and pixel tolerance).
pub fn section(csvs: &[(String, PathBuf)]) -> Result<String> {
    if csvs.is_empty() {
        return Ok("Not measured: cbdam replay not available.\n".into());
    }
    let mut out = String::from(
        "| run | frames | refine ms median | refine ms p95 | triangles median | MB fetched | max screen error (px) |\n\
         |---|---:|---:|---:|---:|---:|---:|\n",
    );
    for (label, path) in csvs {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        let mut lines = text.lines().filter(|l| !l.trim().is_empty());
        let header: Vec<&str> = lines
            .next()
            .unwrap_or("")
            .split(',')
            .map(str::trim)
            .collect();
        let mut idx = [0usize; 4];
        for (k, c) in COLUMNS.iter().enumerate() {
            idx[k] = header
                .iter()
                .position(|h| h == c)
                .with_context(|| format!("{}: no column {c}", path.display()))?;
        }
        let mut cols: [Vec<f64>; 4] = Default::default();
        for (row, line) in lines.enumerate() {
            let f: Vec<&str> = line.split(',').map(str::trim).collect();
            for k in 0..4 {
                let v = f
                    .get(idx[k])
                    .and_then(|s| s.parse::<f64>().ok())
                    .with_context(|| {
                        format!("{}: row {}: bad {}", path.display(), row + 2, COLUMNS[k])
                    })?;
                cols[k].push(v);
            }
        }
        if cols[0].is_empty() {
            bail!("{}: no frames", path.display());
        }
        for c in &mut cols {
            c.sort_by(f64::total_cmp);
        }
        writeln!(
            out,
            "| {label} | {} | {:.2} | {:.2} | {:.0} | {:.2} | {:.2} |",
            cols[0].len(),
            percentile(&cols[0], 0.5),
            percentile(&cols[0], 0.95),
            percentile(&cols[1], 0.5),
            cols[2].iter().sum::<f64>() / 1e6,
            cols[3].last().copied().unwrap_or(0.0),
        )?;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::section;

    #[test]
    fn without_replay_says_so() {
        assert!(section(&[]).unwrap().starts_with("Not measured"));
    }

    #[test]
    fn summarises_frames() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("r.csv");
        // Columns in another order plus one the summary ignores.
        std::fs::write(
            &p,
            "frame,triangles,refine_ms,max_screen_error_px,bytes_fetched\n\
             0,1000,4.0,0.5,2000000\n1,3000,1.0,0.9,0\n2,2000,2.0,0.7,500000\n",
        )
        .unwrap();
        let s = section(&[("ε=1 m, 1 px".into(), p.clone())]).unwrap();
        assert!(
            s.contains("| ε=1 m, 1 px | 3 | 2.00 | 4.00 | 2000 | 2.50 | 0.90 |"),
            "{s}"
        );
        std::fs::write(&p, "frame,refine_ms\n0,1\n").unwrap();
        assert!(section(&[("x".into(), p)]).is_err());
    }
}
