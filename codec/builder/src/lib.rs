//! The C-BDAM build pipeline as a library: one or several DEMs (or an 8-bit RGB image) → one
//! repository file, in parallel, within a memory limit.
//!
//! [`build`] does what `cbdam build` does after parsing its arguments: read ([`input`], the DEM
//! readers), plan, quantize
//! ([`plan`]), encode ([`encode`]), write. Everything it needs comes in one [`BuildOptions`];
//! progress goes to a [`Progress`] callback; failures are [`BuildError`]s that name the file or
//! option at fault. Besides the build: several inputs as one variable-resolution lattice
//! ([`mosaic`]), colour repositories ([`colour`]), the comparisons of `cbdam verify`
//! ([`verify`]) and the GeoTIFF and raw float writers of `cbdam extract` ([`write`]).
#![deny(missing_docs)]

pub mod assign;
pub mod band_cache;
pub mod colour;
pub mod disk_full;
pub mod earth;
pub mod encode;
mod error;
pub mod input;
mod input_cache;
pub mod journal;
pub mod mosaic;
pub mod peak_memory;
pub mod plan;
pub mod planet;
mod planet_input;
pub mod planet_lattice;
pub mod planet_memory;
mod planet_overlap;
mod planet_plan;
mod planet_resampling;
pub mod planet_shard;
mod planet_shard_files;
pub mod planet_shard_plan;
mod planet_spacing;
pub mod planet_verify;
pub mod progress;
pub mod rms;
mod rms_levels;
pub mod shard;
mod shard_grid;
mod shard_plan;
pub mod tiles;
pub mod verify;
mod verify_blocks;
pub mod write;

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use cbdam_codec::entropy::CoderKind;
use cbdam_codec::hierarchy::EncodeOptions;
use cbdam_codec::lifting::Alpha;
use cbdam_codec::quant::QuantPlan;
use cbdam_codec::repository::write_repository;

pub use assign::AssignedGeoRef;
pub use colour::ColourSummary;
pub use encode::ExtraLevels;
pub use error::{BuildError, Result};
pub use progress::{NoProgress, Progress, ProgressEvent, Stage};

use crate::encode::{encode_prepared, with_coarser_roots_if_smaller};
use crate::error::{Context, bail};
use crate::journal::Journal;
use crate::plan::{InputSpec, default_memory_limit, prepare, prepare_mosaic, storage_for};
use cbdam_codec::hierarchy::{BlockJournal, BlockPlan, NoJournal};
use rayon::prelude::*;

/// Everything a build needs, given once.
#[derive(Clone, Debug)]
pub struct BuildOptions {
    /// DEM files (GeoTIFF, .hgt, ASCII grid, PNG, or one raw float32 with `raw_size`); several
    /// georeferenced ones at power-of-two spacings make one variable-resolution dataset. Each
    /// may also be a directory, a glob, `@LIST` or a GDAL VRT of tiles ([`tiles`]). With
    /// `colour`: one 8-bit RGB/RGBA PNG or RGB GeoTIFF.
    pub inputs: Vec<PathBuf>,
    /// The repository to write (atomically: a temporary file renamed into place).
    pub output: PathBuf,
    /// Guaranteed maximum error of every reconstructed sample, metres; with `colour`, whole
    /// 8-bit levels bounding every decoded R, G and B component (0 = lossless). With
    /// `rms_error`, the cap on the maximum error (`f64::INFINITY`: none).
    pub max_error: f64,
    /// Bound the finest level's root-mean-square error over every valid sample instead, metres
    /// ([`rms`]): the coarsest quantizer that meets it within the `max_error` cap.
    pub rms_error: Option<f64>,
    /// `Some((w, h))`: the one input is headerless little-endian float32 of `w × h` samples,
    /// row 0 north, streamed.
    pub raw_size: Option<(usize, usize)>,
    /// Memory budget in bytes; `None`: half of physical memory ([`default_memory_limit`]).
    pub memory_limit: Option<u64>,
    /// Build a colour repository from an RGB image ([`colour`]).
    pub colour: bool,
    /// With `colour`: lay the colour over this elevation repository's domain.
    pub like: Option<PathBuf>,
    /// Diamond grid side N (2^k + 1).
    pub diamond_size: usize,
    /// Level pairs above the smallest hierarchy that covers the data.
    pub extra_levels: ExtraLevels,
    /// Lifting weight α.
    pub alpha: Alpha,
    /// Entropy coder.
    pub coder: CoderKind,
    /// Worker threads for encoding (`None`: all cores).
    pub threads: Option<usize>,
    /// The data's value quantum in metres (`None`: detected from the samples).
    pub quantum: Option<f64>,
    /// Nodata value, overriding the file's own.
    pub nodata: Option<f64>,
    /// Georeferencing for the one input when it carries none (`--bounds`, `--crs`).
    pub assign_georef: Option<AssignedGeoRef>,
    /// Encode in these blocks (with a journal) instead of what the size and the memory limit
    /// choose: for benchmarks of the block encoder. α = 1 only.
    pub block_plan: Option<BlockPlan>,
    /// Build a planet: the inputs (geographic or UTM) resampled onto the cube-sphere
    /// ([`planet`]); `Some(None)`: the lattice the finest input asks for (within the memory
    /// limit), `Some(Some(k))`: `K = k` level pairs.
    pub planet: Option<Option<u32>>,
}

