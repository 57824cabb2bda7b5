//! What the refiner keeps per diamond: a refined node with its children's halves, and what the
//! error metric knows of a diamond.

use std::sync::Arc;

use cbdam_codec::colour::ColourRefined;
use cbdam_codec::hierarchy::Refined;
use glam::DVec3;

use crate::patch::HalfPatch;

/// A refined diamond: its refinement and the halves of its children that lie in it.
#[derive(Debug)]
pub(super) struct Node {
    pub(super) refined: Refined,
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
    /// A node of these parts (immutable after: it is shared as `Arc<Node>`).
    pub(super) fn new(
        refined: Refined,
        colour: Option<ColourRefined>,
        halves: [Option<Arc<HalfPatch>>; 4],
    ) -> Self {
        let heights = Self::bytes_for(
            refined.n(),
            halves.iter().flatten().count(),
            colour.is_some(),
        );
        // Nodata masks, one byte per point, where the record has any nodata.
        let masks = refined.validity().map_or(0, <[bool]>::len)
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

    /// Bytes it holds: heights, colour and nodata masks of the refinement and the halves.
    pub(super) fn bytes(&self) -> usize {
        self.bytes
    }

    /// Bytes of the heights of a node of an `n × n` diamond with `halves` child halves, and of
    /// its colour: three refined channels and a packed colour per child-half point. A refinement
    /// holds `n² + (n−1)²` values ([`Refined`]).
    pub(super) fn bytes_for(n: usize, halves: usize, colour: bool) -> usize {
        let refined = n * n + (n - 1) * (n - 1);
        let heights = 4 * (refined + halves * n * n);
        heights
            + if colour {
                4 * (3 * refined + halves * n * n)
            } else {
                0
            }
    }

    /// The most bytes a node of an `n × n` diamond can take: all four child halves, and nodata
    /// masks (one byte per point) on its `(2n−1)²` half-step grid and on each half.
    pub(super) fn worst_bytes(n: usize, colour: bool) -> usize {
        Self::bytes_for(n, 4, colour) + (2 * n - 1) * (2 * n - 1) + 4 * n * n
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
