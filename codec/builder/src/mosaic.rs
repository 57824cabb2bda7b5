//! Several georeferenced inputs at power-of-two spacings as one variable-resolution lattice
//! (paper §5, "graph construction"; [`cbdam_codec::hierarchy::resolution`]).
//!
//! The lattice has the finest input's spacing and covers the union of the inputs. A coarser input
//! must sample it at a stride of `2^j` lattice points, its samples on the lattice and on
//! multiples of its stride from the lattice origin (so they are vertices of level `L − 2j`).
//! Nothing is resampled: any other geometry is an error that says what is required.
//!
//! Out of core for any number of tiles: [`mosaic_tiles`] reads only the inputs' headers
//! ([`TileReader`]) and places them, with a row index of their extents; no sample is decoded
//! and none is held. [`Mosaic`] is a [`SampleSource`] that composes each block of lattice rows
//! when the quantizer asks for it, from the bands of rows of the inputs that reach the block,
//! decoded on demand and kept in a cache bounded by a share of `--memory-limit`
//! ([`crate::band_cache`]): blocks go north to south, so a band is decoded once per pass and
//! reused by the blocks that cross it. Inputs are painted coarsest first, then the last listed
//! first, valid samples only: the finest input wins, ties go to the first listed, and nodata
//! falls through to what lies below. Which input wins a point is never stored: it is computed
//! from the index when a block is composed.
//!
//! Memory is therefore independent of the number and size of the inputs. The lattice itself —
//! the resolution classes (1 byte per point, [`Mosaic::survey`]) and the quantized grid (5 bytes
//! per point) — is held in memory when it takes at most half of `--memory-limit`, and otherwise
//! in memory-mapped temporary files whose passes keep about a window of each resident
//! ([`cbdam_codec::temp`], [`Mosaic::lattice`]): memory is then independent of the lattice's
//! size too ([`bytes_in_memory`]).

use std::collections::BTreeMap;
use std::ops::Range;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::sync::atomic::Ordering::Relaxed;

use crate::band_cache::{BandCache, Samples};
use crate::error::{Result, bail};
use cbdam_codec::CodecError;
use cbdam_codec::hierarchy::Resolution;
use cbdam_codec::hierarchy::resolution::{COARSE_ONLY, HOLE};
use cbdam_codec::quant::HeightGrid;
use cbdam_codec::repository::GeoRef;
use cbdam_codec::samples::{BlockFn, SampleSource, SampleType};
use cbdam_codec::temp::{LatticeArray, MAPPED_RESIDENT_BYTES, TempStorage};
use rayon::prelude::*;

mod assemble;
mod placement;

pub(crate) use assemble::place_vrt_tile;
pub use assemble::{mosaic, mosaic_tiles};
pub use placement::Placement;

/// Relative tolerance on spacing ratios: GeoTIFF pixel scales are decimal doubles (e.g.
/// 1/3600°), so ratios of exact powers of two come out within a few ulps.
const RATIO_TOLERANCE: f64 = 1e-9;
/// Tolerance, in fine samples, on how far an input's origin may lie from a lattice point:
/// tie points are printed decimals too.
const ORIGIN_TOLERANCE: f64 = 1e-6;
/// Bytes per lattice point of a multi-input build's lattice: the encoder's resolution classes
/// (u8) and the quantized grid (i32 + bool). The encoder's reconstruction field (4 bytes per
/// point of the domain) comes on top, in memory or in a temporary file
/// ([`crate::plan::storage_for`]).
pub const BYTES_PER_POINT: u64 = 1 + HeightGrid::BYTES_PER_POINT;

/// Lattice points composed per block (whole rows, at least one): 8 MiB of `f64`, enough rows
/// for every core and for bands of tile rows to be reused by the next block.
const BLOCK_POINTS: usize = 1 << 20;

/// Where a multi-input build under `memory_limit` keeps its `width × height` lattice
/// ([`TempStorage::for_lattice`]).
pub fn lattice_storage(width: usize, height: usize, memory_limit: u64) -> TempStorage {
    let points = (width as u64).saturating_mul(height as u64);
    TempStorage::for_lattice(points.saturating_mul(BYTES_PER_POINT), memory_limit)
}

