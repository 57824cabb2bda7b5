//! What the refiner keeps per diamond: a refined node with its children's halves, and what the
//! error metric knows of a diamond.

use std::sync::Arc;

use cbdam_codec::colour::ColourRefined;
use cbdam_codec::geometry::DiamondId;
use cbdam_codec::hierarchy::Refined;
use glam::DVec3;

use crate::patch::HalfPatch;

/// A refined diamond: the halves of its children that lie in it and, where they are not
/// enough, its refinement.
#[derive(Debug)]
pub(super) struct Node {
    /// The refinement, kept where something reads it again: a node sent to a worker that shares
    /// no memory with the refiner (a message carries the refinement, not the halves), or one
    /// made without its children's halves (in such a worker). `None` only when every child's
    /// half is in `halves` — all that gathering a child's grid reads.
    refined: Option<Refined>,
    /// Y, Co, Cg refined alike, when a colour repository is draped over the terrain.
    pub(super) colour: Option<ColourRefined>,
    /// `halves[i]` is the half of `children[i]` lying in this diamond.
    pub(super) halves: [Option<Arc<HalfPatch>>; 4],
    /// What [`Node::bytes`] answers, counted once: the refiner asks on every refinement,
    /// coarsening and cache move, and counting touches every half (four cache lines that the
    /// frame thread otherwise never reads).
    bytes: usize,
}

impl Node {
    /// A node of these parts (immutable after: it is shared as `Arc<Node>`), of an `n × n`
    /// diamond. `refined` may be `None` only when `halves` holds the half of every child
    /// `children` names (in [`Domain::children`](cbdam_codec::geometry::Domain::children)
    /// order).
    pub(super) fn new(
        n: usize,
        refined: Option<Refined>,
        colour: Option<ColourRefined>,
        halves: [Option<Arc<HalfPatch>>; 4],
        children: [Option<DiamondId>; 4],
    ) -> Self {
        assert!(
            refined.is_some() || (0..4).all(|i| children[i].is_none() || halves[i].is_some()),
            "a node without its refinement holds every child's half"
        );
        let heights = Self::bytes_for(
            n,
            refined.is_some(),
            halves.iter().flatten().count(),
            colour.is_some(),
        );
        // Nodata masks, one byte per point, where the record has any nodata.
        let masks = refined
            .as_ref()
            .and_then(Refined::validity)
            .map_or(0, <[bool]>::len)
            + halves
                .iter()
                .flatten()
                .filter_map(|h| h.valid.as_ref())
                .map(Vec::len)
                .sum::<usize>();
        Self {
            refined,
            colour,
            halves,
            bytes: heights + masks,
        }
    }

    /// The refinement, where the node kept it ([`Node::new`]).
    pub(super) fn refined(&self) -> Option<&Refined> {
        self.refined.as_ref()
    }

    /// Bytes it holds: heights, colour and nodata masks of the refinement and the halves.
    pub(super) fn bytes(&self) -> usize {
        self.bytes
    }

    /// Bytes of the heights of a node of an `n × n` diamond, with its refinement or not and
    /// with `halves` child halves, and of its colour: three refined channels and a packed colour
    /// per child-half point. A refinement holds `n² + (n−1)²` values ([`Refined`]).
    pub(super) fn bytes_for(n: usize, refined: bool, halves: usize, colour: bool) -> usize {
        let values = n * n + (n - 1) * (n - 1);
        let heights = 4 * (usize::from(refined) * values + halves * n * n);
        heights
            + if colour {
                4 * (3 * values + halves * n * n)
            } else {
                0
            }
    }

    /// The most bytes a node of an `n × n` diamond can take: its refinement, all four child
    /// halves, and nodata masks (one byte per point) on its `(2n−1)²` half-step grid and on each
    /// half.
    pub(super) fn worst_bytes(n: usize, colour: bool) -> usize {
        Self::bytes_for(n, true, 4, colour) + (2 * n - 1) * (2 * n - 1) + 4 * n * n
    }
}

/// What the metric knows of a refinable diamond.
#[derive(Clone, Copy, Debug)]
pub(super) struct Info {
    /// Saturated object-space error, metres.
    pub(super) err_m: f64,
    /// Saturated world bounding box.
    pub(super) lo: DVec3,
    pub(super) hi: DVec3,
}
