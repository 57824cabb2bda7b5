//! Cuts of the diamond DAG and the triangles they draw.

use std::collections::HashMap;

use super::grid::half_grid_triangles;
use super::{DiamondId, Domain, FacePoint, GridMap, Half, IdSet, Layout};

/// A triangle in lattice coordinates, counter-clockwise (x east, y south counts as a right-handed
/// frame here: only consistency matters).
pub type Triangle = [(i64, i64); 3];

/// A triangle on one face, in that face's lattice coordinates: `(face, triangle)`.
pub type FaceTriangle = (u8, Triangle);

/// A cut: the set of refined diamonds, closed under "parents of a refined diamond are refined".
///
/// Kept as a hash set only: the refinement loop refines and looks up thousands of diamonds a
/// frame, and asks for them in order only when something is drawn or compared whole. With an
/// ordered set beside it, `refine` took 10.6 % of the client's refinement loop (perf samples of
/// a paced `low_pass` replay's last 1.5 s), without 4.9 %.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Cut {
    lookup: IdSet,
}

impl Cut {
    /// The coarsest cut: only the roots, none refined.
    pub fn new() -> Self {
        Self::default()
    }

    /// Whether `id` is refined.
    pub fn is_refined(&self, id: DiamondId) -> bool {
        self.lookup.contains(&id)
    }

    /// The refined diamonds, coarse to fine (sorted on each call: see [`Cut::refined_unordered`]).
    pub fn refined(&self) -> impl Iterator<Item = DiamondId> + '_ {
        let mut ids: Vec<DiamondId> = self.lookup.iter().copied().collect();
        ids.sort_unstable();
        ids.into_iter()
    }

    /// The refined diamonds in no particular order, without sorting them.
    pub fn refined_unordered(&self) -> impl Iterator<Item = DiamondId> + '_ {
        self.lookup.iter().copied()
    }

    /// How many diamonds are refined.
    pub fn len(&self) -> usize {
        self.lookup.len()
    }

    /// Whether no diamond is refined (the coarsest cut).
    pub fn is_empty(&self) -> bool {
        self.lookup.is_empty()
    }

    /// Refines `id`, first forcing its parents (recursively). Returns the diamonds newly
    /// refined, parents before children. Diamonds of the finest level cannot be refined.
    pub fn refine(&mut self, domain: &Domain, id: DiamondId) -> Vec<DiamondId> {
        let mut done = Vec::new();
        self.refine_into(domain, id, &mut done);
        done
    }

    fn refine_into(&mut self, domain: &Domain, id: DiamondId, done: &mut Vec<DiamondId>) {
        if self.lookup.contains(&id) || id.level >= domain.finest_level() || !domain.contains(id) {
            return;
        }
        for p in domain.parents(id).into_iter().flatten() {
            self.refine_into(domain, p, done);
        }
        self.lookup.insert(id);
        done.push(id);
    }

    /// Undoes the refinement of `id` if none of its children is refined. Returns whether it did.
    pub fn coarsen(&mut self, domain: &Domain, id: DiamondId) -> bool {
        let blocked = domain
            .children(id)
            .into_iter()
            .flatten()
            .any(|c| self.lookup.contains(&c));
        !blocked && self.lookup.remove(&id)
    }

    /// The halves the cut draws: the half of `K` lying in parent `A` is drawn iff `A` is refined
    /// and `K` is not; unrefined roots draw both halves.
    pub fn drawn_halves(&self, domain: &Domain) -> Vec<(DiamondId, Half)> {
        let mut out: Vec<(DiamondId, Half)> = domain
            .roots()
            .filter(|r| !self.lookup.contains(r))
            .flat_map(|r| Half::BOTH.map(|h| (r, h)))
            .collect();
        for a in self.refined() {
            for k in domain.children(a).into_iter().flatten() {
                if !self.lookup.contains(&k) {
                    let half = domain.half_in(k, a).expect("child lists its parent");
                    out.push((k, half));
                }
            }
        }
        out
    }

    /// All triangles the cut draws, in lattice coordinates of each diamond's own face (on a
    /// cube-sphere the half of an edge diamond on the neighbouring face comes out past the
    /// edge; [`Cut::face_triangles`] puts it on its face).
    pub fn triangles(&self, domain: &Domain) -> Vec<Triangle> {
        let mut out = Vec::new();
        for (id, half) in self.drawn_halves(domain) {
            half_triangles(domain.layout(), id, half, &mut out);
        }
        out
    }

    /// All triangles the cut draws, each on the face it lies on, in that face's lattice
    /// coordinates (on a plane: face 0 and the same triangles as [`Cut::triangles`]).
    pub fn face_triangles(&self, domain: &Domain) -> Vec<FaceTriangle> {
        let mut out = Vec::new();
        let mut tris = Vec::new();
        for (id, half) in self.drawn_halves(domain) {
            let (face, grid) = domain.half_grid(id, half);
            tris.clear();
            half_triangles_on(domain.layout(), id, half, &grid, &mut tris);
            out.extend(tris.iter().map(|&t| (face, t)));
        }
        out
    }
}

