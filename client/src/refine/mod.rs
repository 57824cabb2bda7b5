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
mod collect;
mod config;
mod detail;
mod drawn;
mod figures;
mod frame;
mod job;
mod node;
mod pacing;
mod refine_loop;
mod setup;
mod speculate;
mod state;
mod wants;
mod wire;

pub use cache::LruCache;
pub use config::{FetchOrder, Prefetch, RefineConfig};
pub use detail::DetailConfig;
pub use figures::{CacheUse, FrameStats, FrameSteps};
use job::Source;
pub use job::{DecodeJob, Done};
use node::Info;
use pacing::Pacing;
use speculate::Ahead;
use state::{CutState, Requests, Residency};
pub use wire::{HeadBytes, WorkerDecoder};

use std::collections::BinaryHeap;
use std::sync::Arc;
use std::time::Duration;

use cbdam_codec::CodecError;
use cbdam_codec::geometry::{Cut, DiamondId, Domain, IdMap, IdSet, Layout};
use cbdam_codec::hierarchy::Decoder;
use glam::DVec3;
use std::sync::mpsc::{Receiver, Sender};

use crate::access::{DataSource, Drape};
use crate::camera::{Camera, Frustum};
use crate::horizon::Horizon;
use crate::patch::HalfPatch;
use crate::spawn::{DefaultSpawner, Spawner};
use crate::world::World;

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
    /// The frames' timing: deadlines, overruns, smoothed rates (`pacing.rs`).
    pacing: Pacing,
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
    /// What is decoded ahead of the cut (`speculate.rs`).
    ahead: Ahead,
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
}
