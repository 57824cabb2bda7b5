//! From a cube-sphere face point to geodetic latitude and longitude on WGS84, and back.
//!
//! A face point `(face, s, t)`, `s = x/S`, `t = y/S ∈ [0, 1]`, goes through three steps:
//! 1. the warp: face coordinates `a = 2s − 1`, `b = 2t − 1` become cube coordinates
//!    `(warp(a), warp(b))` with the algebraic sigmoid `warp(w) = w/√(1 + c² − c²w²)`,
//!    `c = 0.87` ([`CubeWarp::AlgebraicSigmoid`]), which evens out the cell areas (max/min
//!    1.25 on the sphere against 5.1 for the plain gnomonic cube; the test
//!    `cell_area_ratios_on_the_sphere` measures them);
//! 2. the cube direction `normal + warp(a)·u + warp(b)·v` of the face's frame
//!    ([`crate::geometry::cube::FACE_FRAMES`]) is a direction from the Earth's centre;
//! 3. the surface point is where that ray meets the WGS84 ellipsoid, and the latitude given is
//!    the **geodetic** latitude of that point (the angle of the ellipsoid normal there), the
//!    latitude in which every geographic input is georeferenced. The ray's own (geocentric)
//!    latitude differs from it by up to 0.19° at 45°, some 21 km on the ground.

use crate::geometry::cube::FACE_FRAMES;
use crate::geometry::{Domain, FacePoint};

use super::wgs84::E2;

/// Geodetic latitude and longitude in degrees (longitude in `(−180, 180]`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LatLon {
    /// Degrees north.
    pub lat: f64,
    /// Degrees east.
    pub lon: f64,
}

/// How the lattice's uniform face coordinate `w ∈ [−1, 1]` is spread over the cube face.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CubeWarp {
    /// None: `u = w` (cells 5× larger at face centres than at corners).
    Gnomonic,
    /// `u = tan(π·w/4)`: equal angles from the centre.
    EquiAngular,
    /// `u = w/√(1 + c² − c²·w²)`, `c = 0.87` (the planet's warp).
    AlgebraicSigmoid,
}

impl CubeWarp {
    /// The warp of the cube-sphere domain.
    pub const PLANET: CubeWarp = CubeWarp::AlgebraicSigmoid;
    /// `c` of the algebraic sigmoid.
    pub const SIGMOID_C: f64 = 0.87;

    /// Cube coordinate of face coordinate `w`; ±1 stays ±1 exactly, so face edges meet.
    #[inline]
    pub fn to_cube(self, w: f64) -> f64 {
        match self {
            CubeWarp::Gnomonic => w,
            // tan(π/4) rounds to 1 − 2⁻⁵³: keep the edges exact.
            CubeWarp::EquiAngular if w.abs() == 1.0 => w,
            CubeWarp::EquiAngular => (std::f64::consts::FRAC_PI_4 * w).tan(),
            CubeWarp::AlgebraicSigmoid => {
                // 1 + c²·(1 − w²): exactly 1 at w = ±1, so the edges stay at ±1.
                let c2 = Self::SIGMOID_C * Self::SIGMOID_C;
                w / (1.0 + c2 * (1.0 - w * w)).sqrt()
            }
        }
    }

    /// Face coordinate of cube coordinate `u` (the inverse of [`CubeWarp::to_cube`]).
    #[inline]
    pub fn from_cube(self, u: f64) -> f64 {
        match self {
            CubeWarp::Gnomonic => u,
            CubeWarp::EquiAngular => u.atan() / std::f64::consts::FRAC_PI_4,
            CubeWarp::AlgebraicSigmoid => {
                let c2 = Self::SIGMOID_C * Self::SIGMOID_C;
                u * ((1.0 + c2) / (1.0 + c2 * u * u)).sqrt()
            }
        }
    }
}

/// The cube direction (from the centre, not unit length) of face point `(face, s, t)` under
/// `warp`.
///
/// # Panics
/// If `face` is not a face (≥ 6); so do the functions below that take a face.
pub fn face_direction(warp: CubeWarp, face: u8, s: f64, t: f64) -> [f64; 3] {
    cube_direction(
        face,
        warp.to_cube(2.0 * s - 1.0),
        warp.to_cube(2.0 * t - 1.0),
    )
}

