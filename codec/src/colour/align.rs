//! How a colour repository's diamonds correspond to an elevation repository's.
//!
//! The two repositories share the domain: the same patch size `N`, the same roots, and data
//! rectangles that cover the same ground, the colour samples refining (or coarsening) the
//! elevation samples by a power of two: `(W_c − 1) · 2^K_e = (W_e − 1) · 2^K_c`, likewise for
//! heights. Then a diamond of level `l` is the same piece of ground in both hierarchies, its
//! centre scaled by `2^(K_c − K_e)`, for every level both have.

use crate::CodecError;
use crate::geometry::DiamondId;
use crate::hierarchy::{CodecParams, RepoKind};
use crate::repository::GeoRef;

/// The correspondence between an elevation and a colour hierarchy ([`Alignment::new`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Alignment {
    /// `K_colour − K_elevation`: lattice coordinates scale by `2^shift`.
    pub shift: i32,
    /// The colour hierarchy's finest level.
    pub colour_finest: u8,
}

/// World position of the centre of sample `(i, j)`.
fn sample_centre(g: &GeoRef, i: f64, j: f64) -> (f64, f64) {
    let half = if g.pixel_is_area { 0.5 } else { 0.0 };
    (
        g.origin_x + (i + half) * g.pixel_x,
        g.origin_y - (j + half) * g.pixel_y,
    )
}

impl Alignment {
    /// Checks that `colour` covers exactly `elevation`'s domain and says how ids map; the error
    /// names the first mismatch. Georeferencing is compared when both have it: the first and
    /// last sample centres must agree within half the coarser sample spacing.
    pub fn new(
        elevation: &CodecParams,
        elevation_geo: Option<&GeoRef>,
        colour: &CodecParams,
        colour_geo: Option<&GeoRef>,
    ) -> Result<Self, CodecError> {
        if elevation.kind != RepoKind::Elevation {
            return Err(CodecError::invalid(
                "the terrain repository is a colour repository, not an elevation one",
            ));
        }
        if colour.kind != RepoKind::Colour {
            return Err(CodecError::invalid(
                "the colour repository is an elevation repository, not a colour one",
            ));
        }
        let (e, c) = (elevation.layout(), colour.layout());
        let mismatch = |what: String| {
            Err(CodecError::invalid(format!(
                "the colour repository does not cover the elevation's domain: {what}"
            )))
        };
        if e.n() != c.n() {
            return mismatch(format!(
                "diamond size {} (colour) vs {} (elevation); rebuild the colour with --like",
                c.n(),
                e.n()
            ));
        }
        let (er, cr) = (e.root_counts(), c.root_counts());
        if er != cr {
            return mismatch(format!(
                "{}×{} root diamonds (colour) vs {}×{} (elevation)",
                cr.0, cr.1, er.0, er.1
            ));
        }
        let scaled = |samples: u32, k: u32| u128::from(samples.saturating_sub(1)) << k;
        let (de, dc) = (elevation.domain.data(), colour.domain.data());
        for (name, we, wc) in [
            ("width", de.width, dc.width),
            ("height", de.height, dc.height),
        ] {
            if scaled(wc, e.k()) != scaled(we, c.k()) {
                return mismatch(format!(
                    "data {name} {wc} samples at {} level pairs (colour) does not refine {we} \
                     at {} (elevation) by a power of two; the colour image must be \
                     (elevation − 1) · 2^m + 1 samples",
                    c.k(),
                    e.k()
                ));
            }
        }
        if let (Some(ge), Some(gc)) = (elevation_geo, colour_geo) {
            check_georefs(elevation, ge, colour, gc).map_err(|what| {
                CodecError::invalid(format!(
                    "the colour repository does not cover the elevation's domain: {what}"
                ))
            })?;
        }
        Ok(Self {
            shift: c.k() as i32 - e.k() as i32,
            colour_finest: c.finest_level(),
        })
    }

    /// The colour diamond covering the same ground as elevation diamond `id`; `None` when the
    /// colour hierarchy has no level that fine.
    pub fn colour_id(&self, id: DiamondId) -> Option<DiamondId> {
        if id.level > self.colour_finest {
            return None;
        }
        let scale = |v: u32| -> Option<u32> {
            if self.shift >= 0 {
                v.checked_mul(1u32.checked_shl(self.shift as u32)?)
            } else {
                let s = (-self.shift) as u32;
                (v.trailing_zeros() >= s || v == 0).then(|| v >> s)
            }
        };
        Some(DiamondId {
            level: id.level,
            face: id.face,
            x: scale(id.x)?,
            y: scale(id.y)?,
        })
    }
}
/// Whether two georeferenced repositories cover the same ground: the same EPSG code where both
/// have one, and the first and last sample centres within half the coarser sample spacing; the
/// mismatch found otherwise.
fn check_georefs(
    elevation: &CodecParams,
    ge: &GeoRef,
    colour: &CodecParams,
    gc: &GeoRef,
) -> Result<(), String> {
    if let (Some(a), Some(b)) = (ge.epsg, gc.epsg)
        && a != b
    {
        return Err(format!("EPSG:{b} (colour) vs EPSG:{a} (elevation)"));
    }
    let tol = 0.5
        * ge.pixel_x
            .abs()
            .max(gc.pixel_x.abs())
            .max(ge.pixel_y.abs())
            .max(gc.pixel_y.abs());
    let last = |p: &CodecParams| {
        let d = p.domain.data();
        (f64::from(d.width) - 1.0, f64::from(d.height) - 1.0)
    };
    let corners = [
        (sample_centre(ge, 0.0, 0.0), sample_centre(gc, 0.0, 0.0)),
        (
            sample_centre(ge, last(elevation).0, last(elevation).1),
            sample_centre(gc, last(colour).0, last(colour).1),
        ),
    ];
    for (a, b) in corners {
        if (a.0 - b.0).abs() > tol || (a.1 - b.1).abs() > tol {
            return Err(format!(
                "georeferenced corner sample at ({}, {}) (colour) vs ({}, {}) (elevation)",
                b.0, b.1, a.0, a.1
            ));
        }
    }
    Ok(())
}
