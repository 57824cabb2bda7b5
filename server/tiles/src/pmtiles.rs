//! One PMTiles v3 archive of tiles (https://github.com/protomaps/PMTiles/blob/main/spec/v3/spec.md):
//! a 127-byte header, the root directory within the first 16 KiB, then the tiles' bytes in
//! tile-id order, the leaf directories and the metadata JSON. Tile ids run along a Hilbert
//! curve level by level ([`tile_id`]); directories are varint columns (tile-id deltas, run
//! lengths, lengths, offsets with 0 for "right after the previous"), gzip-compressed; a run of
//! tiles with the same bytes is one entry, and a small tile repeated elsewhere is stored once.
//!
//! [`PmtilesWriter`] writes into a temporary file beside the archive and renames it into place
//! when done: the archive's path never holds a half-written one.

use std::collections::HashMap;
use std::fs::File;
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use serde_json::Value;

/// Bytes before the tiles: the header and the root directory (the spec's first 16 KiB).
const ROOT_SPACE: u64 = 16_384;
/// Header bytes.
const HEADER: usize = 127;
/// Tiles of at most this many bytes are kept by content, so a repeat is stored once.
const DEDUP_BYTES: usize = 4096;
/// Tiles a leaf directory holds at first (doubled until the root fits).
const LEAF_TILES: usize = 4096;

/// The tiles' content type (the header's `tile_type`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TileType {
    /// Not one the spec names (e.g. quantized-mesh).
    Unknown = 0,
    /// PNG images.
    Png = 2,
    /// WebP images.
    Webp = 4,
}

/// What the header says of the archive besides its directories.
#[derive(Clone, Debug)]
pub struct ArchiveInfo {
    /// The tiles' type.
    pub tile_type: TileType,
    /// Whether each tile's bytes are gzip (the header's `tile_compression`: 2, else 1).
    pub gzipped_tiles: bool,
    /// West, south, east, north, degrees.
    pub bounds: [f64; 4],
    /// Longitude, latitude and zoom a viewer starts at.
    pub center: (f64, f64, u8),
    /// The metadata JSON (TileJSON fields).
    pub metadata: Value,
}

/// One directory entry: `run_length` tiles from `tile_id` with the bytes at `offset`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Entry {
    tile_id: u64,
    offset: u64,
    length: u32,
    run_length: u32,
}

/// Writes tiles, in increasing tile-id order, into one archive.
#[derive(Debug)]
pub struct PmtilesWriter {
    path: PathBuf,
    temp: PathBuf,
    out: BufWriter<File>,
    entries: Vec<Entry>,
    /// Bytes of tiles written.
    data: u64,
    seen: HashMap<Vec<u8>, (u64, u32)>,
    contents: u64,
    zooms: Option<(u8, u8)>,
}

/// The PMTiles tile id of `z/x/y` (XYZ, y from the north): the tiles of the levels above, then
/// `(x, y)`'s place along level `z`'s Hilbert curve. `None` past level 31 or off the level.
pub fn tile_id(z: u8, x: u32, y: u32) -> Option<u64> {
    if z > 31 || u64::from(x) >= 1 << z || u64::from(y) >= 1 << z {
        return None;
    }
    let n = 1u64 << z;
    let (mut x, mut y) = (u64::from(x), u64::from(y));
    let mut id = ((1u64 << (2 * u32::from(z))) - 1) / 3;
    let mut s = n >> 1;
    while s > 0 {
        let (rx, ry) = (u64::from(x & s != 0), u64::from(y & s != 0));
        id += s * s * ((3 * rx) ^ ry);
        if ry == 0 {
            if rx == 1 {
                (x, y) = (n - 1 - x, n - 1 - y);
            }
            (x, y) = (y, x);
        }
        s >>= 1;
    }
    Some(id)
}

impl PmtilesWriter {
    /// An archive to be written at `path` (through a temporary file beside it).
    pub fn create(path: &Path) -> std::io::Result<PmtilesWriter> {
        let mut name = path.file_name().unwrap_or_default().to_os_string();
        name.push(".partial");
        let temp = path.with_file_name(name);
        let mut out = BufWriter::new(File::create(&temp)?);
        out.seek(SeekFrom::Start(ROOT_SPACE))?;
        Ok(PmtilesWriter {
            path: path.to_path_buf(),
            temp,
            out,
            entries: Vec::new(),
            data: 0,
            seen: HashMap::new(),
            contents: 0,
            zooms: None,
        })
    }

    /// Adds tile `z/x/y` (XYZ); tiles must come in increasing [`tile_id`] order.
    pub fn add(&mut self, (z, x, y): (u8, u32, u32), bytes: &[u8]) -> std::io::Result<()> {
        let bad = |m: String| std::io::Error::new(std::io::ErrorKind::InvalidInput, m);
        let id = tile_id(z, x, y).ok_or_else(|| bad(format!("no PMTiles tile {z}/{x}/{y}")))?;
        let length = u32::try_from(bytes.len())
            .map_err(|_| bad(format!("tile {z}/{x}/{y} is over 4 GiB")))?;
        self.zooms = Some(self.zooms.map_or((z, z), |(lo, hi)| (lo.min(z), hi.max(z))));
        if let Some(&last) = self.entries.last() {
            let end = last.tile_id + u64::from(last.run_length);
            if id < end {
                return Err(bad(format!("tile {z}/{x}/{y} added out of tile-id order")));
            }
            // The next tile, with the same bytes as the last: one run.
            if id == end && length == last.length && self.same_as(last.offset, bytes) {
                if let Some(l) = self.entries.last_mut() {
                    l.run_length += 1;
                }
                return Ok(());
            }
        }
        let offset = match self.seen.get(bytes) {
            Some(&(offset, _)) => offset,
            None => {
                let offset = self.data;
                self.out.write_all(bytes)?;
                self.data += u64::from(length);
                self.contents += 1;
                if bytes.len() <= DEDUP_BYTES {
                    self.seen.insert(bytes.to_vec(), (offset, length));
                }
                offset
            }
        };
        self.entries.push(Entry {
            tile_id: id,
            offset,
            length,
            run_length: 1,
        });
        Ok(())
    }

