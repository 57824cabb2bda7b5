//! Encoding and decoding a cube-sphere: the L∞ bound at every lattice point of every face,
//! decoded edge and corner points bit-identical from every face holding them, and random
//! conforming cuts whose halves agree along the cube edges.

use std::collections::HashMap;

use cbdam_codec::CodecError;
use cbdam_codec::entropy::CoderKind;
use cbdam_codec::geodesy::lattice_lat_lon;
use cbdam_codec::geometry::{Cut, DiamondId, Domain, FacePoint, check_conforming_surface};
use cbdam_codec::hierarchy::{
    Decoder, EncodeOptions, Encoded, Encoder, PlanetGrid, RefineScratch, Refined, encode_planet,
    gather, reconstruct_finest, reconstruct_planet, verify, verify_planet,
};
use cbdam_codec::lifting::Alpha;
use cbdam_codec::quant::{HeightGrid, Quantizer};

use super::util::Rng;

/// A hash of a canonical point: deterministic noise that every face holding it agrees on.
fn noise(p: FacePoint, seed: u64) -> u64 {
    let mut r = Rng(seed ^ (u64::from(p.face) << 56) ^ ((p.x as u64) << 28) ^ p.y as u64);
    r.next()
}

/// Smooth relief plus noise as a function of geodetic latitude and longitude, metres as units.
fn relief(n: usize, k: u32, seed: u64) -> PlanetGrid {
    let domain = Domain::cube_sphere(n, k).unwrap();
    PlanetGrid::from_fn(n, k, |p| {
        let ll = lattice_lat_lon(&domain, p.face, p.x, p.y).unwrap();
        let (lat, lon) = (ll.lat.to_radians(), ll.lon.to_radians());
        let smooth =
            3000.0 * (3.0 * lat).sin() * (2.0 * lon).cos() + 800.0 * (7.0 * lon + lat).sin();
        Some(smooth as i32 + (noise(p, seed) % 101) as i32 - 50)
    })
    .unwrap()
}

/// Steps across every cube edge (each face its own plateau, edge points on their canonical
/// face's), spikes at the eight corners and on the edges' midpoints, and nodata holes if asked,
/// some of them on edges and corners.
fn adversarial(n: usize, k: u32, seed: u64, holes: bool) -> PlanetGrid {
    let s = ((n as i64) - 1) << k;
    PlanetGrid::from_fn(n, k, |p| {
        let on_x = p.x == 0 || p.x == s;
        let on_y = p.y == 0 || p.y == s;
        let h = noise(p, seed);
        if holes && (h.is_multiple_of(17) || (on_x && on_y && h.is_multiple_of(2))) {
            return None;
        }
        let plateau = [-9000, 4000, 12000, -300, 7000, 0][usize::from(p.face)];
        let spike = if on_x && on_y {
            if h.is_multiple_of(2) { 30000 } else { -30000 }
        } else if (on_x || on_y) && (p.x == s / 2 || p.y == s / 2) {
            -20000
        } else {
            0
        };
        Some(plateau + spike + (h % 2001) as i32 - 1000)
    })
    .unwrap()
}

fn opts(n: usize, coder: CoderKind) -> EncodeOptions {
    EncodeOptions {
        n,
        coder,
        ..EncodeOptions::default()
    }
}

/// Every lattice point of every face of the reconstruction within `k` of the input where the
/// input has data, validity as the input's, and every edge and corner point decoded the same on
/// each face holding it. Returns the number of points checked.
fn check_reconstruction(planet: &PlanetGrid, encoded: &Encoded) -> usize {
    let k = i64::from(encoded.params.quantizer.k());
    let faces = reconstruct_planet(encoded).unwrap();
    let cube = *planet.domain().cube().unwrap();
    let s = cube.side();
    let mut checked = 0;
    for f in 0..6u8 {
        let input = &planet.face_grid(f);
        for y in 0..=s {
            for x in 0..=s {
                let at = (y * (s + 1) + x) as usize;
                if let Some(want) = input.get(x, y) {
                    let got = faces[usize::from(f)].values[at];
                    assert!(
                        (i64::from(got) - i64::from(want)).abs() <= k,
                        "face {f} ({x}, {y}): decoded {got}, input {want}, k = {k}"
                    );
                    checked += 1;
                }
                if encoded.params.nodata_mask {
                    assert_eq!(faces[usize::from(f)].valid[at], input.is_valid(x, y));
                }
                let (reps, len) = cube.representations(FacePoint::new(f, x, y));
                for r in &reps[1..len] {
                    let other = (r.y * (s + 1) + r.x) as usize;
                    assert_eq!(
                        faces[usize::from(f)].values[at],
                        faces[usize::from(r.face)].values[other],
                        "face {f} ({x}, {y}) and face {} ({}, {}) decode differently",
                        r.face,
                        r.x,
                        r.y
                    );
                }
            }
        }
    }
    checked
}

