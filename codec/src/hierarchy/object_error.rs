//! Object-space error of a diamond: how far its drawn surface is from the input samples under it.
//!
//! The surface of a diamond is the piecewise-linear interpolant of its reconstructed grid, cells
//! split parallel to the split diagonal exactly as they are drawn. Grid spacings are powers of
//! two in lattice units, so the interpolant at an input sample is a rational with that
//! denominator: it is evaluated exactly in integers, and the maximum rounded up.

use crate::geometry::{Diagonal, DiamondId, Layout};
use crate::quant::HeightGrid;

/// The largest distance, in units rounded up, between the surface of diamond `id` with grid `p`
/// and the valid input samples under it (0 if there are none).
///
/// Visits each grid cell once and the samples inside it with the cell's two planes evaluated
/// incrementally: every sample is touched once per level, with no division in the loop.
pub(crate) fn surface_error(layout: &Layout, id: DiamondId, p: &[i32], input: &HeightGrid) -> u32 {
    let n = layout.n();
    let diag = layout.diagonal(id);
    let g = layout.grid(id);
    let (w, h) = (input.width as i64, input.height as i64);
    // Grid coordinates scaled by the spacing `sp`: even levels use (x, y) − origin directly;
    // odd levels use s = Δx + Δy, t = Δx − Δy, where lattice points have s ≡ t (mod 2).
    let (sp, odd) = if id.is_even() {
        (g.u.0, false)
    } else {
        (2 * g.u.0, true)
    };
    let (ox, oy) = g.origin;
    let mut worst_h = 0i64;
    for cj in 0..n - 1 {
        for ci in 0..n - 1 {
            let at = |i: usize, j: usize| i64::from(p[j * n + i]);
            let (v00, v10, v01, v11) = (
                at(ci, cj),
                at(ci + 1, cj),
                at(ci, cj + 1),
                at(ci + 1, cj + 1),
            );
            let (s0, t0) = (ci as i64 * sp, cj as i64 * sp);
            for ft in 0..=sp {
                let t = t0 + ft;
                // Samples of this row of the cell: fs from `first` in steps of `stride`.
                let (first, stride) = if odd { ((s0 + t) & 1, 2) } else { (0, 1) };
                let mut fs = first;
                while fs <= sp {
                    let s = s0 + fs;
                    let (x, y) = if odd {
                        (ox + (s + t) / 2, oy + (s - t) / 2)
                    } else {
                        (ox + s, oy + t)
                    };
                    if x >= 0 && y >= 0 && x < w && y < h {
                        let k = y as usize * input.width + x as usize;
                        if input.valid[k] {
                            let (fx, fy) = (fs, ft);
                            let surf = match diag {
                                Diagonal::Main if fx >= fy => {
                                    v00 * sp + (v10 - v00) * fx + (v11 - v10) * fy
                                }
                                Diagonal::Main => v00 * sp + (v11 - v01) * fx + (v01 - v00) * fy,
                                Diagonal::Anti if fx + fy <= sp => {
                                    v00 * sp + (v10 - v00) * fx + (v01 - v00) * fy
                                }
                                Diagonal::Anti => {
                                    v11 * sp + (v01 - v11) * (sp - fx) + (v10 - v11) * (sp - fy)
                                }
                            };
                            worst_h = worst_h.max((surf - i64::from(input.values[k]) * sp).abs());
                        }
                    }
                    fs += stride;
                }
            }
        }
    }
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

    #[test]
    fn incremental_evaluation_matches_brute_force_on_every_level() {
        let layout = Layout::new(5, 2, 2, 1).unwrap();
        let (ex, ey) = layout.extent();
        let (w, h) = (ex as usize - 3, ey as usize + 1); // data narrower than the domain
        let mut seed = 12345u64;
        let mut rnd = |m: i64| {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed % (2 * m as u64 + 1)) as i64 - m
        };
        let mut input = HeightGrid::all_valid(w, h, (0..w * h).map(|_| rnd(1000) as i32).collect());
        input.valid[7] = false;
        let mut frontier: Vec<DiamondId> = layout.roots().collect();
        let mut seen = std::collections::HashSet::new();
        let mut checked = [0; 2];
        while let Some(d) = frontier.pop() {
            if !seen.insert(d) {
                continue;
            }
            frontier.extend(layout.children(d).into_iter().flatten());
            let p: Vec<i32> = (0..25).map(|_| rnd(1000) as i32).collect();
            assert_eq!(
                surface_error(&layout, d, &p, &input),
                brute_force(&layout, d, &p, &input),
                "{d}"
            );
            checked[usize::from(!d.is_even())] += 1;
        }
        assert!(checked[0] > 10 && checked[1] > 10);
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
