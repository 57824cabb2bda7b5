//! Several georeferenced inputs at power-of-two spacings as one variable-resolution lattice
//! (paper §5, "graph construction"; [`cbdam_codec::hierarchy::resolution`]).
//!
//! The lattice has the finest input's spacing and covers the union of the inputs. A coarser input
//! must sample it at a stride of `2^j` lattice points, its samples on the lattice and on
//! multiples of its stride from the lattice origin (so they are vertices of level `L − 2j`).
//! Nothing is resampled: any other geometry is an error that says what is required.
//!
//! The merged heights are never materialised: [`Mosaic`] is a [`SampleSource`] that composes
//! each block of lattice rows from the inputs when the quantizer asks for it, so what the lattice
//! itself costs is one byte per point (which input wins where, [`Mosaic::source`]) on top of the
//! inputs and the quantized grid ([`bytes_in_memory`]). Inputs that do not fit under
//! `--memory-limit` go to memory-mapped temporary files ([`Store`]); a build whose lattice alone
//! does not fit is refused before the lattice is allocated. Each input is still read whole once
//! (8 bytes a sample while it is narrowed), one at a time.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use crate::error::{Context, Result, bail};
use crate::tiles::{Tile, VrtPlacement};
use cbdam_codec::CodecError;
use cbdam_codec::hierarchy::Resolution;
use cbdam_codec::hierarchy::resolution::{COARSE_ONLY, HOLE};
use cbdam_codec::input::{BlockFn, Dem, GeoRef, ReadOptions, SampleSource, SampleType, read_dem};
use rayon::prelude::*;

/// Relative tolerance on spacing ratios: GeoTIFF pixel scales are decimal doubles (e.g.
/// 1/3600°), so ratios of exact powers of two come out within a few ulps.
const RATIO_TOLERANCE: f64 = 1e-9;
/// Tolerance, in fine samples, on how far an input's origin may lie from a lattice point:
/// tie points are printed decimals too.
const ORIGIN_TOLERANCE: f64 = 1e-6;
/// Bytes per lattice point that a multi-input build keeps in memory besides its inputs: the
/// winning input (u8), the encoder's resolution classes (u8) and the quantized grid (i32 + bool).
/// The encoder's reconstruction field (4 bytes per point of the domain) comes on top, in memory or
/// in a temporary file ([`crate::plan::storage_for`]).
pub const BYTES_PER_POINT: u64 = 1 + 1 + 5;

/// Lattice points composed per block (whole rows, at least one): 1 MiB of `f64`, enough rows
/// for both cores and sequential reads of the inputs.
const BLOCK_POINTS: usize = 1 << 17;

/// What a multi-input build of a `width × height` lattice from inputs of `input_bytes` bytes
/// ([`Samples::bytes`]) holds in memory before its reconstruction field: the inputs,
/// [`BYTES_PER_POINT`] per lattice point, and one block of composed rows.
pub fn bytes_in_memory(width: usize, height: usize, input_bytes: u64) -> u64 {
    let points = (width as u64).saturating_mul(height as u64);
    let block = 8 * (BLOCK_POINTS.max(width) as u64).min(points);
    points
        .saturating_mul(BYTES_PER_POINT)
        .saturating_add(input_bytes)
        .saturating_add(block)
}

/// Where an input's narrowed samples live: in memory, or in a memory-mapped temporary file
/// (created unlinked in the system temporary directory, so the kernel writes its pages back to
/// disk under memory pressure and nothing is left behind) once the inputs exceed the build's
/// memory limit.
#[derive(Debug)]
pub enum Store<T> {
    /// Anonymous memory.
    Memory(Vec<T>),
    /// A mapped temporary file holding `len` values.
    Mapped(memmap2::MmapMut, usize),
}

impl<T: bytemuck::Pod> Store<T> {
    /// `values` in a mapped temporary file.
    fn spill(values: &[T]) -> std::io::Result<Self> {
        let bytes: &[u8] = bytemuck::cast_slice(values);
        let file = tempfile::tempfile()?;
        // A zero-length map is an error on some platforms; an empty input never gets here (it
        // has a valid sample), but one byte costs nothing.
        file.set_len(bytes.len().max(1) as u64)?;
        // SAFETY: the file is ours alone (unlinked at creation), so nothing else can change or
        // truncate it while mapped.
        let mut map = unsafe { memmap2::MmapMut::map_mut(&file)? };
        map[..bytes.len()].copy_from_slice(bytes);
        Ok(Self::Mapped(map, values.len()))
    }
}

