//! Sharded planet builds: the block-wise planet encode of `cbdam build --planet`
//! ([`crate::planet_lattice`]) split into steps that run as separate processes, on other
//! machines, and merged without encoding again into the repository `cbdam build --planet`
//! writes with the same arguments, byte for byte. The same commands and work directory as
//! plane shards ([`crate::shard`]); what the files hold differs:
//!
//! - [`plan`] reads the inputs' headers and heights (the height range, as the build does),
//!   resamples every lattice tile once to outline the planet, and writes `outline` (the stored
//!   diamonds, each tile's stride, the cut), `planet` (the inputs as given, made absolute, with
//!   each file's size and modification time, and the arguments) and, last, `key`.
//! - [`apex`] encodes the levels above the cut from the tiles thinned to the cut's points and
//!   writes `planet-apex` (its records, and the grids and refinements the blocks start from).
//! - [`run`] encodes its shard's blocks (one per lattice tile, each resampled from the inputs
//!   as it is read), each written as the build journal's block file in `blocks/`, and measures
//!   the resampling error of its share of the inputs (`resampling/input-NNNNNN`).
//! - [`merge`] reads no input: the outline, the apex, every block and every input's resampling
//!   error, put together and written atomically. A missing shard is named.
//!
//! The inputs are read by every step but the merge: they must be on a path every machine
//! reaches, unchanged; a step that finds one changed since the plan (size or modification
//! time) refuses, naming it.

use std::fs;
use std::path::{Path, PathBuf};

use cbdam_codec::CodecError;
use cbdam_codec::entropy::CoderKind;
use cbdam_codec::hierarchy::planet::{
    Apex, PlanetBlocks, PlanetTile, PlanetTiles, default_cut, planet_block_groups,
};
use cbdam_codec::hierarchy::{BlockJournal, BlockOutput, EncodeOptions};
use cbdam_codec::lifting::Alpha;
use cbdam_codec::quant::QuantPlan;
use cbdam_codec::repository::write_planet_repository;

use crate::encode::thread_pool;
use crate::error::{Context, Result, bail};
use crate::journal::{Journal, write_atomically};
use crate::planet::{
    InputResampling, PlanetInputs, choose_level, input_cache_budget, lattice_cache_budget,
    planet_block_bytes, provenance_of,
};
use crate::planet_lattice::{LatticeTiles, Resampler};
use crate::planet_shard_files::{
    OutlineFile, read_apex, read_outline, read_resampling, write_apex, write_outline,
    write_resampling,
};
use crate::planet_shard_plan::{PlanetShardPlan, absolute, share};
use crate::shard::{
    KEY, RunSummary, check_shard, claim_work_dir, missing_shards, reuse_or_refuse,
    unfinished_blocks,
};
use crate::{BuildOptions, tiles::expand_inputs};

pub(crate) const PLANET: &str = "planet";
const OUTLINE: &str = "outline";
const APEX: &str = "planet-apex";
const RESAMPLING: &str = "resampling";
const BLOCKS: &str = "blocks";
/// The work directory layout of sharded planets, in the key (`shard_layout=`).
pub(crate) const LAYOUT: &str = "planet-2";

/// Whether `work` holds a finished plan of a planet.
pub fn is_planet(work: &Path) -> bool {
    fs::read_to_string(work.join(KEY))
        .is_ok_and(|k| k.lines().any(|l| l == format!("shard_layout={LAYOUT}")))
}

fn resampling_name(input: usize) -> String {
    format!("input-{input:06}")
}

/// What [`plan`] did.
#[derive(Clone, Debug)]
pub struct PlanetPlanSummary {
    /// The plan (as the work directory holds it).
    pub plan: PlanetShardPlan,
    /// Whether the work directory already held this plan (nothing was done).
    pub reused: bool,
}

