//! The files of a sharded build's work directory that hold the input: `prepared`, the quantized
//! grid in square tiles, each with its own CRC-32, so that a step reads (and checks) only the
//! tiles under the rectangles it encodes; and `summary`, what the encoder's setup measured of
//! the whole grid once in the plan (stored diamonds, roots, bounds), so that no later step scans
//! the whole grid again. Both are internal to the work directory (not a repository format);
//! a file of another layout version is refused.

use std::fs;
use std::io::{BufWriter, Write};
use std::path::Path;

use cbdam_codec::geometry::DiamondId;
use cbdam_codec::hierarchy::{GridSummary, Resolution, TempStorage};
use cbdam_codec::quant::HeightGrid;
use cbdam_codec::temp::LatticeArray;

use crate::error::{Context, Result};
use crate::journal::{Reader, write_atomically};

const PREPARED: &str = "prepared";
const SUMMARY: &str = "summary";
/// Magic bytes of the `prepared` file.
const PREPARED_MAGIC: &[u8; 4] = b"CBDP";
/// Magic bytes of the `summary` file.
const SUMMARY_MAGIC: &[u8; 4] = b"CBDS";
/// Version of these files' layout.
const VERSION: u32 = 2;
/// Side of a tile of `prepared`, samples: 320 KiB of a single-resolution grid.
const TILE: usize = 256;
/// Bytes of the header of `prepared`: magic, version, width, height, classes flag, tile side.
const HEAD: usize = 29;

/// Where the tiles of a `width` × `height` grid of `bps` bytes a sample lie in `prepared`: row
/// by row of tiles, each tile's values (i32), validity (u8) and classes (u8) row by row.
#[derive(Clone, Copy)]
struct Tiling {
    width: usize,
    height: usize,
    /// Bytes a sample: 5, or 6 with classes.
    bps: usize,
}

impl Tiling {
    fn across(&self) -> usize {
        self.width.div_ceil(TILE)
    }
    fn count(&self) -> usize {
        self.across() * self.height.div_ceil(TILE)
    }
    /// Tile `(i, j)`'s samples: columns `x0..x1`, rows `y0..y1`.
    fn rect(&self, i: usize, j: usize) -> (usize, usize, usize, usize) {
        let (x0, y0) = (i * TILE, j * TILE);
        (
            x0,
            y0,
            (x0 + TILE).min(self.width),
            (y0 + TILE).min(self.height),
        )
    }
    /// Byte offset of tile `(i, j)` in the file: the rows of tiles above it are whole rows of
    /// the grid, and the tiles before it in its row are `TILE` wide.
    fn offset(&self, i: usize, j: usize) -> u64 {
        let (_, y0, _, y1) = self.rect(i, j);
        (HEAD + self.bps * (y0 * self.width + (y1 - y0) * i * TILE)) as u64
    }
    /// Offset of the table of the tiles' CRCs, after the last tile.
    fn table(&self) -> u64 {
        (HEAD + self.bps * self.width * self.height) as u64
    }
    fn file_len(&self) -> u64 {
        self.table() + 4 * self.count() as u64 + 4
    }
}

fn head(t: &Tiling, classes: bool) -> Vec<u8> {
    let mut head = Vec::with_capacity(HEAD);
    head.extend_from_slice(PREPARED_MAGIC);
    head.extend_from_slice(&VERSION.to_le_bytes());
    head.extend_from_slice(&(t.width as u64).to_le_bytes());
    head.extend_from_slice(&(t.height as u64).to_le_bytes());
    head.push(u8::from(classes));
    head.extend_from_slice(&(TILE as u32).to_le_bytes());
    head
}