impl BuildOptions {
    /// Options with the CLI's defaults: N = 65, `--extra-levels auto`, α = 1, the adaptive token
    /// coder, all cores, the quantum and nodata value from the input, an elevation repository.
    pub fn new(inputs: Vec<PathBuf>, output: PathBuf, max_error: f64) -> Self {
        let d = EncodeOptions::default();
        BuildOptions {
            inputs,
            output,
            max_error,
            rms_error: None,
            raw_size: None,
            memory_limit: None,
            colour: false,
            like: None,
            diamond_size: d.n,
            extra_levels: ExtraLevels::Auto,
            alpha: d.alpha,
            coder: d.coder,
            threads: None,
            quantum: None,
            nodata: None,
            assign_georef: None,
            block_plan: None,
            planet: None,
        }
    }

    /// The encoder's options of the first (or only) encode.
    pub fn encode_options(&self) -> EncodeOptions {
        EncodeOptions {
            n: self.diamond_size,
            extra_level_pairs: self.extra_levels.first(),
            alpha: self.alpha,
            coder: self.coder,
        }
    }
}

/// What an elevation build made.
#[derive(Clone, Debug)]
pub struct ElevationSummary {
    /// Samples per row of the (combined) input.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Samples with data.
    pub valid: usize,
    /// Records (stored diamonds) in the repository.
    pub records: usize,
    /// The integer mapping.
    pub plan: QuantPlan,
    /// Wall time of each stage, in order.
    pub stages: Vec<(&'static str, Duration)>,
    /// Where the encoder kept its reconstruction ([`plan::Temporaries::describe`]).
    pub temporaries: String,
    /// Whether the quantized lattice (and a mosaic's classes) went to mapped temporary files
    /// because it exceeded half of the memory limit.
    pub lattice_mapped: bool,
}

/// What [`build`] made.
#[derive(Clone, Debug)]
pub enum BuildSummary {
    /// An elevation repository.
    Elevation(ElevationSummary),
    /// A colour repository.
    Colour(ColourSummary),
    /// A planet.
    Planet(planet::PlanetSummary),
}

/// Builds the repository `opts` describe; progress goes to `progress`.
pub fn build(opts: &BuildOptions, progress: &dyn Progress) -> Result<BuildSummary> {
    let built = if let Some(level) = opts.planet {
        planet::build_planet(opts, level, progress).map(BuildSummary::Planet)
    } else if opts.colour {
        colour::build_colour(opts, progress).map(BuildSummary::Colour)
    } else {
        build_elevation(opts, progress).map(BuildSummary::Elevation)
    };
    built.map_err(|e| disk_full::explain(e, &opts.output))
}

/// An elevation build's input, read and quantized, and how it is to be encoded.
pub(crate) struct PreparedBuild {
    /// The input files, directories, globs, lists and VRTs expanded.
    pub(crate) tiles: Vec<tiles::Tile>,
    /// The quantized input.
    pub(crate) input: plan::Prepared,
    /// The classes of a variable-resolution input (several inputs).
    pub(crate) resolution: Option<cbdam_codec::hierarchy::Resolution>,
    /// Where the encoder's temporaries go, and its blocks (`--block-plan` applied).
    pub(crate) storage: plan::Temporaries,
    /// The first encode's options.
    pub(crate) enc_opts: EncodeOptions,
    /// The memory limit, bytes.
    pub(crate) limit: u64,
}

/// The input files: directories, globs, @lists and VRTs become their files; the raw float32
/// input of `--size` is a single file, taken as given.
pub(crate) fn input_tiles(opts: &BuildOptions) -> Result<Vec<tiles::Tile>> {
    let tiles = if opts.raw_size.is_some() {
        for input in &opts.inputs {
            tiles::check_regular_file(input, "input")?;
        }
        opts.inputs.iter().map(tiles::Tile::file).collect()
    } else {
        tiles::expand_inputs(&opts.inputs)?
    };
    check_output_is_not_an_input(opts, &tiles)?;
    Ok(tiles)
}

/// Refuses an output path that is one of the files the build reads — an input argument, an
/// `@LIST`, a VRT, a file they name, or `--like` — as the same file (device and inode: through
/// a symlink, a hard link or another spelling of the path too), before anything is written:
/// the build would replace its own input.
pub(crate) fn check_output_is_not_an_input(
    opts: &BuildOptions,
    tiles: &[tiles::Tile],
) -> Result<()> {
    let Ok(out) = std::fs::metadata(&opts.output) else {
        // Nothing there yet, so nothing it could overwrite.
        return Ok(());
    };
    let args = opts.inputs.iter().map(|p| {
        let text = p.to_string_lossy();
        match text.strip_prefix('@') {
            Some(list) => PathBuf::from(list),
            None => p.clone(),
        }
    });
    let read = args
        .chain(opts.like.iter().cloned())
        .chain(tiles.iter().map(|t| t.path.clone()))
        .chain(
            tiles
                .iter()
                .filter_map(|t| t.vrt.as_ref().map(|v| v.vrt.clone())),
        );
    for input in read {
        if let Ok(m) = std::fs::metadata(&input)
            && same_file(&m, &out, &input, &opts.output)
        {
            bail!(
                "the output {} is the input {}: the build would overwrite what it reads; \
                 choose another -o",
                opts.output.display(),
                input.display()
            );
        }
    }
    Ok(())
}

/// Whether two paths (with their metadata, symlinks followed) name the same file.
fn same_file(a: &std::fs::Metadata, b: &std::fs::Metadata, pa: &Path, pb: &Path) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        let _ = (pa, pb);
        (a.dev(), a.ino()) == (b.dev(), b.ino())
    }
    #[cfg(not(unix))]
    {
        let _ = (a, b);
        matches!(
            (std::fs::canonicalize(pa), std::fs::canonicalize(pb)),
            (Ok(x), Ok(y)) if x == y
        )
    }
}

