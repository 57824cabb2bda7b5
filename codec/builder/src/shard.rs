//! Sharded builds: the block encode of [`crate::build_elevation`] split into steps that run as
//! separate processes, on other machines, and are put together without encoding again into the
//! repository `cbdam build` writes with the same arguments, byte for byte.
//!
//! Every step reads and writes one *work directory* on a path all machines share:
//!
//! - [`plan`] reads the inputs once (as `cbdam build` does), chooses the block plan and the shards
//!   (runs of consecutive blocks) and keeps the quantized grid as `prepared` (the lattice's own
//!   arrays, made in the work directory, and a CRC of each tile: [`crate::shard_grid`]), writes `summary` (what
//!   the encoder's setup measures of the whole grid, so no later step scans it), `plan` (what
//!   the other steps need: output path, options, quantization, georeferencing, blocks, shards)
//!   and, last, `key` (every input and argument that decides the output): a work directory with
//!   a `key` is planned. Planning again with the same key does nothing; with another it is
//!   refused, naming the first difference.
//! - [`apex`] reads `prepared`, refines the levels above the cut over the whole domain and
//!   writes `apex.field` (the reconstruction at the cut, 4 bytes a point) and `apex` (its
//!   records; the blocks measure its object errors).
//! - [`run`] checks the tiles of `prepared` under its blocks' fields, reads them (and
//!   nothing else of the grid) block by block, reads `apex.field`, and
//!   writes one file per block of its shard in `blocks/`: the build journal's block files
//!   ([`crate::journal`]), each renamed into place whole with a CRC, holding besides the block's
//!   records and errors the apex's errors over the block's square. Blocks already there are
//!   kept, so a retried or repeated shard is harmless.
//! - [`merge`] reads `summary`, `apex` and every block file (no sample, but for
//!   `--extra-levels auto`'s second try on small inputs), saturates the object errors over all
//!   of them, and writes the repository atomically. A missing shard is named.
//!
//! Every file is written under a temporary name and renamed, so a killed step leaves nothing
//! half-written.

use std::fs;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use cbdam_codec::geometry::Domain;
use cbdam_codec::hierarchy::{
    BlockJournal, BlockOutput, BlockPlan, GridSummary, NO_WINDOW, Resolution, ShardedEncode,
    TempStorage,
};
use cbdam_codec::lifting::Alpha;
use cbdam_codec::quant::{HeightGrid, QuantPlan};
use cbdam_codec::repository::write_repository;
use cbdam_codec::temp::LATTICE_TEMP_PREFIX;

use crate::encode::{
    AUTO_RETRY_MAX_SAMPLES, ExtraLevels, thread_pool, with_coarser_roots_if_smaller,
};
use crate::error::{Context, Result, bail};
use crate::journal::{Journal, parse_block, serialize_block, write_atomically};
use crate::plan::Prepared;
use crate::shard_grid::{PreparedGrid, read_prepared, read_summary, write_prepared, write_summary};
use crate::{BuildOptions, Progress, input_tiles, journal_key, prepare_elevation};

pub(crate) const KEY: &str = "key";
const PLAN: &str = "plan";
const APEX: &str = "apex";
const APEX_FIELD: &str = "apex.field";
const BLOCKS: &str = "blocks";
/// Marks a directory as a work directory, so that planning never clears one it did not make.
const MARKER: &str = ".cbdam-shard";

/// Magic bytes of the `apex.field` file.
const FIELD_MAGIC: &[u8; 4] = b"CBDF";
/// Version of the work directory's layout (2: the blocks measure the apex's object errors;
/// 3: the prepared grid is the lattice's own arrays, with a table of tile checksums).
const VERSION: u32 = 3;

pub use crate::shard_plan::ShardPlan;

/// What [`plan`] did.
#[derive(Clone, Debug)]
pub struct PlanSummary {
    /// The plan (read back from the work directory).
    pub plan: ShardPlan,
    /// Whether the work directory already held this plan (nothing was done).
    pub reused: bool,
    /// Wall time.
    pub elapsed: Duration,
}

