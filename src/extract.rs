//! `cbdam extract`: decode a repository (or a window / coarser level of it) back to a DEM file,
//! written by [`cbdam_builder::write`].

use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use cbdam_builder::write::{Raster, write_geotiff, write_raw};
use cbdam_codec::atomic::write_atomically;
use cbdam_codec::hierarchy::walk_all_with_validity;
use cbdam_codec::repository::GeoRef;
use cbdam_codec::repository::Repository;
use clap::{Args, ValueEnum};
use serde_json::json;

use crate::flags;

/// Output format of `cbdam extract`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum ExtractFormat {
    /// Single-band GeoTIFF with pixel scale, tie point, GeoKeys (raster type, EPSG) and
    /// GDAL_NODATA.
    Geotiff,
    /// Headerless little-endian floats, row 0 = north, plus a JSON sidecar (the output path with
    /// its extension replaced by `.json`): size, georeferencing, unit, nodata, ε.
    Raw,
}

/// Decode a repository back to a DEM (GeoTIFF or raw float), whole or a window, at the
/// finest or a coarser level.
///
/// Heights are metres (`offset + n·unit`). By default they are written as float32, which
/// rounds each decoded height to the nearest float32: that adds at most half a float32 ulp of
/// the value (about 0.5 mm at 9 000 m, 0.015 mm at 500 m) to the repository's error bound. With
/// --float64 the decoded heights are written exactly and the bound holds as stated.
///
/// Samples without data are written as the recorded nodata value (NaN when the repository
/// recorded none): the input's nodata samples, which the repository's nodata mask keeps exactly,
/// and samples in regions with no valid input sample nearby (no stored diamond). In a
/// variable-resolution repository so are the samples of a level finer than the data there.
#[derive(Args, Debug)]
pub struct ExtractArgs {
    /// Repository file.
    repo: PathBuf,
    /// Output file (written atomically: a temporary file renamed into place).
    #[arg(short, long)]
    output: PathBuf,
    /// Window MINX,MINY,MAXX,MAXY: the samples whose centres lie inside it, clipped to the data.
    /// In the repository's CRS units when it is georeferenced; otherwise column and row indices
    /// (x = column, y = row, row 0 = north). Default: the whole data rectangle.
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true, num_args = 1)]
    bbox: Option<Vec<f64>>,
    /// Decode level L instead of the finest. Only even levels are axis-aligned grids, so L must
    /// be even; level L samples every 2^((finest − L)/2) input samples (the lattice points that
    /// are multiples of that spacing). With --alpha 0.5 repositories coarse levels are
    /// low-pass filtered, not subsampled. `cbdam inspect` lists the levels.
    #[arg(long)]
    level: Option<u8>,
    /// Output format.
    #[arg(long, value_enum, default_value_t = ExtractFormat::Geotiff)]
    format: ExtractFormat,
    /// Write float64 samples: the decoded heights exactly, without float32 rounding.
    #[arg(long)]
    float64: bool,
    #[command(flatten)]
    quiet: flags::Quiet,
}

pub fn run(args: &ExtractArgs) -> Result<()> {
    // Argument checks before the decode, which is the expensive part.
    if args.output.is_dir() {
        bail!("output path {} is a directory", args.output.display());
    }
    let sidecar = sidecar_path(&args.output);
    if args.format == ExtractFormat::Raw && sidecar == args.output {
        bail!(
            "output path {} would be overwritten by its own JSON sidecar; use another extension",
            args.output.display()
        );
    }
    let repo =
        Repository::open(&args.repo).with_context(|| format!("opening {}", args.repo.display()))?;
    if repo.head().params().domain.cube().is_some() {
        bail!(
            "{} is a planet (cube-sphere): extract writes planar rasters, and a planet's six faces \
             are not resampled back to latitude/longitude yet",
            args.repo.display()
        );
    }
    let samples = Samples::of(args, &repo)?;
    let raster = Raster {
        width: samples.width,
        height: samples.height,
        values: samples.decode(&repo, &args.repo)?,
        georef: repo.head().georef().map(|g| samples.georef(g)),
    };
    let plan = *repo.head().plan();
    match args.format {
        ExtractFormat::Geotiff => write_geotiff_and_prj(args, &raster, repo.head().nodata())?,
        ExtractFormat::Raw => {
            write_atomically(&args.output, |f: &mut File| {
                write_raw(f, &raster, args.float64)
            })
            .with_context(|| format!("writing {}", args.output.display()))?;
            let meta = json!({
                "width": raster.width,
                "height": raster.height,
                "dtype": if args.float64 { "float64" } else { "float32" },
                "byte_order": "little",
                "row_order": "north-up (row 0 = north edge)",
                "unit": "m",
                "nodata": repo.head().nodata(),
                "max_error_m": plan.epsilon,
                "guaranteed_max_error_m": plan.max_error(),
                "float_rounding_m": plan.rounding_error(),
                "level": samples.level,
                "georef": raster.georef.as_ref().map(|g| json!({
                    "epsg": g.epsg, "origin_x": g.origin_x, "origin_y": g.origin_y,
                    "pixel_x": g.pixel_x, "pixel_y": g.pixel_y,
                    "pixel_is": if g.pixel_is_area { "area" } else { "point" },
                    "wkt": g.wkt,
                })),
            });
            write_sidecar(&args.output, &sidecar, &meta)?;
        }
    }
    if !args.quiet.value {
        println!(
            "{}: {}×{} samples of level {} (spacing {}), max error {}",
            args.output.display(),
            samples.width,
            samples.height,
            samples.level,
            samples.step,
            plan.bound_text()
        );
    }
    Ok(())
}

