//! The cube-sphere domain: the diamond hierarchy closed over six faces (relations across the 12
//! cube edges and around the 8 corners), canonical edge vertices, and conforming cuts over the
//! whole sphere.

use std::collections::{BTreeMap, BTreeSet, HashSet};

use cbdam_codec::geodesy::lattice_lat_lon;
use cbdam_codec::geometry::cube::ADJACENCY;
use cbdam_codec::geometry::{
    Cut, DiamondId, Domain, DomainKind, FacePoint, Half, check_conforming_surface,
};
use proptest::prelude::*;

/// Every diamond, reached from the roots through children.
fn all_diamonds(d: &Domain) -> Vec<DiamondId> {
    let mut out: Vec<DiamondId> = d.roots().collect();
    let mut level = out.clone();
    while !level.is_empty() {
        let next: BTreeSet<DiamondId> = level
            .iter()
            .flat_map(|&id| d.children(id))
            .flatten()
            .collect();
        level = next.into_iter().collect();
        out.extend(&level);
    }
    out
}

fn centre(id: DiamondId) -> FacePoint {
    FacePoint::new(id.face, i64::from(id.x), i64::from(id.y))
}

#[test]
fn a_cube_sphere_is_six_faces_of_one_root_with_data_everywhere() {
    let d = Domain::cube_sphere(65, 4).unwrap();
    assert_eq!((d.kind(), d.faces()), (DomainKind::CubeSphere, 6));
    assert_eq!(d.kind().name(), "cube-sphere");
    let s = 64 * 16;
    assert_eq!(d.cube().unwrap().side(), s);
    assert_eq!(
        (d.data().width, d.data().height),
        (s as u32 + 1, s as u32 + 1)
    );
    assert!(d.holds_data(5, s, s) && d.holds_data(0, 0, 0) && !d.holds_data(6, 0, 0));
    assert!(!d.holds_data(2, s + 1, 0));
    let rf = d.root_field();
    assert_eq!((rf.width, rf.height, rf.spacing), (65, 65, 16));
    let roots: Vec<DiamondId> = d.roots().collect();
    assert_eq!(roots.len(), 6);
    assert!(
        roots
            .iter()
            .enumerate()
            .all(|(f, r)| *r == DiamondId::on_face(f as u8, 0, 512, 512))
    );
    let fine = d.with_detail(2).unwrap();
    assert_eq!(
        (
            fine.kind(),
            fine.finest_level(),
            fine.cube().unwrap().side()
        ),
        (DomainKind::CubeSphere, d.finest_level() + 4, 4 * s)
    );
    // Ids of no face: no relations, no panic.
    let stray = DiamondId::on_face(9, 3, 64, 128);
    assert!(!d.contains(stray));
    assert_eq!(d.parents(stray), [None, None]);
    assert_eq!(d.children(stray), [None; 4]);
    assert_eq!(d.neighbours(stray), [None; 4]);
    assert_eq!(
        d.half_face(DiamondId::on_face(9, 1, 0, 512), Half::Negative)
            .0,
        9
    );
    assert_eq!(d.canonical_point(9, 0, 0), None);
    assert!(Domain::cube_sphere(65, 30).is_err());
    assert!(Domain::cube_sphere(64, 1).is_err());
    // A plane stays a plane.
    let plane = Domain::covering(65, 100, 80, 0).unwrap();
    assert!(plane.cube().is_none());
    assert_eq!(
        plane.canonical_point(0, 3, 4),
        Some(FacePoint::new(0, 3, 4))
    );
    assert_eq!(plane.canonical_point(0, -1, 4), None);
    assert_eq!(lattice_lat_lon(&plane, 0, 3, 4), None);
}

#[test]
fn levels_hold_the_closed_surface_counts_and_are_the_closure_of_the_roots() {
    for (n, k) in [(3, 3), (5, 2), (9, 1)] {
        let d = Domain::cube_sphere(n, k).unwrap();
        let mut frontier: BTreeSet<DiamondId> = d.roots().collect();
        for level in 0..=d.finest_level() {
            let listed: Vec<DiamondId> = d.level(level).collect();
            assert!(
                listed.windows(2).all(|w| w[0] < w[1]),
                "level {level} order"
            );
            let as_set: BTreeSet<DiamondId> = listed.iter().copied().collect();
            assert_eq!(as_set, frontier, "n {n} k {k} level {level}");
            // A closed quad mesh of 6·4^m faces has 12·4^m edges: one odd diamond per edge.
            let m = u32::from(level / 2);
            let want = if level % 2 == 0 { 6 } else { 12 } * 4usize.pow(m);
            assert_eq!(listed.len(), want, "n {n} k {k} level {level}");
            frontier = frontier
                .iter()
                .flat_map(|&id| d.children(id))
                .flatten()
                .collect();
        }
        assert!(frontier.is_empty());
    }
}

