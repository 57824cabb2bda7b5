//! The files of a sharded build's work directory that hold the input: `prepared`, the quantized
//! grid — its arrays as the build made them (`prepared.values`, `prepared.valid`,
//! `prepared.classes`: the lattice's own mapped files, renamed into the work directory, so the
//! plan writes no second copy) and a header with a CRC-32 of each square tile of them, so that
//! a step checks only the tiles under the rectangles it encodes; and `summary`, what the
//! encoder's setup measured of the whole grid once in the plan (stored diamonds, roots,
//! bounds), so that no later step scans the whole grid again. Both are internal to the work
//! directory (not a repository format); a file of another layout version is refused.

use std::fs;
use std::path::{Path, PathBuf};

use rayon::prelude::*;

use cbdam_codec::geometry::DiamondId;
use cbdam_codec::hierarchy::{GridSummary, Resolution};
use cbdam_codec::quant::HeightGrid;
use cbdam_codec::temp::LatticeArray;

use crate::error::{Context, Result, bail};
use crate::journal::{Reader, write_atomically};

const PREPARED: &str = "prepared";
const SUMMARY: &str = "summary";
/// Magic bytes of the `prepared` file.
const PREPARED_MAGIC: &[u8; 4] = b"CBDP";
/// Magic bytes of the `summary` file.
const SUMMARY_MAGIC: &[u8; 4] = b"CBDS";
/// Version of these files' layout.
const VERSION: u32 = 3;
/// Side of a tile of `prepared`, samples: 320 KiB of a single-resolution grid.
const TILE: usize = 256;
/// Tiles a worker checks at once, side by side in a band of tile rows: its buffers hold
/// `TILE` rows of this many tiles (12 MiB with classes).
const TILES_AT_ONCE: usize = 32;
/// Bytes of the header of `prepared`: magic, version, width, height, classes flag, tile side.
const HEAD: usize = 29;

/// The arrays of the prepared grid, by file name, and their bytes a sample: heights (`i32`),
/// validity (`bool`: 0 or 1), classes (`u8`, with several inputs).
const ARRAYS: [(&str, usize); 3] = [
    ("prepared.values", 4),
    ("prepared.valid", 1),
    ("prepared.classes", 1),
];

/// The square tiles of a `width` × `height` grid, row by row of tiles, each checksummed over
/// its rows of each array in turn.
#[derive(Clone, Copy)]
struct Tiling {
    width: usize,
    height: usize,
    /// With the classes array.
    classes: bool,
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
    /// The arrays: their file names and bytes a sample.
    fn arrays(&self) -> &'static [(&'static str, usize)] {
        &ARRAYS[..2 + usize::from(self.classes)]
    }
    /// Length of the `prepared` file: the header, a CRC-32 a tile, and the CRC-32 of both.
    fn file_len(&self) -> u64 {
        (HEAD + 4 * self.count() + 4) as u64
    }
}

fn head(t: &Tiling) -> Vec<u8> {
    let mut head = Vec::with_capacity(HEAD);
    head.extend_from_slice(PREPARED_MAGIC);
    head.extend_from_slice(&VERSION.to_le_bytes());
    head.extend_from_slice(&(t.width as u64).to_le_bytes());
    head.extend_from_slice(&(t.height as u64).to_le_bytes());
    head.push(u8::from(t.classes));
    head.extend_from_slice(&(TILE as u32).to_le_bytes());
    head
}

/// Refuses a big-endian host: the arrays are the lattice's own files, in the host's byte order,
/// which the format fixes as little-endian.
fn little_endian() -> Result<()> {
    if cfg!(target_endian = "big") {
        bail!("sharded builds need a little-endian machine (their grid files are little-endian)");
    }
    Ok(())
}

