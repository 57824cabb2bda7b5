//! `cbdam build`: DEMs → one repository file, in parallel, within a memory limit.
//!
//! Several inputs form one variable-resolution dataset ([`crate::mosaic`]), held in memory or,
//! above the memory limit, in memory-mapped temporary files.
//!
//! A single GeoTIFF or raw float32 input (`--size WxH`) is streamed: planned and quantized block
//! by block, never held as floats. The other formats are read whole (8 bytes per sample) and
//! dropped once quantized. The encoder's reconstruction field goes to a memory-mapped temporary
//! file when the grid and the field together would exceed `--memory-limit`.

use std::io::IsTerminal;
use std::path::Path;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use cbdam_codec::entropy::CoderKind;
use cbdam_codec::geometry::Layout;
use cbdam_codec::hierarchy::{
    EncodeOptions, Encoded, Resolution, TempStorage, encode_variable, encode_with_storage,
};
use cbdam_codec::input::{
    Format, GeoRef, GeoTiffSource, Limits, RawF32Source, ReadOptions, SampleSource, detect_format,
    read_dem, with_sidecar_crs,
};
use cbdam_codec::lifting::Alpha;
use cbdam_codec::quant::{HeightGrid, QuantPlan};
use cbdam_codec::repository::{serialize, write_repository};
use indicatif::{ProgressBar, ProgressStyle};

use crate::{AlphaArg, BuildArgs, CoderArg};

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
}

/// Whether `path` names a raw float32 file (`.raw`, `.f32`, `.bin`), which carries no size.
pub fn is_raw_path(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| matches!(e.to_ascii_lowercase().as_str(), "raw" | "f32" | "bin"))
}

/// Reads, plans and quantizes the input.
pub fn prepare(spec: &InputSpec<'_>) -> Result<Prepared> {
    let path = spec.path;
    let unit_check = |lo: f64, hi: f64| -> Result<()> {
        // A tolerance above the whole height range would let a flat plane stand for the
        // terrain: almost certainly a unit mistake (feet, centimetres) rather than intent.
        if hi > lo && spec.max_error > hi - lo {
            bail!(
                "--max-error {} m exceeds the data's height range ({lo} … {hi} m, {} m); \
                 is the unit right?",
                spec.max_error,
                hi - lo
            );
        }
        Ok(())
    };
    let streamed = |src: &dyn SampleSource, georef: Option<GeoRef>| -> Result<Prepared> {
        let reading = || format!("reading {}", path.display());
        let t = Instant::now();
        let (plan, grid) =
            QuantPlan::quantize_source(src, spec.max_error, spec.quantum).with_context(reading)?;
        let stages = vec![("read, plan and quantize", t.elapsed())];
        if let Some((lo, hi)) = grid.range() {
            unit_check(plan.metres(lo), plan.metres(hi))?;
        }
        Ok(Prepared {
            grid,
            plan,
            georef,
            nodata: src.nodata(),
            stages,
        })
    };
    if let Some((w, h)) = spec.raw_size {
        let src = RawF32Source::open(path, w, h, spec.nodata, &Limits::default())
            .with_context(|| format!("reading {}", path.display()))?;
        return streamed(&src, None);
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
        return streamed(&src, georef);
    }
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
    unit_check(lo, hi)?;
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
    })
}

/// Where the encoder's temporaries go under `limit` bytes: in memory when the grid (5 bytes per
/// sample) and the reconstruction field (4 bytes per lattice point of the domain) fit.
pub fn storage_for(grid: &HeightGrid, opts: &EncodeOptions, limit: u64) -> Result<TempStorage> {
    let layout = Layout::covering(opts.n, grid.width, grid.height, opts.extra_level_pairs)?;
    let (ex, ey) = layout.face_extent();
    let field = 4 * (ex as u64 + 1) * (ey as u64 + 1);
    let input = 5 * (grid.width as u64) * (grid.height as u64);
    Ok(if input + field > limit {
        TempStorage::File(None)
    } else {
        TempStorage::Memory
    })
}

