//! A decode job: what a worker needs to refine a few diamonds, owned so that it outlives the
//! frame, and what comes back ([`Done`]).
//!
//! A [`DecodeJob`] is a [`Portable`](crate::spawn::Portable) job: a spawner with threads runs
//! it in place (`Portable::run`, no copying), and one whose workers share no memory with the
//! refiner (Web Workers) sends it as bytes (`Portable::encode`) to a
//! [`WorkerDecoder`](super::WorkerDecoder) and hands the answer back (`Portable::receive`); the
//! byte formats, and that implementation, are in `wire.rs`.

use std::sync::Arc;
use std::sync::mpsc::Sender;

use cbdam_codec::CodecError;
use cbdam_codec::colour::ColourRefined;
use cbdam_codec::geometry::{Diagonal, DiamondId, Domain};
use cbdam_codec::hierarchy::{
    Decoder, RefineScratch, Refined, gather, gather_validity, join_halves,
};
use web_time::Instant;

use super::detail;
use super::node::Node;
use crate::access::{Drape, MappedRecord, coloured};
use crate::patch::{HalfPatch, colour_from_parent};

/// How a diamond's refinement can be had.
pub(super) enum Source {
    Cached(Arc<Node>),
    Record(Arc<[u8]>),
    /// A record of a mapped file, read and checked by the worker.
    Mapped(MappedRecord),
    /// A record that could not be read where the job was made (a job sent as bytes reads its
    /// mapped records before it goes): the step fails with this error.
    Unreadable(CodecError),
    Synthetic(i32),
}

/// A finished (or failed) refinement coming back from a worker.
#[derive(Debug)]
pub struct Done {
    pub(super) id: DiamondId,
    /// `None`: not decoded, because a step before it in its job failed.
    pub(super) result: Option<Result<Arc<Node>, CodecError>>,
    /// Worker time (wall); `None` when nothing was decoded (served from the cache).
    pub(super) secs: Option<f64>,
    /// Of `secs`, the worker thread's CPU time where the platform measures it (Unix): the
    /// wall time also holds what the worker waited for a core (its priority is below the
    /// frame thread's).
    pub(super) cpu_secs: Option<f64>,
    /// Decoded ahead of the cut by a speculative job.
    pub(super) speculative: bool,
    /// The last step of its job.
    pub(super) last: bool,
}

/// The parents' nodes of a diamond being refined, in [`Domain::parents`] order.
type ParentNodes = [Option<Arc<Node>>; 2];

/// What a worker needs to refine diamonds, owned so that it outlives the frame: the decoding
/// settings, the diamonds to refine in order (`steps`, each step's parents found among the
/// earlier steps or in `given`), and where to send each result.
pub struct DecodeJob {
    pub(super) decoder: Arc<Decoder>,
    pub(super) drape: Option<Arc<Drape>>,
    pub(super) domain: Domain,
    /// Nodes of the steps' parents that are not steps themselves.
    pub(super) given: Vec<(DiamondId, Arc<Node>)>,
    pub(super) shift: u32,
    pub(super) seed: u64,
    pub(super) steps: Vec<(DiamondId, Source)>,
    /// Decoded ahead of the cut (the results go to the decoded cache).
    pub(super) speculative: bool,
    pub(super) tx: Sender<Done>,
    /// Read from a message (in a worker): the given parents are not the refiner's own, so each
    /// step first checks that its two parents agree on its diagonal (gathering assumes it).
    pub(super) from_message: bool,
    /// Whether the nodes made keep their refinements once their children's halves are made:
    /// the refiner's spawner sends jobs as messages, which carry refinements
    /// ([`Spawner::sends_jobs_as_messages`](crate::spawn::Spawner::sends_jobs_as_messages)).
    pub(super) keep_refined: bool,
}

impl DecodeJob {
    /// How many diamonds the job refines.
    pub fn len(&self) -> usize {
        self.steps.len()
    }

    /// Whether the job refines nothing.
    pub fn is_empty(&self) -> bool {
        self.steps.is_empty()
    }

