//! One refinement on the encoder side: a diamond's residuals quantized against the
//! reconstruction the decoder will have (paper eqs. 5–8), the refined reconstruction, and the
//! coded record.

use crate::CodecError;
use crate::entropy::{Band, BandKind, ParentGrid, encode_bands_on_grid};
use crate::geometry::{DiamondId, GridMap};
use crate::hierarchy::CodecParams;
use crate::hierarchy::mask::encode_mask;
use crate::lifting::{
    Alpha, MAX_ABS_HEIGHT, clamp_prediction, predict_cells, predict_inner_vertices,
};
use crate::quant::Quantizer;

/// What one refinement on the encoder side produces.
pub(in crate::hierarchy) struct Refinement {
    /// Reconstructed cell centres, `(N−1)²`.
    pub(in crate::hierarchy) cells: Vec<i32>,
    /// Reconstructed vertices, `N²`, when α = ½ changed them (`None`: the input grid).
    pub(in crate::hierarchy) vertices: Option<Vec<i32>>,
    /// The coded record.
    pub(in crate::hierarchy) bytes: Vec<u8>,
}

/// One refinement on the encoder side (`target` and `mask` in `id`'s face frame, `mask` saying
/// `Some(valid)` where the nodata mask cares): quantized residuals against the reconstruction
/// (eqs. 5–8), the refined reconstruction, and the coded record.
pub(in crate::hierarchy) fn refine_encode(
    params: &CodecParams,
    id: DiamondId,
    p: &[i32],
    target: impl Fn(i64, i64) -> Option<i32>,
    mask: impl Fn(i64, i64) -> Option<bool>,
) -> Result<Refinement, CodecError> {
    let g = params.layout().grid(id);
    let q = params.quantizer_at(id.level);
    let (cells, dc) = quantize_cells(params, q, &g, p, &target)?;
    let (vertices, dv) = if params.alpha == Alpha::Half {
        let (vertices, dv) = quantize_inner_vertices(params, q, &g, p, &cells, &target)?;
        (Some(vertices), dv)
    } else {
        (None, Vec::new())
    };
    let bytes = code_record(params, q, &g, p, &dc, &dv, &mask);
    Ok(Refinement {
        cells,
        vertices,
        bytes,
    })
}

fn overflow() -> CodecError {
    CodecError::invalid("reconstructed heights overflow the integer range; use a larger tolerance")
}

/// The cell centres predicted from the vertices `p`, then, where `target` has a height, its
/// residual quantized (eqs. 5–6): the reconstructed cells and the quantization indices.
#[inline]
fn quantize_cells(
    params: &CodecParams,
    q: Quantizer,
    g: &GridMap,
    p: &[i32],
    target: &impl Fn(i64, i64) -> Option<i32>,
) -> Result<(Vec<i32>, Vec<i32>), CodecError> {
    let n = params.layout().n();
    let m = n - 1;
    let step = i64::from(q.step());
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
    Ok((cells, dc))
}

/// α = ½: the inner vertices updated from the reconstructed `cells` (eq. 8), their residuals
/// quantized where `target` has a height: the vertices and the quantization indices.
#[inline]
fn quantize_inner_vertices(
    params: &CodecParams,
    q: Quantizer,
    g: &GridMap,
    p: &[i32],
    cells: &[i32],
    target: &impl Fn(i64, i64) -> Option<i32>,
) -> Result<(Vec<i32>, Vec<i32>), CodecError> {
    let n = params.layout().n();
    let step = i64::from(q.step());
    let mut vertices = p.to_vec();
    let k = n - 2;
    let mut dv = vec![0i32; k * k];
    // The decoder's batch prediction (`refine`), so both sides compute it the same way.
    let mut vpred = vec![0i32; k * k];
    predict_inner_vertices(cells, n, &mut vpred);
    for j in 1..n - 1 {
        for i in 1..n - 1 {
            let (x, y) = g.point(i as i64, j as i64);
            // Eq. 8 with P̃: the decoder never has P, so it predicts 2P̃ − Pred_V(C̃).
            let pred = clamp_prediction(
                2 * i64::from(p[j * n + i]) - i64::from(vpred[(j - 1) * k + (i - 1)]),
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
            dv[(j - 1) * k + (i - 1)] = idx as i32;
            vertices[j * n + i] = v as i32;
        }
    }
    Ok((vertices, dv))
}

/// The record: the nodata mask where the repository has one, then the bands of cell (and, at
/// α = ½, vertex) indices, coded on the diamond's grid `p`; empty when all is valid and every
/// index is zero.
#[inline]
fn code_record(
    params: &CodecParams,
    q: Quantizer,
    g: &GridMap,
    p: &[i32],
    dc: &[i32],
    dv: &[i32],
    mask: &impl Fn(i64, i64) -> Option<bool>,
) -> Vec<u8> {
    let n = params.layout().n();
    let m = n - 1;
    let mut bands = vec![Band {
        kind: BandKind::Cells,
        width: m,
        height: m,
        values: dc,
    }];
    if params.alpha == Alpha::Half {
        bands.push(Band {
            kind: BandKind::Vertices,
            width: n - 2,
            height: n - 2,
            values: dv,
        });
    }
    let grid = Some(ParentGrid {
        values: p,
        n,
        step: q.step(),
    });
    let mut bytes = Vec::new();
    if !params.nodata_mask {
        encode_bands_on_grid(params.coder, &bands, grid, &mut bytes);
        return bytes;
    }
    // The validity of the level-`l+1` points of the square (equal-parity half-step points)
    // where `mask` cares (in the data rectangle); the rest is don't care.
    let all_valid = std::cell::Cell::new(true);
    let cared = |a: usize, b: usize| -> Option<bool> {
        if a % 2 != b % 2 {
            return None;
        }
        let (x2, y2) = g.point2(a as i64, b as i64);
        let (x, y) = (x2 / 2, y2 / 2);
        let v = mask(x, y);
        if v == Some(false) {
            all_valid.set(false);
        }
        v
    };
    encode_mask(2 * n - 1, 2 * n - 1, &cared, &mut bytes);
    let mask_len = bytes.len();
    encode_bands_on_grid(params.coder, &bands, grid, &mut bytes);
    // An empty record means "all valid, all residuals zero", as without a mask.
    if all_valid.get() && bytes.len() == mask_len {
        bytes.clear();
    }
    bytes
}
