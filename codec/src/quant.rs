//! From metres to integer heights, and the near-lossless quantizer.
//!
//! Heights are stored as integers `n` in a unit `u` around an offset: `h = offset + n·u`.
//! Two cases, decided by [`QuantPlan::new`]:
//! - **Lattice input**: the samples lie on a grid of values `u` (whole metres, 0.1 m Terrain-RGB;
//!   detected or given). Mapping to integers is exact, and residuals are quantized with step
//!   `(2k+1)·u`, `k = ⌊ε/u⌋`: error ≤ `k·u ≤ ε`, lossless when `ε < u`.
//! - **Float input** (no quantum): the samples are first pre-quantized to the power of two
//!   `u ∈ (ε/16, ε/8]` (error ≤ `u/2`), then quantized with `k = ⌊(ε − u/2)/u⌋ ≥ 7`: total error
//!   ≤ `k·u + u/2 ≤ ε`. A binary `u` keeps `offset + n·u` exact in `f64`. When that unit is so
//!   fine that heights would overflow (ε of a few mm over a whole planet's relief), `u = ε/8`.
//!
//! Either way every reconstructed value is within `k` units of the integer input, which the
//! tests check exactly in integers.

use crate::CodecError;
use rayon::prelude::*;

use crate::lifting::{MAX_ABS_HEIGHT, PREDICTION_LIMIT};
#[cfg(doc)]
use crate::samples::detect_quantum;
use crate::samples::{Dem, QuantumScan, SampleSource};
use crate::temp::{LatticeArray, TempStorage};

mod rounding;

/// Samples per parallel work item of the passes over the input.
const CHUNK: usize = 1 << 16;

/// Largest magnitude of an input height in units: no larger than the clamp on predictions, so a
/// clamped prediction plus a residual within `k` always reaches a valid target.
pub const MAX_ABS_INPUT: i32 = PREDICTION_LIMIT;

/// Largest quantizer half-step `k`: reconstructions are bounded by `PREDICTION_LIMIT + k`.
pub const MAX_K: i32 = MAX_ABS_HEIGHT - PREDICTION_LIMIT;

/// `x` rounded half away from zero. `f64::round` is a library call on baseline x86-64 (no
/// SSE4.1), a visible cost at one call per input sample; the truncating conversion is one
/// instruction. Saturates for |x| ≥ 2⁶³, which every caller rejects as out of range anyway.
#[inline]
fn round_to_i64(x: f64) -> i64 {
    (x + 0.5f64.copysign(x)) as i64
}

/// Uniform quantizer with odd step `2k + 1` (in units): index `⌊(r + k) / (2k+1)⌋`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Quantizer {
    k: i32,
    /// `⌈2⁶⁴ / step⌉` (0 for step 1): division by the step as a multiplication, exact for
    /// 32-bit numerators. A 64-bit division costs tens of cycles, at one per encoded sample.
    magic: u64,
    /// `⌈FAST_INDEX_RANGE / step⌉`: numerators are shifted by this many steps.
    shift_q: i64,
}

/// Numerators `|r + k|` below this take the multiplication in [`Quantizer::index`].
const FAST_INDEX_RANGE: i64 = 1 << 30;

impl Quantizer {
    const fn from_k(k: i32) -> Self {
        let step = 2 * k as u64 + 1;
        let magic = if step == 1 { 0 } else { u64::MAX / step + 1 };
        let step = step as i64;
        let shift_q = (FAST_INDEX_RANGE + step - 1) / step;
        Self { k, magic, shift_q }
    }

    /// A quantizer whose reconstruction error is at most `k` units.
    pub fn new(k: u32) -> Result<Self, CodecError> {
        let k = i32::try_from(k)
            .ok()
            .filter(|&k| k <= MAX_K)
            .ok_or_else(|| CodecError::invalid(format!("quantizer half-step {k} is too large")))?;
        Ok(Self::from_k(k))
    }

    /// The error bound in units.
    pub fn k(&self) -> i32 {
        self.k
    }

    /// The step `2k + 1`.
    pub fn step(&self) -> i32 {
        2 * self.k + 1
    }

