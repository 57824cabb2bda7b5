//! `cbdam replay`: the real refinement loop over a camera flight, one CSV row per frame.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{Context, Result};
use cbdam_client::access::DataSource;
use cbdam_client::flight::Flight;
use cbdam_client::refine::{DetailConfig, FrameStats, RefineConfig, Refiner};
use cbdam_client::stats::percentile;
use clap::Args;

use crate::flags;
use crate::session::{budget_label, terrain_source};

/// Run the client's refinement loop over a camera flight without drawing: one CSV row per
/// frame, then hold the camera still until the cut converges, and print a summary.
#[derive(Args, Debug)]
#[command(mut_arg("colour", |a| a.help(
    "Drape this colour repository (`cbdam build IMG --colour --like REPO`), file or URL, over \
     the terrain: its records are fetched and decoded with the elevation's"
)))]
pub struct ReplayArgs {
    /// Repository file, or the URL of one (`cbdam serve`'s repository URL or a .cbdam file on
    /// any server that honours Range).
    #[arg(value_name = "REPO_OR_URL")]
    pub(crate) repo: String,
    /// Flight file (JSON keyframes relative to the data's extent; see data/flights/).
    #[arg(long)]
    pub(crate) path: PathBuf,
    /// Viewport WIDTHxHEIGHT, pixels.
    #[arg(long, default_value = "1920x1080", value_parser = flags::Size2::pixels)]
    pub(crate) size: (u32, u32),
    #[command(flatten)]
    pub(crate) pixel_error: flags::PixelError,
    #[command(flatten)]
    pub(crate) budget_ms: flags::BudgetMs,
    /// Output CSV, one row per frame: frame, t, settling, refine_ms (wall), cpu_ms (CPU time of
    /// the refining thread), decode_ms (worker time), decoded,
    /// max_screen_error_px, met_target, converged, diamonds_in_cut, drawn_halves, triangles,
    /// refinements, coarsenings, budget_exhausted, bytes_fetched (cumulative), requests_issued
    /// (cumulative), requests_in_flight, failures, cut_bytes (decoded diamonds in the cut),
    /// memory_limited (a refinement waited for --cut-mib), then where refine_ms went, step by
    /// step: before_ms (arrivals, a moving view's collection, the refinement heap), loop_ms
    /// (the refinement loop), collect_ms (a collection after the loop), want_ms (choosing
    /// requests), after_ms (largest error, prefetch, posting requests), ahead_ms (planning the
    /// decoding ahead, last in the frame; the column comes before after_ms), and decode_cpu_ms
    /// (of decode_ms, the workers' CPU time: without what they waited for a core; Unix).
    #[arg(long)]
    pub(crate) out: PathBuf,
    #[command(flatten)]
    pub(crate) fps: flags::Fps,
    /// After the flight, at most this many frames with the camera still waiting for the cut to
    /// converge.
    #[arg(long, default_value_t = 600)]
    pub(crate) max_settle_frames: usize,
    /// Synthesise procedural detail past the finest stored level.
    #[arg(long)]
    pub(crate) detail: bool,
    #[command(flatten)]
    pub(crate) colour: flags::Colour,
    /// Memory for the cut's decoded diamonds, MiB (0: unlimited). At the limit a refinement
    /// goes ahead only by coarsening diamonds of smaller screen error elsewhere.
    #[arg(long, default_value_t = 1024)]
    pub(crate) cut_mib: usize,
    /// Pace the frames at --fps in real time on a local file too (a viewer's timing: the
    /// workers have the time between frames), not back to back.
    #[arg(long)]
    pub(crate) paced: bool,
    /// Do not decode ahead of the cut between frames (the loop before issue 21's pipelining;
    /// for comparisons).
    #[arg(long)]
    pub(crate) no_decode_ahead: bool,
}

/// The CSV header; `tests/cli.rs` checks it. Times in ms; `bytes_fetched` and
/// `requests_issued` are cumulative, the other counters per frame or current state.
pub const HEADER: &str = "frame,t,settling,refine_ms,cpu_ms,decode_ms,decoded,max_screen_error_px,\
met_target,converged,diamonds_in_cut,drawn_halves,triangles,refinements,coarsenings,\
budget_exhausted,bytes_fetched,requests_issued,requests_in_flight,failures,cut_bytes,memory_limited,\
before_ms,loop_ms,collect_ms,want_ms,ahead_ms,after_ms,decode_cpu_ms";