/// Reads and quantizes the inputs of the build `opts` describes (as `cbdam build` would), chooses
/// the block plan (`opts.block_plan`, else the build's own, else blocks a quarter of the domain
/// across at most) and `shards` shards (default one per block; at most one per block), and writes
/// them to `work`. With `with_apex`, it also encodes the apex ([`apex`]) from the grid it holds,
/// saving the apex step a read of it. With the same inputs and arguments as the plan already
/// there it does nothing (but the apex, if asked for and missing).
pub fn plan(
    opts: &BuildOptions,
    work: &Path,
    shards: Option<usize>,
    with_apex: bool,
    progress: &dyn Progress,
) -> Result<PlanSummary> {
    let t = Instant::now();
    refuse_for_shards(opts, shards)?;
    let output = if opts.output.is_absolute() {
        opts.output.clone()
    } else {
        std::env::current_dir()?.join(&opts.output)
    };
    let key = plan_key(opts, &output, shards)?;
    let apex = || apex(work, opts.threads);
    if let Some(plan) = reuse_or_refuse(work, &key, with_apex, apex, || read_plan(work))? {
        return Ok(PlanSummary {
            plan,
            reused: true,
            elapsed: t.elapsed(),
        });
    }
    claim_work_dir(work)?;
    // The lattice's mapped files are made in the work directory, and kept as `prepared`.
    let mut prepared = prepare_elevation(opts, progress, Some(work))?;
    write_prepared(
        work,
        &mut prepared.input.grid,
        prepared.resolution.as_mut(),
        prepared.input.written.as_ref(),
    )?;
    let (blocks, block_count) = choose_blocks(&prepared)?;
    let grid = &prepared.input.grid;
    let enc = prepared.enc_opts;
    let plan = ShardPlan {
        output,
        width: grid.width,
        height: grid.height,
        variable: prepared.resolution.is_some(),
        diamond_size: enc.n,
        extra_levels: opts.extra_levels,
        coder: enc.coder,
        memory_limit: prepared.limit,
        quant: prepared.input.plan,
        georef: prepared.input.georef.clone(),
        nodata: prepared.input.nodata,
        blocks,
        block_count,
        shards: shards.unwrap_or(block_count).min(block_count).max(1),
    };
    // The setup's scans of the whole grid, once: the other steps read its summary.
    let pool = thread_pool(opts.threads)?;
    let encode = pool.install(|| {
        let e = ShardedEncode::new(
            grid,
            prepared.resolution.as_ref(),
            plan.quant.quantizer,
            &plan.encode_options(),
            plan.blocks,
        )?;
        check_block_count(&e, &plan)?;
        Ok::<_, crate::BuildError>(e)
    })?;
    write_summary(work, &encode.summary())?;
    let writing = || format!("writing the plan in {}", work.display());
    write_atomically(work, PLAN, plan.to_text().as_bytes()).with_context(writing)?;
    write_atomically(work, KEY, key.as_bytes()).with_context(writing)?;
    if with_apex {
        encode_apex(work, &encode, &pool)?;
    }
    Ok(PlanSummary {
        plan,
        reused: false,
        elapsed: t.elapsed(),
    })
}

/// Refuses what a sharded elevation build does not take.
fn refuse_for_shards(opts: &BuildOptions, shards: Option<usize>) -> Result<()> {
    if opts.colour {
        bail!(
            "sharded builds make elevation repositories; build colour with `cbdam build --colour`"
        );
    }
    if opts.alpha != Alpha::One {
        bail!(
            "a sharded build needs --alpha 1 (its blocks rely on the coarse levels being subsamples)"
        );
    }
    if shards == Some(0) {
        bail!("--shards must be at least 1");
    }
    Ok(())
}

/// The plan's key: the build journal's (every input and argument that decides the bytes) and
/// what the work directory adds.
fn plan_key(opts: &BuildOptions, output: &Path, shards: Option<usize>) -> Result<String> {
    let tiles = input_tiles(opts)?;
    let mut key = journal_key(
        opts,
        &tiles,
        &opts.encode_options(),
        opts.block_plan.as_ref(),
    )?;
    key += &format!(
        "shard_layout={VERSION}\noutput={}\nmemory_limit={}\nshards={}\n",
        output.display(),
        opts.memory_limit.map_or("auto".into(), |m| m.to_string()),
        shards.map_or("auto".into(), |s| s.to_string()),
    );
    Ok(key)
}

