//! Writes a PMTiles archive of every tile of levels 0…Z (default 8: 87 381 tiles) through
//! cbdam's writer, each tile's bytes a function of its tile id that the independent readers
//! (`scripts/web-maps/pmtiles_leaves_check.py`, `pmtiles_leaves_check.mjs`) compute themselves:
//! too many entries for the root directory, so the archive needs leaf directories. Some
//! consecutive tiles repeat the previous one (runs) and some repeat a tile stored elsewhere
//! (stored once).
//!
//! Usage: `cargo run --release -p cbdam-tiles --example pmtiles_many_tiles -- OUT.pmtiles [Z]`

use cbdam_tiles::pmtiles::{ArchiveInfo, PmtilesWriter, TileType, tile_id};

/// The tile whose bytes tile `id` holds: the previous tile's source every fifth tile (a run),
/// tile 7's every eleventh (a repeat elsewhere), else its own.
fn source(id: u64) -> u64 {
    if id % 5 == 4 {
        source(id - 1)
    } else if id % 11 == 10 && id > 20 {
        7
    } else {
        id
    }
}

/// The bytes of source tile `s`: its number, then 0 to 300 bytes of a sequence it seeds.
fn payload(s: u64) -> Vec<u8> {
    let mut out = format!("tile {s}:").into_bytes();
    let n = (s * 2_654_435_761) % 301;
    out.extend((0..n).map(|i| ((s * 7 + i * 13) % 251) as u8));
    out
}

fn main() -> std::io::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let Some(out) = args.get(1) else {
        eprintln!("usage: pmtiles_many_tiles OUT.pmtiles [MAX_ZOOM]");
        std::process::exit(2);
    };
    let max_zoom: u8 = args.get(2).map_or(8, |z| z.parse().expect("a zoom level"));
    let mut tiles = Vec::new();
    for z in 0..=max_zoom {
        for x in 0..1u32 << z {
            for y in 0..1u32 << z {
                tiles.push((tile_id(z, x, y).expect("on the level"), (z, x, y)));
            }
        }
    }
    tiles.sort_unstable();
    let mut writer = PmtilesWriter::create(std::path::Path::new(out))?;
    for &(id, zxy) in &tiles {
        writer.add(zxy, &payload(source(id)))?;
    }
    let info = ArchiveInfo {
        tile_type: TileType::Unknown,
        gzipped_tiles: false,
        bounds: [-180.0, -85.0, 180.0, 85.0],
        center: (0.0, 0.0, 0),
        metadata: serde_json::json!({ "name": "pmtiles_many_tiles", "maxzoom": max_zoom }),
    };
    let bytes = writer.finish(&info)?;
    println!(
        "{out}: {} tiles, levels 0…{max_zoom}, {bytes} bytes",
        tiles.len()
    );
    Ok(())
}