/// [`FACE_FRAMES`] in `f64`: the same values (an `i8` converts exactly), so that the hot loops
/// below, whose face is known only at run time, do not convert them again point by point.
const FRAMES: [[[f64; 3]; 3]; 6] = {
    let mut out = [[[0.0; 3]; 3]; 6];
    let mut f = 0;
    while f < 6 {
        let mut r = 0;
        while r < 3 {
            let mut k = 0;
            while k < 3 {
                out[f][r][k] = FACE_FRAMES[f][r][k] as f64;
                k += 1;
            }
            r += 1;
        }
        f += 1;
    }
    out
};

/// `d · w` summed as `(0..3).map(|k| d[k] * w[k]).sum()`.
#[inline]
fn dot(d: [f64; 3], w: [f64; 3]) -> f64 {
    (0..3).map(|k| d[k] * w[k]).sum::<f64>()
}

/// The direction `normal + a·u + b·v` of `face`'s frame at cube coordinates `a, b`.
#[inline]
fn cube_direction(face: u8, a: f64, b: f64) -> [f64; 3] {
    let [n, u, v] = FRAMES[usize::from(face)];
    std::array::from_fn(|k| n[k] + a * u[k] + b * v[k])
}

/// Geodetic latitude and longitude of the surface point of a direction from the centre.
fn lat_lon_of_direction(d: [f64; 3]) -> LatLon {
    // On the ellipsoid, tan(geodetic latitude) = z / ((1 − e²)·√(x² + y²)); the ratio is the
    // same for every point of the ray, so the intersection itself is not needed.
    let p = d[0].hypot(d[1]);
    LatLon {
        lat: d[2].atan2((1.0 - E2) * p).to_degrees(),
        lon: d[1].atan2(d[0]).to_degrees(),
    }
}

/// Geodetic latitude and longitude of face point `(face, s, t)`, `s, t ∈ [0, 1]` (lattice
/// `x/S`, `y/S`), under the planet's warp.
pub fn face_st_to_lat_lon(face: u8, s: f64, t: f64) -> LatLon {
    lat_lon_of_direction(face_direction(CubeWarp::PLANET, face, s, t))
}

/// The geodetic latitude and longitude of every point of one face's lattice (`S` steps a
/// side), bit for bit [`face_st_to_lat_lon`]`(face, x/S, y/S)`, with what depends on one
/// coordinate alone computed once: the warp of each column and row, and on the four
/// equatorial faces (whose lattice y runs along the Earth's axis, so a direction's x and y
/// components depend on the column only) the longitude and the distance from the axis of
/// each column — one `atan2` a point instead of two and a `hypot`.
pub struct FaceLattice {
    face: u8,
    /// `CubeWarp::PLANET.to_cube(2·i/S − 1)`, `i = 0..=S` (the same on every face: shared).
    cube: std::sync::Arc<[f64]>,
    /// Equatorial faces: per column, `(1 − e²)·√(x² + y²)` of the direction and its
    /// longitude in degrees.
    columns: Option<Vec<(f64, f64)>>,
}

impl FaceLattice {
    /// The lattice of `face` with `side` steps a side.
    pub fn new(face: u8, side: i64) -> Self {
        Self::with_cube(face, Self::cube_table(side))
    }

    /// The lattices of the six faces with `side` steps a side, sharing one table of the warp.
    pub fn faces(side: i64) -> Vec<Self> {
        let cube = Self::cube_table(side);
        (0..6)
            .map(|face| Self::with_cube(face, std::sync::Arc::clone(&cube)))
            .collect()
    }

    /// `CubeWarp::PLANET.to_cube(2·i/S − 1)`, `i = 0..=S`.
    fn cube_table(side: i64) -> std::sync::Arc<[f64]> {
        (0..=side)
            .map(|i| CubeWarp::PLANET.to_cube(2.0 * (i as f64 / side as f64) - 1.0))
            .collect()
    }