/// The plan already in `work` when its key is `key` (encoding the apex with `apex` if asked for
/// and missing), read with `read_plan`; `None` when `work` holds no plan; an error naming the
/// first difference when it holds another. Planes and planets alike.
pub(crate) fn reuse_or_refuse<P>(
    work: &Path,
    key: &str,
    with_apex: bool,
    apex: impl FnOnce() -> Result<bool>,
    read_plan: impl FnOnce() -> Result<P>,
) -> Result<Option<P>> {
    let Ok(old) = fs::read_to_string(work.join(KEY)) else {
        return Ok(None);
    };
    if old != key {
        bail!(
            "the work directory {} holds the plan of another build ({}); give another --work \
             or remove it",
            work.display(),
            crate::journal::first_difference(&old, key)
        );
    }
    if with_apex {
        apex()?;
    }
    read_plan().map(Some)
}

/// The block plan (`--block-plan`, else the build's own, else blocks a quarter of the domain
/// across at most) and how many blocks it makes.
fn choose_blocks(prepared: &crate::PreparedBuild) -> Result<(BlockPlan, usize)> {
    let enc = prepared.enc_opts;
    let grid = &prepared.input.grid;
    let domain = Domain::covering(enc.n, grid.width, grid.height, enc.extra_level_pairs)?;
    let blocks = match prepared.storage.blocks {
        Some(b) => b,
        None => {
            let (ex, ey) = domain.layout().face_extent();
            let input = 6 * (grid.width as u64) * (grid.height as u64);
            BlockPlan::fitting_at_most(
                domain.layout(),
                prepared.limit.saturating_sub(input),
                ex.max(ey) / 4,
                &NO_WINDOW,
            )
            .ok_or_else(|| {
                crate::BuildError::Invalid(format!(
                    "no block plan fits --memory-limit {} bytes beside the input",
                    prepared.limit
                ))
            })?
        }
    };
    Ok((blocks, blocks.blocks(domain.layout()).len()))
}

/// Makes `work` a work directory: created, or one already marked as such (an unfinished plan's),
/// or empty; anything else is refused rather than cleared.
pub(crate) fn claim_work_dir(work: &Path) -> Result<()> {
    let context = || format!("preparing the work directory {}", work.display());
    if work.exists() {
        let marked = work.join(MARKER).exists();
        let empty = fs::read_dir(work).with_context(context)?.next().is_none();
        if !marked && !empty {
            bail!(
                "the work directory {} is not empty and was not made by `cbdam shard plan`; \
                 give an empty or new directory",
                work.display()
            );
        }
        // An unfinished plan's leftovers: its blocks would belong to no key, and the lattice
        // files of a killed plan (removed when it ends any other way) are as large as the grid.
        let _ = fs::remove_dir_all(work.join(BLOCKS));
        for entry in fs::read_dir(work).with_context(context)?.flatten() {
            if entry
                .file_name()
                .to_string_lossy()
                .starts_with(LATTICE_TEMP_PREFIX)
            {
                let _ = fs::remove_file(entry.path());
            }
        }
    }
    fs::create_dir_all(work).with_context(context)?;
    fs::write(work.join(MARKER), b"a work directory of `cbdam shard`\n").with_context(context)?;
    Ok(())
}

/// The plan of a planned work directory.
pub fn read_plan(work: &Path) -> Result<ShardPlan> {
    let Ok(key) = fs::read_to_string(work.join(KEY)) else {
        bail!(
            "{} holds no finished plan: run `cbdam shard plan INPUTS... -o OUT --max-error E \
             --work {}` first",
            work.display(),
            work.display()
        );
    };
    let layout = key
        .lines()
        .find_map(|l| l.strip_prefix("shard_layout="))
        .unwrap_or("?");
    if layout != VERSION.to_string() {
        bail!(
            "{} was planned by another cbdam version (work directory layout {layout}, this one \
             reads {VERSION}): plan again in a new work directory",
            work.display()
        );
    }
    let file = work.join(PLAN);
    let text = fs::read_to_string(&file).with_context(|| format!("reading {}", file.display()))?;
    ShardPlan::parse(&text, &file)
}

