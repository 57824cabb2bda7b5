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

use cbdam_codec::entropy::CoderKind;
use cbdam_codec::geometry::Domain;
use cbdam_codec::hierarchy::{
    BlockJournal, BlockOutput, BlockPlan, EncodeOptions, GridSummary, NO_WINDOW, Resolution,
    ShardedEncode, TempStorage,
};
use cbdam_codec::lifting::Alpha;
use cbdam_codec::quant::{HeightGrid, QuantPlan, Quantizer};
use cbdam_codec::repository::GeoRef;
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

const KEY: &str = "key";
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

/// What a sharded build's steps share: read from the work directory's `plan` file.
#[derive(Clone, Debug, PartialEq)]
pub struct ShardPlan {
    /// The repository the merge writes (absolute).
    pub output: PathBuf,
    /// Samples per row and rows of the (combined) input.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Whether the input is several inputs (a variable-resolution lattice with classes).
    pub variable: bool,
    /// Diamond grid side N.
    pub diamond_size: usize,
    /// `--extra-levels`.
    pub extra_levels: ExtraLevels,
    /// Entropy coder.
    pub coder: CoderKind,
    /// Memory limit of the build, bytes (the merge's `--extra-levels auto` retry).
    pub memory_limit: u64,
    /// The integer mapping.
    pub quant: QuantPlan,
    /// Georeferencing.
    pub georef: Option<GeoRef>,
    /// Nodata value.
    pub nodata: Option<f64>,
    /// The blocks.
    pub blocks: BlockPlan,
    /// How many blocks the plan makes.
    pub block_count: usize,
    /// How many shards (runs of consecutive blocks).
    pub shards: usize,
}

impl ShardPlan {
    /// The blocks of shard `shard` (`0 .. shards`).
    pub fn shard_blocks(&self, shard: usize) -> Range<usize> {
        let (b, s) = (self.block_count, self.shards.max(1));
        shard * b / s..(shard + 1) * b / s
    }

    /// The shard that holds `block`.
    fn shard_of(&self, block: usize) -> usize {
        (0..self.shards)
            .find(|&s| self.shard_blocks(s).contains(&block))
            .unwrap_or(0)
    }

    fn encode_options(&self) -> EncodeOptions {
        EncodeOptions {
            n: self.diamond_size,
            alpha: Alpha::One,
            coder: self.coder,
            extra_level_pairs: self.extra_levels.first(),
        }
    }

    /// The `plan` file: one `name=value` line each; floats as their bits, so they read back
    /// exactly.
    fn to_text(&self) -> String {
        let f = |v: f64| format!("{:016x}", v.to_bits());
        let q = &self.quant;
        let mut t = format!(
            "output={}\nwidth={}\nheight={}\nvariable={}\ndiamond_size={}\nextra_levels={}\n\
             coder={:?}\nmemory_limit={}\nunit={}\noffset={}\nk={}\nlattice={}\n\
             representation_error={}\nepsilon={}\ncut_level={}\nblock_side={}\nblocks={}\n\
             shards={}\n",
            hex(self.output.to_string_lossy().as_bytes()),
            self.width,
            self.height,
            self.variable,
            self.diamond_size,
            match self.extra_levels {
                ExtraLevels::Auto => "auto".to_string(),
                ExtraLevels::Fixed(n) => n.to_string(),
            },
            self.coder,
            self.memory_limit,
            f(q.unit),
            f(q.offset),
            q.quantizer.k(),
            q.lattice,
            f(q.representation_error),
            f(q.epsilon),
            self.blocks.cut_level,
            self.blocks.block_side,
            self.block_count,
            self.shards,
        );
        if let Some(nodata) = self.nodata {
            t += &format!("nodata={}\n", f(nodata));
        }
        if let Some(g) = &self.georef {
            t += &format!(
                "georef={} {} {} {} {} {} {}\n",
                g.epsg.map_or("-".to_string(), |e| e.to_string()),
                f(g.origin_x),
                f(g.origin_y),
                f(g.pixel_x),
                f(g.pixel_y),
                g.pixel_is_area,
                g.wkt
                    .as_deref()
                    .map_or("-".to_string(), |w| hex(w.as_bytes())),
            );
        }
        t
    }