    /// Refines the steps in order (each step's parents are earlier steps or given), sending each
    /// result as soon as it is made. A step whose parent failed is skipped.
    pub(super) fn run_steps(self) {
        let rest = self.run_until(&|| false);
        debug_assert!(rest.is_none());
    }

    /// [`DecodeJob::run_steps`], asking `stop` after each step but the last: when it says so,
    /// returns the job of the steps not run yet (its parents given: the results so far), which
    /// goes on where this one stopped.
    pub(super) fn run_until(mut self, stop: &dyn Fn() -> bool) -> Option<Self> {
        let mut steps = std::mem::take(&mut self.steps);
        steps.reverse();
        let speculative = self.speculative;
        while let Some((id, source)) = steps.pop() {
            let ids = self.domain.parents(id);
            let parents: ParentNodes = ids.map(|p| {
                p.and_then(|p| {
                    self.given
                        .iter()
                        .find(|(g, _)| *g == p)
                        .map(|(_, n)| n.clone())
                })
            });
            let complete = id.level == 0
                || ids
                    .iter()
                    .zip(&parents)
                    .all(|(i, n)| i.is_some() == n.is_some());
            // The CPU clock is read inside the wall clock's interval, so that its own cost (a
            // system call) never makes the CPU time exceed the wall time.
            let t = Instant::now();
            let cpu = crate::stats::thread_cpu_seconds();
            let (result, secs, cpu_secs) =
                if complete && self.from_message && !self.parents_agree(id, &parents) {
                    let e = CodecError::corrupt(format!(
                        "the parents of {id} disagree on its diagonal"
                    ));
                    (Some(Err(e)), None, None)
                } else if complete {
                    let r = self.refine(id, source, &parents);
                    let cpu_secs = cpu
                        .zip(crate::stats::thread_cpu_seconds())
                        .map(|(a, b)| b - a);
                    (Some(r), Some(t.elapsed().as_secs_f64()), cpu_secs)
                } else {
                    (None, None, None)
                };
            if let Some(Ok(node)) = &result {
                self.given.push((id, node.clone()));
            }
            // The refiner may be gone; then nobody wants the result.
            let _ = self.tx.send(Done {
                id,
                result,
                secs,
                cpu_secs,
                speculative,
                last: steps.is_empty(),
            });
            if !steps.is_empty() && stop() {
                steps.reverse();
                self.steps = steps;
                return Some(self);
            }
        }
        None
    }

    /// Whether both parents (if there are two) give the same values on `id`'s diagonal, for
    /// the heights and the colour channels.
    fn parents_agree(&self, id: DiamondId, parents: &ParentNodes) -> bool {
        let [Some(a), Some(b)] = parents else {
            return true;
        };
        let ids = self.domain.parents(id);
        let n = self.domain.n();
        let diagonal = self.domain.layout().diagonal(id);
        let on_diagonal = |j: usize| match diagonal {
            Diagonal::Main => j * n + j,
            Diagonal::Anti => j * n + (n - 1 - j),
        };
        // Each parent alone (the other half mirrored): their diagonals must be the same.
        let agree = |x: &Refined, y: &Refined| {
            let (mut gx, mut gy) = (vec![0i32; n * n], vec![0i32; n * n]);
            gather(&self.domain, id, [Some(x), None], &mut gx);
            gather(&self.domain, id, [None, Some(y)], &mut gy);
            (0..n).all(|j| gx[on_diagonal(j)] == gy[on_diagonal(j)])
        };
        if ids.iter().any(Option::is_none) {
            return true;
        }
        let (Some(ra), Some(rb)) = (a.refined(), b.refined()) else {
            unreachable!("a worker's nodes keep their refinements")
        };
        agree(ra, rb)
            && match (&a.colour, &b.colour) {
                (Some(ca), Some(cb)) => (0..3).all(|c| agree(&ca[c], &cb[c])),
                _ => true,
            }
    }