pub fn run(args: &ReplayArgs) -> Result<()> {
    let flight =
        Flight::load(&args.path).with_context(|| format!("loading {}", args.path.display()))?;
    let config = RefineConfig {
        pixel_error: args.pixel_error.value,
        budget: (args.budget_ms.value > 0.0)
            .then(|| Duration::from_secs_f64(args.budget_ms.value / 1e3)),
        detail: args.detail.then(DetailConfig::default),
        cut_bytes: match args.cut_mib {
            0 => None,
            m => Some(m.checked_mul(1 << 20).context("--cut-mib is too large")?),
        },
        decode_ahead: !args.no_decode_ahead,
        ..RefineConfig::default()
    };
    let (source, remote) = terrain_source(&args.repo, args.colour.value.as_deref())?;
    let refiner = Refiner::new(source, config).context("starting the refiner")?;
    // Over a network, frames are paced at --fps so that fetches take the time they would take
    // in a viewer; locally nothing waits on I/O and frames run back to back.
    replay(args, &flight, refiner, remote || args.paced)
}

fn replay<S: DataSource>(
    args: &ReplayArgs,
    flight: &Flight,
    mut refiner: Refiner<S>,
    paced: bool,
) -> Result<()> {
    let pacing = ReplayPacing {
        fps: args.fps.value,
        size: args.size,
        max_settle_frames: args.max_settle_frames,
        paced,
    };
    let run = fly(flight, &mut refiner, &pacing, &args.out)?;
    print_summary(args, &run);
    for e in refiner.errors() {
        eprintln!("cbdam: warning: {e}");
    }
    Ok(())
}

/// What one replay measured: the per-frame statistics and the refining thread's CPU time per
/// frame, split at the end of the flight (the rest are the settling frames).
pub struct ReplayRun {
    /// Every frame, flight then settling.
    pub rows: Vec<FrameStats>,
    /// CPU ms of the refining thread, one per row.
    pub cpu_ms: Vec<f64>,
    /// How many of `rows` are flight frames.
    pub flight_frames: usize,
    /// Settling frames until the cut converged; `None` if it did not within the limit.
    pub converged_after: Option<u64>,
    /// Wall seconds from the end of the last flight frame (the camera stopping) to the end of
    /// the frame that converged; `None` if it did not.
    pub converged_after_s: Option<f64>,
    /// Wall seconds from the camera stopping to the end of the first frame from which on every
    /// frame met the target; `None` if the last frame did not.
    pub met_target_after_s: Option<f64>,
    /// The flight's duration, seconds.
    pub duration_s: f64,
    /// Grid intervals per diamond side (N − 1), to turn decoded diamonds into cells.
    pub cells_per_side: usize,
}

impl ReplayRun {
    /// The flight frames (no settling).
    pub fn flight(&self) -> &[FrameStats] {
        &self.rows[..self.flight_frames]
    }

    /// Sorted CPU ms of the flight frames.
    pub fn flight_cpu_sorted(&self) -> Vec<f64> {
        let mut cpu = self.cpu_ms[..self.flight_frames].to_vec();
        cpu.sort_by(f64::total_cmp);
        cpu
    }

    /// Sorted triangles per flight frame.
    pub fn flight_triangles_sorted(&self) -> Vec<u64> {
        let mut tris: Vec<u64> = self.flight().iter().map(|s| s.triangles).collect();
        tris.sort_unstable();
        tris
    }

    /// Bytes fetched by the end of the flight (before settling).
    pub fn flight_bytes(&self) -> u64 {
        self.flight().last().map_or(0, |s| s.access.bytes_fetched)
    }

    /// The last frame: the converged state when `converged_after` is `Some`.
    pub fn last(&self) -> &FrameStats {
        self.rows.last().expect("a replay has at least one frame")
    }
}

/// How a replay runs: frame rate, viewport, settling limit, and whether frames wait for wall
/// time (over a network, so that fetches take the time they would in a viewer).
pub struct ReplayPacing {
    pub fps: f64,
    pub size: (u32, u32),
    pub max_settle_frames: usize,
    pub paced: bool,
}

/// Runs `flight`, then up to `max_settle_frames` settling frames with the camera still,
/// writing one CSV row per frame to `csv_path`.
pub fn fly<S: DataSource>(
    flight: &Flight,
    refiner: &mut Refiner<S>,
    pacing: &ReplayPacing,
    csv_path: &Path,
) -> Result<ReplayRun> {
    fly_observed(flight, refiner, pacing, csv_path, |_, _| {})
}