/// Writes `work/prepared`: the header, the tiles (each: values i32, validity u8, classes u8,
/// row by row), the tiles' CRC-32s, and a CRC-32 of the header and that table; little-endian.
/// Written under a temporary name and renamed.
pub(crate) fn write_prepared(
    work: &Path,
    grid: &HeightGrid,
    classes: Option<&Resolution>,
) -> Result<()> {
    let t = Tiling {
        width: grid.width,
        height: grid.height,
        bps: if classes.is_some() { 6 } else { 5 },
    };
    // Removed when dropped before it is renamed into place: a failed write (a full disk)
    // leaves nothing behind.
    let tmp = tempfile::Builder::new()
        .prefix(&format!(".{PREPARED}."))
        .suffix(".tmp")
        .tempfile_in(work)
        .with_context(|| format!("creating a temporary file in {}", work.display()))?;
    let tmp_path = tmp.path().to_path_buf();
    let context = || format!("writing {}", tmp_path.display());
    let mut out = BufWriter::with_capacity(1 << 20, tmp.as_file());
    let head = head(&t, classes.is_some());
    out.write_all(&head).with_context(context)?;
    let mut table = Vec::with_capacity(4 * t.count());
    let mut tile = Vec::with_capacity(t.bps * TILE * TILE);
    for j in 0..t.height.div_ceil(TILE) {
        for i in 0..t.across() {
            let (x0, y0, x1, y1) = t.rect(i, j);
            tile.clear();
            let rows = || (y0..y1).map(|y| y * t.width + x0..y * t.width + x1);
            for r in rows() {
                grid.values[r]
                    .iter()
                    .for_each(|v| tile.extend(v.to_le_bytes()));
            }
            for r in rows() {
                tile.extend(grid.valid[r].iter().map(|&v| u8::from(v)));
            }
            if let Some(c) = classes {
                for r in rows() {
                    tile.extend_from_slice(&c.class[r]);
                }
            }
            table.extend_from_slice(&crc32fast::hash(&tile).to_le_bytes());
            out.write_all(&tile).with_context(context)?;
        }
        // A mapped grid drops the band of rows it has read from the resident set.
        let (_, y0, _, y1) = t.rect(0, j);
        let band = y0 * t.width..y1 * t.width;
        grid.values.release(band.clone());
        grid.valid.release(band.clone());
        if let Some(c) = classes {
            c.class.release(band);
        }
    }
    let mut crc = crc32fast::Hasher::new();
    crc.update(&head);
    crc.update(&table);
    out.write_all(&table).with_context(context)?;
    out.write_all(&crc.finalize().to_le_bytes())
        .with_context(context)?;
    out.flush().with_context(context)?;
    drop(out);
    tmp.persist(work.join(PREPARED))
        .map_err(|e| e.error)
        .with_context(context)?;
    Ok(())
}

