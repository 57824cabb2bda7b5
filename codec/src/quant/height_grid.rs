//! A grid of integer heights ready for the encoder, quantized from metres under a plan, in
//! memory or mapped from temporary storage.

use rayon::prelude::*;

use super::{CHUNK, QuantPlan, round_to_i64};
use crate::CodecError;
use crate::samples::{Dem, SampleSource};
use crate::temp::{LatticeArray, TempStorage};

/// What the quantizer calls after each block of rows it has written
/// ([`QuantPlan::quantize_source_watched`]): the grid and the rows, in order, while they are
/// still in memory — before a mapped grid drops them — so that a caller can checksum or copy
/// them without reading the file back.
pub type RowsWritten<'a> = dyn FnMut(&HeightGrid, std::ops::Range<usize>) + 'a;

/// A grid of integer heights ready for the encoder.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct HeightGrid {
    /// Columns.
    pub width: usize,
    /// Rows (row 0 = north).
    pub height: usize,
    /// Row-major integer heights; meaningless where `valid` is false.
    pub values: LatticeArray<i32>,
    /// Row-major: false at nodata.
    pub valid: LatticeArray<bool>,
}

impl HeightGrid {
    /// Converts metres to units under `plan`; `nodata` samples (and NaN) become invalid.
    pub fn from_metres(
        width: usize,
        height: usize,
        samples: &[f64],
        nodata: Option<f64>,
        plan: &QuantPlan,
    ) -> Result<Self, CodecError> {
        if samples.len() != width * height {
            return Err(CodecError::invalid(
                "sample count does not match width × height",
            ));
        }
        let mut grid = Self {
            width,
            height,
            values: vec![0i32; samples.len()].into(),
            valid: vec![false; samples.len()].into(),
        };
        grid.quantize_rows(0, samples, nodata, plan)?;
        Ok(grid)
    }

    /// Quantizes `samples`, whole rows starting at row `first_row`, into the grid; in parallel,
    /// reporting the first bad sample in raster order.
    fn quantize_rows(
        &mut self,
        first_row: usize,
        samples: &[f64],
        nodata: Option<f64>,
        plan: &QuantPlan,
    ) -> Result<(), CodecError> {
        match self.quantize_rows_measuring(first_row, samples, nodata, plan, false) {
            (_, None) => Ok(()),
            (_, Some(e)) => Err(e),
        }
    }

    /// [`HeightGrid::quantize_rows`] going on past bad samples; with `measure`, also the largest
    /// distance between a valid sample and its lattice value under `plan` (what
    /// [`QuantPlan::for_source`] measures as the representation error).
    pub(super) fn quantize_rows_measuring(
        &mut self,
        first_row: usize,
        samples: &[f64],
        nodata: Option<f64>,
        plan: &QuantPlan,
        measure: bool,
    ) -> (f64, Option<CodecError>) {
        let start = first_row * self.width;
        let end = start + samples.len();
        let width = self.width;
        let (offset, u) = (plan.offset, plan.unit);
        let (deviation, bad) = samples
            .par_chunks(CHUNK)
            .zip(self.values[start..end].par_chunks_mut(CHUNK))
            .zip(self.valid[start..end].par_chunks_mut(CHUNK))
            .enumerate()
            .map(|(c, ((samples, values), valid))| {
                let mut deviation = 0.0f64;
                let mut bad = None;
                for (i, &v) in samples.iter().enumerate() {
                    if nodata.is_some_and(|nd| v == nd) {
                        continue;
                    }
                    if measure && !v.is_nan() {
                        let d = (offset + round_to_i64((v - offset) / u) as f64 * u - v).abs();
                        deviation = deviation.max(d);
                    }
                    match plan.to_units(v) {
                        Ok(Some(n)) => {
                            values[i] = n;
                            valid[i] = true;
                        }
                        Ok(None) => {}
                        Err(e) => {
                            if bad.is_none() {
                                bad = Some((start + c * CHUNK + i, e));
                            }
                            if !measure {
                                break;
                            }
                        }
                    }
                }
                (deviation, bad)
            })
            .reduce(
                || (0.0, None),
                |(da, ba), (db, bb)| {
                    let bad = match (ba, bb) {
                        (Some(a), Some(b)) => Some(if a.0 <= b.0 { a } else { b }),
                        (a, b) => a.or(b),
                    };
                    (da.max(db), bad)
                },
            );
        let bad = bad.map(|(idx, e)| {
            CodecError::invalid(format!(
                "at column {}, row {}: {e}",
                idx % width,
                idx / width
            ))
        });
        (deviation, bad)
    }

