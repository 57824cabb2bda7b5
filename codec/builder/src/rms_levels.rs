//! `cbdam build --rms-error E` with a quantizer per level (header flag bit 5,
//! [`LevelQuantizers`]): after [`crate::rms`] has chosen one step for every level, this looks
//! for unequal steps that meet the same bound in fewer bytes.
//!
//! With α = 1 every sample keeps the error of the level that added it, so the surface's
//! squared error is the sum over levels of each level's own, and each level's rate is its
//! records' bytes. One encode with one step `k` on every level therefore gives, for every
//! level at once, the rate and the squared error that `k` costs there ([`LevelTable`]). From a
//! table over a few steps (half octaves around the one-step choice) a Lagrangian allocation
//! picks each level's step minimising `bytes + λ · squared error`, with `λ` set so that the
//! predicted error fits the budget `E² · samples`. The closed loop (a coarse level's step
//! changes the finer levels' residuals) and the root field (quantized with half of level 0's
//! step) make the prediction approximate, so every allocation is encoded, decoded and its RMS
//! error measured exactly; the budget is rescaled by the measured error and tried again a few
//! times ([`PROBES`]). The smallest file that meets the bound (and the `--max-error` cap, which
//! bounds the largest step) wins; where none is smaller than the one-step file, the build
//! keeps that one, byte for byte.

use cbdam_codec::hierarchy::{Encoded, NoJournal, reconstruct_finest_with_validity};
use cbdam_codec::quant::{LevelQuantizers, QuantPlan, Quantizer};
use cbdam_codec::repository::serialize;
use cbdam_codec::samples::Dem;

use crate::encode::{ExtraLevels, encode_prepared, with_coarser_roots_if_smaller};
use crate::error::{Result, bail};
use crate::progress::NoProgress;
use crate::{BuildOptions, PreparedBuild, prepare_elevation};

/// The table's steps: the one-step choice's `k` times `2^(j/2)` for these `j` (½ … 4). At
/// these rates each level's bytes and error trade at about the same slope for the same step
/// (measured: the allocations chosen on Fuji and Jacksboro from ¼ … 8 used the one-step `k`
/// and the next half octave only), so the far ends are not encoded.
const HALF_OCTAVES: std::ops::RangeInclusive<i32> = -2..=4;
/// Allocations encoded and measured at most.
const PROBES: usize = 6;

/// What the per-level search found: the quantizers, the level pairs the hierarchy has above
/// the smallest one (fixed, so that the levels are the ones allocated), the RMS error
/// measured and the repository's size.
pub(crate) struct PerLevel {
    pub levels: LevelQuantizers,
    pub extra_level_pairs: u32,
    pub measured: f64,
    pub bytes: usize,
}

/// Per candidate step, per level of records: the bytes and the squared error (metres²) of the
/// samples the level adds, from one encode with that step on every level.
struct LevelTable {
    ks: Vec<u32>,
    bytes: Vec<Vec<f64>>,
    sse: Vec<Vec<f64>>,
    /// The RMS error of each candidate's encode, measured (root field included).
    rms: Vec<f64>,
}