/// The CRC-32 of each tile `wanted` (row by row of tiles; `None` for the others), read from
/// the array files `files` (heights, validity and classes, as `t.arrays()`), in parallel bands
/// of tiles. A validity byte other than 0 or 1 is an error naming its tile.
fn tile_crcs(t: &Tiling, files: &[fs::File], wanted: &[bool]) -> Result<Vec<Option<u32>>, String> {
    use std::os::unix::fs::FileExt;
    // Runs of up to `TILES_AT_ONCE` wanted tiles in a row of tiles: (j, i0, i1).
    let mut runs = Vec::new();
    for j in 0..t.height.div_ceil(TILE) {
        let mut i = 0;
        while i < t.across() {
            if !wanted[j * t.across() + i] {
                i += 1;
                continue;
            }
            let i0 = i;
            while i < t.across() && i - i0 < TILES_AT_ONCE && wanted[j * t.across() + i] {
                i += 1;
            }
            runs.push((j, i0, i));
        }
    }
    let crcs = runs
        .par_iter()
        .map_init(Vec::new, |buf: &mut Vec<u8>, &(j, i0, i1)| {
            let (x0, y0, _, y1) = t.rect(i0, j);
            let x1 = t.rect(i1 - 1, j).2;
            let (w, rows) = (x1 - x0, y1 - y0);
            let mut hashers = vec![crc32fast::Hasher::new(); i1 - i0];
            for (a, (&(name, bps), file)) in t.arrays().iter().zip(files).enumerate() {
                buf.resize(bps * w * rows, 0);
                for (r, y) in (y0..y1).enumerate() {
                    let at = (bps * (y * t.width + x0)) as u64;
                    file.read_exact_at(&mut buf[bps * w * r..bps * w * (r + 1)], at)
                        .map_err(|e| format!("reading {name}: {e}"))?;
                }
                if a == 1
                    && let Some(p) = buf.iter().position(|&b| b > 1)
                {
                    let x = x0 + p % w;
                    return Err(format!(
                        "a validity byte {} in tile ({}, {j})",
                        buf[p],
                        x / TILE
                    ));
                }
                for (k, hasher) in hashers.iter_mut().enumerate() {
                    let (tx0, _, tx1, _) = t.rect(i0 + k, j);
                    for r in 0..rows {
                        let row = bps * (w * r + tx0 - x0)..bps * (w * r + tx1 - x0);
                        hasher.update(&buf[row]);
                    }
                }
            }
            Ok(hashers
                .into_iter()
                .map(|h| h.finalize())
                .collect::<Vec<_>>())
        })
        .collect::<Result<Vec<_>, String>>()?;
    let mut out = vec![None; t.count()];
    for (&(j, i0, _), run) in runs.iter().zip(crcs) {
        for (k, crc) in run.into_iter().enumerate() {
            out[j * t.across() + i0 + k] = Some(crc);
        }
    }
    Ok(out)
}

/// The tiles' CRC-32s computed as the plan writes the arrays, block of rows by block of rows
/// in order, while the rows are still in memory — so the plan does not read the whole grid
/// back (at 4.3 G samples the lattice is larger than the page cache). Each
/// array is hashed on its own; [`crc32fast::Hasher::combine`] joins a tile's three into its
/// CRC over its heights, validity and classes in turn, as [`tile_crcs`] reads it. Rows from
/// row 0 again (a second quantizer pass) start that array over; rows out of order or of
/// another grid make it give nothing, and [`write_prepared`] reads the grid instead.
#[derive(Default)]
pub(crate) struct WrittenCrcs {
    /// Width and height of the grid, from the first rows seen.
    size: Option<(usize, usize)>,
    /// Heights, validity, classes.
    arrays: [ArrayCrcs; 3],
    /// Rows came out of order, or of another size.
    broken: bool,
}

#[derive(Default)]
struct ArrayCrcs {
    /// The next row expected.
    next_row: usize,
    /// Each tile's hasher, by column of tiles, then row of tiles.
    columns: Vec<Vec<crc32fast::Hasher>>,
}

