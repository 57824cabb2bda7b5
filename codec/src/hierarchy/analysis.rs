//! Fine-to-coarse analysis for α = ½ (paper eq. 1): the filtered height field of every level.
//!
//! With α = 1 the filtered field of every level is simply the input subsampled, and none of
//! this is needed. With α = ½ inner vertices are smoothed, `P = ⌊(32·V + 32·Pred_V(C) + 32)/64⌋`
//! with the exact (unrounded) prediction — one rounding, in the same unit as the input, so the
//! field stays on the input's value lattice; diamond sides are copied, never rounded.
//!
//! This is the in-core variant: each level's field covers the whole padded domain.

use rayon::prelude::*;

use crate::geometry::{DiamondId, Layout};
use crate::lifting::predict_vertex_numerator;
use crate::quant::HeightGrid;

/// One level's filtered heights on the lattice points of that level.
#[derive(Clone, Debug)]
pub struct LevelField {
    /// Lattice spacing of the stored grid (the level's points are a subset of it), a power of
    /// two, as its log.
    shift: u32,
    cols: usize,
    extent: (i64, i64),
    data: Vec<i32>,
}

impl LevelField {
    fn new(layout: &Layout, level: u8) -> Self {
        let (ex, ey) = layout.face_extent();
        let grid = layout.grid(DiamondId::new(level, 0, 0));
        // Even levels: axis steps (h, 0); odd levels: diagonal steps (d, ±d) — either way every
        // point of the level lies on the axis-aligned grid of spacing |u.0|.
        let g = grid.u.0;
        debug_assert!(g.count_ones() == 1, "lattice spacings are powers of two");
        let (cols, rows) = ((ex / g + 1) as usize, (ey / g + 1) as usize);
        Self {
            shift: g.trailing_zeros(),
            cols,
            extent: (ex, ey),
            data: vec![0; cols * rows],
        }
    }

    /// The filtered height at lattice point `(x, y)` of this level; points outside the domain are
    /// reflected across its edges (the symmetric extension of edge diamonds).
    #[inline]
    pub fn get(&self, x: i64, y: i64) -> i32 {
        let (x, y) = (reflect(x, self.extent.0), reflect(y, self.extent.1));
        self.data[self.index(x, y)]
    }

    /// [`get`](Self::get) for a point inside the domain (`0 ≤ x ≤ extent.0`, `0 ≤ y ≤ extent.1`),
    /// which needs no reflection: every sample of the data rectangle is one.
    #[inline]
    pub fn get_in_domain(&self, x: i64, y: i64) -> i32 {
        debug_assert!((0..=self.extent.0).contains(&x) && (0..=self.extent.1).contains(&y));
        self.data[self.index(x, y)]
    }

    /// Index of a point of the domain in `data`.
    #[inline]
    fn index(&self, x: i64, y: i64) -> usize {
        (y >> self.shift) as usize * self.cols + (x >> self.shift) as usize
    }
}

/// Reflects `x` into `[0, len]` (symmetric extension without repeating the edge sample).
#[inline]
fn reflect(x: i64, len: i64) -> i64 {
    if (0..=len).contains(&x) {
        return x;
    }
    if len == 0 {
        return 0;
    }
    let period = 2 * len;
    let x = x.rem_euclid(period);
    if x > len { period - x } else { x }
}

/// Filtered fields of levels `0..=L` for α = ½. Level `L` is the input, extended beyond the data
/// rectangle by reflection and filled at nodata by push-pull averaging; these filled values are
/// "don't care" for the bound but feed the smoothing of nearby valid vertices.
pub fn analysis_fields(layout: &Layout, grid: &HeightGrid) -> Vec<LevelField> {
    let finest = layout.finest_level();
    let filled = fill_nodata(grid);
    let mut fine = LevelField::new(layout, finest);
    let ey = layout.face_extent().1;
    let (w, h) = (grid.width as i64, grid.height as i64);
    let cols = fine.cols;
    fine.data
        .par_chunks_mut(cols)
        .enumerate()
        .for_each(|(y, row)| {
            let sy = reflect(y as i64, h - 1);
            for (x, o) in row.iter_mut().enumerate() {
                *o = filled[(sy * w + reflect(x as i64, w - 1)) as usize];
            }
        });
    debug_assert_eq!(fine.data.len(), cols * (ey as usize + 1));
    let mut fields = vec![fine];
    for level in (0..finest).rev() {
        let finer = fields.last().expect("at least the finest field");
        let mut field = LevelField::new(layout, level);
        // Diamonds of a level share only their sides, whose points every diamond copies from
        // the finer field: the values do not depend on the order diamonds are written in.
        for ids in all_diamonds_of_level(layout, level).chunks(DIAMONDS_AT_ONCE) {
            let parts: Vec<Vec<(usize, i32)>> = ids
                .par_iter()
                .map(|&id| filtered_points(layout, id, finer, &field))
                .collect();
            for (k, v) in parts.into_iter().flatten() {
                field.data[k] = v;
            }
        }
        fields.push(field);
    }
    fields.reverse();
    fields
}

