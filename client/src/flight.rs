//! Camera flights: keyframed paths given relative to a repository's extent, so one path flies
//! over any repository.
//!
//! # Format (JSON)
//!
//! ```json
//! {
//!   "description": "a low pass",
//!   "fov_deg": 45,
//!   "keyframes": [
//!     { "t": 0.0, "eye": [0.1, 0.2, 1.5], "target": [0.5, 0.5, 0.3] },
//!     { "t": 4.0, "eye": [0.9, 0.8, 1.2], "target": [0.6, 0.9, 0.2] }
//!   ]
//! }
//! ```
//!
//! - `t`: seconds, strictly increasing, at least two keyframes.
//! - `eye`, `target`: `[x, y, z]` relative to the data: `x` from 0 (west edge of the data
//!   rectangle) to 1 (east edge), `y` from 0 (south edge) to 1 (north edge); values outside
//!   0..1 lie outside the data. `z` relative to the data's height range: 0 is the lowest height,
//!   1 the highest, above 1 is above every peak (a flat dataset counts as 1 m of range).
//! - `fov_deg`: vertical field of view, degrees (optional, default 45).
//! - `description`: free text (optional).
//!
//! Between keyframes eye and target follow uniform Catmull-Rom splines through the keyframe
//! positions (the end keyframes are repeated as their own neighbours), so the path is smooth
//! (continuous velocity at the keyframes) and passes through every keyframe exactly. Before the
//! first keyframe and after the last the camera holds still.
//!
//! # Planets: geodetic keyframes
//!
//! A flight over a planet gives `"geodetic"` keyframes instead of `"keyframes"`:
//!
//! ```json
//! { "geodetic": [
//!     { "t": 0,  "lat": 20, "lon": 30, "height_m": 12000000, "heading_deg": 0, "pitch_deg": -90 },
//!     { "t": 10, "lat": 40.4, "lon": 40.4, "height_m": 4000, "heading_deg": 30, "pitch_deg": -25 }
//! ] }
//! ```
//!
//! - `lat`, `lon`: geodetic degrees on WGS84 (latitude −90…90; longitude any, taken modulo
//!   360°, the path turning the short way round between keyframes).
//! - `height_m`: metres above the ellipsoid.
//! - `heading_deg`: clockwise from north (optional, default 0, the short way round between
//!   keyframes); `pitch_deg`: negative looking down, −90…90 (optional, default −30).
//!
//! The same splines run through latitude, unwrapped longitude, height, heading and pitch; the
//! camera at each time is the geodetic camera of `cbdam render --geo`.

use std::path::Path;

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::camera::Camera;
use crate::world::World;

/// Why a flight could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum FlightError {
    /// Reading the file failed.
    // The messages include the cause, so it is not also the `source` (chains would print it
    // twice).
    #[error("reading the flight: {0}")]
    Io(std::io::Error),
    /// The JSON does not match the format.
    #[error("flight JSON: {0}")]
    Json(serde_json::Error),
    /// The values are unusable.
    #[error("invalid flight: {0}")]
    Invalid(String),
}

impl From<std::io::Error> for FlightError {
    fn from(e: std::io::Error) -> Self {
        FlightError::Io(e)
    }
}

impl From<serde_json::Error> for FlightError {
    fn from(e: serde_json::Error) -> Self {
        FlightError::Json(e)
    }
}

/// One keyframe.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Keyframe {
    /// Time, seconds.
    pub t: f64,
    /// Eye, relative coordinates (see the module documentation).
    pub eye: [f64; 3],
    /// Point looked at, relative coordinates.
    pub target: [f64; 3],
}

/// A camera path.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Flight {
    /// Free text.
    #[serde(default)]
    pub description: String,
    /// Vertical field of view, degrees.
    #[serde(default = "default_fov")]
    pub fov_deg: f64,
    /// Keyframes, by increasing time (relative form; empty for a geodetic flight).
    #[serde(default)]
    pub keyframes: Vec<Keyframe>,
    /// Geodetic keyframes, by increasing time (planets; empty for a relative flight).
    #[serde(default)]
    pub geodetic: Vec<GeoKeyframe>,
}

