//! Reading, planning and quantizing the input(s), and where the encoder's temporaries go.
//!
//! A single GeoTIFF or raw float32 input is streamed: planned and quantized block by block,
//! never held as floats. The other formats are read whole (8 bytes per sample) and dropped once
//! quantized. Several inputs form one variable-resolution lattice ([`crate::mosaic`]), read
//! a band of tile rows at a time.

use std::path::Path;
use std::time::{Duration, Instant};

use crate::input::{
    Format, GeoTiffSource, Limits, RawF32Source, ReadOptions, detect_format, read_dem,
    with_sidecar_crs,
};
use cbdam_codec::geometry::Domain;
use cbdam_codec::hierarchy::{BlockPlan, EncodeOptions, Resolution, TempStorage};
use cbdam_codec::lifting::Alpha;
use cbdam_codec::quant::{HeightGrid, QuantPlan};
use cbdam_codec::repository::GeoRef;
use cbdam_codec::samples::SampleSource;
use cbdam_codec::temp::LatticeArray;

use crate::error::{Context, Result, bail};
use crate::shard_grid::WrittenCrcs;
use crate::tiles::Tile;

/// A quantized input, with what the repository header needs from the file.
pub struct Prepared {
    /// Integer heights.
    pub grid: HeightGrid,
    /// The integer mapping.
    pub plan: QuantPlan,
    /// Georeferencing of the file, if any.
    pub georef: Option<GeoRef>,
    /// Nodata value of the file (or the override).
    pub nodata: Option<f64>,
    /// Wall time of each preparation stage, in order (for `--timings`).
    pub stages: Vec<(&'static str, Duration)>,
    /// The CRC-32s of the grid's tiles (and a mosaic's classes'), computed as they were written
    /// when the lattice went to a sharded plan's work directory ([`InputSpec::lattice_dir`]).
    pub(crate) written: Option<WrittenCrcs>,
}

/// How the input is read.
pub struct InputSpec<'a> {
    /// The DEM file.
    pub path: &'a Path,
    /// `Some((w, h))`: headerless little-endian float32, streamed.
    pub raw_size: Option<(usize, usize)>,
    /// Nodata override.
    pub nodata: Option<f64>,
    /// Value quantum override.
    pub quantum: Option<f64>,
    /// Tolerance, metres.
    pub max_error: f64,
    /// The build's memory limit, bytes: a streamed input's lattice larger than half of it goes
    /// to mapped temporary files ([`TempStorage::for_lattice`]).
    pub memory_limit: u64,
    /// Where those files go, named, when given ([`TempStorage::Named`]: a sharded build's
    /// work directory keeps them as its prepared grid); else unlinked in the system's
    /// temporary directory.
    pub lattice_dir: Option<&'a Path>,
}

/// Whether `path` names a raw float32 file (`.raw`, `.f32`, `.bin`), which carries no size.
pub fn is_raw_path(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| matches!(e.to_ascii_lowercase().as_str(), "raw" | "f32" | "bin"))
}

/// Refuses a tolerance above the whole height range `lo … hi`: it would let a flat plane stand
/// for the terrain, almost certainly a unit mistake (feet, centimetres) rather than intent.
fn unit_check(max_error: f64, lo: f64, hi: f64) -> Result<()> {
    if hi > lo && max_error > hi - lo {
        bail!(
            "--max-error {max_error} m exceeds the data's height range ({lo} … {hi} m, {} m); \
             is the unit right?",
            hi - lo
        );
    }
    Ok(())
}

/// Reads, plans and quantizes the input.
pub fn prepare(spec: &InputSpec<'_>) -> Result<Prepared> {
    let path = spec.path;
    if let Some((w, h)) = spec.raw_size {
        let src = RawF32Source::open(path, w, h, spec.nodata, &Limits::default())
            .with_context(|| format!("reading {}", path.display()))?;
        return prepare_streamed(spec, &src, None);
    }
    if is_raw_path(path) {
        bail!(
            "{}: raw float32 files carry no size; pass --size WIDTHxHEIGHT",
            path.display()
        );
    }
    // GeoTIFF is decoded strip by strip or tile by tile, in parallel, and never held whole.
    if detect_format(path).ok() == Some(Format::GeoTiff) {
        let src = GeoTiffSource::open(path, spec.nodata, &Limits::default())
            .with_context(|| format!("reading {}", path.display()))?;
        let georef = with_sidecar_crs(src.georef().cloned(), path)
            .with_context(|| format!("reading {}", path.display()))?;
        return prepare_streamed(spec, &src, georef);
    }
    prepare_read_whole(spec)
}