/// Diamonds filtered between writes into the level's field: bounds the points held.
const DIAMONDS_AT_ONCE: usize = 256;

/// The filtered heights of diamond `id`'s points in the domain, as `(index in field, value)`,
/// from the next finer level's field.
fn filtered_points(
    layout: &Layout,
    id: DiamondId,
    finer: &LevelField,
    field: &LevelField,
) -> Vec<(usize, i32)> {
    let n = layout.n();
    let (ex, ey) = layout.face_extent();
    let g = layout.grid(id);
    // Each cell centre feeds up to 12 vertex predictions: fetch them once.
    let m = n - 1;
    let mut cells = Vec::with_capacity(m * m);
    for cj in 0..m {
        for ci in 0..m {
            let (x2, y2) = g.point2(2 * ci as i64 + 1, 2 * cj as i64 + 1);
            cells.push(i64::from(finer.get(x2 / 2, y2 / 2)));
        }
    }
    let mut out = Vec::with_capacity(n * n);
    for j in 0..n {
        for i in 0..n {
            let (x, y) = g.point(i as i64, j as i64);
            if x < 0 || y < 0 || x > ex || y > ey {
                continue;
            }
            let v = i64::from(finer.get_in_domain(x, y));
            let inner = (1..n - 1).contains(&i) && (1..n - 1).contains(&j);
            let p = if inner {
                let cell = |ci: usize, cj: usize| cells[cj * m + ci];
                let num = predict_vertex_numerator(cell, n, i, j);
                (32 * v + num + 32) >> 6
            } else {
                v
            };
            out.push((field.index(x, y), p as i32));
        }
    }
    out
}

/// Every diamond of a level, inside the domain or sticking out of it.
fn all_diamonds_of_level(layout: &Layout, level: u8) -> Vec<DiamondId> {
    let r = layout.radius(level);
    let (ex, ey) = layout.face_extent();
    let mut out = Vec::new();
    let mut push = |x: i64, y: i64| {
        let id = DiamondId::new(level, x as u32, y as u32);
        if layout.contains(id) {
            out.push(id);
        }
    };
    if level.is_multiple_of(2) {
        for y in (r..ey).step_by(2 * r as usize) {
            for x in (r..ex).step_by(2 * r as usize) {
                push(x, y);
            }
        }
    } else {
        for y in (0..=ey).step_by(r as usize) {
            for x in (0..=ex).step_by(r as usize) {
                push(x, y);
            }
        }
    }
    out
}