#[test]
fn smooth_relief_with_noise_decodes_within_the_bound_everywhere() {
    for (n, k, q) in [(3, 3, 0), (5, 2, 3), (9, 3, 2), (17, 2, 10), (33, 1, 1)] {
        let planet = relief(n, k, 7);
        for coder in CoderKind::ALL {
            let encoded =
                encode_planet(&planet, Quantizer::new(q).unwrap(), &opts(n, coder)).unwrap();
            let report = verify_planet(&encoded, &planet).unwrap();
            assert!(
                report.within_bound(),
                "N = {n}, K = {k}, k = {q}, {coder:?}: {report:?}"
            );
            assert_eq!(report.bound, q);
            // Every level visited, every face's points counted.
            assert!(
                report
                    .levels
                    .iter()
                    .all(|l| l.diamonds > 0 && l.vertices > 0)
            );
            let checked = check_reconstruction(&planet, &encoded);
            let s = (n - 1) << k;
            assert_eq!(checked, 6 * (s + 1) * (s + 1));
            assert!(encoded.leaf_error <= q);
        }
    }
}

#[test]
fn steps_spikes_and_holes_at_cube_edges_and_corners_decode_within_the_bound() {
    for (n, k, q, holes) in [
        (3, 2, 0, false),
        (5, 3, 5, true),
        (9, 2, 1, true),
        (17, 2, 40, false),
    ] {
        let planet = adversarial(n, k, 11 + u64::from(k), holes);
        assert_eq!(planet.has_nodata(), holes);
        let encoded = encode_planet(
            &planet,
            Quantizer::new(q).unwrap(),
            &opts(n, CoderKind::AdaptiveTokens),
        )
        .unwrap();
        assert_eq!(encoded.params.nodata_mask, holes);
        let report = verify_planet(&encoded, &planet).unwrap();
        assert!(report.within_bound(), "N = {n}, K = {k}: {report:?}");
        // With these steps a bound of zero or a few units is only kept by real residuals.
        assert!(report.max_error() <= q);
        check_reconstruction(&planet, &encoded);
    }
}

#[test]
fn object_errors_bound_the_input_under_every_diamond_and_grow_towards_the_roots() {
    let planet = adversarial(5, 2, 3, false);
    let encoded = encode_planet(
        &planet,
        Quantizer::new(2).unwrap(),
        &opts(5, CoderKind::AdaptiveTokens),
    )
    .unwrap();
    let domain = encoded.params.domain;
    let errors: HashMap<DiamondId, u32> = encoded
        .records
        .iter()
        .map(|r| (r.id, r.object_error))
        .collect();
    for r in &encoded.records {
        for c in domain.children(r.id).into_iter().flatten() {
            if let Some(&e) = errors.get(&c) {
                assert!(e <= r.object_error, "{} below {}", c, r.id);
            }
        }
    }
    // The plateaus differ by thousands of units: the roots' flat-ish surface is far off.
    let root_error = encoded
        .records
        .iter()
        .filter(|r| r.id.level == 0)
        .map(|r| r.object_error)
        .max()
        .unwrap();
    assert!(root_error > 1000, "root error {root_error}");
}

/// The refinement of every recorded diamond, decoded coarse to fine with the decoder's steps.
fn decode_all(encoded: &Encoded) -> HashMap<DiamondId, Refined> {
    let decoder = Decoder::new(encoded.params, &encoded.roots).unwrap();
    let domain = encoded.params.domain;
    let mut out: HashMap<DiamondId, Refined> = HashMap::new();
    let mut scratch = RefineScratch::default();
    for r in &encoded.records {
        let parents = domain.parents(r.id).map(|p| p.map(|p| &out[&p]));
        let grid = decoder.grid_of(r.id, parents);
        let refined = decoder.refine(r.id, &grid, &r.bytes, &mut scratch).unwrap();
        out.insert(r.id, refined);
    }
    out
}

#[test]
fn random_cuts_conform_and_their_halves_agree_along_the_cube_edges() {
    let (n, k) = (5, 3);
    let planet = relief(n, k, 5);
    let encoded = encode_planet(
        &planet,
        Quantizer::new(1).unwrap(),
        &opts(n, CoderKind::AdaptiveTokens),
    )
    .unwrap();
    let domain = encoded.params.domain;
    let decoder = Decoder::new(encoded.params, &encoded.roots).unwrap();
    let refined = decode_all(&encoded);
    let finest_heights = reconstruct_planet(&encoded).unwrap();
    let s = domain.cube().unwrap().side();
    let recorded: Vec<DiamondId> = encoded.records.iter().map(|r| r.id).collect();
    let mut rng = Rng(99);
    let mut straddling_halves = 0;
    for round in 0..24 {
        let mut cut = Cut::new();
        for _ in 0..(1 + round * 6) {
            let id = recorded[rng.below(recorded.len())];
            cut.refine(&domain, id);
        }
        check_conforming_surface(&domain, &cut.face_triangles(&domain)).unwrap();
        // Every drawn half's vertices, each as the client gathers it (one parent's
        // refinement), by canonical point: one height per point, the finest decoded one
        // (α = 1 vertices never change).
        let mut seen: HashMap<FacePoint, i32> = HashMap::new();
        for (id, half) in cut.drawn_halves(&domain) {
            let heights = if id.level == 0 {
                decoder.grid_of(id, [None, None])
            } else {
                let parent = domain.parent(id, half).unwrap();
                let mut parents = [None, None];
                parents[half as usize] = Some(&refined[&parent]);
                let mut g = vec![0i32; n * n];
                gather(&domain, id, parents, &mut g);
                g
            };
            let (face, grid) = domain.half_grid(id, half);
            straddling_halves += usize::from(face != id.face);
            for j in 0..n {
                for i in 0..n {
                    if domain
                        .layout()
                        .half_of_point(id, i, j)
                        .is_some_and(|h| h != half)
                    {
                        continue;
                    }
                    let (x, y) = grid.point(i as i64, j as i64);
                    assert!(
                        (0..=s).contains(&x) && (0..=s).contains(&y),
                        "{id} {half:?}"
                    );
                    let c = domain.canonical_point(face, x, y).unwrap();
                    let h = heights[j * n + i];
                    let decoded =
                        finest_heights[usize::from(c.face)].values[(c.y * (s + 1) + c.x) as usize];
                    assert_eq!(h, decoded, "{id} {half:?} at face {face} ({x}, {y})");
                    if let Some(prev) = seen.insert(c, h) {
                        assert_eq!(prev, h, "crack at {c:?}");
                    }
                }
            }
        }
    }
    assert!(
        straddling_halves > 0,
        "no cut drew a half across a cube edge"
    );
}

