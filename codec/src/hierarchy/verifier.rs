//! The exact L∞ verifier: every reconstructed vertex of every level against the input (or its
//! filtered levels), in one decode of the whole hierarchy that can also hand back the finest
//! level as stored, for the comparison with the input in metres (`cbdam verify`).

use rayon::prelude::*;

use super::Encoded;
use super::analysis::analysis_fields;
use super::decode::{
    FinestRaster, LevelReport, Reached, ReachedRaster, VerifyReport, planar_only, walk_batches_impl,
};
use crate::CodecError;
use crate::lifting::Alpha;
use crate::quant::HeightGrid;

/// Decodes the whole hierarchy ([`super::walk_all_with_validity`]) and compares every
/// reconstructed vertex of every level with the filtered data of that level (the input itself
/// for α = 1 and at the finest level).
///
/// Corrupt records are errors; a bound violation is reported, not an error, so callers can say
/// by how much.
pub fn verify(encoded: &Encoded, input: &HeightGrid) -> Result<VerifyReport, CodecError> {
    verify_walk(encoded, input, |_| {})
}

/// [`verify`] and, from the same decode, the finest level on the input's grid and the nodata
/// mask there: what [`super::reconstruct_finest_with_validity`] returns, without decoding twice.
pub fn verify_with_finest(
    encoded: &Encoded,
    input: &HeightGrid,
) -> Result<(VerifyReport, Vec<i32>, Vec<bool>), CodecError> {
    let mut finest = FinestRaster::new(&encoded.params)?;
    let report = verify_walk(encoded, input, |v| finest.put(v.id, v.grid, v.valid))?;
    Ok((report, finest.heights, finest.valid))
}

/// [`verify`] and, from the same decode, what [`super::reconstruct_reached`] returns: the
/// reconstruction at every lattice point some diamond of any level reaches, and its state.
pub fn verify_with_reached(
    encoded: &Encoded,
    input: &HeightGrid,
) -> Result<(VerifyReport, Vec<i32>, Vec<Reached>), CodecError> {
    let mut reached = ReachedRaster::new(&encoded.params)?;
    let report = verify_walk(encoded, input, |v| reached.put(v.id, v.grid, v.valid))?;
    Ok((report, reached.heights, reached.state))
}

/// [`verify`], handing `also` every visit after it is measured.
fn verify_walk(
    encoded: &Encoded,
    input: &HeightGrid,
    mut also: impl FnMut(&super::Visit<'_>),
) -> Result<VerifyReport, CodecError> {
    let params = encoded.params;
    planar_only(&params)?;
    let layout = params.layout();
    let fields = (params.alpha == Alpha::Half).then(|| analysis_fields(layout, input));
    let n = layout.n();
    let mut levels = LevelReport::empty(&params);
    // Each diamond's worst error on its own, in parallel; maxima and sums do not depend on the
    // order they are taken in, so the report is the serial walk's.
    walk_batches_impl(encoded, true, |batch| {
        let found: Vec<(u64, u32)> = batch
            .par_iter()
            .map(|v| {
                let want = |x, y, level: u8| -> Option<i32> {
                    let v = input.get(x, y)?;
                    Some(fields.as_ref().map_or(v, |f| f[level as usize].get(x, y)))
                };
                let g = layout.grid(v.id);
                let (mut vertices, mut worst) = (0u64, 0u32);
                for j in 0..n {
                    for i in 0..n {
                        let (x, y) = g.point(i as i64, j as i64);
                        let Some(want) = want(x, y, v.id.level) else {
                            continue;
                        };
                        let e = (i64::from(v.grid[j * n + i]) - i64::from(want)).unsigned_abs();
                        worst = worst.max(u32::try_from(e).unwrap_or(u32::MAX));
                        vertices += 1;
                    }
                }
                (vertices, worst)
            })
            .collect();
        for (v, (vertices, worst)) in batch.iter().zip(found) {
            let report = &mut levels[v.id.level as usize];
            report.diamonds += 1;
            report.vertices += vertices;
            report.max_error = report.max_error.max(worst);
            also(v);
        }
    })?;
    Ok(VerifyReport {
        levels,
        bound: params.quantizer.k() as u32,
    })
}
