//! `cbdam bench report`: rate–distortion and time against error on every bundled DEM and a
//! synthetic terrain, optionally beside peer codecs measured in the same run, as `report.md`,
//! `results.json` and SVG plots.
//!
//! Our figures come from [`super::codec::measure`], which verifies every point (every
//! level, every valid sample) and fails the run if any exceeds ε.

pub(crate) mod machine;
mod peers;
pub(crate) mod plot;
mod render_cost;
mod rms_mode;
mod throughput;

use std::collections::BTreeSet;
use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use cbdam_builder::input::{ReadOptions, read_dem};
use cbdam_codec::entropy::CoderKind;
use cbdam_codec::hierarchy::EncodeOptions;
use cbdam_codec::samples::{Dem, detect_quantum};
use clap::Args;

use super::codec::{Measurement, bundled_inputs, measure, on_all_cores};
use crate::build::CoderArg;
use machine::{Machine, load_average};
use peers::{PeerRow, Peers};

/// Rate–distortion and time-against-error report: every bundled DEM and a synthetic fractal
/// terrain at a ladder of tolerances, optionally beside peer codecs (SZ3, ZFP, LERC,
/// JPEG-LS, zstd) measured in the same run; writes report.md and SVG plots.
#[derive(Args, Debug)]
pub struct BenchReportArgs {
    /// DEM files. Default: every .tif and .png in data/.
    inputs: Vec<PathBuf>,
    /// Output directory (created): report.md, results.json, plots/*.svg, replay/ (the
    /// rendering-cost repository and per-frame CSVs).
    #[arg(long, default_value = "bench-report")]
    out: PathBuf,
    /// Small and fast: one run per point and a 257² synthetic terrain unless given explicitly.
    #[arg(long)]
    quick: bool,
    /// Also measure the peer codecs (bench/peers.py in a Python venv; skipped with a message
    /// when Python or pip is unavailable).
    #[arg(long)]
    peers: bool,
    /// Tolerances ε, metres, comma-separated.
    #[arg(
        long,
        value_delimiter = ',',
        default_values_t = vec![0.05, 0.1, 0.25, 0.5, 1.0, 2.0, 5.0, 10.0],
        value_parser = crate::flags::positive_finite
    )]
    max_error: Vec<f64>,
    /// Timed repetitions per point; medians are reported (default 3, 1 with --quick).
    #[arg(long)]
    runs: Option<usize>,
    /// Side of the synthetic fractal terrain (2^k + 1; 0 for none; default 4097, 257 with
    /// --quick).
    #[arg(long)]
    synthetic: Option<usize>,
    /// Worker threads for building and decoding (default 1, as the peers are single-threaded).
    /// Every point is also timed on every core.
    #[arg(long, default_value_t = 1)]
    threads: usize,
    /// Our entropy coders to measure, comma-separated; the first is the one the plots and the
    /// rendering cost use.
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        default_values_t = vec![CoderArg::AdaptiveTokens, CoderArg::FastRice]
    )]
    coders: Vec<CoderArg>,
    /// Also build every input file within this RMS error (`cbdam build --rms-error`) and
    /// within the same maximum error, and compare the two (metres).
    #[arg(long, value_parser = crate::flags::positive_finite)]
    rms: Option<f64>,
    /// Python virtual environment for the peers (default ~/.cache/cbdam-bench-venv).
    #[arg(long)]
    venv: Option<PathBuf>,
    /// Rendering cost: the flights (every *.json in this folder; default data/flights).
    #[arg(long)]
    flights: Option<PathBuf>,
    /// Rendering cost: pixel-error targets, comma-separated (default 0.5,1,2,4,8; 1,4 with
    /// --quick).
    #[arg(long, value_delimiter = ',', value_parser = crate::flags::positive_finite)]
    pixel_errors: Option<Vec<f64>>,
    /// Rendering cost: the dataset to fly over, by its name in the report (default the SRTM
    /// sample when it is an input, else the first input).
    #[arg(long)]
    render_dem: Option<String>,
}