impl WrittenCrcs {
    /// Rows `rows` of the heights and validity of `grid`, just written.
    pub(crate) fn grid_rows(&mut self, grid: &HeightGrid, rows: std::ops::Range<usize>) {
        let (w, h) = (grid.width, grid.height);
        let span = rows.start * w..rows.end * w;
        self.rows(
            0,
            (w, h),
            bytemuck::cast_slice(&grid.values[span.clone()]),
            rows.clone(),
        );
        self.rows(1, (w, h), bytemuck::cast_slice(&grid.valid[span]), rows);
    }

    /// Rows `rows` of the resolution classes of a `width` × `height` grid, just written.
    pub(crate) fn class_rows(
        &mut self,
        (width, height): (usize, usize),
        class: &[u8],
        rows: std::ops::Range<usize>,
    ) {
        self.rows(2, (width, height), class, rows);
    }

    fn rows(
        &mut self,
        array: usize,
        size: (usize, usize),
        bytes: &[u8],
        rows: std::ops::Range<usize>,
    ) {
        if *self.size.get_or_insert(size) != size {
            self.broken = true;
        }
        let (w, h) = size;
        let bps = ARRAYS[array].1;
        let a = &mut self.arrays[array];
        if rows.start == 0 {
            a.next_row = 0;
            a.columns = vec![vec![crc32fast::Hasher::new(); h.div_ceil(TILE)]; w.div_ceil(TILE)];
        }
        if self.broken || rows.start != a.next_row || bytes.len() != bps * w * rows.len() {
            self.broken = true;
            return;
        }
        a.columns
            .par_iter_mut()
            .enumerate()
            .for_each(|(i, column)| {
                let (x0, x1) = (i * TILE, ((i + 1) * TILE).min(w));
                for (r, y) in rows.clone().enumerate() {
                    column[y / TILE].update(&bytes[bps * (r * w + x0)..bps * (r * w + x1)]);
                }
            });
        a.next_row = rows.end;
    }

    /// Each tile's CRC-32 (row by row of tiles), when every row of the heights, the validity
    /// and (with `classes`) the classes was seen in order.
    fn finish(&self, classes: bool) -> Option<Vec<u32>> {
        let (w, h) = self.size?;
        let arrays = &self.arrays[..2 + usize::from(classes)];
        if self.broken || arrays.iter().any(|a| a.next_row != h) {
            return None;
        }
        let t = Tiling {
            width: w,
            height: h,
            classes,
        };
        let mut out = Vec::with_capacity(t.count());
        for j in 0..h.div_ceil(TILE) {
            for i in 0..t.across() {
                let mut tile = arrays[0].columns[i][j].clone();
                for a in &arrays[1..] {
                    tile.combine(&a.columns[i][j]);
                }
                out.push(tile.finalize());
            }
        }
        Some(out)
    }
}