/// Checks `opts`, reads and quantizes the input and chooses the temporaries: everything of an
/// elevation build before the encode. A lattice too large for memory goes to mapped files named
/// in `lattice_dir` when given (a sharded plan's work directory), else unlinked temporaries.
pub(crate) fn prepare_elevation(
    opts: &BuildOptions,
    progress: &dyn Progress,
    lattice_dir: Option<&Path>,
) -> Result<PreparedBuild> {
    check_elevation_options(opts)?;
    let limit = opts.memory_limit.unwrap_or_else(default_memory_limit);
    let enc_opts = opts.encode_options();
    let prepare_step = |done| {
        progress.event(ProgressEvent {
            stage: Stage::Prepare,
            done,
            total: 1,
        })
    };
    prepare_step(0);
    let tiles = input_tiles(opts)?;
    let (input, resolution, mut storage) = match tiles.as_slice() {
        [] => bail!("no input given"),
        [tiles::Tile { path, vrt: None }] => {
            prepare_single_input(opts, path, &enc_opts, limit, lattice_dir)?
        }
        tiles => prepare_several_inputs(opts, tiles, &enc_opts, limit, lattice_dir)?,
    };
    plan::return_freed_memory();
    prepare_step(1);
    if let Some(plan) = opts.block_plan {
        if enc_opts.alpha != Alpha::One {
            bail!("--block-plan needs --alpha one");
        }
        storage.blocks = Some(plan);
    }
    Ok(PreparedBuild {
        tiles,
        input,
        resolution,
        storage,
        enc_opts,
        limit,
    })
}