    fn refine(
        &self,
        id: DiamondId,
        source: Source,
        parents: &ParentNodes,
    ) -> Result<Arc<Node>, CodecError> {
        match source {
            Source::Cached(node) => Ok(node),
            Source::Record(bytes) => self.decode_record(id, &bytes, parents),
            Source::Mapped(record) => self.decode_record(id, record.bytes()?, parents),
            Source::Unreadable(e) => Err(e),
            Source::Synthetic(amp) => {
                let grid = self.grid_of(id, parents);
                let valid = self.validity_of(id, parents);
                let r = detail::synthesize(
                    self.domain.layout(),
                    id,
                    &grid,
                    valid.as_deref(),
                    amp,
                    self.seed,
                );
                // Synthetic detail is for the relief; the colour is interpolated.
                let c = self.refine_colour(id, &[], parents)?;
                Ok(self.node(id, r, c))
            }
        }
    }

    /// Refines `id` by its record (an elevation–colour pair when a colour is draped).
    fn decode_record(
        &self,
        id: DiamondId,
        bytes: &[u8],
        parents: &ParentNodes,
    ) -> Result<Arc<Node>, CodecError> {
        let (elevation, colour) = match self.drape {
            Some(_) => coloured::split(bytes)?,
            None => (bytes, &[][..]),
        };
        // The grid is only read by the refinement: one buffer per worker, not one per diamond.
        let r = GRID.with_borrow_mut(|grid| {
            self.grid_into(id, parents, grid);
            SCRATCH.with_borrow_mut(|s| self.decoder.refine(id, grid, elevation, s))
        })?;
        let c = self.refine_colour(id, colour, parents)?;
        Ok(self.node(id, r, c))
    }

    /// The colour refinement of `id` by its colour record (empty: the prediction from the
    /// colour parents), when a colour is draped.
    fn refine_colour(
        &self,
        id: DiamondId,
        record: &[u8],
        parents: &ParentNodes,
    ) -> Result<Option<ColourRefined>, CodecError> {
        let Some(drape) = &self.drape else {
            return Ok(None);
        };
        let grids = if id.level == 0 {
            let sid = id.coarser(self.shift);
            root_colour(drape, sid)?
        } else {
            let n = self.domain.n();
            let mut grids: [Vec<i32>; 3] = Default::default();
            for (c, g) in grids.iter_mut().enumerate() {
                let parents = [0, 1].map(|h| {
                    parents[h]
                        .as_ref()
                        .and_then(|p| p.colour.as_ref())
                        .map(|col| &col[c])
                });
                *g = vec![0i32; n * n];
                gather(&self.domain, id, parents, g);
            }
            grids
        };
        // The colour channels have their own decoder but the elevation's geometry: the same
        // `N`, and ids that name the same ground (`Alignment`), so the grids gathered in the
        // elevation's layout are the colour's.
        let r = SCRATCH.with_borrow_mut(|s| drape.decoder.refine(&grids, record, s))?;
        Ok(Some(r))
    }

    fn grid_of(&self, id: DiamondId, parents: &ParentNodes) -> Vec<i32> {
        let mut grid = Vec::new();
        self.grid_into(id, parents, &mut grid);
        grid
    }

    /// [`DecodeJob::grid_of`] into `grid` (resized to `N × N`, every value written), so that a
    /// worker can keep one buffer for every diamond it refines.
    fn grid_into(&self, id: DiamondId, parents: &ParentNodes, grid: &mut Vec<i32>) {
        if id.level == 0 {
            let sid = id.coarser(self.shift);
            *grid = self.decoder.grid_of(sid, [None, None]);
            return;
        }
        let n = self.domain.n();
        grid.resize(n * n, 0);
        let grid = &mut grid[..];
        if let Some(halves) = self.halves_of(id, parents) {
            let heights = halves.map(|h| h.map(|h| &h.heights[..]));
            let diagonal = self.domain.layout().diagonal(id);
            join_halves(diagonal, n, heights, grid);
            debug_assert!(
                heights.iter().flatten().all(|h| (0..n).all(|j| {
                    let k = match diagonal {
                        Diagonal::Main => j * n + j,
                        Diagonal::Anti => j * n + n - 1 - j,
                    };
                    h[k] == grid[k]
                })),
                "the parents of {id} disagree on its diagonal"
            );
            return;
        }
        gather(&self.domain, id, refinements(parents), grid);
    }