/// Plans the sharded build of the planet `opts` describes (`opts.planet`: `--planet-level`)
/// in `work`: `shards` shards (default one per block, at most one per block). With
/// `with_apex`, it also encodes the apex ([`apex`]). With the inputs and arguments of the plan
/// already there it does nothing (but the apex, if asked for and missing); another plan there
/// is refused, naming the first difference.
pub fn plan(
    opts: &BuildOptions,
    work: &Path,
    shards: Option<usize>,
    with_apex: bool,
) -> Result<PlanetPlanSummary> {
    check_plan_options(opts, shards)?;
    let opts = with_absolute_paths(opts)?;
    let tiles = expand_inputs(&opts.inputs)?;
    crate::check_output_is_not_an_input(&opts, &tiles)?;
    let limit = opts
        .memory_limit
        .unwrap_or_else(crate::plan::default_memory_limit);
    let inputs = PlanetInputs::read(
        &tiles,
        opts.nodata,
        opts.assign_georef.as_ref(),
        input_cache_budget(limit),
    )?;
    let k = choose_level(&inputs, opts.diamond_size, opts.planet.flatten())?;
    let key = plan_key(&opts, &tiles, k, limit, shards)?;
    let apex = || apex(work, opts.threads);
    if let Some(plan) = reuse_or_refuse(work, &key, with_apex, apex, || read_plan(work))? {
        return Ok(PlanetPlanSummary { plan, reused: true });
    }
    claim_work_dir(work)?;
    let pool = thread_pool(opts.threads)?;
    let Some(range) = pool.install(|| inputs.range())? else {
        bail!("the inputs have no valid sample (all nodata or NaN)");
    };
    let quant = QuantPlan::new(opts.max_error, None, range.0, range.1)?;
    let resampler = Resampler::new(&inputs, opts.diamond_size, k, &quant)?;
    let (lattice, outline, valid, held_points) =
        pool.install(|| LatticeTiles::outline(resampler, lattice_cache_budget(limit), None))?;
    let outline = OutlineFile {
        cut: default_cut(outline.domain(), lattice.tile_log2()),
        strides: lattice.strides().to_vec(),
        outline,
        valid,
        held_points,
    };
    let min_blocks = shards.map_or(1, |s| 4 * s);
    let block_count = planet_block_groups(
        &outline.outline,
        outline.cut,
        &outline.strides,
        (planet_block_bytes(limit), min_blocks),
    )?
    .len();
    let plan = PlanetShardPlan {
        output: opts.output.clone(),
        inputs: opts.inputs.clone(),
        files: PlanetShardPlan::files_of(&tiles)?,
        nodata: opts.nodata,
        assign: opts.assign_georef,
        n: opts.diamond_size,
        k,
        max_error: opts.max_error,
        range,
        coder: opts.coder,
        memory_limit: limit,
        block_count,
        min_blocks,
        shards: shards.unwrap_or(block_count).clamp(1, block_count.max(1)),
    };
    write_outline(work, OUTLINE, &outline)?;
    let writing = || format!("writing the plan in {}", work.display());
    write_atomically(work, PLANET, plan.to_text().as_bytes()).with_context(writing)?;
    if with_apex {
        pool.install(|| encode_apex(work, &plan, &outline, &lattice))?;
    }
    write_atomically(work, KEY, key.as_bytes()).with_context(writing)?;
    Ok(PlanetPlanSummary {
        plan,
        reused: false,
    })
}

/// The options a sharded planet plan refuses: planar ones, a bad tolerance or output, no shard.
fn check_plan_options(opts: &BuildOptions, shards: Option<usize>) -> Result<()> {
    crate::planet::refuse_planar_options(opts)?;
    crate::check_tolerance_and_output(opts)?;
    if shards == Some(0) {
        bail!("--shards must be at least 1");
    }
    Ok(())
}

/// `opts` with its inputs and output made absolute: the steps may run elsewhere.
fn with_absolute_paths(opts: &BuildOptions) -> Result<BuildOptions> {
    let mut opts = opts.clone();
    opts.output = absolute(&opts.output)?;
    opts.inputs = opts
        .inputs
        .iter()
        .map(|p| absolute(p))
        .collect::<Result<_>>()?;
    Ok(opts)
}

