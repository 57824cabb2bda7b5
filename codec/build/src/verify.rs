//! The comparisons of `cbdam verify`: a repository against the input(s) it was built from.
//!
//! Each `compare_*` decodes everything and measures; the caller prints what it likes from the
//! result, then asks it to `check` (errors name the sample and the bound it breaks).

use std::path::{Path, PathBuf};

use cbdam_codec::colour::{ColourVerifyReport, verify_colour};
use cbdam_codec::hierarchy::resolution::{COARSE_ONLY, HOLE};
use cbdam_codec::hierarchy::{
    Reached, VerifyReport, reconstruct_finest_with_validity, reconstruct_reached, verify,
};
use cbdam_codec::input::{Format, Limits, ReadOptions, read_dem, read_rgb};
use cbdam_codec::quant::HeightGrid;
use cbdam_codec::repository::Repository;

use crate::error::{Context, Result, bail};
use crate::mosaic::{NO_WINNER, mosaic_tiles};
use crate::plan::is_raw_path;
use crate::tiles::{Tile, expand_inputs};

/// A colour repository against its image.
pub struct ColourComparison {
    /// Per-channel, per-level errors and the decoded RGB error.
    pub report: ColourVerifyReport,
    /// The bound on each of Y, Co, Cg, levels.
    pub k: i32,
    /// The tolerance on each decoded R, G, B, levels.
    pub epsilon: f64,
}

impl ColourComparison {
    /// Every level of Y, Co, Cg within `k`, and every decoded R, G, B within the tolerance.
    pub fn check(&self) -> Result<()> {
        let (report, k, eps) = (&self.report, self.k, self.epsilon);
        if let Some(c) = report.channels.iter().position(|c| !c.within_bound()) {
            bail!(
                "L∞ bound violated in channel {}: {} levels, bound {k}",
                ["Y", "Co", "Cg"][c],
                report.channels[c].max_error()
            );
        }
        if report.rgb_max.iter().any(|&e| f64::from(e) > eps) {
            bail!(
                "RGB error {:?} above the {eps}-level tolerance",
                report.rgb_max
            );
        }
        Ok(())
    }
}

/// Decodes a colour repository and compares it with the image `against`.
pub fn compare_colour(repo: &Repository, against: &Path) -> Result<ColourComparison> {
    let img = read_rgb(against, &Limits::default())
        .with_context(|| format!("reading {}", against.display()))?;
    let encoded = repo.to_encoded()?;
    let report = verify_colour(&encoded, &img)
        .with_context(|| format!("checking against {}", against.display()))?;
    Ok(ColourComparison {
        report,
        k: repo.params().quantizer.k(),
        epsilon: repo.plan().epsilon,
    })
}

/// An elevation repository against the one DEM it was built from.
pub struct DemComparison {
    /// Errors per level, in units, and their bound.
    pub levels: VerifyReport,
    /// Samples per row of the DEM.
    pub width: usize,
    /// Samples of the DEM.
    pub samples: usize,
    /// Samples of the DEM without data.
    pub nodata: usize,
    /// Samples whose nodata state the repository gets wrong, with what the repository says
    /// there (`true`: data).
    pub mask_mismatches: Vec<(usize, bool)>,
    /// Largest error of the finest level against the DEM's samples, metres.
    pub max_error: f64,
    /// Where it is (sample index).
    pub worst: usize,
    /// The tolerance, metres.
    pub epsilon: f64,
    /// The guaranteed bound, metres.
    pub guaranteed: f64,
}

impl DemComparison {
    /// The nodata mask states exactly which samples had data.
    pub fn check_mask(&self) -> Result<()> {
        if let Some(&(i, repo_valid)) = self.mask_mismatches.first() {
            bail!(
                "nodata mask disagrees with the input at {} samples, first at column {}, row {} \
                 (repository says {}, input says {})",
                self.mask_mismatches.len(),
                i % self.width,
                i / self.width,
                if repo_valid { "data" } else { "nodata" },
                if repo_valid { "nodata" } else { "data" }
            );
        }
        Ok(())
    }

    /// Every level within the bound, and every sample within the tolerance.
    pub fn check_error(&self) -> Result<()> {
        if !self.levels.within_bound() {
            bail!(
                "L∞ bound violated: {} units on some level, bound {} units",
                self.levels.max_error(),
                self.levels.bound
            );
        }
        // f64 evaluation of offset + n·u is good to ~1e-16 relative; the bound itself was
        // checked exactly in integers above.
        if self.max_error > self.epsilon * (1.0 + 1e-12) {
            bail!(
                "sample at column {}, row {} is off by {} m, above the {} m tolerance",
                self.worst % self.width,
                self.worst / self.width,
                self.max_error,
                self.epsilon
            );
        }
        Ok(())
    }