/// Seed of the synthetic terrain: fixed, so every machine measures the same heights.
const SYNTH_SEED: u64 = 2006;

struct Dataset {
    name: String,
    dem: Dem,
    /// Our points, a series per coder (`--coders`, the first first).
    ours: Vec<Series>,
}

/// Our points with one coder, in ε order.
struct Series {
    coder: CoderKind,
    points: Vec<(f64, Measurement)>,
}

impl Dataset {
    /// The first coder's points: the plots' and the rendering cost's.
    fn first(&self) -> &[(f64, Measurement)] {
        &self.ours[0].points
    }
}

/// How the run went for the peers: their rows, or why there are none.
enum PeerOutcome {
    NotRequested,
    Skipped(String),
    Measured(Peers),
}

impl PeerOutcome {
    fn rows(&self) -> &[PeerRow] {
        match self {
            PeerOutcome::Measured(p) => &p.rows,
            _ => &[],
        }
    }
}

/// The inputs read whole, by file name, and the synthetic terrain of side `synth_side` (none
/// for 0).
fn read_dems(inputs: &[PathBuf], synth_side: usize) -> Result<Vec<(String, Dem)>> {
    let mut dems: Vec<(String, Dem)> = Vec::new();
    for path in inputs {
        let dem = read_dem(path, &ReadOptions::default())
            .with_context(|| format!("reading {}", path.display()))?;
        let name = path
            .file_name()
            .unwrap_or_default()
            .to_string_lossy()
            .into_owned();
        dems.push((name, dem));
    }
    if synth_side != 0 {
        dems.push((
            format!("synthetic fractal {synth_side}²"),
            crate::synth::dem(synth_side, SYNTH_SEED),
        ));
    }
    Ok(dems)
}

/// The build's pool and a pool of every core.
struct Pools {
    build: rayon::ThreadPool,
    all: rayon::ThreadPool,
}

/// Our codec with `coder` on `dem` at every tolerance of `eps`, each point verified, then
/// timed on every core too, in ε order.
fn measure_ours(
    name: &str,
    dem: &Dem,
    eps: &[f64],
    runs: usize,
    pools: &Pools,
    coder: CoderKind,
) -> Result<Series> {
    let opts = EncodeOptions {
        coder,
        ..EncodeOptions::default()
    };
    let mut points = Vec::new();
    for &e in eps {
        let mut m = measure(dem, e, &opts, runs, &pools.build)
            .with_context(|| format!("{name}: the codec failed its own bound"))?;
        let all = on_all_cores(dem, e, &opts, runs, &pools.all)?;
        eprintln!(
            "{name} ε={e} {}: {:.3} bits/sample (file), max err {:.4} m, build {:.2} MS/s, \
             decode {:.2} MS/s (1 thread), {:.2} MS/s ({} threads)",
            coder.name(),
            m.file_bps(),
            m.max_err,
            m.msps(m.build),
            m.msps(m.decode),
            m.msps(all.decode),
            all.threads
        );
        m.all_cores = Some(all);
        points.push((e, m));
    }
    Ok(Series { coder, points })
}

/// The peer codecs on every dataset (`--peers`), or why they were skipped.
fn measure_peers(
    args: &BenchReportArgs,
    datasets: &[Dataset],
    eps: &[f64],
    runs: usize,
) -> PeerOutcome {
    let list: Vec<(String, &Dem)> = datasets
        .iter()
        .map(|d| (file_safe(&d.name), &d.dem))
        .collect();
    match peers::measure(
        &list,
        eps,
        runs,
        &args.out.join("peers"),
        args.venv.as_deref(),
    ) {
        Ok(p) => PeerOutcome::Measured(p),
        Err(why) => {
            eprintln!("peers skipped: {why}");
            PeerOutcome::Skipped(why)
        }
    }
}

/// What the flags ask to measure, checked: runs per point, the tolerances in order, the
/// synthetic terrain's side and the input files.
struct Plan {
    runs: usize,
    eps: Vec<f64>,
    synth_side: usize,
    inputs: Vec<PathBuf>,
}

