//! The PMTiles writer's tile ids (against the values of the reference implementation, the
//! `pmtiles` Python package's `zxy_to_tileid`), its directories' varints and runs, and an
//! archive read back by the header's offsets.

use super::*;

#[test]
fn tile_ids_follow_the_specs_hilbert_curve() {
    // zxy_to_tileid of pmtiles 3.8.1 (pip) at these tiles.
    let reference = [
        ((0, 0, 0), 0),
        ((1, 0, 0), 1),
        ((1, 0, 1), 2),
        ((1, 1, 1), 3),
        ((1, 1, 0), 4),
        ((2, 0, 0), 5),
        ((3, 5, 2), 76),
        ((12, 3000, 1000), 20_287_189),
    ];
    for ((z, x, y), id) in reference {
        assert_eq!(tile_id(z, x, y), Some(id), "tile {z}/{x}/{y}");
    }
    assert_eq!(tile_id(2, 4, 0), None, "x past the level");
    assert_eq!(tile_id(32, 0, 0), None, "past level 31");
}

#[test]
fn varints_are_little_endian_base_128() {
    let mut out = Vec::new();
    for v in [0, 127, 128, 300, u64::MAX] {
        varint(&mut out, v);
    }
    let max = [0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0x01];
    let want: Vec<u8> = [&[0x00, 0x7f, 0x80, 0x01, 0xac, 0x02][..], &max].concat();
    assert_eq!(out, want);
}

/// Reads one varint from `bytes` at `at`.
fn read_varint(bytes: &[u8], at: &mut usize) -> u64 {
    let (mut v, mut shift) = (0u64, 0);
    loop {
        let b = bytes[*at];
        *at += 1;
        v |= u64::from(b & 0x7f) << shift;
        if b < 0x80 {
            return v;
        }
        shift += 7;
    }
}

fn gunzip(bytes: &[u8]) -> Vec<u8> {
    use std::io::Read;
    let mut out = Vec::new();
    flate2::read::GzDecoder::new(bytes)
        .read_to_end(&mut out)
        .unwrap();
    out
}

/// A directory's entries: (tile id, offset, length, run length).
fn read_directory(bytes: &[u8]) -> Vec<(u64, u64, u64, u64)> {
    let mut at = 0;
    let n = read_varint(bytes, &mut at) as usize;
    let mut ids = Vec::with_capacity(n);
    let mut last = 0;
    for _ in 0..n {
        last += read_varint(bytes, &mut at);
        ids.push(last);
    }
    let runs: Vec<u64> = (0..n).map(|_| read_varint(bytes, &mut at)).collect();
    let lengths: Vec<u64> = (0..n).map(|_| read_varint(bytes, &mut at)).collect();
    let mut out: Vec<(u64, u64, u64, u64)> = Vec::with_capacity(n);
    for i in 0..n {
        let raw = read_varint(bytes, &mut at);
        let offset = match (raw, out.last()) {
            (0, Some(p)) => p.1 + p.2,
            _ => raw - 1,
        };
        out.push((ids[i], offset, lengths[i], runs[i]));
    }
    assert_eq!(at, bytes.len(), "bytes after the directory");
    out
}

fn u64_at(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().unwrap())
}

#[test]
fn an_archive_holds_every_tile_once_with_runs_and_repeats_shared() {
    let dir = std::env::temp_dir().join(format!("cbdam-pmtiles-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("t.pmtiles");
    let mut w = PmtilesWriter::create(&path).unwrap();
    // Level 2 in tile-id order; tiles 1 and 2 the same bytes (a run), tile 5 as tile 0.
    let mut tiles: Vec<((u8, u32, u32), Vec<u8>)> = (0..4u32)
        .flat_map(|x| (0..4u32).map(move |y| (2u8, x, y)))
        .map(|t| (t, format!("tile {t:?}").into_bytes()))
        .collect();
    tiles.sort_by_key(|(t, _)| tile_id(t.0, t.1, t.2));
    tiles[2].1 = tiles[1].1.clone();
    tiles[5].1 = tiles[0].1.clone();
    for (t, b) in &tiles {
        w.add(*t, b).unwrap();
    }
    assert!(w.add(tiles[3].0, b"late").is_err(), "a tile out of order");
    assert!(!path.exists(), "the archive is there before it is finished");
    let info = ArchiveInfo {
        tile_type: TileType::Png,
        gzipped_tiles: false,
        bounds: [7.0, 46.0, 7.5, 46.25],
        center: (7.25, 46.125, 2),
        metadata: serde_json::json!({"name": "t"}),
    };
    let total = w.finish(&info).unwrap();
    let file = std::fs::read(&path).unwrap();
    assert_eq!(file.len() as u64, total);
    assert_eq!(&file[..8], b"PMTiles\x03");
    let (root_at, root_len) = (u64_at(&file, 8) as usize, u64_at(&file, 16) as usize);
    let (meta_at, meta_len) = (u64_at(&file, 24) as usize, u64_at(&file, 32) as usize);
    let data_at = u64_at(&file, 56) as usize;
    assert_eq!(
        (u64_at(&file, 72), u64_at(&file, 80), u64_at(&file, 88)),
        (16, 15, 14),
        "addressed tiles, entries, contents"
    );
    assert_eq!(&file[96..102], &[1, 2, 1, 2, 2, 2]);
    let meta: serde_json::Value =
        serde_json::from_slice(&gunzip(&file[meta_at..meta_at + meta_len])).unwrap();
    assert_eq!(meta["name"], "t");
    let entries = read_directory(&gunzip(&file[root_at..root_at + root_len]));
    let mut addressed = 0;
    for (id, offset, length, run) in entries {
        for k in 0..run {
            let (t, want) = &tiles[addressed];
            assert_eq!(tile_id(t.0, t.1, t.2), Some(id + k));
            let at = data_at + offset as usize;
            assert_eq!(&file[at..at + length as usize], &want[..], "tile {t:?}");
            addressed += 1;
        }
    }
    assert_eq!(addressed, tiles.len());
    std::fs::remove_dir_all(&dir).unwrap();
}