/// The grid (and classes) of `work/prepared`, `width` × `height` with classes when `variable`
/// (as the plan says), holding the samples of the tiles under `rects` (lattice rectangles
/// `(x0, y0, x1, y1)`, inclusive, clipped to the grid; `None`: all of them) and zeros (nodata)
/// elsewhere, each tile checked against its CRC. The arrays are kept in `storage`; in memory,
/// the pages of the tiles not read are never touched.
pub(crate) fn read_prepared(
    work: &Path,
    (width, height, variable): (usize, usize, bool),
    rects: Option<&[(i64, i64, i64, i64)]>,
    storage: &TempStorage,
) -> Result<(HeightGrid, Option<Resolution>)> {
    use std::os::unix::fs::FileExt;
    let path = work.join(PREPARED);
    let damaged = |why: &str| {
        crate::BuildError::Invalid(format!(
            "{} is damaged ({why}); plan again in a new work directory",
            path.display()
        ))
    };
    let file = fs::File::open(&path).with_context(|| format!("reading {}", path.display()))?;
    let io = |e: std::io::Error| damaged(&format!("{e}"));
    let mut found = [0u8; HEAD];
    file.read_exact_at(&mut found, 0).map_err(io)?;
    if &found[..4] != PREPARED_MAGIC || found[4..8] != VERSION.to_le_bytes() {
        return Err(damaged("not a prepared grid of this cbdam version"));
    }
    let t = Tiling {
        width,
        height,
        bps: if variable { 6 } else { 5 },
    };
    if found[..] != head(&t, variable)[..] {
        return Err(damaged("its size does not match the plan"));
    }
    if file.metadata().map_err(io)?.len() != t.file_len() {
        return Err(damaged("its length does not match its size"));
    }
    let mut table = vec![0u8; 4 * t.count() + 4];
    file.read_exact_at(&mut table, t.table()).map_err(io)?;
    let (table, stored) = table.split_at(4 * t.count());
    let mut crc = crc32fast::Hasher::new();
    crc.update(&found);
    crc.update(table);
    if crc.finalize().to_le_bytes() != stored {
        return Err(damaged("checksum mismatch in its header"));
    }
    let count = width * height;
    let mut values = LatticeArray::filled(count, 0i32, storage)?;
    let mut valid = LatticeArray::filled(count, false, storage)?;
    let mut class = match variable {
        true => Some(LatticeArray::filled(count, 0u8, storage)?),
        false => None,
    };
    let mut wanted = vec![rects.is_none(); t.count()];
    for &(x0, y0, x1, y1) in rects.unwrap_or(&[]) {
        let clip = |a: i64, len: usize| a.clamp(0, len as i64 - 1) as usize / TILE;
        if x0 > x1 || y0 > y1 || x1 < 0 || y1 < 0 {
            continue;
        }
        for j in clip(y0, height)..=clip(y1, height) {
            for i in clip(x0, width)..=clip(x1, width) {
                wanted[j * t.across() + i] = true;
            }
        }
    }
    let mut tile = Vec::new();
    // A mapped grid drops each band of tile rows from the resident set once it is written (the
    // values stay in its files): the encoder reads copies of it, and the band's pages would
    // otherwise stay resident, the whole grid for the apex.
    let mut band: Option<usize> = None;
    let release = |j: usize,
                   values: &LatticeArray<i32>,
                   valid: &LatticeArray<bool>,
                   class: Option<&LatticeArray<u8>>| {
        let (_, y0, _, y1) = t.rect(0, j);
        let rows = y0 * width..y1 * width;
        values.release(rows.clone());
        valid.release(rows.clone());
        if let Some(c) = class {
            c.release(rows);
        }
    };
    for (k, _) in wanted.iter().enumerate().filter(|(_, w)| **w) {
        let (i, j) = (k % t.across(), k / t.across());
        if let Some(b) = band.filter(|&b| b != j) {
            release(b, &values, &valid, class.as_ref());
        }
        band = Some(j);
        let (x0, y0, x1, y1) = t.rect(i, j);
        let n = (x1 - x0) * (y1 - y0);
        tile.resize(t.bps * n, 0);
        file.read_exact_at(&mut tile, t.offset(i, j)).map_err(io)?;
        if crc32fast::hash(&tile).to_le_bytes() != table[4 * k..4 * k + 4] {
            return Err(damaged(&format!("checksum mismatch in tile ({i}, {j})")));
        }
        let (vals, rest) = tile.split_at(4 * n);
        let (oks, classes) = rest.split_at(n);
        let w = x1 - x0;
        for (r, y) in (y0..y1).enumerate() {
            let row = y * width + x0..y * width + x1;
            let src = &vals[4 * w * r..4 * w * (r + 1)];
            for (v, b) in values[row.clone()].iter_mut().zip(src.chunks_exact(4)) {
                *v = i32::from_le_bytes(b.try_into().expect("4 bytes"));
            }
            for (v, &b) in valid[row.clone()].iter_mut().zip(&oks[w * r..w * (r + 1)]) {
                *v = b != 0;
            }
            if let Some(c) = &mut class {
                c[row].copy_from_slice(&classes[w * r..w * (r + 1)]);
            }
        }
    }
    if let Some(j) = band {
        release(j, &values, &valid, class.as_ref());
    }
    Ok((
        HeightGrid {
            width,
            height,
            values,
            valid,
        },
        class.map(|class| Resolution { class }),
    ))
}

