//! Progress as a callback: the library reports, the caller draws (a bar, log lines, nothing).

/// The stage a [`ProgressEvent`] belongs to, in the order a build goes through them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Stage {
    /// Reading the input(s), planning the integer mapping and quantizing (one unit).
    Prepare,
    /// Encoding the hierarchy: `done` of `total` units of the encoder's work.
    Encode,
    /// `--extra-levels auto` of a single-input build: deciding whether to encode again with one
    /// more level pair, and doing so where the root field dominates the first repository (one
    /// unit).
    EncodeCoarserRoots,
    /// Writing the repository file (one unit).
    Write,
}

/// `done` of `total` units of `stage`; `done` never decreases within a stage and reaches
/// `total` when the stage ends.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ProgressEvent {
    /// The stage.
    pub stage: Stage,
    /// Units done so far.
    pub done: usize,
    /// Units in the stage.
    pub total: usize,
}

/// Receives a build's progress. Encoder workers report concurrently, hence `Sync` and `&self`;
/// events of [`Stage::Encode`] may arrive from several threads, out of order by a few units.
pub trait Progress: Sync {
    /// One step of a stage.
    fn event(&self, event: ProgressEvent);
    /// Whether the build continues an earlier run's journal ([`crate::journal`]), starts over,
    /// or starts fresh; reported once, before the encode, by builds that keep a journal.
    fn resumed(&self, _resumed: &crate::journal::Resumed) {}
    /// Something the user should know before the build goes on (a `--memory-limit` under
    /// what the build needs, [`crate::planet_memory::PlanetMemory::too_small`]).
    fn warning(&self, _message: &str) {}
}

/// Any `Fn(ProgressEvent) + Sync` closure is a [`Progress`] (resumption not reported).
impl<F: Fn(ProgressEvent) + Sync> Progress for F {
    fn event(&self, event: ProgressEvent) {
        self(event)
    }
}

/// Reports nothing.
pub struct NoProgress;

impl Progress for NoProgress {
    fn event(&self, _event: ProgressEvent) {}
}