fn plan_of(args: &BenchReportArgs) -> Result<Plan> {
    let runs = args.runs.unwrap_or(if args.quick { 1 } else { 3 });
    if runs == 0 {
        bail!("--runs must be at least 1");
    }
    let mut eps = args.max_error.clone();
    eps.sort_by(f64::total_cmp);
    eps.dedup();
    let synth_side = args
        .synthetic
        .unwrap_or(if args.quick { 257 } else { 4097 });
    if synth_side != 0 && !(synth_side >= 3 && (synth_side - 1).is_power_of_two()) {
        bail!("--synthetic must be 0 or 2^k + 1 (e.g. 257, 4097), not {synth_side}");
    }
    let inputs = if args.inputs.is_empty() {
        bundled_inputs(&["tif", "png"])?
    } else {
        args.inputs.clone()
    };
    Ok(Plan {
        runs,
        eps,
        synth_side,
        inputs,
    })
}

pub fn run(args: &BenchReportArgs) -> Result<()> {
    let Plan {
        runs,
        eps,
        synth_side,
        inputs,
    } = plan_of(args)?;
    std::fs::create_dir_all(args.out.join("plots"))
        .with_context(|| format!("creating {}", args.out.display()))?;

    let load_start = load_average();
    let machine = Machine::probe();
    let pools = Pools {
        build: rayon::ThreadPoolBuilder::new()
            .num_threads(args.threads.max(1))
            .build()?,
        all: rayon::ThreadPoolBuilder::new().build()?,
    };
    let coders = coders_of(&args.coders)?;
    let dems = read_dems(&inputs, synth_side)?;

    let mut datasets = Vec::new();
    for (name, dem) in dems {
        let ours = coders
            .iter()
            .map(|&c| measure_ours(&name, &dem, &eps, runs, &pools, c))
            .collect::<Result<Vec<_>>>()?;
        datasets.push(Dataset { name, dem, ours });
    }
    let rms = match args.rms {
        Some(e) => Some((e, rms_mode::measure(&inputs, e, &args.out.join("rms"))?)),
        None => None,
    };

    let peers = if args.peers {
        measure_peers(args, &datasets, &eps, runs)
    } else {
        PeerOutcome::NotRequested
    };
    let load_end = load_average();

    let mut md = String::new();
    header(
        &mut md,
        &machine,
        &load_start,
        &load_end,
        runs,
        &pools,
        &peers,
    )?;
    datasets_table(&mut md, &datasets)?;
    summary(&mut md, &datasets, &eps, peers.rows())?;
    throughput::section(&mut md, &datasets, peers.rows())?;
    if let Some((e, rows)) = &rms {
        md += "## Mean-square error control\n\n";
        md += &rms_mode::section(rows, *e)?;
        md.push('\n');
    }
    datasets_sections(&mut md, args, &datasets, peers.rows())?;
    md += "\n## Rendering cost against error\n\n";
    md += &rendering_cost(args, &datasets)?;
    fairness(&mut md);
    let report = args.out.join("report.md");
    std::fs::write(&report, md).with_context(|| format!("writing {}", report.display()))?;
    std::fs::write(
        args.out.join("results.json"),
        serde_json::to_vec_pretty(&results_json(&datasets, &peers))?,
    )?;
    println!("{}", report.display());
    Ok(())
}

/// `--coders` without repeats, in order; at least one.
fn coders_of(args: &[CoderArg]) -> Result<Vec<CoderKind>> {
    let mut coders: Vec<CoderKind> = Vec::new();
    for c in args {
        if !coders.contains(&c.kind()) {
            coders.push(c.kind());
        }
    }
    if coders.is_empty() {
        bail!("--coders needs at least one coder");
    }
    Ok(coders)
}