/// One keyframe of a flight over a planet (see the module documentation).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GeoKeyframe {
    /// Time, seconds.
    pub t: f64,
    /// Geodetic latitude, degrees north.
    pub lat: f64,
    /// Longitude, degrees east.
    pub lon: f64,
    /// Metres above the WGS84 ellipsoid.
    pub height_m: f64,
    /// Degrees clockwise from north.
    #[serde(default)]
    pub heading_deg: f64,
    /// Degrees above the horizontal (negative: looking down).
    #[serde(default = "default_pitch")]
    pub pitch_deg: f64,
}

fn default_pitch() -> f64 {
    -30.0
}

/// A geodetic camera pose: where the eye is and which way it looks.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GeoPose {
    /// Degrees north.
    pub lat: f64,
    /// Degrees east, in (−180, 180].
    pub lon: f64,
    /// Metres above the ellipsoid.
    pub height_m: f64,
    /// Degrees clockwise from north, in [0, 360).
    pub heading_deg: f64,
    /// Degrees above the horizontal.
    pub pitch_deg: f64,
}

fn default_fov() -> f64 {
    45.0
}

impl Flight {
    /// Parses and validates a flight.
    pub fn parse(json: &str) -> Result<Self, FlightError> {
        let f: Flight = serde_json::from_str(json)?;
        f.validate()?;
        Ok(f)
    }

    /// Loads a flight file.
    pub fn load(path: &Path) -> Result<Self, FlightError> {
        Self::parse(&std::fs::read_to_string(path)?)
    }

    fn validate(&self) -> Result<(), FlightError> {
        let bad = |m: String| Err(FlightError::Invalid(m));
        if !(self.fov_deg > 1.0 && self.fov_deg < 179.0) {
            return bad(format!("fov_deg {} is not between 1 and 179", self.fov_deg));
        }
        if !self.geodetic.is_empty() {
            return self.validate_geodetic();
        }
        if self.keyframes.len() < 2 {
            return bad("a flight needs at least two keyframes".into());
        }
        for (i, k) in self.keyframes.iter().enumerate() {
            let finite = k.t.is_finite() && k.eye.iter().chain(&k.target).all(|v| v.is_finite());
            if !finite {
                return bad(format!("keyframe {i} has a non-finite value"));
            }
            if k.eye == k.target {
                return bad(format!("keyframe {i}: eye and target coincide"));
            }
            if i > 0 && k.t <= self.keyframes[i - 1].t {
                return bad(format!("keyframe {i}: times must increase"));
            }
        }
        Ok(())
    }

    fn validate_geodetic(&self) -> Result<(), FlightError> {
        let bad = |m: String| Err(FlightError::Invalid(m));
        if !self.keyframes.is_empty() {
            return bad(
                "a flight has either \"keyframes\" or \"geodetic\" keyframes, not both".into(),
            );
        }
        if self.geodetic.len() < 2 {
            return bad("a flight needs at least two keyframes".into());
        }
        for (i, k) in self.geodetic.iter().enumerate() {
            let values = [k.t, k.lat, k.lon, k.height_m, k.heading_deg, k.pitch_deg];
            if !values.iter().all(|v| v.is_finite()) {
                return bad(format!("geodetic keyframe {i} has a non-finite value"));
            }
            if !(-90.0..=90.0).contains(&k.lat) {
                return bad(format!(
                    "geodetic keyframe {i}: latitude {} is not in −90…90",
                    k.lat
                ));
            }
            if !(-90.0..=90.0).contains(&k.pitch_deg) {
                return bad(format!(
                    "geodetic keyframe {i}: pitch {} is not in −90…90",
                    k.pitch_deg
                ));
            }
            if i > 0 && k.t <= self.geodetic[i - 1].t {
                return bad(format!("geodetic keyframe {i}: times must increase"));
            }
        }
        Ok(())
    }

    /// Whether the keyframes are geodetic (a planet's flight).
    pub fn is_geodetic(&self) -> bool {
        !self.geodetic.is_empty()
    }

