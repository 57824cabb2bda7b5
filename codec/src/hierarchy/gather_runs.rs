//! Where a child diamond's half lies on its parent's half-step grid, as runs of the parent's
//! rows: the order in which [`super::gather`] reads a parent (and prefetches it).

use super::Refined;
use crate::geometry::{Diagonal, DiamondId, Domain, Half, IndexMap};

/// One run of a parent's half-step row that a child's half covers: the `count` points `(a, b),
/// (a + 2, b), …`, which are the child's points at indices `start, start + out_step, …` of its
/// row-major `n × n` grid (a diagonal of it).
pub(super) struct HalfRun {
    pub(super) a: i64,
    pub(super) b: i64,
    pub(super) count: usize,
    pub(super) start: i64,
    pub(super) out_step: i64,
}

/// The runs of the parent's rows that cover the points of `half` (split diagonal included) of a
/// child's `n × n` grid mapped through `m`, in memory order of the parent (rows by growing `b`,
/// each by growing `a`). Read that way a parent's values come in whole cache lines; read row by
/// row of the child, every value would be on a line of its own.
pub(super) fn half_runs(
    m: &IndexMap,
    diag: Diagonal,
    half: Half,
    n: usize,
    mut visit: impl FnMut(HalfRun),
) {
    // Along a child diagonal where b is constant, i steps by 1 and j by σ (bi + bj·σ = 0), and
    // a by ai + aj·σ = ±2: walk each diagonal in the direction `dir` (of i) in which a grows.
    let sigma = -m.bi * m.bj;
    let dir = (m.ai + m.aj * sigma).signum();
    assert_eq!(
        (m.ai + m.aj * sigma).abs(),
        2,
        "a child grid maps onto a parent's diagonals"
    );
    let last = n as i64 - 1;
    let out_step = dir * (1 + sigma * n as i64);
    // The diagonals j − σ·i = t, in the order in which the parent's row b = b0 + bj·t grows.
    let lines = if sigma == 1 {
        -last..=last
    } else {
        0..=2 * last
    };
    let mut each_line = |t: i64| {
        let Some((lo, hi)) = half_line_range(diag, half, last, sigma, t) else {
            return;
        };
        let i = if dir > 0 { lo } else { hi };
        let j = t + sigma * i;
        let (a, b) = m.apply(i, j);
        visit(HalfRun {
            a,
            b,
            count: (hi - lo + 1) as usize,
            start: j * n as i64 + i,
            out_step,
        });
    };
    if m.bj > 0 {
        lines.for_each(&mut each_line);
    } else {
        lines.rev().for_each(&mut each_line);
    }
}

/// Where `id`'s points on `half` land on parent `pid`'s half-step grid (in the parent's face
/// frame); `None` if `pid` is not that half's parent.
pub(super) fn half_map(
    domain: &Domain,
    id: DiamondId,
    half: Half,
    pid: DiamondId,
) -> Option<IndexMap> {
    let layout = domain.layout();
    domain
        .grid_in_parent_frame(id, half, pid)?
        .index_map_into_half_step(&layout.grid(pid))
}

/// The columns `lo..=hi` of the points of `half` (split diagonal included, as `refine::half_range`
/// gives them row by row) on the child diagonal `j − σ·i = t` of a grid of side `last + 1`;
/// `None` when the diagonal has none.
fn half_line_range(
    diag: Diagonal,
    half: Half,
    last: i64,
    sigma: i64,
    t: i64,
) -> Option<(i64, i64)> {
    // In the grid: 0 ≤ i ≤ last and 0 ≤ j = t + σ·i ≤ last.
    let (mut lo, mut hi) = if sigma == 1 {
        ((-t).max(0), (last - t).min(last))
    } else {
        ((t - last).max(0), t.min(last))
    };
    let floor_half = |x: i64| x.div_euclid(2);
    let ceil_half = |x: i64| -(-x).div_euclid(2);
    // On the half: i ≥ j or i ≤ j (main split diagonal), i + j ≥ last or ≤ last (anti).
    let whole_line = match (diag, half, sigma) {
        (Diagonal::Main, Half::Positive, 1) => t <= 0,
        (Diagonal::Main, Half::Negative, 1) => t >= 0,
        (Diagonal::Anti, Half::Positive, -1) => t >= last,
        (Diagonal::Anti, Half::Negative, -1) => t <= last,
        (Diagonal::Main, Half::Positive, _) => {
            lo = lo.max(ceil_half(t));
            true
        }
        (Diagonal::Main, Half::Negative, _) => {
            hi = hi.min(floor_half(t));
            true
        }
        (Diagonal::Anti, Half::Positive, _) => {
            lo = lo.max(ceil_half(last - t));
            true
        }
        (Diagonal::Anti, Half::Negative, _) => {
            hi = hi.min(floor_half(last - t));
            true
        }
    };
    (whole_line && lo <= hi).then_some((lo, hi))
}

/// Asks for the values [`super::gather`] will read from `parents` for `id` to be brought into the
/// cache: called a diamond ahead, so that the parents' refinements (written a level earlier,
/// cold) arrive while the diamond before is decoded. A hint only: no effect on results.
pub(crate) fn prefetch_gather(domain: &Domain, id: DiamondId, parents: [Option<&Refined>; 2]) {
    if !cfg!(target_arch = "x86_64") || id.level == 0 {
        return;
    }
    let layout = domain.layout();
    let n = layout.n();
    let diag = layout.diagonal(id);
    let ids = domain.parents(id);
    for (h, half) in Half::BOTH.into_iter().enumerate() {
        let (Some(parent), Some(pid)) = (parents[h], ids[h]) else {
            continue;
        };
        let Some(m) = half_map(domain, id, half, pid) else {
            continue;
        };
        half_runs(&m, diag, half, n, |run| {
            parent.prefetch_row(run.a, run.b, run.count)
        });
    }
}
