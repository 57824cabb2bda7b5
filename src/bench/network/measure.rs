//! One run of `cbdam bench network`: a flight replayed in real time against the local file, or
//! against a server behind a `cbdam-link` proxy, and what it measured.

use std::collections::{BTreeSet, HashMap, HashSet};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, anyhow};
use axum::http::StatusCode;
use cbdam_client::access::{DataSource, LocalSource, Received as Arrival, RemoteSource};
use cbdam_client::fetch::{FetchOptions, FetchStats};
use cbdam_client::flight::Flight;
use cbdam_client::refine::{FrameStats, RefineConfig, Refiner};
use cbdam_codec::geometry::DiamondId;
use cbdam_codec::repository::index::IndexEntry;
use cbdam_link::{Link, Proxy};
use cbdam_server::metrics::{Endpoint, Metrics};
use cbdam_server::{AppState, Config, RepoSpec};

use crate::replay::{ReplayPacing, fly_observed};

/// The name the repository is served under.
pub const REPO_NAME: &str = "bench";

/// Which server a remote run reads from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, clap::ValueEnum)]
pub enum ServerKind {
    /// `cbdam serve`'s batched endpoint (`POST …/diamonds`, up to 64 records a request).
    Serve,
    /// A static file server: `cbdam serve`'s raw file route (`GET …/file` with `Range`), which
    /// the client reads as it reads any `.cbdam` file on a static server: one range request per
    /// run of adjacent records, no batching.
    Static,
}

impl ServerKind {
    pub fn name(self) -> &'static str {
        match self {
            ServerKind::Serve => "serve (batched)",
            ServerKind::Static => "static (Range)",
        }
    }

    pub fn slug(self) -> &'static str {
        match self {
            ServerKind::Serve => "serve",
            ServerKind::Static => "static",
        }
    }
}

/// Where a run read the repository from.
#[derive(Clone, Debug, PartialEq)]
pub enum Route {
    /// The memory-mapped file (the reference: the cut the remote runs should converge to).
    Local,
    /// Over loopback through the emulated link.
    Remote {
        profile: String,
        link: Link,
        server: ServerKind,
    },
}

/// One frame as the bench keeps it.
#[derive(Clone, Copy, Debug)]
pub struct FramePoint {
    /// Seconds since the run's first frame began, when this frame ended.
    pub wall_s: f64,
    pub settling: bool,
    pub error_px: f64,
    pub met_target: bool,
    pub converged: bool,
    pub refine_ms: f64,
    /// CPU time of the refining thread in the frame, ms (NaN where unsupported).
    pub cpu_ms: f64,
}

/// What the server and the link saw during a remote run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Wire {
    /// HTTP requests the client sent (the head's included), cancelled and failed ones, and
    /// those still in flight when the run ended (after up to 5 s of waiting for them).
    pub client_requests: u64,
    pub client_in_flight: u64,
    pub client_cancelled: u64,
    pub client_errors: u64,
    /// Records of cancelled requests that were still wanted and asked for again.
    pub client_requeued: u64,
    /// Batch responses the server dropped unfinished (their client closed the connection),
    /// and the bytes of them it never wrote.
    pub server_aborted: u64,
    pub server_unsent_bytes: u64,
    /// Requests the server answered: batch POSTs (200) and range GETs of the file (206).
    pub server_batches: u64,
    pub server_ranges: u64,
    /// Any other request the server answered (anything else is unexpected).
    pub server_other: u64,
    /// Bytes the link delivered to the client (HTTP heads and the repository head included).
    pub link_bytes_down: u64,
    pub link_bytes_up: u64,
    pub connections: u64,
    pub resets: u64,
}

