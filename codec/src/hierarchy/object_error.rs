//! Object-space error of a diamond: how far its drawn surface is from the input samples under it.
//!
//! The surface of a diamond is the piecewise-linear interpolant of its reconstructed grid, cells
//! split parallel to the split diagonal exactly as they are drawn. Grid spacings are powers of
//! two in lattice units, so the interpolant at an input sample is a rational with that
//! denominator: it is evaluated exactly in integers, and the maximum rounded up.

use rayon::prelude::*;

use crate::geometry::{Diagonal, DiamondId, Layout};
use crate::quant::HeightGrid;

/// Diamonds whose grid rows span at least this many lattice units have their rows scanned in
/// parallel.
const PARALLEL_ROWS_FROM: i64 = 512;

/// The largest distance, in units rounded up, between the surface of diamond `id` with grid `p`
/// and the valid input samples under it (0 if there are none).
///
/// Exact, in integers scaled by the grid spacing `sp` (a power of two). Works row by row in the
/// diamond's scaled grid coordinates `(s, t)`: the surface along a row is filled into a buffer
/// cell by cell (two linear pieces per cell, split by the cell's triangle diagonal), then
/// compared with the input samples of that row in one tight loop. For even levels a row is an
/// input row; for odd levels (s = Δx + Δy, t = Δx − Δy) it is an input diagonal.
pub(crate) fn surface_error(layout: &Layout, id: DiamondId, p: &[i32], input: &HeightGrid) -> u32 {
    let g = layout.grid(id);
    if id.is_even() && g.u.0 == 1 {
        // The finest level: every sample is a grid vertex.
        let n = layout.n();
        let mut worst = 0i64;
        for j in 0..n as i64 {
            for i in 0..n as i64 {
                let (x, y) = g.point(i, j);
                if let Some(v) = input.get(x, y) {
                    worst =
                        worst.max((i64::from(p[j as usize * n + i as usize]) - i64::from(v)).abs());
                }
            }
        }
        return u32::try_from(worst).unwrap_or(u32::MAX);
    }
    let parallel = layout.radius(id.level) * 2 >= PARALLEL_ROWS_FROM;
    surface_error_scan(layout, id, p, input, parallel)
}

/// [`surface_error`] without the finest-level shortcut, rows scanned in parallel or not.
fn surface_error_scan(
    layout: &Layout,
    id: DiamondId,
    p: &[i32],
    input: &HeightGrid,
    parallel: bool,
) -> u32 {
    match layout.diagonal(id) {
        Diagonal::Main => surface_error_rows::<true>(layout, id, p, input, parallel),
        Diagonal::Anti => surface_error_rows::<false>(layout, id, p, input, parallel),
    }
}