#[test]
fn inconsistent_or_misshapen_planets_are_refused() {
    let planet = relief(3, 2, 1);
    let faces: Vec<HeightGrid> = (0..6).map(|f| planet.face_grid(f)).collect();
    assert!(PlanetGrid::new(3, 2, faces.clone()).is_ok());
    // Face 0's corner (0, 0) is shared with two other faces.
    let mut bad = faces.clone();
    bad[0].values[0] += 1;
    let e = PlanetGrid::new(3, 2, bad).unwrap_err().to_string();
    assert!(e.contains("shared points must hold one value"), "{e}");
    // A point inside an edge, validity only.
    let mut bad = faces.clone();
    bad[3].valid[4] = false;
    assert!(PlanetGrid::new(3, 2, bad).is_err());
    assert!(PlanetGrid::new(3, 2, faces[..5].to_vec()).is_err());
    let e = PlanetGrid::new(3, 3, faces.clone())
        .unwrap_err()
        .to_string();
    assert!(e.contains("face 0 is 9×9"), "{e}");
    let empty = PlanetGrid::from_fn(3, 1, |_| None).unwrap();
    let q = Quantizer::new(1).unwrap();
    assert!(encode_planet(&empty, q, &opts(3, CoderKind::AdaptiveTokens)).is_err());
    let half = EncodeOptions {
        alpha: Alpha::Half,
        ..opts(3, CoderKind::AdaptiveTokens)
    };
    assert!(encode_planet(&planet, q, &half).is_err());
    assert!(encode_planet(&planet, q, &opts(5, CoderKind::AdaptiveTokens)).is_err());
    let extra = EncodeOptions {
        extra_level_pairs: 1,
        ..opts(3, CoderKind::AdaptiveTokens)
    };
    assert!(encode_planet(&planet, q, &extra).is_err());
}

#[test]
fn planar_and_planet_decoders_refuse_each_others_hierarchies() {
    let planet = relief(3, 2, 1);
    let q = Quantizer::new(1).unwrap();
    let encoded = encode_planet(&planet, q, &opts(3, CoderKind::AdaptiveTokens)).unwrap();
    let e: CodecError = reconstruct_finest(&encoded).unwrap_err();
    assert!(e.to_string().contains("cube-sphere"), "{e}");
    assert!(verify(&encoded, &planet.face_grid(0)).is_err());
    let plane = HeightGrid::all_valid(9, 9, (0..81).collect());
    let flat = Encoder::new(&plane, q, &opts(3, CoderKind::AdaptiveTokens))
        .encode()
        .unwrap();
    assert!(verify_planet(&flat, &planet).is_err());
    assert!(reconstruct_planet(&flat).is_err());
    let other = relief(3, 3, 1);
    assert!(verify_planet(&encoded, &other).is_err());
}

#[test]
fn damaged_planet_bytes_are_errors_or_wrong_heights_never_panics() {
    let planet = adversarial(5, 2, 9, true);
    let encoded = encode_planet(
        &planet,
        Quantizer::new(3).unwrap(),
        &opts(5, CoderKind::AdaptiveTokens),
    )
    .unwrap();
    let mut rng = Rng(4);
    for _ in 0..300 {
        let mut bad = encoded.clone();
        let target = rng.below(bad.records.len() + 1);
        let bytes = if target == bad.records.len() {
            &mut bad.roots
        } else {
            bad.records[target].bytes.to_mut()
        };
        if bytes.is_empty() {
            continue;
        }
        let at = rng.below(bytes.len());
        bytes[at] ^= 1 << rng.below(8);
        let _ = verify_planet(&bad, &planet);
        let _ = reconstruct_planet(&bad);
    }
}

#[test]
fn a_root_field_coding_a_shared_edge_vertex_twice_is_corrupt() {
    // Face 1's root field repeats values of face 0 along their shared edge; a crafted field that
    // codes one of them (a nonzero residual) is refused rather than silently overriding.
    use cbdam_codec::entropy::{Band, BandKind, encode_bands};
    let planet = relief(3, 1, 2);
    let encoded = encode_planet(
        &planet,
        Quantizer::new(1).unwrap(),
        &opts(3, CoderKind::AdaptiveTokens),
    )
    .unwrap();
    let (w, h) = (3, 3 * 6);
    let mut idx = vec![0i32; w * h];
    let shared = {
        // A point of face 1's root field that face 0 holds too.
        let d = encoded.params.domain;
        let spacing = d.root_field().spacing;
        (0..9)
            .find(|&k| {
                let (x, y) = ((k % 3) as i64 * spacing, (k / 3) as i64 * spacing);
                d.canonical_point(1, x, y).unwrap().face == 0
            })
            .unwrap()
    };
    idx[9 + shared] = 1;
    let mut bytes = Vec::new();
    let band = Band {
        kind: BandKind::Roots,
        width: w,
        height: h,
        values: &idx,
    };
    encode_bands(CoderKind::AdaptiveTokens, &[band], &mut bytes);
    let e = Decoder::new(encoded.params, &bytes)
        .unwrap_err()
        .to_string();
    assert!(e.contains("cube edge vertex"), "{e}");
    // The same field with the shared point left at zero decodes.
    idx[9 + shared] = 0;
    bytes.clear();
    let band = Band {
        kind: BandKind::Roots,
        width: w,
        height: h,
        values: &idx,
    };
    encode_bands(CoderKind::AdaptiveTokens, &[band], &mut bytes);
    assert!(Decoder::new(encoded.params, &bytes).is_ok());
}