    /// The index of residual `r`. Floor division: residuals are negative half of the time, and
    /// Rust's truncating `/` would round those towards zero and break the bound.
    #[inline]
    pub fn index(&self, r: i64) -> i64 {
        let x = r + i64::from(self.k);
        let step = i64::from(self.step());
        if self.magic == 0 {
            return x;
        }
        if x.abs() >= FAST_INDEX_RANGE {
            return x.div_euclid(step);
        }
        // Shifted by a multiple of the step to a non-negative numerator below 2³², where
        // ⌊n / d⌋ = ⌊n · ⌈2⁶⁴/d⌉ / 2⁶⁴⌋ for every d < 2³² (Lemire, Kaser and Kurz 2019).
        let n = (x + self.shift_q * step) as u64;
        let q = ((u128::from(n) * u128::from(self.magic)) >> 64) as i64;
        q - self.shift_q
    }
}

/// How metres become integer units for one dataset at one tolerance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct QuantPlan {
    /// The integer unit `u`, metres.
    pub unit: f64,
    /// Height of integer 0, metres (a multiple of `unit` for lattice input).
    pub offset: f64,
    /// Residual quantizer.
    pub quantizer: Quantizer,
    /// Whether the input lies on multiples of `unit` (no pre-quantization).
    pub lattice: bool,
    /// For lattice input: the largest distance, metres, between a sample as stored and its
    /// lattice value (e.g. 0.1 m data stored as float32 is off by up to half an f32 ulp). It is
    /// taken out of the budget, so the bound holds against the samples exactly as stored.
    pub representation_error: f64,
    /// The tolerance asked for, metres.
    pub epsilon: f64,
    /// The RMS error bound of a `--rms-error` build: the quantizer was chosen so that the finest
    /// level's root-mean-square error over every valid sample is at most `target`. `None` for
    /// a build that bounds the maximum error only.
    pub rms: Option<RmsBound>,
}

/// The root-mean-square error bound of a repository built with `--rms-error` (header flag bit
/// 4, `docs/FORMAT.md`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RmsBound {
    /// The bound asked for, metres.
    pub target: f64,
    /// The RMS error the build measured at the finest level against its input, metres (at
    /// most `target`).
    pub measured: f64,
}

/// Relative slack when dividing decimal tolerances by decimal quanta: 0.3 / 0.1 is
/// 2.9999999999999996 in binary, and a user asking for 0.3 m on 0.1 m data means k = 3.
const DECIMAL_SLACK: f64 = 1e-9;

impl QuantPlan {
    /// Plans the integer mapping for samples in `[min, max]` metres at tolerance `epsilon`;
    /// `quantum` is the data's value grid when known.
    pub fn new(epsilon: f64, quantum: Option<f64>, min: f64, max: f64) -> Result<Self, CodecError> {
        Self::with_representation_error(epsilon, quantum, 0.0, min, max)
    }

    /// Like [`QuantPlan::new`], for lattice data whose samples are up to `deviation` metres off
    /// their lattice values.
    pub fn with_representation_error(
        epsilon: f64,
        quantum: Option<f64>,
        deviation: f64,
        min: f64,
        max: f64,
    ) -> Result<Self, CodecError> {
        if !(epsilon.is_finite() && epsilon > 0.0) {
            return Err(CodecError::invalid(format!(
                "the maximum error must be a positive number of metres, not {epsilon}"
            )));
        }
        if !(min.is_finite() && max.is_finite() && min <= max) {
            return Err(CodecError::invalid(format!(
                "invalid height range {min}…{max}"
            )));
        }
        let reach_in = |u: f64| reach_in(u, min, max);
        let (unit, k, lattice) = match quantum {
            Some(u) => (u, lattice_steps(epsilon, u, deviation)?, true),
            None => {
                // Prefer a power of two (exact in binary, and the step (2k+1)·u ≈ 2ε − u wastes
                // less of the budget), unless it is so fine that heights overflow; then ε/8.
                let binary = 2f64.powi((epsilon / 8.0).log2().floor() as i32);
                let fits = reach_in(binary).1 <= f64::from(MAX_ABS_INPUT);
                let u = if fits { binary } else { epsilon / 8.0 };
                let k = ((epsilon - u / 2.0) / u).floor();
                (u, k, false)
            }
        };
        if !(0.0..=f64::from(MAX_K)).contains(&k) {
            return Err(CodecError::invalid(format!(
                "tolerance {epsilon} m is out of range for unit {unit} m"
            )));
        }
        let (offset, reach) = reach_in(unit);
        if reach > f64::from(MAX_ABS_INPUT) {
            let smallest = (max - min) / 2.0 / f64::from(MAX_ABS_INPUT) * 8.0;
            return Err(CodecError::invalid(format!(
                "tolerance {epsilon} m is too fine for heights {min}…{max} m: integer heights would \
                 overflow; the smallest tolerance for this range is about {smallest:.2e} m"
            )));
        }
        Ok(Self {
            unit,
            offset,
            quantizer: Quantizer::new(k as u32)?,
            lattice,
            representation_error: if lattice { deviation } else { 0.0 },
            epsilon,
            rms: None,
        })
    }