/// What a multi-input build of a `width × height` lattice in `lattice` holds in memory besides
/// its cache of decoded tile rows and its reconstruction field: [`BYTES_PER_POINT`] per lattice
/// point in memory, or a resident window of each of its three mapped arrays, and one block of
/// composed rows (values and winners).
pub fn bytes_in_memory(width: usize, height: usize, lattice: &TempStorage) -> u64 {
    let points = (width as u64).saturating_mul(height as u64);
    let block = 12 * (BLOCK_POINTS.max(width) as u64).min(points);
    let arrays = match lattice {
        TempStorage::Memory => points.saturating_mul(BYTES_PER_POINT),
        TempStorage::File(_) | TempStorage::Named(_) => {
            // Heights (4 bytes a point), validity and classes (1 byte each).
            let resident = |bytes: u64| bytes.min(MAPPED_RESIDENT_BYTES);
            resident(points.saturating_mul(4)) + 2 * resident(points)
        }
    };
    arrays.saturating_add(block)
}

/// No input has a valid sample at this point (in [`Mosaic::for_each_block_winners`]).
pub const NO_WINNER: u32 = u32::MAX;

/// What [`Mosaic::for_each_block_winners`] calls on each block: `(first_row, values, winners)`.
pub type WinnersFn<'a> = dyn FnMut(usize, &[f64], &[u32]) -> Result<()> + 'a;

/// Lattice rows per bucket of the row index.
const BUCKET_ROWS: usize = 256;

/// Per pair of inputs of one spacing (the one painted over, the one below it): the valid samples
/// both hold, how many differ and by how much at most.
type SharedSamples = BTreeMap<(usize, usize), (usize, usize, f64)>;

/// The bands of rows a block of lattice rows reads, per input that reaches it.
struct Block {
    /// Inputs reaching the block, in painting order (coarsest first; among equal strides the
    /// last listed first, so that the first listed wins).
    inputs: Vec<usize>,
    /// Per input (same order): its first band held and the bands.
    bands: Vec<(usize, Vec<Arc<Samples>>)>,
}

impl Block {
    /// Row `r` of the `j`-th input of the block: its band and the offset of the row in it.
    #[inline]
    fn row(&self, p: &Placement, j: usize, r: usize) -> (&Samples, usize) {
        let (first, bands) = &self.bands[j];
        (&bands[r / p.band_rows - first], (r % p.band_rows) * p.width)
    }
}

/// What the survey pass ([`Mosaic::survey`]) found.
pub struct Survey {
    /// The encoder's view: the stride of the winning sample at each lattice point.
    pub resolution: Resolution,
    /// Smallest and largest winning sample.
    pub range: (f64, f64),
}

/// The merged lattice. As a [`SampleSource`] it yields the winning sample of every lattice point
/// (NaN where none, no nodata value), row block by row block, decoding the inputs' rows as the
/// blocks reach them.
pub struct Mosaic {
    /// Lattice columns.
    pub width: usize,
    /// Lattice rows.
    pub height: usize,
    /// The lattice's georeferencing (the finest input's spacing).
    pub georef: GeoRef,
    /// The type the merged samples are stored as: the inputs' common type, else `I32` for
    /// integer inputs, else `F64`.
    pub sample_type: SampleType,
    /// The inputs in command-line order.
    pub inputs: Vec<Placement>,
    /// Per bucket of [`BUCKET_ROWS`] lattice rows: the inputs whose rows reach into it.
    buckets: Vec<Vec<u32>>,
    /// Decoded bands of the inputs' rows.
    cache: BandCache,
    /// Lattice points per block ([`BLOCK_POINTS`]; fewer in tests, to cross block edges).
    block_points: usize,
    /// Where the lattice's arrays (classes, quantized grid) go ([`lattice_storage`]).
    pub lattice: TempStorage,
}

impl Mosaic {
    /// Lattice rows per block: `block_points` points, at least one row.
    fn block_rows(&self) -> usize {
        (self.block_points / self.width.max(1)).max(1)
    }

    /// Bytes of decoded tile rows the mosaic keeps between blocks, besides the block's own.
    pub fn cache_budget(&self) -> u64 {
        self.cache.budget()
    }

    /// Bands of tile rows decoded so far.
    pub fn bands_decoded(&self) -> u64 {
        self.cache.decoded()
    }

