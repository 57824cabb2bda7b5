//! `cbdam build --planet`: geographic and UTM DEMs resampled onto the cube-sphere lattice
//! (`docs/PLANET.md`) and encoded as one planet.
//!
//! Every lattice point takes its height from the finest input that covers it (inputs sorted by
//! ground spacing, ties in the order given): **bilinear** between the input's four surrounding
//! samples where the lattice is at least as fine as the input (bilinear never overshoots), the
//! **area average** of the input's samples within the lattice cell's footprint (a box of the
//! lattice's mean spacing around the point) where the lattice is coarser. A point whose
//! neighbourhood holds nodata in the finest input falls through to the next input; a point no
//! input covers is nodata. Coordinates are exact f64: the lattice point's geodetic latitude and
//! longitude ([`cbdam_codec::geodesy::lattice_lat_lon`]) and, for projected inputs, the UTM
//! transform ([`cbdam_codec::geodesy::Utm`]).
//!
//! The L∞ bound of the repository holds against the resampled lattice (that is what the encoder
//! sees). Beside it [`resampling_error`] measures how far the lattice is from the inputs' own
//! samples: each input sample against the bilinear interpolant of the four lattice points
//! around it, wherever those four took their height from that input.

use std::time::Instant;

use rayon::prelude::*;

use crate::assign::AssignedGeoRef;
use crate::error::{Context, Result, bail};
pub use crate::planet_input::{GEOGRAPHIC_EPSG, MAX_PLANET_INPUTS, PlanetInput, PlanetInputs};
use crate::planet_lattice::{LatticeEncode, Resampler, encode_out_of_core};
use crate::planet_memory::PlanetMemory;
use crate::planet_plan::valid_in_tile;
pub use crate::planet_plan::{
    Candidate, TilePlan, choose_level, input_stride, lattice_spacing_deg, plan_tiles,
};
pub use crate::planet_resampling::{InputResampling, Resampled, provenance_of, resampling_error};
use crate::tiles::Tile;
use crate::{BuildOptions, Progress, ProgressEvent, Stage};
use cbdam_codec::geometry::Domain;
use cbdam_codec::hierarchy::{EncodeOptions, PlanetGrid, PlanetTile, encode_planet};
use cbdam_codec::lifting::Alpha;
use cbdam_codec::quant::QuantPlan;
use cbdam_codec::repository::write_planet_repository;

/// Resamples the inputs onto the `N`, `K` cube-sphere (see the module documentation): the
/// finest input covering a point gives its height where the point lies on that input's
/// stride ([`input_stride`]), and makes it coarse only between. Tile by tile, each at the
/// stride [`plan_tiles`] gives it (denser where a point took a finer input's sample), the whole
/// lattice held: for checking a repository ([`compare_planet`]); a build resamples each tile as
/// a block of the encode asks for it ([`crate::planet_lattice`]).
pub fn resample(inputs: &PlanetInputs, n: usize, k: u32, plan: &QuantPlan) -> Result<Resampled> {
    let resampler = Resampler::new(inputs, n, k, plan)?;
    let domain = *resampler.domain();
    let per_face = PlanetGrid::tile_rects(&domain, resampler.tile_log2()).len();
    let faces: Vec<Vec<(PlanetTile, Vec<u16>)>> = (0..domain.faces())
        .map(|face| {
            (0..per_face)
                .into_par_iter()
                .map(|i| resampler.final_tile(face, i))
                .collect::<Result<Vec<_>>>()
        })
        .collect::<Result<Vec<_>>>()?;
    let mut winners = Vec::with_capacity(faces.len());
    let mut tiles = Vec::with_capacity(faces.len());
    for face in faces {
        let (t, w): (Vec<_>, Vec<_>) = face.into_iter().unzip();
        tiles.push(t);
        winners.push(w);
    }
    let variable = resampler.is_variable();
    let planet = PlanetGrid::from_tiles(n, k, resampler.tile_log2(), tiles, variable)?;
    Ok(Resampled {
        planet,
        winners,
        strides: resampler.input_strides().to_vec(),
    })
}