    /// Whether the tile stored at `offset` is `bytes` (known only for small tiles).
    fn same_as(&self, offset: u64, bytes: &[u8]) -> bool {
        self.seen.get(bytes).is_some_and(|&(o, _)| o == offset)
    }

    /// Writes the directories, metadata and header, and moves the archive into place;
    /// returns its bytes.
    pub fn finish(mut self, info: &ArchiveInfo) -> std::io::Result<u64> {
        let (root, leaves) = directories(&self.entries)?;
        let metadata = gzip(&serde_json::to_vec(&info.metadata)?)?;
        let tiles_at = ROOT_SPACE;
        let leaves_at = tiles_at + self.data;
        let metadata_at = leaves_at + leaves.len() as u64;
        self.out.write_all(&leaves)?;
        self.out.write_all(&metadata)?;
        let addressed: u64 = self.entries.iter().map(|e| u64::from(e.run_length)).sum();
        let (min_zoom, max_zoom) = self.zooms.unwrap_or((0, 0));
        let mut h = Vec::with_capacity(HEADER);
        h.extend_from_slice(b"PMTiles\x03");
        for v in [
            HEADER as u64,
            root.len() as u64,
            metadata_at,
            metadata.len() as u64,
            leaves_at,
            leaves.len() as u64,
            tiles_at,
            self.data,
            addressed,
            self.entries.len() as u64,
            self.contents,
        ] {
            h.extend_from_slice(&v.to_le_bytes());
        }
        let compression = if info.gzipped_tiles { 2 } else { 1 };
        h.extend_from_slice(&[1, 2, compression, info.tile_type as u8, min_zoom, max_zoom]);
        let e7 = |deg: f64| ((deg * 1e7).round() as i32).to_le_bytes();
        let [w, s, e, n] = info.bounds;
        for v in [w, s, e, n] {
            h.extend_from_slice(&e7(v));
        }
        h.push(info.center.2);
        h.extend_from_slice(&e7(info.center.0));
        h.extend_from_slice(&e7(info.center.1));
        debug_assert_eq!(h.len(), HEADER);
        self.out.seek(SeekFrom::Start(0))?;
        self.out.write_all(&h)?;
        self.out.write_all(&root)?;
        let file = self.out.into_inner().map_err(|e| e.into_error())?;
        file.sync_all()?;
        drop(file);
        std::fs::rename(&self.temp, &self.path)?;
        Ok(metadata_at + metadata.len() as u64)
    }
}

/// The gzip of the root directory, and of the leaf directories one after another: all the
/// entries in the root when it fits the first 16 KiB, else leaves of [`LEAF_TILES`] entries
/// (doubled until the root of their first ids fits).
fn directories(entries: &[Entry]) -> std::io::Result<(Vec<u8>, Vec<u8>)> {
    let room = (ROOT_SPACE as usize) - HEADER;
    let root = gzip(&serialize(entries))?;
    if root.len() <= room {
        return Ok((root, Vec::new()));
    }
    let mut per_leaf = LEAF_TILES;
    loop {
        let (mut leaves, mut index) = (Vec::new(), Vec::new());
        for chunk in entries.chunks(per_leaf) {
            let leaf = gzip(&serialize(chunk))?;
            index.push(Entry {
                tile_id: chunk[0].tile_id,
                offset: leaves.len() as u64,
                length: leaf.len() as u32,
                run_length: 0,
            });
            leaves.extend_from_slice(&leaf);
        }
        let root = gzip(&serialize(&index))?;
        if root.len() <= room {
            return Ok((root, leaves));
        }
        per_leaf *= 2;
    }
}

/// A directory's bytes before compression: the count, then the columns.
fn serialize(entries: &[Entry]) -> Vec<u8> {
    let mut out = Vec::new();
    varint(&mut out, entries.len() as u64);
    let mut last = 0;
    for e in entries {
        varint(&mut out, e.tile_id - last);
        last = e.tile_id;
    }
    for e in entries {
        varint(&mut out, u64::from(e.run_length));
    }
    for e in entries {
        varint(&mut out, u64::from(e.length));
    }
    for (i, e) in entries.iter().enumerate() {
        let follows = i > 0 && {
            let p = entries[i - 1];
            e.offset == p.offset + u64::from(p.length)
        };
        varint(&mut out, if follows { 0 } else { e.offset + 1 });
    }
    out
}

fn varint(out: &mut Vec<u8>, mut v: u64) {
    while v >= 0x80 {
        out.push((v as u8 & 0x7f) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

fn gzip(bytes: &[u8]) -> std::io::Result<Vec<u8>> {
    let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    enc.write_all(bytes)?;
    enc.finish()
}

#[cfg(test)]
#[path = "pmtiles_tests.rs"]
mod tests;