/// What a remote run received, against what its cuts used (record bytes, from the index; no
/// framing, no partial records of cancelled requests).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Received {
    /// Distinct records received.
    pub bytes: u64,
    /// Records received again after they had come once (each repeat counted).
    pub repeated: u64,
    /// Records received after the run's last frame (the requests it left in flight).
    pub after_last_frame: u64,
    /// Of those, records no cut used whose last request was a prefetch: what prefetching
    /// fetched that did not earn its bytes.
    pub prefetch_unused: u64,
    /// Records no cut used that the view's cut had wanted when last requested.
    pub other_unused: u64,
    /// Of `prefetch_unused + other_unused`, the records that came after their request was
    /// withdrawn (the view moved on while they were on their way).
    pub unused_after_withdrawal: u64,
    /// Records of the final cut.
    pub final_bytes: u64,
    /// Seconds after the stop that even a policy knowing the flight in advance needs: the
    /// final cut's bytes beyond what the link could deliver during the whole flight, over its
    /// rate.
    pub any_policy_bound_s: f64,
    /// Records of the final cut not yet received when the camera stopped (received by the
    /// first frame after the stop counts as received, so this errs low).
    pub final_missing_at_stop: u64,
    /// `final_missing_at_stop` over the link's downstream rate, seconds: no fetch order
    /// converges sooner after the camera stops (latency, framing and decoding only add to it).
    pub lower_bound_s: f64,
}

/// The measurements of one run.
#[derive(Clone, Debug)]
pub struct Measured {
    pub route: Route,
    pub flight: String,
    pub frames: Vec<FramePoint>,
    /// How many of `frames` are flight frames (the rest: settling, camera still).
    pub flight_frames: usize,
    /// Bytes of record bodies the client received (a remote source counts retries, the batch
    /// framing, and what the last frames left in flight).
    pub bytes_fetched: u64,
    /// Bytes of the records of every diamond that was ever refined in a cut of this run.
    pub bytes_used: u64,
    pub records_used: usize,
    /// The source ids of the records of every diamond ever refined.
    pub used_ids: HashSet<DiamondId>,
    /// The refined diamonds of the last frame.
    pub final_cut: BTreeSet<DiamondId>,
    /// Their source ids.
    pub final_sources: HashSet<DiamondId>,
    pub wire: Option<Wire>,
    /// Remote runs: what was received and what of it no cut used.
    pub received: Option<Received>,
    /// The per-frame CSV (`cbdam replay`'s columns).
    pub csv: PathBuf,
}

impl Measured {
    /// The run's wall time, seconds.
    pub fn wall_s(&self) -> f64 {
        self.frames.last().map_or(0.0, |f| f.wall_s)
    }

    /// Flight frames whose cut met the pixel target.
    pub fn flight_frames_at_target(&self) -> usize {
        self.frames[..self.flight_frames]
            .iter()
            .filter(|f| f.met_target)
            .count()
    }

    /// Seconds from the camera stopping (the end of the last flight frame) to the end of the
    /// first frame from which on every frame met the target: 0 if the last flight frame met it
    /// already, `None` if the last frame did not.
    pub fn stop_to_target_s(&self) -> Option<f64> {
        self.stop_to(|f| f.met_target)
    }

    /// [`Measured::stop_to_target_s`] for a looser target: the largest screen error at most
    /// `px` pixels.
    pub fn stop_to_px_s(&self, px: f64) -> Option<f64> {
        self.stop_to(|f| f.error_px <= px)
    }

    fn stop_to(&self, met: impl Fn(&FramePoint) -> bool) -> Option<f64> {
        let stop = self.frames.get(self.flight_frames.checked_sub(1)?)?.wall_s;
        let tail = &self.frames[self.flight_frames - 1..];
        if !met(tail.last()?) {
            return None;
        }
        let first_met = tail.iter().rposition(|f| !met(f)).map_or(0, |i| i + 1);
        Some(tail[first_met].wall_s - stop)
    }

    /// Whether the last frame's cut is the one the view converges to.
    pub fn converged(&self) -> bool {
        self.frames.last().is_some_and(|f| f.converged)
    }

    /// Frames (flight and settling) whose refinement took longer than `budget_ms` of wall time.
    pub fn frames_over_budget(&self, budget_ms: f64) -> usize {
        self.frames
            .iter()
            .filter(|f| budget_ms > 0.0 && f.refine_ms > budget_ms)
            .count()
    }

