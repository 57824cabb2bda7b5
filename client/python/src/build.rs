//! `cbdam.build` and `cbdam.verify`: the CLI's `build` and `verify` as functions, over the same
//! library calls ([`cbdam_builder::build`], [`cbdam_builder::verify`]), so a build from Python
//! writes the CLI's bytes.

use std::path::PathBuf;
use std::sync::Mutex;

use cbdam_builder::plan::default_memory_limit;
use cbdam_builder::planet::{PlanetComparison, compare_planet};
use cbdam_builder::tiles::{Tile, expand_inputs};
use cbdam_builder::verify::{compare_dem, compare_tiles_with, one_file_in_blocks};
use cbdam_builder::{BuildOptions, BuildSummary, ExtraLevels, ProgressEvent, Stage};
use cbdam_codec::entropy::CoderKind;
use cbdam_codec::hierarchy::{RepoKind, VerifyReport};
use cbdam_codec::lifting::Alpha;
use cbdam_codec::repository::Repository;
use pyo3::prelude::*;
use pyo3::types::{PyAny, PyDict, PyList};

use crate::errors::{PyCbdamError, Result};

/// Builds a repository from `inputs` (paths: DEMs, directories, globs, `@LIST`s or VRTs of
/// tiles, as `cbdam build` takes them) within `max_error` metres, written atomically to
/// `output`; the options are the CLI's flags. `progress(stage, done, total)` is called from the
/// build's threads (stage: 'prepare', 'encode', 'encode-coarser-roots', 'write'); an exception
/// it raises is raised once the build ends. Returns a summary dict.
#[pyfunction]
#[pyo3(signature = (inputs, output, max_error, *, diamond_size = None, extra_levels = None,
    alpha = 1.0, coder = "adaptive-tokens", threads = None, quantum = None, nodata = None,
    memory_limit = None, size = None, colour = false, like = None, planet = false,
    planet_level = None, progress = None))]
#[allow(clippy::too_many_arguments)]
pub fn build<'py>(
    py: Python<'py>,
    inputs: Vec<PathBuf>,
    output: PathBuf,
    max_error: f64,
    diamond_size: Option<usize>,
    extra_levels: Option<&Bound<'py, PyAny>>,
    alpha: f64,
    coder: &str,
    threads: Option<usize>,
    quantum: Option<f64>,
    nodata: Option<f64>,
    memory_limit: Option<u64>,
    size: Option<(usize, usize)>,
    colour: bool,
    like: Option<PathBuf>,
    planet: bool,
    planet_level: Option<u32>,
    progress: Option<Py<PyAny>>,
) -> PyResult<Bound<'py, PyDict>> {
    let mut o = BuildOptions::new(inputs, output, max_error);
    o.diamond_size = diamond_size.unwrap_or(o.diamond_size);
    o.extra_levels = parse_extra_levels(extra_levels)?;
    o.alpha = parse_alpha(alpha)?;
    o.coder = parse_coder(coder)?;
    (o.threads, o.quantum, o.nodata, o.memory_limit, o.raw_size) =
        (threads, quantum, nodata, memory_limit, size);
    (o.colour, o.like) = (colour, like);
    if planet_level.is_some() && !planet {
        return Err(PyCbdamError::Input("planet_level= needs planet=True".into()).into());
    }
    o.planet = planet.then_some(planet_level);
    let summary = build_reporting_progress(py, &o, progress)?;
    summary_dict(py, &o, summary)
}

/// Runs the build without the GIL, calling `progress(stage, done, total)` (with it) on each
/// event; the first exception the callback raises is raised once the build ends.
fn build_reporting_progress(
    py: Python<'_>,
    o: &BuildOptions,
    progress: Option<Py<PyAny>>,
) -> PyResult<BuildSummary> {
    let failed: Mutex<Option<PyErr>> = Mutex::new(None);
    let report = |event: ProgressEvent| {
        let Some(callback) = &progress else {
            return;
        };
        Python::attach(|py| {
            if let Err(e) = callback.call1(py, (stage_name(event.stage), event.done, event.total)) {
                let mut first = failed.lock().expect("progress error");
                first.get_or_insert(e);
            }
        });
    };
    let summary = py.detach(|| cbdam_builder::build(o, &report));
    if let Some(e) = failed.into_inner().expect("progress error") {
        return Err(e);
    }
    Ok(summary.map_err(|e| PyCbdamError::build(&e))?)
}

