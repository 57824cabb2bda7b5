//! The WGS84 ellipsoid: geodetic coordinates ↔ Earth-centred Earth-fixed (ECEF) cartesian
//! coordinates, and the ellipsoid normal.
//!
//! ECEF axes: X through latitude 0 / longitude 0, Y through latitude 0 / longitude 90° E, Z
//! through the north pole; metres. Geodetic latitude is the angle between the ellipsoid normal
//! and the equatorial plane (not the geocentric angle of the position vector).

/// Semi-major axis `a`, metres (WGS84 defining constant).
pub const A: f64 = 6_378_137.0;
/// Flattening `f = 1/298.257223563` (WGS84 defining constant).
pub const F: f64 = 1.0 / 298.257_223_563;
/// Semi-minor axis `b = a·(1 − f)`, metres.
pub const B: f64 = A * (1.0 - F);
/// First eccentricity squared, `e² = f·(2 − f)`.
pub const E2: f64 = F * (2.0 - F);
/// Second eccentricity squared, `e'² = e²/(1 − e²)`.
pub const EP2: f64 = E2 / (1.0 - E2);

/// A position in geodetic coordinates on WGS84.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Geodetic {
    /// Geodetic latitude, degrees north, `[−90, 90]`.
    pub lat: f64,
    /// Longitude, degrees east.
    pub lon: f64,
    /// Height above the ellipsoid along its normal, metres.
    pub height: f64,
}

impl Geodetic {
    /// `(lat, lon, height)` in degrees and metres.
    pub const fn new(lat: f64, lon: f64, height: f64) -> Self {
        Self { lat, lon, height }
    }

    /// ECEF position, metres (closed form, EPSG method 9602):
    /// `X = (ν + h)·cos φ·cos λ`, `Y = (ν + h)·cos φ·sin λ`, `Z = (ν·(1 − e²) + h)·sin φ`,
    /// `ν = a/√(1 − e²·sin² φ)`.
    pub fn to_ecef(&self) -> [f64; 3] {
        let (sp, cp) = self.lat.to_radians().sin_cos();
        let (sl, cl) = self.lon.to_radians().sin_cos();
        let nu = A / (1.0 - E2 * sp * sp).sqrt();
        [
            (nu + self.height) * cp * cl,
            (nu + self.height) * cp * sl,
            (nu * (1.0 - E2) + self.height) * sp,
        ]
    }

    /// Geodetic coordinates of an ECEF position (longitude in `(−180, 180]`).
    ///
    /// Bowring's formula iterated on the parametric latitude until it stops moving (two or three
    /// rounds for terrestrial heights, a few more from orbit), then the height as
    /// `p·cos φ + z·sin φ − a·√(1 − e²·sin² φ)`, which stays accurate at the poles. Exact to
    /// about 1e-15 relative for points outside the ellipsoid's evolute (everything farther than
    /// ~43 km from the centre); nearer the centre the answer is one of several and may differ
    /// from other libraries'. Never NaN for finite input: the centre itself returns the north
    /// pole at height −b.
    pub fn from_ecef(p: [f64; 3]) -> Self {
        let [x, y, z] = p;
        let r = x.hypot(y);
        let lon = y.atan2(x).to_degrees();
        if r == 0.0 && z == 0.0 {
            return Self::new(90.0, lon, -B);
        }
        let mut beta = z.atan2((1.0 - F) * r);
        let mut lat = f64::NAN;
        for _ in 0..32 {
            let (sb, cb) = beta.sin_cos();
            let next = (z + EP2 * B * sb * sb * sb).atan2(r - E2 * A * cb * cb * cb);
            let moved = (next - lat).abs();
            lat = next;
            if moved <= 1e-16 {
                break;
            }
            let (sp, cp) = lat.sin_cos();
            beta = ((1.0 - F) * sp).atan2(cp);
        }
        let (sp, cp) = lat.sin_cos();
        let height = r * cp + z * sp - A * (1.0 - E2 * sp * sp).sqrt();
        Self::new(lat.to_degrees(), lon, height)
    }

