//! The comparisons of `cbdam verify`: a repository against the input(s) it was built from.
//!
//! Each `compare_*` decodes everything and measures; the caller prints what it likes from the
//! result, then asks it to `check` (errors name the sample and the bound it breaks).

use std::path::{Path, PathBuf};

use crate::input::{Format, Limits, ReadOptions, TileReader, read_dem, read_rgb};
use cbdam_codec::colour::{ColourVerifyReport, verify_colour};
use cbdam_codec::geometry::DomainKind;
use cbdam_codec::hierarchy::resolution::{COARSE_ONLY, HOLE};
use cbdam_codec::hierarchy::{
    BlockPlan, BlockWalk, LevelReport, Reached, VerifyReport, verify_with_finest,
    verify_with_reached,
};
use cbdam_codec::lifting::Alpha;
use cbdam_codec::quant::{HeightGrid, QuantPlan};
use cbdam_codec::repository::GeoRef;
use cbdam_codec::repository::Repository;
use cbdam_codec::temp::LatticeArray;

use crate::error::{Context, Result, bail};
use crate::mosaic::{Mosaic, NO_WINNER, mosaic_tiles};
use crate::plan::is_raw_path;
use crate::tiles::{Tile, expand_inputs};
use crate::verify_blocks::{ApexPoints, DecodedRows, Visits, decode_plan, visit_apex};

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
        k: repo.head().params().quantizer.k(),
        epsilon: repo.head().plan().epsilon,
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
    /// Root-mean-square error of the finest level against the DEM's valid samples, metres.
    pub rms_error: f64,
    /// The RMS bound of a `--rms-error` build (header flag bit 4), metres.
    pub rms_bound: Option<f64>,
    /// The tolerance, metres.
    pub epsilon: f64,
    /// The guaranteed bound, metres.
    pub guaranteed: f64,
    /// The nodata value the input file declares itself (the header's may be the build's
    /// `--nodata` instead).
    pub declared_nodata: Option<f64>,
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
            // With per-level quantizers a level may break its own bound and not the largest.
            let bound = |l: &LevelReport| l.bound.min(self.levels.bound);
            let worst = self.levels.levels.iter().find(|l| l.max_error > bound(l));
            bail!(
                "L∞ bound violated: {} units on level {}, bound {} units",
                worst.map_or(self.levels.max_error(), |l| l.max_error),
                worst.map_or("?".to_string(), |l| l.level.to_string()),
                worst.map_or(self.levels.bound, bound)
            );
        }
        // The guarantee includes the float rounding of offset + n·u (QuantPlan::max_error);
        // the bound in units was checked exactly in integers above.
        if self.max_error > self.guaranteed {
            bail!(
                "sample at column {}, row {} is off by {} m, above the {} m guaranteed (tolerance \
                 {} m)",
                self.worst % self.width,
                self.worst / self.width,
                self.max_error,
                self.guaranteed,
                self.epsilon
            );
        }
        if let Some(bound) = self.rms_bound
            && self.rms_error > bound * (1.0 + 1e-12)
        {
            bail!(
                "RMS error {} m of the finest level is above the {bound} m bound the header records",
                self.rms_error
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
    let p = *repo.head().params();
    let plan = *repo.head().plan();
    let mut opts = ReadOptions {
        nodata: repo.head().nodata(),
        ..ReadOptions::default()
    };
    // A raw float32 file has no size of its own: it is the repository's (and a file of another
    // length is refused by the reader).
    let (width, height) = p.domain.data().size();
    if is_raw_path(against) {
        opts.format = Some(Format::RawF32 { width, height });
    }
    // Read with the file's own nodata value, to compare it with the header's, then with the
    // header's as the build did (a recorded value is the file's or the build's `--nodata`).
    let mut dem = read_dem(
        against,
        &ReadOptions {
            nodata: None,
            ..opts
        },
    )
    .with_context(|| format!("reading {}", against.display()))?;
    let declared_nodata = dem.nodata;
    if repo.head().nodata().is_some() {
        dem.nodata = repo.head().nodata();
    }
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
    check_nodata(repo.head().nodata(), declared_nodata, against)?;
    check_georef(repo.head().georef(), dem.georef.as_ref(), against)?;
    let grid = HeightGrid::from_dem(&dem, &plan).with_context(|| {
        format!(
            "mapping {} onto the repository's height lattice",
            against.display()
        )
    })?;
    let encoded = repo.to_encoded()?;
    // One decode: every level against the input, and the finest level as stored, to compare
    // in metres (what the user was promised).
    let (levels, finest, valid) =
        verify_with_finest(&encoded, &grid).context("decoding the hierarchy")?;
    // The nodata mask must state exactly which samples had data: a sample drawn that had none
    // shows invented surface, one hidden that had data loses it.
    let mask_mismatches: Vec<(usize, bool)> = (0..valid.len())
        .filter(|&i| valid[i] != grid.valid[i])
        .map(|i| (i, valid[i]))
        .collect();
    let errors = SampleErrors::of(&finest, &grid.valid, &dem.values, &plan);
    Ok(DemComparison {
        levels,
        width: dem.width,
        samples: grid.valid.len(),
        nodata: grid.valid.iter().filter(|v| !**v).count(),
        mask_mismatches,
        max_error: errors.max,
        worst: errors.worst,
        rms_error: errors.rms,
        rms_bound: plan.rms.map(|r| r.target),
        epsilon: plan.epsilon,
        guaranteed: plan.max_error(),
        declared_nodata,
    })
}

/// The errors of the samples as stored against the input's, metres, over the samples with data.
struct SampleErrors {
    /// The largest.
    max: f64,
    /// The sample (row-major index) of the largest; 0 when none is off.
    worst: usize,
    /// The root mean square.
    rms: f64,
}

impl SampleErrors {
    /// The errors of the decoded heights `finest` (units of `plan`) against the input's
    /// `values`, over the samples `valid` marks.
    fn of(finest: &[i32], valid: &[bool], values: &[f64], plan: &QuantPlan) -> Self {
        let mut max = 0f64;
        let mut worst = 0usize;
        let (mut square_sum, mut valid_count) = (0f64, 0u64);
        for (i, &n) in finest.iter().enumerate() {
            if valid[i] {
                let e = (plan.metres(n) - values[i]).abs();
                square_sum += e * e;
                valid_count += 1;
                if e > max {
                    max = e;
                    worst = i;
                }
            }
        }
        let rms = (square_sum / valid_count.max(1) as f64).sqrt();
        SampleErrors { max, worst, rms }
    }
}

/// The nodata value a repository records against the one its input file declares. A file
/// that declares one (other than NaN, which is nodata anyway and recorded as none) gives
/// every build a nodata value: its own, or the build's `--nodata` overriding it, so a
/// repository that records none was not built from this file as it is. Differing values are
/// not an error (that is `--nodata`); which samples had data is compared sample by sample.
fn check_nodata(recorded: Option<f64>, declared: Option<f64>, input: &Path) -> Result<()> {
    if let Some(d) = declared
        && !d.is_nan()
        && recorded.is_none()
    {
        bail!(
            "nodata differs: {} declares the nodata value {d}, the repository records none",
            input.display()
        );
    }
    Ok(())
}

/// The georeferencing a repository records against its input's: origin, pixel size, pixel
/// convention, CRS (EPSG code and definition) exactly, as the build copies them. Only where
/// both have one: an input without georeferencing may have been given one by the build's
/// `--bounds` and `--crs`, and a repository without any claims no place (the same samples
/// may come from a raw file).
fn check_georef(recorded: Option<&GeoRef>, input: Option<&GeoRef>, what: &Path) -> Result<()> {
    let describe = |g: &GeoRef| {
        format!(
            "origin ({}, {}), pixel {} × {} ({}), EPSG {}{}",
            g.origin_x,
            g.origin_y,
            g.pixel_x,
            g.pixel_y,
            if g.pixel_is_area { "area" } else { "point" },
            g.epsg.map_or_else(|| "none".to_owned(), |e| e.to_string()),
            if g.wkt.is_some() {
                ", with a CRS definition"
            } else {
                ""
            }
        )
    };
    match (recorded, input) {
        (Some(r), Some(i)) if r != i => bail!(
            "georeferencing differs: the repository records {}; {} has {}",
            describe(r),
            what.display(),
            describe(i)
        ),
        _ => Ok(()),
    }
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
    /// Lattice points whose nodata state the repository gets wrong, with what it says there:
    /// the first [`LISTED`] of them.
    pub mask_mismatches: Vec<(usize, Reached)>,
    /// How many lattice points the repository gets the nodata state of wrong.
    pub mask_mismatch_count: u64,
    /// Whether the inputs have data at the first mismatch.
    pub first_mismatch_has_data: bool,
    /// Winning samples never reconstructed: the first [`LISTED`].
    pub unreached: Vec<usize>,
    /// How many winning samples are never reconstructed.
    pub unreached_count: u64,
    /// The largest error of any winning sample, metres, where, and from which input.
    pub worst: Option<(f64, usize, usize)>,
    /// Lattice points per row.
    pub width: usize,
    /// The tolerance, metres.
    pub epsilon: f64,
    /// The guaranteed bound, metres ([`cbdam_codec::quant::QuantPlan::max_error`]).
    pub guaranteed: f64,
    /// The blocks the hierarchy was decoded in, `None` when it was decoded whole.
    pub blocks: Option<BlockPlan>,
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
                self.mask_mismatch_count,
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
                self.unreached_count,
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
            && e > self.guaranteed
        {
            bail!(
                "lattice point at column {}, row {} (from {}) is off by {e} m, above the {} m \
                 guaranteed (tolerance {} m)",
                i % w,
                i / w,
                self.inputs[k].path.display(),
                self.guaranteed,
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

/// Bytes a lattice point that decoding a hierarchy whole ([`compare_dem`],
/// [`compare_tiles_whole`]) holds: the reconstruction, its nodata states and a level's
/// refinements, with the input's quantized heights (measured: 6.9 GB peak at 16385²).
pub const WHOLE_DECODE_BYTES: u64 = 26;

/// Whether comparing `repo` with the one file `against` decodes block by block (through
/// [`compare_tiles_with`]) rather than whole ([`compare_dem`]): when decoding it whole would
/// take more than `memory_limit` ([`WHOLE_DECODE_BYTES`]) and the blocks can read the file
/// (not a raw float32 file, which only [`compare_dem`] reads at the repository's size; one
/// whose header places it, as the mosaic needs) and decode the hierarchy (planar, α = 1).
pub fn one_file_in_blocks(repo: &Repository, against: &Path, memory_limit: u64) -> bool {
    let p = repo.head().params();
    let (w, h) = p.domain.data().size();
    let placed =
        || TileReader::open(against, &ReadOptions::default()).is_ok_and(|r| r.georef().is_some());
    p.alpha == Alpha::One
        && p.domain.kind() == DomainKind::Planar
        && !is_raw_path(against)
        && (w as u64 * h as u64).saturating_mul(WHOLE_DECODE_BYTES) > memory_limit
        && placed()
}

/// [`compare_mosaic`] of inputs already expanded, under the default memory limit
/// ([`crate::plan::default_memory_limit`]).
pub fn compare_tiles(repo: &Repository, tiles: &[Tile]) -> Result<MosaicComparison> {
    compare_tiles_with(repo, tiles, crate::plan::default_memory_limit(), None)
}

/// [`compare_tiles`] within `memory_limit` bytes: a planar α = 1 hierarchy is decoded block by
/// block ([`crate::verify_blocks`]) under `plan`, or the largest plan that fits; any other, and
/// a hierarchy too shallow for blocks, whole ([`compare_tiles_whole`]).
pub fn compare_tiles_with(
    repo: &Repository,
    tiles: &[Tile],
    memory_limit: u64,
    blocks: Option<BlockPlan>,
) -> Result<MosaicComparison> {
    let p = *repo.head().params();
    let layout = *p.layout();
    let blockwise = p.alpha == Alpha::One
        && p.domain.kind() == DomainKind::Planar
        && layout.finest_level() >= 2;
    if !blockwise {
        return compare_tiles_whole(repo, tiles, memory_limit);
    }
    // Half for the decode, three eighths for the mosaic (its lattice and its cache of tile
    // rows), an eighth for the pages of mapped files being read (the lattice's windows, the
    // repository's records) and the allocator's slack.
    let (width, height) = p.domain.data().size();
    let workers = rayon::current_num_threads();
    let plan = match blocks {
        Some(plan) => plan,
        None => decode_plan(&layout, width, workers, memory_limit / 2)?,
    };
    let (m, class, grid) = mosaic_lattice(repo, tiles, memory_limit / 8 * 3)?;
    let mut levels = Visits::new(&p);
    let mut apex = ApexPoints::new(plan.apex_shift(&layout), (width, height));
    let walk = decode_apex(repo, plan, &grid, &mut apex, &mut levels)?;
    let mut compared = RowsCompared {
        rows: DecodedRows::new(&walk, &apex, &grid, (width, height)),
        levels,
        tally: Tally::new(m.inputs.len()),
        quant: *repo.head().plan(),
        width,
    };
    m.for_each_block_winners(&mut |ya, block, winners| {
        compared.block(repo, &class, ya, block, winners)
    })?;
    let RowsCompared {
        rows,
        mut levels,
        tally,
        ..
    } = compared;
    rows.finish(&mut levels)?;
    Ok(tally.finish(
        VerifyReport {
            levels: levels.levels,
            bound: p.quantizer.k() as u32,
        },
        &m,
        repo,
        Some(plan),
    ))
}

/// Reads `repo`'s records and decodes the levels above `plan`'s cut over the whole domain,
/// checking the apex lattice points against `grid` as it goes.
fn decode_apex<'r>(
    repo: &'r Repository,
    plan: BlockPlan,
    grid: &HeightGrid,
    apex: &mut ApexPoints,
    levels: &mut Visits,
) -> Result<BlockWalk<'r>> {
    let p = *repo.head().params();
    let layout = *p.layout();
    let records = repo
        .head()
        .entries()
        .iter()
        .map(|e| Ok((e.id, repo.record(e.id)?)))
        .collect::<Result<Vec<_>>>()?;
    repo.release_pages();
    let apex_input = grid.strided(plan.apex_shift(&layout))?;
    let walk = BlockWalk::new(
        p,
        repo.head().root_bytes(),
        records,
        plan,
        visit_apex(&layout, &apex_input, p.domain.data().size(), apex, levels),
    )
    .context("decoding the hierarchy")?;
    Ok(walk)
}

/// The block-by-block comparison under way: the decoded rows of blocks, the visits of every
/// level and the tally of the winning samples compared so far.
struct RowsCompared<'a> {
    rows: DecodedRows<'a>,
    levels: Visits,
    tally: Tally,
    quant: QuantPlan,
    width: usize,
}

impl RowsCompared<'_> {
    /// Compares one block of the mosaic's winning samples (lattice rows from `ya`) with the
    /// decoded rows, then releases the block's resolution classes.
    fn block(
        &mut self,
        repo: &Repository,
        class: &LatticeArray<u8>,
        ya: usize,
        block: &[f64],
        winners: &[u32],
    ) -> Result<()> {
        let width = self.width;
        let yb = ya + block.len() / width;
        for y in ya..yb {
            let row = self
                .rows
                .at(y, &mut self.levels, &|| repo.release_pages())
                .context("decoding the hierarchy")?;
            let first = y * width;
            let (values, winners) = (
                &block[(y - ya) * width..][..width],
                &winners[(y - ya) * width..][..width],
            );
            for b in row {
                let (decoded, state) = b.row(y);
                for (j, (&d, &s)) in decoded.iter().zip(state).enumerate() {
                    let x = b.x0 + j;
                    self.tally.point(
                        first + x,
                        values[x],
                        winners[x],
                        class[first + x],
                        s,
                        || self.quant.metres(d),
                    );
                }
            }
        }
        class.release(ya * width..yb * width);
        Ok(())
    }
}