    /// The painting order key of input `k`: coarsest first, then the last listed first.
    fn paint_key(&self, k: usize) -> (std::cmp::Reverse<u8>, std::cmp::Reverse<usize>) {
        (std::cmp::Reverse(self.inputs[k].log2), std::cmp::Reverse(k))
    }

    /// The bands lattice rows `ya..yb` need: of the inputs whose samples reach them, the rows on
    /// them (`around`: and the rows bounding the cells they cross).
    fn block(&self, ya: usize, yb: usize, around: bool) -> Result<Block> {
        let mut inputs: Vec<usize> = (ya / BUCKET_ROWS..=(yb - 1) / BUCKET_ROWS)
            .flat_map(|b| self.buckets[b].iter().map(|&k| k as usize))
            .filter(|&k| {
                let p = &self.inputs[k];
                p.y0 < yb && p.last_row() >= ya
            })
            .collect();
        inputs.sort_unstable_by_key(|&k| self.paint_key(k));
        inputs.dedup();
        let mut keys = Vec::new();
        let mut spans = Vec::with_capacity(inputs.len());
        for &k in &inputs {
            let p = &self.inputs[k];
            let rows = if around && p.log2 > 0 {
                p.rows_around(ya, yb)
            } else {
                p.rows_on(ya, yb)
            };
            let span = if rows.is_empty() {
                0..0
            } else {
                rows.start / p.band_rows..(rows.end - 1) / p.band_rows + 1
            };
            keys.extend(span.clone().map(|b| (k, b)));
            spans.push(span);
        }
        let mut got = self
            .cache
            .get(&keys, |(k, b)| self.inputs[k].read_band(b))?
            .into_iter();
        let bands = spans
            .into_iter()
            .map(|span| (span.start, got.by_ref().take(span.len()).collect()))
            .collect();
        Ok(Block { inputs, bands })
    }

    /// Paints lattice row `y` of `block` into `values` (NaN where no input has a sample), in
    /// painting order so that the finest, first listed valid sample wins. With `winners`: the
    /// winning input of each point ([`NO_WINNER`] where none), inputs of one spacing that
    /// overlap compared into `shared`, and `seen[j]` set for every input of the block with a
    /// valid sample on the row.
    fn paint_row(
        &self,
        block: &Block,
        y: usize,
        values: &mut [f64],
        mut winners: Option<(&mut [u32], &mut SharedSamples, &mut [bool])>,
    ) {
        values.fill(f64::NAN);
        if let Some((w, _, _)) = &mut winners {
            w.fill(NO_WINNER);
        }
        for (j, &k) in block.inputs.iter().enumerate() {
            let p = &self.inputs[k];
            let s = p.stride();
            if y < p.y0 || !(y - p.y0).is_multiple_of(s) || (y - p.y0) / s >= p.height {
                continue;
            }
            let (band, at) = block.row(p, j, (y - p.y0) / s);
            match &mut winners {
                None => match band {
                    Samples::I16(v) => paint(p, &v[at..at + p.width], values),
                    Samples::F32(v) => paint(p, &v[at..at + p.width], values),
                    Samples::F64(v) => paint(p, &v[at..at + p.width], values),
                },
                Some((w, shared, seen)) => {
                    for c in 0..p.width {
                        let v = band.get(at + c);
                        if !p.is_valid(v) {
                            continue;
                        }
                        seen[j] = true;
                        let x = p.x0 + c * s;
                        let prev = w[x];
                        if prev != NO_WINNER && self.inputs[prev as usize].log2 == p.log2 {
                            let e = shared.entry((k, prev as usize)).or_insert((0, 0, 0.0));
                            e.0 += 1;
                            if v != values[x] {
                                e.1 += 1;
                                e.2 = e.2.max((v - values[x]).abs());
                            }
                        }
                        w[x] = k as u32;
                        values[x] = v;
                    }
                }
            }
        }
    }