/// A section per dataset (its plot written beside the report).
fn datasets_sections(
    md: &mut String,
    args: &BenchReportArgs,
    datasets: &[Dataset],
    peer_rows: &[PeerRow],
) -> Result<()> {
    for d in datasets {
        let rows: Vec<&PeerRow> = peer_rows
            .iter()
            .filter(|r| r.dem == file_safe(&d.name))
            .collect();
        let plot = format!("plots/{}.svg", file_safe(&d.name));
        plot::dataset(&args.out.join(&plot), &d.name, &plot_series(d, &rows))?;
        per_dataset(md, d, &rows, &plot)?;
    }
    Ok(())
}

/// The rendering-cost section: the flights over one dataset (`--render-dem`, default the SRTM
/// sample when it is among the inputs, else the first) at ε = 1 m.
fn rendering_cost(args: &BenchReportArgs, datasets: &[Dataset]) -> Result<String> {
    const RENDER_EPS: f64 = 1.0;
    let flights_dir = args
        .flights
        .clone()
        .unwrap_or_else(|| std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/flights"));
    let flights = render_cost::flights_in(&flights_dir)?;
    if flights.is_empty() {
        return Ok(format!(
            "Not measured: no flights (*.json) in {}.\n",
            flights_dir.display()
        ));
    }
    let pick = match &args.render_dem {
        Some(name) => datasets
            .iter()
            .find(|d| &d.name == name)
            .with_context(|| format!("--render-dem {name}: not one of the report's datasets"))?,
        None => match datasets.iter().find(|d| d.name.starts_with("srtm")) {
            Some(d) => d,
            None => datasets.first().context("no dataset to fly over")?,
        },
    };
    let mut targets = args.pixel_errors.clone().unwrap_or_else(|| {
        if args.quick {
            vec![1.0, 4.0]
        } else {
            vec![0.5, 1.0, 2.0, 4.0, 8.0]
        }
    });
    targets.sort_by(f64::total_cmp);
    targets.dedup();
    let name = file_safe(&pick.name);
    let points = render_cost::measure(
        &pick.dem,
        &name,
        RENDER_EPS,
        &flights,
        &targets,
        &args.out.join("replay"),
    )?;
    let plot = "plots/render_cost.svg";
    plot::render_cost(
        &args.out.join(plot),
        &format!(
            "{}: rendering cost against the pixel-error target",
            pick.name
        ),
        &points,
    )?;
    render_cost::section(
        &points,
        &format!(
            "{} at ε = {RENDER_EPS} m (repository and per-frame CSVs in `replay/`)",
            pick.name
        ),
        Some(plot),
    )
}

/// Dataset names as file names and harness keys: no spaces or superscripts.
fn file_safe(name: &str) -> String {
    name.replace('²', "")
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '_' || c == '.' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

fn header(
    md: &mut String,
    m: &Machine,
    load_start: &str,
    load_end: &str,
    runs: usize,
    pools: &Pools,
    peers: &PeerOutcome,
) -> Result<()> {
    let (threads, all_threads) = (
        pools.build.current_num_threads(),
        pools.all.current_num_threads(),
    );
    let args: Vec<String> = std::env::args().skip(1).collect();
    writeln!(md, "# cbdam benchmark report\n")?;
    writeln!(
        md,
        "Generated by `cbdam {}` on {}.\n",
        args.join(" "),
        m.date
    )?;
    writeln!(md, "| | |\n|---|---|")?;
    writeln!(md, "| CPU | {} ({} logical cores) |", m.cpu, m.cores)?;
    match m.ram_gib {
        Some(g) => writeln!(md, "| RAM | {g:.1} GiB |")?,
        None => writeln!(md, "| RAM | unknown |")?,
    }
    writeln!(md, "| load average 1/5/15 min at start | {load_start} |")?;
    writeln!(md, "| load average 1/5/15 min at end | {load_end} |")?;
    writeln!(md, "| commit | {} |", m.commit)?;
    writeln!(
        md,
        "| build profile | {} |",
        if cfg!(debug_assertions) {
            "debug assertions on (throughput not representative)"
        } else {
            "release"
        }
    )?;
    writeln!(md, "| timed runs per point | {runs} (medians reported) |")?;
    writeln!(
        md,
        "| cbdam threads | {threads} for build and decode, and every point again on \
         {all_threads} (all cores); N = {}, α = 1 |",
        EncodeOptions::default().n
    )?;
    let p = match peers {
        PeerOutcome::NotRequested => "not requested (`--peers`)".to_string(),
        PeerOutcome::Skipped(why) => format!("skipped: {why}"),
        PeerOutcome::Measured(p) => format!("bench/peers.py, single-threaded: {}", p.versions),
    };
    writeln!(md, "| peers | {p} |\n")?;
    writeln!(
        md,
        "Rates count all width × height samples. *cbdam file* is the whole repository file as \
         `cbdam build` writes it (header, root field, index, checksums, records); *payload* is \
         root field + records + record index. Peers' rates are their compressed bytes alone. \
         Max error is verified after decoding, over valid samples, against the values as read \
         (f64); the run fails if ours exceeds ε. Throughput is M samples/s of wall-clock time \
         (median); other processes on the machine (see the load average) slow it, so compare \
         codecs within one report rather than across reports.\n"
    )?;
    Ok(())
}

fn datasets_table(md: &mut String, datasets: &[Dataset]) -> Result<()> {
    writeln!(md, "## Datasets\n")?;
    writeln!(
        md,
        "| dataset | size | valid samples | value quantum | heights (m) |\n|---|---:|---:|---:|---|"
    )?;
    for d in datasets {
        let valid = (0..d.dem.values.len())
            .filter(|&i| d.dem.is_valid(i))
            .count();
        let (lo, hi) = d.dem.valid_range().unwrap_or((f64::NAN, f64::NAN));
        writeln!(
            md,
            "| {} | {}×{} | {valid} | {} | {lo:.1} … {hi:.1} |",
            d.name,
            d.dem.width,
            d.dem.height,
            detect_quantum(&d.dem).map_or("none (float)".into(), |q| format!("{q} m")),
        )?;
    }
    md.push('\n');
    Ok(())
}

/// Peer codecs in first-seen order.
fn codecs(rows: &[&PeerRow]) -> Vec<String> {
    let mut seen = BTreeSet::new();
    rows.iter()
        .filter(|r| r.eps.is_some() && seen.insert(r.codec.clone()))
        .map(|r| r.codec.clone())
        .collect()
}

fn find<'a>(rows: &[&'a PeerRow], codec: &str, eps: f64) -> Option<&'a PeerRow> {
    rows.iter()
        .copied()
        .find(|r| r.codec == codec && r.eps == Some(eps))
}