/// Appends the triangles of one half of a diamond: its grid cells split parallel to the split
/// diagonal, so that each half is a union of whole grid triangles.
pub fn half_triangles(layout: &Layout, id: DiamondId, half: Half, out: &mut Vec<Triangle>) {
    half_triangles_on(layout, id, half, &layout.grid(id), out);
}

/// [`half_triangles`] with the diamond's grid placed by `g` (its own, or carried onto another
/// face's frame).
fn half_triangles_on(
    layout: &Layout,
    id: DiamondId,
    half: Half,
    g: &GridMap,
    out: &mut Vec<Triangle>,
) {
    for t in half_grid_triangles(layout.n(), layout.diagonal(id), half) {
        let mut p = t.map(|(a, b)| g.point(a, b));
        if signed_area2(&p) < 0 {
            p.swap(1, 2);
        }
        out.push(p);
    }
}

fn signed_area2(t: &Triangle) -> i64 {
    (t[1].0 - t[0].0) * (t[2].1 - t[0].1) - (t[2].0 - t[0].0) * (t[1].1 - t[0].1)
}

/// Checks that `triangles` form a conforming triangulation of the whole planar domain (see
/// [`check_conforming_surface`], which this is for face-0 triangles).
pub fn check_conforming(domain: &Domain, triangles: &[Triangle]) -> Result<(), String> {
    let on_face: Vec<FaceTriangle> = triangles.iter().map(|&t| (0, t)).collect();
    check_conforming_surface(domain, &on_face)
}