/// Parses a byte size: a number with an optional binary suffix K, M, G or T (also KiB, KB …,
/// any case), e.g. `2G`, `512M`, `1.5G`, `1073741824`.
pub fn parse_size(text: &str) -> Result<u64> {
    let t = text.trim();
    let digits = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(t.len());
    let (num, suffix) = t.split_at(digits);
    let scale: u64 = match suffix.trim().to_ascii_lowercase().as_str() {
        "" | "b" => 1,
        "k" | "kb" | "kib" => 1 << 10,
        "m" | "mb" | "mib" => 1 << 20,
        "g" | "gb" | "gib" => 1 << 30,
        "t" | "tb" | "tib" => 1 << 40,
        other => bail!(
            "--memory-limit {text:?}: unknown unit {other:?} (use a number of bytes with K, M, G \
             or T, e.g. 2G or 512M)"
        ),
    };
    let value: f64 = num
        .parse()
        .ok()
        .filter(|v: &f64| v.is_finite())
        .with_context(|| format!("--memory-limit {text:?} is not a size (e.g. 2G or 512M)"))?;
    let bytes = value * scale as f64;
    if bytes < 1.0 || bytes >= u64::MAX as f64 {
        bail!("--memory-limit {text:?} must be at least one byte and below 16 EiB");
    }
    Ok(bytes as u64)
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

/// Parses `WIDTHxHEIGHT`.
pub fn parse_dims(text: &str) -> Result<(usize, usize)> {
    let bad = || anyhow::anyhow!("--size {text:?}: expected WIDTHxHEIGHT, e.g. 16385x16385");
    let (w, h) = text.split_once(['x', 'X']).ok_or_else(bad)?;
    let w: usize = w.trim().parse().map_err(|_| bad())?;
    let h: usize = h.trim().parse().map_err(|_| bad())?;
    if w == 0 || h == 0 {
        return Err(bad());
    }
    Ok((w, h))
}

/// `--extra-levels`: a fixed number of level pairs above the covering hierarchy, or `auto`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ExtraLevels {
    /// Decide by trying (see [`run`]).
    Auto,
    /// Exactly this many.
    Fixed(u32),
}

/// Parses `--extra-levels`: `auto` or a number of level pairs, at most 2: each quadruples the
/// domain's area, and with it the encoder's reconstruction field (4 bytes a lattice point).
pub fn parse_extra_levels(text: &str) -> Result<ExtraLevels, String> {
    if text.eq_ignore_ascii_case("auto") {
        return Ok(ExtraLevels::Auto);
    }
    match text.parse::<u32>() {
        Ok(n) if n <= 2 => Ok(ExtraLevels::Fixed(n)),
        _ => Err(format!(
            "{text:?} is neither `auto` nor a number of level pairs from 0 to 2"
        )),
    }
}

/// Encoder options from the command line.
pub fn encode_options(args: &BuildArgs) -> EncodeOptions {
    EncodeOptions {
        n: args.diamond_size,
        extra_level_pairs: match args.extra_levels {
            ExtraLevels::Fixed(n) => n,
            ExtraLevels::Auto => 0,
        },
        alpha: match args.alpha {
            AlphaArg::One => Alpha::One,
            AlphaArg::Half => Alpha::Half,
        },
        coder: match args.coder {
            CoderArg::Adaptive => CoderKind::Adaptive,
            CoderArg::AdaptiveTokens => CoderKind::AdaptiveTokens,
            CoderArg::EliasGamma => CoderKind::EliasGamma,
        },
    }
}

/// Reads several georeferenced inputs into one variable-resolution lattice ([`crate::mosaic`])
/// and quantizes it: one integer mapping for all inputs.
pub fn prepare_mosaic(
    paths: &[std::path::PathBuf],
    nodata: Option<f64>,
    quantum: Option<f64>,
    max_error: f64,
    memory_limit: u64,
    quiet: bool,
) -> Result<(Prepared, Resolution)> {
    let opts = ReadOptions {
        nodata,
        ..ReadOptions::default()
    };
    let t = Instant::now();
    let m = crate::mosaic::mosaic(paths, &opts, memory_limit)?;
    let spilled: Vec<_> = m.inputs.iter().filter(|p| p.samples.is_spilled()).collect();
    if !quiet && !spilled.is_empty() {
        let bytes: u64 = spilled.iter().map(|p| p.samples.bytes()).sum();
        eprintln!(
            "{} of {} inputs ({} MiB) in memory-mapped temporary files, to stay under \
             --memory-limit",
            spilled.len(),
            m.inputs.len(),
            bytes.div_ceil(1 << 20)
        );
    }
    let (lo, hi) = m.valid_range().expect("every input has a valid sample");
    if hi > lo && max_error > hi - lo {
        bail!(
            "--max-error {max_error} m exceeds the data's height range ({lo} … {hi} m, {} m); \
             is the unit right?",
            hi - lo
        );
    }
    // The lattice's rows are composed from the inputs as the quantizer reads them.
    let (plan, grid) = QuantPlan::quantize_source(&m, max_error, quantum)?;
    let resolution = m.resolution();
    // The header holds one nodata value (for extract and verify): the override, else the value
    // the inputs agree on.
    let values: Vec<f64> = m.inputs.iter().filter_map(|p| p.dem.nodata).collect();
    let common = values
        .first()
        .copied()
        .filter(|&v| values.iter().all(|&w| w.to_bits() == v.to_bits()));
    Ok((
        Prepared {
            grid,
            plan,
            georef: Some(m.georef),
            nodata: nodata.or(common),
            stages: vec![("read, mosaic and quantize", t.elapsed())],
        },
        resolution,
    ))
}