    fn with_cube(face: u8, cube: std::sync::Arc<[f64]>) -> Self {
        let [n, u, v] = FACE_FRAMES[usize::from(face)];
        // x and y of `n + a·u + b·v` do not depend on b when v has none (and adding b·0, a
        // zero, to a sum that is never −0 changes no bit).
        let columns = (v[0] == 0 && v[1] == 0 && n[2] == 0 && u[2] == 0).then(|| {
            cube.iter()
                .map(|&a| {
                    let d = cube_direction(face, a, 0.0);
                    ((1.0 - E2) * d[0].hypot(d[1]), d[1].atan2(d[0]).to_degrees())
                })
                .collect()
        });
        Self {
            face,
            cube,
            columns,
        }
    }

    /// On an equatorial face, the longitude of every point of column `x`, `0 ≤ x ≤ S` (the
    /// bits [`FaceLattice::lat_lon`] gives each); `None` on a polar face, where a point's
    /// longitude depends on its row too.
    #[inline]
    pub fn column_lon(&self, x: usize) -> Option<f64> {
        self.columns.as_ref().map(|columns| columns[x].1)
    }

    /// Latitude and longitude of lattice point `(x, y)`, `0 ≤ x, y ≤ S`.
    #[inline]
    pub fn lat_lon(&self, x: usize, y: usize) -> LatLon {
        let d = cube_direction(self.face, self.cube[x], self.cube[y]);
        match &self.columns {
            Some(columns) => {
                let (p, lon) = columns[x];
                LatLon {
                    lat: d[2].atan2(p).to_degrees(),
                    lon,
                }
            }
            None => lat_lon_of_direction(d),
        }
    }
}

/// The ECEF position (metres) where the ray of face point `(face, s, t)` meets the WGS84
/// ellipsoid.
pub fn face_st_to_surface(face: u8, s: f64, t: f64) -> [f64; 3] {
    use super::wgs84::{A, B};
    let d = face_direction(CubeWarp::PLANET, face, s, t);
    let k = 1.0 / ((d[0] * d[0] + d[1] * d[1]) / (A * A) + d[2] * d[2] / (B * B)).sqrt();
    d.map(|c| k * c)
}

/// The face point of a geodetic latitude and longitude: the face whose normal is closest to
/// the surface point's direction (the lowest-numbered on a tie, as the domain's canonical
/// owner is), and `s, t ∈ [0, 1]` on it.
pub fn lat_lon_to_face_st(ll: LatLon) -> (u8, f64, f64) {
    sin_cos_to_face_st(ll.lat.to_radians().sin_cos(), ll.lon.to_radians().sin_cos())
}

/// [`lat_lon_to_face_st`] from the sine and cosine of the latitude and of the longitude, bit
/// for bit: a caller walking a latitude/longitude grid computes them once per row and column.
#[inline]
pub fn sin_cos_to_face_st((sp, cp): (f64, f64), (sl, cl): (f64, f64)) -> (u8, f64, f64) {
    // The surface point, up to the positive factor ν: (cos φ cos λ, cos φ sin λ, (1 − e²) sin φ).
    let d = [cp * cl, cp * sl, (1.0 - E2) * sp];
    // The first face of greatest alignment (a strict `>` keeps the lower face on ties); each
    // face's alignment worked out once.
    let alignment = FRAMES.map(|[n, _, _]| dot(d, n));
    let mut face = 0;
    for f in 1..FRAMES.len() {
        if alignment[f] > alignment[face] {
            face = f;
        }
    }
    let [n, u, v] = FRAMES[face];
    let along = dot(d, n);
    let to_st = |w: [f64; 3]| {
        let c = CubeWarp::PLANET.from_cube(dot(d, w) / along);
        (0.5 * (c + 1.0)).clamp(0.0, 1.0)
    };
    (face as u8, to_st(u), to_st(v))
}

