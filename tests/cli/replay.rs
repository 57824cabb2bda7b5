//! `cbdam replay` over real repositories and the shipped flights.

use std::path::Path;

use crate::util::*;

/// The per-step columns of a frame's wall time, in the CSV's order.
const STEPS: [&str; 6] = [
    "before_ms",
    "loop_ms",
    "collect_ms",
    "want_ms",
    "ahead_ms",
    "after_ms",
];

/// `cbdam replay` over a real repository and both shipped flights: the documented header, one
/// row per frame, and a last row (camera held still) that meets the target and has converged.
#[test]
fn replay_writes_documented_csv_and_converges() {
    let dir = tempfile::tempdir().unwrap();
    let repo = jacksboro_at("1");
    for flight in ["descent.json", "low_pass.json"] {
        let csv = dir.path().join("stats.csv");
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("data/flights")
            .join(flight);
        let o = cbdam(&[
            "replay",
            &s(&repo),
            "--path",
            &s(&path),
            "--size",
            "640x360",
            "--pixel-error",
            "1",
            "--budget-ms",
            "2",
            "--fps",
            "10",
            "--out",
            &s(&csv),
        ]);
        assert!(o.status.success(), "{flight}: {}", stderr(&o));
        assert!(stdout(&o).contains("converged"), "{}", stdout(&o));
        let text = std::fs::read_to_string(&csv).unwrap();
        let mut lines = text.lines();
        let header: Vec<&str> = lines.next().unwrap().split(',').collect();
        for col in [
            "frame",
            "t",
            "refine_ms",
            "decode_ms",
            "max_screen_error_px",
            "met_target",
            "diamonds_in_cut",
            "triangles",
            "refinements",
            "coarsenings",
            "bytes_fetched",
            "requests_in_flight",
            "cut_bytes",
            "memory_limited",
        ]
        .into_iter()
        .chain(STEPS)
        {
            assert!(header.contains(&col), "{flight}: no column {col}");
        }
        let rows: Vec<Vec<f64>> = lines
            .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
            .collect();
        let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
        assert!(rows.iter().all(|r| r.len() == header.len()));
        assert!(rows.len() >= 121, "{flight}: {} rows", rows.len());
        for (i, r) in rows.iter().enumerate() {
            assert_eq!(r[col("frame")], (i + 1) as f64);
        }
        let last = rows.last().unwrap();
        assert_eq!(last[col("settling")], 1.0);
        assert_eq!(last[col("met_target")], 1.0);
        assert_eq!(last[col("converged")], 1.0);
        assert!(last[col("max_screen_error_px")] <= 1.0);
        assert!(last[col("triangles")] > 0.0 && last[col("diamonds_in_cut")] > 0.0);
        assert!(rows.iter().map(|r| r[col("refinements")]).sum::<f64>() > 0.0);
        assert!(last[col("bytes_fetched")] > 0.0);
        // The default cut memory (1 GiB) is far above what this small tile needs.
        assert!(last[col("cut_bytes")] > 0.0);
        assert!(rows.iter().all(|r| r[col("memory_limited")] == 0.0));
        // The steps of a frame add up to its wall time (each is rounded to 0.1 µs).
        for r in &rows {
            let sum: f64 = STEPS.iter().map(|s| r[col(s)]).sum();
            assert!(STEPS.iter().all(|s| r[col(s)] >= 0.0));
            assert!(
                (sum - r[col("refine_ms")]).abs() < 1e-3,
                "{flight}: {sum} ≠ {r:?}"
            );
        }
        assert!(rows.iter().map(|r| r[col("loop_ms")]).sum::<f64>() > 0.0);
        // The workers' CPU time is part of their wall time, and measured on Linux.
        for r in &rows {
            assert!(
                r[col("decode_cpu_ms")] <= r[col("decode_ms")] + 1e-3,
                "{flight}: {r:?}"
            );
        }
        if cfg!(target_os = "linux") {
            assert!(rows.iter().map(|r| r[col("decode_cpu_ms")]).sum::<f64>() > 0.0);
        }
    }
}

#[test]
fn replay_reports_unreachable_servers_and_bad_flights() {
    let dir = tempfile::tempdir().unwrap();
    let flight = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/flights/descent.json");
    let out = dir.path().join("x.csv");
    let o = cbdam(&[
        "replay",
        // Nothing listens on the discard port: the error names the URL, quickly.
        "http://127.0.0.1:9/v1/repos/srtm",
        "--path",
        &s(&flight),
        "--out",
        &s(&out),
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains("connecting to http://127.0.0.1:9/v1/repos/srtm"),
        "{}",
        stderr(&o)
    );
    let bad = dir.path().join("bad.json");
    std::fs::write(&bad, r#"{ "keyframes": [] }"#).unwrap();
    let repo = dir.path().join("jb.cbdam");
    build_quiet(&data("jacksboro_mpl.tif"), &repo, "4");
    let o = cbdam(&["replay", &s(&repo), "--path", &s(&bad), "--out", &s(&out)]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains("at least two keyframes"),
        "{}",
        stderr(&o)
    );
    let o = cbdam(&[
        "replay",
        &s(&repo),
        "--path",
        &s(&flight),
        "--out",
        &s(&out),
        "--size",
        "0x5",
    ]);
    assert_eq!(o.status.code(), Some(2));
}