    /// [`DemComparison::check_mask`], then [`DemComparison::check_error`].
    pub fn check(&self) -> Result<()> {
        self.check_mask()?;
        self.check_error()
    }
}

/// Decodes an elevation repository and compares it with the DEM `against`, read as the build
/// read it: with the nodata value the header records, and a raw float32 file at the
/// repository's size.
pub fn compare_dem(repo: &Repository, against: &Path) -> Result<DemComparison> {
    let p = *repo.params();
    let plan = *repo.plan();
    let mut opts = ReadOptions {
        nodata: repo.nodata(),
        ..ReadOptions::default()
    };
    // A raw float32 file has no size of its own: it is the repository's (and a file of another
    // length is refused by the reader).
    let (width, height) = p.domain.data().size();
    if is_raw_path(against) {
        opts.format = Some(Format::RawF32 { width, height });
    }
    let dem = read_dem(against, &opts).with_context(|| format!("reading {}", against.display()))?;
    if (dem.width, dem.height) != (width, height) {
        bail!(
            "{} is {}×{} samples, the repository was built from {}×{}",
            against.display(),
            dem.width,
            dem.height,
            width,
            height
        );
    }
    let grid = HeightGrid::from_dem(&dem, &plan).with_context(|| {
        format!(
            "mapping {} onto the repository's height lattice",
            against.display()
        )
    })?;
    let encoded = repo.to_encoded()?;
    let levels = verify(&encoded, &grid).context("decoding the hierarchy")?;
    // Against the samples as stored, in metres: what the user was promised.
    let (finest, valid) = reconstruct_finest_with_validity(&encoded)?;
    // The nodata mask must state exactly which samples had data: a sample drawn that had none
    // shows invented surface, one hidden that had data loses it.
    let mask_mismatches: Vec<(usize, bool)> = (0..valid.len())
        .filter(|&i| valid[i] != grid.valid[i])
        .map(|i| (i, valid[i]))
        .collect();
    let mut max_error = 0f64;
    let mut worst = 0usize;
    for (i, &n) in finest.iter().enumerate() {
        if grid.valid[i] {
            let e = (plan.metres(n) - dem.values[i]).abs();
            if e > max_error {
                max_error = e;
                worst = i;
            }
        }
    }
    Ok(DemComparison {
        levels,
        width: dem.width,
        samples: grid.valid.len(),
        nodata: grid.valid.iter().filter(|v| !**v).count(),
        mask_mismatches,
        max_error,
        worst,
        epsilon: plan.epsilon,
        guaranteed: plan.max_error(),
    })
}

/// What one input of a multi-input build contributes.
pub struct InputComparison {
    /// The input.
    pub path: PathBuf,
    /// Its samples that win on the lattice.
    pub winning: usize,
    /// Its stride on the lattice, fine samples.
    pub stride: u32,
    /// Largest error of its winning samples, metres.
    pub max_error: f64,
}

/// An elevation repository against the several inputs it was built from.
pub struct MosaicComparison {
    /// Errors per level, in units, and their bound.
    pub levels: VerifyReport,
    /// Per input, in the order given.
    pub inputs: Vec<InputComparison>,
    /// Lattice points with data that the hierarchy reaches.
    pub reached_valid: usize,
    /// Lattice points whose nodata state the repository gets wrong, with what it says there.
    pub mask_mismatches: Vec<(usize, Reached)>,
    /// Whether the inputs have data at the first mismatch.
    pub first_mismatch_has_data: bool,
    /// Winning samples never reconstructed.
    pub unreached: Vec<usize>,
    /// The largest error of any winning sample, metres, where, and from which input.
    pub worst: Option<(f64, usize, usize)>,
    /// Lattice points per row.
    pub width: usize,
    /// The tolerance, metres.
    pub epsilon: f64,
}

