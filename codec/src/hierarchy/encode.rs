//! The closed-loop coarse-to-fine encoder (paper §5, "coarse to fine compression").

use std::collections::{BTreeSet, HashMap};

use rayon::prelude::*;

use super::analysis::{LevelField, analysis_fields};
use super::object_error::surface_error;
use super::refine::{Refined, gather};
use super::roots::{encode_roots, root_grid};
use super::{CodecParams, Encoded, Record};
use crate::CodecError;
use crate::entropy::{Band, BandKind, CoderKind, encode_bands};
use crate::geometry::{DiamondId, Layout};
use crate::lifting::{Alpha, MAX_ABS_HEIGHT, clamp_prediction, predict_cells, predict_vertex};
use crate::quant::{HeightGrid, Quantizer};

/// Encoder settings besides the tolerance.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EncodeOptions {
    /// Diamond grid side `N` (`2^k + 1`).
    pub n: usize,
    /// Lifting weight of inner vertices.
    pub alpha: Alpha,
    /// Entropy coder.
    pub coder: CoderKind,
    /// Level pairs above the smallest hierarchy that covers the data with one root.
    pub extra_level_pairs: u32,
}

impl Default for EncodeOptions {
    fn default() -> Self {
        Self {
            n: 65,
            alpha: Alpha::One,
            coder: CoderKind::Adaptive,
            extra_level_pairs: 0,
        }
    }
}

/// The filtered height the encoder aims for at a lattice point of a level, `None` where it is
/// "don't care" (outside the data or at nodata).
struct Targets<'a> {
    grid: &'a HeightGrid,
    fields: Option<Vec<LevelField>>,
}

impl Targets<'_> {
    #[inline]
    fn at(&self, level: u8, x: i64, y: i64) -> Option<i32> {
        let v = self.grid.get(x, y)?;
        Some(match &self.fields {
            Some(f) => f[level as usize].get(x, y),
            None => v,
        })
    }
}

/// Encodes `grid` (integer heights) with residual quantizer `quantizer`.
///
/// Errors if the grid has no valid sample, or if the reconstruction would leave the integer
/// range (a tolerance far too fine for the heights; [`crate::quant::QuantPlan`] normally refuses
/// those first).
pub fn encode(
    grid: &HeightGrid,
    quantizer: Quantizer,
    opts: &EncodeOptions,
) -> Result<Encoded, CodecError> {
    encode_with_progress(grid, quantizer, opts, &|_, _| {})
}

