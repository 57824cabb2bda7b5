//! Universal Transverse Mercator: geodetic latitude and longitude → easting and northing, by
//! Krüger's series to sixth order in the third flattening `n` (Karney 2011, "Transverse Mercator
//! with an accuracy of a few nanometers", eqs. 7–9 and 35), exact to about 5 nm within 3 900 km
//! of the central meridian — far beyond any zone. The forward map looks planet lattice points
//! up in projected inputs (`cbdam build --planet`); the inverse (Karney eqs. 11, 18–21, 36)
//! places the inputs' samples on the planet to measure the resampling error.

use super::LatLon;

/// An ellipsoid by semi-major axis and flattening.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ellipsoid {
    /// Semi-major axis, metres.
    pub a: f64,
    /// Flattening.
    pub f: f64,
}

impl Ellipsoid {
    /// WGS 84 (EPSG:7030).
    pub const WGS84: Ellipsoid = Ellipsoid {
        a: super::wgs84::A,
        f: super::wgs84::F,
    };
    /// GRS 1980 (EPSG:7019), the ellipsoid of NAD83 and ETRS89.
    pub const GRS80: Ellipsoid = Ellipsoid {
        a: 6_378_137.0,
        f: 1.0 / 298.257_222_101,
    };
}

/// A UTM zone: the projection of EPSG 326zz / 327zz (WGS 84), 269zz (NAD83, zones 1–23) and
/// 258zz (ETRS89, zones 28–38).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Utm {
    /// Zone 1 … 60.
    pub zone: u8,
    /// Northern hemisphere (false northing 0) or southern (10 000 km).
    pub north: bool,
    /// The datum's ellipsoid.
    pub ellipsoid: Ellipsoid,
}

/// UTM's scale on the central meridian.
const K0: f64 = 0.9996;
/// UTM's false easting, metres.
const FALSE_EASTING: f64 = 500_000.0;
/// UTM's false northing in the southern hemisphere, metres.
const FALSE_NORTHING_SOUTH: f64 = 10_000_000.0;

impl Utm {
    /// The UTM zone of an EPSG code, or `None` if the code is not one of the UTM families this
    /// module knows (see [`Utm`]).
    pub fn from_epsg(epsg: u32) -> Option<Utm> {
        let (zone, north, ellipsoid) = match epsg {
            32601..=32660 => (epsg - 32600, true, Ellipsoid::WGS84),
            32701..=32760 => (epsg - 32700, false, Ellipsoid::WGS84),
            26901..=26923 => (epsg - 26900, true, Ellipsoid::GRS80),
            25828..=25838 => (epsg - 25800, true, Ellipsoid::GRS80),
            _ => return None,
        };
        Some(Utm {
            zone: zone as u8,
            north,
            ellipsoid,
        })
    }

    /// The zone's central meridian, degrees east.
    pub fn central_meridian(&self) -> f64 {
        -183.0 + 6.0 * f64::from(self.zone)
    }