/// "bps (max err)", with `!` when the verified error exceeds ε and `–` for a skipped point.
fn peer_cell(r: Option<&PeerRow>, with_err: bool) -> String {
    match r.map(|r| &r.result) {
        None => String::new(),
        Some(Err(_)) => "–".into(),
        Some(Ok(p)) => {
            let mark = if p.bound_ok { "" } else { " !" };
            if with_err {
                format!("{:.3} ({}){mark}", p.bps, short(p.max_err))
            } else {
                format!("{:.3}{mark}", p.bps)
            }
        }
    }
}

fn short(v: f64) -> String {
    if v == 0.0 {
        "0".into()
    } else {
        format!("{}", (v * 1e4).round() / 1e4)
    }
}

fn summary(
    md: &mut String,
    datasets: &[Dataset],
    eps: &[f64],
    peer_rows: &[PeerRow],
) -> Result<()> {
    writeln!(md, "## Summary: bits per sample against ε\n")?;
    writeln!(
        md,
        "cbdam: whole repository file. `!` marks a peer point whose verified max error exceeds \
         ε; `–` a point the peer could not code (see its dataset's section).\n"
    )?;
    write!(md, "| dataset | codec |")?;
    for e in eps {
        write!(md, " ε={e} |")?;
    }
    write!(md, "\n|---|---|")?;
    for _ in eps {
        write!(md, "---:|")?;
    }
    md.push('\n');
    for d in datasets {
        for (i, series) in d.ours.iter().enumerate() {
            let name = if i == 0 { d.name.as_str() } else { "" };
            write!(md, "| {name} | **cbdam** {} |", series.coder.name())?;
            for (_, m) in &series.points {
                write!(md, " **{:.3}** |", m.file_bps())?;
            }
            md.push('\n');
        }
        let rows: Vec<&PeerRow> = peer_rows
            .iter()
            .filter(|r| r.dem == file_safe(&d.name))
            .collect();
        for c in codecs(&rows) {
            write!(md, "| | {c} |")?;
            for &e in eps {
                write!(md, " {} |", peer_cell(find(&rows, &c, e), false))?;
            }
            md.push('\n');
        }
        if let Some(Ok(p)) = rows.iter().find(|r| r.eps.is_none()).map(|r| &r.result) {
            write!(
                md,
                "| | zstd -19 lossless ({}) | {:.3} (any ε) |",
                p.note, p.bps
            )?;
            md.push_str(&" |".repeat(eps.len() - 1));
            md.push('\n');
        }
    }
    md.push('\n');
    Ok(())
}