    /// Plans for a DEM: its valid height range, and its value quantum — `quantum` if given,
    /// otherwise the one [`detect_quantum`] finds (none for float data off any grid).
    pub fn for_dem(dem: &Dem, epsilon: f64, quantum: Option<f64>) -> Result<Self, CodecError> {
        Self::for_source(dem, epsilon, quantum)
    }

    /// [`QuantPlan::for_dem`] for samples streamed in blocks: one pass for the range and the
    /// quantum, a second for lattice input's representation error. Same result as `for_dem` on
    /// the same samples.
    pub fn for_source(
        src: &dyn SampleSource,
        epsilon: f64,
        quantum: Option<f64>,
    ) -> Result<Self, CodecError> {
        let nodata = src.nodata();
        let is_valid = |v: f64| !v.is_nan() && nodata != Some(v);
        let given = quantum.is_some();
        let (lo, hi, quantum) = scan_source(src, quantum)?;
        let Some(u) = quantum else {
            return Self::new(epsilon, None, lo, hi);
        };
        // How far the stored samples are from their lattice values, measured on the same
        // offset lattice the plan will use (the offset is a multiple of u).
        let offset = ((lo + hi) / 2.0 / u).round() * u;
        let mut deviation = 0.0f64;
        src.for_each_block(&mut |_, block| {
            let d = block
                .par_chunks(CHUNK)
                .map(|chunk| {
                    chunk
                        .iter()
                        .filter(|&&v| is_valid(v))
                        .map(|&v| (offset + round_to_i64((v - offset) / u) as f64 * u - v).abs())
                        .fold(0.0, f64::max)
                })
                .reduce(|| 0.0, f64::max);
            deviation = deviation.max(d);
            Ok(())
        })?;
        let plan = Self::with_representation_error(epsilon, Some(u), deviation, lo, hi)?;
        Ok(if given {
            plan
        } else {
            plan.coarser_float_plan(lo, hi).unwrap_or(plan)
        })
    }

    /// Lattice data stored with a representation error (float32 Terrain-RGB: 0.1 m steps that
    /// float32 cannot hold exactly) lose that error from the budget, which at a tolerance that
    /// is a multiple of the quantum costs a whole step of `k`: at ε = 0.1 m on 0.1 m steps the
    /// lattice plan is lossless (step 0.1 m) where the float plan quantizes with a step of
    /// 0.195 m. Coarser steps code fewer bits, so where the float plan's step is coarser it is
    /// the better plan (measured on fuji_terrainrgb.tif, `cbdam build --max-error ε`: 6.302
    /// instead of 7.263 bits/sample at 0.1 m, 4.006 instead of 4.062 at 0.5 m). Only for a
    /// detected quantum: one the caller gives is kept.
    fn coarser_float_plan(&self, lo: f64, hi: f64) -> Option<Self> {
        if !self.lattice || self.representation_error == 0.0 {
            return None;
        }
        let float = Self::new(self.epsilon, None, lo, hi).ok()?;
        (float.step_metres() > self.step_metres()).then_some(float)
    }

    /// The residual quantizer's step, metres.
    fn step_metres(&self) -> f64 {
        f64::from(self.quantizer.step()) * self.unit
    }

