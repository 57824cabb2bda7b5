//! `cbdam tiles REPO --format terrarium|terrain-rgb -o OUT.pmtiles`: the raster tiles in one
//! PMTiles v3 archive (`docs/WEB-MAPS.md`), made in parallel and written in tile-id order, with
//! the TileJSON as its metadata.

use anyhow::{Context, Result};
use cbdam_tiles::Tiler;
use cbdam_tiles::pmtiles::{ArchiveInfo, PmtilesWriter, TileType, tile_id};
use cbdam_tiles::raster_image::ImageFormat;
use rayon::prelude::*;

use crate::web_tiles::{TileFormat, TilesArgs, make, progress};

/// Tiles made at a time (in parallel) before they are appended in order.
const BATCH: usize = 64;

/// Writes `tiles` (XYZ) of `tile` pixels of `tiler` into the archive at `args.output`, and
/// says so (levels to `max_zoom`, the repository decoded in `decoded_s`).
pub fn write(
    args: &TilesArgs,
    tiler: &Tiler,
    name: &str,
    (mut tiles, tile): (Vec<(u32, u32, u32)>, u32),
    (max_zoom, decoded_s): (u8, f64),
) -> Result<()> {
    let tiling = std::time::Instant::now();
    let id = |&(z, x, y): &(u32, u32, u32)| u8::try_from(z).ok().and_then(|z| tile_id(z, x, y));
    tiles.sort_by_key(id);
    let path = &args.output;
    let mut out = PmtilesWriter::create(path)
        .with_context(|| format!("creating {} (as {0}.partial)", path.display()))?;
    let bar = progress(args.quiet.value, tiles.len() as u64);
    for batch in tiles.chunks(BATCH) {
        let made: Vec<Vec<u8>> = batch
            .par_iter()
            .map(|&zxy| make(tiler, (args.format, args.image), zxy, tile))
            .collect::<Result<_>>()?;
        for (&(z, x, y), bytes) in batch.iter().zip(&made) {
            let z = u8::try_from(z).context("a zoom past 255")?;
            out.add((z, x, y), bytes)
                .with_context(|| format!("writing tile {z}/{x}/{y} to {}", path.display()))?;
        }
        bar.inc(batch.len() as u64);
    }
    bar.finish_and_clear();
    let info = archive_info(args, tiler, name, tile);
    let bytes = out
        .finish(&info)
        .with_context(|| format!("finishing {}", path.display()))?;
    if !args.quiet.value {
        let (n, secs) = (tiles.len(), tiling.elapsed().as_secs_f64());
        println!(
            "{}: {n} tiles, levels 0…{max_zoom}, {bytes} bytes; decoded in {decoded_s:.2} s, \
             tiles in {secs:.2} s ({:.0} tiles/s)",
            path.display(),
            n as f64 / secs.max(1e-9),
        );
    }
    Ok(())
}

/// The header's fields and the metadata: the TileJSON `cbdam serve` answers, without its
/// `tiles` URLs.
fn archive_info(args: &TilesArgs, tiler: &Tiler, name: &str, tile: u32) -> ArchiveInfo {
    let encoding = match args.format {
        TileFormat::TerrainRgb => cbdam_tiles::Encoding::TerrainRgb,
        _ => cbdam_tiles::Encoding::Terrarium,
    };
    let mut doc = tiler.tilejson(name, (encoding, tile), "", args.attribution.as_deref());
    if let Some(o) = doc.as_object_mut() {
        o.remove("tiles");
        o.insert("format".into(), args.image.format().extension().into());
    }
    let num = |v: &serde_json::Value, i: usize| v[i].as_f64().unwrap_or(0.0);
    let (b, c) = (&doc["bounds"], &doc["center"]);
    ArchiveInfo {
        tile_type: match args.image.format() {
            ImageFormat::Png => TileType::Png,
            ImageFormat::Webp => TileType::Webp,
        },
        gzipped_tiles: false,
        bounds: [num(b, 0), num(b, 1), num(b, 2), num(b, 3)],
        center: (num(c, 0), num(c, 1), num(c, 2) as u8),
        metadata: doc,
    }
}