impl MosaicComparison {
    /// The nodata mask, that every winning sample is reached, the bound on every level, and the
    /// tolerance on every winning sample, in that order.
    pub fn check(&self) -> Result<()> {
        let w = self.width;
        if let Some(&(i, state)) = self.mask_mismatches.first() {
            bail!(
                "nodata mask disagrees with the inputs at {} lattice points, first at column {}, \
                 row {} (repository says {:?}, inputs say {})",
                self.mask_mismatches.len(),
                i % w,
                i / w,
                state,
                if self.first_mismatch_has_data {
                    "data"
                } else {
                    "no data"
                }
            );
        }
        if let Some(&i) = self.unreached.first() {
            bail!(
                "{} winning samples are never reconstructed, first at lattice column {}, row {}",
                self.unreached.len(),
                i % w,
                i / w
            );
        }
        if !self.levels.within_bound() {
            bail!(
                "L∞ bound violated: {} units on some level, bound {} units",
                self.levels.max_error(),
                self.levels.bound
            );
        }
        if let Some((e, i, k)) = self.worst
            && e > self.epsilon * (1.0 + 1e-12)
        {
            bail!(
                "lattice point at column {}, row {} (from {}) is off by {e} m, above the {} m \
                 tolerance",
                i % w,
                i / w,
                self.inputs[k].path.display(),
                self.epsilon
            );
        }
        Ok(())
    }
}

/// Several inputs: rebuilds the build's lattice from them ([`crate::mosaic`]) and compares every
/// winning sample of every input, the nodata mask wherever the hierarchy reaches, and whether
/// every winning sample is reached at all. Directories, globs, `@LIST`s and VRTs are expanded
/// as the build expands them ([`crate::tiles`]).
pub fn compare_mosaic(repo: &Repository, paths: &[PathBuf]) -> Result<MosaicComparison> {
    compare_tiles(repo, &expand_inputs(paths)?)
}

/// [`compare_mosaic`] of inputs already expanded.
pub fn compare_tiles(repo: &Repository, tiles: &[Tile]) -> Result<MosaicComparison> {
    let p = *repo.params();
    let plan = *repo.plan();
    // Read the inputs the way the build did: its nodata value was recorded in the header.
    let opts = ReadOptions {
        nodata: repo.nodata(),
        ..ReadOptions::default()
    };
    let m = mosaic_tiles(tiles, &opts, crate::plan::default_memory_limit())?;
    let (width, height) = p.domain.data().size();
    if (m.width, m.height) != (width, height) {
        bail!(
            "the inputs make a {}×{} lattice, the repository was built from {}×{}",
            m.width,
            m.height,
            width,
            height
        );
    }
    let class = m.survey()?.resolution.class;
    let grid = HeightGrid::from_source_in(&m, &plan, &m.lattice)
        .context("mapping the inputs onto the repository's height lattice")?;
    let encoded = repo.to_encoded()?;
    let levels = verify(&encoded, &grid).context("decoding the hierarchy")?;
    let (values, state) = reconstruct_reached(&encoded)?;
    let mut max_err = vec![0f64; m.inputs.len()];
    let mut count = vec![0usize; m.inputs.len()];
    let mut unreached = Vec::new();
    let mut mask_wrong = Vec::new();
    let mut worst: Option<(f64, usize, usize)> = None;
    m.for_each_block_winners(&mut |y0, block, winners| {
        let first = y0 * m.width;
        for (j, (&v, &k)) in block.iter().zip(winners).enumerate() {
            let i = first + j;
            match (k, class[i], state[i]) {
                (NO_WINNER, HOLE, Reached::Valid) | (NO_WINNER, COARSE_ONLY, Reached::Invalid) => {
                    mask_wrong.push(i)
                }
                (NO_WINNER, _, _) => {}
                (_, _, Reached::No) => unreached.push(i),
                (_, _, Reached::Invalid) => mask_wrong.push(i),
                (k, _, Reached::Valid) => {
                    let e = (plan.metres(values[i]) - v).abs();
                    let k = k as usize;
                    max_err[k] = max_err[k].max(e);
                    count[k] += 1;
                    if worst.is_none_or(|(w, _, _)| e > w) {
                        worst = Some((e, i, k));
                    }
                }
            }
        }
        Ok(())
    })?;
    let inputs = m
        .inputs
        .iter()
        .enumerate()
        .map(|(k, input)| InputComparison {
            path: input.path.clone(),
            winning: count[k],
            stride: 1u32 << input.log2,
            max_error: max_err[k],
        })
        .collect();
    Ok(MosaicComparison {
        levels,
        inputs,
        reached_valid: state.iter().filter(|&&s| s == Reached::Valid).count(),
        first_mismatch_has_data: mask_wrong.first().is_some_and(|&i| class[i] != HOLE),
        mask_mismatches: mask_wrong.iter().map(|&i| (i, state[i])).collect(),
        unreached,
        worst,
        width: m.width,
        epsilon: plan.epsilon,
    })
}