/// A table's head: `ours` (the first columns' titles) and `align` (their alignment row), then a
/// right-aligned column per peer codec.
fn table_head(
    md: &mut String,
    ours: &str,
    align: &str,
    codecs: &[impl std::fmt::Display],
) -> Result<()> {
    write!(md, "{ours}")?;
    for c in codecs {
        write!(md, " {c} |")?;
    }
    write!(md, "\n{align}")?;
    for _ in codecs {
        write!(md, "---:|")?;
    }
    md.push('\n');
    Ok(())
}

fn per_dataset(md: &mut String, d: &Dataset, rows: &[&PeerRow], plot: &str) -> Result<()> {
    let cs = codecs(rows);
    writeln!(md, "## {}\n", d.name)?;
    writeln!(
        md,
        "![{} — rate and throughput against ε]({plot})\n",
        d.name
    )?;
    writeln!(
        md,
        "Rate–distortion (bits per sample; peers: bits per sample (verified max error, m)):\n"
    )?;
    let mut head = "| ε (m) |".to_string();
    let mut align = "|---:|".to_string();
    for s in &d.ours {
        head += &format!(" cbdam {} file bits/sample |", s.coder.name());
        align += "---:|";
    }
    head += " cbdam payload bits/sample | cbdam max err (m) | cbdam RMS (m) |";
    align += "---:|---:|---:|";
    table_head(md, &head, &align, &cs)?;
    for (i, (e, m)) in d.first().iter().enumerate() {
        write!(md, "| {e} |")?;
        for s in &d.ours {
            write!(md, " {:.3} |", s.points[i].1.file_bps())?;
        }
        write!(
            md,
            " {:.3} | {:.4} | {:.4} |",
            m.payload_bps(),
            m.max_err,
            m.rms_err
        )?;
        for c in &cs {
            write!(md, " {} |", peer_cell(find(rows, c, *e), true))?;
        }
        md.push('\n');
    }
    writeln!(
        md,
        "\nThroughput against error: [the table above](#throughput-one-core-and-every-core)."
    )?;
    let skips: Vec<String> = rows
        .iter()
        .filter_map(|r| match &r.result {
            Err(why) => Some(format!("{} at ε={}: {why}", r.codec, r.eps.unwrap_or(0.0))),
            Ok(_) => None,
        })
        .collect();
    if !skips.is_empty() {
        writeln!(md, "\nNot coded: {}.", skips.join("; "))?;
    }
    md.push('\n');
    Ok(())
}