    /// The geodetic pose at time `t` (a geodetic flight; `None` for a relative one).
    /// Longitudes and headings are unwrapped along the keyframes, so the path turns the short
    /// way round, then interpolated like relative keyframes.
    pub fn geo_pose(&self, t: f64) -> Option<GeoPose> {
        let k = &self.geodetic;
        if k.is_empty() {
            return None;
        }
        // Unwrapped values: each longitude and heading within 180° of the previous one.
        let mut lon = Vec::with_capacity(k.len());
        let mut heading = Vec::with_capacity(k.len());
        for (i, f) in k.iter().enumerate() {
            let near = |prev: f64, v: f64| v - 360.0 * ((v - prev) / 360.0).round();
            lon.push(if i == 0 {
                f.lon
            } else {
                near(lon[i - 1], f.lon)
            });
            heading.push(if i == 0 {
                f.heading_deg
            } else {
                near(heading[i - 1], f.heading_deg)
            });
        }
        let values = |i: usize| [k[i].lat, lon[i], k[i].height_m, heading[i], k[i].pitch_deg];
        let last = k.len() - 1;
        let v = if t <= k[0].t {
            values(0)
        } else if t >= k[last].t {
            values(last)
        } else {
            let i = k.partition_point(|f| f.t <= t) - 1;
            let u = (t - k[i].t) / (k[i + 1].t - k[i].t);
            let at = |j: isize| values(j.clamp(0, last as isize) as usize);
            let i = i as isize;
            let (a, b, c, d) = (at(i - 1), at(i), at(i + 1), at(i + 2));
            catmull_rom(a, b, c, d, u)
        };
        let mut lon = v[1] - 360.0 * (v[1] / 360.0).round();
        if lon <= -180.0 {
            lon += 360.0;
        }
        Some(GeoPose {
            lat: v[0].clamp(-90.0, 90.0),
            lon,
            height_m: v[2],
            heading_deg: v[3].rem_euclid(360.0),
            pitch_deg: v[4].clamp(-90.0, 90.0),
        })
    }

    /// Time of the last keyframe (the first is usually 0).
    pub fn duration(&self) -> f64 {
        match self.geodetic.last() {
            Some(k) => k.t,
            None => self.keyframes.last().map_or(0.0, |k| k.t),
        }
    }

    /// Eye and target at time `t`, relative coordinates (a relative flight; a geodetic one has
    /// [`Flight::geo_pose`] and panics here).
    pub fn pose(&self, t: f64) -> ([f64; 3], [f64; 3]) {
        let k = &self.keyframes;
        assert!(!k.is_empty(), "a geodetic flight has no relative pose");
        let last = k.len() - 1;
        if t <= k[0].t {
            return (k[0].eye, k[0].target);
        }
        if t >= k[last].t {
            return (k[last].eye, k[last].target);
        }
        let i = k.partition_point(|f| f.t <= t) - 1;
        let u = (t - k[i].t) / (k[i + 1].t - k[i].t);
        let at = |j: isize| k[j.clamp(0, last as isize) as usize];
        let i = i as isize;
        let (a, b, c, d) = (at(i - 1), at(i), at(i + 1), at(i + 2));
        (
            catmull_rom(a.eye, b.eye, c.eye, d.eye, u),
            catmull_rom(a.target, b.target, c.target, d.target, u),
        )
    }

    /// The camera at time `t` over `world`, for a `size` viewport: a geodetic flight's
    /// [`Camera::geodetic`] (on a plane its latitude and longitude read as world metres, as
    /// `--geo` does), a relative flight's eye and target mapped onto the world's bounds.
    pub fn camera(&self, world: &World, t: f64, size: (u32, u32)) -> Camera {
        if let Some(p) = self.geo_pose(t) {
            return Camera::geodetic(
                world,
                (p.lat, p.lon, p.height_m),
                (p.heading_deg, p.pitch_deg),
                self.fov_deg.to_radians(),
                size,
            );
        }
        let (eye, target) = self.pose(t);
        let (eye, mut target) = (to_world(world, eye), to_world(world, target));
        if (target - eye).length_squared() < 1e-12 {
            // Interpolation can bring them together between keyframes; look ahead instead.
            target = eye + DVec3::new(0.0, 1.0, -0.5);
        }
        Camera::looking_at(world, eye, target, self.fov_deg.to_radians(), size)
    }
}

/// World position of relative coordinates (see the module documentation).
pub fn to_world(world: &World, p: [f64; 3]) -> DVec3 {
    let (lo, hi) = world.bounds();
    let range = (world.max_height - world.min_height).max(1.0);
    DVec3::new(
        lo.x + p[0] * (hi.x - lo.x),
        lo.y + p[1] * (hi.y - lo.y),
        world.min_height + p[2] * range,
    )
}