/// The largest distance between the drawn surface of `id` (its grid `p`, cells split parallel
/// to the split diagonal) and the input at every lattice point under either half, each half on
/// the face it lies on: an independent floating-point measurement.
fn measured_surface_error(planet: &PlanetGrid, id: DiamondId, p: &[i32]) -> f64 {
    use cbdam_codec::geometry::{Diagonal, Half};
    let domain = planet.domain();
    let layout = domain.layout();
    let n = layout.n();
    let n1 = (n - 1) as f64;
    let s = domain.cube().unwrap().side();
    let diag = layout.diagonal(id);
    let at = |i: usize, j: usize| f64::from(p[j * n + i]);
    let mut worst: f64 = 0.0;
    for half in Half::BOTH {
        let (face, g) = domain.half_grid(id, half);
        let corners = [
            (0, 0),
            (n1 as i64, 0),
            (0, n1 as i64),
            (n1 as i64, n1 as i64),
        ]
        .map(|(i, j)| g.point(i, j));
        let (x0, x1) = (
            corners.iter().map(|c| c.0).min().unwrap().max(0),
            corners.iter().map(|c| c.0).max().unwrap().min(s),
        );
        let (y0, y1) = (
            corners.iter().map(|c| c.1).min().unwrap().max(0),
            corners.iter().map(|c| c.1).max().unwrap().min(s),
        );
        let uu = (g.u.0 * g.u.0 + g.u.1 * g.u.1) as f64;
        for y in y0..=y1 {
            for x in x0..=x1 {
                let Some(want) = planet.get(face, x, y) else {
                    continue;
                };
                let d = (x - g.origin.0, y - g.origin.1);
                let a = (d.0 * g.u.0 + d.1 * g.u.1) as f64 / uu;
                let b = (d.0 * g.v.0 + d.1 * g.v.1) as f64 / uu;
                let eps = 1e-9;
                if a < -eps || b < -eps || a > n1 + eps || b > n1 + eps {
                    continue;
                }
                let inside = match (diag, half) {
                    (Diagonal::Main, Half::Positive) => a >= b - eps,
                    (Diagonal::Main, Half::Negative) => a <= b + eps,
                    (Diagonal::Anti, Half::Positive) => a + b >= n1 - eps,
                    (Diagonal::Anti, Half::Negative) => a + b <= n1 + eps,
                };
                if !inside {
                    continue;
                }
                let (i, j) = (
                    (a.floor() as usize).min(n - 2),
                    (b.floor() as usize).min(n - 2),
                );
                let (fa, fb) = (a - i as f64, b - j as f64);
                let v = match diag {
                    Diagonal::Main if fa >= fb => {
                        at(i, j)
                            + fa * (at(i + 1, j) - at(i, j))
                            + fb * (at(i + 1, j + 1) - at(i + 1, j))
                    }
                    Diagonal::Main => {
                        at(i, j)
                            + fb * (at(i, j + 1) - at(i, j))
                            + fa * (at(i + 1, j + 1) - at(i, j + 1))
                    }
                    Diagonal::Anti if fa + fb <= 1.0 => {
                        at(i, j) + fa * (at(i + 1, j) - at(i, j)) + fb * (at(i, j + 1) - at(i, j))
                    }
                    Diagonal::Anti => {
                        at(i + 1, j + 1)
                            + (1.0 - fa) * (at(i, j + 1) - at(i + 1, j + 1))
                            + (1.0 - fb) * (at(i + 1, j) - at(i + 1, j + 1))
                    }
                };
                worst = worst.max((v - f64::from(want)).abs());
            }
        }
    }
    worst
}

#[test]
fn object_errors_cover_both_halves_of_diamonds_across_cube_edges() {
    let (n, k) = (5, 3);
    let planet = adversarial(n, k, 21, false);
    let encoded = encode_planet(
        &planet,
        Quantizer::new(1).unwrap(),
        &opts(n, CoderKind::AdaptiveTokens),
    )
    .unwrap();
    let domain = encoded.params.domain;
    let decoder = Decoder::new(encoded.params, &encoded.roots).unwrap();
    let refined = decode_all(&encoded);
    let mut straddlers = 0;
    let mut tight = 0;
    for r in &encoded.records {
        let parents = domain.parents(r.id).map(|p| p.map(|p| &refined[&p]));
        let p = decoder.grid_of(r.id, parents);
        let measured = measured_surface_error(&planet, r.id, &p);
        assert!(
            f64::from(r.object_error) + 1e-6 >= measured,
            "{}: object error {} below the measured {measured}",
            r.id,
            r.object_error
        );
        let across = cbdam_codec::geometry::Half::BOTH
            .into_iter()
            .any(|h| domain.half_grid(r.id, h).0 != r.id.face);
        if across {
            straddlers += 1;
            tight += usize::from(f64::from(r.object_error) < measured + 1.0);
        }
    }
    assert!(straddlers > 0);
    // Saturation may raise a diamond's error above its own surface's; most are their own.
    assert!(
        tight > 0,
        "no diamond across an edge carries its own measured error"
    );
}