/// The samples to write: the lattice points of one even level inside the window, from
/// `(x0, y0)` to at most `(x1, y1)`, `step` input samples apart.
struct Samples {
    level: u8,
    step: i64,
    x0: i64,
    y0: i64,
    x1: i64,
    y1: i64,
    width: usize,
    height: usize,
}

impl Samples {
    /// The samples `--level` and `--bbox` ask for, checked.
    fn of(args: &ExtractArgs, repo: &Repository) -> Result<Samples> {
        let p = repo.head().params();
        let finest = p.layout().finest_level();
        let level = args.level.unwrap_or(finest);
        if !level.is_multiple_of(2) || level > finest {
            bail!(
                "--level {level}: only even levels 0, 2, …, {finest} are axis-aligned grids in \
                 this repository (the finest is {finest})"
            );
        }
        // Lattice spacing of the level's samples: level 2m samples every 2^(K−m) input samples.
        let step = 1i64 << ((finest - level) / 2);
        let (w, h) = (
            i64::from(p.domain.data().width),
            i64::from(p.domain.data().height),
        );
        let window = match &args.bbox {
            None => (0, 0, w - 1, h - 1),
            Some(b) => bbox_window(b, repo.head().georef(), w, h)?,
        };
        // The level's lattice points inside the window: multiples of `step`.
        let first = |lo: i64| (lo + step - 1).div_euclid(step) * step;
        let (x0, y0) = (first(window.0), first(window.1));
        if x0 > window.2 || y0 > window.3 {
            bail!(
                "the bounding box holds no sample of level {level} (spacing {step} input samples)"
            );
        }
        Ok(Samples {
            level,
            step,
            x0,
            y0,
            x1: window.2,
            y1: window.3,
            width: ((window.2 - x0) / step + 1) as usize,
            height: ((window.3 - y0) / step + 1) as usize,
        })
    }

    /// Decodes `repo` (read from `path`) and returns the samples' heights in metres, row by row.
    ///
    /// Points no decoded diamond covers lie in parts of the data rectangle with no valid sample
    /// nearby (the encoder stores only diamonds that meet one), and the repository's nodata mask
    /// marks the others that had no data: both are written as nodata, or NaN without a value.
    /// In a variable-resolution repository, levels finer than the data at a place are not
    /// reached there either (every level's leaves are visited, so a coarse input's level is
    /// extracted whole).
    fn decode(&self, repo: &Repository, path: &Path) -> Result<Vec<f64>> {
        let encoded = repo
            .to_encoded()
            .with_context(|| format!("reading {}", path.display()))?;
        let (p, plan) = (repo.head().params(), repo.head().plan());
        let fill = repo.head().nodata().unwrap_or(f64::NAN);
        let mut values = vec![fill; self.width * self.height];
        let n = p.layout().n();
        walk_all_with_validity(&encoded, |id, grid, valid| {
            if id.level != self.level {
                return;
            }
            let g = p.layout().grid(id);
            for j in 0..n {
                for i in 0..n {
                    let (x, y) = g.point(i as i64, j as i64);
                    if x < self.x0 || y < self.y0 || x > self.x1 || y > self.y1 {
                        continue;
                    }
                    // Even-level grids sit on multiples of their own spacing, which is `step`.
                    debug_assert!((x - self.x0) % self.step == 0 && (y - self.y0) % self.step == 0);
                    let c = ((x - self.x0) / self.step) as usize;
                    let r = ((y - self.y0) / self.step) as usize;
                    if valid.is_none_or(|v| v[j * n + i]) {
                        values[r * self.width + c] = plan.metres(grid[j * n + i]);
                    }
                }
            }
        })
        .with_context(|| format!("decoding {}", path.display()))?;
        Ok(values)
    }

    /// The georeferencing of the output raster, from the repository's `g`.
    fn georef(&self, g: &GeoRef) -> GeoRef {
        // Raster point (0, 0) of the output is lattice point (x0, y0); a PixelIsArea origin is the
        // outer corner of a cell `step` samples wide centred on that point.
        let half = if g.pixel_is_area { 0.5 } else { 0.0 };
        let (sx, sy) = (self.step as f64, self.step as f64);
        GeoRef {
            origin_x: g.origin_x + (self.x0 as f64 + half - half * sx) * g.pixel_x,
            origin_y: g.origin_y - (self.y0 as f64 + half - half * sy) * g.pixel_y,
            pixel_x: g.pixel_x * sx,
            pixel_y: g.pixel_y * sy,
            ..g.clone()
        }
    }
}

