//! `cbdam bench network`: remote browsing over emulated links. For each flight, a reference run
//! on the local file, then for each link profile and each server kind a run over loopback
//! through a `cbdam-link` proxy: `cbdam serve` (batched) or its raw file route read with range
//! requests as from any static server. Every run replays the flight in real time (frames paced
//! at `--fps`, so the link's latency and rate matter), then holds the camera still until the
//! cut converges or `--max-settle-s` pass.
//!
//! Measured per run (see [`measure::Measured`]): bytes fetched, bytes of the records the cuts
//! used (from the index), requests and range requests as the server counted them (and as the
//! client did), flight frames at the pixel target, seconds from the camera stopping to the
//! target, frames over the refinement budget, and whether the final cut is the local file's.
//! Written to `--out`: `network.md` (the table, the targets), `network.json`, one CSV
//! per run (`cbdam replay`'s columns) in `csv/`, and `plots/screen_error.svg`.

mod measure;
mod plot;
mod report;

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, ensure};
use cbdam_client::flight::Flight;
use cbdam_codec::repository::Repository;
use cbdam_link::Link;
use clap::{Args, ValueEnum};

pub use measure::ServerKind;
use measure::{Measured, Route, RunSettings};

use crate::bench::report::machine::{Machine, load_average};
use crate::flags;
use crate::replay::ReplayPacing;
use crate::session::{budget_label, refine_config};

/// Remote browsing over emulated links: each flight replayed in real time against the local
/// file and, for each link profile (adsl, dsl10, fibre, mobile), through a loopback shaping
/// proxy against `cbdam serve` (batched) and against a static file server (range requests);
/// bytes fetched against bytes the cuts used, requests per second, frames at the pixel
/// target, seconds from the camera stopping to the target, frames over budget. Writes
/// network.md, network.json, per-run CSVs and an SVG of screen error over time.
#[derive(Args, Debug)]
#[command(mut_arg("fps", |a| a.help(
    "Frames per second: the flight's and the settling frames' pace in real time"
)))]
pub struct BenchNetworkArgs {
    /// Link profiles, comma-separated: adsl, dsl10, fibre, mobile.
    #[arg(long, value_delimiter = ',', default_value = "adsl,dsl10,fibre,mobile")]
    profiles: Vec<String>,
    /// Flights (JSON, as for `cbdam replay`). Default: every data/flights/*.json.
    #[arg(long, num_args = 1.., value_name = "FLIGHT.json")]
    flights: Vec<PathBuf>,
    /// Servers, comma-separated: serve (`cbdam serve`, batched requests), static (its raw file
    /// route read with range requests, as from any static server).
    #[arg(
        long,
        value_delimiter = ',',
        value_enum,
        default_value = "serve,static"
    )]
    servers: Vec<ServerKind>,
    /// Viewport WIDTHxHEIGHT, pixels.
    #[arg(long, default_value = "1920x1080", value_parser = flags::Size2::pixels)]
    size: (u32, u32),
    #[command(flatten)]
    pixel_error: flags::PixelError,
    #[command(flatten)]
    budget_ms: flags::BudgetMs,
    #[command(flatten)]
    fps: flags::Fps,
    /// After the flight, at most this many seconds with the camera still, waiting for the cut to
    /// converge.
    #[arg(long, default_value_t = 30.0, value_parser = flags::non_negative_finite)]
    max_settle_s: f64,
    /// Repository to serve. Default: a synthetic fractal terrain of --synth-size² built at
    /// ε = 1 m (as `cbdam synth` and `cbdam build` make it), kept in --out and reused.
    #[arg(long)]
    repo: Option<PathBuf>,
    /// Side of the default synthetic terrain, samples.
    #[arg(long, default_value_t = 4097)]
    synth_size: usize,
    /// Override every profile's probability of resetting a connection.
    #[arg(long)]
    reset_prob: Option<f64>,
    /// Seed of the links' reset and jitter draws.
    #[arg(long)]
    seed: Option<u64>,
    /// When the client prefetches: off, always (alongside what the view needs, at a lower
    /// priority), when-idle (only in frames whose cut wants no record).
    #[arg(long, value_enum, default_value = "when-idle")]
    prefetch: PrefetchArg,
    /// The order records are asked for in: screen-error (the worst first), error-per-byte (the
    /// most screen error removed per byte first).
    #[arg(long, value_enum, default_value = "screen-error")]
    fetch_order: FetchOrderArg,
    /// Ask only for the records of the cut's most urgent candidates beyond what each frame
    /// refined: as many as the loop refines in a second, and at least this many (0: all;
    /// default: the viewer's, 128).
    #[arg(long)]
    want_limit: Option<usize>,
    /// Most records a frame prefetches (0: no limit; default: the viewer's, 32).
    #[arg(long)]
    prefetch_limit: Option<usize>,
    /// Output directory (created): network.md, network.json, csv/, plots/.
    #[arg(long, default_value = "bench-network")]
    out: PathBuf,
}