/// An input streamed from `src` (a raw float32 file, a GeoTIFF): planned and quantized as it is
/// read, its lattice in memory or in mapped files by [`InputSpec::memory_limit`].
fn prepare_streamed(
    spec: &InputSpec<'_>,
    src: &dyn SampleSource,
    georef: Option<GeoRef>,
) -> Result<Prepared> {
    let reading = || format!("reading {}", spec.path.display());
    let t = Instant::now();
    let points = (src.width() as u64).saturating_mul(src.height() as u64);
    let lattice = TempStorage::for_lattice(
        points.saturating_mul(HeightGrid::BYTES_PER_POINT),
        spec.memory_limit,
    )
    .named_in(spec.lattice_dir);
    let mut written = spec.lattice_dir.map(|_| WrittenCrcs::default());
    let (plan, grid) = QuantPlan::quantize_source_watched(
        src,
        spec.max_error,
        spec.quantum,
        &lattice,
        &mut |grid, rows| {
            if let Some(w) = written.as_mut() {
                w.grid_rows(grid, rows);
            }
        },
    )
    .with_context(reading)?;
    let stages = vec![("read, plan and quantize", t.elapsed())];
    if let Some((lo, hi)) = grid.range() {
        unit_check(spec.max_error, plan.metres(lo), plan.metres(hi))?;
    }
    Ok(Prepared {
        grid,
        plan,
        georef,
        nodata: src.nodata(),
        stages,
        written,
    })
}

/// An input of another format: read whole, then planned and quantized.
fn prepare_read_whole(spec: &InputSpec<'_>) -> Result<Prepared> {
    let path = spec.path;
    let opts = ReadOptions {
        nodata: spec.nodata,
        ..ReadOptions::default()
    };
    let t = Instant::now();
    let dem = read_dem(path, &opts).with_context(|| format!("reading {}", path.display()))?;
    let read = t.elapsed();
    let Some((lo, hi)) = dem.valid_range() else {
        bail!("{} has no valid sample (all nodata or NaN)", path.display());
    };
    unit_check(spec.max_error, lo, hi)?;
    let plan = QuantPlan::for_dem(&dem, spec.max_error, spec.quantum)?;
    let planned = t.elapsed();
    let grid = HeightGrid::from_dem(&dem, &plan)?;
    Ok(Prepared {
        grid,
        plan,
        georef: dem.georef,
        nodata: dem.nodata,
        stages: vec![
            ("read", read),
            ("plan", planned - read),
            ("quantize", t.elapsed() - planned),
        ],
        written: None,
    })
}

/// Where the encoder's temporaries go, and whether it encodes block by block.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Temporaries {
    /// Memory or a mapped temporary file.
    pub storage: TempStorage,
    /// `Some`: the fine levels are encoded block by block, each in a field of its own
    /// ([`BlockPlan`]); the output is the same.
    pub blocks: Option<BlockPlan>,
    /// Whether the quantized lattice (and a mosaic's classes) is in mapped temporary files.
    pub lattice_mapped: bool,
}

impl Temporaries {
    /// How `cbdam bench build` and `--timings` name them.
    pub fn describe(&self) -> String {
        let storage = match self.storage {
            TempStorage::Memory => "memory",
            TempStorage::File(_) | TempStorage::Named(_) => "mapped file",
        };
        let field = match &self.blocks {
            None => storage.to_string(),
            Some(b) => format!("{storage}, blocks of {}", b.block_side),
        };
        if self.lattice_mapped {
            format!("{field}; lattice in mapped files")
        } else {
            field
        }
    }
}

/// Inputs of at least this many samples (4097², 2^24) are encoded block by block with a journal
/// ([`crate::journal`]), so that a killed build resumes: their encode takes seconds to hours.
pub const JOURNAL_FROM_SAMPLES: usize = 1 << 24;

/// Where the encoder's temporaries go under `limit` bytes: in memory with one reconstruction
/// field over the domain when the grid (5 bytes per sample in memory, or the resident windows
/// of a mapped grid, [`HeightGrid::resident_bytes`]) and that field (4 bytes per lattice point
/// of the domain) fit and the input is smaller than [`JOURNAL_FROM_SAMPLES`]; in memory
/// block by block ([`BlockPlan::fitting`]; at least 4 × 4 blocks for large inputs) when the grid
/// and the block fields fit, with the window of the input each block of a mapped grid (and
/// its `classes`) reads ([`HeightGrid::window`]); otherwise the whole field in a mapped
/// temporary file.
pub fn storage_for(
    grid: &HeightGrid,
    classes: Option<&Resolution>,
    opts: &EncodeOptions,
    limit: u64,
) -> Result<Temporaries> {
    let domain = Domain::covering(opts.n, grid.width, grid.height, opts.extra_level_pairs)?;
    let (ex, ey) = domain.layout().face_extent();
    let field = 4 * (ex as u64 + 1) * (ey as u64 + 1);
    let resident = grid.resident_bytes() + classes.map_or(0, |c| c.class.resident_bytes());
    let lattice_mapped = grid.is_mapped();
    let large = grid.width * grid.height >= JOURNAL_FROM_SAMPLES && opts.alpha == Alpha::One;
    if resident + field <= limit && !large {
        return Ok(Temporaries {
            storage: TempStorage::Memory,
            blocks: None,
            lattice_mapped,
        });
    }
    // The apex and the blocks of a mapped grid read copies of parts of it (the apex's points,
    // [`HeightGrid::strided`]; a block's field, [`HeightGrid::window`]), after its resident
    // pages are dropped: the copies take the place of those pages, not their sum.
    let windowed = grid.windows();
    let budget = if windowed {
        limit
    } else {
        limit.saturating_sub(resident)
    };
    let window = |rows: usize, row_len: usize| -> u64 {
        if !windowed {
            return 0;
        }
        grid.window_bytes(rows, row_len)
            + classes.map_or(0, |_| {
                LatticeArray::<u8>::window_bytes(rows, row_len, grid.width)
            })
    };
    let layout = domain.layout();
    let blocks = if large {
        // At least 4 × 4 blocks: units of work a killed build resumes from.
        BlockPlan::fitting_at_most(layout, budget, ex.max(ey) / 4, &window)
    } else if opts.alpha == Alpha::One {
        BlockPlan::fitting_at_most(layout, budget, layout.root_side(), &window)
    } else {
        None
    };
    Ok(match blocks {
        Some(plan) => Temporaries {
            storage: TempStorage::Memory,
            blocks: Some(plan),
            lattice_mapped,
        },
        None => Temporaries {
            storage: TempStorage::File(None),
            blocks: None,
            lattice_mapped,
        },
    })
}

