//! The refinement loop's settings: the error target, the time budget, the caches, and how it
//! fetches and prefetches.

use super::DetailConfig;
use std::time::Duration;

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
