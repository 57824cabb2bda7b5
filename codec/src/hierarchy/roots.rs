//! The root field: all level-0 vertices of the domain as one grid.
//!
//! Coding the roots as one field (rather than `N²` values per root) stores each shared edge
//! vertex once, so neighbouring roots agree on their common side by construction. Values are
//! predicted in raster order from already reconstructed neighbours with the median edge
//! detector of LOCO-I and quantized closed loop like every other level.

use super::CodecParams;
use super::mask::{decode_mask, encode_mask};
use crate::CodecError;
use crate::entropy::{Band, BandKind, BandMut, DecodeLimits, decode_bands, encode_bands};
use crate::geometry::{DiamondId, Domain};
use crate::lifting::MAX_ABS_HEIGHT;

/// Median edge detector prediction of `(x, y)` from the reconstructed left, upper and
/// upper-left neighbours.
#[inline]
fn med(field: &[i32], w: usize, x: usize, y: usize) -> i64 {
    let at = |x: usize, y: usize| i64::from(field[y * w + x]);
    match (x, y) {
        (0, 0) => 0,
        (_, 0) => at(x - 1, 0),
        (0, _) => at(0, y - 1),
        _ => {
            let (a, b, c) = (at(x - 1, y), at(x, y - 1), at(x - 1, y - 1));
            if c >= a.max(b) {
                a.min(b)
            } else if c <= a.min(b) {
                a.max(b)
            } else {
                a + b - c
            }
        }
    }
}

/// Encodes the root field: `target(x, y)` is the filtered height at lattice point `(x, y)` or
/// `None` where it is "don't care"; `drawn(x, y)` is what the nodata mask says of a point in the
/// data rectangle. Returns the reconstruction and the coded bytes.
pub(crate) fn encode_roots(
    params: &CodecParams,
    target: impl Fn(i64, i64) -> Option<i32>,
    drawn: impl Fn(i64, i64) -> bool,
) -> Result<(Vec<i32>, Vec<u8>), CodecError> {
    let rf = params.domain.root_field();
    let (w, h, s) = (rf.width, rf.height, rf.spacing);
    let q = params.root_quantizer;
    let step = i64::from(q.step());
    let mut recon = vec![0i32; w * h];
    let mut idx = vec![0i32; w * h];
    for y in 0..h {
        for x in 0..w {
            let pred = med(&recon, w, x, y);
            let (i, v) = match target(x as i64 * s, y as i64 * s) {
                Some(t) => {
                    let i = q.index(i64::from(t) - pred);
                    (i, pred + i * step)
                }
                None => (0, pred),
            };
            if v.abs() > i64::from(MAX_ABS_HEIGHT) {
                return Err(CodecError::invalid(
                    "root heights overflow the integer range",
                ));
            }
            idx[y * w + x] = i as i32;
            recon[y * w + x] = v as i32;
        }
    }
    let mut bytes = Vec::new();
    if params.nodata_mask {
        let cared = |x: usize, y: usize| {
            let (lx, ly) = (x as i64 * s, y as i64 * s);
            params.domain.holds_data(0, lx, ly).then(|| drawn(lx, ly))
        };
        encode_mask(w, h, &cared, &mut bytes);
    }
    let band = Band {
        kind: BandKind::Roots,
        width: w,
        height: h,
        values: &idx,
    };
    encode_bands(params.coder, &[band], &mut bytes);
    Ok((recon, bytes))
}

/// The decoded root field: heights, and validity when the repository has a nodata mask.
pub(crate) type DecodedRoots = (Vec<i32>, Option<Vec<bool>>);

/// Decodes the root field written by [`encode_roots`].
pub(crate) fn decode_roots(params: &CodecParams, bytes: &[u8]) -> Result<DecodedRoots, CodecError> {
    let rf = params.domain.root_field();
    let (w, h) = (rf.width, rf.height);
    let (valid, bytes) = if params.nodata_mask {
        let (m, used) = decode_mask(w, h, bytes)?;
        (Some(m), &bytes[used..])
    } else {
        (None, bytes)
    };
    let mut idx = vec![0i32; w * h];
    let mut bands = [BandMut {
        kind: BandKind::Roots,
        width: w,
        height: h,
        values: &mut idx,
    }];
    decode_bands(params.coder, bytes, &mut bands, DecodeLimits::default())?;
    let step = i64::from(params.root_quantizer.step());
    let mut recon = vec![0i32; w * h];
    for y in 0..h {
        for x in 0..w {
            let v = med(&recon, w, x, y) + i64::from(idx[y * w + x]) * step;
            if v.abs() > i64::from(MAX_ABS_HEIGHT) {
                return Err(CodecError::corrupt(
                    "root field reconstructs heights out of range",
                ));
            }
            recon[y * w + x] = v as i32;
        }
    }
    Ok((recon, valid))
}

/// Copies a root diamond's `N × N` grid out of the root field (heights or validity).
pub(crate) fn root_grid<T: Copy>(domain: &Domain, field: &[T], id: DiamondId, out: &mut [T]) {
    let n = domain.n();
    let rf = domain.root_field();
    let (w, s) = (rf.width, rf.spacing);
    let g = domain.layout().grid(id);
    let (x0, y0) = ((g.origin.0 / s) as usize, (g.origin.1 / s) as usize);
    for j in 0..n {
        out[j * n..(j + 1) * n].copy_from_slice(&field[(y0 + j) * w + x0..(y0 + j) * w + x0 + n]);
    }
}