/// Writes the apex field: magic, version, count, the values (i32), CRC-32; little-endian.
fn write_apex_field(work: &Path, field: &[i32]) -> std::io::Result<()> {
    let mut out = Vec::with_capacity(16 + 4 * field.len() + 4);
    out.extend_from_slice(FIELD_MAGIC);
    out.extend_from_slice(&VERSION.to_le_bytes());
    out.extend_from_slice(&(field.len() as u64).to_le_bytes());
    for v in field {
        out.extend_from_slice(&v.to_le_bytes());
    }
    let crc = crc32fast::hash(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    write_atomically(work, APEX_FIELD, &out)
}

fn read_apex_field(work: &Path) -> Result<Vec<i32>> {
    let path = work.join(APEX_FIELD);
    let bytes = match fs::read(&path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => bail!(
            "the apex is not encoded yet ({} is missing): run `cbdam shard apex --work {}` first",
            path.display(),
            work.display()
        ),
        Err(e) => return Err(e).with_context(|| format!("reading {}", path.display())),
    };
    let damaged = || crate::BuildError::Invalid(format!("{} is damaged", path.display()));
    let (body, crc) = bytes
        .split_at_checked(bytes.len().checked_sub(4).ok_or_else(damaged)?)
        .ok_or_else(damaged)?;
    if crc32fast::hash(body).to_le_bytes() != crc
        || body.len() < 16
        || &body[..4] != FIELD_MAGIC
        || body[4..8] != VERSION.to_le_bytes()
    {
        return Err(damaged());
    }
    let count = u64::from_le_bytes(body[8..16].try_into().expect("8 bytes"));
    let values = &body[16..];
    if values.len() as u64 != count.saturating_mul(4) {
        return Err(damaged());
    }
    Ok(values
        .chunks_exact(4)
        .map(|c| i32::from_le_bytes(c.try_into().expect("4 bytes")))
        .collect())
}

fn read_apex_records(work: &Path) -> Result<Option<BlockOutput>> {
    match fs::read(work.join(APEX)) {
        Ok(b) => Ok(parse_block(&b)),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(e).with_context(|| format!("reading {}", work.join(APEX).display())),
    }
}

/// The encode of the prepared grid (or the part of it a step reads) in the plan's blocks, set
/// up from the plan's summary of the grid.
fn sharded<'a>(
    grid: &'a HeightGrid,
    classes: Option<&'a Resolution>,
    plan: &ShardPlan,
    summary: GridSummary,
) -> Result<ShardedEncode<'a>> {
    let e = ShardedEncode::with_summary(
        grid,
        classes,
        plan.quant.quantizer,
        &plan.encode_options(),
        plan.blocks,
        summary,
    )?;
    check_block_count(&e, plan)?;
    Ok(e)
}

fn check_block_count(e: &ShardedEncode, plan: &ShardPlan) -> Result<()> {
    if e.block_count() != plan.block_count {
        bail!(
            "the plan counts {} blocks where its block plan makes {}: plan again in a new work \
             directory",
            plan.block_count,
            e.block_count()
        );
    }
    Ok(())
}

/// The prepared grid (and classes), mapped; no tile checked yet.
fn read_grid(work: &Path, plan: &ShardPlan) -> Result<PreparedGrid> {
    read_prepared(work, (plan.width, plan.height, plan.variable))
}

/// Encodes the apex (the levels above the cut) of a planned work directory, unless it is there.
/// Returns whether it encoded.
pub fn apex(work: &Path, threads: Option<usize>) -> Result<bool> {
    let plan = read_plan(work)?;
    if read_apex_records(work)?.is_some() && read_apex_field(work).is_ok() {
        return Ok(false);
    }
    let summary = read_summary(work)?;
    let PreparedGrid {
        grid,
        classes,
        mut tiles,
    } = read_grid(work, &plan)?;
    tiles.check(None)?;
    let encode = sharded(&grid, classes.as_ref(), &plan, summary)?;
    encode_apex(work, &encode, &thread_pool(threads)?)?;
    Ok(true)
}