impl<T: bytemuck::Pod> std::ops::Deref for Store<T> {
    type Target = [T];
    fn deref(&self) -> &[T] {
        match self {
            Self::Memory(v) => v,
            // The map is page-aligned and at least `len` values long (an empty input maps one
            // byte), so the cast never fails.
            Self::Mapped(map, len) => bytemuck::cast_slice(&map[..len * std::mem::size_of::<T>()]),
        }
    }
}

/// An input's samples in the narrowest type that holds every one of them exactly, NaN included:
/// SRTM's 16-bit integers cost 2 bytes a sample instead of the reader's 8.
#[derive(Debug)]
pub enum Samples {
    /// Whole numbers in the `i16` range.
    I16(Store<i16>),
    /// Values that `f32` represents exactly, and NaN.
    F32(Store<f32>),
    /// Anything else.
    F64(Store<f64>),
}

impl Samples {
    /// The narrowest exact representation of `values`, in memory.
    pub fn compact(values: Vec<f64>) -> Self {
        // `as` saturates and maps NaN to 0, so the round trip fails exactly where the narrow
        // type cannot hold the value (a zero's sign is the only thing dropped).
        if values.iter().all(|&v| f64::from(v as i16) == v) {
            Self::I16(Store::Memory(values.iter().map(|&v| v as i16).collect()))
        } else if values
            .iter()
            .all(|&v| v.is_nan() || f64::from(v as f32) == v)
        {
            Self::F32(Store::Memory(values.iter().map(|&v| v as f32).collect()))
        } else {
            Self::F64(Store::Memory(values))
        }
    }

    /// The same samples in a memory-mapped temporary file (a no-op if they are already).
    pub fn spill(self) -> std::io::Result<Self> {
        Ok(match self {
            Self::I16(Store::Memory(v)) => Self::I16(Store::spill(&v)?),
            Self::F32(Store::Memory(v)) => Self::F32(Store::spill(&v)?),
            Self::F64(Store::Memory(v)) => Self::F64(Store::spill(&v)?),
            mapped => mapped,
        })
    }

    /// Sample `i`.
    #[inline]
    pub fn get(&self, i: usize) -> f64 {
        match self {
            Self::I16(v) => f64::from(v[i]),
            Self::F32(v) => f64::from(v[i]),
            Self::F64(v) => v[i],
        }
    }

    /// Bytes of the samples, wherever they are.
    pub fn bytes(&self) -> u64 {
        match self {
            Self::I16(v) => 2 * v.len() as u64,
            Self::F32(v) => 4 * v.len() as u64,
            Self::F64(v) => 8 * v.len() as u64,
        }
    }

    /// Bytes held in anonymous memory: [`Samples::bytes`], or 0 once spilled.
    pub fn bytes_in_memory(&self) -> u64 {
        if self.is_spilled() { 0 } else { self.bytes() }
    }

    /// Whether the samples are in a mapped temporary file.
    pub fn is_spilled(&self) -> bool {
        matches!(
            self,
            Self::I16(Store::Mapped(..))
                | Self::F32(Store::Mapped(..))
                | Self::F64(Store::Mapped(..))
        )
    }
}

/// Where one input lies on the lattice.
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
    /// Its size, type, nodata value and georeferencing; `values` is empty (see `samples`).
    pub dem: Dem,
    /// Its samples, row-major.
    pub samples: Samples,
}

impl Placement {
    fn stride(&self) -> usize {
        1 << self.log2
    }

    /// Whether sample `i` holds a height ([`Dem::is_valid`]).
    fn is_valid(&self, i: usize) -> bool {
        let v = self.samples.get(i);
        !v.is_nan() && self.dem.nodata != Some(v)
    }
}