#[test]
fn relations_are_consistent_across_all_edges_and_corners() {
    for (n, k) in [(3, 3), (5, 2), (3, 1)] {
        let d = Domain::cube_sphere(n, k).unwrap();
        let cube = *d.cube().unwrap();
        let s = cube.side();
        let all = all_diamonds(&d);
        let set: HashSet<DiamondId> = all.iter().copied().collect();
        assert_eq!(set.len(), all.len());
        // Which cube edges (as face pairs) host straddling diamonds, and which corners odd
        // diamonds reach with a tip, per level.
        let mut edges_hosting: BTreeMap<u8, BTreeSet<(u8, u8)>> = BTreeMap::new();
        let mut corner_tips: BTreeMap<u8, BTreeMap<[i64; 3], usize>> = BTreeMap::new();
        for &id in &all {
            assert!(d.contains(id), "{id} produced but not contained");
            // A centre is never a cube corner: at most two faces hold it.
            let (_, holders) = cube.representations(centre(id));
            assert!(holders <= 2, "{id} is centred on a cube corner");
            if let Some(edge) = cube.edge_of(centre(id)) {
                assert_eq!(id.level % 2, 1, "{id}: only odd levels straddle");
                let other = ADJACENCY[usize::from(id.face)][edge as usize].face;
                assert!(other > id.face, "{id} is not owned by the lower face");
                edges_hosting
                    .entry(id.level)
                    .or_default()
                    .insert((id.face, other));
            }
            if id.level % 2 == 1 {
                // The two tips of an odd diamond lie along its split diagonal.
                let r = d.layout().radius(id.level);
                let (x, y) = (i64::from(id.x), i64::from(id.y));
                let tips = if x % (2 * r) == r {
                    [(x - r, y), (x + r, y)]
                } else {
                    [(x, y - r), (x, y + r)]
                };
                for (tx, ty) in tips {
                    if (tx == 0 || tx == s) && (ty == 0 || ty == s) {
                        let corner = cube.cube_point(FacePoint::new(id.face, tx, ty));
                        *corner_tips
                            .entry(id.level)
                            .or_default()
                            .entry(corner)
                            .or_default() += 1;
                    }
                }
            }
            let parents = d.parents(id);
            if id.level == 0 {
                assert_eq!(parents, [None, None]);
            } else {
                let [Some(p0), Some(p1)] = parents else {
                    panic!("{id} lacks a parent on a closed surface: {parents:?}");
                };
                assert_ne!(p0, p1);
                for (h, p) in [(Half::Positive, p0), (Half::Negative, p1)] {
                    assert!(set.contains(&p));
                    assert_eq!(p.level + 1, id.level);
                    assert!(d.children(p).contains(&Some(id)), "{p} lacks child {id}");
                    assert_eq!(d.half_in(id, p), Some(h));
                }
            }
            let children = d.children(id);
            if id.level < d.finest_level() {
                let kids: BTreeSet<DiamondId> = children.iter().map(|c| c.unwrap()).collect();
                assert_eq!(kids.len(), 4, "{id}: {children:?}");
                for c in kids {
                    assert!(d.half_in(c, id).is_some(), "{c} does not list {id}");
                }
            } else {
                assert_eq!(children, [None; 4]);
            }
            let nbs = d.neighbours(id);
            let distinct: BTreeSet<DiamondId> = nbs.iter().map(|c| c.unwrap()).collect();
            assert_eq!(distinct.len(), 4, "{id}: {nbs:?}");
            for nb in distinct {
                assert_eq!(nb.level, id.level);
                assert!(
                    d.neighbours(nb).contains(&Some(id)),
                    "{nb} not back to {id}"
                );
            }
        }
        for level in (1..=d.finest_level()).step_by(2) {
            let m = u32::from(level / 2);
            // All 12 cube edges host straddling diamonds, 2^m each (counted by owner above).
            assert_eq!(edges_hosting[&level].len(), 12, "level {level}");
            let on_edges = all
                .iter()
                .filter(|id| id.level == level && cube.edge_of(centre(**id)).is_some())
                .count();
            assert_eq!(on_edges, 12 << m, "level {level}");
            // All 8 corners, each the tip of exactly 3 odd diamonds (valence 3: three faces).
            let tips = &corner_tips[&level];
            assert_eq!(tips.len(), 8, "level {level}");
            assert!(tips.values().all(|&c| c == 3), "level {level}: {tips:?}");
        }
    }
}