#[test]
fn a_peak_under_the_far_half_of_an_edge_diamond_is_in_its_object_error() {
    // A cone on face B under the half of a level-1 diamond (owned by face A) that lies on B,
    // its apex a cell centre of that diamond (no vertex of its grid): the coarse surface misses
    // it by thousands of units, the diamond's finer descendants by less. Flat zero elsewhere.
    let (n, k) = (5, 3);
    let domain = Domain::cube_sphere(n, k).unwrap();
    let s = domain.cube().unwrap().side();
    let (id, face_b, apex) = domain
        .level(1)
        .find_map(|id| {
            cbdam_codec::geometry::Half::BOTH.into_iter().find_map(|h| {
                let (face, g) = domain.half_grid(id, h);
                if face == id.face {
                    return None;
                }
                (0..n as i64 - 1)
                    .flat_map(|ci| (0..n as i64 - 1).map(move |cj| (ci, cj)))
                    .find_map(|(ci, cj)| {
                        let (x2, y2) = g.point2(2 * ci + 1, 2 * cj + 1);
                        let (x, y) = (x2 / 2, y2 / 2);
                        let margin = 3;
                        (x >= margin && y >= margin && x <= s - margin && y <= s - margin)
                            .then_some((id, face, (x, y)))
                    })
            })
        })
        .expect("a level-1 diamond with a half on another face");
    let planet = PlanetGrid::from_fn(n, k, |p| {
        if p.face != face_b {
            return Some(0);
        }
        let d = ((p.x - apex.0).abs() + (p.y - apex.1).abs()) as i32;
        Some((10_000 - 2_000 * d).max(0))
    })
    .unwrap();
    let encoded = encode_planet(
        &planet,
        Quantizer::new(1).unwrap(),
        &opts(n, CoderKind::AdaptiveTokens),
    )
    .unwrap();
    assert!(verify_planet(&encoded, &planet).unwrap().within_bound());
    let decoder = Decoder::new(encoded.params, &encoded.roots).unwrap();
    let refined = decode_all(&encoded);
    let record = encoded.records.iter().find(|r| r.id == id).unwrap();
    let parents = domain.parents(id).map(|p| p.map(|p| &refined[&p]));
    let measured = measured_surface_error(&planet, id, &decoder.grid_of(id, parents));
    assert!(measured > 5000.0, "the cone is under {id}: {measured}");
    assert!(
        f64::from(record.object_error) + 1e-6 >= measured,
        "{id} on face {}: object error {} below the cone's {measured} on face {face_b}",
        id.face,
        record.object_error
    );
}

#[test]
fn a_planet_repository_is_written_and_read_back_with_its_domain() {
    use cbdam_codec::hierarchy::Record;
    use cbdam_codec::quant::QuantPlan;
    use cbdam_codec::repository::GeoRef;
    use cbdam_codec::repository::{Repository, serialize};
    let planet = adversarial(5, 2, 3, true);
    let (lo, hi) = planet.range().unwrap();
    let plan = QuantPlan::new(2.0, Some(1.0), f64::from(lo), f64::from(hi)).unwrap();
    let encoded =
        encode_planet(&planet, plan.quantizer, &opts(5, CoderKind::AdaptiveTokens)).unwrap();
    let bytes = serialize(&encoded, &plan, None, None).unwrap();
    // Flags varint at byte 12: nodata mask (1) and cube-sphere (4).
    assert_eq!(bytes[12], 5);
    let repo = Repository::from_bytes(bytes).unwrap();
    assert_eq!(*repo.head().params(), encoded.params);
    let records: Vec<Record> = repo
        .head()
        .entries()
        .iter()
        .map(|e| Record {
            id: e.id,
            bytes: repo.record(e.id).unwrap().to_vec().into(),
            object_error: e.object_error,
            min: e.min,
            max: e.max,
        })
        .collect();
    assert_eq!(records.len(), encoded.records.len());
    for (a, b) in records.iter().zip(&encoded.records) {
        assert_eq!(
            (a.id, &a.bytes, a.object_error),
            (b.id, &b.bytes, b.object_error)
        );
    }
    assert!(records.iter().any(|r| r.id.face == 5));
    let back = Encoded {
        params: *repo.head().params(),
        roots: repo.head().root_bytes().to_vec(),
        records,
        leaf_error: repo.head().leaf_error(),
    };
    let report = verify_planet(&back, &planet).unwrap();
    assert!(report.within_bound(), "{report:?}");
    check_reconstruction(&planet, &back);
    // A planet takes no planar georeferencing.
    let georef = GeoRef {
        epsg: Some(4326),
        origin_x: 0.0,
        origin_y: 0.0,
        pixel_x: 1.0,
        pixel_y: 1.0,
        pixel_is_area: false,
        wkt: None,
    };
    assert!(serialize(&encoded, &plan, Some(&georef), None).is_err());
}