    /// Marks [`COARSE_ONLY`] the points of lattice row `y` without a sample (`class` [`HOLE`])
    /// that lie in a cell of a coarse input whose four corners have data: they are drawn from
    /// the coarse level.
    fn mark_coarse_only(&self, block: &Block, y: usize, class: &mut [u8]) {
        for (j, &k) in block.inputs.iter().enumerate() {
            let p = &self.inputs[k];
            if p.log2 == 0 || y < p.y0 || y > p.last_row() || p.height < 2 || p.width < 2 {
                continue;
            }
            let s = p.stride();
            let (d, ra) = (y - p.y0, (y - p.y0) / s);
            // A row on a sample row bounds the cells above and below it.
            let cells = [
                d.is_multiple_of(s).then(|| ra.checked_sub(1)).flatten(),
                Some(ra),
            ];
            for r in cells.into_iter().flatten().filter(|&r| r + 1 < p.height) {
                let (top, a) = block.row(p, j, r);
                let (bottom, b) = block.row(p, j, r + 1);
                let valid = |band: &Samples, at: usize| p.is_valid(band.get(at));
                for c in 0..p.width - 1 {
                    if valid(top, a + c)
                        && valid(top, a + c + 1)
                        && valid(bottom, b + c)
                        && valid(bottom, b + c + 1)
                    {
                        for point in &mut class[p.x0 + c * s..=p.x0 + (c + 1) * s] {
                            if *point == HOLE {
                                *point = COARSE_ONLY;
                            }
                        }
                    }
                }
            }
        }
    }

    /// One pass over the inputs before quantizing: the resolution classes, the range of the
    /// winning samples, and the checks that need the samples — every input has a valid one,
    /// inputs of one spacing agree where they overlap (shared edge rows).
    pub fn survey(&self) -> Result<Survey> {
        self.survey_watched(&mut |_, _| {})
    }

    /// [`Mosaic::survey`] calling `watch(classes, rows)` after each block of rows of the
    /// classes is written, in order, while they are still in memory.
    pub fn survey_watched(&self, watch: &mut dyn FnMut(&[u8], Range<usize>)) -> Result<Survey> {
        let w = self.width;
        let mut class = LatticeArray::filled(w * self.height, HOLE, &self.lattice)?;
        let seen_any: Vec<AtomicBool> = (0..self.inputs.len())
            .map(|_| AtomicBool::new(false))
            .collect();
        let mut shared = SharedSamples::new();
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        let rows = self.block_rows();
        let mut values = Vec::new();
        let mut winners = Vec::new();
        for ya in (0..self.height).step_by(rows) {
            let yb = (ya + rows).min(self.height);
            let block = self.block(ya, yb, true)?;
            values.resize((yb - ya) * w, f64::NAN);
            winners.resize((yb - ya) * w, NO_WINNER);
            let part = values
                .par_chunks_mut(w)
                .zip(winners.par_chunks_mut(w))
                .zip(class[ya * w..yb * w].par_chunks_mut(w))
                .enumerate()
                .map(|(i, ((values, winners), class))| {
                    self.survey_row(&block, ya + i, (values, winners, class), &seen_any)
                })
                .reduce(
                    || (SharedSamples::new(), f64::INFINITY, f64::NEG_INFINITY),
                    |mut a, b| {
                        merge_shared(&mut a.0, b.0);
                        (a.0, a.1.min(b.1), a.2.max(b.2))
                    },
                );
            watch(&class[ya * w..yb * w], ya..yb);
            // A mapped lattice drops the rows written from the resident set.
            class.release(ya * w..yb * w);
            merge_shared(&mut shared, part.0);
            lo = lo.min(part.1);
            hi = hi.max(part.2);
        }
        self.check_survey(&seen_any, &shared)?;
        Ok(Survey {
            resolution: Resolution { class },
            range: (lo, hi),
        })
    }

    /// Surveys lattice row `y` of `block`: paints its winning samples, winners and classes,
    /// marks in `seen_any` the inputs with a valid sample on it, and returns the samples shared
    /// by inputs of one spacing and the row's smallest and largest winning sample.
    fn survey_row(
        &self,
        block: &Block,
        y: usize,
        (values, winners, class): (&mut [f64], &mut [u32], &mut [u8]),
        seen_any: &[AtomicBool],
    ) -> (SharedSamples, f64, f64) {
        let mut shared = SharedSamples::new();
        let mut seen = vec![false; block.inputs.len()];
        self.paint_row(block, y, values, Some((winners, &mut shared, &mut seen)));
        for (j, _) in seen.iter().enumerate().filter(|(_, s)| **s) {
            seen_any[block.inputs[j]].store(true, Relaxed);
        }
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for ((c, &k), &v) in class.iter_mut().zip(winners.iter()).zip(values.iter()) {
            if k != NO_WINNER {
                *c = self.inputs[k as usize].log2;
                lo = lo.min(v);
                hi = hi.max(v);
            }
        }
        self.mark_coarse_only(block, y, class);
        (shared, lo, hi)
    }