    /// Frames whose refining thread used more than `budget_ms` of CPU time: the overruns that
    /// are work, not the scheduler keeping the thread waiting on a busy machine.
    pub fn frames_over_budget_cpu(&self, budget_ms: f64) -> usize {
        self.frames
            .iter()
            .filter(|f| budget_ms > 0.0 && f.cpu_ms > budget_ms)
            .count()
    }

    pub fn max_refine_ms(&self) -> f64 {
        self.frames.iter().map(|f| f.refine_ms).fold(0.0, f64::max)
    }
}

/// How every run of a bench flies.
pub struct RunSettings {
    pub config: RefineConfig,
    pub pacing: ReplayPacing,
}

/// The bytes of the records of `ids` (source ids), from the index.
fn record_bytes(entries: &[IndexEntry], ids: &HashSet<DiamondId>) -> u64 {
    ids.iter()
        .filter_map(|id| entries.binary_search_by(|e| e.id.cmp(id)).ok())
        .map(|i| u64::from(entries[i].length))
        .sum()
}

/// Flies `flight` with `refiner`, paced in real time, keeping every frame and the set of
/// diamonds ever refined.
fn fly_and_collect<S: DataSource>(
    flight: &Flight,
    flight_name: &str,
    refiner: &mut Refiner<S>,
    settings: &RunSettings,
    csv: &Path,
    route: Route,
) -> Result<(Measured, FrameStats)> {
    let mut used: HashSet<DiamondId> = HashSet::new();
    let mut frames = Vec::new();
    let mut last = FrameStats::default();
    let start = Instant::now();
    let run = fly_observed(flight, refiner, &settings.pacing, csv, |r, s| {
        let wall_s = start.elapsed().as_secs_f64();
        used.extend(r.cut().refined_unordered().filter_map(|id| r.source_id(id)));
        frames.push(FramePoint {
            wall_s,
            settling: false,
            error_px: s.max_screen_error_px,
            met_target: s.met_target,
            converged: s.converged,
            refine_ms: s.refine_ms,
            cpu_ms: f64::NAN,
        });
        last = *s;
    })?;
    for f in &mut frames[run.flight_frames..] {
        f.settling = true;
    }
    for (f, cpu) in frames.iter_mut().zip(&run.cpu_ms) {
        f.cpu_ms = *cpu;
    }
    let entries = refiner.source().head().entries();
    let final_cut: BTreeSet<DiamondId> = refiner.cut().refined().collect();
    let final_sources = final_cut
        .iter()
        .filter_map(|&id| refiner.source_id(id))
        .collect();
    Ok((
        Measured {
            route,
            flight: flight_name.to_string(),
            flight_frames: run.flight_frames,
            frames,
            bytes_fetched: last.access.bytes_fetched,
            bytes_used: record_bytes(entries, &used),
            records_used: used.len(),
            used_ids: used,
            final_cut,
            final_sources,
            wire: None,
            received: None,
            csv: csv.to_path_buf(),
        },
        last,
    ))
}

/// The reference run on the local file (memory-mapped), paced as the remote runs are.
pub fn local(
    repo: &Path,
    flight: &Flight,
    flight_name: &str,
    settings: &RunSettings,
    csv: &Path,
) -> Result<Measured> {
    let source = LocalSource::open(repo).with_context(|| format!("opening {}", repo.display()))?;
    let mut refiner =
        Refiner::new(source, settings.config.clone()).context("starting the refiner")?;
    let (mut m, last) = fly_and_collect(
        flight,
        flight_name,
        &mut refiner,
        settings,
        csv,
        Route::Local,
    )?;
    // The local source counts the records it read; nothing crosses a network.
    m.bytes_fetched = last.access.bytes_fetched;
    Ok(m)
}

