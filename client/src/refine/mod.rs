//! Time-critical dual-queue refinement (paper §6) over a [`Cut`].
//!
//! Every frame [`Refiner::frame`] rebuilds a refinement heap from the cut's drawn diamonds and
//! the camera, ordered by screen-space error, and refines from the top until every drawn
//! diamond in the frustum meets the pixel target or the frame's time budget is spent. Refining a
//! diamond first forces its unrefined parents. Only diamonds whose record is in RAM are refined;
//! missing ones are requested from the [`DataSource`] with their screen error as priority and
//! never waited for. Decoding runs on the [`Spawner`]'s workers (on the desktop a rayon pool below
//! the frame thread's priority; a page's Web Workers, the jobs sent as bytes: `job.rs`, `wire.rs`):
//! the frame dispatches the most urgent ready refinements, applies results as they come back while
//! budget remains, and leaves the rest running; what finishes after the deadline is applied at the
//! start of the next frame, so a slow decode never stretches a frame. **Between frames the workers
//! keep decoding** (issue 21's pipelined decoder): at the end of each frame, jobs sized to last
//! until the next one take the diamonds the view still needs, most urgent first, as far down as
//! their parents' data exists (decoded, not necessarily refined); their results wait in the decoded
//! cache and a later frame refines them without waiting, within its budget. Coarsening is garbage
//! collection: every few frames (first in the frame while the view moves; while it is still,
//! after a loop that refined all it could), refined diamonds with no refined child that the view
//! no longer needs are undone, least needed first, and their decoded data moves to an LRU cache
//! so that refining them again is free (what the cache evicts is freed by a worker).
//!
//! **A frame's cost follows what changes, not the size of the cut.** The refinement candidates
//! (diamonds with a drawn half), the coarsening candidates (refined diamonds with no refined
//! child) and the drawn half-patches are kept up to date on every refinement and coarsening, each
//! with its saturated metric at hand, so no frame walks the cut or looks diamonds up in the
//! repository's index: what remains per frame is one screen error per candidate (a box test and a
//! distance), for the heaps and the frame's figures. A still view skips even that for its
//! refinement heap: the last frame's leftovers are still exact (see `KeptHeap`). A source that
//! always has every record at hand (a local repository) makes the passes that look for records to
//! request unnecessary; they are skipped.
//!
//! **The error metric is made monotone** so that the cut the loop converges to is unique (it does
//! not depend on latency or on the order of past frames): a diamond's error is its stored
//! object-space error (metres) times [`Camera::pixels_per_metre`] at the distance from the eye
//! to its *saturated* bounding box — the union of its own box and its stored descendants' — and
//! its object error is saturated the same way. A child's box and error are then contained in its
//! parents', so a diamond that needs refining has parents that need it too; the converged cut is
//! exactly the set of stored diamonds whose saturated error exceeds the target and whose
//! saturated box meets the frustum. The saturated box is larger than the diamond (its
//! descendants spill into its neighbours), which makes the metric conservative: the target also
//! holds for the plain per-diamond boxes.

mod cache;
mod detail;
mod drawn;
mod job;
mod node;
mod state;
mod wire;

pub use cache::LruCache;
pub use detail::DetailConfig;
use drawn::DrawnList;
pub use job::{DecodeJob, Done};
use job::{Source, root_colour};
use node::{Info, Node};
use state::{CutState, Requests, Residency};
pub use wire::{HeadBytes, WorkerDecoder};

use std::collections::BinaryHeap;
use std::sync::Arc;
use std::time::Duration;

use cbdam_codec::CodecError;
use cbdam_codec::geometry::{Cut, DiamondId, Domain, Half, IdMap, IdSet, Layout};
use cbdam_codec::hierarchy::Decoder;
use glam::DVec3;
use std::sync::mpsc::{Receiver, Sender};
use web_time::Instant;

use crate::access::{AccessStats, DataSource, Drape, Priority};
use crate::camera::{Camera, Frustum};
use crate::horizon::Horizon;
use crate::patch::{HalfPatch, packed};
use crate::spawn::{DefaultSpawner, Spawner};
use crate::world::{World, exaggerated};

/// Per frame, the remembered overrun past the deadline shrinks by this factor unless a new one
/// is larger: about 34 frames to halve, so a slow tail is remembered for about a second of
/// frames and a rare one (a pre-empted thread) is still forgotten. (At 0.9, 7 frames to halve,
/// a tail was forgotten before the next as long one came.)
const OVERRUN_DECAY: f64 = 0.98;
/// The deadline holds back the remembered overrun times this: frames differ in what their
/// tails find to do (diamonds to decode ahead, candidates to look at), by about this much in
/// traces of `low_pass` (1920×1080, 2 ms).
const OVERRUN_SPREAD: f64 = 1.3;
/// What the overrun memory starts from (a fraction of the budget) before a frame has measured
/// one: the first frame, which starts the decode workers, otherwise always runs past the
/// budget.
const OVERRUN_PRIOR: u32 = 8;
/// At most the budget over this is held back for the tail. A frame whose steps around the loop
/// cost more than the budget allows (a viewer's frames, paced, start with cold caches: about
/// 0.8 ms of a 2 ms budget on `low_pass`) needs half; a quarter left 150 of 390 paced frames
/// over the budget.
const OVERRUN_CAP: u32 = 2;
/// Prefetched diamonds are requested with their error scaled by this, so that they never
/// overtake what the current view needs.
const PREFETCH_PRIORITY: f64 = 1.0 / 16.0;
/// Prefetching stops this fraction of the budget before its end: posting the requests and
/// handing the workers their jobs come after it.
const PREFETCH_RESERVE: u32 = 8;
/// Prefetching looks at the clock once per this many candidates whose screen errors it
/// computes, and once per this many plans.
const PREFETCH_CLOCK_STRIDE: usize = 32;
/// Fewest and most diamonds one speculative decode job refines, parents before children. In
/// between, a job is sized to keep its worker busy until the next frame (the interval between
/// frames over the time a decode takes, both smoothed), so that a job still running does not
/// hold up the next frame's urgent decodes for long.
const SPECULATIVE_STEPS: std::ops::RangeInclusive<usize> = 4..=128;
/// Decoding ahead stops looking after this many diamonds it could not take (records not at
/// hand, parents not decoded, jobs full). Over a network most are missing records: on dsl10
/// `descent` the look went through up to 3 400 of them, 1.5 ms of a 2 ms frame, for nothing;
/// a local paced `low_pass` passed over at most 421 (0.75 ms), so this bound leaves it whole.
const SPECULATION_MISSES: usize = 512;
/// Decoding ahead, last in its frame, plans until this fraction of the budget before its end:
/// handing the jobs to the workers comes after (dsl10 `low_pass`, static server, planning up
/// to the budget's very end: 101 of 1 618 frames ended 0–0.05 ms over 2 ms).
const AHEAD_RESERVE: u32 = 16;
/// Between paced frames that decode ahead, at least the budget over this is held back from the
/// refinement loop for the frame's tail, whatever the tails measured (see `Refiner::overrun`).
/// Without it a loop that spent its budget waiting for the decodes it had dispatched left
/// decoding ahead no time to plan, so the next loop found nothing decoded and waited again
/// (14–36 refinements a frame, for 25–35 frames): a cold start at `low_pass`'s last view
/// (1920×1080, 2 ms, paced) settled in 24–58 frames (12 runs; 3 over 40), with this in 21–32.
const AHEAD_SHARE: u32 = 4;
/// Most diamonds decoded ahead of the cut and not yet refined (in the decoded cache or being
/// decoded): a few frames' worth of refinements (a frame applies about a hundred within a
/// 2 ms budget), so that a moving view does not have the workers decode far more than the cut
/// can take before the view moves on (about 34 MB of nodes at N = 65).
const AHEAD_LIMIT: usize = 256;
/// With [`RefineConfig::want_limit`], the cut asks for the records of as many candidates as
/// the loop refines in this long. Records asked for further ahead arrive for a cut the moving
/// view has left: at 1 s the batched server's runs on dsl10 fetched 1.17–1.23× the bytes their
/// cuts used (`cbdam bench network`, 8193² synthetic, 4 runs of each flight), at 0.4 s
/// 1.10–1.13× (4 runs each), converging as fast (`low_pass` 1.03–1.43 s against 1.13–1.50 s)
/// and with fewer frames over budget (the want list and its requests are shorter). The cost:
/// static Range requests' `low_pass` reached 1 px in 1.70–1.87 s against 1.47–1.53 s (2 runs
/// each; docs/REFINEMENT.md, "The frame").
pub const WANT_HORIZON_S: f64 = 0.4;
/// Weight of the newest sample in the smoothed frame interval and decode time.
const SMOOTHING: f64 = 0.1;
/// Decoding ahead runs on every worker (when they yield to the frame thread) only while frames
/// come at least this many budgets apart: a viewer's paced frames, not frames run back to back.
/// Back to back, a speculative job on every worker holds up the decodes the next frame
/// dispatches and waits for (`low_pass` back to back, 1920×1080, 2 ms, 2 cores: wall p99
/// 2.19–2.53 ms with two jobs against 1.99–2.18 with one).
const PACED_BUDGETS: f64 = 4.0;
/// Fewest diamonds a garbage collection coarsens in a frame before it looks at the clock
/// (about 8 µs each at N = 65): a collection always advances, even in a frame whose
/// budget is already spent.
pub const GC_MIN_COARSENINGS: usize = 16;
/// A frame looks at up to this many candidates past its deadline for one refinement it can
/// start, when it has started none (see `refine_until`); decoding ahead, past its end, misses
/// up to this many a free worker before it gives up finding each a job (over a network most
/// lack their records, and before this bound it could go on through `SPECULATION_MISSES` of
/// them: one frame of a dsl10 bench planned for 2.1 ms, on its core, and ended at 3.4 ms).
const LEAST_LOOKS: usize = 8;
/// While the view moves, a collection runs first in its frame, for at most the budget over this
/// (after its least, [`GC_MIN_COARSENINGS`]). Run after the refinement loop it got what the
/// loop left, which in a viewer's paced frames was nothing: 16 a frame, fewer than the moving
/// view left behind. An unfinished collection also goes on after the loop when the loop leaves
/// at least this share of the budget.
const GC_SHARE: u32 = 4;

