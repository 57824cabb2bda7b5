//! `cbdam build` and `cbdam verify` over tiles: a directory of tiles sharing edge rows builds the
//! same bytes as the DEM they were cut from and verifies against the directory; `--help` says
//! what an input may be; an empty directory is refused by name, leaving no output.

use std::path::Path;

use cbdam_build::write::{Raster, write_geotiff};
use cbdam_codec::input::{GeoRef, ReadOptions, read_dem};

use crate::util::{cbdam, data, s, stdout};

/// Tile side between shared edges; 2 × 2 tiles of `T + 1` samples.
const T: usize = 96;
const SIDE: usize = 2 * T + 1;

fn write(path: &Path, w: usize, values: Vec<f64>, georef: GeoRef) {
    let r = Raster {
        width: w,
        height: w,
        values,
        georef: Some(georef),
    };
    write_geotiff(std::fs::File::create(path).unwrap(), &r, None, false).unwrap();
}

/// Cuts the north-west `(n·t + 1)²` samples of the DEM `dem` into `n × n` GeoTIFF tiles of
/// `t + 1` samples sharing their edge rows and columns (as SRTM's do), written to `dir`.
pub fn cut_into_tiles(dem: &str, dir: &Path, t: usize, n: usize) {
    let dem = read_dem(Path::new(dem), &ReadOptions::default()).unwrap();
    let g = dem.georef.clone().unwrap();
    let at = |r: usize, c: usize| dem.values[r * dem.width + c];
    std::fs::create_dir(dir).unwrap();
    for tr in 0..n {
        for tc in 0..n {
            let v: Vec<f64> = (0..(t + 1) * (t + 1))
                .map(|i| at(tr * t + i / (t + 1), tc * t + i % (t + 1)))
                .collect();
            let tg = GeoRef {
                origin_x: g.origin_x + (tc * t) as f64 * g.pixel_x,
                origin_y: g.origin_y - (tr * t) as f64 * g.pixel_y,
                ..g.clone()
            };
            write(&dir.join(format!("N{tr}E{tc}.tif")), t + 1, v, tg);
        }
    }
}

#[test]
fn a_directory_of_tiles_builds_and_verifies_like_one_file() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let dem = read_dem(
        Path::new(&data("srtm3_demcompare.tif")),
        &ReadOptions::default(),
    )
    .unwrap();
    let g = dem.georef.clone().unwrap();
    let at = |r: usize, c: usize| dem.values[r * dem.width + c];
    let whole: Vec<f64> = (0..SIDE * SIDE).map(|i| at(i / SIDE, i % SIDE)).collect();
    write(&d.join("whole.tif"), SIDE, whole, g.clone());
    let tiles = d.join("tiles");
    cut_into_tiles(&data("srtm3_demcompare.tif"), &tiles, T, 2);
    let build = |input: &Path, out: &Path| {
        let o = cbdam(&[
            "build",
            &s(input),
            "-o",
            &s(out),
            "--max-error",
            "1.5",
            "--quiet",
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        std::fs::read(out).unwrap()
    };
    let want = build(&d.join("whole.tif"), &d.join("whole.cbdam"));
    let got = build(&tiles, &d.join("tiles.cbdam"));
    assert!(got == want, "the directory of tiles built different bytes");
    let o = cbdam(&[
        "verify",
        &s(&d.join("tiles.cbdam")),
        "--against",
        &s(&tiles),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(stdout(&o).contains("OK"), "{}", stdout(&o));
    // Each tile is named with its winning samples: the four tiles were all used.
    assert_eq!(
        stdout(&o).matches("winning samples").count(),
        4,
        "{}",
        stdout(&o)
    );

    let help = stdout(&cbdam(&["build", "--help"]));
    for what in ["directory", "glob", "@LIST", "VRT", "disagree"] {
        assert!(help.contains(what), "--help does not mention {what}");
    }

    let empty = d.join("empty");
    std::fs::create_dir(&empty).unwrap();
    let out = d.join("empty.cbdam");
    let o = cbdam(&["build", &s(&empty), "-o", &s(&out), "--max-error", "1"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains(&s(&empty)), "{err}");
    assert!(!out.exists());
}