/// What a remote run received (`log`: record ids with the frame that collected them), split
/// by whether a cut used it and how it was last requested, and the lower bound of the time to
/// converge after the camera stops.
fn received(
    entries: &[IndexEntry],
    log: &[Arrival],
    prefetched: &HashSet<DiamondId>,
    m: &Measured,
    link: Link,
) -> Received {
    let all: HashSet<DiamondId> = log.iter().map(|a| a.id).collect();
    // Frame numbers start at 1: the first settling frame is flight_frames + 1, and what it
    // collected may have arrived before the stop.
    let by_stop: HashSet<DiamondId> = log
        .iter()
        .filter(|a| a.pump <= m.flight_frames as u64 + 1)
        .map(|a| a.id)
        .collect();
    // A record's last arrival decides (one can come twice: cancelled, then asked for again).
    let mut last_wanted: HashMap<DiamondId, bool> = HashMap::new();
    for a in log {
        last_wanted.insert(a.id, a.wanted);
    }
    let after_withdrawal: HashSet<DiamondId> = last_wanted
        .iter()
        .filter(|&(id, &wanted)| !wanted && !m.used_ids.contains(id))
        .map(|(&id, _)| id)
        .collect();
    let rate = link.down_bps as f64 / 8.0;
    let final_bytes = record_bytes(entries, &m.final_sources);
    let flight_s = m.frames[m.flight_frames.saturating_sub(1)].wall_s;
    let unused = |prefetch: bool| -> HashSet<DiamondId> {
        all.iter()
            .filter(|id| !m.used_ids.contains(id) && prefetched.contains(id) == prefetch)
            .copied()
            .collect()
    };
    let missing: HashSet<DiamondId> = m.final_sources.difference(&by_stop).copied().collect();
    let final_missing_at_stop = record_bytes(entries, &missing);
    let repeated: u64 = log
        .iter()
        .map(|a| record_bytes(entries, &HashSet::from([a.id])))
        .sum::<u64>()
        - record_bytes(entries, &all);
    let late: HashSet<DiamondId> = log
        .iter()
        .filter(|a| a.pump > m.frames.len() as u64)
        .map(|a| a.id)
        .collect();
    Received {
        bytes: record_bytes(entries, &all),
        repeated,
        after_last_frame: record_bytes(entries, &late),
        prefetch_unused: record_bytes(entries, &unused(true)),
        other_unused: record_bytes(entries, &unused(false)),
        unused_after_withdrawal: record_bytes(entries, &after_withdrawal),
        final_missing_at_stop,
        lower_bound_s: final_missing_at_stop as f64 / rate,
        final_bytes,
        any_policy_bound_s: (final_bytes as f64 - rate * flight_s).max(0.0) / rate,
    }
}

/// The network side of a remote run: `cbdam serve` on loopback and the shaping proxy in front
/// of it, on the bench's runtime.
struct Servers {
    state: AppState,
    proxy: Proxy,
    stop: tokio::sync::oneshot::Sender<()>,
    server: tokio::task::JoinHandle<Result<(), cbdam_server::ServerError>>,
}

async fn start_servers(repo: &Path, link: Link) -> Result<Servers> {
    let state = AppState::open(
        &[RepoSpec {
            name: REPO_NAME.into(),
            path: repo.to_path_buf(),
        }],
        Config::default(),
    )
    .with_context(|| format!("serving {}", repo.display()))?;
    let localhost: SocketAddr = "127.0.0.1:0".parse().expect("an address");
    let listener = tokio::net::TcpListener::bind(localhost).await?;
    let upstream = listener.local_addr()?;
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let server = tokio::spawn(cbdam_server::run(listener, state.clone(), async {
        let _ = stopped.await;
    }));
    let proxy = Proxy::start(localhost, upstream, link)
        .await
        .context("starting the link proxy")?;
    Ok(Servers {
        state,
        proxy,
        stop,
        server,
    })
}

