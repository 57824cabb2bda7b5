//! `cbdam tiles`: a repository's web-map tiles written as static files (`docs/WEB-MAPS.md`),
//! the same bytes `cbdam serve` answers, for hosts without `cbdam serve`.

use std::fs::File;
use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use cbdam_codec::atomic::write_atomically;
use cbdam_codec::repository::Repository;
use cbdam_tiles::{Encoding, ImageFormat, Scheme, Tiler};
use clap::{Args, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;

use crate::flags;

/// Tile format of `cbdam tiles`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum TileFormat {
    /// Terrarium PNG (MapLibre `raster-dem`, `encoding: "terrarium"`), Web Mercator.
    Terrarium,
    /// Mapbox terrain-RGB PNG (MapLibre `raster-dem`, `encoding: "mapbox"`), Web Mercator.
    TerrainRgb,
    /// Quantized-mesh-1.0 (CesiumJS), geographic TMS, gzip-compressed, with oct-encoded normals
    /// and metadata.
    QuantizedMesh,
}

/// Raster tiles' image file in `cbdam tiles`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum ImageArg {
    /// PNG.
    Png,
    /// Lossless WebP: the same pixels as the PNG, in fewer bytes.
    Webp,
}

impl ImageArg {
    pub(crate) fn format(self) -> ImageFormat {
        match self {
            ImageArg::Png => ImageFormat::Png,
            ImageArg::Webp => ImageFormat::Webp,
        }
    }
}

/// Write a repository's web-map tiles as files: `DIR/{z}/{x}/{y}.png` (or `.webp`) and
/// `DIR/tiles.json` (terrarium, terrain-rgb), or `DIR/{z}/{x}/{y}.terrain` and `DIR/layer.json`
/// (quantized-mesh; serve them with `Content-Encoding: gzip`).
///
/// Tiles already in DIR are kept (each file is written atomically, so one there is whole): an
/// interrupted export run again goes on where it stopped. Tiles are made in parallel.
///
/// With `-o OUT.pmtiles` the raster tiles go into one PMTiles v3 archive instead (its metadata
/// holds the TileJSON), written beside it as OUT.pmtiles.partial and renamed when whole (an
/// interrupted export starts again).
#[derive(Args, Debug)]
pub struct TilesArgs {
    /// Repository file.
    pub(crate) repo: PathBuf,
    /// Tile format.
    #[arg(long, value_enum)]
    pub(crate) format: TileFormat,
    /// Output directory (created if missing), or a `.pmtiles` file (raster formats).
    #[arg(short, long)]
    pub(crate) output: PathBuf,
    /// Deepest zoom level written (default, and at most: the format's maxzoom for this
    /// repository, the first level whose tiles carry its finest data).
    #[arg(long)]
    pub(crate) max_zoom: Option<u8>,
    /// Raster tile size, pixels: 256 or 512.
    #[arg(long, default_value_t = 512)]
    pub(crate) tile: u32,
    /// Raster tiles' image file: png, or webp (lossless: the same pixels, fewer bytes; read
    /// by MapLibre's raster-dem). Not for quantized-mesh.
    #[arg(long, value_enum, default_value_t = ImageArg::Png)]
    pub(crate) image: ImageArg,
    /// Only the tiles meeting this box: west,south,east,north in degrees (WGS84 longitude
    /// and latitude, west < east, south < north); `tiles.json` / `layer.json` then state
    /// its part of the data. A box that misses the data is refused.
    #[arg(long, value_parser = parse_bbox, allow_hyphen_values = true)]
    pub(crate) bbox: Option<[f64; 4]>,
    /// The `attribution` of `tiles.json` / `layer.json` (or the PMTiles metadata): the credit
    /// viewers show, e.g. the data's source. Default: what the repository records of itself.
    #[arg(long, value_name = "TEXT")]
    pub(crate) attribution: Option<String>,
    #[command(flatten)]
    pub(crate) quiet: flags::Quiet,
}