/// The summary dict `build` returns: the output, its size, its kind and what the kind reports.
fn summary_dict<'py>(
    py: Python<'py>,
    o: &BuildOptions,
    summary: BuildSummary,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("output", o.output.display().to_string())?;
    d.set_item("bytes", std::fs::metadata(&o.output).map(|m| m.len()).ok())?;
    match summary {
        BuildSummary::Elevation(s) => {
            d.set_item("kind", "elevation")?;
            d.set_item("width", s.width)?;
            d.set_item("height", s.height)?;
            d.set_item("valid", s.valid)?;
            d.set_item("records", s.records)?;
            d.set_item("max_error", s.plan.max_error())?;
        }
        BuildSummary::Colour(s) => {
            d.set_item("kind", "colour")?;
            d.set_item("records", s.records)?;
        }
        BuildSummary::Planet(s) => {
            d.set_item("kind", "planet")?;
            d.set_item("records", s.records)?;
            d.set_item("max_error", s.plan.max_error())?;
        }
    }
    Ok(d)
}

/// `alpha=`: 1 or 0.5.
fn parse_alpha(alpha: f64) -> Result<Alpha> {
    match alpha {
        1.0 => Ok(Alpha::One),
        0.5 => Ok(Alpha::Half),
        other => Err(PyCbdamError::Input(format!("alpha={other}: 1 or 0.5"))),
    }
}

/// `coder=`: a coder's name.
fn parse_coder(coder: &str) -> Result<CoderKind> {
    CoderKind::ALL
        .into_iter()
        .find(|c| c.name() == coder)
        .ok_or_else(|| {
            let names: Vec<String> = CoderKind::ALL
                .iter()
                .map(|c| format!("'{}'", c.name()))
                .collect();
            PyCbdamError::Input(format!("coder={coder:?}: one of {}", names.join(", ")))
        })
}

fn parse_extra_levels(v: Option<&Bound<'_, PyAny>>) -> Result<ExtraLevels> {
    let Some(v) = v else {
        return Ok(ExtraLevels::Auto);
    };
    if let Ok(s) = v.extract::<String>()
        && s.eq_ignore_ascii_case("auto")
    {
        return Ok(ExtraLevels::Auto);
    }
    match v.extract::<u32>() {
        Ok(n) if n <= ExtraLevels::MAX => Ok(ExtraLevels::Fixed(n)),
        _ => Err(PyCbdamError::Input(format!(
            "extra_levels={v}: 'auto' or a number of level pairs from 0 to {}",
            ExtraLevels::MAX
        ))),
    }
}

fn stage_name(stage: Stage) -> &'static str {
    match stage {
        Stage::Prepare => "prepare",
        Stage::Encode => "encode",
        Stage::EncodeCoarserRoots => "encode-coarser-roots",
        Stage::Write => "write",
    }
}