#[test]
fn valid_samples_are_counted_once_per_surface_point_from_the_masks() {
    use cbdam_codec::hierarchy::mask::count_valid_samples;
    for (n, k, holes) in [(3, 2, true), (5, 2, true), (9, 1, false)] {
        let planet = adversarial(n, k, 31, holes);
        let encoded = encode_planet(
            &planet,
            Quantizer::new(2).unwrap(),
            &opts(n, CoderKind::AdaptiveTokens),
        )
        .unwrap();
        // Independently: the valid points whose canonical point is themselves.
        let d = *planet.domain();
        let s = d.cube().unwrap().side();
        let mut want = 0u64;
        for f in 0..6u8 {
            for y in 0..=s {
                for x in 0..=s {
                    let own = d.canonical_point(f, x, y) == Some(FacePoint::new(f, x, y));
                    want += u64::from(own && planet.validity(f, x, y) == Some(true));
                }
            }
        }
        if !holes {
            assert_eq!(want, 6 * (s as u64).pow(2) + 2);
        }
        let got = count_valid_samples(
            &encoded.params,
            &encoded.roots,
            encoded.records.iter().map(|r| (r.id, &r.bytes[..])),
        )
        .unwrap();
        assert_eq!(got, want, "N = {n}, K = {k}");
    }
}

/// Throughput of the planet encoder and decoder on a synthetic relief (N = 65, K = 4: six faces
/// of 1025², 6.3 M lattice points). Run with
/// `cargo test -p cbdam-codec --test tests -- --ignored planet_codec::throughput --nocapture`.
#[test]
#[ignore = "a measurement, not a check; prints figures"]
fn throughput() {
    let (n, k) = (65, 4);
    let t = std::time::Instant::now();
    let planet = relief(n, k, 3);
    let points = planet.lattice_points() as f64;
    eprintln!("input: {:.2} s", t.elapsed().as_secs_f64());
    for q in [2u32, 8] {
        let t = std::time::Instant::now();
        let encoded = encode_planet(
            &planet,
            Quantizer::new(q).unwrap(),
            &opts(n, CoderKind::AdaptiveTokens),
        )
        .unwrap();
        let enc_s = t.elapsed().as_secs_f64();
        let t = std::time::Instant::now();
        let report = verify_planet(&encoded, &planet).unwrap();
        let dec_s = t.elapsed().as_secs_f64();
        assert!(report.within_bound());
        eprintln!(
            "k = {q}: encode {enc_s:.2} s ({:.2} M points/s, {} threads), decode+verify {dec_s:.2} s, \
             {:.3} bits/point, {} records",
            points / enc_s / 1e6,
            rayon::current_num_threads(),
            encoded.payload_bytes() as f64 * 8.0 / points,
            encoded.records.len()
        );
    }
}

/// The class of a canonical point of the variable-resolution test planet: a hole where the
/// noise says so, a sample of stride 1 north of 20° N (across cube edges and the corners of
/// the north face), a sample of stride 4 elsewhere, coarse only between those.
fn variable_class(domain: &Domain, p: FacePoint) -> u8 {
    use cbdam_codec::hierarchy::resolution::{COARSE_ONLY, HOLE};
    if noise(p, 3).is_multiple_of(29) {
        return HOLE;
    }
    let ll = lattice_lat_lon(domain, p.face, p.x, p.y).unwrap();
    if ll.lat > 20.0 {
        0
    } else if p.x % 4 == 0 && p.y % 4 == 0 {
        2
    } else {
        COARSE_ONLY
    }
}

