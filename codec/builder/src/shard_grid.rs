//! The files of a sharded build's work directory that hold the input: `prepared`, the quantized
//! grid — its arrays as the build made them (`prepared.values`, `prepared.valid`,
//! `prepared.classes`: the lattice's own mapped files, renamed into the work directory, so the
//! plan writes no second copy) and a header with a CRC-32 of each square tile of them, so that
//! a step checks only the tiles under the rectangles it encodes; and `summary`, what the
//! encoder's setup measured of the whole grid once in the plan (stored diamonds, roots,
//! bounds), so that no later step scans the whole grid again. Both are internal to the work
//! directory (not a repository format); a file of another layout version is refused.
//!
//! This file holds `prepared`; `tiles.rs` its tiling and CRCs, `summary.rs` the summary.

use std::fs;
use std::path::{Path, PathBuf};

use cbdam_codec::hierarchy::Resolution;
use cbdam_codec::quant::HeightGrid;
use cbdam_codec::temp::LatticeArray;

use crate::error::{Context, Result, bail};
use crate::journal::write_atomically;

mod summary;
#[cfg(test)]
mod tests;
mod tiles;

pub(crate) use summary::{read_summary, write_summary};
pub(crate) use tiles::WrittenCrcs;
use tiles::{TILE, Tiling, tile_crcs};

const PREPARED: &str = "prepared";
/// Magic bytes of the `prepared` file.
const PREPARED_MAGIC: &[u8; 4] = b"CBDP";
/// Version of these files' layout.
const VERSION: u32 = 3;
/// Bytes of the header of `prepared`: magic, version, width, height, classes flag, tile side.
const HEAD: usize = 29;

/// The arrays of the prepared grid, by file name, and their bytes a sample: heights (`i32`),
/// validity (`bool`: 0 or 1), classes (`u8`, with several inputs).
const ARRAYS: [(&str, usize); 3] = [
    ("prepared.values", 4),
    ("prepared.valid", 1),
    ("prepared.classes", 1),
];

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