/// [`encode`], calling `progress(done, total)` after each diamond (from worker threads). The
/// units are input samples covered: every level covers the data once and costs about the same,
/// while a coarse diamond costs as much as thousands of fine ones, so covered area gives a usable
/// ETA where a diamond count would not.
pub fn encode_with_progress(
    grid: &HeightGrid,
    quantizer: Quantizer,
    opts: &EncodeOptions,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Encoded, CodecError> {
    if grid.range().is_none() {
        return Err(CodecError::invalid("the input has no valid sample"));
    }
    let layout = Layout::covering(opts.n, grid.width, grid.height, opts.extra_level_pairs)?;
    let params = CodecParams {
        layout,
        alpha: opts.alpha,
        coder: opts.coder,
        quantizer,
        root_quantizer: super::root_quantizer(quantizer),
        data_width: u32::try_from(grid.width).map_err(|_| CodecError::limit("grid too wide"))?,
        data_height: u32::try_from(grid.height).map_err(|_| CodecError::limit("grid too tall"))?,
    };
    let targets = Targets {
        grid,
        fields: (opts.alpha == Alpha::Half).then(|| analysis_fields(&layout, grid)),
    };
    let stored = stored_sets(&layout, grid);
    let (root_field, roots) = encode_roots(&params, |x, y| targets.at(0, x, y))?;

    let finest = layout.finest_level();
    let n = layout.n();
    let mut records: Vec<Record> = Vec::new();
    let mut own_error: HashMap<DiamondId, u32> = HashMap::new();
    let mut prev: HashMap<DiamondId, Refined> = HashMap::new();
    // Work per diamond is about the data it covers: its bounding box clipped to the data.
    let area = |id: &DiamondId| {
        let (x0, y0, x1, y1) = layout.bounds(*id);
        let span =
            |a: i64, b: i64, len: usize| (b.min(len as i64 - 1) - a.max(0) + 1).max(1) as usize;
        span(x0, x1, grid.width) * span(y0, y1, grid.height)
    };
    let total: usize = stored.iter().flatten().map(area).sum();
    let done = std::sync::atomic::AtomicUsize::new(0);
    let tick = |id: &DiamondId| {
        let a = area(id);
        progress(
            done.fetch_add(a, std::sync::atomic::Ordering::Relaxed) + a,
            total,
        );
    };
    for level in 0..=finest {
        let grids_of = |id: DiamondId| -> Vec<i32> {
            let mut p = vec![0i32; n * n];
            if level == 0 {
                root_grid(&layout, &root_field, id, &mut p);
            } else {
                let parents = layout.parents(id).map(|pid| pid.map(|pid| &prev[&pid]));
                gather(&layout, id, parents, &mut p);
            }
            p
        };
        if level == finest {
            for (id, e) in stored[level as usize]
                .par_iter()
                .map(|&id| {
                    let e = surface_error(&layout, id, &grids_of(id), grid);
                    tick(&id);
                    (id, e)
                })
                .collect::<Vec<_>>()
            {
                own_error.insert(id, e);
            }
            break;
        }
        let results = stored[level as usize]
            .par_iter()
            .map(|&id| {
                let p = grids_of(id);
                let err = surface_error(&layout, id, &p, grid);
                let (refined, bytes) =
                    refine_encode(&params, id, &p, |x, y| targets.at(level + 1, x, y))?;
                let (min, max) = p
                    .iter()
                    .fold((i32::MAX, i32::MIN), |(lo, hi), &v| (lo.min(v), hi.max(v)));
                tick(&id);
                Ok((id, refined, bytes, err, min, max))
            })
            .collect::<Result<Vec<_>, CodecError>>()?;
        prev.clear();
        for (id, refined, bytes, err, min, max) in results {
            own_error.insert(id, err);
            prev.insert(id, refined);
            records.push(Record {
                id,
                bytes,
                object_error: 0,
                min,
                max,
            });
        }
    }

    // Saturate fine to coarse: a diamond's error bounds every descendant's, so the error a
    // renderer sees never increases when it refines.
    let mut saturated: HashMap<DiamondId, u32> = HashMap::new();
    for level in (0..=finest).rev() {
        for &id in &stored[level as usize] {
            let children = layout.children(id).into_iter().flatten();
            let e = children
                .filter_map(|c| saturated.get(&c))
                .fold(own_error[&id], |a, &b| a.max(b));
            saturated.insert(id, e);
        }
    }
    for r in &mut records {
        r.object_error = saturated[&r.id];
    }
    let leaf_error = stored[finest as usize]
        .iter()
        .map(|id| own_error[id])
        .max()
        .unwrap_or(0);
    records.sort_by_key(|r| r.id);
    Ok(Encoded {
        params,
        roots,
        records,
        leaf_error,
    })
}

/// One refinement on the encoder side: quantized residuals against the reconstruction
/// (eqs. 5–8), the refined reconstruction, and the coded record.
fn refine_encode(
    params: &CodecParams,
    id: DiamondId,
    p: &[i32],
    target: impl Fn(i64, i64) -> Option<i32>,
) -> Result<(Refined, Vec<u8>), CodecError> {
    let layout = &params.layout;
    let n = layout.n();
    let m = n - 1;
    let g = layout.grid(id);
    let q = params.quantizer;
    let step = i64::from(q.step());
    let overflow = || {
        CodecError::invalid(
            "reconstructed heights overflow the integer range; use a larger tolerance",
        )
    };
    let mut cells = vec![0i32; m * m];
    predict_cells(p, n, &mut cells);
    for c in &mut cells {
        *c = clamp_prediction(i64::from(*c)) as i32;
    }
    let mut dc = vec![0i32; m * m];
    for cj in 0..m {
        for ci in 0..m {
            let (x2, y2) = g.point2(2 * ci as i64 + 1, 2 * cj as i64 + 1);
            debug_assert!(
                x2 % 2 == 0 && y2 % 2 == 0,
                "cell centres of refinable levels are lattice points"
            );
            let k = cj * m + ci;
            if let Some(t) = target(x2 / 2, y2 / 2) {
                let pred = i64::from(cells[k]);
                let idx = q.index(i64::from(t) - pred);
                let v = pred + idx * step;
                if v.abs() > i64::from(MAX_ABS_HEIGHT) {
                    return Err(overflow());
                }
                dc[k] = idx as i32;
                cells[k] = v as i32;
            }
        }
    }
    let mut vertices = p.to_vec();
    let mut dv = Vec::new();
    if params.alpha == Alpha::Half {
        dv = vec![0i32; (n - 2) * (n - 2)];
        for j in 1..n - 1 {
            for i in 1..n - 1 {
                let (x, y) = g.point(i as i64, j as i64);
                // Eq. 8 with P̃: the decoder never has P, so it predicts 2P̃ − Pred_V(C̃).
                let pred = clamp_prediction(
                    2 * i64::from(p[j * n + i]) - i64::from(predict_vertex(&cells, n, i, j)),
                );
                let (idx, v) = match target(x, y) {
                    Some(t) => {
                        let idx = q.index(i64::from(t) - pred);
                        (idx, pred + idx * step)
                    }
                    None => (0, pred),
                };
                if v.abs() > i64::from(MAX_ABS_HEIGHT) {
                    return Err(overflow());
                }
                dv[(j - 1) * (n - 2) + (i - 1)] = idx as i32;
                vertices[j * n + i] = v as i32;
            }
        }
    }
    let mut bands = vec![Band {
        kind: BandKind::Cells,
        width: m,
        height: m,
        values: &dc,
    }];
    if params.alpha == Alpha::Half {
        bands.push(Band {
            kind: BandKind::Vertices,
            width: n - 2,
            height: n - 2,
            values: &dv,
        });
    }
    let mut bytes = Vec::new();
    encode_bands(params.coder, &bands, &mut bytes);
    Ok((Refined::from_parts(n, &vertices, &cells), bytes))
}

/// The stored diamonds of every level `0..=L`, sorted: the finest diamonds that meet a valid
/// sample, and all their ancestors (a child's grid comes half from each parent, and some
/// parents do not touch the data themselves).
pub(crate) fn stored_sets(layout: &Layout, grid: &HeightGrid) -> Vec<Vec<DiamondId>> {
    let (w, h) = (grid.width, grid.height);
    // Summed-area table of valid samples: any box query in O(1).
    let mut sat = vec![0u32; (w + 1) * (h + 1)];
    for y in 0..h {
        let mut row = 0u32;
        for x in 0..w {
            row += u32::from(grid.valid[y * w + x]);
            sat[(y + 1) * (w + 1) + x + 1] = sat[y * (w + 1) + x + 1] + row;
        }
    }
    let count = |x0: i64, y0: i64, x1: i64, y1: i64| -> u32 {
        let (x0, y0) = (x0.max(0) as usize, y0.max(0) as usize);
        let (x1, y1) = (
            (x1 + 1).min(w as i64) as usize,
            (y1 + 1).min(h as i64) as usize,
        );
        if x0 >= x1 || y0 >= y1 {
            return 0;
        }
        sat[y1 * (w + 1) + x1] + sat[y0 * (w + 1) + x0]
            - sat[y0 * (w + 1) + x1]
            - sat[y1 * (w + 1) + x0]
    };
    let finest = layout.finest_level();
    let r = layout.radius(finest);
    let (ex, ey) = layout.extent();
    let mut leaves = Vec::new();
    for cy in (r..ey.min(h as i64 - 1 + r + 1)).step_by(2 * r as usize) {
        for cx in (r..ex.min(w as i64 - 1 + r + 1)).step_by(2 * r as usize) {
            if count(cx - r, cy - r, cx + r, cy + r) > 0 {
                leaves.push(DiamondId::new(finest, cx as u32, cy as u32));
            }
        }
    }
    let mut sets = vec![Vec::new(); finest as usize + 1];
    sets[finest as usize] = leaves;
    for level in (0..finest as usize).rev() {
        let parents: BTreeSet<DiamondId> = sets[level + 1]
            .iter()
            .flat_map(|&d| layout.parents(d))
            .flatten()
            .collect();
        sets[level] = parents.into_iter().collect();
    }
    sets
}