/// A variable-resolution planet: fine data north of 20° N, data at a 4 times coarser stride
/// elsewhere, holes. Every level is within the bound where there is data, the hierarchy stops
/// at the coarse data's level (L − 4) away from the fine data, the reconstruction holds the
/// coarse samples, and edge and corner points agree between faces.
#[test]
fn a_variable_resolution_planet_stops_refining_where_only_coarse_data_lies() {
    use cbdam_codec::hierarchy::Resolution;
    let (n, k, q) = (9usize, 4u32, 3u32);
    let domain = Domain::cube_sphere(n, k).unwrap();
    let values = adversarial(n, k, 5, false);
    let planet = PlanetGrid::from_fn(n, k, |p| {
        let class = variable_class(&domain, p);
        (class < 32).then(|| values.get(p.face, p.x, p.y).unwrap())
    })
    .unwrap();
    let s = ((n - 1) << k) as i64;
    let classes: Vec<Resolution> = (0..6u8)
        .map(|f| Resolution {
            class: (0..=s)
                .flat_map(|y| (0..=s).map(move |x| (x, y)))
                .map(|(x, y)| variable_class(&domain, domain.canonical_point(f, x, y).unwrap()))
                .collect(),
        })
        .collect();
    let variable = planet.clone().with_classes(classes.clone()).unwrap();
    // Classes must agree with the grid: a sample class where a point has no value is refused.
    let mut wrong = classes.clone();
    let i = wrong[0]
        .class
        .iter()
        .position(|&c| c == cbdam_codec::hierarchy::resolution::COARSE_ONLY)
        .unwrap();
    wrong[0].class[i] = 2;
    assert!(planet.clone().with_classes(wrong).is_err());

    let encoded = encode_planet(
        &variable,
        Quantizer::new(q).unwrap(),
        &opts(n, EncodeOptions::default().coder),
    )
    .unwrap();
    let report = verify_planet(&encoded, &variable).unwrap();
    assert!(report.within_bound(), "{report:?}");
    let finest = domain.finest_level();
    let coarse_leaf = finest - 4;
    // No diamond finer than the coarse data's leaves is refined far from the fine data: a
    // record there has a finest leaf below it, within a few radii of 20° N. The same planet at
    // one resolution (every point a sample) refines everywhere.
    let far_south = |id: DiamondId| {
        lattice_lat_lon(&domain, id.face, i64::from(id.x), i64::from(id.y))
            .unwrap()
            .lat
            < -10.0
    };
    let deep_records = |e: &Encoded| {
        e.records
            .iter()
            .filter(|r| r.id.level >= coarse_leaf && far_south(r.id))
            .count()
    };
    assert_eq!(deep_records(&encoded), 0);
    let full = encode_planet(
        &values,
        Quantizer::new(q).unwrap(),
        &opts(n, EncodeOptions::default().coder),
    )
    .unwrap();
    assert!(deep_records(&full) > 100, "{}", deep_records(&full));
    assert!(encoded.records.len() < full.records.len());
    // Records at the coarse leaves' level and above exist far south: the coarse data is coded.
    assert!(
        encoded
            .records
            .iter()
            .any(|r| r.id.level == coarse_leaf - 1 && far_south(r.id))
    );
    // The reconstruction holds every sample within the bound (coarse samples from the leaves at
    // level L − 4), and each edge or corner point decodes the same on every face holding it.
    let faces = reconstruct_planet(&encoded).unwrap();
    let cube = *domain.cube().unwrap();
    let mut coarse_checked = 0;
    for f in 0..6u8 {
        for y in 0..=s {
            for x in 0..=s {
                let at = (y * (s + 1) + x) as usize;
                let got = &faces[usize::from(f)];
                if let Some(want) = variable.get(f, x, y) {
                    assert!(got.valid[at], "face {f} ({x}, {y}) not decoded");
                    assert!(
                        (i64::from(got.values[at]) - i64::from(want)).abs() <= i64::from(q),
                        "face {f} ({x}, {y}): decoded {}, input {want}",
                        got.values[at]
                    );
                    if classes[usize::from(f)].class[at] == 2 {
                        coarse_checked += 1;
                    }
                }
                let (reps, len) = cube.representations(FacePoint::new(f, x, y));
                for r in &reps[1..len] {
                    let other = (r.y * (s + 1) + r.x) as usize;
                    assert_eq!(
                        (got.values[at], got.valid[at]),
                        (
                            faces[usize::from(r.face)].values[other],
                            faces[usize::from(r.face)].valid[other]
                        ),
                        "face {f} ({x}, {y}) and face {} ({}, {}) decode differently",
                        r.face,
                        r.x,
                        r.y
                    );
                }
            }
        }
    }
    assert!(coarse_checked > 1000, "{coarse_checked}");
}

/// The class of a canonical point of the tiled test planet: a sample of stride 1 north of
/// 50° N, elsewhere a sample of stride 4 (a hole where the noise says so), and between those
/// coarse only when the corners of its 4-step cell all have data, a hole otherwise (what a
/// tile holding only every 4th point says of the points between).
fn tiled_class(domain: &Domain, p: FacePoint) -> u8 {
    use cbdam_codec::hierarchy::resolution::{COARSE_ONLY, HOLE};
    let p = domain.canonical_point(p.face, p.x, p.y).unwrap();
    let fine = |p: FacePoint| lattice_lat_lon(domain, p.face, p.x, p.y).unwrap().lat > 50.0;
    let sample = |p: FacePoint| {
        let p = domain.canonical_point(p.face, p.x, p.y).unwrap();
        if fine(p) {
            0
        } else if noise(p, 11).is_multiple_of(13) {
            HOLE
        } else {
            2
        }
    };
    if fine(p) || (p.x % 4 == 0 && p.y % 4 == 0) {
        return sample(p);
    }
    let around = |v: i64| {
        let lo = v & !3;
        if lo == v { [v, v] } else { [lo, lo + 4] }
    };
    let drawn = around(p.y).iter().all(|&y| {
        around(p.x)
            .iter()
            .all(|&x| sample(FacePoint::new(p.face, x, y)) != HOLE)
    });
    if drawn { COARSE_ONLY } else { HOLE }
}