    /// Easting and northing, metres, of a geodetic point (any longitude; the series is exact
    /// to nanometres within about 35° of the central meridian, and this is called only within a
    /// few degrees of it).
    pub fn forward(&self, p: LatLon) -> (f64, f64) {
        let Ellipsoid { a, f } = self.ellipsoid;
        let n = f / (2.0 - f);
        let (n2, n3) = (n * n, n * n * n);
        let (n4, n5, n6) = (n2 * n2, n2 * n3, n3 * n3);
        // Rectifying radius (Karney eq. 14).
        let big_a = a / (1.0 + n) * (1.0 + n2 / 4.0 + n4 / 64.0 + n6 / 256.0);
        // Krüger's α coefficients (Karney eq. 35).
        let alpha = [
            n / 2.0 - 2.0 * n2 / 3.0 + 5.0 * n3 / 16.0 + 41.0 * n4 / 180.0 - 127.0 * n5 / 288.0
                + 7891.0 * n6 / 37800.0,
            13.0 * n2 / 48.0 - 3.0 * n3 / 5.0 + 557.0 * n4 / 1440.0 + 281.0 * n5 / 630.0
                - 1_983_433.0 * n6 / 1_935_360.0,
            61.0 * n3 / 240.0 - 103.0 * n4 / 140.0
                + 15061.0 * n5 / 26880.0
                + 167_603.0 * n6 / 181_440.0,
            49561.0 * n4 / 161_280.0 - 179.0 * n5 / 168.0 + 6_601_661.0 * n6 / 7_257_600.0,
            34729.0 * n5 / 80640.0 - 3_418_889.0 * n6 / 1_995_840.0,
            212_378_941.0 * n6 / 319_334_400.0,
        ];
        let e = (f * (2.0 - f)).sqrt();
        let phi = p.lat.to_radians();
        let mut dl = p.lon - self.central_meridian();
        dl -= 360.0 * (dl / 360.0).round();
        let lambda = dl.to_radians();
        // Conformal latitude: τ' = tan χ (Karney eqs. 7–9, in the sinh/atanh form).
        let s = phi.sin();
        let t = (s.atanh() - e * (e * s).atanh()).sinh();
        let xi_p = t.atan2(lambda.cos());
        let eta_p = (lambda.sin() / (1.0 + t * t).sqrt()).atanh();
        let (mut xi, mut eta) = (xi_p, eta_p);
        for (j, aj) in alpha.iter().enumerate() {
            let k = 2.0 * (j as f64 + 1.0);
            xi += aj * (k * xi_p).sin() * (k * eta_p).cosh();
            eta += aj * (k * xi_p).cos() * (k * eta_p).sinh();
        }
        let easting = FALSE_EASTING + K0 * big_a * eta;
        let northing = K0 * big_a * xi
            + if self.north {
                0.0
            } else {
                FALSE_NORTHING_SOUTH
            };
        (easting, northing)
    }