/// Writes `raster` as a GeoTIFF to --output and, for a CRS known only as WKT, an ESRI `.prj`
/// beside it (GeoKeys hold EPSG codes, not definitions; GIS software looks for the `.prj`).
fn write_geotiff_and_prj(args: &ExtractArgs, raster: &Raster, nodata: Option<f64>) -> Result<()> {
    write_atomically(&args.output, |f: &mut File| {
        write_geotiff(f, raster, nodata, args.float64)
    })
    .with_context(|| format!("writing {}", args.output.display()))?;
    if let Some(wkt) = raster.georef.as_ref().and_then(|g| g.wkt.as_deref()) {
        let prj = args.output.with_extension("prj");
        let written = write_atomically(&prj, |f: &mut File| -> Result<()> {
            f.write_all(wkt.as_bytes())?;
            f.write_all(b"\n")?;
            Ok(())
        });
        if let Err(e) = written {
            let _ = std::fs::remove_file(&args.output);
            return Err(e.context(format!("writing {}", prj.display())));
        }
    }
    Ok(())
}

/// Writes the JSON sidecar `meta` of the raw samples at `output`, taking the samples back when
/// that fails (raw samples without their sidecar are unreadable).
fn write_sidecar(output: &Path, sidecar: &Path, meta: &serde_json::Value) -> Result<()> {
    let written = write_atomically(sidecar, |f: &mut File| -> Result<()> {
        serde_json::to_writer_pretty(&mut *f, meta)?;
        f.write_all(b"\n")?;
        Ok(())
    });
    if let Err(e) = written {
        let _ = std::fs::remove_file(output);
        return Err(e.context(format!("writing {}", sidecar.display())));
    }
    Ok(())
}

/// `OUT.json` next to a raw `OUT.f32` (the extension replaced).
fn sidecar_path(output: &Path) -> PathBuf {
    output.with_extension("json")
}

/// The inclusive lattice window `(x0, y0, x1, y1)` of the data samples inside `b`, clipped to
/// the data. With georeferencing `b` is in CRS units and a sample is inside when its centre is;
/// without, it is in column / row indices (row 0 = north).
fn bbox_window(b: &[f64], georef: Option<&GeoRef>, w: i64, h: i64) -> Result<(i64, i64, i64, i64)> {
    let [minx, miny, maxx, maxy] = b else {
        bail!(
            "--bbox takes four numbers MINX,MINY,MAXX,MAXY, not {}",
            b.len()
        );
    };
    if !b.iter().all(|v| v.is_finite()) {
        bail!("--bbox holds a non-finite number");
    }
    if minx > maxx || miny > maxy {
        bail!("--bbox is inverted: MINX must not exceed MAXX, nor MINY MAXY");
    }
    // Sample (c, r) has its centre at (ox + (c + half)·px, oy − (r + half)·py); solve for c and r.
    let (ox, oy, px, py, half) = match georef {
        Some(g) => (
            g.origin_x,
            g.origin_y,
            g.pixel_x,
            g.pixel_y,
            if g.pixel_is_area { 0.5 } else { 0.0 },
        ),
        // Pixel coordinates: x = column, y = row.
        None => (0.0, 0.0, 1.0, -1.0, 0.0),
    };
    let range = |a: f64, b: f64| {
        let (lo, hi) = (a.min(b), a.max(b));
        (lo.ceil(), hi.floor())
    };
    let (c0, c1) = range((minx - ox) / px - half, (maxx - ox) / px - half);
    let (r0, r1) = range((oy - maxy) / py - half, (oy - miny) / py - half);
    let (c0, r0) = (c0.max(0.0), r0.max(0.0));
    let (c1, r1) = (c1.min((w - 1) as f64), r1.min((h - 1) as f64));
    if c0 > c1 || r0 > r1 {
        bail!(
            "--bbox {minx},{miny},{maxx},{maxy} holds no sample of the data ({})",
            match georef {
                Some(g) => {
                    let xs = [
                        g.origin_x + half * g.pixel_x,
                        g.origin_x + ((w - 1) as f64 + half) * g.pixel_x,
                    ];
                    let ys = [
                        g.origin_y - half * g.pixel_y,
                        g.origin_y - ((h - 1) as f64 + half) * g.pixel_y,
                    ];
                    format!(
                        "sample centres span x {} … {}, y {} … {}",
                        xs[0].min(xs[1]),
                        xs[0].max(xs[1]),
                        ys[0].min(ys[1]),
                        ys[0].max(ys[1])
                    )
                }
                None => format!(
                    "no georeferencing: columns 0 … {}, rows 0 … {}",
                    w - 1,
                    h - 1
                ),
            }
        );
    }
    Ok((c0 as i64, r0 as i64, c1 as i64, r1 as i64))
}
