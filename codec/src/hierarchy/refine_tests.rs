//! Tests of `refine.rs`: the gather, the reconstruction and the refinement against their
//! definitions.

use super::*;
use crate::hierarchy::reconstruct::reconstruct_cells_with;
use crate::lifting::{
    MAX_ABS_HEIGHT, PREDICTION_LIMIT, VectorKernels, clamp_prediction, predict_cells,
};

/// Every diamond of `domain` down to `levels`, parents before children.
fn diamonds(domain: &Domain, levels: u8) -> Vec<DiamondId> {
    let mut all: Vec<DiamondId> = domain.roots().collect();
    let mut seen: std::collections::HashSet<DiamondId> = all.iter().copied().collect();
    let mut i = 0;
    while i < all.len() {
        let id = all[i];
        if id.level < levels {
            for c in domain.children(id).into_iter().flatten() {
                if seen.insert(c) {
                    all.push(c);
                }
            }
        }
        i += 1;
    }
    all
}

/// The definition [`gather_values`] implements, one point at a time: point `(i, j)` of the
/// half on parent `h` is that parent's half-step value where `(i, j)` lands; a half whose
/// parent is missing is the mirror image of the other; where both exist the diagonal is
/// the second parent's.
fn gather_by_definition(domain: &Domain, id: DiamondId, parents: [Option<&[u32]>; 2]) -> Vec<u32> {
    let layout = domain.layout();
    let n = layout.n();
    let side = (2 * n - 1) as i64;
    let diag = layout.diagonal(id);
    let ids = domain.parents(id);
    let mut out = vec![u32::MAX; n * n];
    for (h, half) in Half::BOTH.into_iter().enumerate() {
        let Some(parent) = parents[h] else { continue };
        let pid = ids[h].unwrap();
        let m = domain
            .grid_in_parent_frame(id, half, pid)
            .unwrap()
            .index_map_into_half_step(&layout.grid(pid))
            .unwrap();
        for j in 0..n {
            let (lo, hi) = half_range(diag, half, n, j);
            for i in lo..=hi {
                let (a, b) = m.apply(i as i64, j as i64);
                out[j * n + i] = parent[(b * side + a) as usize];
            }
        }
    }
    mirror_missing_halves(diag, n, parents.map(|p| p.is_some()), &mut out);
    out
}

/// [`reconstruct_cells`] (in i32, with its early refusal) against the definition in i64:
/// the same cells where every cell is in range, an error exactly where one is not; with
/// residuals up to the entropy decoders' limit and steps up to 2³¹ − 1.
#[test]
fn cells_in_i32_are_the_i64_definition() {
    let n = 9;
    let m = n - 1;
    let mut state = 7u64;
    let mut next = || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        state >> 16
    };
    let mut outcomes = [0usize; 2];
    for round in 0..4000 {
        let p: Vec<i32> = (0..n * n)
            .map(|_| (next() % (2 * MAX_ABS_HEIGHT as u64 + 1)) as i32 - MAX_ABS_HEIGHT)
            .collect();
        let step = [1i64, 3, 2_001, 1 << 20 | 1, i64::from(i32::MAX)][round % 5];
        let dc: Vec<i32> = (0..m * m)
            .map(|_| {
                let magnitude = match next() % 64 {
                    0 => (next() % (1 << 30)) as i32,
                    1 => (i64::from(MAX_ABS_HEIGHT) / step) as i32 + (next() % 3) as i32,
                    _ => (next() % 50) as i32,
                };
                if next() % 2 == 0 {
                    magnitude
                } else {
                    -magnitude
                }
            })
            .collect();
        let expected = cells_by_definition(&p, n, &dc, step);
        let mut got = Vec::new();
        let result = reconstruct_cells(&p, n, &dc, step, &mut got);
        assert_eq!(result.is_ok(), expected.is_some(), "round {round}");
        if let Some(expected) = &expected {
            assert_eq!(&got, expected, "round {round}");
        }
        outcomes[usize::from(expected.is_some())] += 1;
    }
    // Both outcomes were met.
    assert!(outcomes.iter().all(|&c| c > 100), "{outcomes:?}");
}

/// The cells by their definition, in i64: the clamped prediction plus `step ×` the residual;
/// `None` when one is out of range.
fn cells_by_definition(p: &[i32], n: usize, dc: &[i32], step: i64) -> Option<Vec<i32>> {
    let mut cells = vec![0; (n - 1) * (n - 1)];
    predict_cells(p, n, &mut cells);
    let mut in_range = true;
    for (c, &d) in cells.iter_mut().zip(dc) {
        let v = clamp_prediction(i64::from(*c)) + step * i64::from(d);
        in_range &= v.abs() <= i64::from(MAX_ABS_HEIGHT);
        *c = v as i32;
    }
    in_range.then_some(cells)
}