    /// [`QuantPlan::for_source`] followed by [`HeightGrid::from_source`], with one pass over the
    /// samples fewer for lattice input: its representation error is measured while quantizing,
    /// which does not depend on it (only the step `k` does). Same plan, same grid and, for bad
    /// input, the same error as the two calls.
    pub fn quantize_source(
        src: &dyn SampleSource,
        epsilon: f64,
        quantum: Option<f64>,
    ) -> Result<(Self, HeightGrid), CodecError> {
        Self::quantize_source_in(src, epsilon, quantum, &TempStorage::Memory)
    }

    /// [`QuantPlan::quantize_source`] with the grid in `storage` (a mapped file for lattices
    /// larger than the memory limit allows): the same plan and values either way.
    pub fn quantize_source_in(
        src: &dyn SampleSource,
        epsilon: f64,
        quantum: Option<f64>,
        storage: &TempStorage,
    ) -> Result<(Self, HeightGrid), CodecError> {
        Self::quantize_source_watched(src, epsilon, quantum, storage, &mut |_, _| {})
    }

    /// [`QuantPlan::quantize_source_in`] calling `watch` after each block of rows is written
    /// ([`RowsWritten`]). A second pass over the samples (a float plan chosen after the first)
    /// writes every row again, from row 0.
    pub fn quantize_source_watched(
        src: &dyn SampleSource,
        epsilon: f64,
        quantum: Option<f64>,
        storage: &TempStorage,
        watch: &mut RowsWritten<'_>,
    ) -> Result<(Self, HeightGrid), CodecError> {
        let given = quantum.is_some();
        let (lo, hi, quantum) = scan_source(src, quantum)?;
        let Some(u) = quantum else {
            let plan = Self::new(epsilon, None, lo, hi)?;
            let grid = HeightGrid::from_source_watched(src, &plan, storage, watch)?;
            return Ok((plan, grid));
        };
        // What `to_units` uses of a lattice plan is its unit and offset, both known now.
        let offset = ((lo + hi) / 2.0 / u).round() * u;
        let provisional = Self {
            unit: u,
            offset,
            quantizer: Quantizer::from_k(0),
            lattice: true,
            representation_error: 0.0,
            epsilon,
            rms: None,
        };
        let mut grid = HeightGrid::empty(src.width(), src.height(), storage)?;
        let nodata = src.nodata();
        let mut deviation = 0.0f64;
        let mut first_bad = None;
        src.for_each_block(&mut |row, block| {
            // Keep measuring past a bad sample: the plan's own error, which `for_source` would
            // have reported first, depends on every sample's deviation.
            let (d, bad) = grid.quantize_rows_measuring(row, block, nodata, &provisional, true);
            grid.written(row, block.len(), watch);
            deviation = deviation.max(d);
            if first_bad.is_none() {
                first_bad = bad;
            }
            Ok(())
        })?;
        let plan = Self::with_representation_error(epsilon, Some(u), deviation, lo, hi)?;
        debug_assert!(plan.unit == u && plan.offset == offset && plan.lattice);
        if let Some(e) = first_bad {
            return Err(e);
        }
        // The same choice as `for_source`; the float plan needs its own pass over the samples.
        if !given && let Some(float) = plan.coarser_float_plan(lo, hi) {
            drop(grid);
            let grid = HeightGrid::from_source_watched(src, &float, storage, watch)?;
            return Ok((float, grid));
        }
        Ok((plan, grid))
    }

    /// The guaranteed bound, metres, on the distance between any valid sample and its
    /// reconstruction as computed in `f64`: [`QuantPlan::quantization_error`] plus
    /// [`QuantPlan::rounding_error`], rounded up. Exactly the quantization error where the
    /// arithmetic is exact (whole metres and other binary lattices).
    pub fn max_error(&self) -> f64 {
        let quantization = self.quantization_error();
        match self.rounding_error() {
            0.0 => quantization,
            rounding => (quantization + rounding).next_up(),
        }
    }

    /// The bound in exact arithmetic, metres: `k·u`, plus `u/2` of pre-quantization for float
    /// input or the representation error of lattice input.
    pub fn quantization_error(&self) -> f64 {
        let k = f64::from(self.quantizer.k()) * self.unit;
        if self.lattice {
            k + self.representation_error
        } else {
            k + self.unit / 2.0
        }
    }