/// The per-level allocation for `--rms-error target` on the unit and around the maximum error
/// of `uniform` (the one-step choice's build options), `cap` the largest maximum error
/// allowed; `None` where no allocation is smaller than the one-step build.
pub(crate) fn allocate(
    uniform: &BuildOptions,
    dem: &Dem,
    target: f64,
    cap: f64,
) -> Result<Option<PerLevel>> {
    let mut prepared = prepare_elevation(uniform, &NoProgress, None)?;
    let base_k = prepared.input.plan.quantizer.k() as u32;
    // The layout the one-step build has (`--extra-levels auto` may add a level pair): fixed,
    // so that every trial has the same levels.
    let first = encode_whole(&prepared, uniform)?;
    let extra = first.params.layout().k() - layout_k(&prepared, 0)?;
    prepared.enc_opts.extra_level_pairs = extra;
    let threads = uniform.threads;
    let uniform_rms = crate::rms::rms_error(&first, &prepared.input.plan, dem)?;
    let uniform_bytes = file_size(&prepared, &first, None, uniform_rms, target)?;
    let ks = candidate_ks(base_k, &prepared.input.plan, cap);
    let table = measure_table(&mut prepared, dem, &ks, (&first, uniform_rms), threads)?;
    let samples = valid_count(dem);
    let goal = target * target * samples;
    // The table leaves out the root field's points: the first budget is corrected by the
    // one-step build's measured error against its prediction, each next one by the last try's.
    let corrected = |predicted: f64, rms: f64| {
        if rms > 0.0 {
            goal * predicted / (rms * rms * samples)
        } else {
            goal
        }
    };
    let mut budget = corrected(table.predicted(&vec![base_k; table.levels()]), uniform_rms);
    let mut best: Option<PerLevel> = None;
    let mut tried = Vec::new();
    for _ in 0..PROBES {
        let choice = table.allocation(budget);
        if tried.contains(&choice) {
            break;
        }
        tried.push(choice.clone());
        let rms = match table.uniform_rms(&choice) {
            Some(rms) => rms,
            None => {
                let levels = LevelQuantizers::new(&choice)?;
                let (encoded, rms) = encode_levels(&mut prepared, dem, Some(levels), threads)?;
                let bytes = file_size(&prepared, &encoded, Some(levels), rms.min(target), target)?;
                if rms <= target && best.as_ref().is_none_or(|b| bytes < b.bytes) {
                    best = Some(PerLevel {
                        levels,
                        extra_level_pairs: extra,
                        measured: rms,
                        bytes,
                    });
                }
                rms
            }
        };
        budget = corrected(table.predicted(&choice), rms);
    }
    Ok(best.filter(|b| b.bytes < uniform_bytes))
}

/// The layout's level pairs for `extra` pairs above the smallest covering one.
fn layout_k(prepared: &PreparedBuild, extra: u32) -> Result<u32> {
    let g = &prepared.input.grid;
    let d = cbdam_codec::geometry::Domain::covering(prepared.enc_opts.n, g.width, g.height, extra)?;
    Ok(d.layout().k())
}

/// `prepared` encoded in one go, as a build without a journal encodes it.
fn encode_once(prepared: &PreparedBuild, threads: Option<usize>) -> Result<Encoded> {
    encode_prepared(
        &prepared.input,
        None,
        &prepared.enc_opts,
        &prepared.storage,
        &NoJournal,
        threads,
        &|_, _| {},
    )
}

/// The one-step encode as the build does it (with `--extra-levels auto`'s retry).
fn encode_whole(prepared: &PreparedBuild, opts: &BuildOptions) -> Result<Encoded> {
    let encoded = encode_once(prepared, opts.threads)?;
    Ok(if opts.extra_levels == ExtraLevels::Auto {
        with_coarser_roots_if_smaller(
            &prepared.input,
            encoded,
            &prepared.enc_opts,
            prepared.limit,
            opts.threads,
        )?
        .0
    } else {
        encoded
    })
}

/// The table's steps: half octaves around `base_k` whose maximum error is within `cap`, and
/// the largest step within `cap` where it cuts the half octaves short.
fn candidate_ks(base_k: u32, plan: &QuantPlan, cap: f64) -> Vec<u32> {
    let within_cap = |k: u32| {
        Quantizer::new(k).is_ok_and(|q| {
            QuantPlan {
                quantizer: q,
                ..*plan
            }
            .max_error()
                <= cap
        })
    };
    let ladder: Vec<u32> = HALF_OCTAVES
        .map(|j| (f64::from(base_k) * 2f64.powf(f64::from(j) / 2.0)).round() as u32)
        .collect();
    let mut ks: Vec<u32> = ladder.iter().copied().filter(|&k| within_cap(k)).collect();
    // A cap between two rungs: its own step is a candidate too, so that the levels that
    // would take the next rung take the most the cap allows.
    let top = ladder.iter().copied().max().unwrap_or(base_k);
    if let Some(capped) = (base_k..=top).rev().find(|&k| within_cap(k)) {
        ks.push(capped);
    }
    ks.push(base_k);
    ks.sort_unstable();
    ks.dedup();
    ks
}