/// The plan's key: the build journal's (every input's contents and every argument that decides
/// the bytes), the lattice's level pairs, and what the work directory adds.
fn plan_key(
    opts: &BuildOptions,
    tiles: &[crate::tiles::Tile],
    k: u32,
    limit: u64,
    shards: Option<usize>,
) -> Result<String> {
    let enc = encode_options(opts.diamond_size, opts.coder);
    Ok(crate::journal_key(opts, tiles, &enc, None)?
        + &format!(
            "planet=1\nlevel_pairs={k}\nshard_layout={LAYOUT}\noutput={}\nmemory_limit={limit}\n\
             shards={}\n",
            opts.output.display(),
            shards.map_or("auto".into(), |s| s.to_string()),
        ))
}

fn encode_options(n: usize, coder: CoderKind) -> EncodeOptions {
    EncodeOptions {
        n,
        extra_level_pairs: 0,
        alpha: Alpha::One,
        coder,
    }
}

/// The plan of a planned planet work directory.
pub fn read_plan(work: &Path) -> Result<PlanetShardPlan> {
    if !is_planet(work) {
        bail!(
            "{} holds no finished plan of a planet: run `cbdam shard plan INPUTS... --planet -o \
             OUT --max-error E --work {}` first",
            work.display(),
            work.display()
        );
    }
    PlanetShardPlan::read(&work.join(PLANET))
}

/// The inputs of `plan`, opened (headers read), each checked unchanged since the plan.
fn open_inputs(plan: &PlanetShardPlan) -> Result<PlanetInputs> {
    let tiles = expand_inputs(&plan.inputs)?;
    plan.check_files(&tiles)?;
    PlanetInputs::read(
        &tiles,
        plan.nodata,
        plan.assign.as_ref(),
        input_cache_budget(plan.memory_limit),
    )
}

/// The lattice's tiles at the strides the plan's outline fixed.
fn lattice<'a>(
    plan: &PlanetShardPlan,
    inputs: &'a PlanetInputs,
    quant: &'a QuantPlan,
    outline: &OutlineFile,
) -> Result<LatticeTiles<'a>> {
    let resampler = Resampler::new(inputs, plan.n, plan.k, quant)?;
    LatticeTiles::with_strides(
        resampler,
        outline.strides.clone(),
        lattice_cache_budget(plan.memory_limit),
    )
}

/// Encodes the apex from `tiles` and writes it.
fn encode_apex(
    work: &Path,
    plan: &PlanetShardPlan,
    outline: &OutlineFile,
    tiles: &dyn PlanetTiles,
) -> Result<()> {
    let quant = plan.quant()?;
    let enc = encode_options(plan.n, plan.coder);
    let blocks = PlanetBlocks::new(
        &outline.outline,
        tiles,
        quant.quantizer,
        &enc,
        outline.cut,
        Apex::Encode(planet_block_bytes(plan.memory_limit)),
    )?;
    write_apex(work, APEX, blocks.apex())
}

/// Encodes the apex of a planned planet work directory, unless it is there. Returns whether
/// it encoded.
pub fn apex(work: &Path, threads: Option<usize>) -> Result<bool> {
    let plan = read_plan(work)?;
    let outline = read_outline(work, OUTLINE)?;
    if read_apex(work, APEX, &outline.outline)?.is_some() {
        return Ok(false);
    }
    let inputs = open_inputs(&plan)?;
    let quant = plan.quant()?;
    let tiles = lattice(&plan, &inputs, &quant, &outline)?;
    thread_pool(threads)?.install(|| encode_apex(work, &plan, &outline, &tiles))?;
    Ok(true)
}