/// Encodes a prepared input with `threads` workers (all cores when `None`); variable-resolution
/// data when `resolution` is given.
pub fn encode_prepared(
    input: &Prepared,
    resolution: Option<&Resolution>,
    opts: &EncodeOptions,
    storage: &TempStorage,
    threads: Option<usize>,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Encoded> {
    let mut pool = rayon::ThreadPoolBuilder::new();
    if let Some(t) = threads {
        if t == 0 {
            bail!("--threads must be at least 1");
        }
        pool = pool.num_threads(t);
    }
    let pool = pool.build()?;
    Ok(pool.install(|| match resolution {
        Some(r) => encode_variable(
            &input.grid,
            r,
            input.plan.quantizer,
            opts,
            storage,
            progress,
        ),
        None => encode_with_storage(&input.grid, input.plan.quantizer, opts, storage, progress),
    })?)
}

pub fn run(args: &BuildArgs) -> Result<()> {
    if args.colour {
        return crate::colour_build::run(args, encode_options(args));
    }
    if args.like.is_some() {
        bail!("--like only applies to colour repositories (--colour)");
    }
    let start = Instant::now();
    // Cheap argument checks first, so a typo does not cost a DEM read.
    if !(args.max_error.is_finite() && args.max_error > 0.0) {
        bail!(
            "--max-error must be a positive number of metres, not {}",
            args.max_error
        );
    }
    if args.output.is_dir() {
        bail!("output path {} is a directory", args.output.display());
    }
    if args.threads == Some(0) {
        bail!("--threads must be at least 1");
    }
    let limit = match &args.memory_limit {
        Some(text) => parse_size(text)?,
        None => default_memory_limit(),
    };
    let raw_size = args.size.as_deref().map(parse_dims).transpose()?;
    let enc_opts = encode_options(args);
    let (input, resolution, storage) = match args.inputs.as_slice() {
        [] => bail!("no input given"),
        [path] => {
            let input = prepare(&InputSpec {
                path,
                raw_size,
                nodata: args.nodata,
                quantum: args.quantum,
                max_error: args.max_error,
            })?;
            let storage = storage_for(&input.grid, &enc_opts, limit)?;
            (input, None, storage)
        }
        paths => {
            if raw_size.is_some() {
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
                paths,
                args.nodata,
                args.quantum,
                args.max_error,
                limit,
                args.quiet,
            )?;
            // The inputs are gone by now: what stays is the grid, the classes and the field.
            let classes = res.class.len() as u64;
            let storage = storage_for(&input.grid, &enc_opts, limit.saturating_sub(classes))?;
            (input, Some(res), storage)
        }
    };
    let progress = Progress::new(args.quiet);
    let mut stages = input.stages.clone();
    let t = Instant::now();
    let encoded = encode_prepared(
        &input,
        resolution.as_ref(),
        &enc_opts,
        &storage,
        args.threads,
        &|done, total| progress.update(done, total),
    )?;
    progress.finish();
    stages.push(("encode", t.elapsed()));
    let plan = &input.plan;
    let encoded = if args.extra_levels == ExtraLevels::Auto && resolution.is_none() {
        let t = Instant::now();
        let (e, tried) =
            with_coarser_roots_if_smaller(&input, encoded, &enc_opts, limit, args.threads)?;
        if tried {
            stages.push(("encode with coarser roots", t.elapsed()));
        }
        e
    } else {
        encoded
    };
    let t = Instant::now();
    write_repository(
        &args.output,
        &encoded,
        plan,
        input.georef.as_ref(),
        input.nodata,
    )
    .with_context(|| format!("writing {}", args.output.display()))?;
    stages.push(("write", t.elapsed()));
    if args.timings {
        let total = start.elapsed();
        let parts: Vec<String> = stages
            .iter()
            .map(|(name, d)| format!("{name} {:.3} s", d.as_secs_f64()))
            .collect();
        eprintln!(
            "timings: {}, total {:.3} s ({:.2} M samples/s)",
            parts.join(", "),
            total.as_secs_f64(),
            (input.grid.width * input.grid.height) as f64 / total.as_secs_f64() / 1e6
        );
    }
    if !args.quiet {
        let bytes = std::fs::metadata(&args.output)?.len();
        let grid = &input.grid;
        let samples = grid.width * grid.height;
        println!(
            "{}: {}×{} samples ({} valid), {} bytes, {:.3} bits/sample, {} records, \
             max error {} m (unit {} m, k = {}), {:.2} s",
            args.output.display(),
            grid.width,
            grid.height,
            grid.valid.iter().filter(|&&v| v).count(),
            bytes,
            bytes as f64 * 8.0 / samples as f64,
            encoded.records.len(),
            plan.max_error(),
            plan.unit,
            plan.quantizer.k(),
            start.elapsed().as_secs_f64()
        );
    }
    Ok(())
}

/// `--extra-levels auto` tries one more level pair only where a second encode is cheap ...
const AUTO_RETRY_MAX_SAMPLES: usize = 16 << 20;
/// ... and the root field is at least this share of the repository (percent): only there can
/// sparser roots pay for the coarse records that replace them. Measured on the bundled DEMs
/// (`--extra-levels 0` vs `1`): lidar1m_mn's root field is 47–70 % of the file at 0.5–5 m and
/// one more level pair saves 9 % at 2 m and 39 % at 5 m (but costs 30 % at 0.5 and 1 m, so it
/// must be tried, not assumed); on every other DEM the roots are at most 7 % of the file
/// (Fuji at 5 m) and the difference within ±0.9 %.
const AUTO_RETRY_MIN_ROOT_SHARE: usize = 40;

/// `--extra-levels auto`: when the root field dominates `first` (encoded with
/// `opts.extra_level_pairs`), encodes again with one more level pair and keeps whichever
/// repository is smaller (ties: the first). Also says whether it tried.
pub fn with_coarser_roots_if_smaller(
    input: &Prepared,
    first: Encoded,
    opts: &EncodeOptions,
    limit: u64,
    threads: Option<usize>,
) -> Result<(Encoded, bool)> {
    let size = |e: &Encoded| -> Result<usize> {
        Ok(serialize(e, &input.plan, input.georef.as_ref(), input.nodata)?.len())
    };
    // Large inputs return before anything is serialised: measuring the size would cost a
    // second copy of the repository in memory.
    if input.grid.width * input.grid.height > AUTO_RETRY_MAX_SAMPLES {
        return Ok((first, false));
    }
    let first_size = size(&first)?;
    if first.roots.len() * 100 < first_size * AUTO_RETRY_MIN_ROOT_SHARE {
        return Ok((first, false));
    }
    let opts = EncodeOptions {
        extra_level_pairs: opts.extra_level_pairs + 1,
        ..*opts
    };
    let storage = storage_for(&input.grid, &opts, limit)?;
    let second = encode_prepared(input, None, &opts, &storage, threads, &|_, _| {})?;
    Ok((
        if size(&second)? < first_size {
            second
        } else {
            first
        },
        true,
    ))
}

/// Progress of the encode: a bar with ETA on a terminal, a log line per quarter otherwise (so CI
/// logs and pipes stay readable), nothing with `--quiet`.
pub(crate) enum Progress {
    Quiet,
    Bar(ProgressBar),
    Log(Mutex<usize>),
}

impl Progress {
    pub(crate) fn new(quiet: bool) -> Self {
        if quiet {
            Progress::Quiet
        } else if std::io::stderr().is_terminal() {
            let bar = ProgressBar::new(0);
            bar.set_style(
                ProgressStyle::with_template(
                    "encoding {bar:40} {percent:>3}%, {elapsed} elapsed, ETA {eta}",
                )
                .expect("static template"),
            );
            Progress::Bar(bar)
        } else {
            Progress::Log(Mutex::new(0))
        }
    }

    pub(crate) fn update(&self, done: usize, total: usize) {
        match self {
            Progress::Quiet => {}
            Progress::Bar(bar) => {
                bar.set_length(total as u64);
                bar.set_position(done as u64);
            }
            Progress::Log(logged) => {
                let q = done * 4 / total.max(1);
                // Workers report concurrently: log every quarter crossed, once and in order.
                let mut logged = logged.lock().unwrap_or_else(|e| e.into_inner());
                while *logged < q.min(4) {
                    *logged += 1;
                    eprintln!("encoding: {}% done", *logged * 25);
                }
            }
        }
    }

    pub(crate) fn finish(&self) {
        if let Progress::Bar(bar) = self {
            bar.finish_and_clear();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The streamed GeoTIFF path writes the same repository bytes as reading the whole file
    /// (decoded by the `tiff` crate's own whole-image reader, not by the chunk reader under
    /// test), on every bundled GeoTIFF.
    #[test]
    fn streamed_geotiff_builds_the_same_repository_as_the_whole_file() {
        use tiff::decoder::{Decoder, DecodingResult};
        let dir = tempfile::tempdir().unwrap();
        let inputs = crate::bench_codec::bundled_inputs(&["tif"]).unwrap();
        assert!(inputs.len() >= 6, "{inputs:?}");
        let opts = EncodeOptions::default();
        for path in inputs {
            let spec = InputSpec {
                path: &path,
                raw_size: None,
                nodata: None,
                quantum: None,
                max_error: 1.0,
            };
            let streamed = prepare(&spec).unwrap();
            let mut dem = read_dem(&path, &ReadOptions::default()).unwrap();
            let mut dec = Decoder::new(std::fs::File::open(&path).unwrap()).unwrap();
            let whole: Vec<f64> = match dec.read_image().unwrap() {
                DecodingResult::I16(v) => v.into_iter().map(f64::from).collect(),
                DecodingResult::F32(v) => v.into_iter().map(f64::from).collect(),
                _ => panic!(
                    "{}: a sample type the bundled data does not use",
                    path.display()
                ),
            };
            assert_eq!(dem.values, whole, "{}", path.display());
            dem.values = whole;
            let plan = QuantPlan::for_dem(&dem, 1.0, None).unwrap();
            let grid = HeightGrid::from_dem(&dem, &plan).unwrap();
            assert_eq!(plan, streamed.plan, "{}", path.display());
            assert_eq!(grid, streamed.grid, "{}", path.display());
            let mut bytes = Vec::new();
            for (grid, plan, georef, nodata) in [
                (&grid, &plan, dem.georef.as_ref(), dem.nodata),
                (
                    &streamed.grid,
                    &streamed.plan,
                    streamed.georef.as_ref(),
                    streamed.nodata,
                ),
            ] {
                let enc = cbdam_codec::hierarchy::encode(grid, plan.quantizer, &opts).unwrap();
                let out = dir.path().join("r.cbdam");
                write_repository(&out, &enc, plan, georef, nodata).unwrap();
                bytes.push(std::fs::read(&out).unwrap());
            }
            assert!(
                bytes[0] == bytes[1],
                "{}: repositories differ",
                path.display()
            );
        }
    }

    #[test]
    fn sizes_parse_with_binary_suffixes_and_junk_is_refused() {
        assert_eq!(parse_size("2G").unwrap(), 2 << 30);
        assert_eq!(parse_size("512m").unwrap(), 512 << 20);
        assert_eq!(parse_size("1.5GiB").unwrap(), 3 << 29);
        assert_eq!(parse_size("4096").unwrap(), 4096);
        assert_eq!(parse_size(" 64 K ").unwrap(), 64 << 10);
        for bad in [
            "",
            "G",
            "-1G",
            "0",
            "0.1",
            "2X",
            "1e3",
            "nanG",
            "1..2G",
            "99999999999T",
        ] {
            assert!(parse_size(bad).is_err(), "{bad:?} accepted");
        }
        assert!(default_memory_limit() >= 1 << 20);
        assert_eq!(parse_dims("16385x16385").unwrap(), (16385, 16385));
        assert_eq!(parse_dims("3X2").unwrap(), (3, 2));
        for bad in ["16385", "0x5", "5x", "ax3", "-1x3"] {
            assert!(parse_dims(bad).is_err(), "{bad:?} accepted");
        }
    }
}
