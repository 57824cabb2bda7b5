//! A diamond's surface walked row by row in its scaled grid coordinates `(s, t)`: filled
//! exactly along the first row, then moved to each next row by adding a step per column, of
//! which only one per cell changes from row to row (where the cell's split diagonal crosses).
//! The object-error scan ([`super::scan`]) compares each row with the input.
//!
//! Every method is `#[inline(always)]`: the scan is compiled a second time for AVX2
//! (`Scan::rows_avx2`), and its loops must be inlined into that body to be vectorised for it.

use super::lanes::Lane;

/// The surface over columns `ulo..=uhi` of the current row of a diamond's grid `p` (N × N, of
/// spacing `sp = 2^shift` in `(s, t)` units), its cells split along the main diagonal (`MAIN`)
/// or the anti-diagonal.
pub(super) struct SurfaceWalk<'p, const MAIN: bool, T: Lane> {
    p: &'p [i32],
    n: usize,
    sp: i64,
    shift: u32,
    /// The columns kept.
    ulo: i64,
    uhi: i64,
    /// The cells those columns meet.
    cl: i64,
    ch: i64,
    /// The surface along the current row, column `ulo` first.
    surface: Vec<T>,
    /// What moving to the next row adds at each column.
    step: Vec<T>,
    /// The climb of each vertex column across the current row of cells.
    edge: Vec<T>,
}

impl<'p, const MAIN: bool, T: Lane> SurfaceWalk<'p, MAIN, T> {
    /// The walk at row `ta` over columns `ulo..=uhi`, ready to move on when `ta < tb` (the
    /// last row).
    #[inline(always)]
    pub(super) fn new(
        p: &'p [i32],
        n: usize,
        (sp, shift): (i64, u32),
        (ulo, uhi): (i64, i64),
        (ta, tb): (i64, i64),
    ) -> Self {
        let last = n as i64 - 2;
        let len = (uhi - ulo + 1) as usize;
        let mut walk = Self {
            p,
            n,
            sp,
            shift,
            ulo,
            uhi,
            cl: (ulo >> shift).min(last),
            ch: (uhi >> shift).min(last),
            surface: vec![T::default(); len],
            step: vec![T::default(); len],
            edge: vec![T::default(); n],
        };
        walk.fill_surface(ta);
        if ta < tb {
            walk.fill_edges(ta);
            walk.fill_steps(ta);
        }
        walk
    }

    /// The surface along the current row, column `ulo` first.
    #[inline(always)]
    pub(super) fn surface(&self) -> &[T] {
        &self.surface
    }

    /// The cells of row `t`: (index of cell (0, cj) in `p`, offset ft of t in its row of cells).
    #[inline(always)]
    fn cell_row(&self, t: i64) -> (usize, i64) {
        let last = self.n as i64 - 2;
        let cj = (t >> self.shift).min(last);
        (cj as usize * self.n, t - (cj << self.shift))
    }

    /// The exact surface along row `t`: two linear pieces `c0 + c1·fs` per cell.
    #[inline(always)]
    fn fill_surface(&mut self, t: i64) {
        let (row, ft) = self.cell_row(t);
        let (p, n, sp, shift) = (self.p, self.n, self.sp, self.shift);
        let (ulo, uhi) = (self.ulo, self.uhi);
        let at = |k: usize| T::of(i64::from(p[k]));
        let (spl, ftl) = (T::of(sp), T::of(ft));
        for ci in self.cl..=self.ch {
            let s0 = ci << shift;
            let from = (ulo - s0).max(0);
            let to = (uhi - s0).min(sp);
            if from > to {
                continue;
            }
            let slots = &mut self.surface[(s0 + from - ulo) as usize..=(s0 + to - ulo) as usize];
            let k = row + ci as usize;
            let (v00, v10, v01, v11) = (at(k), at(k + 1), at(k + n), at(k + n + 1));
            // fs in [0, split] lies on the first piece, the rest on the second.
            let (split, first, second) = if MAIN {
                (
                    ft - 1,
                    (v00.mul(spl).add(v01.sub(v00).mul(ftl)), v11.sub(v01)),
                    (v00.mul(spl).add(v11.sub(v10).mul(ftl)), v10.sub(v00)),
                )
            } else {
                (
                    sp - ft,
                    (v00.mul(spl).add(v01.sub(v00).mul(ftl)), v10.sub(v00)),
                    (
                        v01.mul(spl).add(v10.sub(v11).mul(T::of(sp - ft))),
                        v11.sub(v01),
                    ),
                )
            };
            for (fs, slot) in (from..).zip(slots.iter_mut()) {
                let (c0, c1) = if fs <= split { first } else { second };
                *slot = c0.add(c1.mul(T::of(fs)));
            }
        }
    }

    /// `edge[i]`: the climb of vertex column i across the row of cells of row `t`.
    #[inline(always)]
    fn fill_edges(&mut self, t: i64) {
        let (row, _) = self.cell_row(t);
        let n = self.n;
        let (lower, upper) = (&self.p[row..row + n], &self.p[row + n..row + 2 * n]);
        for ((e, &a), &b) in self.edge.iter_mut().zip(lower).zip(upper) {
            *e = T::of(i64::from(b)).sub(T::of(i64::from(a)));
        }
    }

    /// Steps from row t (offset ft in its row of cells) to t + 1. Main diagonal: the upper
    /// triangle (fs ≤ ft) climbs like the cell's left edge, the lower one like its right
    /// edge. Anti-diagonal: the lower-left one (fs < sp − ft) like the left edge, the
    /// upper-right one like the right edge.
    #[inline(always)]
    fn fill_steps(&mut self, t: i64) {
        let (_, ft) = self.cell_row(t);
        let (sp, shift) = (self.sp, self.shift);
        let split = if MAIN { ft } else { sp - ft - 1 };
        for (s, slot) in (self.ulo..).zip(self.step.iter_mut()) {
            let right = usize::from((s & (sp - 1)) > split);
            *slot = self.edge[(s >> shift) as usize + right];
        }
    }

    /// Moves the surface from row `t − 1` to row `t`, and readies the steps out of `t` (there
    /// are none out of the last row, `tb`).
    #[inline(always)]
    pub(super) fn advance(&mut self, t: i64, tb: i64) {
        for (s, &d) in self.surface.iter_mut().zip(&self.step) {
            *s = s.add(d);
        }
        if t == tb {
            // No step out of the last row.
        } else if t & (self.sp - 1) == 0 {
            self.fill_edges(t);
            self.fill_steps(t);
        } else {
            // One entry per cell changes triangle: fs = ft to the left edge (main), or
            // fs = sp − ft to the right edge (anti).
            let (_, ft) = self.cell_row(t);
            let fs = if MAIN { ft } else { self.sp - ft };
            for ci in self.cl..=self.ch {
                let s = (ci << self.shift) + fs;
                if (self.ulo..=self.uhi).contains(&s) {
                    self.step[(s - self.ulo) as usize] =
                        self.edge[ci as usize + usize::from(!MAIN)];
                }
            }
        }
    }
}
