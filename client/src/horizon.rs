//! Horizon culling on a planet: what the ellipsoid hides from the eye.
//!
//! The occluder is an ellipsoid inside the terrain's solid (the WGS84 ellipsoid lowered below the
//! lowest height of the data). In the occluder's scaled space (divide by its radii, it becomes
//! the unit sphere) a point is hidden when it lies beyond the horizon plane (the plane of the
//! circle where the eye's tangent cone touches the sphere) and inside that cone: the segment from
//! the eye then crosses the horizon disc, which lies inside the sphere (Cesium's scaled-space
//! horizon test). That region is the intersection of a half-space and a convex cone, so it is
//! convex, and a linear map keeps it so: a box whose eight corners are all hidden is hidden
//! whole. The test is conservative (it never hides what could be seen) as long as the terrain is
//! closed; through a nodata hole one would see the far side's underside, which back-face culling
//! does not draw anyway.

use glam::DVec3;

/// An ellipsoid that hides what lies behind it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Occluder {
    /// Semi-axes x, y, z, metres (ECEF).
    pub radii: DVec3,
}

/// What an [`Occluder`] hides from one eye: the eye in scaled space and `|v|² − 1`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Horizon {
    radii: DVec3,
    eye: DVec3,
    vh2: f64,
}

impl Occluder {
    /// The horizon seen from `eye` (ECEF); `None` when the eye is inside the occluder (nothing
    /// can be said to be hidden).
    pub fn from_eye(&self, eye: DVec3) -> Option<Horizon> {
        let v = eye / self.radii;
        let vh2 = v.length_squared() - 1.0;
        (vh2 > 0.0).then_some(Horizon {
            radii: self.radii,
            eye: v,
            vh2,
        })
    }
}

impl Horizon {
    /// Whether point `p` (ECEF) is behind the occluder.
    pub fn hides_point(&self, p: DVec3) -> bool {
        let vt = p / self.radii - self.eye;
        let along = -vt.dot(self.eye);
        along > self.vh2 && along * along > self.vh2 * vt.length_squared()
    }

    /// Whether the whole box `lo..hi` is behind the occluder (all corners are: see the module
    /// documentation).
    pub fn hides_box(&self, lo: DVec3, hi: DVec3) -> bool {
        (0..8).all(|i| {
            self.hides_point(DVec3::new(
                if i & 1 == 0 { lo.x } else { hi.x },
                if i & 2 == 0 { lo.y } else { hi.y },
                if i & 4 == 0 { lo.z } else { hi.z },
            ))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// On a sphere of radius 1 seen from distance 2 along x: the far pole is hidden, a point
    /// just above the limb is not, and the test agrees with ray casting on random points.
    #[test]
    fn hides_exactly_what_the_sphere_covers() {
        let o = Occluder {
            radii: DVec3::splat(1.0),
        };
        let eye = DVec3::new(2.0, 0.0, 0.0);
        let h = o.from_eye(eye).unwrap();
        assert!(h.hides_point(DVec3::new(-1.0, 0.0, 0.0)));
        assert!(h.hides_point(DVec3::new(-0.5, 0.1, 0.0)));
        assert!(!h.hides_point(DVec3::new(1.0, 0.0, 0.0)));
        // Behind the sphere's plane but seen past the limb (the line passes 1.25 from the centre).
        assert!(!h.hides_point(DVec3::new(-0.5, 2.0, 0.0)));
        assert!(o.from_eye(DVec3::new(0.5, 0.0, 0.0)).is_none());
        // Against ray casting: the segment from the eye to p meets the open ball before p.
        let mut s = 7u64;
        let mut rnd = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64 * 6.0 - 3.0
        };
        let mut hidden = 0;
        for _ in 0..20000 {
            let p = DVec3::new(rnd(), rnd(), rnd());
            if p.length() <= 1.0 {
                continue;
            }
            // Smallest t of |eye + t (p − eye)| = 1.
            let d = p - eye;
            let (a, b, c) = (d.dot(d), 2.0 * eye.dot(d), eye.dot(eye) - 1.0);
            let disc = b * b - 4.0 * a * c;
            let blocked = disc > 1e-9 && {
                let t = (-b - disc.sqrt()) / (2.0 * a);
                t > 0.0 && t < 1.0 - 1e-9
            };
            if h.hides_point(p) {
                hidden += 1;
                assert!(blocked, "{p} hidden but visible");
            }
        }
        assert!(hidden > 1000, "{hidden}");
    }

    /// A box straddling the limb is not hidden although some of its corners are; a box wholly
    /// behind is.
    #[test]
    fn a_box_is_hidden_only_when_all_of_it_is() {
        let o = Occluder {
            radii: DVec3::new(2.0, 2.0, 1.5),
        };
        let h = o.from_eye(DVec3::new(10.0, 0.0, 0.0)).unwrap();
        assert!(h.hides_box(DVec3::new(-1.9, -0.1, -0.1), DVec3::new(-1.7, 0.1, 0.1)));
        assert!(!h.hides_box(DVec3::new(-1.9, -0.1, -0.1), DVec3::new(-1.7, 3.0, 0.1)));
    }
}