    /// The halves of `id` that its parents' nodes hold (made when each parent was refined),
    /// in [`Domain::parents`] order: gathering `id`'s grid from them is a copy of rows, where
    /// gathering from the parents' refinements reads them on diagonals. `None` when a parent's
    /// node has no halves (one read from a message).
    fn halves_of<'a>(
        &self,
        id: DiamondId,
        parents: &'a ParentNodes,
    ) -> Option<[Option<&'a HalfPatch>; 2]> {
        let ids = self.domain.parents(id);
        let mut halves = [None, None];
        for h in 0..2 {
            let (Some(pid), Some(node)) = (ids[h], &parents[h]) else {
                continue;
            };
            let slot = self
                .domain
                .children(pid)
                .iter()
                .position(|c| *c == Some(id))?;
            halves[h] = Some(node.halves[slot].as_deref()?);
        }
        Some(halves)
    }

    fn validity_of(&self, id: DiamondId, parents: &ParentNodes) -> Option<Vec<bool>> {
        if id.level == 0 {
            let sid = id.coarser(self.shift);
            return self.decoder.validity_of(sid, [None, None]);
        }
        if let Some(halves) = self.halves_of(id, parents) {
            if halves.iter().flatten().all(|h| h.valid.is_none()) {
                return None;
            }
            let n = self.domain.n();
            let all = vec![true; n * n];
            let valid = halves.map(|h| h.map(|h| h.valid.as_deref().unwrap_or(&all)));
            let mut out = vec![true; n * n];
            join_halves(self.domain.layout().diagonal(id), n, valid, &mut out);
            return Some(out);
        }
        gather_validity(&self.domain, id, refinements(parents))
    }

    pub(super) fn node(
        &self,
        id: DiamondId,
        refined: Refined,
        colour: Option<ColourRefined>,
    ) -> Arc<Node> {
        let n = self.domain.n();
        let children = self.domain.children(id);
        // In a worker the node is only sent back (the refiner rebuilds the halves from its
        // refinement) or gathered from: its children's halves would be thrown away.
        if self.from_message {
            return Arc::new(Node::new(
                n,
                Some(refined),
                colour,
                Default::default(),
                children,
            ));
        }
        let halves = children.map(|c| {
            c.and_then(|c| {
                let mut h = HalfPatch::from_parent(&self.domain, c, id, &refined)?;
                if let Some(col) = &colour {
                    h.colour = colour_from_parent(&self.domain, c, id, col);
                }
                Some(Arc::new(h))
            })
        });
        // Gathering a child's grid reads its halves, not the refinement: keeping it only to
        // send it in a message saves its memory (a third of a node) on every other spawner.
        let refined = self.keep_refined.then_some(refined);
        Arc::new(Node::new(n, refined, colour, halves, children))
    }
}

/// The parents' refinements, for gathering a grid from nodes that hold no halves (which keep
/// their refinements: [`Node::new`]).
fn refinements(parents: &ParentNodes) -> [Option<&Refined>; 2] {
    parents.each_ref().map(|p| {
        p.as_ref().map(|n| {
            n.refined()
                .expect("a node without its children's halves keeps its refinement")
        })
    })
}

/// The Y, Co, Cg grids of the colour root covering elevation root `root`.
pub(super) fn root_colour(drape: &Drape, root: DiamondId) -> Result<[Vec<i32>; 3], CodecError> {
    let c = drape.alignment.colour_id(root).ok_or_else(|| {
        CodecError::invalid(format!("no colour root covers elevation root {root}"))
    })?;
    Ok(drape.decoder.grid_of(c, [None, None]))
}

thread_local! {
    /// Decoding buffers, one set per worker thread.
    static SCRATCH: std::cell::RefCell<RefineScratch> = std::cell::RefCell::default();
    /// The grid of the diamond a worker refines ([`DecodeJob::grid_into`]), one per worker
    /// thread.
    static GRID: std::cell::RefCell<Vec<i32>> = std::cell::RefCell::default();
}