fn catmull_rom<const N: usize>(
    a: [f64; N],
    b: [f64; N],
    c: [f64; N],
    d: [f64; N],
    u: f64,
) -> [f64; N] {
    let (u2, u3) = (u * u, u * u * u);
    std::array::from_fn(|i| {
        0.5 * (2.0 * b[i]
            + (c[i] - a[i]) * u
            + (2.0 * a[i] - 5.0 * b[i] + 4.0 * c[i] - d[i]) * u2
            + (3.0 * b[i] - a[i] - 3.0 * c[i] + d[i]) * u3)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use cbdam_codec::geometry::Domain;

    const JSON: &str = r#"{ "keyframes": [
        { "t": 0, "eye": [0, 0, 2], "target": [0.5, 0.5, 0] },
        { "t": 1, "eye": [1, 0, 2], "target": [0.5, 0.5, 0] },
        { "t": 3, "eye": [1, 1, 3], "target": [0.5, 0.5, 1] } ] }"#;

    fn world() -> World {
        World::planar(
            Domain::covering(65, 1001, 801, 0).unwrap(),
            (30.0, 20.0),
            1.0,
            0.0,
            (100.0, 300.0),
        )
    }

    #[test]
    fn passes_through_keyframes_and_moves_smoothly() {
        let f = Flight::parse(JSON).unwrap();
        assert_eq!(f.fov_deg, 45.0);
        assert_eq!(f.duration(), 3.0);
        for k in &f.keyframes {
            let (e, t) = f.pose(k.t);
            for i in 0..3 {
                assert!((e[i] - k.eye[i]).abs() < 1e-12 && (t[i] - k.target[i]).abs() < 1e-12);
            }
        }
        assert_eq!(f.pose(-5.0), f.pose(0.0));
        assert_eq!(f.pose(99.0), f.pose(3.0));
        // No jumps: small time steps give small moves, across a keyframe too.
        let mut prev = f.pose(0.0).0;
        for s in 1..=300 {
            let e = f.pose(s as f64 * 0.01).0;
            let d: f64 = (0..3).map(|i| (e[i] - prev[i]).powi(2)).sum::<f64>().sqrt();
            assert!(d < 0.03, "step {s}: {d}");
            prev = e;
        }
    }

    #[test]
    fn relative_coordinates_map_to_the_bounds() {
        let w = world();
        let (lo, hi) = w.bounds();
        assert_eq!(to_world(&w, [0.0, 0.0, 0.0]), DVec3::new(lo.x, lo.y, 100.0));
        assert_eq!(to_world(&w, [1.0, 1.0, 1.0]), DVec3::new(hi.x, hi.y, 300.0));
        // y = 1 is the north edge: lattice row 0, world y = 0.
        assert_eq!(to_world(&w, [0.0, 1.0, 0.0]).y, 0.0);
        let f = Flight::parse(JSON).unwrap();
        let cam = f.camera(&w, 0.0, (640, 480));
        assert_eq!(cam.eye, to_world(&w, [0.0, 0.0, 2.0]));
    }

    const GEO: &str = r#"{ "geodetic": [
        { "t": 0, "lat": 10, "lon": 170, "height_m": 1e7, "heading_deg": 350, "pitch_deg": -90 },
        { "t": 2, "lat": 20, "lon": -170, "height_m": 1e5, "heading_deg": 10 },
        { "t": 4, "lat": 30, "lon": -160, "height_m": 2000, "heading_deg": 20, "pitch_deg": -10 } ] }"#;

    /// Geodetic keyframes pass through every keyframe, cross the antimeridian and north the
    /// short way (170° E → 170° W through 180°, heading 350° → 10° through 0°), and move
    /// smoothly.
    #[test]
    fn geodetic_keyframes_turn_the_short_way() {
        let f = Flight::parse(GEO).unwrap();
        assert!(f.is_geodetic());
        assert_eq!(f.duration(), 4.0);
        let p = f.geo_pose(2.0).unwrap();
        assert!(
            (p.lat - 20.0).abs() < 1e-12 && (p.lon + 170.0).abs() < 1e-12,
            "{p:?}"
        );
        assert_eq!(p.pitch_deg, -30.0);
        let mid = f.geo_pose(1.0).unwrap();
        // Halfway between 170° E and 170° W lies near 180°, not near 0°.
        assert!(mid.lon.abs() > 170.0, "{mid:?}");
        assert!(mid.heading_deg < 15.0 || mid.heading_deg > 345.0, "{mid:?}");
        assert_eq!(f.geo_pose(-1.0), f.geo_pose(0.0));
        let mut prev = f.geo_pose(0.0).unwrap();
        for s in 1..=400 {
            let p = f.geo_pose(s as f64 * 0.01).unwrap();
            let mut dlon = p.lon - prev.lon;
            dlon -= 360.0 * (dlon / 360.0).round();
            assert!(
                (p.lat - prev.lat).abs() < 0.2 && dlon.abs() < 0.3,
                "step {s}: {p:?}"
            );
            prev = p;
        }
        assert!(Flight::parse(JSON).unwrap().geo_pose(0.0).is_none());
    }

    /// A geodetic flight's camera is the geodetic camera of its pose: at the end keyframe the
    /// eye is that latitude, longitude and height on WGS84.
    #[test]
    fn a_geodetic_flight_places_the_eye_on_the_ellipsoid() {
        use cbdam_codec::geodesy::Geodetic;
        let w = World::planet(Domain::cube_sphere(17, 2).unwrap(), 1.0, 0.0, (0.0, 100.0));
        let f = Flight::parse(GEO).unwrap();
        let cam = f.camera(&w, 4.0, (640, 480));
        let g = Geodetic::from_ecef(cam.eye.to_array());
        assert!(
            (g.lat - 30.0).abs() < 1e-9 && (g.lon + 160.0).abs() < 1e-9,
            "{g:?}"
        );
        assert!((g.height - 2000.0).abs() < 1e-6, "{g:?}");
    }

    #[test]
    fn rejects_bad_flights() {
        for bad in [
            r#"{ "keyframes": [ { "t": 0, "eye": [0, 0, 1], "target": [1, 1, 0] } ] }"#,
            r#"{ "keyframes": [ { "t": 1, "eye": [0, 0, 1], "target": [1, 1, 0] },
                                { "t": 1, "eye": [1, 0, 1], "target": [1, 1, 0] } ] }"#,
            r#"{ "keyframes": [ { "t": 0, "eye": [0, 0, 1], "target": [0, 0, 1] },
                                { "t": 1, "eye": [1, 0, 1], "target": [1, 1, 0] } ] }"#,
            r#"{ "fov_deg": 0, "keyframes": [ { "t": 0, "eye": [0, 0, 1], "target": [1, 1, 0] },
                                { "t": 1, "eye": [1, 0, 1], "target": [1, 1, 0] } ] }"#,
            r#"{ "keyframes": [], "extra": 1 }"#,
            r#"{ "geodetic": [ { "t": 0, "lat": 91, "lon": 0, "height_m": 1 },
                               { "t": 1, "lat": 0, "lon": 0, "height_m": 1 } ] }"#,
            r#"{ "geodetic": [ { "t": 0, "lat": 0, "lon": 0, "height_m": 1 } ] }"#,
            r#"{ "geodetic": [ { "t": 0, "lat": 0, "lon": 0, "height_m": 1, "pitch_deg": -95 },
                               { "t": 1, "lat": 0, "lon": 0, "height_m": 1 } ] }"#,
            r#"{ "keyframes": [ { "t": 0, "eye": [0, 0, 1], "target": [1, 1, 0] },
                                { "t": 1, "eye": [1, 0, 1], "target": [1, 1, 0] } ],
                 "geodetic": [ { "t": 0, "lat": 0, "lon": 0, "height_m": 1 },
                               { "t": 1, "lat": 0, "lon": 0, "height_m": 1 } ] }"#,
            "not json",
        ] {
            assert!(Flight::parse(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn every_bundled_flight_loads() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/flights");
        let mut dirs = vec![root];
        let mut loaded = 0;
        while let Some(dir) = dirs.pop() {
            for entry in std::fs::read_dir(&dir).unwrap() {
                let path = entry.unwrap().path();
                if path.is_dir() {
                    dirs.push(path);
                } else if path.extension().is_some_and(|e| e == "json") {
                    let f =
                        Flight::load(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
                    assert!(f.duration() > 0.0, "{}", path.display());
                    // Planet flights are geodetic, plane flights relative.
                    let planet = path.parent().is_some_and(|p| p.ends_with("planet"));
                    assert_eq!(f.is_geodetic(), planet, "{}", path.display());
                    loaded += 1;
                }
            }
        }
        assert!(loaded >= 4, "only {loaded} flights under data/flights");
    }
}
