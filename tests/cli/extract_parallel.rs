//! `cbdam extract` decodes each level's diamonds in parallel and writes each batch of decoded
//! grids into the raster in parallel, by bands of raster rows: on any number of threads its
//! output must be the serial reconstruction's samples, bit for bit, with its nodata.

use std::path::Path;
use std::process::Command;

use cbdam_builder::input::{ReadOptions, read_dem};
use cbdam_codec::hierarchy::reconstruct_finest_with_validity;
use cbdam_codec::repository::Repository;

use crate::util::*;

/// `cbdam extract REPO -o OUT --quiet ARGS…` on `threads` rayon threads; the output's bytes.
fn extract_on(threads: usize, repo: &Path, out: &Path, args: &[&str]) -> Vec<u8> {
    let o = Command::new(env!("CARGO_BIN_EXE_cbdam"))
        .args(["extract", &s(repo), "-o", &s(out), "--quiet"])
        .args(args)
        .env("RAYON_NUM_THREADS", threads.to_string())
        .output()
        .expect("run cbdam");
    assert!(o.status.success(), "extract {args:?}: {}", stderr(&o));
    std::fs::read(out).unwrap()
}

/// The finest level as the serial walk reconstructs it, as extract's raw float32 bytes.
fn serial_reconstruction(repo: &Path) -> Vec<u8> {
    let repo = Repository::open(repo).unwrap();
    let (units, valid) = reconstruct_finest_with_validity(&repo.to_encoded().unwrap()).unwrap();
    let (plan, fill) = (repo.head().plan(), repo.head().nodata().unwrap_or(f64::NAN));
    let metres = |(&u, &v): (&i32, &bool)| if v { plan.metres(u) } else { fill };
    units
        .iter()
        .zip(&valid)
        .flat_map(|s| (metres(s) as f32).to_le_bytes())
        .collect()
}

/// A `--bbox` of columns 30 … 229 and rows 20 … 169 of `input`, in its CRS units.
fn window_of(input: &str) -> String {
    let dem = read_dem(Path::new(input), &ReadOptions::default()).unwrap();
    let g = dem.georef.expect("a georeferenced DEM");
    let (x0, y1) = (g.origin_x + 30.0 * g.pixel_x, g.origin_y - 20.0 * g.pixel_y);
    let (x1, y0) = (
        g.origin_x + 230.0 * g.pixel_x,
        g.origin_y - 170.0 * g.pixel_y,
    );
    format!("{x0},{y0},{x1},{y1}")
}

#[test]
fn extract_on_any_thread_count_is_the_serial_reconstruction() {
    let dir = tempfile::tempdir().unwrap();
    for (name, eps, alpha) in [
        // A nodata mask: masked samples keep the fill value.
        ("rhine_nodata.tif", "0.5", "1"),
        // α = ½: the grids visited are the gathered ones, not the refinements' vertices.
        ("srtm3_demcompare.tif", "2", "0.5"),
        ("jacksboro_mpl.tif", "1", "1"),
    ] {
        let repo = dir.path().join(format!("{name}.cbdam"));
        let input = data(name);
        let build = [
            "build",
            &input,
            "-o",
            &s(&repo),
            "--max-error",
            eps,
            "--alpha",
            alpha,
            "--quiet",
        ];
        run_ok(&build);
        let want = serial_reconstruction(&repo);
        let raw = dir.path().join("x.f32");
        for threads in [1, 2, 3, 8] {
            let got = extract_on(threads, &repo, &raw, &["--format", "raw"]);
            assert!(
                got == want,
                "{name} on {threads} threads: not the serial samples"
            );
        }
        // A coarser level and a window: the same bytes on every thread count.
        let bbox = window_of(&input);
        for args in [&["--level", "4"][..], &["--bbox", &bbox]] {
            let tif = dir.path().join("x.tif");
            let one = extract_on(1, &repo, &tif, args);
            for threads in [2, 5] {
                let got = extract_on(threads, &repo, &tif, args);
                assert!(got == one, "{name} {args:?} on {threads} threads");
            }
        }
    }
}