/// One CSV row ([`HEADER`]) of the frame `s`, at flight time `t`, with the refining thread's
/// CPU time `cpu_ms`.
fn write_row(
    csv: &mut impl Write,
    s: &FrameStats,
    t: f64,
    settling: bool,
    cpu_ms: f64,
) -> std::io::Result<()> {
    writeln!(
        csv,
        "{},{:.4},{},{:.4},{:.4},{:.4},{},{:.4},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4}",
        s.frame,
        t,
        u8::from(settling),
        s.refine_ms,
        cpu_ms,
        s.decode_ms,
        s.decoded,
        s.max_screen_error_px,
        u8::from(s.met_target),
        u8::from(s.converged),
        s.refined,
        s.drawn_halves,
        s.triangles,
        s.refinements,
        s.coarsenings,
        u8::from(s.budget_exhausted),
        s.access.bytes_fetched,
        s.access.requests_issued,
        s.access.in_flight,
        s.failures,
        s.cut_bytes,
        u8::from(s.memory_limited),
        s.steps.before_ms,
        s.steps.loop_ms,
        s.steps.collect_ms,
        s.steps.want_ms,
        s.steps.ahead_ms,
        s.steps.after_ms,
        s.decode_cpu_ms,
    )
}

/// [`fly`], calling `observe` after every frame with the refiner (its cut, its source) and the
/// frame's statistics; what `observe` spends is outside the frame's timings.
pub fn fly_observed<S: DataSource>(
    flight: &Flight,
    refiner: &mut Refiner<S>,
    pacing: &ReplayPacing,
    csv_path: &Path,
    mut observe: impl FnMut(&Refiner<S>, &FrameStats),
) -> Result<ReplayRun> {
    let world = *refiner.world();
    let start = std::time::Instant::now();

    let file = std::fs::File::create(csv_path)
        .with_context(|| format!("creating {}", csv_path.display()))?;
    let mut csv = std::io::BufWriter::new(file);
    writeln!(csv, "{HEADER}")?;

    let flight_frames = (flight.duration() * pacing.fps).ceil() as u64 + 1;
    let mut rows: Vec<FrameStats> = Vec::new();
    let mut cpu_rows: Vec<f64> = Vec::new();
    let mut converged_after = None;
    let mut converged_after_s = None;
    // Wall time at the end of the last flight frame, and of the first frame of the current run
    // of frames at target.
    let mut stopped_at: Option<f64> = None;
    let mut met_since: Option<f64> = None;
    let mut frame = 0u64;
    loop {
        let settling = frame >= flight_frames;
        if settling && frame - flight_frames >= pacing.max_settle_frames as u64 {
            break;
        }
        let t = (frame as f64 / pacing.fps).min(flight.duration());
        if pacing.paced {
            let due = Duration::from_secs_f64(frame as f64 / pacing.fps);
            std::thread::sleep(due.saturating_sub(start.elapsed()));
        }
        let camera = flight.camera(&world, t, pacing.size);
        let cpu = thread_cpu_seconds();
        let s = refiner.frame(&camera);
        let cpu_ms = (thread_cpu_seconds() - cpu) * 1e3;
        write_row(&mut csv, &s, t, settling, cpu_ms)?;
        let now = start.elapsed().as_secs_f64();
        if !settling && frame + 1 == flight_frames {
            stopped_at = Some(now);
        }
        met_since = match (s.met_target, met_since) {
            (false, _) => None,
            (true, None) => Some(now),
            (true, kept) => kept,
        };
        observe(refiner, &s);
        rows.push(s);
        cpu_rows.push(cpu_ms);
        frame += 1;
        if settling && s.converged {
            converged_after = Some(frame - flight_frames);
            converged_after_s = stopped_at.map(|t0| now - t0);
            break;
        }
    }
    csv.flush()?;
    Ok(ReplayRun {
        flight_frames: rows.len().min(flight_frames as usize),
        rows,
        cpu_ms: cpu_rows,
        converged_after,
        converged_after_s,
        met_target_after_s: stopped_at.zip(met_since).map(|(t0, t)| (t - t0).max(0.0)),
        duration_s: flight.duration(),
        cells_per_side: refiner.layout().n() - 1,
    })
}