/// Makes the grid (and classes) the work directory's prepared grid: each array given its file
/// there ([`LatticeArray::persist`]: a mapped array of the lattice, made in `work`, is renamed,
/// not copied), then `work/prepared` written: the header, each tile's CRC-32 (over its rows of
/// heights, of validity and of classes in turn) and a CRC-32 of the header and that table;
/// little-endian, under a temporary name and renamed, last. The CRCs are `written`'s where it
/// saw every row written, else read from the files. The grid stays usable.
pub(crate) fn write_prepared(
    work: &Path,
    grid: &mut HeightGrid,
    classes: Option<&mut Resolution>,
    written: Option<&WrittenCrcs>,
) -> Result<()> {
    little_endian()?;
    let t = Tiling {
        width: grid.width,
        height: grid.height,
        classes: classes.is_some(),
    };
    let path = |name: &str| work.join(name);
    let context = |name: &'static str| move || format!("writing {}", work.join(name).display());
    grid.values
        .persist(&path(ARRAYS[0].0))
        .with_context(context(ARRAYS[0].0))?;
    grid.valid
        .persist(&path(ARRAYS[1].0))
        .with_context(context(ARRAYS[1].0))?;
    if let Some(c) = classes {
        c.class
            .persist(&path(ARRAYS[2].0))
            .with_context(context(ARRAYS[2].0))?;
    }
    let files = t
        .arrays()
        .iter()
        .map(|(name, _)| fs::File::open(path(name)).with_context(context(name)))
        .collect::<Result<Vec<_>>>()?;
    let read = || {
        tile_crcs(&t, &files, &vec![true; t.count()])
            .map(|crcs| crcs.into_iter().map(|c| c.expect("every tile")).collect())
            .map_err(|e| crate::BuildError::Invalid(format!("checksumming the prepared grid: {e}")))
    };
    let crcs: Vec<u32> = match written.and_then(|w| w.finish(t.classes)) {
        Some(crcs) => {
            // Tests (debug builds) check the streamed CRCs against the files themselves.
            debug_assert!(
                crcs == read()?,
                "CRCs of the rows written differ from the files'"
            );
            crcs
        }
        None => read()?,
    };
    let head = head(&t);
    let mut out = head.clone();
    crcs.iter()
        .for_each(|c| out.extend_from_slice(&c.to_le_bytes()));
    let crc = crc32fast::hash(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    write_atomically(work, PREPARED, &out).with_context(context(PREPARED))?;
    Ok(())
}

/// The prepared grid of a work directory, mapped ([`read_prepared`]), and the check of its
/// tiles against their CRCs, made as the caller comes to them ([`TileCheck::check`]).
pub(crate) struct PreparedGrid {
    /// Heights and validity.
    pub(crate) grid: HeightGrid,
    /// Resolution classes, with several inputs.
    pub(crate) classes: Option<Resolution>,
    /// What checks the tiles.
    pub(crate) tiles: TileCheck,
}

/// The check of a prepared grid's tiles ([`TileCheck::check`]).
pub(crate) struct TileCheck {
    /// `work/prepared`, for errors.
    path: PathBuf,
    tiling: Tiling,
    /// The array files, as `tiling.arrays()`.
    files: Vec<fs::File>,
    /// The CRC-32 table of `prepared`: 4 bytes a tile.
    table: Vec<u8>,
    /// Tiles checked so far.
    checked: Vec<bool>,
}

impl TileCheck {
    /// Checks every tile under `rects` (lattice rectangles `(x0, y0, x1, y1)`, inclusive,
    /// clipped to the grid; `None`: all of them) not checked yet against its CRC. A shard checks
    /// each block's field just before encoding it, so the encoder reads tiles the check has
    /// just brought into the page cache rather than reading the grid from disk twice.
    pub(crate) fn check(&mut self, rects: Option<&[(i64, i64, i64, i64)]>) -> Result<()> {
        let t = self.tiling;
        let mut wanted = vec![rects.is_none(); t.count()];
        for &(x0, y0, x1, y1) in rects.unwrap_or(&[]) {
            let clip = |a: i64, len: usize| a.clamp(0, len as i64 - 1) as usize / TILE;
            if x0 > x1 || y0 > y1 || x1 < 0 || y1 < 0 {
                continue;
            }
            for j in clip(y0, t.height)..=clip(y1, t.height) {
                for i in clip(x0, t.width)..=clip(x1, t.width) {
                    wanted[j * t.across() + i] = true;
                }
            }
        }
        for (w, &done) in wanted.iter_mut().zip(&self.checked) {
            *w &= !done;
        }
        let crcs = tile_crcs(&t, &self.files, &wanted).map_err(|e| damaged(&self.path, &e))?;
        for (k, crc) in crcs.iter().enumerate() {
            let Some(crc) = crc else { continue };
            if crc.to_le_bytes() != self.table[4 * k..4 * k + 4] {
                let (i, j) = (k % t.across(), k / t.across());
                return Err(damaged(
                    &self.path,
                    &format!("checksum mismatch in tile ({i}, {j})"),
                ));
            }
            self.checked[k] = true;
        }
        Ok(())
    }
}

fn damaged(file: &Path, why: &str) -> crate::BuildError {
    crate::BuildError::Invalid(format!(
        "{} is damaged ({why}); plan again in a new work directory",
        file.display()
    ))
}

/// The grid (and classes) of `work/prepared`, `width` × `height` with classes when `variable`
/// (as the plan says): its header checked and its array files mapped, not read; no tile is
/// checked yet ([`TileCheck::check`]). The caller reads only tiles it has checked, through
/// [`LatticeArray::window`] or [`LatticeArray::strided`] (which read the files, not the
/// mapping): nothing else of the grid is read or held in memory.
pub(crate) fn read_prepared(
    work: &Path,
    (width, height, variable): (usize, usize, bool),
) -> Result<PreparedGrid> {
    little_endian()?;
    let path = work.join(PREPARED);
    let header = fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
    let t = Tiling {
        width,
        height,
        classes: variable,
    };
    if header.len() < HEAD
        || &header[..4] != PREPARED_MAGIC
        || header[4..8] != VERSION.to_le_bytes()
    {
        return Err(damaged(&path, "not a prepared grid of this cbdam version"));
    }
    if header[..HEAD] != head(&t)[..] {
        return Err(damaged(&path, "its size does not match the plan"));
    }
    if header.len() as u64 != t.file_len() {
        return Err(damaged(&path, "its length does not match its size"));
    }
    let (body, stored) = header.split_at(header.len() - 4);
    if crc32fast::hash(body).to_le_bytes() != stored {
        return Err(damaged(&path, "checksum mismatch in its header"));
    }
    let table = body[HEAD..].to_vec();
    let count = width * height;
    let mut files = Vec::new();
    for &(name, bps) in t.arrays() {
        let p: PathBuf = work.join(name);
        let file = fs::File::open(&p).with_context(|| format!("reading {}", p.display()))?;
        let len = file
            .metadata()
            .with_context(|| format!("reading {}", p.display()))?
            .len();
        if len != (bps * count) as u64 {
            return Err(damaged(&p, "its length does not match the grid's size"));
        }
        files.push(file);
    }
    let mapping = |e: cbdam_codec::CodecError| damaged(&path, &format!("mapping its arrays: {e}"));
    let map_copy = |f: &fs::File| {
        f.try_clone()
            .with_context(|| format!("reading {}", path.display()))
    };
    // SAFETY: the files are the work directory's, written once by the plan before `prepared`
    // and never changed after it; the arrays are read only through `window` and `strided`
    // (the caller's contract, above), which read the files and make every validity byte a
    // valid `bool`, and only under the tiles checked.
    let (values, valid, class) = unsafe {
        (
            LatticeArray::map_file(map_copy(&files[0])?, count).map_err(mapping)?,
            LatticeArray::map_file(map_copy(&files[1])?, count).map_err(mapping)?,
            match variable {
                true => Some(LatticeArray::map_file(map_copy(&files[2])?, count).map_err(mapping)?),
                false => None,
            },
        )
    };
    Ok(PreparedGrid {
        grid: HeightGrid {
            width,
            height,
            values,
            valid,
        },
        classes: class.map(|class| Resolution { class }),
        tiles: TileCheck {
            path,
            tiling: t,
            files,
            table,
            checked: vec![false; t.count()],
        },
    })
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
    use cbdam_codec::temp::TempStorage;

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

    /// The prepared grid of `dir` with the tiles under `rects` checked.
    fn read(
        dir: &Path,
        dims: (usize, usize, bool),
        rects: Option<&[(i64, i64, i64, i64)]>,
    ) -> Result<(HeightGrid, Option<Resolution>)> {
        let mut p = read_prepared(dir, dims)?;
        p.tiles.check(rects)?;
        Ok((p.grid, p.classes))
    }

    /// The names in `dir`, sorted.
    fn names(dir: &Path) -> Vec<String> {
        let mut n: Vec<String> = fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        n.sort();
        n
    }

    /// A write that fails leaves no temporary behind (a full disk would leave gigabytes), from
    /// a grid in memory (written out) and from one in named mapped files in the work directory
    /// (renamed), once the grid is dropped: here the final name of the heights is taken by a
    /// directory.
    #[test]
    fn a_failed_write_leaves_nothing_behind() {
        for named in [false, true] {
            let dir = tempfile::tempdir().unwrap();
            fs::create_dir(dir.path().join(ARRAYS[0].0)).unwrap();
            let mut g = grid(40, 30);
            if named {
                g = g
                    .copied_to(&TempStorage::Named(dir.path().to_path_buf()))
                    .unwrap();
            }
            assert!(write_prepared(dir.path(), &mut g, None, None).is_err());
            // The arrays not yet renamed are the grid's own files until it is dropped.
            drop(g);
            assert_eq!(names(dir.path()), [ARRAYS[0].0], "named: {named}");
        }
        let dir = tempfile::tempdir().unwrap();
        fs::create_dir(dir.path().join(PREPARED)).unwrap();
        assert!(crate::journal::write_atomically(dir.path(), PREPARED, b"x").is_err());
        assert_eq!(names(dir.path()), [PREPARED]);
    }

    /// The grid reads back whole; a step checks only the tiles under its rectangles and reads
    /// their points; a grid made in named mapped files is renamed into the work directory.
    #[test]
    fn a_step_checks_the_tiles_under_its_rectangles_and_reads_them() {
        let dir = tempfile::tempdir().unwrap();
        let (w, h) = (2 * TILE + 17, TILE + 3);
        let g = grid(w, h);
        let classes = Resolution {
            class: (0..w * h)
                .map(|k| (k % 3) as u8)
                .collect::<Vec<u8>>()
                .into(),
        };
        for (variable, named) in [(false, false), (true, false), (true, true)] {
            let named_in = TempStorage::Named(dir.path().to_path_buf());
            let (mut g, mut c) = (g.clone(), classes.clone());
            if named {
                g = g.copied_to(&named_in).unwrap();
                c.class = c.class.copied_to(&named_in).unwrap();
            }
            let c = variable.then_some(&mut c);
            write_prepared(dir.path(), &mut g, c, None).unwrap();
            let mut want = vec![PREPARED, ARRAYS[0].0, ARRAYS[1].0];
            if variable {
                want.push(ARRAYS[2].0);
            }
            want.sort();
            assert_eq!(
                names(dir.path()),
                want,
                "variable {variable}, named {named}"
            );
            let (all, all_c) = read(dir.path(), (w, h, variable), None).unwrap();
            assert!(all == g, "the whole grid reads back");
            assert_eq!(
                all_c.map(|r| r.class.to_vec()),
                variable.then(|| classes.class.to_vec())
            );
            let t = TILE as i64;
            for rect in [(2 * t + 5, t + 1, 9 * t, 9 * t), (t - 1, -5, t + 4, t)] {
                let (part, part_c) = read(dir.path(), (w, h, variable), Some(&[rect])).unwrap();
                let values = part.values.window(w, rect).unwrap();
                let valid = part.valid.window(w, rect).unwrap();
                let (x0, y0) = (rect.0.max(0) as usize, rect.1.max(0) as usize);
                let (x1, y1) = ((rect.2 as usize).min(w - 1), (rect.3 as usize).min(h - 1));
                for y in y0..=y1 {
                    for x in x0..=x1 {
                        let k = y * w + x;
                        assert_eq!((values[k], valid[k]), (g.values[k], g.valid[k]));
                    }
                }
                if let Some(pc) = part_c {
                    assert_eq!(
                        pc.class.window(w, rect).unwrap()[y1 * w + x1],
                        classes.class[y1 * w + x1]
                    );
                }
            }
        }
    }

    /// A damaged tile is refused when a step's rectangles cover it, naming it, and does not
    /// matter when they do not; so is a validity byte other than 0 or 1 (which a `bool` cannot
    /// hold); another size than the plan's, or an array cut short, is refused.
    #[test]
    fn damaged_tiles_and_files_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let (w, h) = (2 * TILE + 17, TILE + 3);
        write_prepared(dir.path(), &mut grid(w, h), None, None).unwrap();
        let read = |rect: (i64, i64, i64, i64)| {
            super::tests::read(dir.path(), (w, h, false), Some(&[rect])).map(|_| ())
        };
        let t = TILE as i64;
        let damage = |name: &str, at: usize, byte: Option<u8>| {
            let path = dir.path().join(name);
            let good = fs::read(&path).unwrap();
            let mut bytes = good.clone();
            bytes[at] = byte.unwrap_or(bytes[at] ^ 1);
            fs::write(&path, &bytes).unwrap();
            good
        };
        // Heights of point (TILE + 3, 0): tile (1, 0).
        let good = damage(ARRAYS[0].0, 4 * (TILE + 3), None);
        let e = read((t, 0, t, 0)).unwrap_err().to_string();
        assert!(e.contains("checksum mismatch in tile (1, 0)"), "{e}");
        assert!(read((0, t, 10, t)).is_ok());
        fs::write(dir.path().join(ARRAYS[0].0), &good).unwrap();
        // Validity of point (2 TILE + 1, TILE + 2): tile (2, 1).
        let good = damage(ARRAYS[1].0, (TILE + 2) * w + 2 * TILE + 1, Some(2));
        let e = read((2 * t, t, 2 * t, t)).unwrap_err().to_string();
        assert!(e.contains("a validity byte 2 in tile (2, 1)"), "{e}");
        assert!(read((0, 0, t, t)).is_ok());
        fs::write(dir.path().join(ARRAYS[1].0), &good).unwrap();
        assert!(read((0, 0, 3 * t, 2 * t)).is_ok());
        let e = read_prepared(dir.path(), (w, h + 1, false))
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("does not match the plan"), "{e}");
        let path = dir.path().join(ARRAYS[1].0);
        fs::write(&path, &good[..good.len() - 1]).unwrap();
        let e = read((0, 0, 0, 0)).unwrap_err().to_string();
        assert!(e.contains("prepared.valid") && e.contains("length"), "{e}");
        let header = dir.path().join(PREPARED);
        let mut bytes = fs::read(&header).unwrap();
        bytes[HEAD + 1] ^= 1;
        fs::write(&header, &bytes).unwrap();
        let e = read((0, 0, 0, 0)).unwrap_err().to_string();
        assert!(e.contains("checksum mismatch in its header"), "{e}");
    }

    /// The CRCs computed from the rows as they are written, in blocks of any size, equal
    /// those read from the files (a grid a few tiles wide with a ragged last tile, with and
    /// without classes); a second pass from row 0 starts over; rows out of order, missing or
    /// of another size give none, so the files are read instead.
    #[test]
    fn crcs_of_the_rows_written_equal_the_files_ones() {
        let (w, h) = (2 * TILE + 17, 2 * TILE + 3);
        let g = grid(w, h);
        let class: Vec<u8> = (0..w * h).map(|k| (k * 31 % 7) as u8).collect();
        let t = |classes| Tiling {
            width: w,
            height: h,
            classes,
        };
        let dir = tempfile::tempdir().unwrap();
        let files = |classes: bool| {
            let mut paths = vec![ARRAYS[0].0, ARRAYS[1].0];
            fs::write(
                dir.path().join(ARRAYS[0].0),
                bytemuck::cast_slice(&g.values[..]),
            )
            .unwrap();
            fs::write(
                dir.path().join(ARRAYS[1].0),
                bytemuck::cast_slice(&g.valid[..]),
            )
            .unwrap();
            if classes {
                fs::write(dir.path().join(ARRAYS[2].0), &class).unwrap();
                paths.push(ARRAYS[2].0);
            }
            paths
                .iter()
                .map(|p| fs::File::open(dir.path().join(p)).unwrap())
                .collect::<Vec<_>>()
        };
        let feed = |c: &mut WrittenCrcs, block: usize, rows: std::ops::Range<usize>| {
            for y in rows.clone().step_by(block) {
                let ys = y..(y + block).min(rows.end);
                c.class_rows((w, h), &class[ys.start * w..ys.end * w], ys.clone());
                c.grid_rows(&g, ys);
            }
        };
        for classes in [false, true] {
            let want: Vec<u32> = tile_crcs(
                &t(classes),
                &files(classes),
                &vec![true; t(classes).count()],
            )
            .unwrap()
            .into_iter()
            .map(Option::unwrap)
            .collect();
            for block in [1, 7, TILE, 300, h] {
                let mut c = WrittenCrcs::default();
                feed(&mut c, block, 0..h);
                assert_eq!(
                    c.finish(classes).as_ref(),
                    Some(&want),
                    "blocks of {block} rows"
                );
            }
            let mut again = WrittenCrcs::default();
            feed(&mut again, 50, 0..100);
            feed(&mut again, 64, 0..h);
            assert_eq!(again.finish(classes), Some(want.clone()), "a second pass");
        }
        let mut short = WrittenCrcs::default();
        feed(&mut short, 64, 0..h - 1);
        assert_eq!(short.finish(false), None, "a row missing");
        let mut skipped = WrittenCrcs::default();
        feed(&mut skipped, 64, 0..64);
        feed(&mut skipped, 64, 128..h);
        assert_eq!(skipped.finish(false), None, "rows skipped");
        let mut other = WrittenCrcs::default();
        feed(&mut other, 64, 0..h);
        other.class_rows((w + 1, h), &vec![0; w + 1], 0..1);
        assert_eq!(other.finish(true), None, "rows of another size");
        let mut no_classes = WrittenCrcs::default();
        for y in 0..h {
            no_classes.grid_rows(&g, y..y + 1);
        }
        assert_eq!(no_classes.finish(true), None, "classes never written");
        assert!(no_classes.finish(false).is_some());
    }

    /// Tiles are checked as a step comes to them: a damaged tile is found only by the check
    /// that covers it, and a tile is read once however many checks cover it.
    #[test]
    fn tiles_are_checked_when_a_step_comes_to_them() {
        let dir = tempfile::tempdir().unwrap();
        let (w, h) = (3 * TILE, 2 * TILE);
        write_prepared(dir.path(), &mut grid(w, h), None, None).unwrap();
        let t = TILE as i64;
        let mut p = read_prepared(dir.path(), (w, h, false)).unwrap();
        p.tiles.check(Some(&[(0, 0, t - 1, t - 1)])).unwrap();
        // Damage tile (0, 0), already checked, and tile (2, 1), not yet.
        let path = dir.path().join(ARRAYS[0].0);
        let mut bytes = fs::read(&path).unwrap();
        bytes[0] ^= 1;
        bytes[4 * ((TILE + 1) * w + 2 * TILE + 1)] ^= 1;
        fs::write(&path, &bytes).unwrap();
        p.tiles.check(Some(&[(0, 0, 2 * t - 1, t - 1)])).unwrap();
        let e = p
            .tiles
            .check(Some(&[(2 * t, t, 2 * t, t)]))
            .unwrap_err()
            .to_string();
        assert!(e.contains("checksum mismatch in tile (2, 1)"), "{e}");
        let e = read(dir.path(), (w, h, false), None)
            .unwrap_err()
            .to_string();
        assert!(e.contains("checksum mismatch in tile (0, 0)"), "{e}");
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