/// Checks every checksum of the repository at `path` and, given `against` (the build's input
/// paths), decodes every level and compares it with them, as `cbdam verify` does; raises
/// `CorruptError` or `InputError` with the CLI's message when a check fails. Returns the
/// per-level errors (`levels`: level, diamonds, worst error in metres; within `level_bound`),
/// the worst error of the finest level (a planet: of any level, against its resampled
/// lattice) in metres (`max_error`) and the guaranteed bound it keeps (`bound`); for a planet
/// also `inputs`, per input: its `path`, `samples`, `compared`, the lattice's
/// `resampling_max`/`resampling_rms` and the decoded surface's `surface_max`/`surface_rms`
/// against its samples, metres, and the `allowed` surface error (bound + resampling error).
#[pyfunction]
#[pyo3(signature = (path, against = None, memory_limit = None))]
pub fn verify<'py>(
    py: Python<'py>,
    path: PathBuf,
    against: Option<Vec<PathBuf>>,
    memory_limit: Option<u64>,
) -> PyResult<Bound<'py, PyDict>> {
    let checked = py.detach(|| check(&path, against.as_deref(), memory_limit))?;
    let d = PyDict::new(py);
    d.set_item("checksums", true)?;
    let Some(c) = checked else {
        return Ok(d);
    };
    let levels: Vec<(u8, usize, f64)> = c
        .report
        .levels
        .iter()
        .map(|l| (l.level, l.diamonds, f64::from(l.max_error) * c.unit))
        .collect();
    d.set_item("levels", levels)?;
    d.set_item("level_bound", f64::from(c.report.bound) * c.unit)?;
    d.set_item("max_error", c.max_error)?;
    d.set_item("bound", c.bound)?;
    if let Some(planet) = c.planet {
        let inputs = PyList::empty(py);
        for (r, e) in planet.resampling.iter().zip(&planet.end_to_end) {
            let i = PyDict::new(py);
            i.set_item("path", r.path.display().to_string())?;
            i.set_item("samples", r.samples)?;
            i.set_item("compared", r.compared)?;
            i.set_item("resampling_max", r.max_error)?;
            i.set_item("resampling_rms", r.rms_error)?;
            i.set_item("surface_max", e.max_error)?;
            i.set_item("surface_rms", e.rms_error)?;
            i.set_item("allowed", r.max_error + c.bound)?;
            inputs.append(i)?;
        }
        d.set_item("inputs", inputs)?;
    }
    Ok(d)
}

/// What [`verify`] measured against the inputs.
struct Checked {
    report: VerifyReport,
    /// Metres of one unit.
    unit: f64,
    /// The worst error, metres (see [`verify`]).
    max_error: f64,
    /// The guaranteed bound, metres.
    bound: f64,
    /// A planet's comparison with each input.
    planet: Option<PlanetComparison>,
}

/// [`verify`]'s work.
fn check(
    path: &std::path::Path,
    against: Option<&[PathBuf]>,
    memory_limit: Option<u64>,
) -> Result<Option<Checked>> {
    let name = path.display();
    let repo =
        Repository::open(path).map_err(|e| PyCbdamError::codec(&format!("opening {name}"), &e))?;
    repo.check_all()
        .map_err(|e| PyCbdamError::codec(&format!("checking {name}"), &e))?;
    let Some(against) = against else {
        return Ok(None);
    };
    let head = repo.head();
    if head.kind() == RepoKind::Colour {
        return Err(PyCbdamError::Unsupported(format!(
            "{name} is a colour repository: compare it with `cbdam verify`"
        )));
    }
    let (unit, bound) = (head.plan().unit, head.plan().max_error());
    let build = |e: cbdam_builder::BuildError| PyCbdamError::build(&e);
    let tiles = expand_inputs(against).map_err(build)?;
    let checked = |report, max_error, planet| Checked {
        report,
        unit,
        max_error,
        bound,
        planet,
    };
    if head.params().domain.cube().is_some() {
        let c = compare_planet(&repo, &tiles, head.nodata(), None).map_err(build)?;
        c.check().map_err(build)?;
        let worst = f64::from(c.report.max_error()) * unit;
        return Ok(Some(checked(c.report.clone(), worst, Some(c))));
    }
    let limit = memory_limit.unwrap_or_else(default_memory_limit);
    match tiles.as_slice() {
        [
            Tile {
                path: one,
                vrt: None,
            },
        ] if !one_file_in_blocks(&repo, one, limit) => {
            let c = compare_dem(&repo, one).map_err(build)?;
            c.check_mask().map_err(build)?;
            c.check_error().map_err(build)?;
            Ok(Some(checked(c.levels, c.max_error, None)))
        }
        several => {
            let c = compare_tiles_with(&repo, several, limit, None).map_err(build)?;
            c.check().map_err(build)?;
            let worst = c.worst.map_or(0.0, |w| w.0);
            Ok(Some(checked(c.levels, worst, None)))
        }
    }
}