/// The summary's decoding lines: diamonds and cells per second (wall and the workers' CPU time)
/// and the decoding done ahead of the cut; nothing when nothing was decoded.
fn print_decoding(run: &ReplayRun) {
    let decoded: usize = run.rows.iter().map(|s| s.decoded).sum();
    let decode_s: f64 = run.rows.iter().map(|s| s.decode_ms).sum::<f64>() / 1e3;
    let decode_cpu_s: f64 = run.rows.iter().map(|s| s.decode_cpu_ms).sum::<f64>() / 1e3;
    let n1 = run.cells_per_side as f64;
    if decode_s <= 0.0 {
        return;
    }
    println!(
        "decoding: {decoded} diamonds in {:.1} ms, {:.0} diamonds/s, {:.1} M cells/s",
        decode_s * 1e3,
        decoded as f64 / decode_s,
        decoded as f64 * n1 * n1 / decode_s / 1e6
    );
    if decode_cpu_s > 0.0 {
        // The wall time above holds what the workers waited for a core; their CPU time
        // is what a diamond costs.
        println!(
            "decoding, workers' CPU time: {:.1} ms, {:.1} M cells/s",
            decode_cpu_s * 1e3,
            decoded as f64 * n1 * n1 / decode_cpu_s / 1e6
        );
    }
    let ahead: usize = run.rows.iter().map(|s| s.decoded_ahead).sum();
    let used: usize = run.rows.iter().map(|s| s.refined_ahead).sum();
    let refinements: usize = run.rows.iter().map(|s| s.refinements).sum();
    println!(
        "decoded ahead of the cut: {ahead} diamonds, {used} of them refined since; {refinements} refinements in all"
    );
    let rescued = cbdam_client::spawn::DecodePool::rescued();
    if rescued > 0 {
        println!(
            "decode workers starved (another program's load): the standby pool ran {rescued} jobs"
        );
    }
}

/// Prints the summary of `cbdam replay`.
fn print_summary(args: &ReplayArgs, run: &ReplayRun) {
    let flight_rows = run.flight();
    let mut ms: Vec<f64> = flight_rows.iter().map(|s| s.refine_ms).collect();
    ms.sort_by(f64::total_cmp);
    let cpu = run.flight_cpu_sorted();
    let tris = run.flight_triangles_sorted();
    let pixels = f64::from(args.size.0) * f64::from(args.size.1);
    let last = run.last();
    let over = flight_rows.iter().filter(|s| s.budget_exhausted).count();
    let memory_limited = run.rows.iter().filter(|s| s.memory_limited).count();
    println!(
        "flight: {} frames at {} fps ({:.1} s), {}×{}, target {} px, budget {}",
        flight_rows.len(),
        args.fps.value,
        run.duration_s,
        args.size.0,
        args.size.1,
        args.pixel_error.value,
        budget_label(args.budget_ms.value)
    );
    println!(
        "refine ms per frame, wall: median {:.3}, p99 {:.3}, max {:.3}; budget exhausted in {over} frames",
        percentile(&ms, 0.5),
        percentile(&ms, 0.99),
        ms.last().copied().unwrap_or(0.0)
    );
    println!(
        "refine ms per frame, CPU of the calling thread: median {:.3}, p99 {:.3}, max {:.3}",
        percentile(&cpu, 0.5),
        percentile(&cpu, 0.99),
        cpu.last().copied().unwrap_or(0.0)
    );
    println!(
        "triangles per frame: median {}, max {} ({:.2} per pixel at the median)",
        percentile(&tris, 0.5),
        tris.last().copied().unwrap_or(0),
        percentile(&tris, 0.5) as f64 / pixels
    );
    print_decoding(run);
    let flight_bytes = run.flight_bytes();
    println!(
        "fetched: {} bytes during the flight ({:.0} bytes per second of flight), {} in all, {} failures",
        flight_bytes,
        flight_bytes as f64 / run.duration_s.max(1e-9),
        last.access.bytes_fetched,
        last.failures
    );
    match run.converged_after {
        Some(n) => println!(
            "converged {n} frames ({:.3} s wall; target met after {:.3} s) after the flight: {} diamonds refined, {} triangles, max error {:.3} px",
            run.converged_after_s.unwrap_or(f64::NAN),
            run.met_target_after_s.unwrap_or(f64::NAN),
            last.refined,
            last.triangles,
            last.max_screen_error_px
        ),
        None => println!(
            "not converged within {} frames after the flight (max error {:.3} px{})",
            args.max_settle_frames,
            last.max_screen_error_px,
            match run.met_target_after_s {
                Some(t) => format!("; target met after {t:.3} s wall"),
                None => String::new(),
            }
        ),
    }
    if memory_limited > 0 {
        println!(
            "the cut's memory limit (--cut-mib {}) held refinement back in {memory_limited} frames; \
             cut now {:.1} MiB",
            args.cut_mib,
            last.cut_bytes as f64 / f64::from(1u32 << 20)
        );
    }
}

/// CPU time of the calling thread, seconds: what the loop costs the render thread, without
/// the time the shared machine's scheduler keeps it waiting. NaN where unsupported.
fn thread_cpu_seconds() -> f64 {
    cbdam_client::stats::thread_cpu_seconds().unwrap_or(f64::NAN)
}