/// Encodes the apex and writes it to `work`.
fn encode_apex(work: &Path, encode: &ShardedEncode, pool: &rayon::ThreadPool) -> Result<()> {
    let out = pool.install(|| encode.apex(&TempStorage::Memory))?;
    let writing = || format!("writing the apex in {}", work.display());
    // The field first: `apex` present means both are.
    write_apex_field(work, &out.field).with_context(writing)?;
    write_atomically(work, APEX, &serialize_block(&out.output)).with_context(writing)?;
    Ok(())
}

/// What [`run`] did.
#[derive(Clone, Debug)]
pub struct RunSummary {
    /// The shard's blocks.
    pub blocks: Range<usize>,
    /// How many of them this run encoded (the others an earlier run had).
    pub encoded: usize,
}

/// Refuses shard `shard` when the plan in `work` has only `shards` (planes and planets).
pub(crate) fn check_shard(work: &Path, shard: usize, shards: usize) -> Result<()> {
    if shard >= shards {
        bail!(
            "shard {shard} does not exist: the plan in {} has {} shards (0 … {})",
            work.display(),
            shards,
            shards - 1
        );
    }
    Ok(())
}

/// The block journal of `work` and the blocks of `blocks` it does not hold yet: what a run of
/// the shard owning `blocks` encodes (planes and planets).
pub(crate) fn unfinished_blocks(
    work: &Path,
    blocks: Range<usize>,
) -> Result<(Journal, Vec<usize>)> {
    let journal = Journal::in_dir(work.join(BLOCKS))?;
    let mut todo = Vec::new();
    for b in blocks {
        if journal.load(b)?.is_none() {
            todo.push(b);
        }
    }
    Ok((journal, todo))
}

/// Encodes the blocks of shard `shard` that are not in the work directory yet.
pub fn run(work: &Path, shard: usize, threads: Option<usize>) -> Result<RunSummary> {
    let plan = read_plan(work)?;
    check_shard(work, shard, plan.shards)?;
    let blocks = plan.shard_blocks(shard);
    let (journal, todo) = unfinished_blocks(work, blocks.clone())?;
    if todo.is_empty() {
        return Ok(RunSummary { blocks, encoded: 0 });
    }
    let field = read_apex_field(work)?;
    let summary = read_summary(work)?;
    // Only the tiles under the blocks' fields are read, each block's checked just before it
    // is encoded (so the encoder finds them in the page cache).
    let fields: Vec<_> = {
        let domain = Domain::covering(
            plan.diamond_size,
            plan.width,
            plan.height,
            plan.extra_levels.first(),
        )?;
        let blocks = plan.blocks.blocks(domain.layout());
        todo.iter()
            .map(|&b| blocks.get(b).map(|b| b.field_rect))
            .collect()
    };
    let PreparedGrid {
        grid,
        classes,
        mut tiles,
    } = read_grid(work, &plan)?;
    thread_pool(threads)?.install(|| -> Result<()> {
        let encode = sharded(&grid, classes.as_ref(), &plan, summary)?;
        let apex = encode.apex_field(&field, &TempStorage::Memory)?;
        drop(field);
        for (&b, field) in todo.iter().zip(&fields) {
            tiles.check(Some(field.as_slice()))?;
            let out = encode.block(&apex, b, &TempStorage::Memory)?;
            journal.save(b, &out)?;
        }
        Ok(())
    })?;
    Ok(RunSummary {
        blocks,
        encoded: todo.len(),
    })
}