/// The decoder's shortcuts against the definition: a record without residuals (cells only
/// clamped, on grids whose predictions overshoot the clamp), and residuals whose largest
/// `step ×` magnitude lies just below, at and above the reach where no cell can leave the
/// range (the cells are then not checked), on every grid size up to N = 65.
#[test]
fn cells_without_or_with_small_residuals_are_the_i64_definition() {
    let mut state = 11u64;
    let mut next = || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        state >> 16
    };
    let unchecked_reach = i64::from(MAX_ABS_HEIGHT - PREDICTION_LIMIT);
    let mut outcomes = [0usize; 2];
    for round in 0..3000 {
        let n = [3, 5, 9, 17, 65][round % 5];
        let m = n - 1;
        // Grids at the edges of the range, so that order-4 predictions overshoot the clamp.
        let p: Vec<i32> = (0..n * n)
            .map(|_| match next() % 3 {
                0 => MAX_ABS_HEIGHT,
                1 => -MAX_ABS_HEIGHT,
                _ => (next() % (2 * MAX_ABS_HEIGHT as u64 + 1)) as i32 - MAX_ABS_HEIGHT,
            })
            .collect();
        let zero = round % 3 == 0;
        let step = 1 + (next() % 4) as i64;
        // The largest magnitude: its reach step × largest just below, at or above the limit.
        let largest = (unchecked_reach / step) as i32 + (next() % 3) as i32 - 1;
        let dc: Vec<i32> = (0..m * m)
            .map(|_| match next() % 4 {
                _ if zero => 0,
                0 => largest * if next() % 2 == 0 { 1 } else { -1 },
                _ => (next() % 3) as i32 - 1,
            })
            .collect();
        let expected = cells_by_definition(&p, n, &dc, step);
        let mut got = Vec::new();
        let result = reconstruct_cells(&p, n, &dc, step, &mut got);
        assert_eq!(result.is_ok(), expected.is_some(), "round {round}");
        if let Some(expected) = &expected {
            assert_eq!(&got, expected, "round {round}");
        }
        outcomes[usize::from(expected.is_some())] += 1;
    }
    // Both outcomes were met.
    assert!(outcomes.iter().all(|&c| c > 100), "{outcomes:?}");
}

/// Gathering in the parents' memory order gives every point its definition, on a plane
/// (diamonds on its edges have one parent) and on a cube-sphere (halves read across face
/// edges and at the corners, in the neighbouring face's frame).
#[test]
fn gathering_row_by_row_follows_the_definition() {
    let domains = [
        Domain::covering(9, 50, 37, 0).unwrap(),
        Domain::covering(17, 90, 131, 0).unwrap(),
        Domain::cube_sphere(9, 1).unwrap(),
    ];
    for domain in domains {
        let n = domain.n();
        let side = 2 * n - 1;
        let ids = diamonds(&domain, 3);
        let mut checked = [0usize; 2];
        for (k, &id) in ids.iter().enumerate().filter(|(_, id)| id.level > 0) {
            // Distinct values everywhere, so that any misplaced read shows.
            let grids: [Vec<u32>; 2] = std::array::from_fn(|h| {
                (0..side * side)
                    .map(|p| (k * 4 + h) as u32 * 100_000 + p as u32)
                    .collect()
            });
            let present = domain.parents(id).map(|p| p.is_some());
            let parents: [Option<&[u32]>; 2] =
                std::array::from_fn(|h| present[h].then_some(&grids[h][..]));
            let mut got = vec![u32::MAX; n * n];
            let grids = parents.map(|p| p.map(|values| HalfStepGrid { side, values }));
            gather_values(&domain, id, grids, false, &mut got);
            let expected = gather_by_definition(&domain, id, parents);
            assert_eq!(got, expected, "{id}");
            // Heights: the same gather from refinements that store only the vertices and
            // cell centres of those half-step grids.
            let refined = parents.map(|p| {
                p.map(|g| {
                    let pick = |o: usize, side_of: usize| -> Vec<i32> {
                        (0..side_of * side_of)
                            .map(|q| {
                                let (i, j) = (q % side_of, q / side_of);
                                g[(2 * j + o) * side + 2 * i + o] as i32
                            })
                            .collect()
                    };
                    Refined::from_parts(n, &pick(0, n), &pick(1, n - 1))
                })
            });
            let mut heights = vec![i32::MIN; n * n];
            gather_values(
                &domain,
                id,
                refined.each_ref().map(Option::as_ref),
                false,
                &mut heights,
            );
            for (k, (&h, &e)) in heights.iter().zip(&expected).enumerate() {
                assert_eq!(h, e as i32, "{id} point {k}");
            }
            checked[usize::from(present.iter().all(|&p| p))] += 1;
        }
        // Both kinds of diamond were checked where the domain has them.
        assert!(checked[1] > 0, "{checked:?}");
        if domain.cube().is_none() {
            assert!(checked[0] > 0, "{checked:?}");
        }
    }
}