/// The merged lattice. As a [`SampleSource`] it yields the winning sample of every lattice point
/// (NaN where none, no nodata value), row block by row block.
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
    /// Per lattice point: the index of the winning input in `inputs`, or [`COARSE_ONLY`] /
    /// [`HOLE`].
    pub source: Vec<u8>,
    /// The inputs in command-line order.
    pub inputs: Vec<Placement>,
}

impl Mosaic {
    /// The winning sample at lattice index `i` (row-major), NaN where no input has one.
    pub fn value(&self, i: usize) -> f64 {
        match self.source[i] {
            COARSE_ONLY | HOLE => f64::NAN,
            k => {
                let p = &self.inputs[usize::from(k)];
                let (x, y) = (i % self.width, i / self.width);
                let (c, r) = ((x - p.x0) >> p.log2, (y - p.y0) >> p.log2);
                p.samples.get(r * p.dem.width + c)
            }
        }
    }

    /// Smallest and largest winning sample, `None` if there is none.
    pub fn valid_range(&self) -> Option<(f64, f64)> {
        (0..self.source.len())
            .into_par_iter()
            .filter(|&i| self.source[i] != COARSE_ONLY && self.source[i] != HOLE)
            .map(|i| {
                let v = self.value(i);
                (v, v)
            })
            .reduce_with(|a, b| (a.0.min(b.0), a.1.max(b.1)))
    }

    /// The winning samples of lattice rows `rows` into `out` (row-major).
    fn compose(&self, rows: std::ops::Range<usize>, out: &mut Vec<f64>) {
        let w = self.width;
        out.clear();
        out.resize(rows.len() * w, f64::NAN);
        out.par_chunks_mut(w).zip(rows).for_each(|(row, y)| {
            for (x, v) in row.iter_mut().enumerate() {
                *v = self.value(y * w + x);
            }
        });
    }