    /// Refuses a survey in which an input has no valid sample, or inputs of one spacing
    /// disagree where they overlap.
    fn check_survey(&self, seen_any: &[AtomicBool], shared: &SharedSamples) -> Result<()> {
        if let Some(p) = (0..self.inputs.len())
            .find(|&k| !seen_any[k].load(Relaxed))
            .map(|k| &self.inputs[k])
        {
            bail!(
                "{} has no valid sample (all nodata or NaN)",
                p.path.display()
            );
        }
        let clashes: Vec<_> = shared.iter().filter(|(_, e)| e.1 > 0).collect();
        if let Some(&(&(a, b), &(n, bad, most))) = clashes.first() {
            bail!(
                "tiles {} and {} disagree on {bad} of their {n} shared samples by up to {most} \
                 (height units){}: inputs of the same spacing must hold the same values where \
                 they overlap (shared edge rows)",
                self.inputs[a].path.display(),
                self.inputs[b].path.display(),
                match clashes.len() - 1 {
                    0 => String::new(),
                    more => format!(", and {more} more pairs of tiles disagree"),
                }
            );
        }
        Ok(())
    }

    /// One pass over the lattice: `f(first_row, values, winners)` per block of rows, with the
    /// winning sample (NaN where none) and the index in [`Mosaic::inputs`] of the input it comes
    /// from ([`NO_WINNER`] where none).
    pub fn for_each_block_winners(&self, f: &mut WinnersFn<'_>) -> Result<()> {
        let w = self.width;
        let rows = self.block_rows();
        let (mut values, mut winners) = (Vec::new(), Vec::new());
        for ya in (0..self.height).step_by(rows) {
            let yb = (ya + rows).min(self.height);
            let block = self.block(ya, yb, false)?;
            values.resize((yb - ya) * w, f64::NAN);
            winners.resize((yb - ya) * w, NO_WINNER);
            values
                .par_chunks_mut(w)
                .zip(winners.par_chunks_mut(w))
                .enumerate()
                .for_each(|(i, (values, winners))| {
                    let mut shared = SharedSamples::new();
                    let mut seen = vec![false; block.inputs.len()];
                    self.paint_row(
                        &block,
                        ya + i,
                        values,
                        Some((winners, &mut shared, &mut seen)),
                    );
                });
            f(ya, &values, &winners)?;
        }
        Ok(())
    }
}

/// Paints the valid samples of one row of input `p` onto `values` at its stride.
#[inline]
fn paint<T: Copy + Into<f64>>(p: &Placement, row: &[T], values: &mut [f64]) {
    let s = p.stride();
    for (c, &v) in row.iter().enumerate() {
        let v: f64 = v.into();
        if p.is_valid(v) {
            values[p.x0 + c * s] = v;
        }
    }
}

fn merge_shared(into: &mut SharedSamples, from: SharedSamples) {
    for (key, (n, bad, most)) in from {
        let e = into.entry(key).or_insert((0, 0, 0.0));
        e.0 += n;
        e.1 += bad;
        e.2 = e.2.max(most);
    }
}

impl SampleSource for Mosaic {
    fn width(&self) -> usize {
        self.width
    }
    fn height(&self) -> usize {
        self.height
    }
    fn sample_type(&self) -> SampleType {
        self.sample_type
    }
    fn nodata(&self) -> Option<f64> {
        None
    }
    fn for_each_block(&self, f: &mut BlockFn<'_>) -> Result<(), CodecError> {
        let w = self.width;
        let rows = self.block_rows();
        let mut values = Vec::new();
        for ya in (0..self.height).step_by(rows) {
            let yb = (ya + rows).min(self.height);
            let block = self
                .block(ya, yb, false)
                .map_err(|e| CodecError::invalid(e.to_string()))?;
            values.resize((yb - ya) * w, f64::NAN);
            values
                .par_chunks_mut(w)
                .enumerate()
                .for_each(|(i, row)| self.paint_row(&block, ya + i, row, None));
            f(ya, &values)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests;
