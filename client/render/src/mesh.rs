//! The patch grid's triangle lists, shared by every patch and uploaded once.
//!
//! A half-patch is drawn as the triangles of its half of the `N × N` grid that
//! [`half_grid_triangles`] lists, the triangulation the codec's cut is made of too (any other
//! split would leave T-junctions against the neighbouring patches). Which triangles those are
//! depends on the split diagonal and the half; which way round they wind in the world depends
//! on the grid map's orientation: even levels map `(i, j)` to the lattice with a positive
//! determinant, odd levels with a negative one, and the lattice's y runs south while the world's
//! runs north. So there are 2 × 2 × 2 lists, stored back to back in one index buffer; each is
//! drawn with one instanced draw call.

use std::ops::Range;

use cbdam_codec::geometry::{Diagonal, Half, half_grid_triangles};

/// Which of the 8 shared index lists a half-patch uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct MeshKind {
    /// The split diagonal of the diamond's grid.
    pub diagonal: Diagonal,
    /// The drawn half.
    pub half: Half,
    /// Whether the grid map has a negative determinant (odd levels).
    pub mirrored: bool,
}

impl MeshKind {
    /// All 8 kinds, in index-buffer order.
    pub fn all() -> [MeshKind; 8] {
        let mut out = [MeshKind {
            diagonal: Diagonal::Main,
            half: Half::Positive,
            mirrored: false,
        }; 8];
        for (k, o) in out.iter_mut().enumerate() {
            *o = MeshKind {
                diagonal: if k & 4 == 0 {
                    Diagonal::Main
                } else {
                    Diagonal::Anti
                },
                half: if k & 2 == 0 {
                    Half::Positive
                } else {
                    Half::Negative
                },
                mirrored: k & 1 == 1,
            };
        }
        out
    }

    /// Position in [`MeshKind::all`].
    pub fn index(self) -> usize {
        (usize::from(self.diagonal == Diagonal::Anti) << 2)
            | ((self.half as usize) << 1)
            | usize::from(self.mirrored)
    }
}

/// The shared index buffer's contents: grid vertex numbers `j·N + i`, and where each kind's list
/// lies in it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SharedMesh {
    /// Grid side `N`.
    pub n: usize,
    /// All 8 lists back to back.
    pub indices: Vec<u32>,
    /// Range of `indices` of each [`MeshKind`], by [`MeshKind::index`].
    pub ranges: [Range<u32>; 8],
}

impl SharedMesh {
    /// The lists for grid side `n`.
    pub fn new(n: usize) -> Self {
        let mut indices = Vec::with_capacity(8 * (n - 1) * (n - 1) * 3);
        let mut ranges: [Range<u32>; 8] = Default::default();
        for kind in MeshKind::all() {
            let start = indices.len() as u32;
            half_indices(n, kind, &mut indices);
            ranges[kind.index()] = start..indices.len() as u32;
        }
        Self { n, indices, ranges }
    }

    /// Triangles in one half-patch.
    pub fn triangles_per_patch(&self) -> u32 {
        self.ranges[0].len() as u32 / 3
    }
}

/// Appends the triangles of one half, counter-clockwise in the world seen from above.
fn half_indices(n: usize, kind: MeshKind, out: &mut Vec<u32>) {
    let vertex = |(i, j): (i64, i64)| (j * n as i64 + i) as u32;
    for [a, b, c] in half_grid_triangles(n, kind.diagonal, kind.half) {
        // Listed counter-clockwise in (i, j) with j down, i.e. clockwise in a right-handed
        // (i, j). Even levels keep that handedness into the lattice (x east, y south); the world
        // flips y; odd levels flip once more.
        if kind.mirrored {
            out.extend([vertex(a), vertex(b), vertex(c)]);
        } else {
            out.extend([vertex(a), vertex(c), vertex(b)]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cbdam_codec::geometry::{Cut, DiamondId, Domain, Layout, Triangle};
    use std::collections::BTreeSet;

    fn world_area2(p: [(i64, i64); 3]) -> i64 {
        // World (x, −y): flip y, then the usual cross product.
        let w = p.map(|(x, y)| (x, -y));
        (w[1].0 - w[0].0) * (w[2].1 - w[0].1) - (w[2].0 - w[0].0) * (w[1].1 - w[0].1)
    }

    /// For cuts from the coarsest through random ones to the finest, the shared lists of every
    /// drawn half mapped through its grid map are exactly the codec's `Cut::triangles`, and
    /// every triangle is counter-clockwise in the world frame seen from above.
    #[test]
    fn shared_lists_match_the_codec_triangulation() {
        let domain = Domain::full_plane(Layout::new(5, 2, 2, 1).unwrap());
        let layout = *domain.layout();
        let mesh = SharedMesh::new(layout.n());
        let n = layout.n() as u32;
        let mut ids = Vec::new();
        let mut frontier: Vec<DiamondId> = layout.roots().collect();
        while let Some(d) = frontier.pop() {
            if !ids.contains(&d) {
                ids.push(d);
                frontier.extend(layout.children(d).into_iter().flatten());
            }
        }
        let mut cut = Cut::new();
        let mut state = 99u64;
        for round in 0..12 {
            let mut ours: Vec<[(i64, i64); 3]> = Vec::new();
            for (id, half) in cut.drawn_halves(&domain) {
                let g = layout.grid(id);
                let kind = MeshKind {
                    diagonal: layout.diagonal(id),
                    half,
                    mirrored: !id.is_even(),
                };
                let r = mesh.ranges[kind.index()].clone();
                assert_eq!(r.len() as u32, 3 * mesh.triangles_per_patch());
                for t in mesh.indices[r.start as usize..r.end as usize].chunks(3) {
                    let p = [0, 1, 2].map(|k| g.point(i64::from(t[k] % n), i64::from(t[k] / n)));
                    assert!(world_area2(p) > 0, "{id} {half:?}: {p:?} not CCW in world");
                    ours.push(p);
                }
            }
            let codec: Vec<Triangle> = cut.triangles(&domain);
            let norm = |t: &[(i64, i64); 3]| t.iter().copied().collect::<BTreeSet<_>>();
            let a: BTreeSet<_> = ours.iter().map(norm).collect();
            let b: BTreeSet<_> = codec.iter().map(norm).collect();
            assert_eq!(
                (a.len(), ours.len()),
                (b.len(), codec.len()),
                "round {round}"
            );
            assert_eq!(a, b, "round {round}");
            // Next: a few more random refinements; the last round refines everything.
            for _ in 0..3 {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                cut.refine(&domain, ids[(state >> 33) as usize % ids.len()]);
            }
            if round == 10 {
                for &d in &ids {
                    cut.refine(&domain, d);
                }
            }
        }
    }

    #[test]
    fn kinds_index_round_trips() {
        for (k, kind) in MeshKind::all().into_iter().enumerate() {
            assert_eq!(kind.index(), k);
        }
    }
}