    /// Quantizes streamed samples under `plan` (see [`QuantPlan::for_source`]); the same grid
    /// as [`HeightGrid::from_metres`] on the same samples.
    pub fn from_source(src: &dyn SampleSource, plan: &QuantPlan) -> Result<Self, CodecError> {
        Self::from_source_in(src, plan, &TempStorage::Memory)
    }

    /// [`HeightGrid::from_source`] with the grid in `storage`.
    pub fn from_source_in(
        src: &dyn SampleSource,
        plan: &QuantPlan,
        storage: &TempStorage,
    ) -> Result<Self, CodecError> {
        Self::from_source_watched(src, plan, storage, &mut |_, _| {})
    }

    /// [`HeightGrid::from_source_in`] calling `watch` after each block of rows is written.
    pub(super) fn from_source_watched(
        src: &dyn SampleSource,
        plan: &QuantPlan,
        storage: &TempStorage,
        watch: &mut RowsWritten<'_>,
    ) -> Result<Self, CodecError> {
        let mut grid = Self::empty(src.width(), src.height(), storage)?;
        let nodata = src.nodata();
        src.for_each_block(&mut |row, block| {
            let written = grid.quantize_rows(row, block, nodata, plan);
            grid.written(row, block.len(), watch);
            written
        })?;
        Ok(grid)
    }

    /// After a block of `samples` samples from row `first_row` has been quantized: `watch`
    /// sees its rows, then a mapped grid drops them from the resident set (they stay in the
    /// file; the quantizer never comes back to them).
    pub(super) fn written(&self, first_row: usize, samples: usize, watch: &mut RowsWritten<'_>) {
        let start = first_row * self.width;
        let rows = samples.checked_div(self.width).unwrap_or(0);
        watch(self, first_row..first_row + rows);
        self.values.release(start..start + samples);
        self.valid.release(start..start + samples);
    }

    /// A `width × height` grid in `storage` with no valid sample yet.
    pub fn empty(width: usize, height: usize, storage: &TempStorage) -> Result<Self, CodecError> {
        let len = width
            .checked_mul(height)
            .ok_or_else(|| CodecError::limit("grid too large"))?;
        Ok(Self {
            width,
            height,
            values: LatticeArray::filled(len, 0i32, storage)?,
            valid: LatticeArray::filled(len, false, storage)?,
        })
    }

    /// Whether the grid lives in mapped files ([`crate::temp`]).
    pub fn is_mapped(&self) -> bool {
        self.values.is_mapped()
    }

    /// Bytes the grid keeps resident ([`LatticeArray::resident_bytes`]).
    pub fn resident_bytes(&self) -> u64 {
        self.values.resident_bytes() + self.valid.resident_bytes()
    }

    /// Bytes per lattice point of a grid: an `i32` height and a validity flag.
    pub const BYTES_PER_POINT: u64 = 5;

    /// Whether [`HeightGrid::window`] copies: the grid is in mapped files (on Unix), where
    /// reading a block's samples in place would fault them in page by page.
    pub fn windows(&self) -> bool {
        self.values.windows()
    }

    /// The samples of the rectangle `(x0, y0, x1, y1)` (inclusive, clipped to the grid) in a
    /// grid of the same size that holds nothing else (nodata elsewhere), in memory
    /// ([`LatticeArray::window`]): [`HeightGrid::window_bytes`] of it.
    pub fn window(&self, rect: (i64, i64, i64, i64)) -> Result<Self, CodecError> {
        Ok(Self {
            width: self.width,
            height: self.height,
            values: self.values.window(self.width, rect)?,
            valid: self.valid.window(self.width, rect)?,
        })
    }

    /// A copy of the grid in `storage`.
    pub fn copied_to(&self, storage: &TempStorage) -> Result<Self, CodecError> {
        Ok(Self {
            width: self.width,
            height: self.height,
            values: self.values.copied_to(storage)?,
            valid: self.valid.copied_to(storage)?,
        })
    }

