//! `cbdam bench report --quick`.

use crate::util::*;

/// The rows of every Markdown table in `md` whose header has a column named `key`, as maps
/// from column name to cell.
fn tables_with(md: &str, key: &str) -> Vec<Vec<std::collections::HashMap<String, String>>> {
    let cells = |l: &str| -> Vec<String> {
        l.trim()
            .trim_matches('|')
            .split('|')
            .map(|c| c.trim().to_string())
            .collect()
    };
    let lines: Vec<&str> = md.lines().collect();
    let mut out = Vec::new();
    let mut i = 0;
    while i < lines.len() {
        let head = cells(lines[i]);
        if lines[i].starts_with('|') && head.iter().any(|c| c == key) {
            let mut rows = Vec::new();
            i += 2; // header and |---| line
            while i < lines.len() && lines[i].starts_with('|') {
                rows.push(head.iter().cloned().zip(cells(lines[i])).collect());
                i += 1;
            }
            out.push(rows);
        } else {
            i += 1;
        }
    }
    out
}

#[test]
fn bench_report_quick() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("report");
    let o = cbdam(&[
        "bench",
        "report",
        "--quick",
        "--synthetic",
        "65",
        "--out",
        &s(&out),
        &data("jacksboro_mpl.tif"),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(md.contains("| CPU |") && md.contains("| commit |"), "{md}");
    // Rendering cost: the two bundled flights over the DEM at 1 and 4 px (the --quick
    // targets), measured by the real refinement loop.
    let cost = tables_with(&md, "triangles / frame (median)");
    assert_eq!(cost.len(), 1, "{md}");
    let cost = &cost[0];
    assert_eq!(cost.len(), 4, "{cost:?}");
    for flight in ["descent", "low_pass"] {
        let rows: Vec<_> = cost.iter().filter(|r| r["flight"] == flight).collect();
        assert_eq!(rows.len(), 2, "{cost:?}");
        let tris = |r: &std::collections::HashMap<String, String>| -> u64 {
            r["triangles, converged"].parse().unwrap()
        };
        // A looser target never needs more triangles once the cut has converged.
        assert!(tris(rows[1]) <= tris(rows[0]), "{rows:?}");
        for r in &rows {
            let target: f64 = r["target (px)"].parse().unwrap();
            let frames: usize = r["frames"].parse().unwrap();
            assert!(frames > 10, "{r:?}");
            let converged: f64 = r["error (px), converged"]
                .parse()
                .unwrap_or_else(|_| panic!("did not converge: {r:?}"));
            assert!(converged <= target, "{r:?}");
            let csv = out.join("replay").join(format!("{flight}_{target}px.csv"));
            let lines = std::fs::read_to_string(&csv).unwrap().lines().count();
            assert!(lines > frames, "{}: {lines} lines", csv.display());
        }
    }
    assert!(md.contains("(plots/render_cost.svg)"));
    let svg = std::fs::read_to_string(out.join("plots/render_cost.svg")).unwrap();
    assert!(svg.contains("<svg") && svg.contains("low_pass"));
    // One rate table per dataset (the DEM and the synthetic terrain), every default ε, every
    // verified max error within its ε.
    let tables = tables_with(&md, "cbdam max err (m)");
    assert_eq!(tables.len(), 2, "{md}");
    for rows in &tables {
        assert_eq!(rows.len(), 8, "{rows:?}");
        for r in rows {
            let eps: f64 = r["ε (m)"].parse().unwrap();
            let err: f64 = r["cbdam max err (m)"].parse().unwrap();
            let rms: f64 = r["cbdam RMS (m)"].parse().unwrap();
            let bps: f64 = r["cbdam file bits/sample"].parse().unwrap();
            assert!(err <= eps && rms <= err, "{r:?}");
            assert!(bps > 0.0 && bps < 64.0, "{r:?}");
        }
        // Looser tolerance, fewer bits.
        let first: f64 = rows[0]["cbdam file bits/sample"].parse().unwrap();
        let last: f64 = rows[7]["cbdam file bits/sample"].parse().unwrap();
        assert!(last < first, "{rows:?}");
    }
    assert_eq!(tables_with(&md, "cbdam decode").len(), 2);
    for plot in ["jacksboro_mpl.tif.svg", "synthetic_fractal_65.svg"] {
        let svg = std::fs::read_to_string(out.join("plots").join(plot)).unwrap();
        assert!(
            svg.contains("<svg") && svg.contains("cbdam (file)"),
            "{plot}"
        );
        assert!(md.contains(&format!("(plots/{plot})")), "{plot} not linked");
    }
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("results.json")).unwrap()).unwrap();
    assert_eq!(json["cbdam"].as_array().unwrap().len(), 16);
}