    /// Geodetic latitude and longitude of an easting and northing (the inverse of
    /// [`Utm::forward`], to nanometres likewise).
    pub fn inverse(&self, easting: f64, northing: f64) -> LatLon {
        let Ellipsoid { a, f } = self.ellipsoid;
        let n = f / (2.0 - f);
        let (n2, n3) = (n * n, n * n * n);
        let (n4, n5, n6) = (n2 * n2, n2 * n3, n3 * n3);
        let big_a = a / (1.0 + n) * (1.0 + n2 / 4.0 + n4 / 64.0 + n6 / 256.0);
        // Krüger's β coefficients (Karney eq. 36).
        let beta = [
            n / 2.0 - 2.0 * n2 / 3.0 + 37.0 * n3 / 96.0 - n4 / 360.0 - 81.0 * n5 / 512.0
                + 96199.0 * n6 / 604_800.0,
            n2 / 48.0 + n3 / 15.0 - 437.0 * n4 / 1440.0 + 46.0 * n5 / 105.0
                - 1_118_711.0 * n6 / 3_870_720.0,
            17.0 * n3 / 480.0 - 37.0 * n4 / 840.0 - 209.0 * n5 / 4480.0 + 5569.0 * n6 / 90720.0,
            4397.0 * n4 / 161_280.0 - 11.0 * n5 / 504.0 - 830_251.0 * n6 / 7_257_600.0,
            4583.0 * n5 / 161_280.0 - 108_847.0 * n6 / 3_991_680.0,
            20_648_693.0 * n6 / 638_668_800.0,
        ];
        let e2 = f * (2.0 - f);
        let e = e2.sqrt();
        let false_northing = if self.north {
            0.0
        } else {
            FALSE_NORTHING_SOUTH
        };
        let xi = (northing - false_northing) / (K0 * big_a);
        let eta = (easting - FALSE_EASTING) / (K0 * big_a);
        let (mut xi_p, mut eta_p) = (xi, eta);
        for (j, bj) in beta.iter().enumerate() {
            let k = 2.0 * (j as f64 + 1.0);
            xi_p -= bj * (k * xi).sin() * (k * eta).cosh();
            eta_p -= bj * (k * xi).cos() * (k * eta).sinh();
        }
        let tau_p = xi_p.sin() / (eta_p.sinh().powi(2) + xi_p.cos().powi(2)).sqrt();
        let lambda = eta_p.sinh().atan2(xi_p.cos());
        // τ from τ' by Newton's method (Karney eqs. 19–21); converges in 2–3 steps.
        let tau_of = |tau: f64| {
            let sigma = (e * (e * tau / (1.0 + tau * tau).sqrt()).atanh()).sinh();
            tau * (1.0 + sigma * sigma).sqrt() - sigma * (1.0 + tau * tau).sqrt()
        };
        let mut tau = tau_p / (1.0 - e2);
        for _ in 0..8 {
            let tp = tau_of(tau);
            let slope = (1.0 - e2) * (1.0 + tp * tp).sqrt() * (1.0 + tau * tau).sqrt()
                / (1.0 + (1.0 - e2) * tau * tau);
            let step = (tau_p - tp) / slope;
            tau += step;
            if step.abs() <= 1e-15 * tau.abs().max(1.0) {
                break;
            }
        }
        let mut lon = self.central_meridian() + lambda.to_degrees();
        lon -= 360.0 * ((lon - 1e-12) / 360.0).round();
        LatLon {
            lat: tau.atan().to_degrees(),
            lon,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// GeographicLib's `GeoConvert(1)` manual, EXAMPLES: `echo 33.3 44.4 | GeoConvert -u`
    /// prints `38n 444140.54 3684706.36` (WGS 84, UTM zone 38 north), to the centimetre.
    #[test]
    fn matches_geoconvert_example() {
        let utm = Utm::from_epsg(32638).unwrap();
        let (e, n) = utm.forward(LatLon {
            lat: 33.3,
            lon: 44.4,
        });
        assert!((e - 444_140.54).abs() < 0.006, "easting {e}");
        assert!((n - 3_684_706.36).abs() < 0.006, "northing {n}");
    }

    /// On the central meridian the northing is the meridian arc times k0; at the equator 0;
    /// the southern hemisphere adds the false northing; east and west are mirror images.
    #[test]
    fn central_meridian_equator_and_symmetry() {
        let utm = Utm::from_epsg(32631).unwrap();
        let (e, n) = utm.forward(LatLon { lat: 0.0, lon: 3.0 });
        assert!((e - 500_000.0).abs() < 1e-9 && n.abs() < 1e-9, "{e} {n}");
        // Meridian arc to 45°N on WGS 84: 4 984 944.378 m (a standard value; k0 scales it).
        let (e, n) = utm.forward(LatLon {
            lat: 45.0,
            lon: 3.0,
        });
        assert!((e - 500_000.0).abs() < 1e-9);
        assert!((n / K0 - 4_984_944.378).abs() < 0.01, "arc {}", n / K0);
        let (ew, nw) = utm.forward(LatLon {
            lat: 45.0,
            lon: 1.0,
        });
        let (ee, ne) = utm.forward(LatLon {
            lat: 45.0,
            lon: 5.0,
        });
        assert!((ew + ee - 1_000_000.0).abs() < 1e-6 && (nw - ne).abs() < 1e-6);
        let south = Utm::from_epsg(32731).unwrap();
        let (_, ns) = south.forward(LatLon {
            lat: -45.0,
            lon: 3.0,
        });
        assert!((ns - (FALSE_NORTHING_SOUTH - n)).abs() < 1e-6);
    }

    /// Inverse of the forward map to 1e-11° (about a micrometre) over every zone's width and
    /// latitudes from −80° to 84° (UTM's range), both hemispheres' false northings.
    #[test]
    fn inverse_undoes_forward() {
        let mut worst: f64 = 0.0;
        for epsg in [32601, 32615, 32638, 32660, 32701, 32733, 26915, 25832] {
            let utm = Utm::from_epsg(epsg).unwrap();
            for i in 0..=40 {
                for j in 0..=12 {
                    let lat = -80.0 + 164.0 * f64::from(i) / 40.0;
                    let lon = utm.central_meridian() - 3.5 + 7.0 * f64::from(j) / 12.0;
                    let (e, n) = utm.forward(LatLon { lat, lon });
                    let back = utm.inverse(e, n);
                    let mut dlon = back.lon - lon;
                    dlon -= 360.0 * (dlon / 360.0).round();
                    worst = worst.max((back.lat - lat).abs()).max(dlon.abs());
                }
            }
        }
        assert!(worst < 1e-11, "worst round trip {worst:e}°");
    }

    #[test]
    fn epsg_families() {
        assert_eq!(Utm::from_epsg(26915).unwrap().zone, 15);
        assert_eq!(Utm::from_epsg(26915).unwrap().ellipsoid, Ellipsoid::GRS80);
        assert!(!Utm::from_epsg(32760).unwrap().north);
        assert_eq!(Utm::from_epsg(4326), None);
        assert_eq!(Utm::from_epsg(2154), None);
    }
}