    /// The ellipsoid's outward unit normal at this latitude and longitude (ECEF components):
    /// the direction heights are measured along.
    pub fn normal(&self) -> [f64; 3] {
        let (sp, cp) = self.lat.to_radians().sin_cos();
        let (sl, cl) = self.lon.to_radians().sin_cos();
        [cp * cl, cp * sl, sp]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dms(d: f64, m: f64, s: f64) -> f64 {
        d + m / 60.0 + s / 3600.0
    }

    #[test]
    fn published_conversions() {
        // EPSG Guidance Note 7-2, method 9602 (geographic/geocentric conversions), worked
        // example on WGS84: 53°48'33.820"N 2°07'46.380"E, h = 73.0 m ->
        // X = 3771793.968 m, Y = 140253.342 m, Z = 5124304.349 m.
        let g = Geodetic::new(dms(53.0, 48.0, 33.820), dms(2.0, 7.0, 46.380), 73.0);
        let p = g.to_ecef();
        let want = [3_771_793.968, 140_253.342, 5_124_304.349];
        for k in 0..3 {
            assert!((p[k] - want[k]).abs() < 0.0005, "{p:?}");
        }
        let back = Geodetic::from_ecef(want);
        // The published values are rounded to the millimetre: 0.5 mm is 4.5e-9° of latitude.
        assert!((back.lat - g.lat).abs() < 1e-8 && (back.lon - g.lon).abs() < 1e-8);
        assert!((back.height - 73.0).abs() < 0.001, "{back:?}");
        // GeographicLib CartConvert(1) manual, EXAMPLES: `echo 33.3 44.4 6000 | CartConvert`
        // => 3816209.60 3737108.55 3485109.57.
        let p = Geodetic::new(33.3, 44.4, 6000.0).to_ecef();
        let want = [3_816_209.60, 3_737_108.55, 3_485_109.57];
        for k in 0..3 {
            assert!((p[k] - want[k]).abs() < 0.005, "{p:?}");
        }
        // Rounded to the centimetre: 5 mm is 4.5e-8° of latitude.
        let back = Geodetic::from_ecef(want);
        assert!((back.lat - 33.3).abs() < 1e-7 && (back.lon - 44.4).abs() < 1e-7);
        assert!((back.height - 6000.0).abs() < 0.01, "{back:?}");
    }

    #[test]
    fn poles_equator_and_axes() {
        let north = Geodetic::new(90.0, 17.0, 0.0).to_ecef();
        assert!(north[0].abs() < 1e-9 && north[1].abs() < 1e-9);
        assert!((north[2] - B).abs() < 1e-9);
        assert_eq!(Geodetic::new(0.0, 0.0, 0.0).to_ecef(), [A, 0.0, 0.0]);
        let g = Geodetic::from_ecef([0.0, 0.0, -B - 100.0]);
        assert!((g.lat + 90.0).abs() < 1e-12 && (g.height - 100.0).abs() < 1e-8);
        let g = Geodetic::from_ecef([0.0, A + 5.0, 0.0]);
        assert!(g.lat.abs() < 1e-12 && (g.lon - 90.0).abs() < 1e-12);
        assert!((g.height - 5.0).abs() < 1e-8);
        // Near the centre: an answer, not NaN.
        for p in [[0.0; 3], [30_000.0, 30_000.0, 0.0], [1.0, 0.0, 1.0]] {
            let g = Geodetic::from_ecef(p);
            assert!(g.lat.is_finite() && g.lon.is_finite() && g.height.is_finite());
        }
    }

    #[test]
    fn ecef_round_trips_to_1e_12_relative_from_the_trench_to_orbit() {
        let mut seed = 0x9e37_79b9_7f4a_7c15_u64;
        let mut next = || {
            seed = seed
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut worst = 0.0f64;
        for _ in 0..100_000 {
            let lat = -90.0 + 180.0 * next();
            let lon = -180.0 + 360.0 * next();
            let height = -12_000.0 + 40_000_000.0 * next().powi(4);
            let g = Geodetic::new(lat, lon, height);
            let p = g.to_ecef();
            let back = Geodetic::from_ecef(p);
            let q = back.to_ecef();
            let norm = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            let err = (0..3).map(|k| (p[k] - q[k]).abs()).fold(0.0, f64::max) / norm;
            worst = worst.max(err);
            assert!((back.lat - lat).abs() < 1e-10, "{g:?} -> {back:?}");
            assert!(
                (back.height - height).abs() < 1e-12 * norm + 1e-6,
                "{g:?} -> {back:?}"
            );
        }
        eprintln!("ECEF -> geodetic -> ECEF, 100 000 points: worst relative error {worst:e}");
        assert!(worst < 1e-12, "worst relative error {worst:e}");
    }

    #[test]
    fn the_normal_is_perpendicular_to_the_ellipsoid() {
        // Moving along the normal by h changes the position by exactly h·normal.
        for (lat, lon) in [(0.0, 0.0), (45.0, 10.0), (-63.5, -170.0), (89.9, 33.0)] {
            let n = Geodetic::new(lat, lon, 0.0).normal();
            let p0 = Geodetic::new(lat, lon, 0.0).to_ecef();
            let p1 = Geodetic::new(lat, lon, 1000.0).to_ecef();
            for k in 0..3 {
                assert!((p1[k] - p0[k] - 1000.0 * n[k]).abs() < 1e-8);
            }
            // And it is the gradient direction of x²/a² + y²/a² + z²/b² at p0.
            let grad = [p0[0] / (A * A), p0[1] / (A * A), p0[2] / (B * B)];
            let g = (grad[0] * grad[0] + grad[1] * grad[1] + grad[2] * grad[2]).sqrt();
            for k in 0..3 {
                assert!((grad[k] / g - n[k]).abs() < 1e-12);
            }
        }
    }
}