proptest::proptest! {
    /// Every vector kernel this CPU runs (AVX2 on x86-64 where it has it) reconstructs the
    /// cells the portable loops do, and refuses the same records: random grids and residuals,
    /// with heights at ±MAX_ABS_HEIGHT, residuals up to the entropy decoders' limit (2³⁰) and
    /// around the refusal threshold, and steps up to 2³¹ − 1.
    #[test]
    fn every_vector_kernel_reconstructs_the_portable_cells(
        n_pow in 1u32..8,
        seed in proptest::prelude::any::<u64>(),
        step_kind in 0usize..4,
        extremes in proptest::prelude::any::<bool>(),
    ) {
        let n = (1usize << n_pow) + 1;
        let m = n - 1;
        let mut state = seed | 1;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let step = match step_kind {
            0 => 1,
            1 => 1 + (next() % 1000) as i64,
            2 => 1 + (next() % (1 << 20)) as i64,
            _ => i64::from(i32::MAX),
        };
        let span = 2 * MAX_ABS_HEIGHT as u64 + 1;
        let p: Vec<i32> = (0..n * n)
            .map(|_| match next() % 8 {
                0 if extremes => MAX_ABS_HEIGHT,
                1 if extremes => -MAX_ABS_HEIGHT,
                _ => (next() % span) as i32 - MAX_ABS_HEIGHT,
            })
            .collect();
        let dc: Vec<i32> = (0..m * m)
            .map(|_| {
                let magnitude = match next() % 64 {
                    0 if extremes => (next() % (1 << 30)) as i32,
                    1 => (i64::from(MAX_ABS_HEIGHT) / step) as i32 + (next() % 3) as i32,
                    _ => (next() % 50) as i32,
                };
                if next() % 2 == 0 { magnitude } else { -magnitude }
            })
            .collect();
        let mut portable = Vec::new();
        let expected =
            reconstruct_cells_with(VectorKernels::Portable, &p, n, &dc, step, &mut portable);
        for kernels in VectorKernels::available() {
            let mut got = Vec::new();
            let result = reconstruct_cells_with(kernels, &p, n, &dc, step, &mut got);
            proptest::prop_assert_eq!(result.is_ok(), expected.is_ok(), "{:?}", kernels);
            if result.is_ok() {
                proptest::prop_assert_eq!(&got, &portable, "{:?}", kernels);
            }
        }
    }
}

/// [`ChildHalf::map_row`] (a child's row read along its parent's diagonal and converted in the
/// same pass, what the finest level's raster writer uses) against the definition: every run of
/// every row of every half a parent gives a child, from any start column to any end, is the
/// converted [`gather_by_definition`] of that child at those points.
#[test]
fn a_child_half_row_maps_to_the_gathered_points() {
    for domain in [
        Domain::covering(9, 50, 37, 0).unwrap(),
        Domain::covering(17, 90, 131, 0).unwrap(),
    ] {
        let n = domain.n();
        let side = 2 * n - 1;
        // Distinct values on each diamond's half-step grid, so that any misplaced read shows.
        let grid_of = |id: DiamondId| -> Vec<u32> {
            let seed = (u32::from(id.level) * 7919 + id.x * 131 + id.y) * 10_000;
            (0..side * side).map(|p| seed + p as u32).collect()
        };
        let refined_of = |g: &[u32]| {
            let pick = |o: usize, side_of: usize| -> Vec<i32> {
                (0..side_of * side_of)
                    .map(|q| g[(2 * (q / side_of) + o) * side + 2 * (q % side_of) + o] as i32)
                    .collect()
            };
            Refined::from_parts(n, &pick(0, n), &pick(1, n - 1))
        };
        let convert = |v: i32| f64::from(v) * 0.25 - 3.0;
        let mut runs = 0usize;
        for &child in diamonds(&domain, 3).iter().filter(|id| id.level > 0) {
            let ids = domain.parents(child);
            for (h, half) in Half::BOTH.into_iter().enumerate() {
                let Some(pid) = ids[h] else { continue };
                let g = grid_of(pid);
                // The definition with this parent alone: its half, split diagonal included.
                let mut alone = [None, None];
                alone[h] = Some(&g[..]);
                let expected = gather_by_definition(&domain, child, alone);
                let refined = refined_of(&g);
                let ch = ChildHalf::new(&domain, child, half, pid, &refined);
                for j in 0..n {
                    let (lo, hi) = ch.row_range(n, j);
                    for i0 in lo..=hi {
                        for i1 in i0..=hi {
                            let mut got = vec![f64::NAN; i1 - i0 + 1];
                            ch.map_row(i0, j, &mut got, convert);
                            let want: Vec<f64> = (i0..=i1)
                                .map(|i| convert(expected[j * n + i] as i32))
                                .collect();
                            assert_eq!(got, want, "{child} half {h} row {j} columns {i0}..={i1}");
                            runs += 1;
                        }
                    }
                }
            }
        }
        assert!(runs > 1000, "{runs}");
    }
}
