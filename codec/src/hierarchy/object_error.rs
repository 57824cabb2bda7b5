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
/// Visits each input sample under the diamond once; grid spacings are powers of two, so the
/// sample's cell and position in it come from shifts, and the surface is evaluated exactly in
/// integers scaled by the spacing.
pub(crate) fn surface_error(layout: &Layout, id: DiamondId, p: &[i32], input: &HeightGrid) -> u32 {
    // Long runs amortise their set-up from a spacing of 4 lattice units; below that a cell row
    // holds one to three samples and the per-sample scan is cheaper.
    let g = layout.grid(id);
    let sp = if id.is_even() { g.u.0 } else { 2 * g.u.0 };
    if sp >= 4 {
        return surface_error_runs(layout, id, p, input);
    }
    if sp == 1 {
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
    match layout.diagonal(id) {
        Diagonal::Main => surface_error_impl::<true>(layout, id, p, input),
        Diagonal::Anti => surface_error_impl::<false>(layout, id, p, input),
    }
}

/// [`surface_error`] for coarse levels: each grid cell row splits into two runs of samples, one per triangle, on which the surface is
/// linear: `surface·sp = c0 + c1·fs`. Runs are clipped to the data once, then scanned without
/// branches, so each input sample costs a few instructions per level.
fn surface_error_runs(layout: &Layout, id: DiamondId, p: &[i32], input: &HeightGrid) -> u32 {
    let n = layout.n();
    let diag = layout.diagonal(id);
    let g = layout.grid(id);
    let (w, h) = (input.width as i64, input.height as i64);
    // Grid coordinates scaled by the spacing `sp`: even levels use (x, y) − origin directly;
    // odd levels use s = Δx + Δy, t = Δx − Δy, where lattice points have s ≡ t (mod 2).
    let odd = !id.is_even();
    let sp = if odd { 2 * g.u.0 } else { g.u.0 };
    let (ox, oy) = g.origin;
    let mut worst_h = 0i64;
    let sp_n = sp * (n as i64 - 1);
    for cj in 0..n - 1 {
        let t0 = cj as i64 * sp;
        for ci in 0..n - 1 {
            let s0 = ci as i64 * sp;
            // Skip cells entirely outside the data (cheap bounding-box test).
            let (bx0, by0, bx1, by1) = if odd {
                let (sa, sb, ta, tb) = (s0, s0 + sp, t0, t0 + sp);
                (
                    ox + (sa + ta) / 2,
                    oy + (sa - tb) / 2,
                    ox + (sb + tb) / 2,
                    oy + (sb - ta) / 2,
                )
            } else {
                (ox + s0, oy + t0, ox + s0 + sp, oy + t0 + sp)
            };
            if bx1 < 0 || by1 < 0 || bx0 >= w || by0 >= h || s0 >= sp_n || t0 >= sp_n {
                continue;
            }
            let at = |i: usize, j: usize| i64::from(p[j * n + i]);
            let (v00, v10, v01, v11) = (
                at(ci, cj),
                at(ci + 1, cj),
                at(ci, cj + 1),
                at(ci + 1, cj + 1),
            );
            for ft in 0..=sp {
                // The row's two runs: [lo, hi] inclusive in fs, with surface·sp = c0 + c1·fs.
                let runs = match diag {
                    Diagonal::Main => [
                        (ft, sp, v00 * sp + (v11 - v10) * ft, v10 - v00),
                        (0, ft - 1, v00 * sp + (v01 - v00) * ft, v11 - v01),
                    ],
                    Diagonal::Anti => [
                        (0, sp - ft, v00 * sp + (v01 - v00) * ft, v10 - v00),
                        (
                            sp - ft + 1,
                            sp,
                            v01 * sp + (v10 - v11) * (sp - ft),
                            v11 - v01,
                        ),
                    ],
                };
                let t = t0 + ft;
                for (lo, hi, c0, c1) in runs {
                    worst_h = worst_h.max(scan_run(
                        input,
                        odd,
                        (ox, oy),
                        s0,
                        t,
                        lo,
                        hi,
                        c0,
                        c1,
                        sp,
                        (w, h),
                    ));
                }
            }
        }
    }
    let e = (worst_h + sp - 1) / sp;
    u32::try_from(e).unwrap_or(u32::MAX)
}

/// Largest `|c0 + c1·fs − input·sp|` over the lattice samples of one run of a cell row
/// (`fs ∈ [lo, hi]`, grid row `t`), clipped to the data rectangle.
#[allow(clippy::too_many_arguments)]
#[inline]
fn scan_run(
    input: &HeightGrid,
    odd: bool,
    (ox, oy): (i64, i64),
    s0: i64,
    t: i64,
    mut lo: i64,
    mut hi: i64,
    c0: i64,
    c1: i64,
    sp: i64,
    (w, h): (i64, i64),
) -> i64 {
    let (kstep, fstep, k0);
    if odd {
        // x = ox + (s0 + fs + t)/2, y = oy + (s0 + fs − t)/2 need s0 + fs ≡ t (mod 2); clip
        // 0 ≤ x < w and 0 ≤ y < h, i.e. fs within four half-planes.
        if (s0 + lo + t).rem_euclid(2) != 0 {
            lo += 1;
        }
        let fs_lo = (-2 * ox - s0 - t).max(-2 * oy - s0 + t);
        let fs_hi = (2 * (w - 1 - ox) - s0 - t).min(2 * (h - 1 - oy) - s0 + t);
        if lo < fs_lo {
            lo += (fs_lo - lo + 1) & !1;
        }
        hi = hi.min(fs_hi);
        if lo > hi {
            return 0;
        }
        let (x, y) = (ox + (s0 + lo + t) / 2, oy + (s0 + lo - t) / 2);
        k0 = (y * w + x) as usize;
        kstep = input.width + 1;
        fstep = 2;
    } else {
        let y = oy + t;
        if y < 0 || y >= h {
            return 0;
        }
        lo = lo.max(-ox - s0);
        hi = hi.min(w - 1 - ox - s0);
        if lo > hi {
            return 0;
        }
        k0 = (y * w + ox + s0 + lo) as usize;
        kstep = 1;
        fstep = 1;
    }
    let count = ((hi - lo) / fstep + 1) as usize;
    let mut worst = 0i64;
    let mut surf = c0 + c1 * lo;
    let dsurf = c1 * fstep;
    let mut k = k0;
    for _ in 0..count {
        let e = (surf - i64::from(input.values[k]) * sp).abs();
        // Branch-free: invalid samples contribute 0.
        worst = worst.max(e * i64::from(input.valid[k]));
        surf += dsurf;
        k += kstep;
    }
    worst
}

fn surface_error_impl<const MAIN: bool>(
    layout: &Layout,
    id: DiamondId,
    p: &[i32],
    input: &HeightGrid,
) -> u32 {
    let n = layout.n();
    let g = layout.grid(id);
    let (w, h) = (input.width as i64, input.height as i64);
    // Grid coordinates scaled by the spacing `sp`: even levels use (x, y) − origin directly;
    // odd levels use s = Δx + Δy, t = Δx − Δy.
    let odd = !id.is_even();
    let sp = if odd { 2 * g.u.0 } else { g.u.0 };
    debug_assert!(sp.count_ones() == 1, "grid spacings are powers of two");
    let shift = sp.trailing_zeros();
    let last = n as i64 - 2;
    let (ox, oy) = g.origin;
    let r = layout.radius(id.level);
    let (cx, cy) = (i64::from(id.x), i64::from(id.y));
    let surface_sp = |s: i64, t: i64| -> i64 {
        let ci = (s >> shift).min(last);
        let cj = (t >> shift).min(last);
        let (fx, fy) = (s - (ci << shift), t - (cj << shift));
        let k = cj as usize * n + ci as usize;
        let (v00, v10, v01, v11) = (
            i64::from(p[k]),
            i64::from(p[k + 1]),
            i64::from(p[k + n]),
            i64::from(p[k + n + 1]),
        );
        if MAIN {
            if fx >= fy {
                v00 * sp + (v10 - v00) * fx + (v11 - v10) * fy
            } else {
                v00 * sp + (v11 - v01) * fx + (v01 - v00) * fy
            }
        } else if fx + fy <= sp {
            v00 * sp + (v10 - v00) * fx + (v01 - v00) * fy
        } else {
            v11 * sp + (v01 - v11) * (sp - fx) + (v10 - v11) * (sp - fy)
        }
    };
    let mut worst_h = 0i64;
    for y in (cy - r).max(0)..=(cy + r).min(h - 1) {
        // Even levels cover the whole square; odd levels the rotated one, |Δx| + |Δy| ≤ r.
        let half = if odd { r - (y - cy).abs() } else { r };
        let (x0, x1) = ((cx - half).max(0), (cx + half).min(w - 1));
        let row = y as usize * input.width;
        for x in x0..=x1 {
            let (s, t) = if odd {
                ((x - ox) + (y - oy), (x - ox) - (y - oy))
            } else {
                (x - ox, y - oy)
            };
            let k = row + x as usize;
            let e = (surface_sp(s, t) - i64::from(input.values[k]) * sp).abs();
            // Branch-free: nodata contributes 0.
            worst_h = worst_h.max(e * i64::from(input.valid[k]));
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

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig { cases: 40, ..Default::default() })]
        #[test]
        fn incremental_evaluation_matches_brute_force_on_every_level(
            n_pow in 1u32..4,
            k in 0u32..3,
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
                proptest::prop_assert_eq!(
                    surface_error(&layout, d, &p, &input),
                    brute_force(&layout, d, &p, &input),
                    "{}", d
                );
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