/// [`cbdam_client::refine::Prefetch`] on the command line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum PrefetchArg {
    Off,
    Always,
    WhenIdle,
}

impl From<PrefetchArg> for cbdam_client::refine::Prefetch {
    fn from(p: PrefetchArg) -> Self {
        match p {
            PrefetchArg::Off => Self::Off,
            PrefetchArg::Always => Self::Always,
            PrefetchArg::WhenIdle => Self::WhenIdle,
        }
    }
}

/// [`cbdam_client::refine::FetchOrder`] on the command line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum FetchOrderArg {
    ScreenError,
    ErrorPerByte,
}

impl From<FetchOrderArg> for cbdam_client::refine::FetchOrder {
    fn from(o: FetchOrderArg) -> Self {
        match o {
            FetchOrderArg::ScreenError => Self::ScreenError,
            FetchOrderArg::ErrorPerByte => Self::ScreenErrorPerByte,
        }
    }
}

/// Seed of the default synthetic terrain: `cbdam synth`'s default.
const SYNTH_SEED: u64 = 1;
/// Tolerance of the default synthetic terrain's build, metres (the issue's).
const SYNTH_MAX_ERROR: f64 = 1.0;

/// The profiles of the arguments, with the overrides applied, by name.
fn links(args: &BenchNetworkArgs) -> Result<Vec<(String, Link)>> {
    ensure!(
        !args.profiles.is_empty(),
        "--profiles must name at least one profile"
    );
    let mut out: Vec<(String, Link)> = Vec::new();
    for p in &args.profiles {
        let mut link: Link = p.parse().map_err(anyhow::Error::msg)?;
        if let Some(r) = args.reset_prob {
            ensure!(
                (0.0..=1.0).contains(&r),
                "--reset-prob must be a probability from 0 to 1, not {r}"
            );
            link.reset_prob = r;
        }
        if let Some(s) = args.seed {
            link.seed = s;
        }
        let name = p.trim().to_ascii_lowercase();
        if !out.iter().any(|(n, _)| *n == name) {
            out.push((name, link));
        }
    }
    Ok(out)
}

/// The repository: `--repo`, or the synthetic terrain built as `cbdam synth --size S` and
/// `cbdam build --size SxS --max-error 1` would, kept in `out` and reused when there.
fn repository(args: &BenchNetworkArgs, out: &Path) -> Result<PathBuf> {
    if let Some(p) = &args.repo {
        return Ok(p.clone());
    }
    let s = args.synth_size;
    ensure!(s >= 65, "--synth-size must be at least 65, not {s}");
    let path = out.join(format!("synthetic_{s}.cbdam"));
    if path.exists() {
        eprintln!("reusing {} (delete it to rebuild)", path.display());
        return Ok(path);
    }
    let tmp = tempfile::tempdir()?;
    let raw = tmp.path().join(format!("synthetic_{s}.f32"));
    eprintln!(
        "synthesising a {s}² terrain (seed {SYNTH_SEED}) and building it at ε = {SYNTH_MAX_ERROR} m …"
    );
    crate::synth::write(&raw, s, SYNTH_SEED)?;
    let mut opts = cbdam_builder::BuildOptions::new(vec![raw], path.clone(), SYNTH_MAX_ERROR);
    opts.raw_size = Some((s, s));
    cbdam_builder::build(&opts, &cbdam_builder::NoProgress)
        .with_context(|| format!("building {}", path.display()))?;
    Ok(path)
}