/// The face coordinates `(s, t)` on `face` of a geodetic latitude and longitude (given as in
/// [`sin_cos_to_face_st`]), extended beyond `[0, 1]` past the face's edges (the ray through
/// the face's plane, warped as inside): equal to [`sin_cos_to_face_st`]'s where `face` is the
/// point's own face. `None` where the point is not in front of the face (its ray never meets
/// the face's plane).
pub fn sin_cos_on_face((sp, cp): (f64, f64), (sl, cl): (f64, f64), face: u8) -> Option<(f64, f64)> {
    let d = [cp * cl, cp * sl, (1.0 - E2) * sp];
    let [n, u, v] = FRAMES[usize::from(face)];
    let along = dot(d, n);
    let to_st = |w: [f64; 3]| 0.5 * (CubeWarp::PLANET.from_cube(dot(d, w) / along) + 1.0);
    (along > 0.0).then(|| (to_st(u), to_st(v)))
}

/// Geodetic latitude and longitude of lattice point `(face, x, y)` of a cube-sphere domain,
/// computed from its canonical point ([`Domain::canonical_point`]) so that every face holding
/// an edge or corner vertex gets bit-identical values. `None` on a plane or off the surface.
pub fn lattice_lat_lon(domain: &Domain, face: u8, x: i64, y: i64) -> Option<LatLon> {
    let cube = domain.cube()?;
    let FacePoint { face, x, y } = domain.canonical_point(face, x, y)?;
    let side = cube.side() as f64;
    Some(face_st_to_lat_lon(face, x as f64 / side, y as f64 / side))
}

#[cfg(test)]
mod tests {
    use super::super::wgs84::Geodetic;
    use super::*;

    fn lcg(seed: &mut u64) -> f64 {
        *seed = seed
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (*seed >> 11) as f64 / (1u64 << 53) as f64
    }

    fn unit(d: [f64; 3]) -> [f64; 3] {
        let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        d.map(|c| c / n)
    }

    /// A face's lattice gives every point's latitude and longitude bit for bit as
    /// `face_st_to_lat_lon` does, on all six faces (the equatorial ones from per-column terms).
    #[test]
    fn face_lattices_are_face_st_to_lat_lon_bit_for_bit() {
        for side in [96i64, 100] {
            for face in 0..6u8 {
                let lattice = FaceLattice::new(face, side);
                assert_eq!(lattice.columns.is_some(), face < 4);
                for y in 0..=side {
                    for x in 0..=side {
                        let want = face_st_to_lat_lon(
                            face,
                            x as f64 / side as f64,
                            y as f64 / side as f64,
                        );
                        let got = lattice.lat_lon(x as usize, y as usize);
                        assert_eq!(
                            (got.lat.to_bits(), got.lon.to_bits()),
                            (want.lat.to_bits(), want.lon.to_bits()),
                            "face {face} ({x}, {y}) of {side}"
                        );
                    }
                }
            }
        }
    }

    /// On a point's own face the extended coordinates are `sin_cos_to_face_st`'s, bit for bit;
    /// on a neighbouring face they lie past its edge, continuing across it, and a face behind
    /// the point has none.
    #[test]
    fn extended_face_coordinates_continue_across_the_edges() {
        let mut seed = 11u64;
        let mut beyond = 0;
        for _ in 0..50_000 {
            let lat = (2.0 * lcg(&mut seed) - 1.0).asin();
            let lon = (-180.0 + 360.0 * lcg(&mut seed)).to_radians();
            let (row, col) = (lat.sin_cos(), lon.sin_cos());
            let (face, s, t) = sin_cos_to_face_st(row, col);
            let (es, et) = sin_cos_on_face(row, col, face).unwrap();
            assert_eq!((es.to_bits(), et.to_bits()), (s.to_bits(), t.to_bits()));
            for other in (0..6u8).filter(|&f| f != face) {
                if let Some((os, ot)) = sin_cos_on_face(row, col, other) {
                    // Past the other face's edge (or on it).
                    let out = |c: f64| !(1e-12..=1.0 - 1e-12).contains(&c);
                    assert!(out(os) || out(ot), "face {other}: ({os}, {ot})");
                    beyond += 1;
                }
            }
        }
        assert!(beyond > 0);
        // Across an edge: a point just inside face 0's edge at s = 1 and one just past it seen
        // from face 0 are a lattice step apart in s.
        let just = |lon: f64| sin_cos_on_face((0.0, 1.0), lon.to_radians().sin_cos(), 0);
        let (s_in, _) = just(44.999).unwrap();
        let (s_out, _) = just(45.001).unwrap();
        assert!(
            s_in < 1.0 && s_out > 1.0 && s_out - s_in < 1e-4,
            "{s_in} {s_out}"
        );
    }