/// Input heights with nodata replaced by push-pull averages (the mean of the valid samples of
/// the smallest enclosing power-of-two block that has any). Deterministic and cheap; the values
/// only have to be plausible.
fn fill_nodata(grid: &HeightGrid) -> Vec<i32> {
    let (w, h) = (grid.width, grid.height);
    let mut out = grid.values.to_vec();
    if grid.valid.iter().all(|&v| v) {
        return out;
    }
    // Pyramid of (sum, count) by 2×2 blocks.
    // (width, height, per-block (sum, count)) from the full grid up to 1×1.
    type Level = (usize, usize, Vec<(i64, u64)>);
    let mut levels: Vec<Level> = vec![(
        w,
        h,
        grid.values
            .iter()
            .zip(&grid.valid)
            .map(|(&v, &ok)| if ok { (i64::from(v), 1) } else { (0, 0) })
            .collect(),
    )];
    while levels.last().is_some_and(|(lw, lh, _)| *lw > 1 || *lh > 1) {
        let (lw, lh, prev) = levels.last().expect("non-empty");
        let (nw, nh) = (lw.div_ceil(2), lh.div_ceil(2));
        let mut next = vec![(0i64, 0u64); nw * nh];
        for y in 0..*lh {
            for x in 0..*lw {
                let (s, c) = prev[y * lw + x];
                let t = &mut next[(y / 2) * nw + x / 2];
                t.0 += s;
                t.1 += c;
            }
        }
        levels.push((nw, nh, next));
    }
    for y in 0..h {
        for x in 0..w {
            if grid.valid[y * w + x] {
                continue;
            }
            out[y * w + x] = levels
                .iter()
                .enumerate()
                .skip(1)
                .find_map(|(l, (lw, _, data))| {
                    let (s, c) = data[(y >> l) * lw + (x >> l)];
                    (c > 0).then(|| s.div_euclid(c as i64) as i32)
                })
                .unwrap_or(0);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// The serial analysis that [`analysis_fields`] replaced, point by point with divisions:
    /// the reference.
    fn reference(layout: &Layout, grid: &HeightGrid) -> Vec<Vec<i32>> {
        let (ex, ey) = layout.face_extent();
        let at = |data: &[i32], g: i64, x: i64, y: i64| {
            let (x, y) = (reflect_slow(x, ex), reflect_slow(y, ey));
            data[(y / g) as usize * (ex / g + 1) as usize + (x / g) as usize]
        };
        let spacing = |level: u8| layout.grid(DiamondId::new(level, 0, 0)).u.0;
        let filled = fill_nodata(grid);
        let (w, h) = (grid.width as i64, grid.height as i64);
        let mut finer = Vec::new();
        for y in 0..=ey {
            for x in 0..=ex {
                finer.push(filled[(reflect_slow(y, h - 1) * w + reflect_slow(x, w - 1)) as usize]);
            }
        }
        let n = layout.n();
        let mut out = vec![finer];
        for level in (0..layout.finest_level()).rev() {
            let (gf, g) = (spacing(level + 1), spacing(level));
            let finer = out.last().unwrap();
            let mut field = vec![0; ((ex / g + 1) * (ey / g + 1)) as usize];
            for id in all_diamonds_of_level(layout, level) {
                let grid = layout.grid(id);
                for j in 0..n {
                    for i in 0..n {
                        let (x, y) = grid.point(i as i64, j as i64);
                        if x < 0 || y < 0 || x > ex || y > ey {
                            continue;
                        }
                        let v = i64::from(at(finer, gf, x, y));
                        let p = if (1..n - 1).contains(&i) && (1..n - 1).contains(&j) {
                            let cell = |ci: usize, cj: usize| {
                                let (x2, y2) = grid.point2(2 * ci as i64 + 1, 2 * cj as i64 + 1);
                                i64::from(at(finer, gf, x2 / 2, y2 / 2))
                            };
                            (32 * v + predict_vertex_numerator(cell, n, i, j) + 32) >> 6
                        } else {
                            v
                        };
                        field[(y / g) as usize * (ex / g + 1) as usize + (x / g) as usize] =
                            p as i32;
                    }
                }
            }
            out.push(field);
        }
        out.reverse();
        out
    }

    fn reflect_slow(x: i64, len: i64) -> i64 {
        if len == 0 {
            return 0;
        }
        let x = x.rem_euclid(2 * len);
        if x > len { 2 * len - x } else { x }
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 32, ..ProptestConfig::default() })]
        #[test]
        fn parallel_analysis_matches_the_serial_reference(
            n_pow in 1u32..5,
            w in 1usize..80,
            h in 1usize..80,
            extra in 0u32..2,
            holes in proptest::collection::vec(any::<u16>(), 0..20),
            seed in any::<u64>(),
        ) {
            let mut s = seed | 1;
            let values = (0..w * h)
                .map(|_| {
                    s ^= s << 13;
                    s ^= s >> 7;
                    s ^= s << 17;
                    (s % 2001) as i32 - 1000
                })
                .collect();
            let mut grid = HeightGrid::all_valid(w, h, values);
            for hole in holes {
                grid.valid[hole as usize % (w * h)] = false;
            }
            let layout = Layout::covering((1 << n_pow) + 1, w, h, extra).unwrap();
            let got: Vec<Vec<i32>> = analysis_fields(&layout, &grid).into_iter().map(|f| f.data).collect();
            prop_assert_eq!(got, reference(&layout, &grid));
        }
    }

    #[test]
    fn reflection_folds_back_without_repeating_the_edge() {
        for len in [0, 1, 5, 8] {
            for x in -40..40 {
                assert_eq!(reflect(x, len), reflect_slow(x, len), "{x} in [0, {len}]");
            }
        }
        assert_eq!(reflect(-1, 4), 1);
        assert_eq!(reflect(5, 4), 3);
        assert_eq!(reflect(9, 4), 1);
    }
}