/// The inputs composed as the build composed them: the mosaic, its resolution classes and its
/// quantized heights, each checked against the repository's lattice.
fn mosaic_lattice(
    repo: &Repository,
    tiles: &[Tile],
    memory_limit: u64,
) -> Result<(Mosaic, LatticeArray<u8>, HeightGrid)> {
    let p = *repo.head().params();
    let plan = *repo.head().plan();
    // Read the inputs the way the build did: its nodata value was recorded in the header.
    let opts = ReadOptions {
        nodata: repo.head().nodata(),
        ..ReadOptions::default()
    };
    let m = mosaic_tiles(tiles, &opts, memory_limit)?;
    let what = match tiles {
        [t] => t.path.clone(),
        _ => PathBuf::from("the inputs' mosaic"),
    };
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
    check_georef(repo.head().georef(), Some(&m.georef), &what)?;
    let class = m.survey()?.resolution.class;
    let grid = HeightGrid::from_source_in(&m, &plan, &m.lattice)
        .context("mapping the inputs onto the repository's height lattice")?;
    Ok((m, class, grid))
}

/// [`compare_tiles`] decoding the whole hierarchy at once: the reconstruction and the nodata
/// states of every lattice point in memory.
pub fn compare_tiles_whole(
    repo: &Repository,
    tiles: &[Tile],
    memory_limit: u64,
) -> Result<MosaicComparison> {
    let (m, class, grid) = mosaic_lattice(repo, tiles, memory_limit)?;
    let encoded = repo.to_encoded()?;
    // One decode: every level against the lattice, and every point it reaches.
    let (levels, values, state) =
        verify_with_reached(&encoded, &grid).context("decoding the hierarchy")?;
    let quant = *repo.head().plan();
    let mut tally = Tally::new(m.inputs.len());
    m.for_each_block_winners(&mut |y0, block, winners| {
        let first = y0 * m.width;
        for (j, (&v, &k)) in block.iter().zip(winners).enumerate() {
            let i = first + j;
            tally.point(i, v, k, class[i], state[i], || quant.metres(values[i]));
        }
        Ok(())
    })?;
    Ok(tally.finish(levels, &m, repo, None))
}