fn flight_name(path: &Path) -> String {
    path.file_stem()
        .unwrap_or_default()
        .to_string_lossy()
        .into_owned()
}

/// One line on stderr per finished run.
fn progress(m: &Measured) {
    let what = match &m.route {
        Route::Local => "local file".to_string(),
        Route::Remote {
            profile, server, ..
        } => format!("{profile}, {}", server.name()),
    };
    eprintln!(
        "  {} / {what}: {:.1} s, {:.2} MB fetched, {:.2} MB used, camera stop → target {}",
        m.flight,
        m.wall_s(),
        m.bytes_fetched as f64 / 1e6,
        m.bytes_used as f64 / 1e6,
        m.stop_to_target_s()
            .map_or_else(|| "not met".into(), |s| format!("{s:.2} s")),
    );
    if let Some(r) = &m.received {
        eprintln!(
            "    received {:.2} MB ({:.2} MB again, {:.2} MB after the last frame); unused: {:.2} MB prefetched, {:.2} MB wanted by the cut ({:.2} MB came after \
             withdrawal); final cut {:.2} MB, lacked {:.2} MB at the stop (≥ {:.2} s; any \
             policy ≥ {:.2} s); stop → 2 px {}, → 4 px {}",
            r.bytes as f64 / 1e6,
            r.repeated as f64 / 1e6,
            r.after_last_frame as f64 / 1e6,
            r.prefetch_unused as f64 / 1e6,
            r.other_unused as f64 / 1e6,
            r.unused_after_withdrawal as f64 / 1e6,
            r.final_bytes as f64 / 1e6,
            r.final_missing_at_stop as f64 / 1e6,
            r.lower_bound_s,
            r.any_policy_bound_s,
            m.stop_to_px_s(2.0)
                .map_or_else(|| "not met".into(), |s| format!("{s:.2} s")),
            m.stop_to_px_s(4.0)
                .map_or_else(|| "not met".into(), |s| format!("{s:.2} s")),
        );
    }
}

/// The flights to replay: --flights, else every data/flights/*.json, loaded and named.
fn load_flights(args: &BenchNetworkArgs) -> Result<Vec<(String, Flight)>> {
    let flights = if args.flights.is_empty() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/flights");
        crate::bench::codec::files_with(&dir, &["json"])
            .with_context(|| format!("reading the flights folder {}", dir.display()))?
    } else {
        args.flights.clone()
    };
    ensure!(!flights.is_empty(), "no flights to replay");
    flights
        .iter()
        .map(|p| {
            Flight::load(p)
                .with_context(|| format!("loading {}", p.display()))
                .map(|f| (flight_name(p), f))
        })
        .collect()
}

/// The client's settings for every run: the viewer's refinement with the flags' fetch policy and
/// limits, paced in real time; and the want and prefetch limits in force.
fn run_settings(args: &BenchNetworkArgs) -> Result<(RunSettings, Option<usize>, Option<usize>)> {
    let viewer = refine_config(args.pixel_error.value, args.budget_ms.value, 1.0);
    // A limit given on the command line replaces the viewer's; 0 is none.
    let limit = |arg: Option<usize>, default: Option<usize>| match arg {
        Some(0) => None,
        Some(n) => Some(n),
        None => default,
    };
    let config = cbdam_client::refine::RefineConfig {
        prefetch: args.prefetch.into(),
        fetch_order: args.fetch_order.into(),
        want_limit: limit(args.want_limit, viewer.want_limit),
        prefetch_limit: limit(args.prefetch_limit, viewer.prefetch_limit),
        ..viewer
    };
    let (want_limit, prefetch_limit) = (config.want_limit, config.prefetch_limit);
    let settings = RunSettings {
        config,
        pacing: ReplayPacing {
            fps: args.fps.value,
            size: args.size,
            max_settle_frames: (args.max_settle_s * args.fps.value).ceil() as usize,
            paced: true,
        },
    };
    Ok((settings, want_limit, prefetch_limit))
}

