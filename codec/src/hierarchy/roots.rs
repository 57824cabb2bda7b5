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
use crate::geometry::{DiamondId, Domain, FacePoint};
use crate::lifting::{MAX_ABS_HEIGHT, median_edge};

/// Median edge detector prediction of `(x, y)` from the reconstructed left, upper and
/// upper-left neighbours.
#[inline]
fn med(field: &[i32], w: usize, x: usize, y: usize) -> i64 {
    let at = |x: usize, y: usize| i64::from(field[y * w + x]);
    match (x, y) {
        (0, 0) => 0,
        (_, 0) => at(x - 1, 0),
        (0, _) => at(0, y - 1),
        _ => median_edge(at(x - 1, y), at(x, y - 1), at(x - 1, y - 1)),
    }
}

/// Where the value of root-field point `(x, y)` of `face` is coded: `None` when it is coded
/// here, or the index (in the faces' concatenated root fields) of the point on an earlier face
/// that holds it — a cube-sphere's edge and corner vertices are coded once, on their canonical
/// (lowest) face, and copied to the others.
#[inline]
fn shared_owner(domain: &Domain, face: u8, x: usize, y: usize) -> Option<usize> {
    let cube = domain.cube()?;
    let rf = domain.root_field();
    let s = rf.spacing;
    let c = cube.canonical(FacePoint::new(face, x as i64 * s, y as i64 * s));
    (c.face < face).then(|| {
        (usize::from(c.face) * rf.height + (c.y / s) as usize) * rf.width + (c.x / s) as usize
    })
}

/// Encodes the root field: `target(face, x, y)` is the filtered height at lattice point
/// `(x, y)` of `face` or `None` where it is "don't care"; `drawn(face, x, y)` is what the nodata
/// mask says of a point in the data rectangle. The faces' root fields are coded one after the
/// other as one band of `width × (height · faces)` values, each face predicted on its own;
/// a point shared with an earlier face (cube edges and corners) takes that face's value and
/// codes a zero. Returns the reconstruction (the faces' fields concatenated) and the coded bytes.
pub(crate) fn encode_roots(
    params: &CodecParams,
    target: impl Fn(u8, i64, i64) -> Option<i32>,
    drawn: impl Fn(u8, i64, i64) -> bool,
) -> Result<(Vec<i32>, Vec<u8>), CodecError> {
    let domain = &params.domain;
    let rf = domain.root_field();
    let (w, h, s) = (rf.width, rf.height, rf.spacing);
    let faces = usize::from(domain.faces());
    let q = params.root_quantizer;
    let step = i64::from(q.step());
    let mut recon = vec![0i32; w * h * faces];
    let mut idx = vec![0i32; w * h * faces];
    for face in 0..faces {
        let base = face * w * h;
        for y in 0..h {
            for x in 0..w {
                let k = base + y * w + x;
                if let Some(owner) = shared_owner(domain, face as u8, x, y) {
                    recon[k] = recon[owner];
                    continue;
                }
                let pred = med(&recon[base..base + w * h], w, x, y);
                let (i, v) = match target(face as u8, x as i64 * s, y as i64 * s) {
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
                idx[k] = i as i32;
                recon[k] = v as i32;
            }
        }
    }
    let mut bytes = Vec::new();
    if params.nodata_mask {
        let cared = |x: usize, yy: usize| {
            let (face, y) = ((yy / h) as u8, yy % h);
            if shared_owner(domain, face, x, y).is_some() {
                return None;
            }
            let (lx, ly) = (x as i64 * s, y as i64 * s);
            domain.holds_data(face, lx, ly).then(|| drawn(face, lx, ly))
        };
        encode_mask(w, h * faces, &cared, &mut bytes);
    }
    let band = Band {
        kind: BandKind::Roots,
        width: w,
        height: h * faces,
        values: &idx,
    };
    encode_bands(params.coder, &[band], &mut bytes);
    Ok((recon, bytes))
}

/// The decoded root field: heights, and validity when the repository has a nodata mask.
pub(crate) type DecodedRoots = (Vec<i32>, Option<Vec<bool>>);

/// Decodes the root field written by [`encode_roots`].
pub(crate) fn decode_roots(params: &CodecParams, bytes: &[u8]) -> Result<DecodedRoots, CodecError> {
    let domain = &params.domain;
    let rf = domain.root_field();
    let (w, h) = (rf.width, rf.height);
    let faces = usize::from(domain.faces());
    let (mut valid, bytes) = if params.nodata_mask {
        let (m, used) = decode_mask(w, h * faces, bytes)?;
        (Some(m), &bytes[used..])
    } else {
        (None, bytes)
    };
    let mut idx = vec![0i32; w * h * faces];
    let mut bands = [BandMut {
        kind: BandKind::Roots,
        width: w,
        height: h * faces,
        values: &mut idx,
    }];
    decode_bands(params.coder, bytes, &mut bands, DecodeLimits::default())?;
    let step = i64::from(params.root_quantizer.step());
    let mut recon = vec![0i32; w * h * faces];
    for face in 0..faces {
        let base = face * w * h;
        for y in 0..h {
            for x in 0..w {
                let k = base + y * w + x;
                if let Some(owner) = shared_owner(domain, face as u8, x, y) {
                    if idx[k] != 0 {
                        return Err(CodecError::corrupt(
                            "root field codes a value for a cube edge vertex its lower face holds",
                        ));
                    }
                    recon[k] = recon[owner];
                    if let Some(v) = valid.as_mut() {
                        v[k] = v[owner];
                    }
                    continue;
                }
                let v = med(&recon[base..base + w * h], w, x, y) + i64::from(idx[k]) * step;
                if v.abs() > i64::from(MAX_ABS_HEIGHT) {
                    return Err(CodecError::corrupt(
                        "root field reconstructs heights out of range",
                    ));
                }
                recon[k] = v as i32;
            }
        }
    }
    Ok((recon, valid))
}

/// Copies a root diamond's `N × N` grid out of the root field (heights or validity): the field
/// of the root's face.
pub(crate) fn root_grid<T: Copy>(domain: &Domain, field: &[T], id: DiamondId, out: &mut [T]) {
    let n = domain.n();
    let rf = domain.root_field();
    let (w, s) = (rf.width, rf.spacing);
    let field = &field[usize::from(id.face) * rf.points()..][..rf.points()];
    let g = domain.layout().grid(id);
    let (x0, y0) = ((g.origin.0 / s) as usize, (g.origin.1 / s) as usize);
    for j in 0..n {
        out[j * n..(j + 1) * n].copy_from_slice(&field[(y0 + j) * w + x0..(y0 + j) * w + x0 + n]);
    }
}