/// Settings of the refinement loop.
#[derive(Clone, Debug)]
pub struct RefineConfig {
    /// Target screen-space error, pixels.
    pub pixel_error: f64,
    /// Time budget per frame; `None` refines until the cut is locally optimal.
    pub budget: Option<Duration>,
    /// Garbage-collect (coarsen) every this many frames. With a budget, a collection runs first
    /// in its frame for at most a quarter of the budget while the view moves; while it is still,
    /// after a refinement loop that refined all it could (it waits while the budget ends with
    /// refinements left); at least [`GC_MIN_COARSENINGS`] either way, more when the loop leaves
    /// time; and it goes on in the next frames until it has coarsened everything it found.
    pub gc_interval: u32,
    /// When to prefetch (see [`Prefetch`]).
    pub prefetch: Prefetch,
    /// Most records a frame prefetches (the most urgent; `None`: no limit): what the last
    /// frames leave in flight when the view stops needing them is at most this many records.
    /// With a budget, prefetching stops an eighth of the budget before its end; a frame it
    /// cuts short keeps the last frame's prefetches that are still on their way.
    pub prefetch_limit: Option<usize>,
    /// The order in which missing records are asked for (see [`FetchOrder`]).
    pub fetch_order: FetchOrder,
    /// Ask only for the records of the most urgent of the cut's candidates that the frame's
    /// budget did not reach: as many as the loop refined in the last [`WANT_HORIZON_S`]
    /// (smoothed), and at least this many (`None`: all of them), and for those already
    /// requested. A source faster than the refinement otherwise delivers records that wait in
    /// RAM until the view has moved on.
    pub want_limit: Option<usize>,
    /// Prefetch what a frustum enlarged by this fraction of the eye–target distance sees.
    pub prefetch_margin: f64,
    /// Prefetch where the eye will be this many frames ahead at its current velocity.
    pub lookahead_frames: f64,
    /// Bytes of decoded diamonds kept after they are coarsened (and decoded ahead): a view
    /// that comes back over ground evicted from it decodes that ground again.
    pub decoded_cache_bytes: usize,
    /// Bytes of compressed records kept in RAM.
    pub record_cache_bytes: usize,
    /// Bytes the cut's decoded diamonds may take (refined and being decoded); `None` for no
    /// limit. At the limit the loop is the paper's dual queue: a refinement goes ahead only by
    /// coarsening refined leaves of smaller screen error, so the cut degrades coarser where it
    /// matters least; if none is smaller, the refinement waits and the frame reports
    /// `memory_limited`.
    pub cut_bytes: Option<usize>,
    /// A diamond whose record fails this many times is given up on (never refined).
    pub max_failures: u32,
    /// Synthesise detail past the finest stored level (off by default).
    pub detail: Option<DetailConfig>,
    /// Vertical exaggeration: heights (and so boxes and object-space errors) are scaled by
    /// this, as [`exaggerated`] scales the renderer's world. 1 by default.
    pub exaggeration: f64,
    /// Between frames, keep the workers decoding what the view still needs, ahead of the cut
    /// (on by default; only with a spawner whose jobs run in the background).
    pub decode_ahead: bool,
}

impl Default for RefineConfig {
    fn default() -> Self {
        Self {
            pixel_error: 1.0,
            budget: Some(Duration::from_millis(2)),
            gc_interval: 8,
            prefetch: Prefetch::WhenIdle,
            prefetch_limit: Some(32),
            fetch_order: FetchOrder::ScreenError,
            want_limit: Some(128),
            prefetch_margin: 0.25,
            lookahead_frames: 15.0,
            decoded_cache_bytes: 256 << 20,
            record_cache_bytes: 64 << 20,
            // About 8 000 diamonds at N = 65: far above what a 4K view needs at 1 px.
            cut_bytes: Some(1 << 30),
            max_failures: 3,
            detail: None,
            exaggeration: 1.0,
            decode_ahead: true,
        }
    }
}

/// When the refiner asks a remote source for records the current view does not need yet (the
/// children of diamonds it will refine next, what the camera is about to see).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Prefetch {
    /// Never.
    Off,
    /// Every frame, at a lower priority than what the view needs (both share the link: the
    /// fetcher sends the most urgent first but keeps the link full with prefetches).
    Always,
    /// Only in frames where the view's cut wants no record that it lacks (none queued, none in
    /// flight): prefetches use the link only while it would idle, and the first frame that
    /// wants a record again withdraws them, which cancels their requests in flight.
    #[default]
    WhenIdle,
}

impl Prefetch {
    /// Whether a frame whose cut still lacks `cut_wants` records prefetches.
    pub fn allows(self, cut_wants: usize) -> bool {
        match self {
            Prefetch::Off => false,
            Prefetch::Always => true,
            Prefetch::WhenIdle => cut_wants == 0,
        }
    }
}

/// The priority a remote source gets for the records a refinement lacks (all of them, parents
/// and the diamond, get the same; the source fetches the highest first).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum FetchOrder {
    /// The diamond's screen error, pixels: the worst error first.
    #[default]
    ScreenError,
    /// The screen error over the kilobytes of the records still missing: the most error
    /// removed per byte of the link first, so that on a slow link the largest screen error
    /// falls fastest.
    ScreenErrorPerByte,
}

/// What one frame did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FrameStats {
    /// Frame number, from 1.
    pub frame: u64,
    /// Wall time of the frame on the calling thread, ms: pump, heaps, dispatching, waiting for
    /// decodes while budget remains, coarsening.
    pub refine_ms: f64,
    /// Worker time spent decoding the refinements that came back this frame, ms.
    pub decode_ms: f64,
    /// Of `decode_ms`, the workers' CPU time where the platform measures it (Unix; 0
    /// elsewhere): without the time they waited for a core.
    pub decode_cpu_ms: f64,
    /// Diamonds decoded that came back this frame (refinements served from the cache do not
    /// count).
    pub decoded: usize,
    /// Largest screen-space error, pixels, of a drawn diamond in the frustum that could still
    /// be refined (stored, or synthetic with detail synthesis on; neither it nor a parent it
    /// needs given up on); 0 if none. Without detail synthesis, the finest level's own error
    /// (the data's resolution) does not count: nothing can reduce it.
    pub max_screen_error_px: f64,
    /// `max_screen_error_px` is within the target.
    pub met_target: bool,
    /// Met the target and nothing is left to coarsen: the cut is the one this view converges to.
    pub converged: bool,
    /// Refined diamonds in the cut.
    pub refined: usize,
    /// Half-patches drawn.
    pub drawn_halves: usize,
    /// Triangles drawn.
    pub triangles: u64,
    /// Refinements this frame.
    pub refinements: usize,
    /// Of `decoded`, the diamonds decoded ahead of the cut (speculatively, between frames).
    pub decoded_ahead: usize,
    /// Of `refinements`, those that took a diamond decoded ahead (one decoded ahead of a view
    /// that then moved away from it counts as a plain refinement from the decoded cache).
    pub refined_ahead: usize,
    /// Coarsenings this frame.
    pub coarsenings: usize,
    /// The budget ran out with work left.
    pub budget_exhausted: bool,
    /// A refinement waited because the cut was at `cut_bytes` and nothing coarser could give
    /// way.
    pub memory_limited: bool,
    /// Bytes of the cut's decoded diamonds after the frame.
    pub cut_bytes: usize,
    /// Records the view's cut lacks, wanted this frame (queued or in flight).
    pub cut_wants: usize,
    /// Records wanted this frame only as prefetches (see [`RefineConfig::prefetch`]).
    pub prefetch_wants: usize,
    /// The data source's counters after the frame.
    pub access: AccessStats,
    /// Records rejected so far (failed fetches and failed decodes).
    pub failures: u64,
    /// Where `refine_ms` went, step by step.
    pub steps: FrameSteps,
}

/// Where a frame's wall time went, ms: the steps of [`Refiner::frame`] in order; they add up to
/// [`FrameStats::refine_ms`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FrameSteps {
    /// Before the refinement loop: the source's arrivals, a moving view's collection, the
    /// refinement heap.
    pub before_ms: f64,
    /// The refinement loop: dispatching, waiting for and applying decodes.
    pub loop_ms: f64,
    /// A collection after the loop (a still view's, or one going on in time the loop left).
    pub collect_ms: f64,
    /// Choosing the records to request for what the budget did not reach.
    pub want_ms: f64,
    /// The frame's largest error, prefetching, posting the requests.
    pub after_ms: f64,
    /// Planning the decoding ahead of the cut, last (cut at the end of the budget), and
    /// remembering the overrun.
    pub ahead_ms: f64,
}

/// Bytes held by the refiner's CPU caches ([`Refiner::cache_use`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CacheUse {
    /// Compressed records kept in RAM.
    pub record_bytes: usize,
    /// [`RefineConfig::record_cache_bytes`].
    pub record_budget: usize,
    /// Decoded diamonds kept after coarsening.
    pub decoded_bytes: usize,
    /// [`RefineConfig::decoded_cache_bytes`].
    pub decoded_budget: usize,
    /// Decoded diamonds evicted so far.
    pub decoded_evictions: u64,
}

enum Need {
    Ready(Source),
    Missing,
    Impossible,
}

#[derive(Clone, Copy, Debug, PartialEq)]
struct Candidate {
    err: f64,
    id: DiamondId,
}
impl Eq for Candidate {}
impl Ord for Candidate {
    fn cmp(&self, o: &Self) -> std::cmp::Ordering {
        self.err.total_cmp(&o.err).then(o.id.cmp(&self.id))
    }
}
impl PartialOrd for Candidate {
    fn partial_cmp(&self, o: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(o))
    }
}

/// A frame's refinement heap after its loop, for the next frame if its view is the same.
struct KeptHeap {
    camera: Camera,
    pixel_error: f64,
    heap: BinaryHeap<Candidate>,
}

/// The view a frame is refined for.
struct View {
    camera: Camera,
    frustum: Frustum,
    /// On a planet, what the globe hides from the eye: diamonds wholly behind the horizon are
    /// culled like those outside the frustum.
    horizon: Option<Horizon>,
    /// `2 tan(fov_y / 2)`, the part of [`Camera::pixels_per_metre`] that does not depend on the
    /// distance: computed once per view, with the same arithmetic, so errors are bit-identical.
    two_tan: f64,
}

impl View {
    fn new(camera: Camera, margin: f64, world: &World) -> Self {
        let f = camera.frustum();
        let frustum = if margin > 0.0 { f.enlarged(margin) } else { f };
        Self {
            camera,
            frustum,
            horizon: world.occluder().and_then(|o| o.from_eye(camera.eye)),
            two_tan: 2.0 * (camera.fov_y / 2.0).tan(),
        }
    }

    /// Screen-space error of a diamond, `None` outside the frustum.
    fn error(&self, info: &Info) -> Option<f64> {
        if !self.frustum.intersects_box(info.lo, info.hi) {
            return None;
        }
        if self.horizon.is_some_and(|h| h.hides_box(info.lo, info.hi)) {
            return None;
        }
        let e = self.camera.eye;
        let d = (info.lo - e).max(e - info.hi).max(DVec3::ZERO).length();
        let ppm = f64::from(self.camera.height) / (self.two_tan * d.max(self.camera.near));
        debug_assert_eq!(ppm, self.camera.pixels_per_metre(d));
        Some(info.err_m * ppm)
    }
}