#[test]
fn no_diamond_is_centred_on_a_cube_corner_at_any_level() {
    // Large lattices, every level, every face, every corner spelling: a corner is only ever a
    // vertex (the relation test above covers the small lattices diamond by diamond).
    for (n, k) in [(65, 8), (1025, 3), (3, 20)] {
        let d = Domain::cube_sphere(n, k).unwrap();
        let s = d.cube().unwrap().side() as u32;
        for level in 0..=d.finest_level() {
            for face in 0..6 {
                for (x, y) in [(0, 0), (0, s), (s, 0), (s, s)] {
                    assert!(!d.contains(DiamondId::on_face(face, level, x, y)));
                }
            }
        }
    }
}

#[test]
fn child_grids_meet_their_parents_across_cube_edges() {
    // The codec gathers a child's grid from each parent's half-step grid by an affine index
    // map. Carried onto the face its half lies on, a straddling diamond's grid must map into
    // that parent's grid exactly as inside a face.
    let d = Domain::cube_sphere(5, 2).unwrap();
    let n = d.n() as i64;
    let mut straddling_checked = 0;
    for id in all_diamonds(&d) {
        for half in Half::BOTH {
            let Some(p) = d.parent(id, half) else {
                continue;
            };
            let (face, child_grid) = d.half_grid(id, half);
            // The parent's grid on that face: its own, or the half of it lying there.
            let parent_grid = Half::BOTH
                .iter()
                .map(|&ph| d.half_grid(p, ph))
                .find(|(f, _)| *f == face)
                .map(|(_, g)| g)
                .expect("the parent has a half on the child's half's face");
            let m = child_grid
                .index_map_into_half_step(&parent_grid)
                .unwrap_or_else(|| panic!("{id} {half:?} does not map into {p}"));
            let mut inside = 0;
            for i in 0..n {
                for j in 0..n {
                    let (a, b) = m.apply(i, j);
                    let in_parent = (0..2 * n - 1).contains(&a) && (0..2 * n - 1).contains(&b);
                    inside += usize::from(in_parent);
                    // Inside the parent: exactly the half's points and the split diagonal.
                    let on_side = d.layout().half_of_point(id, i as usize, j as usize);
                    let expected = on_side.is_none_or(|h| h == half);
                    assert_eq!(in_parent, expected, "{id} {half:?} ({i},{j}) in {p}");
                    if in_parent {
                        assert_eq!((a + b).rem_euclid(2), 0);
                    }
                }
            }
            assert_eq!(inside as i64, n * (n + 1) / 2, "{id} {half:?}");
            if face != id.face {
                straddling_checked += 1;
            }
        }
    }
    // 12 + 24 straddling diamonds (levels 1 and 3), one half each on the other face.
    assert_eq!(straddling_checked, 12 + 24);
}

#[test]
fn edge_and_corner_vertices_are_one_point_with_bit_identical_coordinates() {
    let d = Domain::cube_sphere(9, 2).unwrap();
    let cube = *d.cube().unwrap();
    let s = cube.side();
    let mut boundary_points = 0;
    let mut corner_points = 0;
    let mut differs_without_canonical = 0;
    for face in 0..6 {
        for x in 0..=s {
            for y in 0..=s {
                if !(x == 0 || y == 0 || x == s || y == s) {
                    continue;
                }
                let (reps, len) = cube.representations(FacePoint::new(face, x, y));
                let canonical = d.canonical_point(face, x, y).unwrap();
                let ll = lattice_lat_lon(&d, face, x, y).unwrap();
                for r in &reps[..len] {
                    assert_eq!(d.canonical_point(r.face, r.x, r.y), Some(canonical));
                    let other = lattice_lat_lon(&d, r.face, r.x, r.y).unwrap();
                    assert_eq!(
                        (other.lat.to_bits(), other.lon.to_bits()),
                        (ll.lat.to_bits(), ll.lon.to_bits()),
                        "f{face} ({x},{y}) vs {r:?}"
                    );
                    // Computed from a face's own coordinates instead, the bits may differ.
                    let own = cbdam_codec::geodesy::cube_map::face_st_to_lat_lon(
                        r.face,
                        r.x as f64 / s as f64,
                        r.y as f64 / s as f64,
                    );
                    if (own.lat.to_bits(), own.lon.to_bits())
                        != (ll.lat.to_bits(), ll.lon.to_bits())
                    {
                        differs_without_canonical += 1;
                    }
                }
                // A point past an edge is the neighbour's point one step inside.
                boundary_points += 1;
                corner_points += usize::from(len == 3);
            }
        }
    }
    // 6 faces × 4·S boundary points, each counted once per face holding it.
    assert_eq!(boundary_points, 6 * 4 * s as usize);
    assert_eq!(corner_points, 6 * 4);
    eprintln!(
        "edge/corner vertex representations whose own-face lat/lon differ in bits from the \
         canonical one: {differs_without_canonical}"
    );
    // Stepping past an edge lands on the same point as the neighbour's own coordinates.
    assert_eq!(
        d.canonical_point(0, -1, 5),
        d.canonical_point(ADJACENCY[0][3].face, s - 1, 5)
    );
    assert_eq!(d.canonical_point(0, -1, -1), None, "beyond a corner");
}

