//! A refinement's new values from its grid and its decoded residuals (paper eqs. 6 and 8): the
//! cells predicted from the grid and corrected, and with α = ½ the inner vertices updated from
//! them, each checked to stay in the representable range.

use crate::CodecError;
use crate::lifting::{
    MAX_ABS_HEIGHT, PREDICTION_LIMIT, VectorKernels, clamp_prediction, predict_cells_then,
    predict_inner_vertices,
};

fn out_of_range() -> CodecError {
    CodecError::corrupt("record reconstructs heights out of range")
}

/// The new cells: each predicted from the grid `p` (N × N) and corrected by its residual in
/// `dc`, times the quantizer's `step`. Checked before vertices are predicted from them:
/// out-of-range cells would overflow the filter's i32 numerators.
pub(super) fn reconstruct_cells(
    p: &[i32],
    n: usize,
    dc: &[i32],
    step: i64,
    cells: &mut Vec<i32>,
) -> Result<(), CodecError> {
    reconstruct_cells_with(VectorKernels::detected(), p, n, dc, step, cells)
}

/// [`reconstruct_cells`] with the loops compiled as `kernels` says: the same cells and the same
/// refusals whichever kind runs.
pub(super) fn reconstruct_cells_with(
    kernels: VectorKernels,
    p: &[i32],
    n: usize,
    dc: &[i32],
    step: i64,
    cells: &mut Vec<i32>,
) -> Result<(), CodecError> {
    let m = n - 1;
    cells.resize(m * m, 0);
    let dc = &dc[..cells.len()];
    // A clamped prediction is at most PREDICTION_LIMIT, far below MAX_ABS_HEIGHT: a residual
    // whose step × value is over i32::MAX − PREDICTION_LIMIT makes its cell out of range
    // whatever the prediction. Below that every sum fits i32, so the loop is in i32 (it
    // vectorises) and gives the values of an i64 computation exactly.
    let room = u64::from(i32::MAX.unsigned_abs() - PREDICTION_LIMIT.unsigned_abs());
    let in_range = match kernels {
        VectorKernels::Portable => cells_from_residuals(p, n, dc, step, room, cells),
        // SAFETY: `Avx2` is only ever made where the CPU has AVX2 (`VectorKernels::detected`).
        #[cfg(target_arch = "x86_64")]
        VectorKernels::Avx2 => unsafe { cells_from_residuals_avx2(p, n, dc, step, room, cells) },
    };
    if !in_range {
        return Err(out_of_range());
    }
    Ok(())
}

/// [`cells_from_residuals`] compiled for AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn cells_from_residuals_avx2(
    p: &[i32],
    n: usize,
    dc: &[i32],
    step: i64,
    room: u64,
    cells: &mut [i32],
) -> bool {
    cells_from_residuals(p, n, dc, step, room, cells)
}

/// The loops of [`reconstruct_cells_with`]: `cells` = the clamped prediction + `step × dc`;
/// false (cells unspecified) when a residual exceeds `room` or a cell `MAX_ABS_HEIGHT`.
/// One pass predicts and finishes each cell; a record without residuals only clamps, and the
/// cells are checked against `MAX_ABS_HEIGHT` only when the largest residual could reach it.
#[inline(always)]
fn cells_from_residuals(
    p: &[i32],
    n: usize,
    dc: &[i32],
    step: i64,
    room: u64,
    cells: &mut [i32],
) -> bool {
    let largest = dc.iter().fold(0u32, |a, &d| a.max(d.unsigned_abs()));
    let reach = u64::from(largest) * step.unsigned_abs();
    if reach > room {
        return false;
    }
    let clamp = |c: i32| c.clamp(-PREDICTION_LIMIT, PREDICTION_LIMIT);
    if largest == 0 {
        // |clamped prediction| ≤ PREDICTION_LIMIT < MAX_ABS_HEIGHT: nothing to check.
        predict_cells_then(p, n, cells, dc, |c, _| clamp(c));
        return true;
    }
    let step = step as i32;
    predict_cells_then(p, n, cells, dc, |c, d| clamp(c) + step * d);
    // Every cell is within PREDICTION_LIMIT + reach of zero.
    if reach + PREDICTION_LIMIT.unsigned_abs() as u64 <= MAX_ABS_HEIGHT.unsigned_abs() as u64 {
        return true;
    }
    !cells.iter().any(|v| v.abs() > MAX_ABS_HEIGHT)
}

/// α = ½: `vertices` becomes `p` with each inner vertex updated from the new `cells` and
/// corrected by its residual in `dv`.
pub(super) fn reconstruct_vertices(
    p: &[i32],
    n: usize,
    cells: &[i32],
    dv: &[i32],
    step: i64,
    vpred: &mut Vec<i32>,
    vertices: &mut Vec<i32>,
) -> Result<(), CodecError> {
    vertices.clear();
    vertices.extend_from_slice(p);
    let k = n - 2;
    vpred.resize(k * k, 0);
    predict_inner_vertices(cells, n, vpred);
    let mut bad = false;
    for j in 1..n - 1 {
        let row = &mut vertices[j * n + 1..][..k];
        let pred = &vpred[(j - 1) * k..][..k];
        let d = &dv[(j - 1) * k..][..k];
        for ((o, &q), &d) in row.iter_mut().zip(pred).zip(d) {
            let v = clamp_prediction(2 * i64::from(*o) - i64::from(q)) + step * i64::from(d);
            bad |= v.abs() > i64::from(MAX_ABS_HEIGHT);
            *o = v as i32;
        }
    }
    if bad {
        return Err(out_of_range());
    }
    Ok(())
}
