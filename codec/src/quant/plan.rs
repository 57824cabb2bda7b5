//! The quantization plan: how metres become integer units for one dataset at one tolerance
//! (the unit, the offset, the quantizer's `k`), chosen from the input's range and quantum.

use rayon::prelude::*;

use super::{
    CHUNK, HeightGrid, LevelQuantizers, MAX_ABS_INPUT, MAX_K, Quantizer, RowsWritten, round_to_i64,
};
use crate::CodecError;
#[cfg(doc)]
use crate::samples::detect_quantum;
use crate::samples::{Dem, QuantumScan, SampleSource};
use crate::temp::TempStorage;

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
    /// A quantizer per level (an `--rms-error` build that chose unequal steps, header flag bit
    /// 5); `quantizer` is then the largest of them. `None`: `quantizer` on every level.
    pub levels: Option<LevelQuantizers>,
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
            levels: None,
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
            levels: None,
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
    #[inline]
    pub fn metres(&self, n: i32) -> f64 {
        self.offset + f64::from(n) * self.unit
    }

    /// Integer height of sample `v` (metres); `Ok(None)` for NaN (nodata).
    ///
    /// Errors: infinite values, values out of the planned range, and — for lattice input —
    /// values off the lattice (a wrong quantum override would otherwise break the bound).
    ///
    /// Inlined (a planet build asks once for every lattice point it paints, from another
    /// crate), its errors made out of line.
    #[inline]
    pub fn to_units(&self, v: f64) -> Result<Option<i32>, CodecError> {
        if v.is_nan() {
            return Ok(None);
        }
        if v.is_infinite() {
            return Err(unplannable(v, "is infinite"));
        }
        let q = round_to_i64((v - self.offset) / self.unit);
        if q.unsigned_abs() > u64::from(MAX_ABS_INPUT.unsigned_abs()) {
            return Err(unplannable(v, "m is outside the planned height range"));
        }
        let n = q as i32;
        if self.lattice {
            self.on_lattice(v, n)?;
        }
        Ok(Some(n))
    }

    /// For lattice input: that sample `v` is a multiple of the quantum (its units `n`).
    fn on_lattice(&self, v: f64, n: i32) -> Result<(), CodecError> {
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
        Ok(())
    }
}

/// The error of a sample value `v` the plan cannot hold: "sample value {v} {why}".
#[cold]
#[inline(never)]
fn unplannable(v: f64, why: &str) -> CodecError {
    CodecError::invalid(format!("sample value {v} {why}"))
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