/// The checks of an elevation build's options that need no input: cheap, so a typo does not
/// cost a DEM read.
fn check_elevation_options(opts: &BuildOptions) -> Result<()> {
    if opts.like.is_some() {
        bail!("--like only applies to colour repositories (--colour)");
    }
    check_tolerance_and_output(opts)?;
    if opts.threads == Some(0) {
        bail!("--threads must be at least 1");
    }
    if let ExtraLevels::Fixed(n) = opts.extra_levels
        && n > ExtraLevels::MAX
    {
        bail!(
            "--extra-levels {n}: at most {} level pairs",
            ExtraLevels::MAX
        );
    }
    Ok(())
}

/// An input read and quantized, the classes of a variable-resolution input, and where the
/// encoder's temporaries go.
type PreparedInput = (
    plan::Prepared,
    Option<cbdam_codec::hierarchy::Resolution>,
    plan::Temporaries,
);

/// One input file: read (georeferenced by `--bounds`/`--crs` when given) and quantized.
fn prepare_single_input(
    opts: &BuildOptions,
    path: &Path,
    enc_opts: &EncodeOptions,
    limit: u64,
    lattice_dir: Option<&Path>,
) -> Result<PreparedInput> {
    let mut input = prepare(&InputSpec {
        path,
        raw_size: opts.raw_size,
        nodata: opts.nodata,
        quantum: opts.quantum,
        max_error: opts.max_error,
        memory_limit: limit,
        lattice_dir,
    })?;
    if let Some(a) = &opts.assign_georef {
        a.apply(
            path,
            &mut input.georef,
            (input.grid.width, input.grid.height),
        )?;
    }
    let storage = storage_for(&input.grid, None, enc_opts, limit)?;
    Ok((input, None, storage))
}

/// Several inputs (tiles): checked against the options a mosaic cannot take, then mosaicked
/// into one variable-resolution input.
fn prepare_several_inputs(
    opts: &BuildOptions,
    tiles: &[tiles::Tile],
    enc_opts: &EncodeOptions,
    limit: u64,
    lattice_dir: Option<&Path>,
) -> Result<PreparedInput> {
    if opts.assign_georef.is_some() {
        bail!(
            "--bounds and --crs georeference one input; these {} inputs (tiles) need \
             their own georeferencing",
            tiles.len()
        );
    }
    if opts.raw_size.is_some() {
        bail!(
            "--size: raw float32 inputs carry no georeferencing, so several inputs \
             cannot include them"
        );
    }
    if enc_opts.alpha != Alpha::One {
        bail!("several inputs (variable resolution) need --alpha one");
    }
    if enc_opts.extra_level_pairs > 0 {
        bail!(
            "--extra-levels above 0 applies to single-input builds (several inputs keep \
             the covering hierarchy)"
        );
    }
    let (input, res) = prepare_mosaic(
        tiles,
        opts.nodata,
        opts.quantum,
        opts.max_error,
        limit,
        lattice_dir,
    )?;
    // The inputs are gone by now: what stays is the grid, the classes and the field.
    let storage = storage_for(&input.grid, Some(&res), enc_opts, limit)?;
    Ok((input, Some(res), storage))
}