    /// The guarantee as a user reads it: `"0.9375 m"` where the arithmetic is exact, else
    /// `"0.001 m + 3.9e-11 m of float rounding"` (the rounding term rounded up).
    pub fn bound_text(&self) -> String {
        match self.rounding_error() {
            0.0 => format!("{} m", self.quantization_error()),
            r => format!(
                "{} m + {} m of float rounding",
                self.quantization_error(),
                round_up_2_digits(r)
            ),
        }
    }

    /// Metres of integer height `n`.
    pub fn metres(&self, n: i32) -> f64 {
        self.offset + f64::from(n) * self.unit
    }

    /// Integer height of sample `v` (metres); `Ok(None)` for NaN (nodata).
    ///
    /// Errors: infinite values, values out of the planned range, and — for lattice input —
    /// values off the lattice (a wrong quantum override would otherwise break the bound).
    pub fn to_units(&self, v: f64) -> Result<Option<i32>, CodecError> {
        if v.is_nan() {
            return Ok(None);
        }
        if v.is_infinite() {
            return Err(CodecError::invalid(format!("sample value {v} is infinite")));
        }
        let q = round_to_i64((v - self.offset) / self.unit);
        if q.unsigned_abs() > u64::from(MAX_ABS_INPUT.unsigned_abs()) {
            return Err(CodecError::invalid(format!(
                "sample value {v} m is outside the planned height range"
            )));
        }
        let n = q as i32;
        if self.lattice {
            let back = self.metres(n);
            // Exact for integer data; for decimal quanta the nearest f32 of n·u is what the file
            // stored, so allow the representation error of an f32 at that magnitude.
            let slack = (v.abs().max(self.unit) * f64::from(f32::EPSILON)).max(1e-12);
            if (back - v).abs() > slack {
                return Err(CodecError::invalid(format!(
                    "sample value {v} m is not a multiple of the value quantum {} m",
                    self.unit
                )));
            }
        }
        Ok(Some(n))
    }
}

/// `x > 0` rounded up to two significant digits, as text (`3.9e-11`).
fn round_up_2_digits(x: f64) -> String {
    let exponent = x.log10().floor() as i32 - 1;
    let scale = 10f64.powi(exponent);
    let mut mantissa = (x / scale).ceil();
    // The division can round below the true quotient: step up while the value is short of x.
    while mantissa * scale < x {
        mantissa += 1.0;
    }
    // Two digits `m` (10 to 100) times 10^exponent, written as `d.de(exponent + 1)`.
    let (m, e) = match mantissa as u64 {
        100 => (10, exponent + 2),
        m => (m, exponent + 1),
    };
    format!("{}.{}e{e}", m / 10, m % 10)
}