pub fn run(args: &TilesArgs) -> Result<()> {
    let tile = Tiler::tile_size(Some(args.tile)).map_err(anyhow::Error::msg)?;
    if args.format == TileFormat::QuantizedMesh && args.image != ImageArg::Png {
        bail!("--image webp is for raster tiles (terrarium, terrain-rgb), not quantized-mesh");
    }
    let pmtiles = check_output(args)?;
    let started = Instant::now();
    let mut tiler = open_tiler(args)?;
    let decoded_s = started.elapsed().as_secs_f64();
    let name = args
        .repo
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("terrain")
        .to_string();
    let (scheme, deepest) = match args.format {
        TileFormat::QuantizedMesh => (Scheme::Geographic, tiler.mesh_max_zoom()),
        _ => (Scheme::WebMercator, tiler.raster_max_zoom(tile)),
    };
    let max_zoom = args.max_zoom.unwrap_or(deepest).min(deepest);
    if max_zoom < deepest {
        // The documents and the mesh tiles' metadata then list no tile past it.
        tiler.limit_zoom(max_zoom);
    }
    let tiles = match scheme {
        // The tiles `layer.json` lists (its `available`, from the repository's records).
        Scheme::Geographic => (tiler.available().tiles().into_iter())
            .filter(|t| t.z <= max_zoom)
            .map(|t| (u32::from(t.z), t.x, t.y))
            .collect(),
        Scheme::WebMercator => tile_list(tiler.bounds(), max_zoom),
    };
    if pmtiles {
        return crate::web_pmtiles::write(
            args,
            &tiler,
            &name,
            (tiles, tile),
            (max_zoom, decoded_s),
        );
    }
    std::fs::create_dir_all(&args.output)
        .with_context(|| format!("creating {}", args.output.display()))?;
    write_document(args, &tiler, &name, tile)?;
    let bar = progress(args.quiet.value, tiles.len() as u64);
    let (written, bytes) = (AtomicU64::new(0), AtomicU64::new(0));
    let tiling = Instant::now();
    tiles.par_iter().try_for_each(|&(z, x, y)| -> Result<()> {
        let ext = if scheme == Scheme::Geographic {
            "terrain"
        } else {
            args.image.format().extension()
        };
        let path = args.output.join(format!("{z}/{x}/{y}.{ext}"));
        if !path.exists() {
            let body = make(&tiler, (args.format, args.image), (z, x, y), tile)?;
            write_tile(&path, &body)?;
            written.fetch_add(1, Relaxed);
            bytes.fetch_add(body.len() as u64, Relaxed);
        }
        bar.inc(1);
        Ok(())
    })?;
    bar.finish_and_clear();
    let (n, b) = (written.into_inner(), bytes.into_inner());
    if !args.quiet.value {
        let secs = tiling.elapsed().as_secs_f64();
        println!(
            "{}: {n} tiles written ({} already there), levels 0…{max_zoom}, {b} bytes \
             ({:.0} bytes/tile); decoded in {decoded_s:.2} s, tiles in {secs:.2} s \
             ({:.0} tiles/s)",
            args.output.display(),
            tiles.len() as u64 - n,
            b as f64 / n.max(1) as f64,
            n as f64 / secs.max(1e-9),
        );
    }
    Ok(())
}

/// Refuses an output the format cannot go to; returns whether it is a `.pmtiles` archive.
fn check_output(args: &TilesArgs) -> Result<bool> {
    let pmtiles = args.output.extension().is_some_and(|e| e == "pmtiles");
    if pmtiles && args.format == TileFormat::QuantizedMesh {
        bail!(
            "{}: quantized-mesh tiles are not written to PMTiles: its tile ids address 2^z × 2^z \
             tiles a level, the geographic scheme has 2^(z+1) × 2^z, and CesiumJS reads no \
             PMTiles; export them to a directory",
            args.output.display()
        );
    }
    if pmtiles && args.output.is_dir() {
        bail!(
            "output {} is a directory, not a .pmtiles file",
            args.output.display()
        );
    }
    if !pmtiles && args.output.exists() && !args.output.is_dir() {
        bail!(
            "output {} exists and is not a directory",
            args.output.display()
        );
    }
    Ok(pmtiles)
}

/// The repository's tiler, restricted to `--bbox`, with every level decoded (every tile is
/// made, so tiles read the decoded surface, not windows).
fn open_tiler(args: &TilesArgs) -> Result<Tiler> {
    let repo =
        Repository::open(&args.repo).with_context(|| format!("opening {}", args.repo.display()))?;
    Tiler::check(repo.head()).map_err(anyhow::Error::msg)?;
    let encoded = repo
        .to_encoded()
        .with_context(|| format!("reading {}", args.repo.display()))?;
    let mut tiler = Tiler::new(repo.head(), encoded).map_err(anyhow::Error::msg)?;
    if let Some(bbox) = args.bbox {
        tiler
            .restrict_to(bbox)
            .map_err(|e| anyhow::anyhow!("--bbox: {e}"))?;
    }
    tiler.surface().map_err(anyhow::Error::msg)?;
    Ok(tiler)
}