/// A variable-resolution planet held in small tiles — every point of the tiles that hold fine
/// data, every 4th point of the others — reads as the same planet held whole (heights, data,
/// what is drawn, at every point of every face), encodes to the same hierarchy (records, roots,
/// object errors: the tiled object-error scans, including diamonds finer than a tile's
/// points next to fine data, find what the whole faces' scans find), verifies within the
/// bound and decodes onto its tiles as the whole planet decodes onto its faces.
#[test]
fn a_planet_in_strided_tiles_encodes_as_the_same_planet_held_whole() {
    use cbdam_codec::hierarchy::resolution::HOLE;
    use cbdam_codec::hierarchy::{PlanetTile, Resolution, reconstruct_planet_like};
    let (n, k, q, tile_log2) = (9usize, 3u32, 2u32, 3u32);
    let domain = Domain::cube_sphere(n, k).unwrap();
    let s = ((n - 1) << k) as i64;
    let values = relief(n, k, 21);
    let whole = PlanetGrid::from_fn(n, k, |p| {
        (tiled_class(&domain, p) < 32).then(|| values.get(p.face, p.x, p.y).unwrap())
    })
    .unwrap();
    let classes: Vec<Resolution> = (0..6u8)
        .map(|f| Resolution {
            class: (0..=s)
                .flat_map(|y| (0..=s).map(move |x| (x, y)))
                .map(|(x, y)| tiled_class(&domain, FacePoint::new(f, x, y)))
                .collect(),
        })
        .collect();
    let whole = whole.with_classes(classes.clone()).unwrap();
    assert!(whole.has_nodata());
    // The same points in tiles of 8 steps: every point where a tile holds a stride-1 sample,
    // every 4th elsewhere.
    let rects = PlanetGrid::tile_rects(&domain, tile_log2);
    let tiles = |thin: bool| -> Vec<Vec<PlanetTile>> {
        (0..6u8)
            .map(|f| {
                let class = &classes[usize::from(f)].class;
                rects
                    .iter()
                    .map(|&(x0, y0, x1, y1)| {
                        let at = |x: i64, y: i64| (y * (s + 1) + x) as usize;
                        let fine = (y0..=y1).any(|y| (x0..=x1).any(|x| class[at(x, y)] == 0));
                        let stride = if thin && !fine { 2 } else { 0 };
                        let step = 1usize << stride;
                        let points: Vec<(i64, i64)> = (y0..=y1)
                            .step_by(step)
                            .flat_map(|y| (x0..=x1).step_by(step).map(move |x| (x, y)))
                            .collect();
                        let grid = HeightGrid {
                            width: ((x1 - x0) >> stride) as usize + 1,
                            height: ((y1 - y0) >> stride) as usize + 1,
                            values: points
                                .iter()
                                .map(|&(x, y)| whole.get(f, x, y).unwrap_or(0))
                                .collect(),
                            valid: points
                                .iter()
                                .map(|&(x, y)| whole.get(f, x, y).is_some())
                                .collect(),
                        };
                        let held = points.iter().map(|&(x, y)| class[at(x, y)]).collect();
                        PlanetTile::new(stride, (x0, y0, x1, y1), grid, Some(held)).unwrap()
                    })
                    .collect()
            })
            .collect()
    };
    let thin = PlanetGrid::from_tiles(n, k, tile_log2, tiles(true), true).unwrap();
    let dense = PlanetGrid::from_tiles(n, k, tile_log2, tiles(false), true).unwrap();
    // Strided tiles exist, and hold far fewer points.
    let strided = (0..6u8)
        .flat_map(|f| thin.tiles(f))
        .filter(|t| t.stride > 0)
        .count();
    assert!(strided > 100 && strided < 6 * rects.len(), "{strided}");
    assert!(
        thin.held_points() * 2 < dense.held_points(),
        "{} of {}",
        thin.held_points(),
        dense.held_points()
    );
    let mut holes_between = 0;
    for f in 0..6u8 {
        for y in 0..=s {
            for x in 0..=s {
                let want = (whole.get(f, x, y), whole.drawn(f, x, y));
                assert_eq!(
                    (thin.get(f, x, y), thin.drawn(f, x, y)),
                    want,
                    "face {f} ({x}, {y})"
                );
                assert_eq!((dense.get(f, x, y), dense.drawn(f, x, y)), want);
                let between = x % 4 != 0 || y % 4 != 0;
                holes_between += usize::from(
                    between && classes[usize::from(f)].class[(y * (s + 1) + x) as usize] == HOLE,
                );
            }
        }
    }
    // The cell rule is exercised: points between the held ones that are holes.
    assert!(holes_between > 50, "{holes_between}");

    let quantizer = Quantizer::new(q).unwrap();
    let o = opts(n, CoderKind::AdaptiveTokens);
    let from_whole = encode_planet(&whole, quantizer, &o).unwrap();
    // (Compared whole; `assert_eq!` would print every record's bytes.)
    let same = |p: &PlanetGrid| encode_planet(p, quantizer, &o).unwrap() == from_whole;
    assert!(
        same(&thin),
        "the planet in strided tiles encodes differently"
    );
    assert!(
        same(&dense),
        "the planet in dense tiles encodes differently"
    );
    // The variable resolution matters: the planet at one resolution has more records.
    assert!(
        encode_planet(&values, quantizer, &o).unwrap().records.len() > from_whole.records.len()
    );
    let report = verify_planet(&from_whole, &thin).unwrap();
    assert!(report.within_bound(), "{report:?}");

    let decoded = reconstruct_planet(&from_whole).unwrap();
    let on_tiles = reconstruct_planet_like(&from_whole, &thin).unwrap();
    let mut checked = 0;
    for f in 0..6u8 {
        for t in on_tiles.tiles(f) {
            let (x0, y0, x1, y1) = t.rect;
            let step = 1usize << t.stride;
            for y in (y0..=y1).step_by(step) {
                for x in (x0..=x1).step_by(step) {
                    let k = t.index(x, y).unwrap();
                    let at = (y * (s + 1) + x) as usize;
                    let face = &decoded[usize::from(f)];
                    assert_eq!(
                        (t.grid.values[k], t.grid.valid[k]),
                        (face.values[at], face.valid[at]),
                        "face {f} ({x}, {y})"
                    );
                    checked += usize::from(face.valid[at]);
                }
            }
        }
    }
    assert!(checked > 5_000, "{checked}");
}