/// One pass over the samples: the valid height range, and the value quantum (`quantum` when
/// given, else detected). Errors when no sample is valid or a valid one is infinite.
fn scan_source(
    src: &dyn SampleSource,
    quantum: Option<f64>,
) -> Result<(f64, f64, Option<f64>), CodecError> {
    let nodata = src.nodata();
    let is_valid = |v: f64| !v.is_nan() && nodata != Some(v);
    let detect = quantum.is_none();
    let ty = src.sample_type();
    #[derive(Clone)]
    struct Scan {
        lo: f64,
        hi: f64,
        quantum: QuantumScan,
    }
    let empty = || Scan {
        lo: f64::INFINITY,
        hi: f64::NEG_INFINITY,
        quantum: QuantumScan::new(ty),
    };
    let mut total = empty();
    src.for_each_block(&mut |_, block| {
        let part = block
            .par_chunks(CHUNK)
            .map(|chunk| {
                let mut s = empty();
                for &v in chunk.iter().filter(|&&v| is_valid(v)) {
                    s.lo = s.lo.min(v);
                    s.hi = s.hi.max(v);
                    if detect {
                        s.quantum.push(v);
                    }
                }
                s
            })
            .reduce(empty, |a, b| Scan {
                lo: a.lo.min(b.lo),
                hi: a.hi.max(b.hi),
                quantum: a.quantum.merge(b.quantum),
            });
        total = Scan {
            lo: total.lo.min(part.lo),
            hi: total.hi.max(part.hi),
            quantum: total.quantum.clone().merge(part.quantum),
        };
        Ok(())
    })?;
    let (lo, hi) = (total.lo, total.hi);
    if lo > hi {
        return Err(CodecError::invalid(
            "the input has no valid sample (all nodata or NaN)",
        ));
    }
    if !(lo.is_finite() && hi.is_finite()) {
        return Err(CodecError::invalid("the input holds infinite heights"));
    }
    Ok((lo, hi, quantum.or_else(|| total.quantum.finish())))
}

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
    fn quantize_rows_measuring(
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
    fn from_source_watched(
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
    fn written(&self, first_row: usize, samples: usize, watch: &mut RowsWritten<'_>) {
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

/// The offset (a multiple of `u` at the range's middle) and the reach of heights `min…max`
/// around it, in units of `u`.
fn reach_in(u: f64, min: f64, max: f64) -> (f64, f64) {
    let offset = ((min + max) / 2.0 / u).round() * u;
    let reach = ((max - offset).abs().max((min - offset).abs()) / u).ceil();
    (offset, reach)
}

/// The quantizer's `k` (as a float, range-checked by the caller) for data on a value grid of
/// quantum `u` whose samples are up to `deviation` metres off it, within tolerance `epsilon`.
fn lattice_steps(epsilon: f64, u: f64, deviation: f64) -> Result<f64, CodecError> {
    if !(u.is_finite() && u > 0.0) {
        return Err(CodecError::invalid(format!(
            "value quantum must be positive, not {u}"
        )));
    }
    if !(deviation.is_finite() && (0.0..u / 2.0).contains(&deviation)) {
        return Err(CodecError::invalid(format!(
            "samples are up to {deviation} m off the value quantum {u} m"
        )));
    }
    if deviation >= epsilon {
        return Err(CodecError::invalid(format!(
            "tolerance {epsilon} m is below the {deviation} m the samples' storage already \
             deviates from their {u} m value grid"
        )));
    }
    // Exact decimal data (deviation 0) keeps the slack for 0.3/0.1-style quotients.
    let budget = if deviation > 0.0 {
        epsilon - deviation
    } else {
        epsilon * (1.0 + DECIMAL_SLACK)
    };
    Ok((budget / u).floor())
}

#[cfg(test)]
mod tests {
    use super::*;

    proptest::proptest! {
        #[test]
        fn quantizer_index_is_floor_division(
            k in proptest::prop_oneof![0i32..300, 0..=MAX_K],
            r in proptest::prop_oneof![-3000i64..3000, -(3i64 << 30)..(3i64 << 30), i64::from(i32::MIN)..=i64::from(i32::MAX)],
        ) {
            let q = Quantizer::new(k as u32).unwrap();
            let step = i64::from(q.step());
            proptest::prop_assert_eq!(q.index(r), (r + i64::from(k)).div_euclid(step));
        }
    }

    #[test]
    fn quantizer_index_is_exact_at_the_ends_of_the_fast_range() {
        for k in [0, 1, 2, 3, 1000, 65535, MAX_K - 1, MAX_K] {
            let q = Quantizer::new(k as u32).unwrap();
            let step = i64::from(q.step());
            for centre in [0, FAST_INDEX_RANGE, -FAST_INDEX_RANGE] {
                for x in centre - 2 * step - 2..=centre + 2 * step + 2 {
                    let r = x - i64::from(k);
                    assert_eq!(q.index(r), x.div_euclid(step), "k {k}, r {r}");
                }
            }
        }
    }

    #[test]
    fn quantizer_error_is_bounded_for_negative_residuals_too() {
        for k in [0u32, 1, 2, 7, 100] {
            let q = Quantizer::new(k).unwrap();
            for r in -1000i64..=1000 {
                let idx = q.index(r);
                let err = r - idx * i64::from(q.step());
                assert!(err.abs() <= i64::from(k), "k={k} r={r} idx={idx}");
            }
        }
    }

    #[test]
    fn plans_use_the_quantum_or_a_binary_unit() {
        let p = QuantPlan::new(1.0, Some(1.0), 1111.0, 3270.0).unwrap();
        assert_eq!((p.unit, p.quantizer.k(), p.lattice), (1.0, 1, true));
        assert_eq!(p.offset, 2191.0, "mid-range 2190.5 rounded to the lattice");
        let p = QuantPlan::new(0.4, Some(1.0), 0.0, 10.0).unwrap();
        assert_eq!(p.quantizer.k(), 0, "ε < u stores lattice data losslessly");
        let p = QuantPlan::new(0.3, Some(0.1), 13.7, 3751.0).unwrap();
        assert_eq!(p.quantizer.k(), 3, "0.3 m on 0.1 m data is three steps");
        let p = QuantPlan::new(1.0, None, 379.6, 410.8).unwrap();
        assert_eq!((p.unit, p.quantizer.k()), (0.125, 7));
        assert!(p.max_error() <= 1.0);
        for eps in [0.0025, 0.01, 0.1, 0.3, 0.5, 1.0, 2.0, 5.0, 100.0] {
            let p = QuantPlan::new(eps, None, -11000.0, 9000.0).unwrap();
            // Within ε in exact arithmetic; the stated bound adds the float rounding term.
            let stated = (p.quantization_error() + p.rounding_error()).next_up();
            assert!(
                p.quantization_error() <= eps && p.max_error() <= stated,
                "{eps}: {p:?}"
            );
            assert!(p.quantizer.k() >= 7, "{eps}: {p:?}");
            if eps > 0.003 {
                assert_eq!(p.unit.log2().fract(), 0.0, "unit is a power of two");
            }
        }
    }

    #[test]
    fn impossible_tolerances_are_refused_with_a_reason() {
        for eps in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert!(QuantPlan::new(eps, None, 0.0, 1.0).is_err());
        }
        let err = QuantPlan::new(1e-4, None, -11000.0, 9000.0)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("too fine") && err.contains("smallest"),
            "{err}"
        );
        assert!(QuantPlan::new(1.0, Some(0.0), 0.0, 1.0).is_err());
        assert!(QuantPlan::new(1.0, None, f64::NAN, 1.0).is_err());
    }

    #[test]
    fn awkward_floats_are_handled_deliberately() {
        let p = QuantPlan::new(0.01, None, 0.0, 100.0).unwrap();
        assert_eq!(p.to_units(f64::NAN).unwrap(), None);
        assert!(p.to_units(f64::INFINITY).is_err());
        assert!(p.to_units(f64::NEG_INFINITY).is_err());
        assert!(p.to_units(1e30).is_err());
        assert!(p.to_units(-1e30).is_err());
        // Values below the unit (3e-12 next to 100, subnormals) pre-quantize within budget.
        for v in [3e-12, f64::from(f32::from_bits(1)), -0.0, 100.0 - 3e-12] {
            let n = p.to_units(v).unwrap().unwrap();
            assert!((p.metres(n) - v).abs() <= p.unit / 2.0, "{v}");
        }
        // A quantum override the data does not honour is caught, not silently rounded.
        let p = QuantPlan::new(1.0, Some(1.0), 0.0, 100.0).unwrap();
        assert!(p.to_units(12.5).is_err());
        assert_eq!(p.to_units(12.0).unwrap(), Some(12 - 50));
        let err = HeightGrid::from_metres(2, 1, &[1.0, f64::INFINITY], None, &p).unwrap_err();
        // Decimal data stored as float32 is off its lattice by up to half an ulp: that comes
        // out of the budget, so 0.5 m on 0.1 m data stored as f32 takes 4 steps, not 5.
        let v = f64::from(3751.3f32);
        let dev = (v - 3751.3).abs();
        assert!(dev > 0.0);
        let p = QuantPlan::with_representation_error(0.5, Some(0.1), dev, 13.7, 3751.3).unwrap();
        assert_eq!(p.quantizer.k(), 4);
        assert!(p.max_error() <= 0.5);
        assert_eq!(
            QuantPlan::new(0.5, Some(0.1), 13.7, 3751.3)
                .unwrap()
                .quantizer
                .k(),
            5
        );
        assert!(QuantPlan::with_representation_error(dev / 2.0, Some(0.1), dev, 0.0, 1.0).is_err());
        assert!(err.to_string().contains("column 1, row 0"), "{err}");
    }
}