/// The client's side of [`remote`]: `flight` replayed against `url`, then the requests the last
/// frames left in flight drained; the measurement and the fetcher's counters.
fn fly_remote(
    url: &str,
    (route, link): (Route, Link),
    flight: &Flight,
    flight_name: &str,
    settings: &RunSettings,
    csv: &Path,
) -> Result<(Measured, FetchStats)> {
    let mut source = RemoteSource::connect(url, FetchOptions::default())
        .with_context(|| format!("connecting to {url}"))?;
    source.log_received();
    let mut refiner =
        Refiner::new(source, settings.config.clone()).context("starting the refiner")?;
    refiner.track_prefetch_requests();
    let (m, _) = fly_and_collect(flight, flight_name, &mut refiner, settings, csv, route)?;
    // Let the requests the last frames left in flight (prefetches) finish, so that the
    // client's count and the server's describe the same requests; the fetcher starts no
    // more once what was wanted has arrived. Their bytes count as fetched: a viewer would
    // have fetched them too.
    let drain = Instant::now() + Duration::from_secs(5);
    while refiner.source().fetch_stats().in_flight > 0 && Instant::now() < drain {
        std::thread::sleep(Duration::from_millis(10));
    }
    // What the drain brought in, so that the log of received records holds it too.
    refiner.source_mut().pump();
    let f = refiner.source().fetch_stats();
    for e in refiner.errors() {
        eprintln!("  warning: {e}");
    }
    let prefetched: HashSet<DiamondId> = refiner.last_requested_as_prefetch().collect();
    let received = received(
        refiner.source().head().entries(),
        refiner.source().received(),
        &prefetched,
        &m,
        link,
    );
    // The refiner (and its fetcher) goes before the servers stop.
    Ok((
        Measured {
            received: Some(received),
            ..m
        },
        f,
    ))
}

/// Every request the server answered, whatever the endpoint and status.
fn answered_requests(metrics: &Metrics) -> u64 {
    // Every status the server counts on its own, and one it does not (418): those share the
    // `other` counter, which any such status reads.
    let all_statuses = [
        StatusCode::OK,
        StatusCode::NO_CONTENT,
        StatusCode::PARTIAL_CONTENT,
        StatusCode::NOT_MODIFIED,
        StatusCode::BAD_REQUEST,
        StatusCode::NOT_FOUND,
        StatusCode::METHOD_NOT_ALLOWED,
        StatusCode::REQUEST_TIMEOUT,
        StatusCode::PAYLOAD_TOO_LARGE,
        StatusCode::RANGE_NOT_SATISFIABLE,
        StatusCode::INTERNAL_SERVER_ERROR,
        StatusCode::SERVICE_UNAVAILABLE,
        StatusCode::IM_A_TEAPOT,
    ];
    [
        Endpoint::Repos,
        Endpoint::Meta,
        Endpoint::Diamond,
        Endpoint::Batch,
        Endpoint::File,
        Endpoint::Tiles,
        Endpoint::Other,
    ]
    .iter()
    .flat_map(|&e| all_statuses.iter().map(move |&s| metrics.requests(e, s)))
    .sum()
}