/// How many of the lattice points that fail a check a [`MosaicComparison`] lists: all are
/// counted, but against the wrong inputs every point of a lattice of billions may fail.
pub const LISTED: usize = 1000;

/// What [`MosaicComparison`] counts, lattice point by lattice point.
struct Tally {
    max_err: Vec<f64>,
    count: Vec<usize>,
    unreached: Vec<usize>,
    unreached_count: u64,
    mask_wrong: Vec<(usize, Reached)>,
    mask_wrong_count: u64,
    first_mismatch_has_data: bool,
    worst: Option<(f64, usize, usize)>,
    reached_valid: usize,
}

impl Tally {
    fn new(inputs: usize) -> Self {
        Self {
            max_err: vec![0.0; inputs],
            count: vec![0; inputs],
            unreached: Vec::new(),
            unreached_count: 0,
            mask_wrong: Vec::new(),
            mask_wrong_count: 0,
            first_mismatch_has_data: false,
            worst: None,
            reached_valid: 0,
        }
    }

    /// Lattice point `i`: the winning sample `v` of input `k` ([`NO_WINNER`]: none), its class,
    /// and what the hierarchy left there (`state`, and the decoded height in metres).
    #[inline]
    fn point(
        &mut self,
        i: usize,
        v: f64,
        k: u32,
        class: u8,
        state: Reached,
        metres: impl FnOnce() -> f64,
    ) {
        self.reached_valid += usize::from(state == Reached::Valid);
        let mask_wrong = match (k, class, state) {
            (NO_WINNER, HOLE, Reached::Valid) | (NO_WINNER, COARSE_ONLY, Reached::Invalid) => true,
            (NO_WINNER, _, _) => false,
            (_, _, Reached::No) => {
                if self.unreached.len() < LISTED {
                    self.unreached.push(i);
                }
                self.unreached_count += 1;
                false
            }
            (_, _, Reached::Invalid) => true,
            (k, _, Reached::Valid) => {
                let e = (metres() - v).abs();
                let k = k as usize;
                self.max_err[k] = self.max_err[k].max(e);
                self.count[k] += 1;
                if self.worst.is_none_or(|(w, _, _)| e > w) {
                    self.worst = Some((e, i, k));
                }
                false
            }
        };
        if mask_wrong {
            if self.mask_wrong.is_empty() {
                self.first_mismatch_has_data = class != HOLE;
            }
            if self.mask_wrong.len() < LISTED {
                self.mask_wrong.push((i, state));
            }
            self.mask_wrong_count += 1;
        }
    }

    fn finish(
        self,
        levels: VerifyReport,
        m: &Mosaic,
        repo: &Repository,
        blocks: Option<BlockPlan>,
    ) -> MosaicComparison {
        let inputs = m
            .inputs
            .iter()
            .enumerate()
            .map(|(k, input)| InputComparison {
                path: input.path.clone(),
                winning: self.count[k],
                stride: 1u32 << input.log2,
                max_error: self.max_err[k],
            })
            .collect();
        MosaicComparison {
            levels,
            inputs,
            reached_valid: self.reached_valid,
            first_mismatch_has_data: self.first_mismatch_has_data,
            mask_mismatches: self.mask_wrong,
            mask_mismatch_count: self.mask_wrong_count,
            unreached: self.unreached,
            unreached_count: self.unreached_count,
            worst: self.worst,
            width: m.width,
            epsilon: repo.head().plan().epsilon,
            guaranteed: repo.head().plan().max_error(),
            blocks,
        }
    }
}