    /// The encoder's view: the stride of the winning sample at each point.
    pub fn resolution(&self) -> Resolution {
        let strides: Vec<u8> = self.inputs.iter().map(|p| p.log2).collect();
        Resolution {
            class: self
                .source
                .iter()
                .map(|&s| match s {
                    COARSE_ONLY | HOLE => s,
                    i => strides[i as usize],
                })
                .collect(),
        }
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
        let rows = (BLOCK_POINTS / self.width.max(1)).max(1);
        let mut block = Vec::new();
        for y0 in (0..self.height).step_by(rows) {
            let y1 = (y0 + rows).min(self.height);
            self.compose(y0..y1, &mut block);
            f(y0, &block)?;
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

/// Checks a tile read through a VRT against where the VRT places it, and gives it the VRT's
/// georeferencing where it has none of its own.
fn place_vrt_tile(path: &Path, dem: &mut Dem, v: &VrtPlacement) -> Result<()> {
    if (dem.width, dem.height) != (v.width, v.height) {
        bail!(
            "{}: <SrcRect>/<DstRect> of {} are {}×{} but the tile is {}×{}: only whole tiles \
             placed without scaling are supported",
            v.vrt.display(),
            path.display(),
            v.width,
            v.height,
            dem.width,
            dem.height
        );
    }
    let Some(g) = &dem.georef else {
        dem.georef = Some(v.georef.clone());
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
/// their own georeferencing, which they keep; a tile without one takes the VRT's). Inputs of the
/// same spacing that overlap (tiles sharing edge rows) must hold the same valid samples there.
pub fn mosaic_tiles(tiles: &[Tile], opts: &ReadOptions, memory_limit: u64) -> Result<Mosaic> {
    if tiles.is_empty() {
        bail!("no input given");
    }
    if tiles.len() >= usize::from(COARSE_ONLY) {
        bail!(
            "{} inputs: at most {} can be combined",
            tiles.len(),
            COARSE_ONLY - 1
        );
    }
    let mut dems = Vec::new();
    let mut held = 0u64;
    for tile in tiles {
        let path = &tile.path;
        let tile_opts = ReadOptions {
            nodata: opts.nodata.or(tile.vrt.as_ref().and_then(|v| v.nodata)),
            ..opts.clone()
        };
        let mut dem =
            read_dem(path, &tile_opts).with_context(|| format!("reading {}", path.display()))?;
        if let Some(v) = &tile.vrt {
            place_vrt_tile(path, &mut dem, v)?;
        }
        let Some(g) = &dem.georef else {
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
        if dem.valid_count() == 0 {
            bail!("{} has no valid sample (all nodata or NaN)", path.display());
        }
        // Narrowed as soon as read, so that only one input is ever held at 8 bytes a sample.
        let mut samples = Samples::compact(std::mem::take(&mut dem.values));
        // Once the inputs read so far exceed the limit, this one and later ones go to mapped
        // temporary files, which the kernel pages out as it needs to.
        if held.saturating_add(samples.bytes()) > memory_limit {
            samples = samples
                .spill()
                .with_context(|| format!("spilling {} to a temporary file", path.display()))?;
        }
        held = held.saturating_add(samples.bytes_in_memory());
        dems.push((path.clone(), dem, samples));
    }
    let geo = |k: usize| dems[k].1.georef.as_ref().expect("checked above");
    // One coordinate reference system: heights and positions of different CRSs cannot share
    // a lattice without reprojection, which this builder does not do.
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
    // The finest input sets the lattice; ties go to the first listed.
    let fine = (0..dems.len())
        .min_by(|&a, &b| geo(a).pixel_x.total_cmp(&geo(b).pixel_x))
        .expect("at least one input");
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
    // The lattice origin must sit on every input's stride: congruent to the coarsest input's
    // offset modulo its stride, which every other input must agree with modulo its own.
    let coarsest = (0..placed.len())
        .max_by_key(|&k| placed[k].2)
        .expect("at least one input");
    let big = 1i64 << placed[coarsest].2;
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
    let (origin_x, origin_y) = (lowest(|p| p.0), lowest(|p| p.1));
    let mut width = 0usize;
    let mut height = 0usize;
    let mut inputs = Vec::new();
    for ((path, dem, samples), &(ox, oy, log2)) in dems.into_iter().zip(&placed) {
        let p = Placement {
            path,
            x0: (ox - origin_x) as usize,
            y0: (oy - origin_y) as usize,
            log2,
            dem,
            samples,
        };
        width = width.max(p.x0 + (p.dem.width - 1) * p.stride() + 1);
        height = height.max(p.y0 + (p.dem.height - 1) * p.stride() + 1);
        inputs.push(p);
    }
    // The lattice's own arrays stay in memory; if inputs and lattice together are over the
    // limit, spill inputs (largest first) until they fit, and refuse only if the lattice alone
    // does not.
    let need = |inputs: &[Placement]| {
        let input_bytes: u64 = inputs.iter().map(|p| p.samples.bytes_in_memory()).sum();
        bytes_in_memory(width, height, input_bytes)
    };
    while need(&inputs) > memory_limit {
        let Some(k) = (0..inputs.len())
            .filter(|&k| inputs[k].samples.bytes_in_memory() > 0)
            .max_by_key(|&k| inputs[k].samples.bytes_in_memory())
        else {
            bail!(
                "the combined lattice is {width}×{height} points at the finest spacing, which \
                 needs about {} MiB in memory ({BYTES_PER_POINT} bytes a point) even with every \
                 input in a temporary file: above --memory-limit ({} MiB)",
                need(&inputs) >> 20,
                memory_limit >> 20
            );
        };
        let p = &mut inputs[k];
        let samples = std::mem::replace(&mut p.samples, Samples::compact(Vec::new()));
        p.samples = samples
            .spill()
            .with_context(|| format!("spilling {} to a temporary file", p.path.display()))?;
    }
    let len = width * height;
    let mut source = vec![HOLE; len];
    // Coarsest first, so finer samples overwrite; among equal strides the first listed wins.
    let mut order: Vec<usize> = (0..inputs.len()).collect();
    order.sort_by_key(|&k| (std::cmp::Reverse(inputs[k].log2), std::cmp::Reverse(k)));
    // Inputs of one spacing that overlap (tiles sharing edge rows) must agree there: per pair
    // (earlier, later input), the valid samples both hold, how many differ and by how much.
    let mut shared: BTreeMap<(usize, usize), (usize, usize, f64)> = BTreeMap::new();
    for &k in &order {
        let p = &inputs[k];
        let s = p.stride();
        for r in 0..p.dem.height {
            for c in 0..p.dem.width {
                let i = r * p.dem.width + c;
                if p.is_valid(i) {
                    let at = (p.y0 + r * s) * width + p.x0 + c * s;
                    let prev = usize::from(source[at]);
                    if source[at] != HOLE && inputs[prev].log2 == p.log2 {
                        let q = &inputs[prev];
                        let (x, y) = (at % width, at / width);
                        let j = ((y - q.y0) >> q.log2) * q.dem.width + ((x - q.x0) >> q.log2);
                        let (a, b) = (p.samples.get(i), q.samples.get(j));
                        let e = shared.entry((k, prev)).or_insert((0, 0, 0.0));
                        e.0 += 1;
                        if a != b {
                            e.1 += 1;
                            e.2 = e.2.max((a - b).abs());
                        }
                    }
                    source[at] = k as u8;
                }
            }
        }
    }
    let clashes: Vec<_> = shared.iter().filter(|(_, e)| e.1 > 0).collect();
    if let Some(&(&(a, b), &(n, bad, most))) = clashes.first() {
        bail!(
            "tiles {} and {} disagree on {bad} of their {n} shared samples by up to {most} \
             (height units){}: inputs of the same spacing must hold the same values where they \
             overlap (shared edge rows)",
            inputs[a].path.display(),
            inputs[b].path.display(),
            match clashes.len() - 1 {
                0 => String::new(),
                more => format!(", and {more} more pairs of tiles disagree"),
            }
        );
    }
    // Points between a coarse input's samples, in a cell whose four corners have data, are drawn
    // from the coarse level unless some input has a sample there.
    for p in inputs.iter().filter(|p| p.log2 > 0) {
        let s = p.stride();
        let (w, h) = (p.dem.width, p.dem.height);
        for r in 0..h.saturating_sub(1) {
            for c in 0..w.saturating_sub(1) {
                let corners = [(c, r), (c + 1, r), (c, r + 1), (c + 1, r + 1)];
                if !corners.iter().all(|&(c, r)| p.is_valid(r * w + c)) {
                    continue;
                }
                for y in p.y0 + r * s..=p.y0 + (r + 1) * s {
                    for x in p.x0 + c * s..=p.x0 + (c + 1) * s {
                        let at = y * width + x;
                        if source[at] == HOLE {
                            source[at] = COARSE_ONLY;
                        }
                    }
                }
            }
        }
    }
    let types: Vec<SampleType> = inputs.iter().map(|p| p.dem.sample_type).collect();
    let sample_type = if types.iter().all(|&t| t == types[0]) {
        types[0]
    } else if types.iter().all(|t| t.is_integer()) {
        SampleType::I32
    } else {
        SampleType::F64
    };
    let fine_geo = inputs[fine].dem.georef.clone().expect("checked above");
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
        source,
        inputs,
    })
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
        assert_eq!(Samples::compact(vec![1.0; 10]).bytes_in_memory(), 20);
        assert_eq!(Samples::compact(vec![0.1; 10]).bytes(), 80);
    }

    /// Spilled samples read back exactly what was in memory, and count as not in memory.
    #[test]
    fn spilled_samples_are_the_same_samples() {
        for values in [
            vec![],
            vec![1.0, -3.0, 32767.0, -32768.0],
            vec![0.5, f64::NAN, 1e30, -2.25],
            vec![0.1, 1e-300, -7.0, 123456.789],
        ] {
            let memory = Samples::compact(values.clone());
            let spilled = Samples::compact(values.clone()).spill().unwrap();
            assert!(spilled.is_spilled() && !memory.is_spilled());
            assert_eq!(spilled.bytes_in_memory(), 0);
            assert_eq!(spilled.bytes(), memory.bytes());
            for i in 0..values.len() {
                assert_eq!(
                    spilled.get(i).to_bits(),
                    memory.get(i).to_bits(),
                    "{values:?}"
                );
            }
            // Spilling twice is a no-op.
            assert!(spilled.spill().unwrap().is_spilled());
        }
    }
}