/// Builds an elevation repository (`opts.colour` is ignored).
pub fn build_elevation(opts: &BuildOptions, progress: &dyn Progress) -> Result<ElevationSummary> {
    // `--rms-error`: the maximum error whose build meets the RMS bound, then that build.
    let (chosen, rms) = match opts.rms_error {
        Some(target) => {
            let choice = rms::choose(opts, target)?;
            let opts = BuildOptions {
                max_error: choice.max_error,
                quantum: choice.quantum,
                rms_error: None,
                // Per-level quantizers were allocated for this hierarchy's levels.
                extra_levels: choice
                    .levels
                    .map_or(opts.extra_levels, |(_, extra)| ExtraLevels::Fixed(extra)),
                ..opts.clone()
            };
            (Some(opts), Some(choice))
        }
        None => (None, None),
    };
    let opts = chosen.as_ref().unwrap_or(opts);
    let mut prepared = prepare_elevation(opts, progress, None)?;
    if let Some(choice) = rms {
        let plan = &mut prepared.input.plan;
        if let Some((levels, _)) = choice.levels {
            plan.quantizer = cbdam_codec::quant::Quantizer::new(levels.max_k())?;
            plan.levels = Some(levels);
        }
        // The header's tolerance is then the maximum error the chosen quantizer guarantees.
        plan.epsilon = plan.max_error();
        plan.rms = Some(choice.bound);
    }
    let mut stages = prepared.input.stages.clone();
    let journal = open_block_journal(opts, &prepared, progress, &mut stages)?;
    let encoded = encode_elevation(opts, &prepared, journal.as_ref(), progress, &mut stages)?;
    write_elevation(opts, &prepared, &encoded, journal, progress, &mut stages)?;
    let PreparedBuild { input, storage, .. } = prepared;
    let grid = &input.grid;
    Ok(ElevationSummary {
        width: grid.width,
        height: grid.height,
        valid: grid.valid_count(),
        records: encoded.records.len(),
        plan: input.plan,
        stages,
        temporaries: storage.describe(),
        lattice_mapped: grid.is_mapped(),
    })
}

