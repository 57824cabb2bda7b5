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
use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::band_cache::{BandCache, Samples};
use crate::error::{Context, Result, bail};
use crate::input::{ReadOptions, TileReader};
use crate::tiles::{Tile, VrtPlacement};
use cbdam_codec::CodecError;
use cbdam_codec::hierarchy::Resolution;
use cbdam_codec::hierarchy::resolution::{COARSE_ONLY, HOLE};
use cbdam_codec::quant::HeightGrid;
use cbdam_codec::repository::GeoRef;
use cbdam_codec::samples::{BlockFn, SampleSource, SampleType};
use cbdam_codec::temp::{LatticeArray, MAPPED_RESIDENT_BYTES, TempStorage};
use rayon::prelude::*;

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

/// Where one input lies on the lattice, and how its rows are read.
#[derive(Debug)]
pub struct Placement {
    /// The file.
    pub path: PathBuf,
    /// Lattice column of its first sample.
    pub x0: usize,
    /// Lattice row of its first sample.
    pub y0: usize,
    /// Its stride in lattice points, `2^log2`.
    pub log2: u8,
    /// Samples per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// The type its samples are stored as.
    pub sample_type: SampleType,
    /// Its nodata value (the override, a VRT's, else the file's).
    pub nodata: Option<f64>,
    /// Header read; rows decoded on demand.
    reader: TileReader,
    /// Rows per band of decoded samples ([`TileReader::band_rows`]).
    band_rows: usize,
}

impl Placement {
    fn stride(&self) -> usize {
        1 << self.log2
    }

    /// The last lattice row and column its samples reach.
    fn last_row(&self) -> usize {
        self.y0 + (self.height - 1) * self.stride()
    }

    fn last_col(&self) -> usize {
        self.x0 + (self.width - 1) * self.stride()
    }

    /// Whether `v` is a height ([`cbdam_codec::samples::Dem::is_valid`]).
    #[inline]
    fn is_valid(&self, v: f64) -> bool {
        !v.is_nan() && self.nodata != Some(v)
    }

    /// Its rows with a sample on lattice rows `ya..yb`.
    fn rows_on(&self, ya: usize, yb: usize) -> std::ops::Range<usize> {
        let s = self.stride();
        let lo = ya.saturating_sub(self.y0).div_ceil(s);
        let hi = if yb <= self.y0 {
            0
        } else {
            ((yb - 1 - self.y0) / s + 1).min(self.height)
        };
        lo..hi.max(lo)
    }

    /// Its rows bounding the cells that lattice rows `ya..yb` cross (one more on each side than
    /// [`Placement::rows_on`]): what [`COARSE_ONLY`] points are drawn from.
    fn rows_around(&self, ya: usize, yb: usize) -> std::ops::Range<usize> {
        if yb <= self.y0 || ya > self.last_row() {
            return 0..0;
        }
        let s = self.stride();
        let lo = (ya.saturating_sub(self.y0) / s).saturating_sub(1);
        let hi = ((yb - 1 - self.y0) / s + 2).min(self.height);
        lo..hi
    }

