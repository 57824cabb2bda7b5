//! The `cbdam` binary end to end, one module per subcommand; the helpers they share, and what
//! concerns every subcommand (how errors are printed).

mod bench;
mod bench_entropy;
mod bench_network;
mod build;
mod build_refusals;
mod colour;
mod extract;
mod extract_parallel;
mod inspect;
mod link;
mod multires;
mod plane_disk_full;
mod planet;
mod planet_bad_input;
mod planet_closeup;
mod planet_out_of_core;
mod planet_shard;
mod planet_verify;
mod readme;
mod render;
mod render_colour;
mod replay;
mod serve;
mod shard;
mod tiles;
mod upgrade;
mod verify;
mod view;
mod web_export;
mod web_tiles;

use std::path::Path;

use crate::util::*;

/// An ESRI ASCII grid of `rows` (north first).
fn write_asc(path: &Path, rows: &[Vec<f64>], nodata: Option<f64>) {
    let mut t = format!(
        "ncols {}\nnrows {}\nxllcorner 0\nyllcorner 0\ncellsize 1\n",
        rows[0].len(),
        rows.len()
    );
    if let Some(nd) = nodata {
        t += &format!("NODATA_value {nd}\n");
    }
    for r in rows {
        t += &r
            .iter()
            .map(|v| v.to_string())
            .collect::<Vec<_>>()
            .join(" ");
        t += "\n";
    }
    std::fs::write(path, t).unwrap();
}

/// An I/O error is printed once: the codec's, server's and flight's error messages include the
/// OS error, so it is no longer also their `source` (the chain printed it twice).
#[test]
fn io_errors_name_their_cause_once() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.tif");
    let out = dir.path().join("x.cbdam");
    let o = cbdam(&["build", &s(&missing), "-o", &s(&out), "--max-error", "1"]);
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(e.contains("missing.tif"), "{e}");
    assert_eq!(e.matches("No such file or directory").count(), 1, "{e}");
    let repo = dir.path().join("lidar.cbdam");
    build_quiet(&data("lidar1m_mn.tif"), &repo, "5");
    let flight = dir.path().join("no.json");
    let csv = dir.path().join("o.csv");
    let o = cbdam(&[
        "replay",
        &s(&repo),
        "--path",
        &s(&flight),
        "--out",
        &s(&csv),
    ]);
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(e.contains("reading the flight"), "{e}");
    assert_eq!(e.matches("No such file or directory").count(), 1, "{e}");
}