    /// Angle between two geodetic positions on the ellipsoid, degrees (via their normals, so it
    /// is meaningful at the poles where longitude is not).
    fn separation(p: LatLon, q: LatLon) -> f64 {
        let a = Geodetic::new(p.lat, p.lon, 0.0).normal();
        let b = Geodetic::new(q.lat, q.lon, 0.0).normal();
        let cross = [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ];
        let sin = (cross[0] * cross[0] + cross[1] * cross[1] + cross[2] * cross[2]).sqrt();
        let cos = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        sin.atan2(cos).to_degrees()
    }

    fn lon_difference(a: f64, b: f64) -> f64 {
        let d = (a - b).rem_euclid(360.0);
        d.min(360.0 - d)
    }

    #[test]
    fn the_warps_are_inverse_pairs_that_keep_the_edges() {
        for warp in [
            CubeWarp::Gnomonic,
            CubeWarp::EquiAngular,
            CubeWarp::AlgebraicSigmoid,
        ] {
            assert_eq!(warp.to_cube(1.0), 1.0, "{warp:?}");
            assert_eq!(warp.to_cube(-1.0), -1.0, "{warp:?}");
            assert_eq!(warp.to_cube(0.0), 0.0);
            for k in 0..=200 {
                let w = -1.0 + f64::from(k) / 100.0;
                assert!((warp.from_cube(warp.to_cube(w)) - w).abs() < 1e-15);
                if k > 0 {
                    let prev = -1.0 + f64::from(k - 1) / 100.0;
                    assert!(warp.to_cube(w) > warp.to_cube(prev), "monotone");
                }
            }
        }
    }

    #[test]
    fn lat_lon_round_trips_to_1e_9_degrees_everywhere() {
        let mut seed = 7u64;
        let mut samples: Vec<LatLon> = (0..200_000)
            .map(|_| {
                // Uniform on the sphere, not in latitude: asin of a uniform z.
                let z: f64 = 2.0 * lcg(&mut seed) - 1.0;
                LatLon {
                    lat: z.asin().to_degrees(),
                    lon: -180.0 + 360.0 * lcg(&mut seed),
                }
            })
            .collect();
        // Poles, the antimeridian from both sides, face edges and cube corners.
        let corner_lat = (1.0 / (2.0f64.sqrt() * (1.0 - E2))).atan().to_degrees();
        for lon in [
            -180.0,
            -179.999_999_999,
            179.999_999_999,
            180.0,
            -135.0,
            -45.0,
            45.0,
            135.0,
        ] {
            for lat in [
                -90.0,
                -89.999_999,
                -45.0,
                0.0,
                corner_lat,
                -corner_lat,
                89.999_999,
                90.0,
            ] {
                samples.push(LatLon { lat, lon });
            }
        }
        let mut worst = 0.0f64;
        for ll in samples {
            let (face, s, t) = lat_lon_to_face_st(ll);
            assert!((0.0..=1.0).contains(&s) && (0.0..=1.0).contains(&t));
            let back = face_st_to_lat_lon(face, s, t);
            let sep = separation(ll, back);
            worst = worst.max(sep);
            assert!(sep < 1e-9, "{ll:?} -> f{face} ({s}, {t}) -> {back:?}");
            assert!((back.lat - ll.lat).abs() < 1e-9, "{ll:?} -> {back:?}");
            if ll.lat.abs() < 89.9 {
                assert!(
                    lon_difference(back.lon, ll.lon) < 1e-9,
                    "{ll:?} -> {back:?}"
                );
            }
        }
        eprintln!("lat/lon -> face -> lat/lon: worst separation {worst:e}°");
        assert!(worst < 1e-9, "worst {worst:e}°");
        // And face points round-trip the other way (on an edge the face may change, the point
        // may not).
        for face in 0..6u8 {
            for (s, t) in [
                (0.5, 0.5),
                (0.0, 0.3),
                (1.0, 1.0),
                (0.25, 1.0),
                (0.999, 0.001),
            ] {
                let ll = face_st_to_lat_lon(face, s, t);
                let (f2, s2, t2) = lat_lon_to_face_st(ll);
                let a = unit(face_direction(CubeWarp::PLANET, face, s, t));
                let b = unit(face_direction(CubeWarp::PLANET, f2, s2, t2));
                for k in 0..3 {
                    assert!((a[k] - b[k]).abs() < 1e-14, "f{face} ({s}, {t}) -> f{f2}");
                }
                if (0.0 < s && s < 1.0) && (0.0 < t && t < 1.0) {
                    assert_eq!(f2, face);
                    assert!((s - s2).abs() < 1e-14 && (t - t2).abs() < 1e-14);
                }
            }
        }
    }

