//! `cbdam synth --earth DIR`: an SRTM-like Earth of 3″ `.hgt` tiles from the bundled ETOPO5,
//! with fractal detail fitted to the bundled SRTM tile ([`cbdam_builder::earth`]).

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use cbdam_builder::earth::{EarthDetail, Etopo, Roughness, hgt_name, region_of};
use cbdam_builder::input::{ReadOptions, read_dem};
use cbdam_codec::atomic::write_atomically;
use clap::Args;
use rayon::prelude::*;

/// The flags of `synth --earth`.
#[derive(Args, Debug)]
pub struct EarthArgs {
    /// Write an SRTM-like Earth into this directory (created; tiles already there are
    /// refused by name): 1°×1° 3″ `.hgt` tiles (1201², int16 big-endian, voids −32768) for every land
    /// cell of ETOPO5 between 56° S and 60° N, ETOPO5 interpolated plus fractal detail fitted
    /// to the SRTM tile of --srtm (docs/PLANET.md)
    #[arg(long, value_name = "DIR")]
    pub earth: Option<PathBuf>,
    /// With --earth: at most N tiles (the first land cells, north to south, west to east)
    #[arg(long, value_name = "N", requires = "earth")]
    pub cells: Option<usize>,
    /// With --earth: only cells whose south-west corner lies in WEST,SOUTH,EAST,NORTH (whole
    /// degrees, east and north exclusive), e.g. `--bbox 5,43,11,48`
    #[arg(
        long,
        value_name = "W,S,E,N",
        requires = "earth",
        allow_hyphen_values = true
    )]
    pub bbox: Option<String>,
    /// With --earth: the global grid under the tiles
    #[arg(long, requires = "earth", default_value = "data/etopo5_global.tif")]
    pub etopo: PathBuf,
    /// With --earth: the real 3″ tile whose roughness the detail is fitted to
    #[arg(long, requires = "earth", default_value = "data/srtm3_demcompare.tif")]
    pub srtm: PathBuf,
    /// With --earth: print how many tiles it would write and their bytes, and write nothing
    #[arg(long, requires = "earth")]
    pub dry_run: bool,
}

/// `W,S,E,N` in whole degrees.
fn parse_bbox(s: &str) -> Result<(i32, i32, i32, i32)> {
    let v: Vec<i32> = s
        .split(',')
        .map(|p| p.trim().parse::<i32>())
        .collect::<Result<_, _>>()
        .with_context(|| format!("--bbox {s}: four whole degrees WEST,SOUTH,EAST,NORTH"))?;
    let [w, so, e, n] = v[..] else {
        bail!("--bbox {s}: four whole degrees WEST,SOUTH,EAST,NORTH");
    };
    if !(w < e && so < n && (-180..=180).contains(&w) && (-180..=180).contains(&e)) {
        bail!("--bbox {s}: west must be below east and south below north, within ±180°");
    }
    Ok((w, so, e, n))
}

/// The detail fitted to the real tile at `srtm` (3″ latitude/longitude).
fn fit(etopo: &Etopo, srtm: &Path) -> Result<(EarthDetail, Roughness, Roughness)> {
    let dem = read_dem(srtm, &ReadOptions::default())
        .with_context(|| format!("reading {}", srtm.display()))?;
    let g = dem
        .georef
        .as_ref()
        .filter(|g| g.epsg == Some(4326) && (g.pixel_x * 1200.0 - 1.0).abs() < 1e-6)
        .with_context(|| format!("{}: not a 3″ EPSG:4326 tile", srtm.display()))?;
    let half = if g.pixel_is_area { 0.5 } else { 0.0 };
    let north_west = (g.origin_y - half * g.pixel_y, g.origin_x + half * g.pixel_x);
    let tile: Vec<Option<f64>> = dem
        .values
        .iter()
        .map(|&v| (!v.is_nan() && dem.nodata != Some(v)).then_some(v))
        .collect();
    let region = region_of(north_west, (dem.width, dem.height));
    let detail = EarthDetail::fit(etopo, &tile, region, 1)?;
    let real = Roughness::of(&tile, dem.width);
    let synthetic = Roughness::of(&detail.region(etopo, region), dem.width);
    Ok((detail, real, synthetic))
}

pub fn run(dir: &Path, args: &EarthArgs) -> Result<()> {
    let bbox = args
        .bbox
        .as_deref()
        .map(parse_bbox)
        .transpose()?
        .unwrap_or((-180, -56, 180, 60));
    let start = Instant::now();
    let etopo = Etopo::read(&args.etopo)?;
    let mut cells = etopo.land_cells(bbox);
    let land = cells.len();
    if let Some(n) = args.cells {
        cells.truncate(n);
    }
    eprintln!("{land} land cells in the box; writing {}", cells.len());
    if cells.is_empty() {
        bail!("no land cell of ETOPO5 in the box asked for");
    }
    if args.dry_run {
        let samples = cells.len() as u64 * 1201 * 1201;
        println!(
            "{} tiles of 1201² 3″ samples ({:.3} G samples, {:.2} GB) would be written to {}",
            cells.len(),
            samples as f64 / 1e9,
            2.0 * samples as f64 / 1e9,
            dir.display()
        );
        return Ok(());
    }
    if let Some(path) = cells
        .iter()
        .map(|&(lat, lon)| dir.join(hgt_name(lat, lon)))
        .find(|p| p.exists())
    {
        bail!(
            "{} exists: --earth writes only tiles that are not there yet",
            path.display()
        );
    }
    let (detail, real, synthetic) = fit(&etopo, &args.srtm)?;
    eprintln!(
        "detail fitted to {}: H = {:.3}, finest octave {:.2} m at ETOPO5 relief {:.1} m; RMS \
         difference at 3″ / 48″: real {:.2} / {:.2} m, synthetic {:.2} / {:.2} m",
        args.srtm.display(),
        detail.h,
        detail.amplitude,
        detail.reference_relief,
        real.lag1,
        real.lag16,
        synthetic.lag1,
        synthetic.lag16
    );
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    write_tiles(dir, &cells, &detail, &etopo, start)?;
    let samples = cells.len() as u64 * 1201 * 1201;
    println!(
        "{}: {} tiles of 1201² 3″ samples ({:.3} G samples, {:.2} GB), {:.1} s",
        dir.display(),
        cells.len(),
        samples as f64 / 1e9,
        2.0 * samples as f64 / 1e9,
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

/// Writes the `.hgt` tile of each of `cells` into `dir`, on every core, saying every hundredth.
fn write_tiles(
    dir: &Path,
    cells: &[(i32, i32)],
    detail: &EarthDetail,
    etopo: &Etopo,
    start: Instant,
) -> Result<()> {
    let written = AtomicUsize::new(0);
    cells.par_iter().try_for_each(|&(lat, lon)| -> Result<()> {
        let path = dir.join(hgt_name(lat, lon));
        let bytes = detail.hgt_tile(etopo, lat, lon);
        write_atomically::<anyhow::Error>(&path, |f| {
            std::io::Write::write_all(f, &bytes)?;
            Ok(())
        })?;
        let done = written.fetch_add(1, Ordering::Relaxed) + 1;
        if done.is_multiple_of(100) {
            eprintln!(
                "{done} of {} tiles, {:.0} s",
                cells.len(),
                start.elapsed().as_secs_f64()
            );
        }
        Ok(())
    })
}
