//! The whole-repository decode of one [`LevelGrid`]: every record walked once, level by level and
//! in parallel ([`walk_all_batches`]), each batch of the level's diamonds written into the
//! window's raster in parallel over disjoint bands of its rows. What `cbdam extract` writes and
//! the Python package's whole-array `read` returns (one owner for both).

use rayon::prelude::*;

use super::LevelGrid;
use crate::CodecError;
use crate::geometry::GridMap;
use crate::hierarchy::{ChildHalf, Encoded, Visit, walk_all_batches, walk_child_halves};

impl LevelGrid {
    /// Decodes `encoded` and returns the samples' heights (`to_sample` of a height in units),
    /// row by row; `fill` where no decoded diamond has data. See [`LevelGrid::decode_into`].
    pub fn decode<T: Copy + Send + Sync>(
        &self,
        encoded: &Encoded,
        fill: T,
        to_sample: impl Fn(i32) -> T + Sync,
    ) -> Result<Vec<T>, CodecError> {
        // The size comes from a header: a crafted file may declare terabytes, so ask, don't abort.
        let len = self.width.checked_mul(self.height);
        let mut values = Vec::new();
        len.and_then(|len| values.try_reserve_exact(len).ok())
            .ok_or_else(|| {
                CodecError::limit(format!(
                    "cannot hold {}×{} samples in memory",
                    self.width, self.height
                ))
            })?;
        // Filled in parallel: the first touch of hundreds of megabytes of pages.
        values.par_extend(rayon::iter::repeat_n(fill, self.width * self.height));
        self.decode_into(encoded, to_sample, &mut values)?;
        Ok(values)
    }