fn plot_series(d: &Dataset, rows: &[&PeerRow]) -> Vec<plot::Series> {
    let mut v = vec![plot::Series {
        name: "cbdam (file)".into(),
        points: d
            .first()
            .iter()
            .map(|(e, m)| (*e, m.file_bps(), m.msps(m.build), m.msps(m.decode)))
            .collect(),
    }];
    for c in codecs(rows) {
        // Points over the bound are in the tables, marked, but not drawn as if they were
        // comparable.
        let points = rows
            .iter()
            .filter(|r| r.codec == c)
            .filter_map(|r| match (&r.result, r.eps) {
                (Ok(p), Some(e)) if p.bound_ok => Some((e, p.bps, p.enc_msps, p.dec_msps)),
                _ => None,
            })
            .collect();
        v.push(plot::Series { name: c, points });
    }
    v
}

fn fairness(md: &mut String) {
    md.push_str(
        "\n## What the comparison leaves out\n\n\
         The peers compress a whole raster into one stream; cbdam stores a hierarchy of \
         diamonds. What the cbdam rate pays for and theirs does not:\n\n\
         - **Random access**: every diamond is a record that decodes on its own, located by the \
         index, so a viewer fetches only what the view needs; the peers decode the whole array \
         (or, for tiled use, would pay per-tile restarts not measured here).\n\
         - **Every level bounded**: every coarser level of the hierarchy is within ε of the \
         input too, not only the finest; the peers guarantee the full-resolution array only.\n\
         - **Progressive streaming**: coarse levels come first and refine in place; the peers \
         have no coarse version to show before the whole stream is decoded.\n\
         - **Object-space error per diamond** (in the index) for screen-space refinement.\n\n\
         Peers get the same budget rules as cbdam: where float32 storage of the input moves a \
         value (0.1 m Terrain-RGB steps), that representation error is taken out of ε; nodata \
         samples are filled row-wise for codecs without a mask (LERC gets the mask) and \
         excluded from the error. *ZFP tuned* raises ZFP's tolerance while the error, checked \
         against the original, stays within ε — a search a user cannot run without the \
         original, so it flatters ZFP. JPEG-LS codes integers on the data's value quantum, or \
         on cbdam's own pre-quantization grid for float data. Decode throughput for cbdam is \
         a full decode of every record plus synthesis of every diamond (what a viewer does \
         piecemeal), single-threaded in the one-core column and a batch of the walk's diamonds \
         at a time in parallel (as `cbdam extract` decodes) in the every-core column; the \
         peers are measured single-threaded only.\n",
    );
}

fn results_json(datasets: &[Dataset], peers: &PeerOutcome) -> serde_json::Value {
    use serde_json::json;
    let ours: Vec<_> = datasets
        .iter()
        .flat_map(|d| d.ours.iter().map(move |s| (d, s)))
        .flat_map(|(d, s)| {
            s.points.iter().map(move |(e, m)| {
                let all = m.all_cores.as_ref();
                json!({
                    "dem": d.name, "coder": s.coder.name(), "eps": e,
                    "file_bps": m.file_bps(), "payload_bps": m.payload_bps(),
                    "max_err": m.max_err, "rms_err": m.rms_err,
                    "build_msps": m.msps(m.build), "encode_msps": m.msps(m.encode),
                    "decode_msps": m.msps(m.decode),
                    "all_cores_threads": all.map(|a| a.threads),
                    "all_cores_encode_msps": all.map(|a| m.msps(a.encode)),
                    "all_cores_decode_msps": all.map(|a| m.msps(a.decode)),
                    "file_bytes": m.file_bytes, "records": m.records,
                })
            })
        })
        .collect();
    let peers: Vec<_> = peers
        .rows()
        .iter()
        .map(|r| match &r.result {
            Ok(p) => json!({
                "codec": r.codec, "dem": r.dem, "eps": r.eps, "bps": p.bps,
                "max_err": p.max_err, "rms_err": p.rms_err, "enc_msps": p.enc_msps,
                "dec_msps": p.dec_msps, "bound_ok": p.bound_ok, "note": p.note,
            }),
            Err(why) => json!({"codec": r.codec, "dem": r.dem, "eps": r.eps, "skipped": why}),
        })
        .collect();
    json!({"cbdam": ours, "peers": peers})
}