/// One encode per candidate step, every level quantized with it (the one-step build's,
/// `uniform` and its RMS error, is not encoded again).
fn measure_table(
    prepared: &mut PreparedBuild,
    dem: &Dem,
    ks: &[u32],
    uniform: (&Encoded, f64),
    threads: Option<usize>,
) -> Result<LevelTable> {
    let base = prepared.input.plan.quantizer;
    let mut table = LevelTable {
        ks: ks.to_vec(),
        bytes: Vec::new(),
        sse: Vec::new(),
        rms: Vec::new(),
    };
    for &k in ks {
        prepared.input.plan.quantizer = Quantizer::new(k)?;
        let trial;
        let (encoded, rms) = if prepared.input.plan.quantizer == base {
            uniform
        } else {
            trial = encode_levels(prepared, dem, None, threads)?;
            (&trial.0, trial.1)
        };
        table.rms.push(rms);
        let levels = usize::from(encoded.params.layout().finest_level());
        let mut bytes = vec![0f64; levels];
        for r in &encoded.records {
            bytes[usize::from(r.id.level)] += r.bytes.len() as f64;
        }
        table.bytes.push(bytes);
        table
            .sse
            .push(level_sse(encoded, &prepared.input.plan, dem)?);
    }
    Ok(table)
}