    #[test]
    fn the_latitude_is_geodetic_at_the_point_where_the_ray_meets_the_ellipsoid() {
        // The point's ECEF position from its geodetic coordinates (a separate formula) lies on
        // the ray and is the ray's intersection with the ellipsoid.
        let mut worst_shift = 0.0f64;
        for face in 0..6u8 {
            for (s, t) in [(0.5, 0.5), (0.1, 0.7), (0.9, 0.05), (0.0, 0.5), (0.5, 0.0)] {
                let ll = face_st_to_lat_lon(face, s, t);
                let on_ray = face_st_to_surface(face, s, t);
                let from_geodetic = Geodetic::new(ll.lat, ll.lon, 0.0).to_ecef();
                for k in 0..3 {
                    assert!(
                        (on_ray[k] - from_geodetic[k]).abs() < 1e-6,
                        "f{face} ({s}, {t}): {on_ray:?} vs {from_geodetic:?}"
                    );
                }
                let d = face_direction(CubeWarp::PLANET, face, s, t);
                let geocentric = d[2].atan2(d[0].hypot(d[1])).to_degrees();
                worst_shift = worst_shift.max((ll.lat - geocentric).abs());
            }
        }
        // Face 0 at (0.5, 0) is at 45° geocentric latitude, where the two latitudes differ
        // most: atan(tan 45°/(1 − e²)) − 45° = 0.1924°.
        eprintln!("geodetic − geocentric latitude, largest on the sample: {worst_shift:.4}°");
        assert!(worst_shift > 0.19, "{worst_shift}");
        // Face centres: the equator at 0°, 90°, 180°, −90° and the poles.
        let centres = [(0.0, 0.0), (0.0, 90.0), (0.0, 180.0), (0.0, -90.0)];
        for (face, (lat, lon)) in centres.into_iter().enumerate() {
            let ll = face_st_to_lat_lon(face as u8, 0.5, 0.5);
            assert!((ll.lat - lat).abs() < 1e-12 && lon_difference(ll.lon, lon) < 1e-12);
        }
        assert_eq!(face_st_to_lat_lon(4, 0.5, 0.5).lat, 90.0);
        assert_eq!(face_st_to_lat_lon(5, 0.5, 0.5).lat, -90.0);
        // x runs east on the belt, y south.
        let a = face_st_to_lat_lon(0, 0.6, 0.5);
        let b = face_st_to_lat_lon(0, 0.5, 0.6);
        assert!(a.lon > 0.0 && b.lat < 0.0);
    }