/// The `limit` most urgent of `wanted` (all without a limit); between equals the coarser
/// (parents before children).
fn most_urgent(wanted: IdMap<f64>, limit: Option<usize>) -> IdMap<f64> {
    match limit {
        Some(limit) if wanted.len() > limit => {
            let mut by_priority: Vec<(DiamondId, f64)> = wanted.into_iter().collect();
            by_priority
                .select_nth_unstable_by(limit, |a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
            by_priority.truncate(limit);
            by_priority.into_iter().collect()
        }
        _ => wanted,
    }
}

/// Distance from `p` to the box `lo..hi` (0 inside).
pub fn box_distance(p: DVec3, lo: DVec3, hi: DVec3) -> f64 {
    (lo - p).max(p - hi).max(DVec3::ZERO).length()
}

/// The streaming refinement loop over one data source, decoding on the spawner `X`'s workers.
pub struct Refiner<S: DataSource, X: Spawner = DefaultSpawner> {
    source: S,
    spawner: X,
    config: RefineConfig,
    decoder: Arc<Decoder>,
    /// The colour draped over the terrain, when the source pairs one.
    drape: Option<Arc<Drape>>,
    /// The refiner's hierarchy: the source's, with `shift` more level pairs when synthesising
    /// detail (ids then have coordinates `2^shift` times the source's).
    domain: Domain,
    world: World,
    shift: u32,
    source_finest: u8,
    /// Every stored diamond's metric, and its position in the source's index, so that a mapped
    /// record is found without searching the index (a binary search of it took 11 % of decoding
    /// ahead's perf samples and 3 % of the refinement loop's, in a paced `low_pass` replay).
    stored: IdMap<(Info, usize)>,
    synthetic: IdMap<Option<Info>>,
    cut_state: CutState,
    residency: Residency,
    requests: Requests,
    frame: u64,
    last_camera: Option<Camera>,
    /// How far recent frames ran past their refinement deadline (the bookkeeping after the
    /// loop, the last results applied): the next deadline comes that much earlier, so that the
    /// whole frame, not only its refinement loop, fits the budget. A decaying maximum, so one
    /// slow tail is remembered for a while (the budget is a bound on every frame, not on the
    /// average).
    overrun: Duration,
    /// A garbage collection stopped at its frame's budget: the next frame goes on with it.
    collecting: bool,
    /// What the last frame prefetched, each diamond with its priority: a prefetch that the
    /// budget cuts short keeps those of them still on their way (see [`Refiner::prefetch`]).
    last_ahead: IdMap<f64>,
    /// The last frame's refinement heap (see [`KeptHeap`]), kept when `heap_whole`.
    kept_heap: Option<KeptHeap>,
    /// No candidate that violates the target has left this frame's heap without being refined
    /// (none missing its record, given up on, held back by the memory limit, decoded for a
    /// parent coarsened since or failed; none coarsened to make room): the heap after the loop
    /// holds every violating candidate but those being decoded, which come back refined.
    heap_whole: bool,
    /// Diamonds being refined on worker threads (speculative ones included).
    decoding: IdSet,
    /// The part of `decoding` decoded ahead of the cut by speculative jobs: their results go to
    /// the decoded cache, from which a later refinement takes them at no cost.
    speculative: IdSet,
    /// Speculative jobs dispatched and not finished.
    speculative_jobs: usize,
    /// Diamonds decoded ahead that came back and are not refined yet, and that the view of
    /// `ahead_view` needs (pruned when speculating: those that left the decoded cache, and
    /// those the view has moved away from).
    ahead: IdSet,
    /// Diamonds decoded ahead that came back since the last pruning, not looked at yet.
    ahead_arrived: IdSet,
    /// The camera `ahead` was last pruned for.
    ahead_view: Option<Camera>,
    /// When the last frame started, and the smoothed interval between frames, seconds.
    last_frame_start: Option<Instant>,
    frame_interval_s: f64,
    /// Smoothed refinements per second.
    refinement_rate: f64,
    /// Smoothed worker time of one decode, seconds.
    decode_s: f64,
    done_tx: Sender<Done>,
    done_rx: Receiver<Done>,
}

impl<S: DataSource> Refiner<S> {
    /// A refiner with the coarsest cut (roots only), decoding on the target's
    /// [`DefaultSpawner`].
    pub fn new(source: S, config: RefineConfig) -> Result<Self, CodecError> {
        Self::with_spawner(source, config, DefaultSpawner::default())
    }
}

impl<S: DataSource, X: Spawner> Refiner<S, X> {
    /// A refiner with the coarsest cut (roots only), decoding on `spawner`.
    pub fn with_spawner(source: S, config: RefineConfig, spawner: X) -> Result<Self, CodecError> {
        let decoder = source.decoder()?;
        let params = *source.head().params();
        let src_finest = params.domain.finest_level();
        let shift = config.detail.map_or(0, |d| d.level_pairs);
        let world = exaggerated(
            &World::new(
                &params,
                source.head().plan(),
                source.head().georef(),
                source.head().entries(),
            ),
            config.exaggeration,
        )
        .with_detail(shift)?;
        if world.is_planet() && shift > 0 {
            return Err(CodecError::unsupported(
                "synthetic detail below the finest level is planar only",
            ));
        }
        let domain = world.domain;

        // Saturate boxes and errors bottom-up: ids sort coarse to fine, so go in reverse.
        let mut stored: IdMap<(Info, usize)> = IdMap::default();
        for (index, e) in source.head().entries().iter().enumerate().rev() {
            let id = e.id.finer(shift);
            let (mut lo, mut hi) = world.diamond_box(id, e.min, e.max);
            // On a planet the flat triangles' sag under the curved surface counts too.
            let mut err_m = (f64::from(e.object_error) * world.unit).max(world.chord_error(id));
            for c in domain.children(id).into_iter().flatten() {
                if let Some((ci, _)) = stored.get(&c) {
                    lo = lo.min(ci.lo);
                    hi = hi.max(ci.hi);
                    err_m = err_m.max(ci.err_m);
                }
            }
            stored.insert(id, (Info { err_m, lo, hi }, index));
        }

        let drape = source.drape().cloned().map(Arc::new);
        let mut roots = IdMap::default();
        for r in domain.roots() {
            let src = r.coarser(shift);
            let heights = decoder.grid_of(src, [None, None]);
            let valid = decoder.validity_of(src, [None, None]);
            let colour = drape
                .as_ref()
                .map(|d| root_colour(d, src).map(|g| packed(&g)))
                .transpose()?;
            roots.insert(
                r,
                Half::BOTH.map(|half| {
                    Arc::new(HalfPatch {
                        id: r,
                        half,
                        heights: heights.clone(),
                        valid: valid.clone(),
                        colour: colour.clone(),
                    })
                }),
            );
        }
        let (done_tx, done_rx) = std::sync::mpsc::channel();
        let mut me = Self {
            source,
            spawner,
            decoder: Arc::new(decoder),
            drape,
            domain,
            world,
            shift,
            source_finest: src_finest,
            stored,
            synthetic: IdMap::default(),
            cut_state: CutState {
                cut: Cut::new(),
                nodes: IdMap::default(),
                roots,
                drawn: DrawnList::default(),
                candidates: IdMap::default(),
                leaves: IdMap::default(),
            },
            residency: Residency {
                records: LruCache::new(config.record_cache_bytes),
                decoded: LruCache::new(config.decoded_cache_bytes),
                cut_bytes: 0,
                evicted: Vec::new(),
            },
            requests: Requests::default(),
            frame: 0,
            last_camera: None,
            overrun: config.budget.map_or(Duration::ZERO, |b| b / OVERRUN_PRIOR),
            collecting: false,
            kept_heap: None,
            last_ahead: IdMap::default(),
            heap_whole: false,
            decoding: IdSet::default(),
            speculative: IdSet::default(),
            speculative_jobs: 0,
            ahead: IdSet::default(),
            ahead_arrived: IdSet::default(),
            ahead_view: None,
            last_frame_start: None,
            frame_interval_s: 1.0 / 30.0,
            refinement_rate: 0.0,
            decode_s: 1e-3,
            done_tx,
            done_rx,
            config,
        };
        me.cut_state.rebuild_drawn(&me.domain);
        let roots: Vec<DiamondId> = me.domain.roots().collect();
        for r in roots {
            let info = me.info(r);
            me.cut_state.candidates.insert(r, info);
        }
        Ok(me)
    }

    /// The message that sets up a [`WorkerDecoder`] to run this refiner's decode jobs from
    /// their bytes (for workers that share no memory with it): the heads of the repository the
    /// source reads (and of the draped colour one, if any) and the detail settings.
    pub fn worker_context(&self, elevation: HeadBytes, colour: Option<HeadBytes>) -> Vec<u8> {
        let seed = self.config.detail.map_or(0, |d| d.seed);
        wire::encode_context(elevation, colour, self.shift, seed)
    }

    /// The settings.
    pub fn config(&self) -> &RefineConfig {
        &self.config
    }

    /// Changes the screen-space error target from the next frame on (an interactive viewer's
    /// `+`/`-`). Non-positive or non-finite values are ignored: the target must stay a positive
    /// number of pixels.
    pub fn set_pixel_error(&mut self, pixel_error: f64) {
        if pixel_error.is_finite() && pixel_error > 0.0 {
            self.config.pixel_error = pixel_error;
        }
    }

    /// Changes the time budget per frame from the next frame on (`None`: refine until the cut
    /// is locally optimal).
    pub fn set_budget(&mut self, budget: Option<Duration>) {
        self.config.budget = budget;
    }

    /// How full the CPU-side caches are.
    pub fn cache_use(&self) -> CacheUse {
        CacheUse {
            record_bytes: self.residency.records.bytes(),
            record_budget: self.config.record_cache_bytes,
            decoded_bytes: self.residency.decoded.bytes(),
            decoded_budget: self.config.decoded_cache_bytes,
            decoded_evictions: self.residency.decoded.evictions(),
        }
    }

    /// The current cut (in [`Refiner::layout`]'s ids).
    pub fn cut(&self) -> &Cut {
        &self.cut_state.cut
    }

    /// The hierarchy the cut lives in: the source's, deeper when synthesising detail.
    pub fn layout(&self) -> &Layout {
        self.domain.layout()
    }

    /// The domain of the cut's ids (the repository's, with the synthetic detail levels).
    pub fn domain(&self) -> &Domain {
        &self.domain
    }

    /// Lattice to world metres for [`Refiner::layout`]'s ids.
    pub fn world(&self) -> &World {
        &self.world
    }

    /// The data source.
    pub fn source(&self) -> &S {
        &self.source
    }

    /// The data source, mutably (e.g. to change a test double's behaviour).
    pub fn source_mut(&mut self) -> &mut S {
        &mut self.source
    }

    /// The half-patches the cut draws, in [`Cut::drawn_halves`] order.
    pub fn drawn(&self) -> impl Iterator<Item = &Arc<HalfPatch>> {
        self.cut_state.drawn.iter()
    }

    /// Recent error messages (rejected records), oldest first.
    pub fn errors(&self) -> &[String] {
        &self.requests.errors
    }

    /// The source's id of one of the refiner's diamonds (`None` for synthetic levels).
    pub fn source_id(&self, id: DiamondId) -> Option<DiamondId> {
        let mask = (1u32 << self.shift) - 1;
        (id.level <= self.source_finest && id.x & mask == 0 && id.y & mask == 0)
            .then(|| id.coarser(self.shift))
    }

    /// The refiner's id of one of the source's diamonds.
    pub fn refiner_id(&self, id: DiamondId) -> DiamondId {
        id.finer(self.shift)
    }

    /// Screen-space error of a refinable diamond as the loop sees it (`None` if it cannot be
    /// refined or lies outside the frustum).
    pub fn screen_error(&mut self, id: DiamondId, camera: &Camera) -> Option<f64> {
        let info = self.info(id)?;
        View::new(*camera, 0.0, &self.world).error(&info)
    }

    fn info(&mut self, id: DiamondId) -> Option<Info> {
        if let Some((i, _)) = self.stored.get(&id) {
            return Some(*i);
        }
        let detail = self.config.detail?;
        if id.level < self.source_finest || id.level >= self.domain.finest_level() {
            return None;
        }
        if let Some(i) = self.synthetic.get(&id) {
            return *i;
        }
        // Synthesised only where every parent has data (stored or itself synthesised).
        let mut z = (f64::INFINITY, f64::NEG_INFINITY);
        let mut ok = true;
        for p in self.domain.parents(id).into_iter().flatten() {
            match self.info(p) {
                Some(pi) => z = (z.0.min(pi.lo.z), z.1.max(pi.hi.z)),
                None => ok = false,
            }
        }
        let info = ok.then(|| {
            let amp = |l: u8| {
                f64::from(detail::amplitude_units(&self.world, &detail, l)) * self.world.unit
            };
            let below: f64 = (id.level..self.domain.finest_level()).map(amp).sum();
            let (x0, y0, x1, y1) = self.domain.layout().bounds(id);
            let pad = 2 * self.domain.layout().radius(id.level);
            let a = self.world.point(x0 - pad, y0 - pad, 0);
            let b = self.world.point(x1 + pad, y1 + pad, 0);
            Info {
                err_m: amp(id.level),
                lo: DVec3::new(a.x.min(b.x), a.y.min(b.y), z.0 - below),
                hi: DVec3::new(a.x.max(b.x), a.y.max(b.y), z.1 + below),
            }
        });
        self.synthetic.insert(id, info);
        info
    }

    fn is_synthetic(&self, id: DiamondId) -> bool {
        id.level >= self.source_finest
    }

    /// Records a failure to fetch or decode `id`: the request log counts it (and gives up on
    /// the diamond after [`RefineConfig::max_failures`]), and its record, if any, is dropped.
    fn log_failure(&mut self, id: DiamondId, message: String) {
        self.heap_whole = false;
        self.requests
            .log_failure(id, message, self.config.max_failures);
        self.residency.records.remove(&id);
    }

    /// Moves a record that has arrived into RAM.
    fn take(&mut self, id: DiamondId, sid: DiamondId) -> Option<Arc<[u8]>> {
        match self.source.take(sid)? {
            Ok(bytes) => {
                let bytes: Arc<[u8]> = bytes.into();
                self.residency.keep_record(id, bytes.clone());
                Some(bytes)
            }
            Err(e) => {
                self.log_failure(id, e.to_string());
                None
            }
        }
    }

    fn need(&mut self, id: DiamondId) -> Need {
        // A stored diamond's entry (one lookup for its metric and its place in the index).
        let entry = self.stored.get(&id).map(|&(_, index)| index);
        if self.requests.broken.contains(&id) || (entry.is_none() && self.info(id).is_none()) {
            return Need::Impossible;
        }
        // A peek: the loop takes a cached node out of the cache at once, and decoding ahead
        // only asks whether it is there.
        if let Some(n) = self.residency.decoded.peek(&id) {
            return Need::Ready(Source::Cached(n.clone()));
        }
        if self.is_synthetic(id) {
            let detail = self
                .config
                .detail
                .expect("synthetic levels only with detail");
            let amp = detail::amplitude_units(&self.world, &detail, id.level);
            return Need::Ready(Source::Synthetic(amp));
        }
        if let Some(r) = self.residency.records.get(&id) {
            return Need::Ready(Source::Record(r.clone()));
        }
        let sid = self.source_id(id).expect("stored levels map to the source");
        let mapped = match entry {
            Some(index) => self.source.mapped_entry(sid, index),
            None => self.source.mapped(sid),
        };
        if let Some(record) = mapped {
            // Read by the worker that decodes it: nothing to keep in RAM.
            return Need::Ready(Source::Mapped(record));
        }
        if self.source.is_available(sid) {
            self.requests.requested.remove(&id);
            if let Some(r) = self.take(id, sid) {
                return Need::Ready(Source::Record(r));
            }
            if self.requests.broken.contains(&id) {
                return Need::Impossible;
            }
        }
        Need::Missing
    }

    /// Whether a diamond's data could be had without a request (in RAM, cached, synthetic, or
    /// available from the source). Takes nothing.
    fn have_or_available(&mut self, id: DiamondId) -> bool {
        self.residency.decoded.contains(&id)
            || self.residency.records.contains(&id)
            || self.is_synthetic(id)
            || self
                .source_id(id)
                .is_some_and(|sid| self.source.is_available(sid))
    }

    /// The unrefined diamonds refining `id` takes, parents before children.
    fn plan(&self, id: DiamondId) -> Vec<DiamondId> {
        fn visit(me: &Cut, domain: &Domain, d: DiamondId, out: &mut Vec<DiamondId>) {
            if me.is_refined(d) || out.contains(&d) {
                return;
            }
            for p in domain.parents(d).into_iter().flatten() {
                visit(me, domain, p, out);
            }
            out.push(d);
        }
        // Most often only `id` itself is unrefined (a candidate whose parents are refined).
        if self.cut_state.cut.is_refined(id) {
            return Vec::new();
        }
        let parents = self.domain.parents(id);
        if parents
            .iter()
            .flatten()
            .all(|&p| self.cut_state.cut.is_refined(p))
        {
            return vec![id];
        }
        let mut out = Vec::new();
        visit(&self.cut_state.cut, &self.domain, id, &mut out);
        out
    }

    /// Whether refining `id` needs a diamond that was given up on.
    fn blocked(&self, id: DiamondId) -> bool {
        !self.requests.broken.is_empty()
            && self
                .plan(id)
                .iter()
                .any(|d| self.requests.broken.contains(d))
    }

    /// The diamonds with a drawn half (refinement candidates), each once, with their metric.
    fn candidate_list(&self) -> Vec<(DiamondId, Option<Info>)> {
        self.cut_state
            .candidates
            .iter()
            .map(|(&id, &i)| (id, i))
            .collect()
    }

    /// [`Refiner::violation`] for a diamond whose metric is at hand.
    fn violation_of(&self, id: DiamondId, info: Option<Info>, view: &View) -> Option<f64> {
        view.error(&info?)
            .filter(|&e| e > self.config.pixel_error && !self.requests.broken.contains(&id))
    }

    /// Refines `id` (whose parents are refined and whose node is in `nodes`) and updates the
    /// drawn halves and both candidate sets. Returns the children that became candidates, with
    /// their metric so that the caller need not look them up again: a child of two parents
    /// became one when the first was refined, and is in the refinement heap already (pushed
    /// twice, half the heap's entries were duplicates in a settling `low_pass`).
    fn refine_in_cut(&mut self, id: DiamondId) -> [Option<(DiamondId, Option<Info>)>; 4] {
        let mut children = [None; 4];
        let newly = self.cut_state.cut.refine(&self.domain, id);
        debug_assert_eq!(newly, vec![id], "parents are refined first");
        if newly.is_empty() {
            return children;
        }
        self.cut_state.hide_halves(&self.domain, id);
        let info = match self.cut_state.candidates.remove(&id) {
            Some(info) => info,
            None => self.info(id),
        };
        let node = self.cut_state.nodes[&id].clone();
        for (slot, k) in self.domain.children(id).into_iter().enumerate() {
            debug_assert_eq!(
                k.is_some(),
                node.halves[slot].is_some(),
                "refined diamonds hold their children's halves"
            );
            let Some(k) = k else { continue };
            if self.cut_state.candidates.contains_key(&k) {
                continue;
            }
            let info = self.info(k);
            self.cut_state.candidates.insert(k, info);
            children[slot] = Some((k, info));
        }
        self.cut_state.drawn.show_children(id, node);
        self.cut_state.leaves.insert(id, info);
        for p in self.domain.parents(id).into_iter().flatten() {
            self.cut_state.leaves.remove(&p);
        }
        children
    }

    /// Coarsens `id` if none of its children is refined, updating the drawn halves and both
    /// candidate sets. Returns whether it did.
    fn coarsen_in_cut(&mut self, id: DiamondId) -> bool {
        if !self.cut_state.cut.coarsen(&self.domain, id) {
            return false;
        }
        self.cut_state.drawn.hide_children(id);
        for k in self.domain.children(id).into_iter().flatten() {
            let still_drawn = self
                .domain
                .parents(k)
                .into_iter()
                .flatten()
                .any(|p| self.cut_state.cut.is_refined(p));
            if !still_drawn {
                self.cut_state.candidates.remove(&k);
            }
        }
        self.cut_state.show_halves(&self.domain, id);
        let info = self.info(id);
        self.cut_state.candidates.insert(id, info);
        self.cut_state.leaves.remove(&id);
        for p in self.domain.parents(id).into_iter().flatten() {
            if self.cut_state.is_leaf(&self.domain, p) {
                let info = self.info(p);
                self.cut_state.leaves.insert(p, info);
            }
        }
        true
    }

    fn violation(&mut self, id: DiamondId, view: &View) -> Option<f64> {
        let info = self.info(id)?;
        view.error(&info)
            .filter(|&e| e > self.config.pixel_error && !self.requests.broken.contains(&id))
    }

    /// Wants the records that refining `id` (parents first) still lacks.
    fn want_plan(&mut self, id: DiamondId, priority: f64, wanted: &mut IdMap<f64>) {
        let plan = self.plan(id);
        self.want_planned(&plan, priority, wanted);
    }

    /// [`Refiner::want_plan`] for a plan at hand.
    fn want_planned(&mut self, plan: &[DiamondId], priority: f64, wanted: &mut IdMap<f64>) {
        // Usually everything is at hand (always with a local source): then nothing is wanted
        // whatever the metric says, and the metric's lookups can be skipped.
        if plan.iter().all(|&d| self.have_or_available(d)) {
            return;
        }
        let priority = match self.config.fetch_order {
            FetchOrder::ScreenError => priority,
            FetchOrder::ScreenErrorPerByte => {
                priority * 1024.0 / self.missing_bytes(plan).max(1) as f64
            }
        };
        for &d in plan {
            if self.requests.broken.contains(&d) || self.info(d).is_none() {
                return;
            }
            if !self.have_or_available(d) {
                let w = wanted.entry(d).or_insert(priority);
                *w = w.max(priority);
            }
        }
    }

    /// Bytes of the records of `plan` that are not at hand.
    fn missing_bytes(&mut self, plan: &[DiamondId]) -> u64 {
        let mut missing = Vec::with_capacity(plan.len());
        for &d in plan {
            if !self.have_or_available(d)
                && let Some(sid) = self.source_id(d)
            {
                missing.push(sid);
            }
        }
        let entries = self.source.head().entries();
        missing
            .iter()
            .filter_map(|sid| entries.binary_search_by(|e| e.id.cmp(sid)).ok())
            .map(|i| u64::from(entries[i].length))
            .sum()
    }

    /// Runs one frame for `camera`: refine within the budget, request what is missing,
    /// prefetch, cancel what is no longer needed, and every few frames coarsen.
    pub fn frame(&mut self, camera: &Camera) -> FrameStats {
        let start = Instant::now();
        if let Some(last) = self.last_frame_start {
            let dt = start.duration_since(last).as_secs_f64();
            self.frame_interval_s += SMOOTHING * (dt - self.frame_interval_s);
        }
        self.last_frame_start = Some(start);
        self.frame += 1;
        let collects = self.config.gc_interval > 0
            && (self.collecting
                || self
                    .frame
                    .is_multiple_of(u64::from(self.config.gc_interval)));
        // At most half the budget is held back for the tail, so refinement always gets the
        // other half; between paced frames that decode ahead, at least AHEAD_SHARE of it.
        let ahead_floor = match self.config.budget {
            Some(b) if self.decodes_ahead() && self.paced() => b / AHEAD_SHARE,
            _ => Duration::ZERO,
        };
        let deadline = self.config.budget.map(|b| {
            let held_back = self.overrun.mul_f64(OVERRUN_SPREAD).max(ahead_floor);
            start + b - held_back.min(b / OVERRUN_CAP)
        });
        self.source.pump();
        self.take_arrived();

        let view = View::new(*camera, 0.0, &self.world);
        let mut stats = FrameStats {
            frame: self.frame,
            ..FrameStats::default()
        };
        // While the view moves a collection comes first, for a share of the budget:
        // coarsening costs microseconds a diamond, a view moving fast leaves hundreds to
        // coarsen at once, and a collection left what the refinement loop leaves would get
        // nothing in frames whose budget the loop spends. Coarsening before refining changes
        // nothing the loop does: what is coarsened meets the target, what is refined does not.
        // A still view's refinement comes first: its collection takes its least after the loop.
        let still = self.config.budget.is_some() && self.last_camera == Some(*camera);
        if collects && !still {
            let until = self.config.budget.map(|b| start + b / GC_SHARE);
            let (coarsened, finished) = self.collect_garbage(&view, GC_MIN_COARSENINGS, until);
            stats.coarsenings += coarsened;
            self.collecting = !finished;
        }
        // A still view's heap is the last frame's leftovers when nothing left it since but
        // what was refined: the same screen errors, and the pass over every candidate skipped.
        let mut heap = match self.kept_heap.take() {
            Some(kept)
                if still
                    && kept.camera == *camera
                    && kept.pixel_error == self.config.pixel_error =>
            {
                #[cfg(debug_assertions)]
                self.check_kept_heap(&view, &kept.heap);
                kept.heap
            }
            _ => self.refinement_heap(&view),
        };
        self.heap_whole = true;
        let mut wanted: IdMap<f64> = IdMap::default();
        let loop_start = Instant::now();
        self.refine_until(deadline, &view, &mut heap, &mut wanted, &mut stats);
        let loop_end = Instant::now();
        // A still view collects only once its loop has refined all it could: until then its
        // collection waits (its garbage is the moving view's, and the loop's refinements are
        // what the view lacks).
        let deferred = collects && still && !stats.budget_exhausted;
        if collects && still && stats.budget_exhausted {
            self.collecting = true;
        }
        if let (Some(d), Some(b)) = (deadline, self.config.budget)
            && (deferred
                || (self.collecting && d.saturating_duration_since(Instant::now()) >= b / GC_SHARE))
        {
            // The still view's collection, or one that goes on in the time the loop left
            // (nothing it could refine now), up to the deadline.
            let least = if deferred { GC_MIN_COARSENINGS } else { 0 };
            let (coarsened, finished) = self.collect_garbage(&view, least, deadline);
            stats.coarsenings += coarsened;
            self.collecting = !finished;
        }
        let rate = stats.refinements as f64 / self.frame_interval_s.max(1e-3);
        self.refinement_rate += SMOOTHING * (rate - self.refinement_rate);
        let collect_end = Instant::now();

        // What the budget did not reach still gets requested, then prefetch (neither can want
        // anything from a source that always has everything at hand).
        let may_want = !self.source.always_available();
        // A whole heap is still needed after this (the frame's largest error, the next frame's
        // heap): copied; otherwise taken.
        let leftovers: Vec<Candidate> = if self.heap_whole {
            heap.iter().copied().collect()
        } else {
            std::mem::take(&mut heap).into_vec()
        };
        if may_want {
            let mut order: Vec<&Candidate> = leftovers
                .iter()
                .filter(|c| !self.cut_state.cut.is_refined(c.id))
                .collect();
            let limit = self
                .config
                .want_limit
                .map(|min| min.max((self.refinement_rate * WANT_HORIZON_S) as usize));
            if let Some(limit) = limit
                && order.len() > limit
            {
                // Past the most urgent, only what is already on its way stays wanted: dropping
                // it would cancel requests the link has carried part of.
                order.select_nth_unstable_by(limit, |a, b| b.cmp(a));
                let rest = order.split_off(limit);
                order.extend(
                    rest.into_iter()
                        .filter(|c| self.requests.requested.contains_key(&c.id)),
                );
            }
            for c in order {
                self.want_plan(c.id, c.err, &mut wanted);
            }
        }
        let want_end = Instant::now();
        let worst_violating = if self.heap_whole {
            self.worst_violating(&view, &heap)
        } else {
            None
        };
        self.kept_heap = (self.config.budget.is_some() && self.heap_whole).then_some(KeptHeap {
            camera: *camera,
            pixel_error: self.config.pixel_error,
            heap,
        });
        // One pass over the final cut's candidates serves prefetching and the frame's figures.
        // Without prefetching the figures need only the largest error: no list is made.
        stats.cut_wants = wanted.len();
        let prefetching = may_want && self.config.prefetch.allows(wanted.len());
        let (worst, ahead) = if prefetching {
            let candidates = self.candidate_list();
            let errors: Vec<Option<f64>> = candidates
                .iter()
                .map(|&(_, info)| info.and_then(|i| view.error(&i)))
                .collect();
            let until = self.config.budget.map(|b| start + b - b / PREFETCH_RESERVE);
            let ahead = self.prefetch(camera, &candidates, &errors, until);
            let worst =
                self.worst_error(candidates.iter().zip(&errors).map(|(&(id, _), &e)| (id, e)));
            (worst, ahead)
        } else if let Some(worst) = worst_violating {
            #[cfg(debug_assertions)]
            assert_eq!(
                worst,
                self.worst_of_candidates(&view),
                "largest error from the heap"
            );
            (worst, IdMap::default())
        } else {
            (self.worst_of_candidates(&view), IdMap::default())
        };
        self.last_camera = Some(*camera);
        let track = self.requests.track_classes;
        if track {
            for id in wanted.keys() {
                self.requests.last_class.insert(*id, false);
            }
        }
        for (&id, &prio) in &ahead {
            if let std::collections::hash_map::Entry::Vacant(e) = wanted.entry(id) {
                e.insert(prio);
                stats.prefetch_wants += 1;
                if track {
                    self.requests.last_class.insert(id, true);
                }
            }
        }
        self.last_ahead = ahead;

        self.post_requests(wanted);
        let after_end = Instant::now();
        // The workers keep decoding what the view still needs until the next frame. Last in
        // the frame, so that what it may take is known: the rest of the budget (its plan is
        // cut there, but each free worker gets a job; see AHEAD_RESERVE).
        if self.decodes_ahead() {
            let budget_end = self.config.budget.map(|b| start + b - b / AHEAD_RESERVE);
            self.speculate(&view, leftovers, budget_end);
        }
        self.remember_overrun(deadline, &stats);
        self.release_evicted();
        let end = Instant::now();
        stats.refine_ms = (end - start).as_secs_f64() * 1e3;
        let ms = |a: Instant, b: Instant| (b - a).as_secs_f64() * 1e3;
        stats.steps = FrameSteps {
            before_ms: ms(start, loop_start),
            loop_ms: ms(loop_start, loop_end),
            collect_ms: ms(loop_end, collect_end),
            want_ms: ms(collect_end, want_end),
            after_ms: ms(want_end, after_end),
            ahead_ms: ms(after_end, end),
        };
        #[cfg(debug_assertions)]
        self.cut_state.check_incremental_sets(&self.domain);
        self.figures(&view, worst, &mut stats);
        stats
    }

    /// Frame step: hands the nodes the decoded cache evicted this frame to a worker to drop.
    /// Dropping a node frees its five buffers (~100 KB at N = 65), allocated by the worker that
    /// decoded it: on the frame thread that was a fifth of garbage collection's time in a paced
    /// `low_pass` flight (each coarsening moves a node into the full cache, which evicts one).
    /// A spawner without threads drops them here.
    fn release_evicted(&mut self) {
        if !self.residency.evicted.is_empty() {
            let evicted = std::mem::take(&mut self.residency.evicted);
            self.spawner.spawn(move || drop(evicted));
        }
    }

    /// Whether frames end by decoding ahead of the cut (see [`Refiner::speculate`]).
    fn decodes_ahead(&self) -> bool {
        self.config.decode_ahead && self.spawner.runs_in_background()
    }

    /// Whether frames come at least [`PACED_BUDGETS`] budgets apart: a viewer's frames, whose
    /// workers have the time between them.
    fn paced(&self) -> bool {
        self.config
            .budget
            .is_some_and(|b| self.frame_interval_s > PACED_BUDGETS * b.as_secs_f64())
    }

    /// Frame step: moves the records that arrived into RAM; failures are logged now rather than
    /// when next wanted.
    fn take_arrived(&mut self) {
        let arrived: Vec<DiamondId> = self
            .requests
            .requested
            .keys()
            .copied()
            .filter(|id| {
                self.source_id(*id)
                    .is_some_and(|s| self.source.is_available(s))
            })
            .collect();
        for id in arrived {
            self.requests.requested.remove(&id);
            let sid = self.source_id(id).expect("requested ids are stored");
            self.take(id, sid);
        }
    }

    /// Frame step: the refinement heap, the candidates that violate the target in `view`, most
    /// urgent on top.
    fn refinement_heap(&self, view: &View) -> BinaryHeap<Candidate> {
        // Collected, then made a heap in one pass (the order is total: ties go by id).
        let violations: Vec<Candidate> = self
            .cut_state
            .candidates
            .iter()
            .filter_map(|(&id, &info)| {
                self.violation_of(id, info, view)
                    .map(|err| Candidate { err, id })
            })
            .collect();
        BinaryHeap::from(violations)
    }

    /// Checks that a kept heap holds every candidate that violates the target in `view` but
    /// those being decoded (debug builds, so every test frame of a still view checks it).
    #[cfg(debug_assertions)]
    fn check_kept_heap(&self, view: &View, kept: &BinaryHeap<Candidate>) {
        let held: IdSet = kept.iter().map(|c| c.id).collect();
        for c in self.refinement_heap(view).into_vec() {
            assert!(
                held.contains(&c.id) || self.decoding.contains(&c.id),
                "the kept refinement heap lacks {} ({} px)",
                c.id,
                c.err
            );
        }
    }

    /// Frame step: applies the results of decodes dispatched in earlier frames, then dispatches
    /// the most urgent ready refinements and applies what comes back until nothing more can
    /// start or `deadline` passes. What could not be refined (missing records, blocked on an
    /// ancestor) is left in `heap`; missing records go into `wanted`.
    fn refine_until(
        &mut self,
        deadline: Option<Instant>,
        view: &View,
        heap: &mut BinaryHeap<Candidate>,
        wanted: &mut IdMap<f64>,
        stats: &mut FrameStats,
    ) {
        // Results of decodes dispatched in earlier frames first.
        while let Ok(done) = self.done_rx.try_recv() {
            self.apply(done, view, heap, stats);
        }
        let max_in_flight = 2 * self.spawner.parallelism().max(1);
        let mut waiting: Vec<Candidate> = Vec::new();
        let mut coarsening = None;
        let past = |d: Option<Instant>| d.is_some_and(|d| Instant::now() >= d);
        // Candidates looked at this frame before one could start: a frame whose deadline has
        // passed before its loop began (a loaded machine, a tiny budget) still starts one
        // refinement when one of its first few candidates can, so that every frame advances.
        let mut looked = 0;
        let mut started = false;
        loop {
            // Dispatch the most urgent ready refinements to the workers. Refinements decoded
            // ahead (the decoded cache) are applied here at once, so the deadline is checked
            // here too.
            while self.decoding.len() - self.speculative.len() < max_in_flight {
                if past(deadline) && (started || looked >= LEAST_LOOKS) {
                    stats.budget_exhausted = true;
                    break;
                }
                let Some(c) = heap.pop() else { break };
                looked += 1;
                if self.cut_state.cut.is_refined(c.id) {
                    continue;
                }
                let mut blocked = false;
                let mut dispatched_self = false;
                for d in self.plan(c.id) {
                    if self.decoding.contains(&d) {
                        continue;
                    }
                    let parents_done = self
                        .domain
                        .parents(d)
                        .into_iter()
                        .flatten()
                        .all(|p| self.cut_state.cut.is_refined(p));
                    match self.need(d) {
                        Need::Impossible => {
                            blocked = true;
                            break;
                        }
                        Need::Missing => {
                            let w = wanted.entry(d).or_insert(c.err);
                            *w = w.max(c.err);
                            blocked = true;
                        }
                        Need::Ready(_)
                            if parents_done
                                && !self.make_room(c.err, d, view, &mut coarsening, stats) =>
                        {
                            stats.memory_limited = true;
                            blocked = true;
                            break;
                        }
                        Need::Ready(Source::Cached(node)) if parents_done => {
                            // Decoded before (ahead of the cut, or coarsened since): refining
                            // is free.
                            self.apply(
                                Done {
                                    id: d,
                                    result: Some(Ok(node)),
                                    secs: None,
                                    cpu_secs: None,
                                    speculative: false,
                                    last: false,
                                },
                                view,
                                heap,
                                stats,
                            );
                            dispatched_self |= d == c.id;
                            started = true;
                        }
                        Need::Ready(s) if parents_done => {
                            self.dispatch(d, s);
                            dispatched_self |= d == c.id;
                            started = true;
                        }
                        Need::Ready(_) => {}
                    }
                }
                if blocked {
                    self.heap_whole = false;
                } else if !dispatched_self && !self.cut_state.cut.is_refined(c.id) {
                    waiting.push(c);
                }
            }
            let regular = self.decoding.len() - self.speculative.len();
            if stats.budget_exhausted || (regular == 0 && waiting.is_empty()) {
                // Nothing in flight that this frame waits for and nothing more could be
                // started: locally optimal for the data at hand (speculative decodes still
                // running are applied when they come back).
                break;
            }
            let done = self.next_done(deadline);
            let Some(done) = done else {
                stats.budget_exhausted = true;
                break;
            };
            self.apply(done, view, heap, stats);
            while let Ok(done) = self.done_rx.try_recv() {
                self.apply(done, view, heap, stats);
            }
            // Candidates that waited for an ancestor may be ready now.
            heap.extend(waiting.drain(..));
        }
        heap.extend(waiting);
    }

    /// The next finished decode: waits for it until `deadline` (forever without one); `None`
    /// when the deadline passed first.
    #[cfg(not(target_arch = "wasm32"))]
    fn next_done(&self, deadline: Option<Instant>) -> Option<Done> {
        match deadline {
            None => self.done_rx.recv().ok(),
            Some(d) => {
                let now = Instant::now();
                if now >= d {
                    None
                } else {
                    self.done_rx.recv_timeout(d - now).ok()
                }
            }
        }
    }

    /// The next finished decode, if one has arrived and `deadline` has not passed: a browser's
    /// page must never block (and `recv_timeout` would read `std`'s clock, which wasm32 lacks).
    /// With the [`Inline`](crate::spawn::Inline) spawner every decode has finished when it is
    /// dispatched, so this loses nothing; with asynchronous workers the frame ends and the
    /// results are applied next frame.
    #[cfg(target_arch = "wasm32")]
    fn next_done(&self, deadline: Option<Instant>) -> Option<Done> {
        if deadline.is_some_and(|d| Instant::now() >= d) {
            return None;
        }
        self.done_rx.try_recv().ok()
    }

    /// Frame step: posts new requests, re-prioritises, and cancels what is no longer wanted.
    fn post_requests(&mut self, wanted: IdMap<f64>) {
        let stale: Vec<DiamondId> = self
            .requests
            .requested
            .keys()
            .filter(|id| !wanted.contains_key(id))
            .copied()
            .collect();
        for id in stale {
            self.requests.requested.remove(&id);
            if let Some(sid) = self.source_id(id) {
                // A remote source may have completed it since the frame began: keep what was
                // paid for rather than dropping it.
                if self.source.is_available(sid) {
                    self.take(id, sid);
                } else {
                    self.source.cancel(sid);
                }
            }
        }
        for (id, prio) in wanted {
            let prio = prio as Priority;
            if self.requests.requested.get(&id) != Some(&prio)
                && let Some(sid) = self.source_id(id)
            {
                self.source.request(sid, prio);
                self.requests.requested.insert(id, prio);
            }
        }
    }

    /// Frame step: when the budget ran out, how far past its deadline the frame ran (see
    /// `overrun`).
    fn remember_overrun(&mut self, deadline: Option<Instant>, stats: &FrameStats) {
        if let (Some(d), Some(b), true) = (deadline, self.config.budget, stats.budget_exhausted) {
            // Remembered at most as the most the deadline can hold back: a longer one is a
            // stall (the thread off its core for a scheduler tick, 4 ms on this machine), which
            // no deadline avoids, and remembered whole it held the next 80 frames' deadlines at
            // the cap.
            let over = Instant::now()
                .saturating_duration_since(d)
                .min(b / OVERRUN_CAP);
            self.overrun = over.max(self.overrun.mul_f64(OVERRUN_DECAY));
        }
    }

    /// Frame step: the frame's figures of the cut it leaves.
    fn figures(&mut self, view: &View, worst: f64, stats: &mut FrameStats) {
        let (max_err, coarsenable) = self.measure(view, worst);
        stats.max_screen_error_px = max_err;
        stats.met_target = max_err <= self.config.pixel_error;
        stats.converged = stats.met_target && coarsenable == 0;
        stats.refined = self.cut_state.nodes.len();
        stats.cut_bytes = self.residency.cut_bytes;
        stats.drawn_halves = self.cut_state.drawn.len();
        let n1 = (self.domain.n() - 1) as u64;
        stats.triangles = self.cut_state.drawn.len() as u64 * n1 * n1;
        stats.access = self.source.stats();
        stats.failures = self.requests.failure_count;
    }

    /// Runs frames for one still `camera` until the cut has converged, or for `max_frames`
    /// frames at most, and returns the last frame's stats. With an unlimited budget and a local
    /// source the first frame usually converges: a single image's cut, picked exactly as a
    /// flight's frames pick theirs.
    pub fn settle(&mut self, camera: &Camera, max_frames: u32) -> FrameStats {
        let mut stats = self.frame(camera);
        for _ in 1..max_frames {
            if stats.converged {
                break;
            }
            stats = self.frame(camera);
        }
        stats
    }

    /// Frame step: what to prefetch, each diamond with its priority: the records that refining
    /// the candidates that violate the target in the view `lookahead_frames` ahead at the
    /// camera's velocity (with a margin) would take, and those of the children of the
    /// candidates that violate it now, at [`PREFETCH_PRIORITY`] of their screen errors; at most
    /// [`RefineConfig::prefetch_limit`] of them, the most urgent (between equals the coarser).
    ///
    /// With a limit (and priorities that are screen errors), only the most urgent contributions
    /// are planned: each candidate's and child's screen error is computed, and the plans (and
    /// what they lack) are looked at from the most urgent down until the limit is reached and
    /// the next contribution is less urgent than everything kept. In the frames of a fast
    /// flight over a network that prefetch, planning every one of ~3 700 contributions wanted
    /// ~1 000 diamonds to keep 32, in 2.1–2.7 ms of a 2 ms budget; from the most urgent down,
    /// ~1 500 are planned, in 1.2–1.7 ms. The same diamonds and priorities as planning every
    /// contribution (checked in debug builds): a diamond's priority is the largest of its
    /// contributions', and every contribution at least as urgent as the kept ones is planned.
    ///
    /// Prefetching stops at `until` (the budget's end less [`PREFETCH_RESERVE`]): cut short
    /// while planning, it keeps the most urgent of what it planned (their priorities are
    /// final: a diamond's first contribution is its most urgent), and cut short sooner,
    /// nothing new; either way the last frame's prefetches still on their way stay wanted
    /// ([`Refiner::keep_last_ahead`]), so that a frame short of time cancels nothing the link
    /// carries. (By screen error per byte, once begun every plan is looked at.)
    fn prefetch(
        &mut self,
        camera: &Camera,
        candidates: &[(DiamondId, Option<Info>)],
        errors: &[Option<f64>],
        until: Option<Instant>,
    ) -> IdMap<f64> {
        let past = || until.is_some_and(|u| Instant::now() >= u);
        if past() {
            return self.keep_last_ahead(IdMap::default(), self.config.prefetch_limit);
        }
        let velocity = self.last_camera.map_or(DVec3::ZERO, |c| camera.eye - c.eye);
        let ahead = velocity * self.config.lookahead_frames;
        let mut future = *camera;
        future.eye += ahead;
        future.target += ahead;
        let margin = self.config.prefetch_margin * (camera.target - camera.eye).length();
        let view = View::new(future, margin, &self.world);
        let now = View::new(*camera, 0.0, &self.world);
        if self.config.fetch_order == FetchOrder::ScreenErrorPerByte {
            // The priority then depends on what a plan lacks: every plan is looked at.
            let mut wanted = IdMap::default();
            self.prefetch_all(&view, &now, candidates, errors, &mut wanted);
            return most_urgent(wanted, self.config.prefetch_limit);
        }
        // Without a limit every contribution is planned, still most urgent first: what a
        // deadline cuts off is the least urgent.
        let limit = self.config.prefetch_limit.unwrap_or(usize::MAX);
        // Each contribution: a diamond whose plan is wanted, at its priority.
        let mut contributions = Vec::new();
        for (n, (&(id, info), &err_now)) in candidates.iter().zip(errors).enumerate() {
            if n % PREFETCH_CLOCK_STRIDE == PREFETCH_CLOCK_STRIDE - 1 && past() {
                return self.keep_last_ahead(IdMap::default(), Some(limit));
            }
            if let Some(err) = self.violation_of(id, info, &view) {
                contributions.push(Candidate {
                    err: err * PREFETCH_PRIORITY,
                    id,
                });
            }
            if self.violates(id, err_now) {
                for k in self.domain.children(id).into_iter().flatten() {
                    if let Some(err) = self.violation(k, &now) {
                        contributions.push(Candidate {
                            err: err * PREFETCH_PRIORITY,
                            id: k,
                        });
                    }
                }
            }
        }
        let mut contributions = BinaryHeap::from(contributions);
        let mut wanted = IdMap::default();
        // The priority of the contribution that brought `wanted` to the limit: every later one
        // as urgent is planned too (it may add diamonds that tie with the kept ones).
        let mut least_kept: Option<f64> = None;
        let mut planned = 0;
        while let Some(c) = contributions.pop() {
            if limit == 0 || least_kept.is_some_and(|p| c.err < p) {
                break;
            }
            planned += 1;
            if planned % PREFETCH_CLOCK_STRIDE == 0 && past() {
                #[cfg(debug_assertions)]
                {
                    let mut all = IdMap::default();
                    self.prefetch_all(&view, &now, candidates, errors, &mut all);
                    for (d, p) in &wanted {
                        assert_eq!(all.get(d), Some(p), "a prefetch cut short: {d}'s priority");
                    }
                }
                let kept = most_urgent(wanted, Some(limit));
                return self.keep_last_ahead(kept, Some(limit));
            }
            self.want_plan(c.id, c.err, &mut wanted);
            if least_kept.is_none() && wanted.len() >= limit {
                least_kept = Some(c.err);
            }
        }
        let kept = most_urgent(wanted, Some(limit));
        #[cfg(debug_assertions)]
        {
            let mut all = IdMap::default();
            self.prefetch_all(&view, &now, candidates, errors, &mut all);
            let all = most_urgent(all, Some(limit));
            let sorted = |m: &IdMap<f64>| {
                let mut v: Vec<(DiamondId, f64)> = m.iter().map(|(&d, &p)| (d, p)).collect();
                v.sort_unstable_by_key(|&(d, _)| d);
                v
            };
            assert_eq!(sorted(&kept), sorted(&all), "prefetch from the most urgent");
        }
        kept
    }

    /// A prefetch cut short: `kept`, and what the last frame prefetched that is still on its
    /// way (requested, not arrived), each at the larger of its priorities; at most `limit`, the
    /// most urgent.
    fn keep_last_ahead(&self, mut kept: IdMap<f64>, limit: Option<usize>) -> IdMap<f64> {
        for (&id, &p) in &self.last_ahead {
            if self.requests.requested.contains_key(&id) {
                let w = kept.entry(id).or_insert(p);
                *w = w.max(p);
            }
        }
        most_urgent(kept, limit)
    }

    /// [`Refiner::prefetch`] planning every contribution, in candidate order.
    fn prefetch_all(
        &mut self,
        view: &View,
        now: &View,
        candidates: &[(DiamondId, Option<Info>)],
        errors: &[Option<f64>],
        wanted: &mut IdMap<f64>,
    ) {
        for (&(id, info), &err_now) in candidates.iter().zip(errors) {
            if let Some(err) = self.violation_of(id, info, view) {
                self.want_plan(id, err * PREFETCH_PRIORITY, wanted);
            }
            if self.violates(id, err_now) {
                for k in self.domain.children(id).into_iter().flatten() {
                    let plan = self.plan(k);
                    if plan.iter().all(|&d| self.have_or_available(d)) {
                        continue; // nothing to want: skip the metric
                    }
                    if let Some(err) = self.violation(k, now) {
                        self.want_planned(&plan, err * PREFETCH_PRIORITY, wanted);
                    }
                }
            }
        }
    }

    /// Whether a candidate whose screen error is `err` violates the target (and has not been
    /// given up on).
    fn violates(&self, id: DiamondId, err: Option<f64>) -> bool {
        err.is_some_and(|e| e > self.config.pixel_error) && !self.requests.broken.contains(&id)
    }

    /// Remembers from now on, per record requested, whether its last request was a prefetch
    /// only ([`Refiner::last_requested_as_prefetch`]; benchmarks: an entry per record ever
    /// requested).
    pub fn track_prefetch_requests(&mut self) {
        self.requests.track_classes = true;
    }

    /// The source ids of the records whose last request was a prefetch only (see
    /// [`FrameStats::prefetch_wants`]), since [`Refiner::track_prefetch_requests`] (none
    /// without it): with the records fetched and those the cuts used, what prefetching fetched
    /// that no cut used.
    pub fn last_requested_as_prefetch(&self) -> impl Iterator<Item = DiamondId> + '_ {
        self.requests
            .last_class
            .iter()
            .filter(|&(_, &prefetch)| prefetch)
            .filter_map(|(&id, _)| self.source_id(id))
    }

    /// Starts refining `id` (whose parents are refined) on a worker thread.
    fn dispatch(&mut self, id: DiamondId, source: Source) {
        let given = self
            .domain
            .parents(id)
            .into_iter()
            .flatten()
            .map(|p| (p, self.cut_state.nodes[&p].clone()))
            .collect();
        self.dispatch_job(vec![(id, source)], given, false);
    }

    /// Starts one job on a worker thread: `steps` refined in order, each step's parents found
    /// among the earlier steps or in `given`.
    fn dispatch_job(
        &mut self,
        steps: Vec<(DiamondId, Source)>,
        given: Vec<(DiamondId, Arc<Node>)>,
        speculative: bool,
    ) {
        for &(id, _) in &steps {
            self.decoding.insert(id);
            if speculative {
                self.speculative.insert(id);
            }
        }
        if speculative {
            self.speculative_jobs += 1;
        }
        self.spawner.spawn_job(DecodeJob {
            decoder: self.decoder.clone(),
            drape: self.drape.clone(),
            domain: self.domain,
            given,
            shift: self.shift,
            seed: self.config.detail.map_or(0, |d| d.seed),
            steps,
            speculative,
            tx: self.done_tx.clone(),
            from_message: false,
        });
    }

    /// Frame step, after the refinement loop: hands the workers the refinements the view still
    /// needs, so that they decode until the next frame instead of idling. From the most urgent
    /// `leftovers` (refinement candidates the budget did not reach) down, most urgent first, it
    /// takes every diamond that violates the target in `view` and whose parents' data exists
    /// (refined, decoded ahead, or taken earlier in this pass: it does not need the cut),
    /// followed by its children. Each job refines its diamonds in that order; a diamond goes
    /// to the job holding its parents (skipped if they are in two), else to the least loaded.
    /// The results go to the decoded cache; the next frames' refinements take them from there
    /// without waiting. Because the metric is monotone (a child's error is at most its
    /// parents'), parents come before their children, and what a still view speculates is
    /// exactly what its converged cut refines: nothing is decoded in vain unless the view moves.
    fn speculate(&mut self, view: &View, leftovers: Vec<Candidate>, until: Option<Instant>) {
        // Workers at the frame thread's priority get one job fewer than there are of them, so
        // that the frame's own thread keeps a core (decoding ahead would pre-empt the next
        // frame's refinement: measured on 2 cores); workers that yield to it get one each
        // while frames are paced (PACED_BUDGETS).
        let workers = self.spawner.parallelism().max(1);
        let paced = self.paced();
        let max_jobs = if self.spawner.yields_to_caller() && paced {
            workers
        } else {
            workers.saturating_sub(1).max(1)
        };
        let free = max_jobs.saturating_sub(self.speculative_jobs);
        if free == 0 {
            return;
        }
        let per_job = (self.frame_interval_s / self.decode_s.max(1e-6)) as usize;
        let max_steps = per_job.clamp(*SPECULATIVE_STEPS.start(), *SPECULATIVE_STEPS.end());
        // What was decoded ahead for a view that has moved on (a diamond this view does not
        // refine) stays in the decoded cache like anything coarsened, but is no longer counted
        // as ahead: counted, it would take room that what this view needs could use (a fast
        // flight leaves such diamonds behind every frame). For a still view only what came
        // back since the last frame is looked at.
        let mut look_at: Vec<DiamondId> = self.ahead_arrived.drain().collect();
        if self.ahead_view == Some(view.camera) {
            let decoded = &self.residency.decoded;
            self.ahead.retain(|id| decoded.contains(id));
        } else {
            look_at.extend(self.ahead.drain());
            self.ahead_view = Some(view.camera);
        }
        for id in look_at {
            if self.residency.decoded.contains(&id) && self.violation(id, view).is_some() {
                self.ahead.insert(id);
            }
        }
        let room = AHEAD_LIMIT.saturating_sub(self.ahead.len() + self.speculative.len());
        let max_taken = (max_steps * free).min(room);
        struct Planned {
            steps: Vec<(DiamondId, Source)>,
            given: Vec<(DiamondId, Arc<Node>)>,
        }
        let mut jobs: Vec<Planned> = (0..free)
            .map(|_| Planned {
                steps: Vec::new(),
                given: Vec::new(),
            })
            .collect();
        // Which job refines a diamond taken in this pass; decoded ones (cut, cache) are
        // looked up when a job needs them.
        let mut job_of: IdMap<usize> = IdMap::default();
        let mut seen = IdSet::default();
        // Children pushed, each once (one that is also among the leftovers may come twice: the
        // second is passed over as seen; filling this with every leftover cost more, over a
        // network, where thousands lack their records).
        let mut queued = IdSet::default();
        let mut frontier = BinaryHeap::from(leftovers);
        let mut taken = 0;
        let mut looked = 0;
        // Diamonds to decode that could not be taken (record missing, parents not at hand, job
        // full), counted once `until` has passed.
        let mut missed_late: Option<usize> = None;
        while let Some(Candidate { id, .. }) = frontier.pop() {
            if taken >= max_taken || looked - taken >= SPECULATION_MISSES {
                break;
            }
            // Past `until`, the plan stops once it has taken a diamond per free worker, or has
            // missed LEAST_LOOKS a free worker since (until a diamond per worker is taken, the
            // clock is read every LEAST_LOOKS looks).
            if missed_late.is_none()
                && (taken >= free || looked % LEAST_LOOKS == 0)
                && until.is_some_and(|u| Instant::now() >= u)
            {
                missed_late = Some(0);
            }
            if let Some(missed) = missed_late
                && (taken >= free || missed >= LEAST_LOOKS * free)
            {
                break;
            }
            looked += 1;
            if !seen.insert(id) || self.cut_state.cut.is_refined(id) || self.decoding.contains(&id)
            {
                continue;
            }
            let decoded = self.residency.decoded.contains(&id);
            if !decoded {
                // The job of the parents taken in this pass, if any; the others must be at
                // hand.
                let mut job = None;
                let mut ok = true;
                for p in self.domain.parents(id).into_iter().flatten() {
                    if let Some(&j) = job_of.get(&p) {
                        ok &= job.is_none_or(|k| k == j);
                        job = Some(j);
                    } else {
                        ok &=
                            self.cut_state.cut.is_refined(p) || self.residency.decoded.contains(&p);
                    }
                }
                let j = job.unwrap_or_else(|| {
                    (0..free)
                        .min_by_key(|&j| jobs[j].steps.len())
                        .expect("at least one job")
                });
                let late_miss = |m: &mut Option<usize>| {
                    if let Some(m) = m {
                        *m += 1;
                    }
                };
                if !ok || jobs[j].steps.len() >= max_steps {
                    late_miss(&mut missed_late);
                    continue;
                }
                let source = match self.need(id) {
                    Need::Ready(Source::Cached(_)) | Need::Missing | Need::Impossible => {
                        late_miss(&mut missed_late);
                        continue;
                    }
                    Need::Ready(source) => source,
                };
                for p in self.domain.parents(id).into_iter().flatten() {
                    if job_of.contains_key(&p) || jobs[j].given.iter().any(|(g, _)| *g == p) {
                        continue;
                    }
                    let node = self
                        .cut_state
                        .nodes
                        .get(&p)
                        .or_else(|| self.residency.decoded.get(&p))
                        .cloned()
                        .expect("checked above");
                    jobs[j].given.push((p, node));
                }
                jobs[j].steps.push((id, source));
                job_of.insert(id, j);
                taken += 1;
            }
            for k in self.domain.children(id).into_iter().flatten() {
                // A child of two parents is looked at once.
                if !queued.insert(k) {
                    continue;
                }
                if let Some(err) = self.violation(k, view) {
                    frontier.push(Candidate { err, id: k });
                }
            }
        }
        for job in jobs {
            if !job.steps.is_empty() {
                self.dispatch_job(job.steps, job.given, true);
            }
        }
    }

    /// Puts a finished refinement into the cut, or into the cache if the cut moved on (a
    /// parent was coarsened meanwhile).
    fn apply(
        &mut self,
        done: Done,
        view: &View,
        heap: &mut BinaryHeap<Candidate>,
        stats: &mut FrameStats,
    ) {
        let id = done.id;
        if done.speculative {
            self.speculative.remove(&id);
            if done.last {
                self.speculative_jobs -= 1;
            }
        }
        self.decoding.remove(&id);
        if let Some(secs) = done.secs {
            stats.decode_ms += secs * 1e3;
            stats.decode_cpu_ms += done.cpu_secs.unwrap_or(0.0) * 1e3;
            stats.decoded += 1;
            self.decode_s += SMOOTHING * (secs - self.decode_s);
        }
        let node = match done.result {
            Some(Ok(node)) => node,
            Some(Err(e)) => {
                self.log_failure(id, format!("decoding {id} failed: {e}"));
                return;
            }
            // Not decoded: a step before it in its job failed.
            None => {
                self.heap_whole = false;
                return;
            }
        };
        let parents_refined = self
            .domain
            .parents(id)
            .into_iter()
            .flatten()
            .all(|p| self.cut_state.cut.is_refined(p));
        // Decoded ahead: into the cache, from which the refinement loop takes it (within its
        // budget and the cut's memory limit).
        if done.speculative {
            self.ahead_arrived.insert(id);
            if done.secs.is_some() {
                stats.decoded_ahead += 1;
            }
        }
        if !done.speculative && !parents_refined {
            self.heap_whole = false;
        }
        if done.speculative || self.cut_state.cut.is_refined(id) || !parents_refined {
            self.residency.keep_decoded(id, node);
            return;
        }
        self.residency.decoded.remove(&id);
        if self.ahead.remove(&id) | self.ahead_arrived.remove(&id) {
            stats.refined_ahead += 1;
        }
        self.residency.cut_bytes += node.bytes();
        if let Some(old) = self.cut_state.nodes.insert(id, node) {
            self.residency.cut_bytes -= old.bytes();
        }
        let children = self.refine_in_cut(id);
        stats.refinements += 1;
        for (k, info) in children.into_iter().flatten() {
            if let Some(err) = self.violation_of(k, info, view) {
                heap.push(Candidate { err, id: k });
            }
        }
    }

    /// Coarsens every refined diamond the view does not need, finest first (a coarsening
    /// heap ordered by ascending screen error, re-fed with parents that become leaves), or
    /// those it reaches by `until` (after at least `least`). Returns how many
    /// it coarsened and whether it found none left.
    fn collect_garbage(
        &mut self,
        view: &View,
        least: usize,
        until: Option<Instant>,
    ) -> (usize, bool) {
        // Collected, then made a heap in one pass.
        let unneeded: Vec<std::cmp::Reverse<Candidate>> = self
            .cut_state
            .leaves
            .iter()
            .filter_map(|(&id, info)| {
                let err = info.and_then(|i| view.error(&i)).unwrap_or(0.0);
                (err <= self.config.pixel_error).then_some(std::cmp::Reverse(Candidate { err, id }))
            })
            .collect();
        let mut heap = BinaryHeap::from(unneeded);
        let mut done = 0;
        while let Some(std::cmp::Reverse(c)) = heap.pop() {
            if done >= least && until.is_some_and(|u| Instant::now() >= u) {
                return (done, false);
            }
            if !self.coarsen_in_cut(c.id) {
                continue;
            }
            done += 1;
            self.release(c.id);
            for p in self.domain.parents(c.id).into_iter().flatten() {
                if self.cut_state.cut.is_refined(p)
                    && self.cut_state.is_leaf(&self.domain, p)
                    && let Some(c) = self.unneeded(p, view)
                {
                    heap.push(std::cmp::Reverse(c));
                }
            }
        }
        (done, true)
    }

    /// After `id` was coarsened: its node moves to the decoded cache.
    fn release(&mut self, id: DiamondId) {
        if let Some(node) = self.cut_state.nodes.remove(&id) {
            self.residency.retire(id, node);
        }
    }

    /// Makes room in the cut budget for one more node before `keep` is refined (or dispatched
    /// for decoding) to fix a screen error of `err`: coarsens refined leaves, smallest screen
    /// error first, while theirs is below `err`. Parents of `keep` and of diamonds being
    /// decoded stay. `pool` is this frame's coarsening heap, built on first need. False if the
    /// budget cannot be met that way.
    fn make_room(
        &mut self,
        err: f64,
        keep: DiamondId,
        view: &View,
        pool: &mut Option<BinaryHeap<std::cmp::Reverse<Candidate>>>,
        stats: &mut FrameStats,
    ) -> bool {
        let Some(limit) = self.config.cut_bytes else {
            return true;
        };
        // Worst case: every node with all four child halves and nodata masks.
        let node = Node::worst_bytes(self.domain.n(), self.drape.is_some());
        let fits = |me: &Self| {
            let regular = me.decoding.len() - me.speculative.len();
            me.residency.cut_bytes + (regular + 1) * node <= limit
        };
        if fits(self) {
            return true;
        }
        if pool.is_none() {
            let heap = self
                .cut_state
                .leaves
                .iter()
                .map(|(&id, info)| {
                    std::cmp::Reverse(Candidate {
                        err: info.and_then(|i| view.error(&i)).unwrap_or(0.0),
                        id,
                    })
                })
                .collect();
            *pool = Some(heap);
        }
        let heap = pool.as_mut().expect("built above");
        let mut kept = Vec::new();
        let ok = loop {
            if fits(self) {
                break true;
            }
            let Some(std::cmp::Reverse(c)) = heap.pop() else {
                break false;
            };
            // Entries go stale as the frame refines and coarsens.
            if !self.cut_state.cut.is_refined(c.id) || !self.cut_state.is_leaf(&self.domain, c.id) {
                continue;
            }
            if c.err >= err {
                heap.push(std::cmp::Reverse(c));
                break false;
            }
            let is_parent = |d: DiamondId| self.domain.parents(d).contains(&Some(c.id));
            if is_parent(keep) || self.decoding.iter().any(|&d| is_parent(d)) {
                kept.push(std::cmp::Reverse(c));
                continue;
            }
            if !self.coarsen_in_cut(c.id) {
                continue;
            }
            stats.coarsenings += 1;
            self.heap_whole = false;
            self.release(c.id);
            for p in self.domain.parents(c.id).into_iter().flatten() {
                if self.cut_state.cut.is_refined(p) && self.cut_state.is_leaf(&self.domain, p) {
                    let err = self.drawn_error(p, view);
                    heap.push(std::cmp::Reverse(Candidate { err, id: p }));
                }
            }
        };
        heap.extend(kept);
        ok
    }

    /// The screen error a refined diamond would show if coarsened: its own, 0 outside the
    /// frustum.
    fn drawn_error(&mut self, id: DiamondId, view: &View) -> f64 {
        self.info(id).and_then(|i| view.error(&i)).unwrap_or(0.0)
    }

    /// `Some` (with its error, for ordering) if a refined diamond is not needed by the view.
    fn unneeded(&mut self, id: DiamondId, view: &View) -> Option<Candidate> {
        let err = self.info(id).and_then(|i| view.error(&i)).unwrap_or(0.0);
        (err <= self.config.pixel_error).then_some(Candidate { err, id })
    }

    /// [`Refiner::worst_error`] over the cut's candidates in `view`.
    fn worst_of_candidates(&self, view: &View) -> f64 {
        self.worst_error(
            self.cut_state
                .candidates
                .iter()
                .map(|(&id, info)| (id, info.and_then(|i| view.error(&i)))),
        )
    }

    /// With a whole heap (see `heap_whole`), the frame's largest error found without a pass
    /// over every candidate: every candidate that violates the target is in `heap` or being
    /// decoded, so when one of them could still be refined, the largest of theirs is the
    /// largest of all. `None` when none could (the largest error is then within the target,
    /// and only the pass finds it).
    fn worst_violating(&self, view: &View, heap: &BinaryHeap<Candidate>) -> Option<f64> {
        let mut worst: Option<f64> = None;
        let mut consider = |me: &Self, id: DiamondId, err: f64| {
            if worst.is_none_or(|w| err > w)
                && me.cut_state.candidates.contains_key(&id)
                && !me.blocked(id)
            {
                worst = Some(err);
            }
        };
        for c in heap.iter() {
            consider(self, c.id, c.err);
        }
        for &id in &self.decoding {
            let info = self.cut_state.candidates.get(&id).copied().flatten();
            if let Some(err) = self.violation_of(id, info, view) {
                consider(self, id, err);
            }
        }
        worst
    }

    /// The largest of `errors` (the cut's candidates with their screen errors) that a
    /// refinement could still fix.
    fn worst_error(&self, errors: impl Iterator<Item = (DiamondId, Option<f64>)>) -> f64 {
        let mut worst = 0f64;
        for (id, e) in errors {
            if let Some(e) = e
                && e > worst
                && !self.blocked(id)
            {
                worst = e;
            }
        }
        worst
    }

    /// `worst` (from [`Refiner::worst_error`]), and how many refined diamonds garbage
    /// collection would remove (0, uncounted, when `worst` is above the target).
    fn measure(&mut self, view: &View, worst: f64) -> (f64, usize) {
        // Only a cut that meets the target can be converged, so only then does the count
        // matter: skip the pass over the whole cut otherwise.
        if worst > self.config.pixel_error {
            return (worst, 0);
        }
        let coarsenable = self
            .cut_state
            .leaves
            .values()
            .filter(|info| {
                info.and_then(|i| view.error(&i)).unwrap_or(0.0) <= self.config.pixel_error
            })
            .count();
        (worst, coarsenable)
    }
}
