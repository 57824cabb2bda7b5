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
    /// Keyframes, by increasing time.
    pub keyframes: Vec<Keyframe>,
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
        if self.keyframes.len() < 2 {
            return bad("a flight needs at least two keyframes".into());
        }
        if !(self.fov_deg > 1.0 && self.fov_deg < 179.0) {
            return bad(format!("fov_deg {} is not between 1 and 179", self.fov_deg));
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

    /// Time of the last keyframe (the first is usually 0).
    pub fn duration(&self) -> f64 {
        self.keyframes.last().map_or(0.0, |k| k.t)
    }

    /// Eye and target at time `t`, relative coordinates.
    pub fn pose(&self, t: f64) -> ([f64; 3], [f64; 3]) {
        let k = &self.keyframes;
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

    /// The camera at time `t` over `world`, for a `size` viewport.
    pub fn camera(&self, world: &World, t: f64, size: (u32, u32)) -> Camera {
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

fn catmull_rom(a: [f64; 3], b: [f64; 3], c: [f64; 3], d: [f64; 3], u: f64) -> [f64; 3] {
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
            "not json",
        ] {
            assert!(Flight::parse(bad).is_err(), "{bad}");
        }
    }
}