fn surface_error_rows<const MAIN: bool>(
    layout: &Layout,
    id: DiamondId,
    p: &[i32],
    input: &HeightGrid,
    parallel: bool,
) -> u32 {
    let n = layout.n();
    let g = layout.grid(id);
    let odd = !id.is_even();
    let sp = if odd { 2 * g.u.0 } else { g.u.0 };
    debug_assert!(sp.count_ones() == 1, "grid spacings are powers of two");
    let shift = sp.trailing_zeros();
    let last = n as i64 - 2;
    let side = sp * (n as i64 - 1);
    let (ox, oy) = g.origin;
    let (w, h) = (input.width as i64, input.height as i64);
    // One row of the diamond: the largest scaled error over its samples in the data.
    let row_error = |t: i64, surface: &mut [i64]| -> i64 {
        // The row's samples that lie in the data: s in [lo, hi] (odd levels: s ≡ t mod 2).
        let (mut lo, mut hi) = if odd {
            (
                (-2 * ox - t).max(t - 2 * oy).max(0),
                (2 * (w - 1 - ox) - t).min(2 * (h - 1 - oy) + t).min(side),
            )
        } else {
            if oy + t < 0 || oy + t >= h {
                return 0;
            }
            ((-ox).max(0), (w - 1 - ox).min(side))
        };
        if odd && (lo - t).rem_euclid(2) != 0 {
            lo += 1;
        }
        if odd && (hi - t).rem_euclid(2) != 0 {
            hi -= 1;
        }
        if lo > hi {
            return 0;
        }
        let cj = (t >> shift).min(last);
        let ft = t - (cj << shift);
        let row = cj as usize * n;
        for ci in (lo >> shift).min(last)..=(hi >> shift).min(last) {
            let k = row + ci as usize;
            let (v00, v10, v01, v11) = (
                i64::from(p[k]),
                i64::from(p[k + 1]),
                i64::from(p[k + n]),
                i64::from(p[k + n + 1]),
            );
            // Two linear pieces c0 + c1·fs: [a0, a1] and [b0, b1] in fs.
            let (a1, pieces) = if MAIN {
                (
                    ft - 1,
                    [
                        (v00 * sp + (v01 - v00) * ft, v11 - v01),
                        (v00 * sp + (v11 - v10) * ft, v10 - v00),
                    ],
                )
            } else {
                (
                    sp - ft,
                    [
                        (v00 * sp + (v01 - v00) * ft, v10 - v00),
                        (v01 * sp + (v10 - v11) * (sp - ft), v11 - v01),
                    ],
                )
            };
            let s0 = ci << shift;
            let ranges = [(0, a1), (a1 + 1, sp)];
            for ((r0, r1), (c0, c1)) in ranges.into_iter().zip(pieces) {
                let from = r0.max(lo - s0);
                let to = r1.min(hi - s0);
                if from > to {
                    continue;
                }
                let mut v = c0 + c1 * from;
                for slot in &mut surface[(s0 + from) as usize..=(s0 + to) as usize] {
                    *slot = v;
                    v += c1;
                }
            }
        }
        // Compare the row with the input.
        let (kstep, sstep) = if odd { (input.width + 1, 2) } else { (1, 1) };
        let (x, y) = if odd {
            (ox + (lo + t) / 2, oy + (lo - t) / 2)
        } else {
            (ox + lo, oy + t)
        };
        let mut k = (y * w + x) as usize;
        let mut s = lo;
        let mut worst_h = 0i64;
        while s <= hi {
            let e = (surface[s as usize] - i64::from(input.values[k]) * sp).abs();
            // Branch-free: nodata contributes 0.
            worst_h = worst_h.max(e * i64::from(input.valid[k]));
            k += kstep;
            s += sstep;
        }
        worst_h
    };
    // The coarsest diamonds cover the whole dataset alone, and their level has too few
    // diamonds to keep every core busy: split their rows across threads instead.
    let rows = 0..=side;
    let fresh = || vec![0i64; side as usize + 1];
    let worst_h = if parallel {
        rows.into_par_iter()
            .map_init(fresh, |surface, t| row_error(t, surface))
            .max()
            .unwrap_or(0)
    } else {
        let mut surface = fresh();
        rows.map(|t| row_error(t, &mut surface)).max().unwrap_or(0)
    };
    let e = (worst_h + sp - 1) / sp;
    u32::try_from(e).unwrap_or(u32::MAX)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Layout;

    /// `h ×` the piecewise-linear interpolant at `(is, js)` (grid coordinates times `h`), for a grid
    /// of spacing `h` split along `diag`.
    #[inline]
    fn interpolate_h(p: &[i32], n: usize, diag: Diagonal, h: i64, is: i64, js: i64) -> i64 {
        let ci = ((is / h) as usize).min(n - 2);
        let cj = ((js / h) as usize).min(n - 2);
        let (fx, fy) = (is - ci as i64 * h, js - cj as i64 * h);
        let at = |i: usize, j: usize| i64::from(p[j * n + i]);
        let (v00, v10, v01, v11) = (
            at(ci, cj),
            at(ci + 1, cj),
            at(ci, cj + 1),
            at(ci + 1, cj + 1),
        );
        match diag {
            Diagonal::Main if fx >= fy => v00 * h + (v10 - v00) * fx + (v11 - v10) * fy,
            Diagonal::Main => v00 * h + (v11 - v01) * fx + (v01 - v00) * fy,
            Diagonal::Anti if fx + fy <= h => v00 * h + (v10 - v00) * fx + (v01 - v00) * fy,
            Diagonal::Anti => v11 * h + (v01 - v11) * (h - fx) + (v10 - v11) * (h - fy),
        }
    }

    /// Reference: the surface at every sample of the diamond, located by division.
    fn brute_force(layout: &Layout, id: DiamondId, p: &[i32], input: &HeightGrid) -> u32 {
        let (n, diag, g) = (layout.n(), layout.diagonal(id), layout.grid(id));
        let r = layout.radius(id.level);
        let (cx, cy) = (i64::from(id.x), i64::from(id.y));
        let mut worst = 0f64;
        for y in cy - r..=cy + r {
            for x in cx - r..=cx + r {
                let Some(v) = input.get(x, y) else { continue };
                let (dx, dy) = (x - g.origin.0, y - g.origin.1);
                let (sp, s, t) = if id.is_even() {
                    (g.u.0, dx, dy)
                } else {
                    (2 * g.u.0, dx + dy, dx - dy)
                };
                if s < 0 || t < 0 || s > sp * (n as i64 - 1) || t > sp * (n as i64 - 1) {
                    continue; // outside a rotated diamond
                }
                let surf = interpolate_h(p, n, diag, sp, s, t) as f64 / sp as f64;
                worst = worst.max((surf - f64::from(v)).abs());
            }
        }
        worst.ceil() as u32
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig { cases: 64, ..Default::default() })]
        #[test]
        fn incremental_evaluation_matches_brute_force_on_every_level(
            n_pow in 1u32..4,
            k in 0u32..4,
            rx in 1u32..3,
            ry in 1u32..3,
            cut_w in 0usize..6,
            cut_h in 0usize..6,
            holes in proptest::collection::vec(proptest::prelude::any::<u16>(), 0..8),
            seed in proptest::prelude::any::<u64>(),
        ) {
            let layout = Layout::new((1 << n_pow) + 1, k, rx, ry).unwrap();
            let n = layout.n();
            let (ex, ey) = layout.extent();
            // Data narrower and shorter than the domain, or reaching its far edge.
            let w = (ex as usize + 1).saturating_sub(cut_w).max(1);
            let h = (ey as usize + 1).saturating_sub(cut_h).max(1);
            let mut seed = seed | 1;
            let mut rnd = |m: i64| {
                seed ^= seed << 13;
                seed ^= seed >> 7;
                seed ^= seed << 17;
                (seed % (2 * m as u64 + 1)) as i64 - m
            };
            let mut input = HeightGrid::all_valid(w, h, (0..w * h).map(|_| rnd(1000) as i32).collect());
            for hole in holes {
                input.valid[hole as usize % (w * h)] = false;
            }
            let mut frontier: Vec<DiamondId> = layout.roots().collect();
            let mut seen = std::collections::HashSet::new();
            while let Some(d) = frontier.pop() {
                if !seen.insert(d) {
                    continue;
                }
                frontier.extend(layout.children(d).into_iter().flatten());
                let p: Vec<i32> = (0..n * n).map(|_| rnd(1000) as i32).collect();
                let want = brute_force(&layout, d, &p, &input);
                proptest::prop_assert_eq!(surface_error(&layout, d, &p, &input), want, "{}", d);
                if d.level < layout.finest_level() || !d.is_even() {
                    for parallel in [false, true] {
                        proptest::prop_assert_eq!(surface_error_scan(&layout, d, &p, &input, parallel), want, "{} {}", d, parallel);
                    }
                }
            }
        }
    }

    #[test]
    fn interpolation_hits_vertices_and_is_linear_on_triangles() {
        let n = 3;
        let p = [0, 10, 20, 5, 16, 30, 8, 20, 40];
        for diag in [Diagonal::Main, Diagonal::Anti] {
            let h = 4;
            for j in 0..n {
                for i in 0..n {
                    let got = interpolate_h(&p, n, diag, h, i as i64 * h, j as i64 * h);
                    assert_eq!(
                        got,
                        i64::from(p[j * n + i]) * h,
                        "{diag:?} vertex ({i},{j})"
                    );
                }
            }
        }
        // Midpoint of the split diagonal of cell (0,0): the mean of its two ends.
        assert_eq!(
            interpolate_h(&p, n, Diagonal::Main, 4, 2, 2),
            16 * 2,
            "(0 + 16) / 2, times h = 4"
        );
        assert_eq!(interpolate_h(&p, n, Diagonal::Anti, 4, 2, 2), (10 + 5) * 2);
    }

    #[test]
    fn error_of_an_exact_plane_is_zero_and_of_a_bump_is_its_height() {
        let layout = Layout::new(5, 1, 1, 1).unwrap(); // root side 8, finest spacing 1
        let root = layout.roots().next().unwrap();
        let plane = |x: i64, y: i64| (3 * x - 2 * y) as i32;
        let values: Vec<i32> = (0..81).map(|k| plane(k % 9, k / 9)).collect();
        let mut input = HeightGrid::all_valid(9, 9, values);
        let g = layout.grid(root);
        let p: Vec<i32> = (0..25)
            .map(|k| {
                let (x, y) = g.point(k % 5, k / 5);
                plane(x, y)
            })
            .collect();
        assert_eq!(surface_error(&layout, root, &p, &input), 0);
        input.values[4 * 9 + 3] += 7; // a sample between grid vertices
        assert_eq!(surface_error(&layout, root, &p, &input), 7);
        input.valid[4 * 9 + 3] = false; // nodata does not count
        assert_eq!(surface_error(&layout, root, &p, &input), 0);
    }
}