/// Checks that `triangles` form a conforming triangulation of the whole domain, every face of
/// it: every triangle non-degenerate, counter-clockwise and inside its face, their areas adding
/// up to the domain's, and every directed edge matched by exactly one opposite edge unless it
/// lies on a plane's outer boundary (a cube-sphere has none). Edges are compared between
/// canonical points ([`Domain::canonical_point`]), so a crack along a cube edge counts like any
/// other. Together these rule out cracks, T-junctions (an edge with a vertex in its interior has
/// no single matching edge), overlaps and holes.
pub fn check_conforming_surface(domain: &Domain, triangles: &[FaceTriangle]) -> Result<(), String> {
    let (ex, ey) = domain.layout().face_extent();
    let mut area2 = 0i64;
    type Edge = (FacePoint, FacePoint);
    let mut edges: HashMap<Edge, u32> = HashMap::new();
    for &(face, t) in triangles {
        let a = signed_area2(&t);
        if a <= 0 {
            return Err(format!("degenerate or clockwise triangle {t:?}"));
        }
        if face >= domain.faces() || t.iter().any(|p| p.0 < 0 || p.1 < 0 || p.0 > ex || p.1 > ey) {
            return Err(format!("triangle {t:?} leaves the domain"));
        }
        area2 += a;
        let canonical = t.map(|p| {
            domain
                .canonical_point(face, p.0, p.1)
                .expect("a point of the face square is on the surface")
        });
        for e in 0..3 {
            *edges
                .entry((canonical[e], canonical[(e + 1) % 3]))
                .or_default() += 1;
        }
    }
    let faces = i64::from(domain.faces());
    if area2 != 2 * faces * ex * ey {
        return Err(format!(
            "triangles cover {} but the domain is {}",
            area2 as f64 / 2.0,
            faces * ex * ey
        ));
    }
    let closed = domain.cube().is_some();
    let on_boundary = |p: FacePoint, q: FacePoint| {
        !closed
            && ((p.x == q.x && (p.x == 0 || p.x == ex)) || (p.y == q.y && (p.y == 0 || p.y == ey)))
    };
    let show = |p: FacePoint| {
        if closed {
            format!("f{}{:?}", p.face, (p.x, p.y))
        } else {
            format!("{:?}", (p.x, p.y))
        }
    };
    for (&(p, q), &count) in &edges {
        if count != 1 {
            return Err(format!(
                "edge {}->{} used {count} times in one direction",
                show(p),
                show(q)
            ));
        }
        let back = edges.get(&(q, p)).copied().unwrap_or(0);
        if back == 0 && !on_boundary(p, q) {
            return Err(format!(
                "edge {}->{} has no neighbour: crack or T-junction",
                show(p),
                show(q)
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn random_cut(domain: &Domain, picks: &[(u8, u32, u32)]) -> Cut {
        let layout = domain.layout();
        let mut cut = Cut::new();
        let (ex, ey) = layout.face_extent();
        for &(l, fx, fy) in picks {
            let level = l % layout.finest_level().max(1);
            // Snap a random point to the nearest centre of the chosen level, then refine it.
            let r = layout.radius(level);
            let x = (i64::from(fx) % (ex + 1)) / r * r;
            let y = (i64::from(fy) % (ey + 1)) / r * r;
            for (dx, dy) in [(0, 0), (r, 0), (0, r), (r, r)] {
                if let (Ok(x), Ok(y)) = (u32::try_from(x + dx), u32::try_from(y + dy)) {
                    let id = DiamondId::new(level, x, y);
                    if layout.contains(id) {
                        let newly = cut.refine(domain, id);
                        // Parents come before children in the returned order.
                        for (pos, d) in newly.iter().enumerate() {
                            for p in layout.parents(*d).into_iter().flatten() {
                                assert!(
                                    cut.is_refined(p) && !newly[pos..].contains(&p),
                                    "parent {p} of {d} not refined first"
                                );
                            }
                        }
                        break;
                    }
                }
            }
        }
        cut
    }

    #[test]
    fn coarsest_and_finest_cuts_conform() {
        let layout = Domain::full_plane(Layout::new(5, 2, 2, 1).unwrap());
        let cut = Cut::new();
        check_conforming(&layout, &cut.triangles(&layout)).unwrap();
        // Refine everything but the finest level.
        let mut cut = Cut::new();
        let mut frontier: Vec<DiamondId> = layout.roots().collect();
        let mut seen = std::collections::HashSet::new();
        while let Some(d) = frontier.pop() {
            if d.level < layout.finest_level() && seen.insert(d) {
                cut.refine(&layout, d);
                frontier.extend(layout.children(d).into_iter().flatten());
            }
        }
        let tris = cut.triangles(&layout);
        check_conforming(&layout, &tris).unwrap();
        // Finest level everywhere: one unit-spaced grid, two triangles per lattice cell.
        let (ex, ey) = layout.layout().face_extent();
        assert_eq!(tris.len() as i64, 2 * ex * ey);
    }

    #[test]
    fn the_naive_cut_rule_leaves_holes() {
        // "Draw unrefined diamonds whose parents are both refined" is not the same rule: a
        // diamond with one refined parent leaves its half in that parent undrawn.
        let layout = Domain::full_plane(Layout::new(3, 2, 1, 1).unwrap());
        let mut cut = Cut::new();
        let root = layout.roots().next().unwrap();
        cut.refine(&layout, root);
        let child = layout.children(root)[0].unwrap();
        cut.refine(&layout, child);
        let mut naive = Vec::new();
        for (id, half) in cut.drawn_halves(&layout) {
            let all_parents_refined = layout
                .parents(id)
                .into_iter()
                .flatten()
                .all(|p| cut.is_refined(p));
            if all_parents_refined {
                half_triangles(layout.layout(), id, half, &mut naive);
            }
        }
        assert!(check_conforming(&layout, &naive).is_err());
        check_conforming(&layout, &cut.triangles(&layout)).unwrap();
    }

    #[test]
    fn a_missing_triangle_or_a_t_junction_is_detected() {
        let layout = Domain::full_plane(Layout::new(3, 1, 1, 1).unwrap());
        let mut cut = Cut::new();
        cut.refine(&layout, layout.roots().next().unwrap());
        let mut tris = cut.triangles(&layout);
        tris.pop();
        assert!(check_conforming(&layout, &tris).is_err());
        // Replace one triangle by its two halves split at an edge midpoint: area is the same,
        // but the neighbour across that edge now meets a T-junction.
        let mut tris = cut.triangles(&layout);
        let t = tris.remove(0);
        let two = |p: (i64, i64)| (2 * p.0, 2 * p.1);
        let mut doubled: Vec<Triangle> = tris.iter().map(|t| t.map(two)).collect();
        let t2 = t.map(two);
        let m = ((t2[0].0 + t2[1].0) / 2, (t2[0].1 + t2[1].1) / 2);
        doubled.push([t2[0], m, t2[2]]);
        doubled.push([m, t2[1], t2[2]]);
        let big = Domain::full_plane(Layout::new(3, 2, 1, 1).unwrap()); // twice the extent
        let err = check_conforming(&big, &doubled).unwrap_err();
        assert!(
            err.contains("T-junction") || err.contains("neighbour"),
            "{err}"
        );
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]
        #[test]
        fn random_cuts_conform(
            n_pow in 1u32..4,
            k in 1u32..4,
            rx in 1u32..3,
            ry in 1u32..3,
            picks in proptest::collection::vec((any::<u8>(), any::<u32>(), any::<u32>()), 0..40),
            coarsen in proptest::collection::vec(any::<u16>(), 0..20),
        ) {
            let layout = Domain::full_plane(Layout::new((1 << n_pow) + 1, k, rx, ry).unwrap());
            let mut cut = random_cut(&layout, &picks);
            check_conforming(&layout, &cut.triangles(&layout)).map_err(TestCaseError::fail)?;
            // Coarsening (garbage collection) keeps it conforming too.
            let refined: Vec<DiamondId> = cut.refined().collect();
            for c in coarsen {
                if !refined.is_empty() {
                    cut.coarsen(&layout, refined[c as usize % refined.len()]);
                }
            }
            check_conforming(&layout, &cut.triangles(&layout)).map_err(TestCaseError::fail)?;
        }

        /// `refined` runs coarse to fine without repeats (parents before children, which
        /// `decode_cut` and the drawn order rely on), and holds what `refined_unordered` and
        /// `is_refined` say is refined, after refinements and coarsenings alike.
        #[test]
        fn refined_runs_coarse_to_fine_over_the_refined_set(
            picks in proptest::collection::vec((any::<u8>(), any::<u32>(), any::<u32>()), 0..40),
            coarsen in proptest::collection::vec(any::<u16>(), 0..20),
        ) {
            let layout = Domain::full_plane(Layout::new(9, 2, 2, 1).unwrap());
            let mut cut = random_cut(&layout, &picks);
            for c in coarsen {
                let refined: Vec<DiamondId> = cut.refined_unordered().collect();
                if !refined.is_empty() {
                    cut.coarsen(&layout, refined[c as usize % refined.len()]);
                }
            }
            let ordered: Vec<DiamondId> = cut.refined().collect();
            prop_assert!(ordered.windows(2).all(|w| w[0] < w[1]), "{ordered:?}");
            for (i, &id) in ordered.iter().enumerate() {
                prop_assert!(cut.is_refined(id));
                for p in layout.parents(id).into_iter().flatten() {
                    prop_assert!(ordered[..i].contains(&p), "{p} after its child {id}");
                }
            }
            let mut unordered: Vec<DiamondId> = cut.refined_unordered().collect();
            unordered.sort_unstable();
            prop_assert_eq!(&unordered, &ordered);
            prop_assert_eq!(cut.len(), ordered.len());
            prop_assert_eq!(cut.is_empty(), ordered.is_empty());
        }
    }
}