/// What a planet build made.
#[derive(Clone, Debug)]
pub struct PlanetSummary {
    /// Diamond grid side `N`.
    pub n: usize,
    /// Level pairs `K`.
    pub level_pairs: u32,
    /// The level pairs the finest input asks for: above `level_pairs` when `--planet-level`
    /// made the lattice coarser.
    pub finest_input_level_pairs: u32,
    /// Mean lattice spacing, degrees.
    pub lattice_deg: f64,
    /// Distinct lattice points (`6·S² + 2`).
    pub lattice_points: u64,
    /// Points the planet's tiles held ([`PlanetGrid::held_points`]): what the build's memory
    /// and time follow.
    pub held_points: u64,
    /// Lattice points with data.
    pub valid: u64,
    /// Records in the repository.
    pub records: usize,
    /// The integer mapping.
    pub plan: QuantPlan,
    /// Per input, the resampling error against its samples.
    pub resampling: Vec<InputResampling>,
    /// Times an input was read from its file: once for the height range, then again each time
    /// the resampling asked for one the cache had let go ([`input_cache_budget`]).
    pub inputs_read: u64,
    /// Wall time of each stage.
    pub stages: Vec<(&'static str, std::time::Duration)>,
    /// Encoded block by block: how many blocks, and how many lattice tiles they group.
    pub blocks: Option<(usize, usize)>,
    /// Block by block: lattice points painted by each step ([`LatticeEncode::painted`]).
    pub painted: Vec<(&'static str, u64)>,
    /// Block by block: points the outline did not paint ([`LatticeEncode::outline_covered`]).
    pub outline_covered: u64,
    /// Block by block: the peak resident memory after each step ([`LatticeEncode::peaks`]).
    pub peaks: Vec<(&'static str, u64)>,
    /// Block by block: inputs read from their files by each step ([`LatticeEncode::reads`]).
    pub reads: Vec<(&'static str, u64)>,
    /// Block by block: the CPU time of each step ([`LatticeEncode::cpu`]).
    pub cpu: Vec<(&'static str, (f64, f64))>,
}

/// Bytes a planet build holds per lattice point its tiles hold when it resamples and encodes
/// the whole lattice at once (measured on the ETOPO5 planet with margin, `/usr/bin/time -v
/// cbdam build data/etopo5_global.tif --planet --max-error 16`: 19.6 B a point): the tiles
/// (6 B with classes), the resampling winners (2 B) and the encoder's per-diamond refinements
/// of two levels. A lattice over the memory limit at this rate is encoded block by block.
pub const BYTES_PER_LATTICE_POINT: u64 = 24;

/// The whole lattice resampled, then encoded while each input's resampling error is measured
/// (the measurement fills the cores the encoder's coarse levels leave idle): what
/// [`encode_out_of_core`] gives, for a lattice that fits in memory.
fn encode_whole(
    inputs: &PlanetInputs,
    n: usize,
    k: u32,
    plan: &QuantPlan,
    enc: &EncodeOptions,
) -> Result<LatticeEncode> {
    let resampled = resample(inputs, n, k, plan)?;
    let (encoded, resampling) = rayon::join(
        || encode_planet(&resampled.planet, plan.quantizer, enc),
        || resampling_error(inputs, &resampled, plan),
    );
    Ok(LatticeEncode {
        encoded: encoded?,
        resampling: resampling?,
        valid: count_valid(&resampled.planet),
        held_points: resampled.planet.held_points(),
        blocks: None,
        painted: Vec::new(),
        outline_covered: 0,
        peaks: Vec::new(),
        reads: Vec::new(),
        cpu: Vec::new(),
    })
}

/// Resamples and encodes the lattice: whole in memory where its tiles fit in the memory limit
/// at [`BYTES_PER_LATTICE_POINT`] (the faster path), block by block where not, with a journal
/// of finished blocks beside the output so that a build killed and run again continues (the
/// whole-lattice path is short enough to redo). The same bytes either way; the stage is named
/// after the path taken.
#[allow(clippy::too_many_arguments)]
fn encode_lattice(
    opts: &BuildOptions,
    tiles: &[Tile],
    inputs: &PlanetInputs,
    (n, k): (usize, u32),
    plan: &QuantPlan,
    enc: &EncodeOptions,
    progress: &dyn Progress,
    stages: &mut Vec<(&'static str, std::time::Duration)>,
) -> Result<(LatticeEncode, Option<crate::journal::Journal>)> {
    let limit = opts
        .memory_limit
        .unwrap_or_else(crate::plan::default_memory_limit);
    let whole = crate::planet_plan::estimated_held_points(inputs, n, k)?
        .saturating_mul(BYTES_PER_LATTICE_POINT)
        <= limit;
    if whole {
        let t = Instant::now();
        let lattice = encode_whole(inputs, n, k, plan, enc)?;
        stages.push((
            "resample, encode and measure resampling error (whole lattice)",
            t.elapsed(),
        ));
        return Ok((lattice, None));
    }
    let t = Instant::now();
    let memory = PlanetMemory::new(inputs, (n, k), rayon::current_num_threads(), limit)?;
    if let Some(message) = memory.too_small() {
        progress.warning(&message);
    }
    inputs.set_cache_budget(memory.input_cache_budget());
    let block_bytes = memory.block_bytes();
    // The blocks are grouped within the blocks' share less what the encode holds per diamond
    // (`LatticeTiles::share_out`, since 2026-12-08): a journal of blocks grouped otherwise
    // starts over rather than mixing two groupings.
    let key = crate::journal_key(opts, tiles, enc, None)?
        + &format!(
            "planet=1\nlevel_pairs={k}\nplanet_block_bytes={block_bytes}\n\
             planet_blocks=less the diamonds\n"
        );
    let (journal, resumed) = crate::journal::Journal::open(&opts.output, &key)?;
    stages.push(("journal (hash the inputs, check the blocks)", t.elapsed()));
    progress.resumed(&resumed);
    let t = Instant::now();
    let lattice = encode_out_of_core(
        inputs,
        n,
        k,
        plan,
        enc,
        (memory.lattice_cache_budget(), block_bytes),
        &journal,
    )?;
    stages.push((
        "resample, encode and measure resampling error (block by block)",
        t.elapsed(),
    ));
    Ok((lattice, Some(journal)))
}

/// Bytes of the inputs' samples a planet build keeps besides those in use while it reads them
/// for the height range, and a sharded build's steps throughout: an eighth of the memory limit
/// (the rest is the lattice's; `cbdam build --planet`'s block-wise encode shares the limit less
/// its floor out instead, [`PlanetMemory`]). The inputs are read when a lattice tile asks for
/// them, so memory does not grow with their number.
pub fn input_cache_budget(memory_limit: u64) -> u64 {
    memory_limit / 8
}

/// Bytes of resampled lattice tiles a sharded planet build keeps for the blocks that read them
/// again (a block reads its neighbours' edges): a quarter of the memory limit ([`PlanetMemory`]
/// for `cbdam build --planet`).
pub fn lattice_cache_budget(memory_limit: u64) -> u64 {
    memory_limit / 4
}

/// Bytes one block of a sharded planet build is planned to hold (its tiles, and the grids of
/// the diamonds it owns): a quarter of the memory limit ([`PlanetMemory`] for `cbdam build
/// --planet`). Tiles are grouped into blocks of
/// about this much ([`cbdam_codec::hierarchy::planet::BlockGroups`]), so that blocks follow the
/// data: a coarse face is a few blocks, a fine tile one.
pub fn planet_block_bytes(memory_limit: u64) -> u64 {
    memory_limit / 4
}

/// Distinct lattice points with data (a point on a cube edge or corner counted once, a point
/// on a tile's side once).
pub fn count_valid(planet: &PlanetGrid) -> u64 {
    let d = planet.domain();
    (0..d.faces())
        .flat_map(|f| planet.tiles(f).iter().map(move |t| (f, t)))
        .collect::<Vec<_>>()
        .into_par_iter()
        .map(|(f, t)| valid_in_tile(d, f, t))
        .sum()
}

/// Checks the options a planet build does not take.
pub(crate) fn refuse_planar_options(opts: &BuildOptions) -> Result<()> {
    if opts.colour || opts.like.is_some() {
        bail!("--planet builds elevation; colour planets are not supported yet");
    }
    if opts.raw_size.is_some() {
        bail!("--planet: raw float32 inputs carry no georeferencing");
    }
    if opts.alpha != Alpha::One {
        bail!("--planet needs --alpha one (the α = ½ analysis filter is planar)");
    }
    if opts.block_plan.is_some() {
        bail!("--planet does not take --block-plan (planets are encoded whole)");
    }
    if opts.quantum.is_some() {
        bail!("--planet: resampled heights lie on no value grid, so --quantum does not apply");
    }
    Ok(())
}

/// The inputs of a planet build, expanded and opened, and their height range: every input read
/// once here (one at a time, on `pool`), so that a damaged one is named before the lattice.
fn open_planet_inputs(
    opts: &BuildOptions,
    pool: &rayon::ThreadPool,
    cache_budget: u64,
) -> Result<(Vec<Tile>, PlanetInputs, (f64, f64))> {
    let tiles = crate::tiles::expand_inputs(&opts.inputs)?;
    crate::check_output_is_not_an_input(opts, &tiles)?;
    crate::input_cache::give_large_frees_back();
    let inputs = PlanetInputs::read(
        &tiles,
        opts.nodata,
        opts.assign_georef.as_ref(),
        cache_budget,
    )?;
    let Some(range) = pool.install(|| inputs.range())? else {
        bail!("the inputs have no valid sample (all nodata or NaN)");
    };
    Ok((tiles, inputs, range))
}

/// Writes the planet repository (atomically), then removes the journal of its blocks.
fn write_planet(
    opts: &BuildOptions,
    encoded: &cbdam_codec::hierarchy::Encoded,
    plan: &QuantPlan,
    resampling: &[InputResampling],
    journal: Option<crate::journal::Journal>,
) -> Result<()> {
    write_planet_repository(
        &opts.output,
        encoded,
        plan,
        opts.nodata,
        &provenance_of(resampling),
    )
    .with_context(|| format!("writing {}", opts.output.display()))?;
    if let Some(journal) = journal {
        journal.finish()?;
    }
    Ok(())
}

/// Builds a planet repository from `opts.inputs` (each a geographic or UTM DEM, a directory,
/// glob or `@list` of them).
pub fn build_planet(
    opts: &BuildOptions,
    planet_level: Option<u32>,
    progress: &dyn Progress,
) -> Result<PlanetSummary> {
    refuse_planar_options(opts)?;
    crate::check_tolerance_and_output(opts)?;
    let limit = opts
        .memory_limit
        .unwrap_or_else(crate::plan::default_memory_limit);
    let event = |stage, done| {
        progress.event(ProgressEvent {
            stage,
            done,
            total: 1,
        })
    };
    let mut stages = Vec::new();
    event(Stage::Prepare, 0);
    // Every stage runs on the build's own workers (`--threads`).
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(opts.threads.unwrap_or(0))
        .build()
        .context("starting the build's threads")?;
    let t = Instant::now();
    let (tiles, inputs, (lo, hi)) = open_planet_inputs(opts, &pool, input_cache_budget(limit))?;
    stages.push(("read", t.elapsed()));
    let n = opts.diamond_size;
    let k = choose_level(&inputs, n, planet_level)?;
    let wanted = choose_level(&inputs, n, None)?;
    let plan = QuantPlan::new(opts.max_error, None, lo, hi)?;
    event(Stage::Prepare, 1);
    event(Stage::Encode, 0);
    let enc = EncodeOptions {
        n,
        extra_level_pairs: 0,
        alpha: Alpha::One,
        coder: opts.coder,
    };
    let (lattice, journal) = pool.install(|| {
        encode_lattice(
            opts,
            &tiles,
            &inputs,
            (n, k),
            &plan,
            &enc,
            progress,
            &mut stages,
        )
    })?;
    let (encoded, resampling) = (lattice.encoded, lattice.resampling);
    event(Stage::Encode, 1);
    event(Stage::Write, 0);
    let t = Instant::now();
    write_planet(opts, &encoded, &plan, &resampling, journal)?;
    stages.push(("write", t.elapsed()));
    event(Stage::Write, 1);
    Ok(PlanetSummary {
        n,
        level_pairs: k,
        finest_input_level_pairs: wanted,
        lattice_deg: lattice_spacing_deg(n, k),
        lattice_points: Domain::cube_sphere(n, k)?.lattice_points(),
        held_points: lattice.held_points,
        valid: lattice.valid,
        records: encoded.records.len(),
        plan,
        resampling,
        inputs_read: inputs.reads().0,
        stages,
        blocks: lattice.blocks,
        painted: lattice.painted,
        outline_covered: lattice.outline_covered,
        peaks: lattice.peaks,
        reads: lattice.reads,
        cpu: lattice.cpu,
    })
}

/// A planet repository checked against its inputs ([`compare_planet`]).
#[derive(Clone, Debug)]
pub struct PlanetComparison {
    /// Every level of the hierarchy against the resampled lattice (units; bound `k`).
    pub report: cbdam_codec::hierarchy::VerifyReport,
    /// The resampled lattice against each input's samples (what the build reported).
    pub resampling: Vec<InputResampling>,
    /// The decoded finest level against each input's samples, measured the same way.
    pub end_to_end: Vec<InputResampling>,
    /// The repository's bound in metres.
    pub max_error: f64,
    /// Compared block by block ([`crate::planet_verify`]): how; `None` when whole.
    pub blocks: Option<BlockWise>,
}

/// How a planet was compared block by block ([`crate::planet_verify`]).
#[derive(Debug, Clone, Copy)]
pub struct BlockWise {
    /// Blocks of lattice tiles.
    pub blocks: usize,
    /// Bytes of the decoded finest level written to temporary files.
    pub decoded_written: u64,
    /// The most of them held at once (the insets' tiles are let go once measured).
    pub decoded_peak: u64,
    /// Those held at the end (every tile at the global inputs' stride).
    pub decoded_at_end: u64,
}

impl PlanetComparison {
    /// Errors unless every level is within the bound and, per input, the decoded surface is
    /// within the bound plus the resampling error of the samples (the triangle inequality: the
    /// bilinear weights are non-negative and sum to 1).
    pub fn check(&self) -> Result<()> {
        if !self.report.within_bound() {
            bail!(
                "a level exceeds the bound: max error {} units, bound {}",
                self.report.max_error(),
                self.report.bound
            );
        }
        for (r, e) in self.resampling.iter().zip(&self.end_to_end) {
            let allowed = r.max_error + self.max_error + 1e-9;
            if e.max_error > allowed {
                bail!(
                    "{}: the decoded surface is {:.6} m from a sample, over the {:.6} m of the \
                     bound plus the resampling error",
                    e.path.display(),
                    e.max_error,
                    allowed
                );
            }
        }
        Ok(())
    }
}

/// Checks a planet repository against the inputs it was built from: the inputs are resampled
/// again onto the repository's lattice (the same arithmetic as the build, so the same integer
/// lattice), every level is compared with it exactly
/// ([`cbdam_codec::hierarchy::verify_planet`]), and both the lattice and the decoded finest
/// level are measured against the inputs' samples.
pub fn compare_planet(
    repo: &cbdam_codec::repository::Repository,
    tiles: &[Tile],
    nodata: Option<f64>,
    assign: Option<&AssignedGeoRef>,
) -> Result<PlanetComparison> {
    if repo.head().params().domain.cube().is_none() {
        bail!("this repository is planar: compare it with compare_dem or compare_tiles");
    }
    let budget = input_cache_budget(crate::plan::default_memory_limit());
    let inputs = PlanetInputs::read(tiles, nodata, assign, budget)?;
    compare_planet_inputs(repo, &inputs)
}

/// [`compare_planet`] of inputs already opened.
pub(crate) fn compare_planet_inputs(
    repo: &cbdam_codec::repository::Repository,
    inputs: &PlanetInputs,
) -> Result<PlanetComparison> {
    use cbdam_codec::hierarchy::{reconstruct_planet_like, verify_planet};
    let domain = repo.head().params().domain;
    let plan = *repo.head().plan();
    let (n, k) = (domain.n(), domain.layout().k());
    let resampled = resample(inputs, n, k, &plan)?;
    let encoded = repo.to_encoded()?;
    let report = verify_planet(&encoded, &resampled.planet)?;
    let resampling = resampling_error(inputs, &resampled, &plan)?;
    let decoded = Resampled {
        planet: reconstruct_planet_like(&encoded, &resampled.planet)?,
        winners: resampled.winners,
        strides: resampled.strides,
    };
    let end_to_end = resampling_error(inputs, &decoded, &plan)?;
    Ok(PlanetComparison {
        report,
        resampling,
        end_to_end,
        max_error: plan.max_error(),
        blocks: None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::band_cache::Samples;
    use crate::planet_input::{Frame, SampleSource, frame_of};
    use cbdam_codec::geodesy::LatLon;
    use cbdam_codec::repository::GeoRef;
    use std::path::PathBuf;
    use std::sync::Arc;

    fn input(spacing_deg: f64) -> PlanetInput {
        PlanetInput {
            path: PathBuf::from("x.tif"),
            width: 2,
            height: 2,
            source: SampleSource::Held(Arc::new(Samples::compact(vec![0.0; 4]))),
            nodata: None,
            frame: Frame::Geographic {
                lon0: 0.0,
                lat0: 1.0,
                dlon: spacing_deg,
                dlat: spacing_deg,
                period: None,
            },
            spacing_deg,
        }
    }

    /// The lattice is the coarsest at least as fine as the finest input (whatever the memory:
    /// it is encoded out of core); `--planet-level` sets it, finer or coarser, up to 16.
    #[test]
    fn the_level_follows_the_finest_input_unless_forced() {
        let inputs = PlanetInputs::held(vec![input(0.25), input(2.0)]);
        // 90°/(16·2^K) ≤ 0.25° first at K = 5 (0.176°); K = 4 is 0.352°.
        assert_eq!(choose_level(&inputs, 17, None).unwrap(), 5);
        let coarse = PlanetInputs::held(vec![input(2.0)]);
        // 90°/(16·2^K) ≤ 2° first at K = 2 (1.41°).
        assert_eq!(choose_level(&coarse, 17, None).unwrap(), 2);
        assert_eq!(choose_level(&inputs, 17, Some(3)).unwrap(), 3);
        assert_eq!(choose_level(&inputs, 17, Some(6)).unwrap(), 6);
        let e = choose_level(&inputs, 17, Some(17)).unwrap_err().to_string();
        assert!(
            e.contains("--planet-level 17") && e.contains("at most 16"),
            "{e}"
        );
    }

    /// More inputs than a winner index holds are refused by count, before any is read.
    #[test]
    fn more_inputs_than_a_planet_tells_apart_are_refused_before_reading() {
        let tiles: Vec<Tile> = (0..=MAX_PLANET_INPUTS)
            .map(|i| Tile {
                path: PathBuf::from(format!("/nonexistent/{i}.tif")),
                vrt: None,
            })
            .collect();
        let e = PlanetInputs::read(&tiles, None, None, 0)
            .err()
            .unwrap()
            .to_string();
        assert!(
            e.contains("65535 inputs") && e.contains("at most 65534"),
            "{e}"
        );
        // One fewer is read (and fails on the first missing file, naming it).
        let e = PlanetInputs::read(&tiles[1..], None, None, 0)
            .err()
            .unwrap();
        assert!(format!("{e:#}").contains("/nonexistent/1.tif"), "{e:#}");
    }

    /// Bilinear interpolation reproduces a function linear in columns and rows, wraps across
    /// the seam of a global input, and needs all four samples valid.
    #[test]
    fn bilinear_wraps_and_needs_four_valid_samples() {
        // 4 columns of 90°: a global input; value = 10·column + row.
        let mut values: Vec<f64> = (0..12).map(|i| f64::from(10 * (i % 4) + i / 4)).collect();
        let mut g = PlanetInput {
            path: PathBuf::from("g.tif"),
            width: 4,
            height: 3,
            source: SampleSource::Held(Arc::new(Samples::compact(values.clone()))),
            nodata: Some(-1.0),
            frame: Frame::Geographic {
                lon0: 0.0,
                lat0: 90.0,
                dlon: 90.0,
                dlat: 90.0,
                period: Some(4),
            },
            spacing_deg: 90.0,
        };
        let at = |g: &PlanetInput, lat, lon| {
            let SampleSource::Held(s) = &g.source else {
                unreachable!("made in memory")
            };
            g.bilinear(&**s, g.pixel_of(LatLon { lat, lon }).unwrap())
        };
        assert_eq!(at(&g, 45.0, 45.0), Some(5.0 + 0.5));
        // Between column 3 (270°) and column 0 (360° = 0°): halfway is 315° = −45°.
        assert_eq!(at(&g, 0.0, -45.0), Some(0.5 * 30.0 + 0.5 * 0.0 + 1.0));
        values[4] = -1.0;
        g.source = SampleSource::Held(Arc::new(Samples::compact(values)));
        assert_eq!(at(&g, 45.0, 45.0), None);
    }

    /// Only an input whose columns go all the way round wraps: an inset whose spacing divides
    /// 360° (3″, as SRTM's) covers nothing east of its last column.
    #[test]
    fn only_inputs_around_the_globe_wrap() {
        let georef = |pixel: f64| GeoRef {
            epsg: Some(4326),
            origin_x: 10.0,
            origin_y: 50.0,
            pixel_x: pixel,
            pixel_y: pixel,
            pixel_is_area: false,
            wkt: None,
        };
        let wraps = |f: Frame| {
            matches!(
                f,
                Frame::Geographic {
                    period: Some(_),
                    ..
                }
            )
        };
        assert!(wraps(frame_of(&georef(5.0 / 60.0), 4320).unwrap()));
        assert!(!wraps(frame_of(&georef(5.0 / 60.0), 100).unwrap()));
        assert!(!wraps(frame_of(&georef(3.0 / 3600.0), 1201).unwrap()));
        let mut inset = input(0.5);
        inset.width = 3;
        inset.source = SampleSource::Held(Arc::new(Samples::compact(vec![0.0; 6])));
        inset.frame = frame_of(&georef(0.5), 3).unwrap();
        // Columns at 10°, 10.5° and 11° E: 11.2° E is off the inset, 10.9° E on it.
        assert!(
            inset
                .pixel_of(LatLon {
                    lat: 49.8,
                    lon: 11.2
                })
                .is_none()
        );
        assert!(
            inset
                .pixel_of(LatLon {
                    lat: 49.8,
                    lon: 10.9
                })
                .is_some()
        );
    }
}