/// `--bbox`: four comma-separated degrees, west,south,east,north.
fn parse_bbox(text: &str) -> Result<[f64; 4], String> {
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    let [w, s, e, n] = parts[..] else {
        return Err(format!(
            "{} values; the box is four: west,south,east,north (degrees)",
            parts.len()
        ));
    };
    let mut v = [0.0; 4];
    for (slot, (name, part)) in
        v.iter_mut()
            .zip([("west", w), ("south", s), ("east", e), ("north", n)])
    {
        *slot = part
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| format!("{name} `{part}` is not a number of degrees"))?;
    }
    let [w, s, e, n] = v;
    for (name, x, limit) in [("west", w, 180.0), ("east", e, 180.0)]
        .into_iter()
        .chain([("south", s, 90.0), ("north", n, 90.0)])
    {
        if x.abs() > limit {
            return Err(format!("{name} {x}° is outside ±{limit}°"));
        }
    }
    if w >= e {
        return Err(format!(
            "west {w}° is not west of east {e}° (a box across the antimeridian is not supported)"
        ));
    }
    if s >= n {
        return Err(format!("south {s}° is not south of north {n}°"));
    }
    Ok(v)
}

/// Every Web Mercator tile of levels `0..=max_zoom` that meets `bounds`.
fn tile_list(bounds: [f64; 4], max_zoom: u8) -> Vec<(u32, u32, u32)> {
    let scheme = Scheme::WebMercator;
    let mut out = Vec::new();
    for z in 0..=max_zoom {
        let Some((x0, y0, x1, y1)) = scheme.range(z, bounds) else {
            continue;
        };
        for y in y0..=y1 {
            for x in x0..=x1 {
                if scheme.meets(cbdam_tiles::TileId { z, x, y }, bounds) {
                    out.push((u32::from(z), x, y));
                }
            }
        }
    }
    out
}

/// One tile's file bytes.
pub(crate) fn make(
    tiler: &Tiler,
    (format, image): (TileFormat, ImageArg),
    zxy: (u32, u32, u32),
    tile: u32,
) -> Result<Vec<u8>> {
    let at =
        |e: cbdam_tiles::TilesError| anyhow::anyhow!("tile {}/{}/{}: {e}", zxy.0, zxy.1, zxy.2);
    let raster = |encoding| tiler.raster(zxy, tile, (encoding, image.format()));
    Ok(match format {
        TileFormat::Terrarium => raster(Encoding::Terrarium).map_err(at)?.image,
        TileFormat::TerrainRgb => raster(Encoding::TerrainRgb).map_err(at)?.image,
        TileFormat::QuantizedMesh => tiler.mesh(zxy, true, true).map_err(at)?.gzipped.clone(),
    })
}

fn write_tile(path: &Path, body: &[u8]) -> Result<()> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    write_atomically(path, |f: &mut File| -> Result<()> {
        Ok(f.write_all(body)?)
    })
    .with_context(|| format!("writing {}", path.display()))
}

/// `tiles.json` or `layer.json`, with URLs relative to the directory.
fn write_document(args: &TilesArgs, tiler: &Tiler, name: &str, tile: u32) -> Result<()> {
    let template = format!("{{z}}/{{x}}/{{y}}.{}", args.image.format().extension());
    let (file, doc) = match args.format {
        TileFormat::QuantizedMesh => (
            "layer.json",
            (tiler.layer_json(name, args.attribution.as_deref())).map_err(anyhow::Error::msg)?,
        ),
        TileFormat::Terrarium => (
            "tiles.json",
            tiler.tilejson(
                name,
                (Encoding::Terrarium, tile),
                &template,
                args.attribution.as_deref(),
            ),
        ),
        TileFormat::TerrainRgb => (
            "tiles.json",
            tiler.tilejson(
                name,
                (Encoding::TerrainRgb, tile),
                &template,
                args.attribution.as_deref(),
            ),
        ),
    };
    let body = serde_json::to_vec_pretty(&doc)?;
    let path = args.output.join(file);
    if let Ok(there) = std::fs::read(&path)
        && there != body
    {
        bail!(
            "{} holds another export (its {file} differs from this one's in {}): an export run \
             again keeps the tiles already there, which would mix the two; remove the \
             directory or write to another one",
            args.output.display(),
            differing_fields(&there, &doc)
        );
    }
    write_tile(&path, &body)
}

/// The top-level fields in which the JSON document `there` differs from `doc`, named.
fn differing_fields(there: &[u8], doc: &serde_json::Value) -> String {
    let Ok(serde_json::Value::Object(there)) = serde_json::from_slice(there) else {
        return "being no JSON object".to_string();
    };
    let Some(doc) = doc.as_object() else {
        return "its form".to_string();
    };
    let keys = doc
        .keys()
        .chain(there.keys().filter(|k| !doc.contains_key(*k)));
    let differ: Vec<&str> = keys
        .filter(|k| there.get(*k) != doc.get(*k))
        .map(String::as_str)
        .collect();
    differ.join(", ")
}

pub(crate) fn progress(quiet: bool, total: u64) -> ProgressBar {
    if quiet || !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(total);
    bar.set_style(
        ProgressStyle::with_template("tiles {bar:40} {pos}/{len}, {elapsed} elapsed, ETA {eta}")
            .expect("static template"),
    );
    bar
}