    /// Reads band `band` of its rows, narrowed ([`Samples::compact`]).
    fn read_band(&self, band: usize) -> Result<Samples> {
        let r0 = band * self.band_rows;
        let r1 = (r0 + self.band_rows).min(self.height);
        let mut values = Vec::new();
        self.reader
            .read_rows(r0..r1, &mut values)
            .with_context(|| format!("reading {}", self.path.display()))?;
        if values.len() != (r1 - r0) * self.width {
            bail!(
                "reading {}: rows {r0}..{r1} came back as {} samples, not {} × {}",
                self.path.display(),
                values.len(),
                r1 - r0,
                self.width
            );
        }
        Ok(Samples::compact(values))
    }
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
        let seen_any: Vec<std::sync::atomic::AtomicBool> = (0..self.inputs.len())
            .map(|_| std::sync::atomic::AtomicBool::new(false))
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
                    let y = ya + i;
                    let mut shared = SharedSamples::new();
                    let mut seen = vec![false; block.inputs.len()];
                    self.paint_row(&block, y, values, Some((winners, &mut shared, &mut seen)));
                    for (j, _) in seen.iter().enumerate().filter(|(_, s)| **s) {
                        seen_any[block.inputs[j]].store(true, std::sync::atomic::Ordering::Relaxed);
                    }
                    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
                    for ((c, &k), &v) in class.iter_mut().zip(winners.iter()).zip(values.iter()) {
                        if k != NO_WINNER {
                            *c = self.inputs[k as usize].log2;
                            lo = lo.min(v);
                            hi = hi.max(v);
                        }
                    }
                    self.mark_coarse_only(&block, y, class);
                    (shared, lo, hi)
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
        if let Some(p) = (0..self.inputs.len())
            .find(|&k| !seen_any[k].load(std::sync::atomic::Ordering::Relaxed))
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
        Ok(Survey {
            resolution: Resolution { class },
            range: (lo, hi),
        })
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

/// Sample-centre position of raster point (0, 0), so that PixelIsArea and PixelIsPoint inputs
/// mix.
fn centre(g: &GeoRef) -> (f64, f64) {
    let half = if g.pixel_is_area { 0.5 } else { 0.0 };
    (g.origin_x + half * g.pixel_x, g.origin_y - half * g.pixel_y)
}

fn describe(p: &Path, g: &GeoRef) -> String {
    let (cx, cy) = centre(g);
    format!(
        "{} (spacing {} × {}, first sample centre at ({cx}, {cy}))",
        p.display(),
        g.pixel_x,
        g.pixel_y
    )
}

/// Reads `paths` and places them on one lattice; refuses (before allocating it) a lattice whose
/// build would need more than `memory_limit` bytes.
pub fn mosaic(paths: &[PathBuf], opts: &ReadOptions, memory_limit: u64) -> Result<Mosaic> {
    let tiles: Vec<Tile> = paths.iter().map(Tile::file).collect();
    mosaic_tiles(&tiles, opts, memory_limit)
}

/// Checks a tile read through a VRT against where the VRT places it (its size `width × height`
/// and its own georeferencing `georef`), and gives it the VRT's georeferencing where it has
/// none of its own.
pub(crate) fn place_vrt_tile(
    path: &Path,
    (width, height): (usize, usize),
    georef: &mut Option<GeoRef>,
    v: &VrtPlacement,
) -> Result<()> {
    if (width, height) != (v.width, v.height) {
        bail!(
            "{}: <SrcRect>/<DstRect> of {} are {}×{} but the tile is {}×{}: only whole tiles \
             placed without scaling are supported",
            v.vrt.display(),
            path.display(),
            v.width,
            v.height,
            width,
            height
        );
    }
    let Some(g) = georef.as_ref() else {
        *georef = Some(v.georef.clone());
        return Ok(());
    };
    let want = &v.georef;
    let close = |a: f64, b: f64| (a - b).abs() <= RATIO_TOLERANCE * b.abs();
    let (cx, cy) = centre(g);
    let (wx, wy) = centre(want);
    let (ox, oy) = ((cx - wx) / want.pixel_x, (cy - wy) / want.pixel_y);
    if !close(g.pixel_x, want.pixel_x)
        || !close(g.pixel_y, want.pixel_y)
        || ox.abs() > ORIGIN_TOLERANCE
        || oy.abs() > ORIGIN_TOLERANCE
    {
        bail!(
            "{} places {} with spacing {} × {} and its first sample centre at ({wx}, {wy}), but \
             the tile's own georeferencing says {} × {} and ({cx}, {cy}) ({ox:.4} × {oy:.4} \
             samples off): fix the VRT or the tile",
            v.vrt.display(),
            path.display(),
            want.pixel_x,
            want.pixel_y,
            g.pixel_x,
            g.pixel_y
        );
    }
    if let (Some(a), Some(b)) = (g.epsg, want.epsg)
        && a != b
    {
        bail!(
            "{}: its SRS is EPSG:{b} but {} is in EPSG:{a}",
            v.vrt.display(),
            path.display()
        );
    }
    Ok(())
}

/// [`mosaic`] of tiles ([`crate::tiles`]): plain files, or tiles a VRT places (checked against
/// their own georeferencing, which they keep; a tile without one takes the VRT's). Only the
/// tiles' headers are read here: every check of where the tiles lie is made before any sample
/// is decoded; the checks that need the samples (each tile has a valid one; inputs of the same
/// spacing that overlap hold the same valid samples there) are made by [`Mosaic::survey`].
/// Decoded rows are kept in a cache of at most half of what `memory_limit` leaves beside the
/// lattice ([`bytes_in_memory`]).
pub fn mosaic_tiles(tiles: &[Tile], opts: &ReadOptions, memory_limit: u64) -> Result<Mosaic> {
    if tiles.is_empty() {
        bail!("no input given");
    }
    if tiles.len() > NO_WINNER as usize {
        bail!(
            "{} inputs: at most {NO_WINNER} can be combined",
            tiles.len()
        );
    }
    let dems = open_tiles(tiles, opts)?;
    check_one_crs(&dems)?;
    // The finest input sets the lattice; ties go to the first listed.
    let fine = (0..dems.len())
        .min_by(|&a, &b| dems[a].2.pixel_x.total_cmp(&dems[b].2.pixel_x))
        .expect("at least one input");
    let fine_georef = dems[fine].2.clone();
    let (fx, fy) = (fine_georef.pixel_x, fine_georef.pixel_y);
    let (fcx, fcy) = centre(&fine_georef);
    let placed = place_on_finest(&dems, fine)?;
    let coarsest = (0..placed.len())
        .max_by_key(|&k| placed[k].2)
        .expect("at least one input");
    check_strides(&dems, &placed, coarsest)?;
    let (origin_x, origin_y) = lattice_origin(&placed, coarsest);
    let mut width = 0usize;
    let mut height = 0usize;
    let mut inputs = Vec::new();
    for ((path, reader, _), &(ox, oy, log2)) in dems.into_iter().zip(&placed) {
        let p = Placement {
            path,
            x0: (ox - origin_x) as usize,
            y0: (oy - origin_y) as usize,
            log2,
            width: reader.width(),
            height: reader.height(),
            sample_type: reader.sample_type(),
            nodata: reader.nodata(),
            band_rows: reader.band_rows(),
            reader,
        };
        width = width.max(p.last_col() + 1);
        height = height.max(p.last_row() + 1);
        inputs.push(p);
    }
    // The lattice's own arrays stay in memory when they fit half the limit, else they are
    // mapped; the inputs are read a band of rows at a time.
    let lattice = lattice_storage(width, height, memory_limit);
    let need = bytes_in_memory(width, height, &lattice);
    let mut buckets = vec![Vec::new(); height.div_ceil(BUCKET_ROWS)];
    for (k, p) in inputs.iter().enumerate() {
        for bucket in &mut buckets[p.y0 / BUCKET_ROWS..=p.last_row() / BUCKET_ROWS] {
            bucket.push(k as u32);
        }
    }
    let sample_type = common_sample_type(&inputs);
    let fine_geo = fine_georef;
    let half = if fine_geo.pixel_is_area { 0.5 } else { 0.0 };
    let georef = GeoRef {
        origin_x: fcx + (origin_x as f64 - half) * fx,
        origin_y: fcy - (origin_y as f64 - half) * fy,
        ..fine_geo
    };
    Ok(Mosaic {
        width,
        height,
        georef,
        sample_type,
        inputs,
        buckets,
        cache: BandCache::new(memory_limit.saturating_sub(need) / 2),
        block_points: BLOCK_POINTS,
        lattice,
    })
}

/// The type every input's samples fit exactly: theirs when they agree, else `i32` for integers
/// and `f64` for anything else.
fn common_sample_type(inputs: &[Placement]) -> SampleType {
    let types: Vec<SampleType> = inputs.iter().map(|p| p.sample_type).collect();
    if types.iter().all(|&t| t == types[0]) {
        types[0]
    } else if types.iter().all(|t| t.is_integer()) {
        SampleType::I32
    } else {
        SampleType::F64
    }
}

/// An input tile opened: its path, its reader, and where it lies.
type OpenTile = (PathBuf, TileReader, GeoRef);

/// Opens every tile, each with its georeferencing (a VRT's placement over the file's own), and
/// refuses one without georeferencing, with a spacing that is not positive or without samples.
fn open_tiles(tiles: &[Tile], opts: &ReadOptions) -> Result<Vec<OpenTile>> {
    let mut dems: Vec<OpenTile> = Vec::with_capacity(tiles.len());
    for tile in tiles {
        let path = &tile.path;
        let tile_opts = ReadOptions {
            nodata: opts.nodata.or(tile.vrt.as_ref().and_then(|v| v.nodata)),
            ..opts.clone()
        };
        let reader = TileReader::open(path, &tile_opts)
            .with_context(|| format!("reading {}", path.display()))?;
        let mut georef = reader.georef().cloned();
        if let Some(v) = &tile.vrt {
            place_vrt_tile(path, (reader.width(), reader.height()), &mut georef, v)?;
        }
        let Some(g) = georef else {
            bail!(
                "{} has no georeferencing (GeoTIFF tie point and pixel scale, or an .hgt/.asc \
                 position): several inputs are combined by where they lie, so each needs one",
                path.display()
            );
        };
        if !(g.pixel_x > 0.0 && g.pixel_y > 0.0) {
            bail!(
                "{}: sample spacing {} × {} is not positive (only north-up grids are combined)",
                path.display(),
                g.pixel_x,
                g.pixel_y
            );
        }
        if reader.width() == 0 || reader.height() == 0 {
            bail!("{} has no valid sample (all nodata or NaN)", path.display());
        }
        dems.push((path.clone(), reader, g));
    }
    Ok(dems)
}

/// One coordinate reference system: heights and positions of different CRSs cannot share a
/// lattice without reprojection, which this builder does not do.
fn check_one_crs(dems: &[OpenTile]) -> Result<()> {
    let geo = |k: usize| &dems[k].2;
    for k in 1..dems.len() {
        if geo(k).epsg != geo(0).epsg {
            let name =
                |e: Option<u32>| e.map_or("no EPSG code".to_string(), |e| format!("EPSG:{e}"));
            bail!(
                "{} is in {} but {} is in {}: inputs must share one coordinate reference system \
                 (reproject them first)",
                dems[k].0.display(),
                name(geo(k).epsg),
                dems[0].0.display(),
                name(geo(0).epsg)
            );
        }
        // Without an EPSG code the CRS is whatever the `.prj` files define: different texts
        // may name the same CRS, but the builder cannot tell, so it asks rather than guesses.
        if geo(k).epsg.is_none()
            && let (Some(a), Some(b)) = (&geo(k).wkt, &geo(0).wkt)
            && a != b
        {
            bail!(
                "{} and {} have different CRS definitions (.prj) and no EPSG code: inputs must \
                 share one coordinate reference system (reproject them, or give them the same \
                 .prj)",
                dems[k].0.display(),
                dems[0].0.display()
            );
        }
    }
    Ok(())
}

/// Each input's offset from the finest input (`fine`), in fine samples, and its stride as a
/// power of two: refused unless its spacing is 2^j times the finest and its samples fall on
/// the finest input's sample positions.
fn place_on_finest(dems: &[OpenTile], fine: usize) -> Result<Vec<(i64, i64, u8)>> {
    let geo = |k: usize| &dems[k].2;
    let (fx, fy) = (geo(fine).pixel_x, geo(fine).pixel_y);
    let (fcx, fcy) = centre(geo(fine));
    let mut placed = Vec::new();
    for (k, (path, _, _)) in dems.iter().enumerate() {
        let g = geo(k);
        let (rx, ry) = (g.pixel_x / fx, g.pixel_y / fy);
        let log2 = rx.log2().round();
        let power = (0.0..31.0).contains(&log2) && {
            let p = log2.exp2();
            (rx - p).abs() <= RATIO_TOLERANCE * p && (ry - p).abs() <= RATIO_TOLERANCE * p
        };
        if !power {
            bail!(
                "{} is {rx:.6} × {ry:.6} times as coarse as {}: combined inputs must be \
                 2^j times the finest spacing (1, 2, 4, …) on both axes, so that every coarse \
                 sample is a vertex of the diamond lattice (e.g. SRTM 1″ with 3″ is a ratio of \
                 3, which would need resampling; resample the coarse input to a power-of-two \
                 ratio first)",
                describe(path, g),
                describe(&dems[fine].0, geo(fine))
            );
        }
        let (cx, cy) = centre(g);
        let (ox, oy) = ((cx - fcx) / fx, (fcy - cy) / fy);
        if (ox - ox.round()).abs() > ORIGIN_TOLERANCE || (oy - oy.round()).abs() > ORIGIN_TOLERANCE
        {
            bail!(
                "{} lies {ox:.4} × {oy:.4} samples from {}: its samples must fall on the \
                 finest input's sample positions (a whole number of fine samples apart)",
                describe(path, g),
                describe(&dems[fine].0, geo(fine))
            );
        }
        placed.push((ox.round() as i64, oy.round() as i64, log2 as u8));
    }
    Ok(placed)
}

/// The lattice origin must sit on every input's stride: congruent to the coarsest input's
/// offset modulo its stride, which every other input must agree with modulo its own.
fn check_strides(dems: &[OpenTile], placed: &[(i64, i64, u8)], coarsest: usize) -> Result<()> {
    let geo = |k: usize| &dems[k].2;
    for (k, &(ox, oy, l)) in placed.iter().enumerate() {
        let s = 1i64 << l;
        let (dx, dy) = (
            (ox - placed[coarsest].0).rem_euclid(s),
            (oy - placed[coarsest].1).rem_euclid(s),
        );
        if dx != 0 || dy != 0 {
            bail!(
                "{} and {} are misaligned: with a stride of {s} fine samples, {} must start a \
                 multiple of {s} fine samples from {}, but is {} × {} off (mod {s}); shift or \
                 crop one of them",
                describe(&dems[k].0, geo(k)),
                describe(&dems[coarsest].0, geo(coarsest)),
                dems[k].0.display(),
                dems[coarsest].0.display(),
                dx,
                dy
            );
        }
    }
    Ok(())
}

/// The lattice's origin, in fine samples from the finest input: the lowest point on the
/// coarsest input's stride at or before every input's first sample.
fn lattice_origin(placed: &[(i64, i64, u8)], coarsest: usize) -> (i64, i64) {
    let big = 1i64 << placed[coarsest].2;
    let lowest = |axis: fn(&(i64, i64, u8)) -> i64| {
        let min = placed.iter().map(axis).min().expect("inputs");
        let c = axis(&placed[coarsest]);
        c - (c - min).div_euclid(big) * big
            - if (c - min).rem_euclid(big) == 0 {
                0
            } else {
                big
            }
    };
    (lowest(|p| p.0), lowest(|p| p.1))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every value comes back bit for bit (a zero's sign aside) from the narrowest type chosen.
    #[test]
    fn samples_narrow_only_where_exact() {
        let cases: [(&[f64], &str); 5] = [
            (&[0.0, -32768.0, 32767.0, 1200.0], "i16"),
            (&[0.0, 32768.0, 1.5], "f32"),
            (&[f64::NAN, 7.0, -9999.0], "f32"),
            (&[0.1, 1.0], "f64"),
            // Beyond f32's range: f32 would make it infinite.
            (&[3.0e38 * 10.0, 1.0], "f64"),
        ];
        for (values, want) in cases {
            let s = Samples::compact(values.to_vec());
            let got = match &s {
                Samples::I16(_) => "i16",
                Samples::F32(_) => "f32",
                Samples::F64(_) => "f64",
            };
            assert_eq!(got, want, "{values:?}");
            for (i, &v) in values.iter().enumerate() {
                let back = s.get(i);
                assert!(
                    back == v || (back.is_nan() && v.is_nan()),
                    "{v} came back as {back}"
                );
            }
        }
        assert_eq!(Samples::compact(vec![1.0; 10]).bytes(), 20);
        assert_eq!(Samples::compact(vec![0.1; 10]).bytes(), 80);
    }

    /// The lattice the former in-memory mosaic built, point by point from the whole inputs:
    /// winners (painting coarsest first, the last listed first, valid samples only), values and
    /// resolution classes (coarse cells with four valid corners drawn from the coarse level).
    fn reference(m: &Mosaic) -> (Vec<u32>, Vec<f64>, Vec<u8>) {
        let (w, h) = (m.width, m.height);
        let dems: Vec<_> = m
            .inputs
            .iter()
            .map(|p| {
                let opts = ReadOptions {
                    nodata: p.nodata,
                    ..ReadOptions::default()
                };
                crate::input::read_dem(&p.path, &opts).unwrap()
            })
            .collect();
        let mut winner = vec![NO_WINNER; w * h];
        let mut order: Vec<usize> = (0..m.inputs.len()).collect();
        order.sort_by_key(|&k| m.paint_key(k));
        for &k in &order {
            let (p, d) = (&m.inputs[k], &dems[k]);
            for r in 0..p.height {
                for c in 0..p.width {
                    if d.is_valid(r * p.width + c) {
                        winner[(p.y0 + r * p.stride()) * w + p.x0 + c * p.stride()] = k as u32;
                    }
                }
            }
        }
        let mut class: Vec<u8> = winner
            .iter()
            .map(|&k| match k {
                NO_WINNER => HOLE,
                k => m.inputs[k as usize].log2,
            })
            .collect();
        let values = (0..w * h)
            .map(|i| match winner[i] {
                NO_WINNER => f64::NAN,
                k => {
                    let p = &m.inputs[k as usize];
                    let (c, r) = ((i % w - p.x0) >> p.log2, (i / w - p.y0) >> p.log2);
                    dems[k as usize].values[r * p.width + c]
                }
            })
            .collect();
        for (p, d) in m.inputs.iter().zip(&dems).filter(|(p, _)| p.log2 > 0) {
            let s = p.stride();
            for r in 0..p.height - 1 {
                for c in 0..p.width - 1 {
                    let corners = [(c, r), (c + 1, r), (c, r + 1), (c + 1, r + 1)];
                    if corners.iter().all(|&(c, r)| d.is_valid(r * p.width + c)) {
                        for y in p.y0 + r * s..=p.y0 + (r + 1) * s {
                            for x in p.x0 + c * s..=p.x0 + (c + 1) * s {
                                if class[y * w + x] == HOLE {
                                    class[y * w + x] = COARSE_ONLY;
                                }
                            }
                        }
                    }
                }
            }
        }
        (winner, values, class)
    }

    /// Inputs at strides 1, 2 and 4 that overlap (agreeing where they share a spacing), with
    /// nodata that falls through to coarser inputs: every block size, down to one row a block
    /// and under a cache that keeps nothing, composes the lattice the whole inputs make.
    #[test]
    fn blocks_of_any_size_compose_the_whole_inputs_lattice() {
        use crate::write::{Raster, write_geotiff};
        let dir = tempfile::tempdir().unwrap();
        const ND: f64 = -9999.0;
        // (name, lattice column and row of the first sample, stride, columns, rows)
        let inputs = [
            ("fine_a", 5, 7, 1, 30, 25),
            ("coarse", 0, 0, 4, 20, 15),
            ("fine_b", 21, 19, 1, 20, 22),
            ("medium", 2, 30, 2, 16, 12),
        ];
        let mut paths = Vec::new();
        for (name, x0, y0, s, w, h) in inputs {
            let values = (0..w * h)
                .map(|i| {
                    let (x, y) = (x0 + (i % w) * s, y0 + (i / w) * s);
                    // Holes: a block in `fine_a` (where `fine_b` and `coarse` show through), a
                    // coarse sample, a diagonal of `medium`.
                    let hole = match name {
                        "fine_a" => (22..27).contains(&x) && (20..30).contains(&y),
                        "coarse" => (x, y) == (40, 20),
                        _ => name == "medium" && i % (w + 1) == 3,
                    };
                    if hole {
                        ND
                    } else {
                        // One function of the lattice point per stride: inputs of one spacing
                        // agree where they overlap.
                        ((x * 7 + y * 13) % 50) as f64 + 100.0 * s as f64
                    }
                })
                .collect();
            let r = Raster {
                width: w,
                height: h,
                values,
                georef: Some(GeoRef {
                    epsg: Some(32632),
                    origin_x: 500_000.0 + x0 as f64 * 10.0,
                    origin_y: 4_000_000.0 - y0 as f64 * 10.0,
                    pixel_x: 10.0 * s as f64,
                    pixel_y: 10.0 * s as f64,
                    pixel_is_area: false,
                    wkt: None,
                }),
            };
            let path = dir.path().join(format!("{name}.tif"));
            write_geotiff(std::fs::File::create(&path).unwrap(), &r, Some(ND), false).unwrap();
            paths.push(path);
        }
        let mut m = mosaic(&paths, &ReadOptions::default(), 1 << 30).unwrap();
        assert_eq!((m.width, m.height), (77, 57));
        let (winner, values, class) = reference(&m);
        assert!(class.contains(&COARSE_ONLY) && class.contains(&HOLE) && class.contains(&1));
        let same = |a: &[f64], b: &[f64]| {
            a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
        };
        for (points, budget) in [(BLOCK_POINTS, 1 << 30), (1, 0), (3 * 77 + 5, 4096)] {
            m.block_points = points;
            m.cache = BandCache::new(budget);
            let survey = m.survey().unwrap();
            assert!(
                survey.resolution.class[..] == class[..],
                "classes, blocks of {points}"
            );
            let valid: Vec<f64> = values.iter().copied().filter(|v| !v.is_nan()).collect();
            let lo = valid.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = valid.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            assert_eq!(survey.range, (lo, hi));
            let (mut got_w, mut got_v) = (Vec::new(), Vec::new());
            m.for_each_block_winners(&mut |y0, v, w| {
                assert_eq!(y0 * m.width, got_v.len());
                got_v.extend_from_slice(v);
                got_w.extend_from_slice(w);
                Ok(())
            })
            .unwrap();
            assert!(got_w == winner, "winners, blocks of {points}");
            assert!(same(&got_v, &values), "values, blocks of {points}");
            let mut streamed = Vec::new();
            m.for_each_block(&mut |_, v| {
                streamed.extend_from_slice(v);
                Ok(())
            })
            .unwrap();
            assert!(same(&streamed, &values), "source, blocks of {points}");
        }
        // A sample of `fine_b` changed where it overlaps `fine_a`: refused, naming both.
        let mut b = crate::input::read_dem(&paths[2], &ReadOptions::default()).unwrap();
        b.values[0] += 2.5;
        let r = Raster {
            width: b.width,
            height: b.height,
            values: b.values,
            georef: b.georef,
        };
        write_geotiff(
            std::fs::File::create(&paths[2]).unwrap(),
            &r,
            Some(ND),
            false,
        )
        .unwrap();
        let e = mosaic(&paths, &ReadOptions::default(), 1 << 30)
            .unwrap()
            .survey()
            .err()
            .expect("disagreeing tiles accepted")
            .to_string();
        assert!(
            e.contains("fine_b.tif")
                && e.contains("fine_a.tif")
                && e.contains("disagree on 1 of their")
                && e.contains("by up to 2.5"),
            "{e}"
        );
    }
}