/// A run over the emulated `link` against `server`. The server and proxy are fresh for each
/// run, so their counters are the run's own.
#[allow(clippy::too_many_arguments)]
pub fn remote(
    rt: &tokio::runtime::Runtime,
    repo: &Path,
    profile: &str,
    link: Link,
    server: ServerKind,
    flight: &Flight,
    flight_name: &str,
    settings: &RunSettings,
    csv: &Path,
) -> Result<Measured> {
    let servers = rt.block_on(start_servers(repo, link))?;
    let route = Route::Remote {
        profile: profile.to_string(),
        link,
        server,
    };
    let base = format!("http://{}/v1/repos/{REPO_NAME}", servers.proxy.local_addr());
    let url = match server {
        ServerKind::Serve => base,
        ServerKind::Static => format!("{base}/file"),
    };
    let outcome = fly_remote(&url, (route, link), flight, flight_name, settings, csv);
    let Servers {
        state,
        proxy,
        stop,
        server: task,
    } = servers;
    let link_counters = rt.block_on(proxy.shutdown());
    let _ = stop.send(());
    rt.block_on(async { tokio::time::timeout(Duration::from_secs(10), task).await })
        .map_err(|_| anyhow!("the server did not stop within 10 s"))?
        .context("the server task failed")??;
    let (mut m, f) = outcome?;
    m.bytes_fetched = f.bytes;
    let metrics = state.metrics();
    let server_batches = metrics.requests(Endpoint::Batch, StatusCode::OK);
    let server_ranges = metrics.requests(Endpoint::File, StatusCode::PARTIAL_CONTENT);
    let answered = answered_requests(metrics);
    m.wire = Some(Wire {
        client_requests: f.requests,
        client_cancelled: f.cancelled,
        client_in_flight: f.in_flight,
        client_errors: f.errors,
        client_requeued: f.requeued,
        server_aborted: metrics.aborted_batches().0,
        server_unsent_bytes: metrics.aborted_batches().1,
        server_batches,
        server_ranges,
        server_other: answered - server_batches - server_ranges,
        link_bytes_down: link_counters.bytes_down,
        link_bytes_up: link_counters.bytes_up,
        connections: link_counters.connections,
        resets: link_counters.resets,
    });
    Ok(m)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frames(spec: &[(f64, bool)]) -> Vec<FramePoint> {
        spec.iter()
            .map(|&(wall_s, met)| FramePoint {
                wall_s,
                settling: false,
                error_px: if met { 0.5 } else { 3.0 },
                met_target: met,
                converged: false,
                refine_ms: 1.0,
                cpu_ms: 0.5,
            })
            .collect()
    }

    fn run(spec: &[(f64, bool)], flight_frames: usize) -> Measured {
        Measured {
            route: Route::Local,
            flight: "f".into(),
            frames: frames(spec),
            flight_frames,
            bytes_fetched: 0,
            bytes_used: 0,
            records_used: 0,
            used_ids: HashSet::new(),
            final_cut: BTreeSet::new(),
            final_sources: HashSet::new(),
            wire: None,
            received: None,
            csv: PathBuf::new(),
        }
    }

    #[test]
    fn seconds_from_the_camera_stopping_to_the_target() {
        // Camera stops at the end of frame 2 (1.0 s); met from the frame ending at 1.7 s on,
        // after a frame that met it once and lost it.
        let r = run(
            &[
                (0.5, true),
                (1.0, false),
                (1.2, true),
                (1.5, false),
                (1.7, true),
                (2.0, true),
            ],
            2,
        );
        assert!((r.stop_to_target_s().unwrap() - 0.7).abs() < 1e-12);
        assert_eq!(r.flight_frames_at_target(), 1);
        // Met at the stop already: 0.
        assert_eq!(
            run(&[(0.5, false), (1.0, true), (1.2, true)], 2).stop_to_target_s(),
            Some(0.0)
        );
        // Never met after the stop.
        assert_eq!(
            run(&[(0.5, true), (1.0, true), (1.2, false)], 2).stop_to_target_s(),
            None
        );
        assert_eq!(run(&[], 0).stop_to_target_s(), None);
    }

    #[test]
    fn frames_over_budget_count_wall_time_above_it() {
        let mut r = run(&[(0.1, true), (0.2, true), (0.3, true)], 3);
        r.frames[1].refine_ms = 2.5;
        r.frames[2].refine_ms = 2.0;
        r.frames[0].cpu_ms = 2.1;
        assert_eq!(r.frames_over_budget(2.0), 1);
        assert_eq!(r.frames_over_budget_cpu(2.0), 1);
        r.frames[0].cpu_ms = f64::NAN;
        assert_eq!(
            r.frames_over_budget_cpu(2.0),
            0,
            "unknown CPU time is not over"
        );
        assert_eq!(r.frames_over_budget(0.0), 0, "0 is an unlimited budget");
        assert_eq!(r.max_refine_ms(), 2.5);
    }

    #[test]
    fn record_bytes_sum_the_index_lengths_of_stored_ids() {
        let e = |l, x, y, length| IndexEntry {
            id: DiamondId::new(l, x, y),
            offset: 0,
            length,
            object_error: 0,
            min: 0,
            max: 0,
        };
        let entries = [e(1, 0, 0, 10), e(2, 1, 1, 20), e(3, 2, 2, 40)];
        let ids: HashSet<DiamondId> = [
            DiamondId::new(1, 0, 0),
            DiamondId::new(3, 2, 2),
            // Not stored: counts nothing.
            DiamondId::new(5, 0, 0),
        ]
        .into();
        assert_eq!(record_bytes(&entries, &ids), 50);
    }
}
