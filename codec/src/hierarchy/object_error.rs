//! Object-space error of a diamond: how far its drawn surface is from the input samples under it.
//!
//! The surface of a diamond is the piecewise-linear interpolant of its reconstructed grid, cells
//! split parallel to the split diagonal exactly as they are drawn. Grid spacings are powers of
//! two in lattice units, so the interpolant at an input sample is a rational with that
//! denominator: it is evaluated exactly in integers, and the maximum rounded up.

use crate::geometry::{Diagonal, DiamondId, Layout};
use crate::quant::HeightGrid;

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

/// The largest distance, in units rounded up, between the surface of diamond `id` with grid `p`
/// and the valid input samples under it (0 if there are none).
pub(crate) fn surface_error(layout: &Layout, id: DiamondId, p: &[i32], input: &HeightGrid) -> u32 {
    let n = layout.n();
    let diag = layout.diagonal(id);
    let g = layout.grid(id);
    let (w, h) = (input.width as i64, input.height as i64);
    let mut worst_h = 0i64;
    let r = layout.radius(id.level);
    let (cx, cy) = (i64::from(id.x), i64::from(id.y));
    let spacing;
    if id.is_even() {
        spacing = g.u.0;
        let (x0, y0) = g.origin;
        for y in y0.max(0)..=(y0 + 2 * r).min(h - 1) {
            for x in x0.max(0)..=(x0 + 2 * r).min(w - 1) {
                if let Some(v) = input.get(x, y) {
                    let s = interpolate_h(p, n, diag, spacing, x - x0, y - y0);
                    worst_h = worst_h.max((s - i64::from(v) * spacing).abs());
                }
            }
        }
    } else {
        // Rotated grid: with o the left corner, s = Δx + Δy and t = Δx − Δy are the grid
        // coordinates times 2d.
        spacing = 2 * g.u.0;
        let (ox, oy) = g.origin;
        for y in (cy - r).max(0)..=(cy + r).min(h - 1) {
            let half = r - (y - cy).abs();
            for x in (cx - half).max(0)..=(cx + half).min(w - 1) {
                if let Some(v) = input.get(x, y) {
                    let (s, t) = ((x - ox) + (y - oy), (x - ox) - (y - oy));
                    let sh = interpolate_h(p, n, diag, spacing, s, t);
                    worst_h = worst_h.max((sh - i64::from(v) * spacing).abs());
                }
            }
        }
    }
    let e = (worst_h + spacing - 1) / spacing;
    u32::try_from(e).unwrap_or(u32::MAX)
}

#[cfg(test)]
mod tests {
    use super::*;

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
        assert_eq!(interpolate_h(&p, n, Diagonal::Main, 4, 2, 2), (0 + 16) * 2);
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