/// Writes `work/summary`: magic, version, max |height|, all valid, nodata mask, the stored
/// diamonds per level, the recorded ones (variable resolution), the root field and the coded
/// roots, and a CRC-32; little-endian.
pub(crate) fn write_summary(work: &Path, s: &GridSummary) -> Result<()> {
    let mut out = Vec::new();
    out.extend_from_slice(SUMMARY_MAGIC);
    out.extend_from_slice(&VERSION.to_le_bytes());
    out.extend_from_slice(&s.max_abs.to_le_bytes());
    out.push(u8::from(s.all_valid));
    out.push(u8::from(s.nodata_mask));
    let put_levels = |out: &mut Vec<u8>, levels: &[Vec<DiamondId>]| {
        out.extend_from_slice(&(levels.len() as u64).to_le_bytes());
        for level in levels {
            out.extend_from_slice(&(level.len() as u64).to_le_bytes());
            for id in level {
                out.push(id.level);
                out.push(id.face);
                out.extend_from_slice(&id.x.to_le_bytes());
                out.extend_from_slice(&id.y.to_le_bytes());
            }
        }
    };
    put_levels(&mut out, &s.stored);
    out.push(u8::from(s.recorded.is_some()));
    if let Some(r) = &s.recorded {
        put_levels(&mut out, r);
    }
    out.extend_from_slice(&(s.root_field.len() as u64).to_le_bytes());
    s.root_field
        .iter()
        .for_each(|v| out.extend_from_slice(&v.to_le_bytes()));
    out.extend_from_slice(&(s.roots.len() as u64).to_le_bytes());
    out.extend_from_slice(&s.roots);
    let crc = crc32fast::hash(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    write_atomically(work, SUMMARY, &out)
        .with_context(|| format!("writing the grid summary in {}", work.display()))?;
    Ok(())
}

/// The summary's stored sets: per level, its diamonds.
fn read_levels(r: &mut Reader) -> Option<Vec<Vec<DiamondId>>> {
    let levels = r.count(8)?;
    (0..levels)
        .map(|_| {
            let n = r.count(10)?;
            (0..n).map(|_| r.id()).collect()
        })
        .collect()
}

/// The summary [`write_summary`] wrote.
pub(crate) fn read_summary(work: &Path) -> Result<GridSummary> {
    let path = work.join(SUMMARY);
    let bytes = fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
    let damaged = || {
        crate::BuildError::Invalid(format!(
            "{} is damaged or of another cbdam version; plan again in a new work directory",
            path.display()
        ))
    };
    let (body, crc) = bytes
        .split_at_checked(bytes.len().checked_sub(4).ok_or_else(damaged)?)
        .ok_or_else(damaged)?;
    if crc32fast::hash(body).to_le_bytes() != crc {
        return Err(damaged());
    }
    let mut r = Reader(body);
    let parse = |r: &mut Reader| -> Option<GridSummary> {
        if r.take(4)? != SUMMARY_MAGIC || r.u32()? != VERSION {
            return None;
        }
        let max_abs = r.u64()? as i64;
        let (all_valid, nodata_mask) = (r.u8()? != 0, r.u8()? != 0);
        let stored = read_levels(r)?;
        let recorded = match r.u8()? {
            0 => None,
            _ => Some(read_levels(r)?),
        };
        let n = r.count(4)?;
        let root_field = (0..n)
            .map(|_| Some(r.u32()? as i32))
            .collect::<Option<_>>()?;
        let n = r.count(1)?;
        let roots = r.take(n)?.to_vec();
        r.0.is_empty().then_some(GridSummary {
            max_abs,
            all_valid,
            nodata_mask,
            stored,
            recorded,
            root_field,
            roots,
        })
    };
    parse(&mut r).ok_or_else(damaged)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Lattice rectangles `(x0, y0, x1, y1)` (inclusive) and the tiles `(i, j)` they read.
    type Case<'a> = (&'a [(i64, i64, i64, i64)], &'a [(usize, usize)]);

    /// A `w` × `h` grid with nodata here and there, and classes when `variable`.
    fn grid(w: usize, h: usize) -> HeightGrid {
        let mut g = HeightGrid::all_valid(
            w,
            h,
            (0..w * h)
                .map(|k| (k * 7919 % 10007) as i32 - 5000)
                .collect(),
        );
        for k in (0..w * h).step_by(37) {
            g.valid[k] = false;
        }
        g
    }

    /// A write that fails leaves no temporary behind (a full disk would leave gigabytes): here
    /// the final name is taken by a directory, so the rename fails after every byte is written.
    #[test]
    fn a_failed_write_leaves_nothing_behind() {
        let dir = tempfile::tempdir().unwrap();
        fs::create_dir(dir.path().join(PREPARED)).unwrap();
        assert!(write_prepared(dir.path(), &grid(40, 30), None).is_err());
        assert!(crate::journal::write_atomically(dir.path(), PREPARED, b"x").is_err());
        let left: Vec<_> = fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(left, [std::ffi::OsString::from(PREPARED)], "{left:?}");
    }

    #[test]
    fn a_window_holds_the_tiles_under_its_rectangles_each_checked() {
        let dir = tempfile::tempdir().unwrap();
        let (w, h) = (2 * TILE + 17, TILE + 3);
        let g = grid(w, h);
        let classes = Resolution {
            class: (0..w * h)
                .map(|k| (k % 3) as u8)
                .collect::<Vec<u8>>()
                .into(),
        };
        for variable in [false, true] {
            let c = variable.then_some(&classes);
            write_prepared(dir.path(), &g, c).unwrap();
            let memory = TempStorage::Memory;
            let (all, all_c) = read_prepared(dir.path(), (w, h, variable), None, &memory).unwrap();
            assert!(all == g, "the whole grid reads back");
            assert_eq!(all_c.map(|r| r.class.to_vec()), c.map(|r| r.class.to_vec()));
            // Tile (2, 1) alone (the last column of tiles, 17 wide, in the last row, 3 high,
            // from a rectangle reaching past the grid); tiles (0, 0) and (1, 0) from a
            // rectangle across their edge; (1, 0) and (1, 1) from one from beyond the first row.
            let t = TILE as i64;
            let cases: [Case; 3] = [
                (&[(2 * t + 5, t + 1, 9 * t, 9 * t)], &[(2, 1)]),
                (&[(t - 1, 0, t, 0)], &[(0, 0), (1, 0)]),
                (&[(t + 3, -5, t + 4, t)], &[(1, 0), (1, 1)]),
            ];
            for (rects, tiles) in cases {
                let (part, _) =
                    read_prepared(dir.path(), (w, h, variable), Some(rects), &memory).unwrap();
                for y in 0..h {
                    for x in 0..w {
                        let k = y * w + x;
                        if tiles.contains(&(x / TILE, y / TILE)) {
                            assert_eq!((part.values[k], part.valid[k]), (g.values[k], g.valid[k]));
                        } else {
                            assert_eq!((part.values[k], part.valid[k]), (0, false), "({x}, {y})");
                        }
                    }
                }
            }
            // Nothing read: all nodata.
            let (none, _) =
                read_prepared(dir.path(), (w, h, variable), Some(&[]), &memory).unwrap();
            assert!(!none.valid.iter().any(|&v| v));
        }
        // A damaged tile is refused when read, naming it, and does not matter when not.
        let path = dir.path().join(PREPARED);
        write_prepared(dir.path(), &g, None).unwrap();
        let good = fs::read(&path).unwrap();
        let mut bytes = good.clone();
        let t = Tiling {
            width: w,
            height: h,
            bps: 5,
        };
        bytes[t.offset(1, 0) as usize + 3] ^= 1;
        fs::write(&path, &bytes).unwrap();
        let read = |rect: (i64, i64, i64, i64)| {
            read_prepared(
                dir.path(),
                (w, h, false),
                Some(&[rect]),
                &TempStorage::Memory,
            )
        };
        let e = read((TILE as i64, 0, TILE as i64, 0))
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("checksum mismatch in tile (1, 0)"), "{e}");
        assert!(read((0, TILE as i64, 10, TILE as i64)).is_ok());
        // Another size than the plan's, or a file cut short, is refused.
        let e = read_prepared(dir.path(), (w, h + 1, false), None, &TempStorage::Memory)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("does not match the plan"), "{e}");
        fs::write(&path, &good[..good.len() - 1]).unwrap();
        assert!(read((0, 0, 0, 0)).is_err());
    }

    #[test]
    fn a_summary_reads_back_and_a_damaged_one_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let id = |l, x, y| DiamondId::on_face(0, l, x, y);
        let s = GridSummary {
            max_abs: 1234,
            all_valid: false,
            nodata_mask: true,
            stored: vec![vec![id(0, 4, 4)], vec![id(1, 2, 4), id(1, 6, 4)]],
            recorded: Some(vec![vec![id(0, 4, 4)], vec![]]),
            root_field: vec![1, -2, 3, 4],
            roots: vec![9, 8, 7],
        };
        write_summary(dir.path(), &s).unwrap();
        assert_eq!(read_summary(dir.path()).unwrap(), s);
        let path = dir.path().join(SUMMARY);
        let mut bytes = fs::read(&path).unwrap();
        bytes[12] ^= 1;
        fs::write(&path, &bytes).unwrap();
        let e = read_summary(dir.path()).err().unwrap().to_string();
        assert!(e.contains("is damaged"), "{e}");
    }
}