/// Every flight on the local file, then over every link profile from every server kind.
fn measure_all(
    args: &BenchNetworkArgs,
    rt: &tokio::runtime::Runtime,
    repo_path: &Path,
    loaded: &[(String, Flight)],
    links: &[(String, Link)],
    servers: &[ServerKind],
    settings: &RunSettings,
) -> Result<Vec<Measured>> {
    let mut runs: Vec<Measured> = Vec::new();
    for (name, flight) in loaded {
        let csv = args.out.join("csv").join(format!("{name}_local.csv"));
        let m = measure::local(repo_path, flight, name, settings, &csv)
            .with_context(|| format!("{name}: the local run"))?;
        progress(&m);
        runs.push(m);
        for (profile, link) in links {
            for &server in servers {
                let csv = args
                    .out
                    .join("csv")
                    .join(format!("{name}_{profile}_{}.csv", server.slug()));
                let m = measure::remote(
                    rt, repo_path, profile, *link, server, flight, name, settings, &csv,
                )
                .with_context(|| format!("{name} over {profile} from {}", server.name()))?;
                progress(&m);
                runs.push(m);
            }
        }
    }
    Ok(runs)
}

/// One panel per flight and link profile: the screen error of the local run and of each server's.
fn screen_error_panels(
    loaded: &[(String, Flight)],
    links: &[(String, Link)],
    runs: &[Measured],
) -> Vec<plot::Panel> {
    loaded
        .iter()
        .flat_map(|(name, _)| {
            links.iter().map(move |(profile, _)| plot::Panel {
                title: format!("{name}, {profile}"),
                series: runs
                    .iter()
                    .filter(|m| &m.flight == name)
                    .filter(|m| match &m.route {
                        Route::Local => true,
                        Route::Remote { profile: p, .. } => p == profile,
                    })
                    .map(|m| plot::Series {
                        name: match &m.route {
                            Route::Local => "local file".into(),
                            Route::Remote { server, .. } => server.name().into(),
                        },
                        points: m.frames.iter().map(|f| (f.wall_s, f.error_px)).collect(),
                        stop_s: m.frames[m.flight_frames.saturating_sub(1)].wall_s,
                    })
                    .collect(),
            })
        })
        .collect()
}

/// What the report's header table shows besides the flags.
struct HeaderFacts<'a> {
    machine: &'a Machine,
    /// Load averages at the start and the end.
    load: (&'a str, &'a str),
    /// The repository, its records and its size in bytes.
    repo: (&'a Path, usize, u64),
    /// The want and prefetch limits in force.
    limits: (Option<usize>, Option<usize>),
    links: &'a [(String, Link)],
}