/// A build encoded block by block (`--block-plan`) keeps a journal beside the output, so an
/// interrupted build resumes; `None` for a build in one piece.
fn open_block_journal(
    opts: &BuildOptions,
    prepared: &PreparedBuild,
    progress: &dyn Progress,
    stages: &mut Vec<(&'static str, Duration)>,
) -> Result<Option<Journal>> {
    let Some(plan) = &prepared.storage.blocks else {
        return Ok(None);
    };
    let t = Instant::now();
    let key = journal_key(opts, &prepared.tiles, &prepared.enc_opts, Some(plan))?;
    let (journal, resumed) = Journal::open(&opts.output, &key)?;
    stages.push(("journal (hash the inputs, check the blocks)", t.elapsed()));
    progress.resumed(&resumed);
    Ok(Some(journal))
}

/// Encodes the prepared input; with `--extra-levels auto` on a single input, encodes it again
/// with coarser roots and keeps whichever repository is smaller.
fn encode_elevation(
    opts: &BuildOptions,
    prepared: &PreparedBuild,
    journal: Option<&Journal>,
    progress: &dyn Progress,
    stages: &mut Vec<(&'static str, Duration)>,
) -> Result<cbdam_codec::hierarchy::Encoded> {
    let PreparedBuild {
        input,
        resolution,
        storage,
        enc_opts,
        limit,
        ..
    } = prepared;
    let t = Instant::now();
    let encoded = encode_prepared(
        input,
        resolution.as_ref(),
        enc_opts,
        storage,
        journal.map_or(&NoJournal as &dyn BlockJournal, |j| j),
        opts.threads,
        &|done, total| {
            progress.event(ProgressEvent {
                stage: Stage::Encode,
                done,
                total,
            })
        },
    )?;
    stages.push(("encode", t.elapsed()));
    if opts.extra_levels != ExtraLevels::Auto || resolution.is_some() {
        return Ok(encoded);
    }
    let step = |done| {
        progress.event(ProgressEvent {
            stage: Stage::EncodeCoarserRoots,
            done,
            total: 1,
        })
    };
    step(0);
    let t = Instant::now();
    let (encoded, tried) =
        with_coarser_roots_if_smaller(input, encoded, enc_opts, *limit, opts.threads)?;
    if tried {
        stages.push(("encode with coarser roots", t.elapsed()));
    }
    step(1);
    Ok(encoded)
}

/// Writes the repository to `opts.output`, then removes the journal of a block build.
fn write_elevation(
    opts: &BuildOptions,
    prepared: &PreparedBuild,
    encoded: &cbdam_codec::hierarchy::Encoded,
    journal: Option<Journal>,
    progress: &dyn Progress,
    stages: &mut Vec<(&'static str, Duration)>,
) -> Result<()> {
    let write_step = |done| {
        progress.event(ProgressEvent {
            stage: Stage::Write,
            done,
            total: 1,
        })
    };
    let t = Instant::now();
    write_step(0);
    let input = &prepared.input;
    write_repository(
        &opts.output,
        encoded,
        &input.plan,
        input.georef.as_ref(),
        input.nodata,
    )
    .with_context(|| format!("writing {}", opts.output.display()))?;
    if let Some(journal) = journal {
        journal.finish()?;
    }
    stages.push(("write", t.elapsed()));
    write_step(1);
    Ok(())
}

/// The checks every elevation build makes before reading anything: a positive finite
/// tolerance and an output path that is not a directory.
fn check_tolerance_and_output(opts: &BuildOptions) -> Result<()> {
    if !(opts.max_error.is_finite() && opts.max_error > 0.0) {
        bail!(
            "--max-error must be a positive number of metres, not {}",
            opts.max_error
        );
    }
    check_output(&opts.output)
}

/// Checks the output path before any work: not a directory, and in a directory that exists (a
/// build that is not journaled would otherwise find out only when it writes, after encoding).
pub(crate) fn check_output(output: &Path) -> Result<()> {
    if output.is_dir() {
        bail!("output path {} is a directory", output.display());
    }
    let dir = match output.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    if !dir.is_dir() {
        bail!(
            "the output's directory {} does not exist (or is not a directory); create it first",
            dir.display()
        );
    }
    Ok(())
}

/// Everything a block encode's output depends on, one `name=value` line each: the journal of an
/// earlier run is continued only when all of them are the same ([`journal`]). The memory limit
/// and the thread count are not among them: only the block plan they lead to is.
pub(crate) fn journal_key(
    opts: &BuildOptions,
    tiles: &[tiles::Tile],
    enc: &EncodeOptions,
    plan: Option<&BlockPlan>,
) -> Result<String> {
    let mut key = format!(
        "journal=3\ncbdam={}\nformat={}\n",
        env!("CARGO_PKG_VERSION"),
        cbdam_codec::repository::FORMAT_VERSION
    );
    // The inputs' contents, not their modification times: a file changed and given its old
    // time back (a restored backup, `touch -r`) must not resume from blocks of the old bytes.
    // One streamed CRC-32 a file, the files in parallel: a read of what the build has just
    // read, from the page cache for inputs that fit it.
    let crcs = tiles
        .par_iter()
        .map(|t| journal::content_crc(&t.path))
        .collect::<Result<Vec<_>>>()?;
    for (t, (len, crc)) in tiles.iter().zip(crcs) {
        let placed = t
            .vrt
            .as_ref()
            .map_or(String::new(), |v| format!(", placed {v:?}"));
        key += &format!(
            "input={} {len} bytes, crc32 {crc:08x}{placed}\n",
            t.path.display()
        );
    }
    key += &format!(
        "max_error={}\nraw_size={:?}\nquantum={:?}\nnodata={:?}\ndiamond_size={}\n\
         extra_level_pairs={}\nalpha={:?}\ncoder={:?}\nbounds={:?}\nblocks={}\n",
        opts.max_error,
        opts.raw_size,
        opts.quantum,
        opts.nodata,
        enc.n,
        enc.extra_level_pairs,
        enc.alpha,
        enc.coder,
        opts.assign_georef,
        plan.map_or("auto".to_string(), |p| format!(
            "cut {} side {}",
            p.cut_level, p.block_side
        ))
    );
    Ok(key)
}