/// Hands the heap's free pages back to the system, once the input is prepared. The mosaic's
/// cache of decoded tile rows (up to half the memory limit) and the decoders' buffers are
/// freed in pieces the allocator keeps, resident, for reuse; the encoder's large fields are
/// mapped afresh, so without this that memory would stay in the build's resident set beside
/// them (16385² as 256 tiles under `--memory-limit 2G`: peak 953–1 020 MiB without, 556–560
/// with).
pub(crate) fn return_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: `malloc_trim` only releases free memory of glibc's own heap.
    unsafe {
        libc::malloc_trim(0);
    }
}

/// The default memory limit: half of physical memory (`MemTotal` in `/proc/meminfo`), or 4 GiB
/// where that cannot be read. Half, because the page cache and other processes need the rest.
pub fn default_memory_limit() -> u64 {
    std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|m| {
            let line = m.lines().find(|l| l.starts_with("MemTotal:"))?;
            let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
            Some(kib * 1024 / 2)
        })
        .unwrap_or(4 << 30)
}

/// Reads several georeferenced inputs (files or tiles, [`crate::tiles`]) into one
/// variable-resolution lattice ([`crate::mosaic`]) and quantizes it: one integer mapping for all
/// inputs. The tiles' headers are read first; their samples are decoded band by band as the
/// survey and the quantizer's passes reach them, within the mosaic's cache. A mapped lattice's
/// files go to `lattice_dir`, named, when given ([`InputSpec::lattice_dir`]).
pub fn prepare_mosaic(
    tiles: &[Tile],
    nodata: Option<f64>,
    quantum: Option<f64>,
    max_error: f64,
    memory_limit: u64,
    lattice_dir: Option<&Path>,
) -> Result<(Prepared, Resolution)> {
    let opts = ReadOptions {
        nodata,
        ..ReadOptions::default()
    };
    let t = Instant::now();
    let mut m = crate::mosaic::mosaic_tiles(tiles, &opts, memory_limit)?;
    m.lattice = m.lattice.named_in(lattice_dir);
    let indexed = t.elapsed();
    // A sharded plan's lattice: its tiles' CRCs as the rows are written.
    let mut written = lattice_dir.map(|_| WrittenCrcs::default());
    let size = (m.width(), m.height());
    let survey = m.survey_watched(&mut |class, rows| {
        if let Some(w) = written.as_mut() {
            w.class_rows(size, class, rows);
        }
    })?;
    let surveyed = t.elapsed();
    let (lo, hi) = survey.range;
    unit_check(max_error, lo, hi)?;
    // The lattice's rows are composed from the inputs as the quantizer reads them.
    let (plan, grid) = QuantPlan::quantize_source_watched(
        &m,
        max_error,
        quantum,
        &m.lattice,
        &mut |grid, rows| {
            if let Some(w) = written.as_mut() {
                w.grid_rows(grid, rows);
            }
        },
    )?;
    // The header holds one nodata value (for extract and verify): the override, else the value
    // the inputs agree on.
    let values: Vec<f64> = m.inputs.iter().filter_map(|p| p.nodata).collect();
    let common = values
        .first()
        .copied()
        .filter(|&v| values.iter().all(|&w| w.to_bits() == v.to_bits()));
    Ok((
        Prepared {
            grid,
            plan,
            georef: Some(m.georef.clone()),
            nodata: nodata.or(common),
            stages: vec![
                ("index tile headers", indexed),
                ("survey tiles", surveyed - indexed),
                ("mosaic, plan and quantize", t.elapsed() - surveyed),
            ],
            written,
        },
        survey.resolution,
    ))
}