    fn parse(text: &str, file: &Path) -> Result<ShardPlan> {
        let bad = |what: &str| {
            crate::BuildError::Invalid(format!(
                "{}: {what} missing or unreadable (a plan file of another cbdam version?)",
                file.display()
            ))
        };
        let value = |name: &str| {
            text.lines()
                .find_map(|l| l.strip_prefix(name)?.strip_prefix('='))
        };
        let get = |name: &str| value(name).ok_or_else(|| bad(name));
        let num = |name: &str| get(name)?.parse::<u64>().map_err(|_| bad(name));
        let float = |s: &str| u64::from_str_radix(s, 16).ok().map(f64::from_bits);
        let real = |name: &str| float(get(name)?).ok_or_else(|| bad(name));
        let text_of = |s: &str, name: &str| {
            unhex(s)
                .and_then(|b| String::from_utf8(b).ok())
                .ok_or_else(|| bad(name))
        };
        let k = get("k")?.parse::<u32>().map_err(|_| bad("k"))?;
        let quant = QuantPlan {
            unit: real("unit")?,
            offset: real("offset")?,
            quantizer: Quantizer::new(k).map_err(|_| bad("k"))?,
            lattice: get("lattice")? == "true",
            representation_error: real("representation_error")?,
            epsilon: real("epsilon")?,
            // Sharded builds bound the maximum error only.
            rms: None,
        };
        let georef = match value("georef") {
            None => None,
            Some(g) => {
                let p: Vec<&str> = g.split(' ').collect();
                let [epsg, ox, oy, px, py, area, wkt] = p[..] else {
                    return Err(bad("georef"));
                };
                let r = |s: &str| float(s).ok_or_else(|| bad("georef"));
                Some(GeoRef {
                    epsg: match epsg {
                        "-" => None,
                        e => Some(e.parse().map_err(|_| bad("georef"))?),
                    },
                    origin_x: r(ox)?,
                    origin_y: r(oy)?,
                    pixel_x: r(px)?,
                    pixel_y: r(py)?,
                    pixel_is_area: area == "true",
                    wkt: match wkt {
                        "-" => None,
                        w => Some(text_of(w, "georef")?),
                    },
                })
            }
        };
        let coder_name = get("coder")?;
        Ok(ShardPlan {
            output: PathBuf::from(text_of(get("output")?, "output")?),
            width: num("width")? as usize,
            height: num("height")? as usize,
            variable: get("variable")? == "true",
            diamond_size: num("diamond_size")? as usize,
            extra_levels: match get("extra_levels")? {
                "auto" => ExtraLevels::Auto,
                n => ExtraLevels::Fixed(n.parse().map_err(|_| bad("extra_levels"))?),
            },
            coder: CoderKind::ALL
                .into_iter()
                .find(|c| format!("{c:?}") == coder_name)
                .ok_or_else(|| bad("coder"))?,
            memory_limit: num("memory_limit")?,
            quant,
            georef,
            nodata: match value("nodata") {
                None => None,
                Some(v) => Some(float(v).ok_or_else(|| bad("nodata"))?),
            },
            blocks: BlockPlan {
                cut_level: num("cut_level")? as u8,
                block_side: num("block_side")? as i64,
            },
            block_count: num("blocks")? as usize,
            shards: num("shards")? as usize,
        })
    }
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn unhex(s: &str) -> Option<Vec<u8>> {
    if !s.len().is_multiple_of(2) {
        return None;
    }
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(s.get(i..i + 2)?, 16).ok())
        .collect()
}

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
    let output = if opts.output.is_absolute() {
        opts.output.clone()
    } else {
        std::env::current_dir()?.join(&opts.output)
    };
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
    if let Ok(old) = fs::read_to_string(work.join(KEY)) {
        if old == key {
            if with_apex {
                apex(work, opts.threads)?;
            }
            return Ok(PlanSummary {
                plan: read_plan(work)?,
                reused: true,
                elapsed: t.elapsed(),
            });
        }
        bail!(
            "the work directory {} holds the plan of another build ({}); give another --work \
             or remove it",
            work.display(),
            crate::journal::first_difference(&old, &key)
        );
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
    let enc = prepared.enc_opts;
    let grid = &prepared.input.grid;
    let blocks = match prepared.storage.blocks {
        Some(b) => b,
        None => {
            let domain = Domain::covering(enc.n, grid.width, grid.height, enc.extra_level_pairs)?;
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
    let block_count = {
        let domain = Domain::covering(enc.n, grid.width, grid.height, enc.extra_level_pairs)?;
        blocks.blocks(domain.layout()).len()
    };
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

/// Makes `work` a work directory: created, or one already marked as such (an unfinished plan's),
/// or empty; anything else is refused rather than cleared.
fn claim_work_dir(work: &Path) -> Result<()> {
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

/// Encodes the blocks of shard `shard` that are not in the work directory yet.
pub fn run(work: &Path, shard: usize, threads: Option<usize>) -> Result<RunSummary> {
    let plan = read_plan(work)?;
    if shard >= plan.shards {
        bail!(
            "shard {shard} does not exist: the plan in {} has {} shards (0 … {})",
            work.display(),
            plan.shards,
            plan.shards - 1
        );
    }
    let blocks = plan.shard_blocks(shard);
    let journal = Journal::in_dir(work.join(BLOCKS))?;
    let mut todo = Vec::new();
    for b in blocks.clone() {
        if journal.load(b)?.is_none() {
            todo.push(b);
        }
    }
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
    if !missing.is_empty() {
        let mut shards: Vec<usize> = missing.iter().map(|&b| plan.shard_of(b)).collect();
        shards.dedup();
        let list: Vec<String> = shards.iter().map(usize::to_string).collect();
        bail!(
            "{} of {} shards have not finished: shard{} {} (block file {} missing); run \
             `cbdam shard run --work {} --shard I` for each",
            shards.len(),
            plan.shards,
            if shards.len() > 1 { "s" } else { "" },
            list.join(", "),
            journal.block_path(missing[0]).display(),
            work.display()
        );
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