    /// Area of the spherical triangle of three unit vectors (Van Oosterom & Strackee 1983).
    fn spherical_triangle(a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> f64 {
        let dot = |p: [f64; 3], q: [f64; 3]| p[0] * q[0] + p[1] * q[1] + p[2] * q[2];
        let cross = [
            b[1] * c[2] - b[2] * c[1],
            b[2] * c[0] - b[0] * c[2],
            b[0] * c[1] - b[1] * c[0],
        ];
        2.0 * dot(a, cross)
            .abs()
            .atan2(1.0 + dot(a, b) + dot(b, c) + dot(c, a))
    }

    /// (max/min cell area, total area / 4π) of a 128 × 128-cell face lattice on the unit
    /// sphere; all faces are congruent, so one face gives the ratio of the whole sphere.
    fn cell_area_ratio(warp: CubeWarp) -> (f64, f64) {
        let m = 128;
        let p = |i: usize, j: usize| {
            unit(face_direction(
                warp,
                0,
                i as f64 / m as f64,
                j as f64 / m as f64,
            ))
        };
        let (mut lo, mut hi, mut total) = (f64::MAX, 0.0f64, 0.0);
        for i in 0..m {
            for j in 0..m {
                let area = spherical_triangle(p(i, j), p(i + 1, j), p(i + 1, j + 1))
                    + spherical_triangle(p(i, j), p(i + 1, j + 1), p(i, j + 1));
                lo = lo.min(area);
                hi = hi.max(area);
                total += area;
            }
        }
        (hi / lo, 6.0 * total / (4.0 * std::f64::consts::PI))
    }

    #[test]
    fn cells_on_the_ellipsoid_are_as_even_at_the_poles_as_at_the_equator() {
        // All six faces of a 64²-cell lattice on WGS84 (cells as two flat triangles between
        // surface points): the pole faces 4 and 5 hold the same cells as the belt, no
        // singularity, no stretched cells at the poles or along the antimeridian (face 2).
        let m = 64;
        let mut per_face = Vec::new();
        for face in 0..6u8 {
            let p = |i: usize, j: usize| {
                face_st_to_surface(face, i as f64 / m as f64, j as f64 / m as f64)
            };
            let tri = |a: [f64; 3], b: [f64; 3], c: [f64; 3]| {
                let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
                let v = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
                let x = [
                    u[1] * v[2] - u[2] * v[1],
                    u[2] * v[0] - u[0] * v[2],
                    u[0] * v[1] - u[1] * v[0],
                ];
                0.5 * (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt()
            };
            let (mut lo, mut hi) = (f64::MAX, 0.0f64);
            for i in 0..m {
                for j in 0..m {
                    let area = tri(p(i, j), p(i + 1, j), p(i + 1, j + 1))
                        + tri(p(i, j), p(i + 1, j + 1), p(i, j + 1));
                    lo = lo.min(area);
                    hi = hi.max(area);
                }
            }
            per_face.push((lo, hi));
        }
        let lo = per_face.iter().map(|f| f.0).fold(f64::MAX, f64::min);
        let hi = per_face.iter().map(|f| f.1).fold(0.0, f64::max);
        eprintln!(
            "max/min cell area on WGS84, 64² cells per face, all faces: {:.4}",
            hi / lo
        );
        assert!(hi / lo < 1.3, "{}", hi / lo);
        // The pole faces' largest and smallest cells are within 1 % of the belt's.
        for f in [4, 5] {
            assert!((per_face[f].1 / per_face[0].1 - 1.0).abs() < 0.01);
            assert!((per_face[f].0 / per_face[0].0 - 1.0).abs() < 0.01);
        }
    }

    #[test]
    fn cell_area_ratios_on_the_sphere() {
        let gnomonic = cell_area_ratio(CubeWarp::Gnomonic);
        let equi = cell_area_ratio(CubeWarp::EquiAngular);
        let sigmoid = cell_area_ratio(CubeWarp::AlgebraicSigmoid);
        eprintln!(
            "max/min cell area, 128² cells per face: gnomonic {:.4}, equi-angular {:.4}, \
             algebraic sigmoid (c = 0.87) {:.4}",
            gnomonic.0, equi.0, sigmoid.0
        );
        for (ratio, cover) in [gnomonic, equi, sigmoid] {
            assert!(
                (cover - 1.0).abs() < 1e-12,
                "six faces cover the sphere once"
            );
            assert!(ratio > 1.0);
        }
        // The gnomonic cube's limit is 3√3 ≈ 5.196 (centre cell against corner cell).
        assert!(gnomonic.0 > 5.0 && gnomonic.0 < 3.0 * 3f64.sqrt());
        assert!(equi.0 > 1.35 && equi.0 < 1.45);
        assert!(sigmoid.0 > 1.2 && sigmoid.0 < 1.3);
        assert!(sigmoid.0 < equi.0 && equi.0 < gnomonic.0);
    }
}