/// `blocks` with its tiles grouped as the plan grouped them (the memory limit's block size),
/// refusing a plan whose block count differs (another version's plan).
fn grouped<'a>(
    blocks: PlanetBlocks<'a>,
    plan: &PlanetShardPlan,
    outline: &OutlineFile,
) -> Result<PlanetBlocks<'a>> {
    let budget = (planet_block_bytes(plan.memory_limit), plan.min_blocks);
    let blocks = blocks.with_block_bytes(&outline.strides, budget)?;
    if blocks.block_count() != plan.block_count {
        bail!(
            "the plan has {} blocks but its outline groups into {}: plan again with this \
             version of cbdam",
            plan.block_count,
            blocks.block_count()
        );
    }
    Ok(blocks)
}

/// The inputs whose resampling error shard `shard` measures: every `shards`-th.
fn measured_by(plan: &PlanetShardPlan, inputs: usize, shard: usize) -> Vec<usize> {
    (shard..inputs).step_by(plan.shards.max(1)).collect()
}

/// Encodes the blocks of shard `shard` not in the work directory yet, and measures the
/// resampling error of its share of the inputs not measured yet.
pub fn run(work: &Path, shard: usize, threads: Option<usize>) -> Result<RunSummary> {
    let plan = read_plan(work)?;
    check_shard(work, shard, plan.shards)?;
    let blocks = share(plan.block_count, plan.shards, shard);
    let (journal, todo) = unfinished_blocks(work, blocks.clone())?;
    let measured = work.join(RESAMPLING);
    fs::create_dir_all(&measured).with_context(|| format!("creating {}", measured.display()))?;
    let mut to_measure = Vec::new();
    for i in measured_by(&plan, plan.files.len(), shard) {
        if read_resampling(&measured, &resampling_name(i))?.is_none() {
            to_measure.push(i);
        }
    }
    if todo.is_empty() && to_measure.is_empty() {
        return Ok(RunSummary { blocks, encoded: 0 });
    }
    let apex_path = work.join(APEX);
    if !todo.is_empty() && !apex_path.exists() {
        bail!(
            "the apex is not encoded yet ({} is missing): run `cbdam shard apex --work {}` first",
            apex_path.display(),
            work.display()
        );
    }
    let inputs = open_inputs(&plan)?;
    let outline = read_outline(work, OUTLINE)?;
    let quant = plan.quant()?;
    let tiles = lattice(&plan, &inputs, &quant, &outline)?;
    thread_pool(threads)?.install(|| -> Result<()> {
        if !todo.is_empty() {
            let Some(apex) = read_apex(work, APEX, &outline.outline)? else {
                bail!("{} vanished during the run", apex_path.display());
            };
            let enc = encode_options(plan.n, plan.coder);
            let encode = PlanetBlocks::new(
                &outline.outline,
                &tiles,
                quant.quantizer,
                &enc,
                outline.cut,
                Apex::Given(Box::new(apex)),
            )?;
            let encode = grouped(encode, &plan, &outline)?;
            for &b in &todo {
                journal.save(b, &encode.encode_block(b)?)?;
            }
        }
        for &i in &to_measure {
            write_resampling(&measured, &resampling_name(i), &tiles.resampling(i)?)?;
        }
        Ok(())
    })?;
    Ok(RunSummary {
        blocks,
        encoded: todo.len(),
    })
}

/// What [`merge`] wrote.
#[derive(Clone, Debug)]
pub struct PlanetMergeSummary {
    /// The repository.
    pub output: PathBuf,
    /// Its records.
    pub records: usize,
    /// The lattice's level pairs.
    pub level_pairs: u32,
    /// Lattice points with data.
    pub valid: u64,
    /// The integer mapping.
    pub quant: QuantPlan,
}

/// The merge's view of the blocks: every one must be there and whole (it reads no input to
/// encode one again).
struct Finished<'a> {
    journal: &'a Journal,
    plan: &'a PlanetShardPlan,
    work: &'a Path,
}