/// The report's title, the command and the header table (machine, repository, replay, links).
fn report_header(md: &mut String, args: &BenchNetworkArgs, c: &HeaderFacts) -> Result<()> {
    let (machine, (load_start, load_end)) = (c.machine, c.load);
    let (repo_path, records, file_len) = c.repo;
    let (want_limit, prefetch_limit) = c.limits;
    let command: Vec<String> = std::env::args().skip(1).collect();
    writeln!(md, "# Remote browsing over emulated links\n")?;
    writeln!(
        md,
        "Generated by `cbdam {}` on {}.\n",
        command.join(" "),
        machine.date
    )?;
    writeln!(md, "| | |\n|---|---|")?;
    writeln!(
        md,
        "| CPU | {} ({} logical cores) |",
        machine.cpu, machine.cores
    )?;
    writeln!(
        md,
        "| load average 1/5/15 min at start / end | {load_start} / {load_end} |"
    )?;
    writeln!(md, "| commit | {} |", machine.commit)?;
    writeln!(
        md,
        "| build profile | {} |",
        if cfg!(debug_assertions) {
            "debug assertions on (timings not representative)"
        } else {
            "release"
        }
    )?;
    writeln!(
        md,
        "| repository | {} ({records} records, {:.2} MB) |",
        repo_path.display(),
        file_len as f64 / 1e6
    )?;
    writeln!(
        md,
        "| replay | {}×{}, target {} px, budget {}, {} fps, paced in real time; up to {} s with \
         the camera still; prefetch {:?}, fetch order {:?}, want limit {:?}, prefetch limit {:?} |",
        args.size.0,
        args.size.1,
        args.pixel_error.value,
        budget_label(args.budget_ms.value),
        args.fps.value,
        args.max_settle_s,
        args.prefetch,
        args.fetch_order,
        want_limit,
        prefetch_limit
    )?;
    for (profile, link) in c.links {
        writeln!(md, "| link `{profile}` | {link} |")?;
    }
    writeln!(md)?;
    Ok(())
}

/// The report's note on method: what each column counts.
const METHOD: &str = "Every run is one process: `cbdam serve` and the `cbdam-link` proxy on a runtime of two \
           threads, the client's fetcher on its own, the refinement loop on this thread and its \
           decode workers — all on this machine's cores. *MB fetched*: record bodies received \
           (batch framing and retries included, and the requests the last frame left in \
           flight, which the bench waits for after the run: up to 5 s); for the local file, \
           record bytes its decode workers read from the map (a record decoded twice, read \
           twice). *MB used by the cuts*: the index's sizes of the \
           records of every diamond refined in any frame's cut. *MB over the link*: everything \
           the proxy delivered (HTTP heads, the repository head). Requests are the server's \
           count (`serve` runs also read the head with 2 range requests). *Camera stop → \
           target*: from the end of the last flight frame to the end of the first frame from \
           which on every frame met the target. *Frames over budget*: frames (flight and \
           settling) whose refinement took longer than the budget in wall time, and those whose \
           refining thread used more than the budget in CPU time (the rest is waiting for a core). *Final cut = local*: \
           the converged cut's refined diamonds are exactly the local run's.\n\n";

/// The note on what was received and no cut used, and on the lower bounds of settling.
const RECEIVED: &str = "*MB received*: distinct records received (record bytes); *received again*: records that came more than once, each repeat; *after the last frame*: records of the requests the last frame left in flight. *Unused, prefetched*: \
           of those, the records no cut of the run used whose last request was a prefetch; \
           *unused, wanted by the cut*: those no cut used that the view's cut had wanted; \
           *came after withdrawal*: of all unused, those whose request had been withdrawn when \
           they came. \
           *Final cut lacked at stop*: records of the final cut not received by the first frame \
           after the camera stopped; *lower bound*: that over the link's downstream rate — \
           no fetch order converges sooner; *any policy's bound*: the final cut's bytes beyond \
           what the link could deliver during the whole flight, over its rate — not even a \
           policy that knew the flight in advance converges sooner. Then the time from the stop until every frame's \
           largest screen error is within 1, 2 and 4 px.\n\n";

/// The plot of every run's largest screen error against wall time, a panel per flight and link.
fn plot_screen_error(
    args: &BenchNetworkArgs,
    loaded: &[(String, Flight)],
    links: &[(String, Link)],
    runs: &[Measured],
    plot_file: &str,
) -> Result<()> {
    let panels = screen_error_panels(loaded, links, runs);
    plot::screen_error(
        &args.out.join(plot_file),
        &format!(
            "largest screen error of the cut against wall time ({}×{}; target {} px dashed, \
             camera stop dotted)",
            args.size.0, args.size.1, args.pixel_error.value
        ),
        &panels,
        links.len(),
        args.pixel_error.value,
    )?;
    Ok(())
}