/// The error of a merge that finds shards unfinished: `shards` (in block order, repeats
/// allowed) of `total`, `file` the first missing (a `kind`, e.g. "block file").
pub(crate) fn missing_shards(
    work: &Path,
    total: usize,
    mut shards: Vec<usize>,
    (kind, file): (&str, &Path),
) -> crate::BuildError {
    shards.dedup();
    let list: Vec<String> = shards.iter().map(usize::to_string).collect();
    crate::BuildError::Invalid(format!(
        "{} of {} shards have not finished: shard{} {} ({kind} {} missing); run `cbdam shard \
         run --work {} --shard I` for each",
        shards.len(),
        total,
        if shards.len() > 1 { "s" } else { "" },
        list.join(", "),
        file.display(),
        work.display()
    ))
}

/// The apex's output and every block's, in order; a damaged block file is named.
fn finished_parts(
    work: &Path,
    plan: &ShardPlan,
    journal: &Journal,
    apex: BlockOutput,
) -> Result<Vec<BlockOutput>> {
    let mut parts = vec![apex];
    for b in 0..plan.block_count {
        match journal.load(b)? {
            Some(out) => parts.push(out),
            None => bail!(
                "{} (shard {}) is damaged: remove it and run `cbdam shard run --work {} \
                 --shard {}` again",
                journal.block_path(b).display(),
                plan.shard_of(b),
                work.display(),
                plan.shard_of(b)
            ),
        }
    }
    Ok(parts)
}

/// What [`merge`] wrote.
#[derive(Clone, Debug)]
pub struct MergeSummary {
    /// The repository.
    pub output: PathBuf,
    /// Its records.
    pub records: usize,
    /// Samples per row and rows of the input.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// The integer mapping.
    pub quant: QuantPlan,
}

/// Puts the apex's and every shard's output together into the repository, written atomically.
/// A missing shard (or apex) is an error naming it.
pub fn merge(work: &Path, threads: Option<usize>) -> Result<MergeSummary> {
    let plan = read_plan(work)?;
    let journal = Journal::in_dir(work.join(BLOCKS))?;
    let missing: Vec<usize> = (0..plan.block_count)
        .filter(|&b| !journal.block_path(b).exists())
        .collect();
    if let Some(&first) = missing.first() {
        let shards = missing.iter().map(|&b| plan.shard_of(b)).collect();
        return Err(missing_shards(
            work,
            plan.shards,
            shards,
            ("block file", &journal.block_path(first)),
        ));
    }
    let Some(apex) = read_apex_records(work)? else {
        bail!(
            "the apex is not encoded ({} missing or damaged): run `cbdam shard apex --work {}`",
            work.join(APEX).display(),
            work.display()
        );
    };
    let summary = read_summary(work)?;
    // The merge reads no sample, but for `--extra-levels auto`'s second try on small inputs.
    let retry = plan.extra_levels == ExtraLevels::Auto
        && !plan.variable
        && plan.width * plan.height <= AUTO_RETRY_MAX_SAMPLES;
    let PreparedGrid {
        grid,
        classes,
        mut tiles,
    } = read_grid(work, &plan)?;
    if retry {
        tiles.check(None)?;
    }
    let input = Prepared {
        grid,
        plan: plan.quant,
        georef: plan.georef.clone(),
        nodata: plan.nodata,
        stages: Vec::new(),
        written: None,
    };
    let encoded = thread_pool(threads)?.install(|| -> Result<_> {
        let encode = sharded(&input.grid, classes.as_ref(), &plan, summary)?;
        let parts = finished_parts(work, &plan, &journal, apex)?;
        Ok(encode.finish(parts)?)
    })?;
    // `cbdam build`'s second try with sparser roots, on the small inputs where it applies.
    let encoded = if plan.extra_levels == ExtraLevels::Auto && classes.is_none() {
        let opts = plan.encode_options();
        with_coarser_roots_if_smaller(&input, encoded, &opts, plan.memory_limit, threads)?.0
    } else {
        encoded
    };
    write_repository(
        &plan.output,
        &encoded,
        &input.plan,
        input.georef.as_ref(),
        input.nodata,
    )
    .with_context(|| format!("writing {}", plan.output.display()))?;
    Ok(MergeSummary {
        output: plan.output.clone(),
        records: encoded.records.len(),
        width: plan.width,
        height: plan.height,
        quant: plan.quant,
    })
}
