//! Tests of the object error against a brute-force evaluation of the interpolant.

use super::{
    ErrorInput, finest_error_fast, finest_error_lanes, grid_abs, surface_error,
    surface_error_lanes, surface_error_scan,
};
use crate::geometry::{Diagonal, DiamondId, Layout};
use crate::quant::HeightGrid;

std::thread_local! {
    /// Set while a test checks the portable kernels on a CPU that has faster ones.
    static PORTABLE: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

pub(super) fn portable_only() -> bool {
    PORTABLE.get()
}

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
        let (ex, ey) = layout.face_extent();
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
            proptest::prop_assert_eq!(surface_error(&layout, d, &p, &ErrorInput::new(&input)), want, "{}", d);
            // Clipped to a rectangle (possibly empty or beyond the grid): the samples
            // outside it are as if nodata.
            let mut corner = |len: usize| rnd(len as i64 + 1);
            let (xa, xb, ya, yb) = (corner(w), corner(w), corner(h), corner(h));
            let rect = (xa.min(xb), ya.min(yb), xa.max(xb) + rnd(1), ya.max(yb));
            let mut masked = input.clone();
            for y in 0..h {
                for x in 0..w {
                    let (xi, yi) = (x as i64, y as i64);
                    if xi < rect.0 || xi > rect.2 || yi < rect.1 || yi > rect.3 {
                        masked.valid[y * w + x] = false;
                    }
                }
            }
            let want_clipped = brute_force(&layout, d, &p, &masked);
            let clipped = ErrorInput::new(&input).clipped(rect);
            proptest::prop_assert_eq!(surface_error(&layout, d, &p, &clipped), want_clipped, "{} clipped to {:?}", d, rect);
            proptest::prop_assert_eq!(surface_error_scan(&layout, d, &p, grid_abs(&p), &clipped, true), want_clipped, "{} clipped to {:?}, parallel", d, rect);
            if d.level == layout.finest_level() && d.is_even() {
                // The shortcut's other lanes and its portable kernel.
                let origin = layout.grid(d).origin;
                let wide = finest_error_lanes::<i64>(n, origin, &p, &ErrorInput::new(&input));
                PORTABLE.set(true);
                let portable = finest_error_fast(n, origin, &p, grid_abs(&p), &ErrorInput::new(&input));
                PORTABLE.set(false);
                proptest::prop_assert_eq!((wide, portable), (want, want), "{} finest", d);
            }
            if d.level < layout.finest_level() || !d.is_even() {
                for parallel in [false, true] {
                    proptest::prop_assert_eq!(surface_error_scan(&layout, d, &p, grid_abs(&p), &ErrorInput::new(&input), parallel), want, "{} {}", d, parallel);
                    // The same in 64-bit lanes, which the small heights here never pick.
                    proptest::prop_assert_eq!(surface_error_lanes(&layout, d, &p, &ErrorInput::new(&input), parallel, false), want, "{} {} wide", d, parallel);
                }
                // The portable kernels, which a CPU with AVX2 never runs otherwise (one
                // thread: the switch is per thread).
                PORTABLE.set(true);
                let got = [true, false].map(|narrow| surface_error_lanes(&layout, d, &p, &ErrorInput::new(&input), false, narrow));
                PORTABLE.set(false);
                proptest::prop_assert_eq!(got, [want; 2], "{} portable", d);
            }
        }
    }
}

#[test]
fn extreme_heights_on_coarse_grids_take_wide_lanes_and_stay_exact() {
    // Spacing 2^7 at the root: 44·10⁶ · 2^7 does not fit 32 bits.
    let layout = Layout::new(5, 5, 1, 1).unwrap();
    let (ex, ey) = layout.face_extent();
    let (w, h) = (ex as usize + 1, ey as usize + 1 - 3);
    let big = crate::lifting::MAX_ABS_HEIGHT;
    let values = (0..w * h)
        .map(|k| {
            if (k * 7919) % 5 < 2 {
                big
            } else {
                -big + (k % 13) as i32
            }
        })
        .collect();
    let input = HeightGrid::all_valid(w, h, values);
    let n = layout.n();
    let mut frontier: Vec<DiamondId> = layout.roots().collect();
    let mut seen = std::collections::HashSet::new();
    while let Some(d) = frontier.pop() {
        if !seen.insert(d) || d.level > 3 {
            continue;
        }
        frontier.extend(layout.children(d).into_iter().flatten());
        let p: Vec<i32> = (0..n * n)
            .map(|k| if k % 3 == 0 { -big } else { big - k as i32 })
            .collect();
        let want = brute_force(&layout, d, &p, &input);
        assert!(want > 1 << 25, "{d}: the errors are large");
        assert_eq!(
            surface_error(&layout, d, &p, &ErrorInput::new(&input)),
            want,
            "{d}"
        );
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
    assert_eq!(
        surface_error(&layout, root, &p, &ErrorInput::new(&input)),
        0
    );
    input.values[4 * 9 + 3] += 7; // a sample between grid vertices
    assert_eq!(
        surface_error(&layout, root, &p, &ErrorInput::new(&input)),
        7
    );
    input.valid[4 * 9 + 3] = false; // nodata does not count
    assert_eq!(
        surface_error(&layout, root, &p, &ErrorInput::new(&input)),
        0
    );
}