impl LevelTable {
    /// Each level's step for the multiplier `λ` that fits `budget` (squared metres summed over
    /// the samples): `λ` bisected on a log scale, the predicted error falling as it grows.
    fn allocation(&self, budget: f64) -> Vec<u32> {
        let (mut lo, mut hi) = (-40f64, 40f64);
        for _ in 0..80 {
            let mid = (lo + hi) / 2.0;
            if self.predicted_sse(mid.exp2()) <= budget {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        self.choose(hi.exp2())
            .into_iter()
            .map(|c| self.ks[c])
            .collect()
    }

    /// Per level, the candidate with the least `bytes + λ · sse`.
    fn choose(&self, lambda: f64) -> Vec<usize> {
        let levels = self.bytes[0].len();
        (0..levels)
            .map(|l| {
                (0..self.ks.len())
                    .min_by(|&a, &b| {
                        let cost = |c: usize| self.bytes[c][l] + lambda * self.sse[c][l];
                        cost(a).total_cmp(&cost(b))
                    })
                    .expect("at least one candidate")
            })
            .collect()
    }

    fn predicted_sse(&self, lambda: f64) -> f64 {
        self.choose(lambda)
            .iter()
            .enumerate()
            .map(|(l, &c)| self.sse[c][l])
            .sum()
    }

    fn levels(&self) -> usize {
        self.bytes[0].len()
    }

    /// The squared error the table predicts for `ks`, one step per level.
    fn predicted(&self, ks: &[u32]) -> f64 {
        ks.iter()
            .enumerate()
            .map(|(l, k)| self.sse[self.ks.iter().position(|c| c == k).expect("a candidate")][l])
            .sum()
    }

    /// The measured RMS error of `ks` when it is one step on every level (a table entry).
    fn uniform_rms(&self, ks: &[u32]) -> Option<f64> {
        let c = self.ks.iter().position(|&k| k == ks[0])?;
        ks.iter().all(|&k| k == ks[0]).then_some(self.rms[c])
    }
}

/// Encodes the prepared input with `levels` (`None`: the plan's one quantizer; with `levels`
/// the plan's quantizer becomes their largest) and measures the RMS error at the finest level.
fn encode_levels(
    prepared: &mut PreparedBuild,
    dem: &Dem,
    levels: Option<LevelQuantizers>,
    threads: Option<usize>,
) -> Result<(Encoded, f64)> {
    if let Some(l) = levels {
        prepared.input.plan.quantizer = Quantizer::new(l.max_k())?;
    }
    prepared.input.plan.levels = levels;
    let encoded = encode_once(prepared, threads)?;
    let rms = crate::rms::rms_error(&encoded, &prepared.input.plan, dem)?;
    Ok((encoded, rms))
}

/// The repository's size as the build writes it, the header's bounds included.
fn file_size(
    prepared: &PreparedBuild,
    encoded: &Encoded,
    levels: Option<LevelQuantizers>,
    measured: f64,
    target: f64,
) -> Result<usize> {
    let mut plan = prepared.input.plan;
    plan.quantizer = encoded.params.quantizer;
    plan.levels = levels;
    plan.epsilon = plan.max_error();
    plan.rms = Some(cbdam_codec::quant::RmsBound { target, measured });
    let input = &prepared.input;
    Ok(serialize(encoded, &plan, input.georef.as_ref(), input.nodata)?.len())
}

fn valid_count(dem: &Dem) -> f64 {
    dem.values
        .iter()
        .filter(|&&v| !(v.is_nan() || dem.nodata == Some(v)))
        .count() as f64
}

/// The squared error, metres², of the valid samples each level of records adds (level `l`'s
/// records add the points new at level `l + 1`); the root field's points are left out.
fn level_sse(encoded: &Encoded, plan: &QuantPlan, dem: &Dem) -> Result<Vec<f64>> {
    let (finest, _) = reconstruct_finest_with_validity(encoded)?;
    if finest.len() != dem.values.len() {
        bail!("the decoded surface and the input differ in size");
    }
    let layout = encoded.params.layout();
    let mut sse = vec![0f64; usize::from(layout.finest_level())];
    for (i, (&n, &v)) in finest.iter().zip(&dem.values).enumerate() {
        if v.is_nan() || dem.nodata == Some(v) {
            continue;
        }
        let (x, y) = ((i % dem.width) as u64, (i / dem.width) as u64);
        if let Some(l) = adding_level(x, y, layout.k()) {
            let e = plan.metres(n) - v;
            sse[l] += e * e;
        }
    }
    Ok(sse)
}

/// The level whose records add lattice point `(x, y)` of a hierarchy of `k` level pairs (the
/// point is new at that level + 1), `None` for a root vertex (both coordinates multiples of
/// `2^k`). A point whose coordinates have `v` trailing zero bits at the least is a cell centre
/// of the level-`2(k − v − 1)` squares (new at level `2k − 2v − 1`) when both have `v`, else
/// the midpoint of a side of the level-`2(k − v) − 1` diamonds (new at level `2k − 2v`).
pub(crate) fn adding_level(x: u64, y: u64, k: u32) -> Option<usize> {
    let tz = |a: u64| if a == 0 { 64 } else { a.trailing_zeros() };
    let (tx, ty) = (tz(x), tz(y));
    let v = tx.min(ty);
    if v >= k {
        return None;
    }
    let new_at = if tx == ty {
        2 * (k - v) - 1
    } else {
        2 * (k - v)
    };
    Some(new_at as usize - 1)
}

#[cfg(test)]
mod tests {
    use super::adding_level;

    #[test]
    fn each_level_adds_the_points_a_refinement_adds() {
        // k = 2: roots every 4; level 1 adds the centres (2, 2) of the 4-squares, level 2 the
        // side midpoints (2, 0) and (0, 2), level 3 the odd-odd centres, level 4 the rest.
        let k = 2;
        assert_eq!(adding_level(0, 0, k), None);
        assert_eq!(adding_level(4, 8, k), None);
        assert_eq!(adding_level(2, 2, k), Some(0));
        assert_eq!(adding_level(2, 4, k), Some(1));
        assert_eq!(adding_level(0, 6, k), Some(1));
        assert_eq!(adding_level(1, 3, k), Some(2));
        assert_eq!(adding_level(1, 2, k), Some(3));
        assert_eq!(adding_level(4, 1, k), Some(3));
        // On a 2^k-periodic lattice each level adds what its (N − 1)² cells per diamond do:
        // level 2k − 1 adds half of the points, level 2k − 2 a quarter of the rest...
        let side = 64u64;
        let mut counts = [0usize; 4];
        for y in 0..side {
            for x in 0..side {
                if let Some(l) = adding_level(x, y, k) {
                    counts[l] += 1;
                }
            }
        }
        let all = (side * side) as usize;
        assert_eq!(counts, [all / 16, all / 8, all / 4, all / 2]);
    }
}