/// Refines a diamond near each pick (any face, level, place), forcing its parents.
fn random_cut(d: &Domain, picks: &[(u8, u8, u32, u32)]) -> Cut {
    let mut cut = Cut::new();
    let s = d.cube().unwrap().side();
    for &(f, l, fx, fy) in picks {
        let face = f % 6;
        let level = l % d.finest_level();
        let r = d.layout().radius(level);
        let x = (i64::from(fx) % (s + 1)) / r * r;
        let y = (i64::from(fy) % (s + 1)) / r * r;
        for (dx, dy) in [(0, 0), (r, 0), (0, r), (r, r)] {
            let Some(p) = d.canonical_point(face, x + dx, y + dy) else {
                continue;
            };
            let id = DiamondId::on_face(p.face, level, p.x as u32, p.y as u32);
            if d.contains(id) {
                cut.refine(d, id);
                break;
            }
        }
    }
    cut
}

#[test]
fn the_coarsest_and_finest_cuts_of_the_sphere_conform() {
    let d = Domain::cube_sphere(3, 2).unwrap();
    let s = d.cube().unwrap().side();
    check_conforming_surface(&d, &Cut::new().face_triangles(&d)).unwrap();
    let mut cut = Cut::new();
    for level in 0..d.finest_level() {
        for id in d.level(level) {
            cut.refine(&d, id);
        }
    }
    let tris = cut.face_triangles(&d);
    check_conforming_surface(&d, &tris).unwrap();
    assert_eq!(tris.len() as i64, 6 * 2 * s * s);
    // The checker sees a hole next to a cube edge...
    let mut cut = Cut::new();
    cut.refine(&d, d.level(1).next().unwrap());
    let mut tris = cut.face_triangles(&d);
    let at_edge = tris
        .iter()
        .position(|(_, t)| t.iter().any(|p| p.1 == 0))
        .unwrap();
    tris.remove(at_edge);
    assert!(check_conforming_surface(&d, &tris).is_err());
    // On a plane, face triangles are the plain triangles on face 0.
    let plane = Domain::covering(5, 9, 7, 0).unwrap();
    let mut cut = Cut::new();
    cut.refine(&plane, plane.level(2).nth(3).unwrap());
    let plain: Vec<_> = cut
        .triangles(&plane)
        .into_iter()
        .map(|t| (0u8, t))
        .collect();
    assert_eq!(cut.face_triangles(&plane), plain);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]
    #[test]
    fn random_cuts_over_the_whole_sphere_conform(
        n_pow in 1u32..3,
        k in 1u32..4,
        picks in proptest::collection::vec(
            (any::<u8>(), any::<u8>(), any::<u32>(), any::<u32>()), 0..40),
        coarsen in proptest::collection::vec(any::<u16>(), 0..20),
    ) {
        let d = Domain::cube_sphere((1 << n_pow) + 1, k).unwrap();
        let mut cut = random_cut(&d, &picks);
        check_conforming_surface(&d, &cut.face_triangles(&d)).map_err(TestCaseError::fail)?;
        let refined: Vec<DiamondId> = cut.refined().collect();
        for c in coarsen {
            if !refined.is_empty() {
                cut.coarsen(&d, refined[c as usize % refined.len()]);
            }
        }
        check_conforming_surface(&d, &cut.face_triangles(&d)).map_err(TestCaseError::fail)?;
    }
}
