//! `cbdam extract`: decode a repository (or a window / coarser level of it) back to a DEM file,
//! written by [`cbdam_builder::write`].

use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use cbdam_builder::write::{Raster, write_geotiff, write_geotiff_f32, write_raw, write_raw_f32};
use cbdam_codec::atomic::write_atomically;
use cbdam_codec::repository::Repository;
use cbdam_codec::repository::{GeoRef, LevelGrid, bbox_window};
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
    let georef = repo.head().georef().map(|g| samples.georef(g));
    let (plan, nodata) = (*repo.head().plan(), repo.head().nodata());
    let heights = decode_heights(args, &repo, &samples, georef)?;
    match args.format {
        ExtractFormat::Geotiff => write_geotiff_and_prj(args, &heights, nodata)?,
        ExtractFormat::Raw => {
            write_raw_and_sidecar(args, &heights, &repo, samples.level, &sidecar)?
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

/// The window's samples decoded straight into the sample type written (no float64 raster to
/// convert for float32); samples without data hold the recorded nodata value, or NaN.
fn decode_heights(
    args: &ExtractArgs,
    repo: &Repository,
    samples: &Samples,
    georef: Option<GeoRef>,
) -> Result<Heights> {
    let (plan, fill) = (
        *repo.head().plan(),
        repo.head().nodata().unwrap_or(f64::NAN),
    );
    Ok(if args.float64 {
        Heights::F64(Raster {
            width: samples.width,
            height: samples.height,
            values: samples.decode(repo, &args.repo, fill, |h| plan.metres(h))?,
            georef,
        })
    } else {
        Heights::F32(Raster {
            width: samples.width,
            height: samples.height,
            values: samples.decode(repo, &args.repo, fill as f32, |h| plan.metres(h) as f32)?,
            georef,
        })
    })
}

/// `--format raw`: the samples, then the JSON sidecar describing them.
fn write_raw_and_sidecar(
    args: &ExtractArgs,
    heights: &Heights,
    repo: &Repository,
    level: u8,
    sidecar: &Path,
) -> Result<()> {
    let (plan, nodata) = (*repo.head().plan(), repo.head().nodata());
    let (width, height, georef) = heights.shape();
    write_atomically(&args.output, |f: &mut File| heights.write_raw(f))
        .with_context(|| format!("writing {}", args.output.display()))?;
    let meta = json!({
        "width": width,
        "height": height,
        "dtype": if args.float64 { "float64" } else { "float32" },
        "byte_order": "little",
        "row_order": "north-up (row 0 = north edge)",
        "unit": "m",
        "nodata": nodata,
        "max_error_m": plan.epsilon,
        "guaranteed_max_error_m": plan.max_error(),
        "float_rounding_m": plan.rounding_error(),
        "level": level,
        "georef": georef.map(|g| json!({
            "epsg": g.epsg, "origin_x": g.origin_x, "origin_y": g.origin_y,
            "pixel_x": g.pixel_x, "pixel_y": g.pixel_y,
            "pixel_is": if g.pixel_is_area { "area" } else { "point" },
            "wkt": g.wkt,
        })),
    });
    write_sidecar(&args.output, sidecar, &meta)
}

/// The samples to write: one even level inside the window ([`LevelGrid`]).
struct Samples(LevelGrid);

impl std::ops::Deref for Samples {
    type Target = LevelGrid;
    fn deref(&self) -> &LevelGrid {
        &self.0
    }
}

impl Samples {
    /// The samples `--level` and `--bbox` ask for, checked.
    fn of(args: &ExtractArgs, repo: &Repository) -> Result<Samples> {
        let p = repo.head().params();
        let (w, h) = (
            i64::from(p.domain.data().width),
            i64::from(p.domain.data().height),
        );
        let rect = match &args.bbox {
            None => None,
            Some(b) => Some(
                bbox_window(b, repo.head().georef(), w, h, "--bbox").map_err(anyhow::Error::msg)?,
            ),
        };
        Ok(Samples(
            LevelGrid::new(p, args.level, rect, "--level").map_err(anyhow::Error::msg)?,
        ))
    }

    /// Decodes `repo` (read from `path`) and returns the samples' heights in metres (`to_sample`
    /// of a height in units), row by row; `fill` where there is no data
    /// ([`LevelGrid::decode`]).
    fn decode<T: Copy + Send + Sync>(
        &self,
        repo: &Repository,
        path: &Path,
        fill: T,
        to_sample: impl Fn(i32) -> T + Sync,
    ) -> Result<Vec<T>> {
        let encoded = repo
            .to_encoded()
            .with_context(|| format!("reading {}", path.display()))?;
        self.0
            .decode(&encoded, fill, to_sample)
            .with_context(|| format!("decoding {}", path.display()))
    }
}

/// The decoded heights, in the sample type written.
enum Heights {
    /// `--float64`: exactly as decoded.
    F64(Raster<f64>),
    /// The default: rounded to float32.
    F32(Raster<f32>),
}

impl Heights {
    /// Width, height and georeferencing.
    fn shape(&self) -> (usize, usize, Option<&cbdam_codec::repository::GeoRef>) {
        match self {
            Heights::F64(r) => (r.width, r.height, r.georef.as_ref()),
            Heights::F32(r) => (r.width, r.height, r.georef.as_ref()),
        }
    }

    fn write_geotiff(&self, f: &mut File, nodata: Option<f64>) -> cbdam_builder::Result<()> {
        match self {
            Heights::F64(r) => write_geotiff(f, r, nodata, true),
            Heights::F32(r) => write_geotiff_f32(f, r, nodata),
        }
    }

    fn write_raw(&self, f: &mut File) -> cbdam_builder::Result<()> {
        match self {
            Heights::F64(r) => write_raw(f, r, true),
            Heights::F32(r) => write_raw_f32(f, r),
        }
    }
}

/// Writes `heights` as a GeoTIFF to --output and, for a CRS known only as WKT, an ESRI `.prj`
/// beside it (GeoKeys hold EPSG codes, not definitions; GIS software looks for the `.prj`).
fn write_geotiff_and_prj(args: &ExtractArgs, heights: &Heights, nodata: Option<f64>) -> Result<()> {
    write_atomically(&args.output, |f: &mut File| {
        heights.write_geotiff(f, nodata)
    })
    .with_context(|| format!("writing {}", args.output.display()))?;
    if let Some(wkt) = heights.shape().2.and_then(|g| g.wkt.as_deref()) {
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