impl BlockJournal for Finished<'_> {
    fn load(&self, index: usize) -> Result<Option<BlockOutput>, CodecError> {
        match self.journal.load(index)? {
            Some(out) => Ok(Some(out)),
            None => {
                let shard = (0..self.plan.shards)
                    .find(|&s| share(self.plan.block_count, self.plan.shards, s).contains(&index))
                    .unwrap_or(0);
                Err(CodecError::invalid(format!(
                    "{} (shard {shard}) is damaged: remove it and run `cbdam shard run --work {} \
                     --shard {shard}` again",
                    self.journal.block_path(index).display(),
                    self.work.display()
                )))
            }
        }
    }

    fn save(&self, _index: usize, _output: &BlockOutput) -> Result<(), CodecError> {
        Ok(())
    }
}

/// The merge reads no tile: every block is finished.
struct NoTiles;

impl PlanetTiles for NoTiles {
    fn tile(
        &self,
        face: u8,
        index: usize,
        _: u32,
    ) -> Result<std::sync::Arc<PlanetTile>, CodecError> {
        Err(CodecError::invalid(format!(
            "the merge reads no tile (face {face} tile {index} asked for)"
        )))
    }
}

/// Every input's resampling error, as the shards measured it; a missing one names its shard.
fn measured_resampling(work: &Path, plan: &PlanetShardPlan) -> Result<Vec<InputResampling>> {
    let measured = work.join(RESAMPLING);
    let mut resampling = Vec::with_capacity(plan.files.len());
    for i in 0..plan.files.len() {
        match read_resampling(&measured, &resampling_name(i))? {
            Some(e) => resampling.push(e),
            None => {
                let shard = i % plan.shards.max(1);
                let file = measured.join(resampling_name(i));
                return Err(missing_shards(
                    work,
                    plan.shards,
                    vec![shard],
                    ("resampling error file", &file),
                ));
            }
        }
    }
    Ok(resampling)
}

/// Puts the apex, every block and every input's resampling error together into the
/// repository, written atomically. A missing shard (or apex) is an error naming it.
pub fn merge(work: &Path, threads: Option<usize>) -> Result<PlanetMergeSummary> {
    let plan = read_plan(work)?;
    let journal = Journal::in_dir(work.join(BLOCKS))?;
    let shard_of = |b: usize| {
        (0..plan.shards)
            .find(|&s| share(plan.block_count, plan.shards, s).contains(&b))
            .unwrap_or(0)
    };
    let missing: Vec<usize> = (0..plan.block_count)
        .filter(|&b| !journal.block_path(b).exists())
        .collect();
    if let Some(&first) = missing.first() {
        let shards: Vec<usize> = missing.iter().map(|&b| shard_of(b)).collect();
        let file = journal.block_path(first);
        return Err(missing_shards(
            work,
            plan.shards,
            shards,
            ("block file", &file),
        ));
    }
    let resampling = measured_resampling(work, &plan)?;
    let outline = read_outline(work, OUTLINE)?;
    let Some(apex) = read_apex(work, APEX, &outline.outline)? else {
        bail!(
            "the apex is not encoded ({} missing): run `cbdam shard apex --work {}`",
            work.join(APEX).display(),
            work.display()
        );
    };
    let quant = plan.quant()?;
    let enc = encode_options(plan.n, plan.coder);
    let encoded = thread_pool(threads)?.install(|| -> Result<_> {
        let finished = Finished {
            journal: &journal,
            plan: &plan,
            work,
        };
        let blocks = PlanetBlocks::new(
            &outline.outline,
            &NoTiles,
            quant.quantizer,
            &enc,
            outline.cut,
            Apex::Given(Box::new(apex)),
        )?;
        Ok(grouped(blocks, &plan, &outline)?.finish(&finished, true)?)
    })?;
    write_planet_repository(
        &plan.output,
        &encoded,
        &quant,
        plan.nodata,
        &provenance_of(&resampling),
    )
    .with_context(|| format!("writing {}", plan.output.display()))?;
    Ok(PlanetMergeSummary {
        output: plan.output.clone(),
        records: encoded.records.len(),
        level_pairs: plan.k,
        valid: outline.valid,
        quant,
    })
}
