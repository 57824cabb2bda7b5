//! The square tiles of the prepared grid and their CRC-32s: read back from the array files,
//! or computed as the plan writes the rows ([`WrittenCrcs`]).

use std::fs;

use rayon::prelude::*;

use cbdam_codec::quant::HeightGrid;

use super::{ARRAYS, HEAD};
use crate::error::Result;

/// Side of a tile of `prepared`, samples: 320 KiB of a single-resolution grid.
pub(super) const TILE: usize = 256;
/// Tiles a worker checks at once, side by side in a band of tile rows: its buffers hold
/// `TILE` rows of this many tiles (12 MiB with classes).
pub(super) const TILES_AT_ONCE: usize = 32;
/// The square tiles of a `width` × `height` grid, row by row of tiles, each checksummed over
/// its rows of each array in turn.
#[derive(Clone, Copy)]
pub(super) struct Tiling {
    pub(super) width: usize,
    pub(super) height: usize,
    /// With the classes array.
    pub(super) classes: bool,
}

impl Tiling {
    pub(super) fn across(&self) -> usize {
        self.width.div_ceil(TILE)
    }
    pub(super) fn count(&self) -> usize {
        self.across() * self.height.div_ceil(TILE)
    }
    /// Tile `(i, j)`'s samples: columns `x0..x1`, rows `y0..y1`.
    pub(super) fn rect(&self, i: usize, j: usize) -> (usize, usize, usize, usize) {
        let (x0, y0) = (i * TILE, j * TILE);
        (
            x0,
            y0,
            (x0 + TILE).min(self.width),
            (y0 + TILE).min(self.height),
        )
    }
    /// The arrays: their file names and bytes a sample.
    pub(super) fn arrays(&self) -> &'static [(&'static str, usize)] {
        &ARRAYS[..2 + usize::from(self.classes)]
    }
    /// Length of the `prepared` file: the header, a CRC-32 a tile, and the CRC-32 of both.
    pub(super) fn file_len(&self) -> u64 {
        (HEAD + 4 * self.count() + 4) as u64
    }
}
/// The CRC-32 of each tile `wanted` (row by row of tiles; `None` for the others), read from
/// the array files `files` (heights, validity and classes, as `t.arrays()`), in parallel bands
/// of tiles. A validity byte other than 0 or 1 is an error naming its tile.
pub(super) fn tile_crcs(
    t: &Tiling,
    files: &[fs::File],
    wanted: &[bool],
) -> Result<Vec<Option<u32>>, String> {
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
pub(super) struct ArrayCrcs {
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

    pub(super) fn rows(
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
    pub(super) fn finish(&self, classes: bool) -> Option<Vec<u32>> {
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
