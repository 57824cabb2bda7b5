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
        "--rms",
        "1",
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
            assert!(err <= eps && rms <= err, "{r:?}");
            // Both default coders, each its own file size.
            for coder in ["adaptive-tokens", "fast-rice"] {
                let bps: f64 = r[&format!("cbdam {coder} file bits/sample")]
                    .parse()
                    .unwrap();
                assert!(bps > 0.0 && bps < 64.0, "{r:?}");
            }
        }
        // Looser tolerance, fewer bits.
        let key = "cbdam adaptive-tokens file bits/sample";
        let first: f64 = rows[0][key].parse().unwrap();
        let last: f64 = rows[7][key].parse().unwrap();
        assert!(last < first, "{rows:?}");
    }
    // Throughput on one core and every core, both coders, every dataset and ε in one table.
    let threads = std::thread::available_parallelism().unwrap().get();
    let speed = tables_with(&md, "dataset");
    let speed: Vec<_> = speed
        .iter()
        .filter(|t| t[0].keys().any(|k| k.contains(" decode 1 / ")))
        .collect();
    assert_eq!(speed.len(), 1, "{md}");
    assert_eq!(speed[0].len(), 16, "{:?}", speed[0]);
    for r in speed[0] {
        for coder in ["adaptive-tokens", "fast-rice"] {
            for what in ["encode", "decode"] {
                let cell = &r[&format!("cbdam {coder} {what} 1 / {threads}")];
                let (one, all) = cell.split_once(" / ").unwrap_or_else(|| panic!("{r:?}"));
                let (one, all): (f64, f64) = (one.parse().unwrap(), all.parse().unwrap());
                assert!(one > 0.0 && all > 0.0, "{r:?}");
            }
        }
    }
    // The mean-square error mode beside the maximum error, both files checked against the DEM.
    let rms = tables_with(&md, "RMS ÷ max");
    assert_eq!(rms.len(), 1, "{md}");
    let row = &rms[0][0];
    assert_eq!(row["dataset"], "jacksboro_mpl.tif");
    let pair = |k: &str| -> (f64, f64) {
        let (a, b) = row[k].split_once(" / ").unwrap();
        (a.parse().unwrap(), b.parse().unwrap())
    };
    let (max_build, rms_build) = (
        pair("max 1 m: max / RMS error (m)"),
        pair("RMS 1 m: max / RMS error (m)"),
    );
    assert!(max_build.0 <= 1.0 && rms_build.1 <= 1.0, "{row:?}");
    let sizes = |name: &str| std::fs::metadata(out.join("rms").join(name)).unwrap().len() as f64;
    let ratio: f64 = row["RMS ÷ max"].parse().unwrap();
    let measured = sizes("jacksboro_mpl.tif.rms.cbdam") / sizes("jacksboro_mpl.tif.max.cbdam");
    assert!(
        (ratio - measured).abs() < 0.001,
        "{ratio} against {measured}"
    );
    assert!(ratio <= 1.0, "{row:?}");
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
    // Two datasets × eight ε × two coders.
    assert_eq!(json["cbdam"].as_array().unwrap().len(), 32);
}