    /// Decodes `encoded` into `values` (`width × height`, row-major, row 0 north), writing
    /// `to_sample` of each height the level's diamonds hold there and leaving the other samples
    /// as they are.
    ///
    /// Points no decoded diamond covers lie in parts of the data rectangle with no valid sample
    /// nearby (the encoder stores only diamonds that meet one), and the repository's nodata mask
    /// marks the others that had no data: both are left. In a variable-resolution repository,
    /// levels finer than the data at a place are not reached there either (every level's leaves
    /// are visited, so a coarse input's level is read whole).
    pub fn decode_into<T: Copy + Send + Sync>(
        &self,
        encoded: &Encoded,
        to_sample: impl Fn(i32) -> T + Sync,
        values: &mut [T],
    ) -> Result<(), CodecError> {
        if encoded.params.domain.cube().is_some() {
            return Err(CodecError::invalid(
                "this hierarchy is a cube-sphere: a planar level grid does not hold its faces",
            ));
        }
        if Some(values.len()) != self.width.checked_mul(self.height) {
            return Err(CodecError::invalid(format!(
                "{} samples given for a {}×{} grid",
                values.len(),
                self.width,
                self.height
            )));
        }
        let layout = encoded.params.layout();
        let n = layout.n();
        if self.level == layout.finest_level() && self.level > 0 && !encoded.params.nodata_mask {
            // Straight from the level above's refinements: no grid of this level is gathered.
            return walk_child_halves(encoded, self.level - 1, |halves| {
                let halves: Vec<(GridMap, &ChildHalf<'_>)> =
                    halves.iter().map(|h| (layout.grid(h.child), h)).collect();
                self.put_batch(&halves, n, values, |g, h, rows, band| {
                    self.put_half(g, n, h, &to_sample, rows, band)
                });
            });
        }
        walk_all_batches(encoded, |batch| {
            let grids: Vec<(GridMap, &Visit<'_>)> = batch
                .iter()
                .filter(|v| v.id.level == self.level)
                .map(|v| (layout.grid(v.id), v))
                .collect();
            self.put_batch(&grids, n, values, |g, v, rows, band| {
                self.put_grid(g, n, v, &to_sample, rows, band)
            });
        })
    }

    /// Writes a batch of even-level grids (or parts of them: `put` writes one item's samples on
    /// the given raster rows into the band of those rows) into `values`, the window's raster, in
    /// parallel over disjoint bands of the raster rows the batch covers: each band takes the
    /// batch's items in the walk's order, so every sample ends as the serial walk leaves it.
    fn put_batch<T: Send, I: Sync>(
        &self,
        grids: &[(GridMap, I)],
        n: usize,
        values: &mut [T],
        put: impl Fn(&GridMap, &I, std::ops::Range<usize>, &mut [T]) + Sync,
    ) {
        // The rows the batch covers: an even-level grid's lines run along the raster's rows.
        let rows = grids.iter().filter_map(|(g, _)| self.rows_of(g, n));
        let (Some(first), Some(last)) = (
            rows.clone().map(|r| r.start).min(),
            rows.map(|r| r.end).max(),
        ) else {
            return;
        };
        let workers = rayon::current_num_threads();
        let put_rows = |band: &mut [T], start: usize| {
            let band_rows = start..start + band.len() / self.width;
            for (g, v) in grids {
                put(g, v, band_rows.clone(), band);
            }
        };
        let values = &mut values[first * self.width..last * self.width];
        if workers <= 1 {
            return put_rows(values, first);
        }
        let band_rows = (last - first).div_ceil(BANDS_PER_WORKER * workers);
        values
            .par_chunks_mut(band_rows * self.width)
            .enumerate()
            .for_each(|(b, band)| put_rows(band, first + b * band_rows));
    }

    /// The raster rows an even-level grid has samples on, `None` when none is in the window.
    fn rows_of(&self, g: &GridMap, n: usize) -> Option<std::ops::Range<usize>> {
        let across = if g.u.1 == 0 { g.v } else { g.u };
        let last = (g.origin.0, g.origin.1 + (n as i64 - 1) * across.1);
        let (lo, hi) = (
            g.origin.1.min(last.1).max(self.y0),
            g.origin.1.max(last.1).min(self.y1),
        );
        (lo <= hi).then(|| {
            let row = |y: i64| ((y - self.y0).div_euclid(self.step)) as usize;
            row(lo)..row(hi) + 1
        })
    }

    /// Writes the heights of one even-level `n × n` grid (`v`: the grid and its validity) that
    /// fall on raster rows `rows` into `band`, those rows of the window's raster. An even-level
    /// grid's lines are lines of the raster, along x or along y; each raster row the grid covers
    /// is written as one run, reading the grid down its columns when its lines run along y (the
    /// grid is small and stays in cache; the raster's rows are far apart).
    fn put_grid<T: Copy>(
        &self,
        g: &GridMap,
        n: usize,
        v: &Visit<'_>,
        to_sample: &impl Fn(i32) -> T,
        rows: std::ops::Range<usize>,
        band: &mut [T],
    ) {
        let (grid, valid) = (v.grid, v.valid);
        // `along` steps along a raster row: one sample of a line; `across` from line to line.
        let (along, across, sample_stride, line_stride) = if g.u.1 == 0 {
            (g.u, g.v, 1, n)
        } else {
            (g.v, g.u, n, 1)
        };
        debug_assert!(
            along.1 == 0 && across.0 == 0,
            "even-level grids are axis-aligned"
        );
        let dk = along.0 / self.step;
        // The samples of a line inside the window's columns: the same for every line (the lines
        // are parallel and start at the same x). Then the lines on the band's rows (which are
        // inside the window's).
        let anywhere = (i64::MIN, i64::MAX);
        let Some(columns) = clip_line(g.origin, along, n, (self.x0, self.x1), anywhere) else {
            return;
        };
        let band_y = (
            self.y0 + rows.start as i64 * self.step,
            self.y0 + (rows.end as i64 - 1) * self.step,
        );
        let Some(lines) = clip_line(g.origin, across, n, anywhere, band_y) else {
            return;
        };
        let (x, y) = (
            g.origin.0 + columns.start * along.0,
            g.origin.1 + lines.start * across.1,
        );
        // Even-level grids sit on multiples of their own spacing, which is `step`.
        debug_assert!((x - self.x0) % self.step == 0 && (y - self.y0) % self.step == 0);
        let row = ((y - self.y0) / self.step) as usize - rows.start;
        // The first sample of each line in `band`, line after line.
        let mut line_start = (row * self.width) as i64 + (x - self.x0) / self.step;
        let next_line = across.1 / self.step * self.width as i64;
        let count = (columns.end - columns.start) as usize;
        for line in lines.start as usize..lines.end as usize {
            let first = line * line_stride + columns.start as usize * sample_stride;
            let mut k = line_start;
            line_start += next_line;
            if valid.is_none() && dk == 1 && sample_stride == 1 {
                // The common case: a run of the raster row from a run of the grid, no mask.
                let out = &mut band[k as usize..][..count];
                for (o, &h) in out.iter_mut().zip(&grid[first..][..count]) {
                    *o = to_sample(h);
                }
                continue;
            }
            for s in 0..count {
                let i = first + s * sample_stride;
                if valid.is_none_or(|v| v[i]) {
                    band[k as usize] = to_sample(grid[i]);
                }
                k += dk;
            }
        }
    }
}

impl LevelGrid {
    /// Writes the points of one child half `h` ([`ChildHalf`]: part of the even-level `n × n`
    /// grid `g`) that fall on raster rows `rows` into `band`, those rows of the window's raster,
    /// as [`LevelGrid::put_grid`] writes a whole grid without a mask: each row of the half is one
    /// run of a raster row, read from the parent's refinement along one of its diagonals.
    fn put_half<T: Copy>(
        &self,
        g: &GridMap,
        n: usize,
        h: &ChildHalf<'_>,
        to_sample: &impl Fn(i32) -> T,
        rows: std::ops::Range<usize>,
        band: &mut [T],
    ) {
        // A planar even-level grid's rows run along the raster's rows, one sample apart
        // (`Layout::grid`: u = (step, 0), v = (0, step)).
        debug_assert!(g.u == (self.step, 0) && g.v == (0, self.step));
        let anywhere = (i64::MIN, i64::MAX);
        let Some(columns) = clip_line(g.origin, g.u, n, (self.x0, self.x1), anywhere) else {
            return;
        };
        let band_y = (
            self.y0 + rows.start as i64 * self.step,
            self.y0 + (rows.end as i64 - 1) * self.step,
        );
        let Some(lines) = clip_line(g.origin, g.v, n, anywhere, band_y) else {
            return;
        };
        for j in lines.start as usize..lines.end as usize {
            let (lo, hi) = h.row_range(n, j);
            let (i0, i1) = (
                lo.max(columns.start as usize),
                hi.min(columns.end as usize - 1),
            );
            if i0 > i1 {
                continue;
            }
            let (x, y) = (
                g.origin.0 + i0 as i64 * g.u.0,
                g.origin.1 + j as i64 * g.v.1,
            );
            let row = ((y - self.y0) / self.step) as usize - rows.start;
            let k = row * self.width + ((x - self.x0) / self.step) as usize;
            // Read along the parent's diagonal and converted straight into the raster's row.
            h.map_row(i0, j, &mut band[k..][..=i1 - i0], to_sample);
        }
    }
}

/// Bands of raster rows per worker in [`LevelGrid::put_batch`]: a few, so that a band's share of
/// a batch evens out between workers.
const BANDS_PER_WORKER: usize = 4;

/// The indices `i` in `0..n` whose points `origin + i·u` lie inside `x` × `y` (inclusive
/// ranges), `None` when none does (`u` is axis-aligned).
fn clip_line(
    origin: (i64, i64),
    u: (i64, i64),
    n: usize,
    x: (i64, i64),
    y: (i64, i64),
) -> Option<std::ops::Range<i64>> {
    let (mut lo, mut hi) = (0i64, n as i64 - 1);
    for (start, step, (min, max)) in [(origin.0, u.0, x), (origin.1, u.1, y)] {
        match step.signum() {
            0 if start < min || start > max => return None,
            0 => {}
            1 => {
                lo = lo.max((min.saturating_sub(start) + step - 1).div_euclid(step));
                hi = hi.min(max.saturating_sub(start).div_euclid(step));
            }
            _ => {
                let s = -step;
                lo = lo.max((start.saturating_sub(max) + s - 1).div_euclid(s));
                hi = hi.min(start.saturating_sub(min).div_euclid(s));
            }
        }
    }
    (lo <= hi).then_some(lo..hi + 1)
}