    /// The samples at multiples of `2^shift` in both directions, as a compact grid in memory
    /// ([`LatticeArray::strided`]): `((width − 1) >> shift) + 1` columns.
    pub fn strided(&self, shift: u32) -> Result<Self, CodecError> {
        let cols = |len: usize| {
            if len == 0 {
                0
            } else {
                ((len - 1) >> shift) + 1
            }
        };
        Ok(Self {
            width: cols(self.width),
            height: cols(self.height),
            values: self.values.strided(self.width, shift)?,
            valid: self.valid.strided(self.width, shift)?,
        })
    }

    /// Bytes of a [`HeightGrid::window`] of `rows` rows of `row_len` points.
    pub fn window_bytes(&self, rows: usize, row_len: usize) -> u64 {
        LatticeArray::<i32>::window_bytes(rows, row_len, self.width)
            + LatticeArray::<bool>::window_bytes(rows, row_len, self.width)
    }

    /// Notes that a pass read `rows` runs of about `row_len` lattice points each (heights and
    /// validity), so that a mapped grid drops its resident pages every window
    /// ([`LatticeArray::touched_rows`]).
    #[inline]
    pub fn touched_rows(&self, rows: usize, row_len: usize) {
        self.values.touched_rows(rows, row_len);
        self.valid.touched_rows(rows, row_len);
    }

    /// [`HeightGrid::touched_rows`] for runs far apart ([`LatticeArray::touched_sparse_rows`]).
    #[inline]
    pub fn touched_sparse_rows(&self, rows: usize, row_len: usize) {
        self.values.touched_sparse_rows(rows, row_len);
        self.valid.touched_sparse_rows(rows, row_len);
    }

    /// Drops every resident page of a mapped grid (the values stay in its files); nothing in
    /// memory.
    pub fn release_all(&self) {
        self.values.release(0..self.values.len());
        self.valid.release(0..self.valid.len());
    }

    /// Whether some sample is nodata; a scan by windows.
    pub fn has_invalid(&self) -> bool {
        self.valid.any(|&v| !v)
    }

    /// How many samples are valid; a scan by windows.
    pub fn valid_count(&self) -> usize {
        let mut count = 0;
        self.valid
            .for_each_window(|_, w| count += w.iter().filter(|&&v| v).count());
        count
    }

    /// Converts a DEM under `plan` (see [`QuantPlan::for_dem`]).
    pub fn from_dem(dem: &Dem, plan: &QuantPlan) -> Result<Self, CodecError> {
        Self::from_metres(dem.width, dem.height, &dem.values, dem.nodata, plan)
    }

    /// A grid whose samples are all valid.
    pub fn all_valid(width: usize, height: usize, values: Vec<i32>) -> Self {
        assert_eq!(values.len(), width * height);
        Self {
            width,
            height,
            valid: vec![true; values.len()].into(),
            values: values.into(),
        }
    }

    /// The height at lattice point `(x, y)` if it is a valid sample.
    #[inline]
    pub fn get(&self, x: i64, y: i64) -> Option<i32> {
        if x < 0 || y < 0 || x >= self.width as i64 || y >= self.height as i64 {
            return None;
        }
        let k = y as usize * self.width + x as usize;
        self.valid[k].then(|| self.values[k])
    }

    /// Whether `(x, y)` is a valid sample (inside the grid and not nodata).
    #[inline]
    pub fn is_valid(&self, x: i64, y: i64) -> bool {
        if x < 0 || y < 0 || x >= self.width as i64 || y >= self.height as i64 {
            return false;
        }
        self.valid[y as usize * self.width + x as usize]
    }

    /// Smallest and largest valid height, or `None` if no sample is valid.
    /// A scan by windows: a mapped grid's resident set stays one window.
    pub fn range(&self) -> Option<(i32, i32)> {
        let mut range: Option<(i32, i32)> = None;
        self.values.for_each_window(|start, values| {
            let valid = &self.valid[start..start + values.len()];
            let mut it = values
                .iter()
                .zip(valid)
                .filter(|(_, ok)| **ok)
                .map(|(v, _)| *v);
            if let Some(first) = range.map(|r| r.0).or_else(|| it.next()) {
                let (lo, hi) = range.unwrap_or((first, first));
                range = Some(it.fold((lo, hi), |(lo, hi), v| (lo.min(v), hi.max(v))));
            }
            self.valid.release(start..start + values.len());
        });
        range
    }
}