/// Writes network.md (the header, the notes and the tables `table` and `targets` of `runs`,
/// the plot) and network.json, and prints where the report is.
fn write_report(
    args: &BenchNetworkArgs,
    facts: &HeaderFacts,
    runs: &[Measured],
    (table, targets): (&str, &str),
    plot_file: &str,
) -> Result<()> {
    let mut md = String::new();
    report_header(&mut md, args, facts)?;
    md += METHOD;
    md += table;
    md += "\n## What was received and no cut used; the lower bound of settling\n\n";
    md += RECEIVED;
    md += &report::received_table(runs)?;
    md += "\n## The issue's targets (issue 21)\n\n";
    md += targets;
    md += "\n## Requests: the client's count and the server's\n\n";
    md += &report::wire_table(runs)?;
    writeln!(md, "\n![screen error against time]({plot_file})")?;
    let md_path = args.out.join("network.md");
    std::fs::write(&md_path, md).with_context(|| format!("writing {}", md_path.display()))?;
    std::fs::write(
        args.out.join("network.json"),
        serde_json::to_vec_pretty(&report::json(runs, args.budget_ms.value))?,
    )?;
    println!("{}", md_path.display());
    Ok(())
}

pub fn run(args: &BenchNetworkArgs) -> Result<()> {
    let links = links(args)?;
    let mut servers = args.servers.clone();
    servers.sort();
    servers.dedup();
    ensure!(
        !servers.is_empty(),
        "--servers must name serve, static or both"
    );
    let loaded = load_flights(args)?;
    for dir in ["csv", "plots"] {
        std::fs::create_dir_all(args.out.join(dir))
            .with_context(|| format!("creating {}", args.out.join(dir).display()))?;
    }
    let repo_path = repository(args, &args.out)?;
    let repo =
        Repository::open(&repo_path).with_context(|| format!("opening {}", repo_path.display()))?;
    let records = repo.head().entries().len();
    let file_len = repo.head().file_len();
    drop(repo);

    let (settings, want_limit, prefetch_limit) = run_settings(args)?;
    // The servers and proxies of the remote runs; the client has its own runtime (the
    // fetcher's), as in `cbdam replay`.
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_name("bench-net")
        .enable_all()
        .build()
        .context("starting the async runtime")?;

    let machine = Machine::probe();
    let load_start = load_average();
    eprintln!(
        "{}: {records} records, {:.2} MB; {} flights × (local + {} profiles × {} servers), \
         {}×{}, {} px, budget {}, {} fps, up to {} s settling, prefetch {:?}, fetch order {:?}, want limit {:?}, prefetch limit {:?}",
        repo_path.display(),
        file_len as f64 / 1e6,
        loaded.len(),
        links.len(),
        servers.len(),
        args.size.0,
        args.size.1,
        args.pixel_error.value,
        budget_label(args.budget_ms.value),
        args.fps.value,
        args.max_settle_s,
        args.prefetch,
        args.fetch_order,
        want_limit,
        prefetch_limit
    );
    let runs = measure_all(args, &rt, &repo_path, &loaded, &links, &servers, &settings)?;
    let load_end = load_average();

    let table = report::table(&runs, args.budget_ms.value)?;
    println!("{table}");
    let targets = report::targets(&runs)?;
    println!("{targets}");

    let plot_file = "plots/screen_error.svg";
    plot_screen_error(args, &loaded, &links, &runs, plot_file)?;

    let facts = HeaderFacts {
        machine: &machine,
        load: (&load_start, &load_end),
        repo: (&repo_path, records, file_len),
        limits: (want_limit, prefetch_limit),
        links: &links,
    };
    write_report(args, &facts, &runs, (&table, &targets), plot_file)?;
    Ok(())
}
