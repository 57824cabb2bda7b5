//! Interactive camera controllers of `cbdam view`, independent of any windowing library: the
//! window maps its mouse and keyboard events onto these calls.
//!
//! - **Orbit** (default): the eye circles a target point; dragging rotates (azimuth and
//!   elevation), the wheel zooms (distance), panning moves the target in the horizontal plane.
//!   The elevation stays between [`MIN_PITCH`] and [`MAX_PITCH`], so the eye is always above the
//!   target and never flips over the pole.
//! - **Fly**: the eye moves along the look direction (forward/back), sideways and vertically;
//!   the mouse turns the look direction.
//!
//! Speeds and distances are fractions of the data's horizontal extent, so a 1 km tile and a
//! continent feel the same.
//!
//! On a planet the orbit circles the globe's centre (elevation is latitude-like, from −89° to
//! 89°, north up), and the fly camera works in the local frame under the eye: its heading and
//! pitch are measured from the local east-north-up frame, "up" moves along the ellipsoid normal
//! and speeds scale with the height above the ellipsoid, so the horizon stays level from orbit
//! to the ground.

use glam::DVec3;

use crate::camera::Camera;
use crate::world::World;

/// Lowest orbit elevation above the target's horizon, radians (2°).
pub const MIN_PITCH: f64 = 2.0 * std::f64::consts::PI / 180.0;
/// Highest orbit elevation, radians (89°: straight down would make the azimuth undefined).
pub const MAX_PITCH: f64 = 89.0 * std::f64::consts::PI / 180.0;
/// Radians of rotation per pixel dragged.
pub const TURN_PER_PIXEL: f64 = 0.005;
/// Zoom factor per wheel step.
pub const ZOOM_STEP: f64 = 0.85;
/// Fly speed in extents per second, and its factor while Shift is held.
const FLY_SPEED: f64 = 0.1;
/// Multiplier of the fly speed with Shift held.
pub const FAST: f64 = 5.0;

/// Which controller is active.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// Circle a target point.
    Orbit,
    /// Free flight.
    Fly,
}

/// Movement keys held this frame, each −1, 0 or 1 (opposite keys cancel).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Movement {
    /// Forward (W) minus back (S).
    pub forward: f64,
    /// Right (D) minus left (A).
    pub right: f64,
    /// Up minus down.
    pub up: f64,
    /// Shift held.
    pub fast: bool,
}

/// The viewer's camera state in both modes.
#[derive(Clone, Debug, PartialEq)]
pub struct Controls {
    mode: Mode,
    /// Orbit: the point circled; fly: unused.
    target: DVec3,
    /// Orbit: eye–target distance, metres.
    distance: f64,
    /// Azimuth of the view direction, radians: 0 looks north, π/2 east.
    yaw: f64,
    /// Orbit: elevation of the eye above the target's horizon; fly: of the view direction.
    pitch: f64,
    /// Fly: eye position.
    eye: DVec3,
    fov_y: f64,
    /// Horizontal extent of the data, metres (speeds, zoom limits).
    extent: f64,
    /// Where [`Controls::reset`] returns to.
    home: (DVec3, DVec3),
    /// Whether the world is a planet (ECEF, local frames under the eye).
    planet: bool,
}

impl Controls {
    /// Orbit controls starting from `start` (e.g. [`Camera::overview`]): its target is the orbit
    /// centre and its eye the orbit position.
    pub fn new(world: &World, start: &Camera) -> Self {
        let (lo, hi) = world.bounds();
        let extent = (hi.x - lo.x).max(hi.y - lo.y).max(1.0);
        let mut me = Self {
            mode: Mode::Orbit,
            target: start.target,
            distance: 1.0,
            yaw: 0.0,
            pitch: 0.0,
            eye: start.eye,
            fov_y: start.fov_y,
            extent,
            home: (start.eye, start.target),
            planet: world.is_planet(),
        };
        me.orbit_from(start.eye, start.target);
        me
    }

    /// The active mode.
    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// Back to the starting view, in orbit mode.
    pub fn reset(&mut self) {
        let (eye, target) = self.home;
        self.mode = Mode::Orbit;
        self.orbit_from(eye, target);
    }

    /// Switches orbit ↔ fly without moving the eye or turning the view. Leaving fly mode, the
    /// new orbit target is where the view ray meets the horizontal plane of the old target (or,
    /// looking above the horizon, a point at the old orbit distance).
    pub fn toggle_mode(&mut self) {
        match self.mode {
            Mode::Orbit if self.planet => {
                // The same view direction, as heading and pitch in the frame under the eye.
                let dir = self.look_dir();
                self.eye = self.eye();
                let (east, north, up) = local_frame(self.eye);
                self.pitch = dir.dot(up).clamp(-1.0, 1.0).asin();
                self.yaw = dir.dot(east).atan2(dir.dot(north));
                self.mode = Mode::Fly;
            }
            Mode::Orbit => {
                self.eye = self.eye();
                self.pitch = -self.pitch;
                self.mode = Mode::Fly;
            }
            Mode::Fly if self.planet => {
                self.mode = Mode::Orbit;
                self.orbit_from(self.eye, DVec3::ZERO);
            }
            Mode::Fly => {
                let dir = self.look_dir();
                let down = -dir.z;
                let along = if down > 1e-3 {
                    ((self.eye.z - self.target.z) / down)
                        .clamp(self.extent * 1e-4, self.extent * 10.0)
                } else {
                    self.distance
                };
                let target = self.eye + dir * along;
                self.mode = Mode::Orbit;
                self.orbit_from(self.eye, target);
            }
        }
    }

    /// Mouse dragged with the rotate button (orbit) or any button (fly look), pixels.
    pub fn rotate(&mut self, dx: f64, dy: f64) {
        self.yaw += dx * TURN_PER_PIXEL;
        match self.mode {
            // Dragging down raises the eye, as if pulling the terrain towards the viewer.
            Mode::Orbit => {
                self.pitch = (self.pitch + dy * TURN_PER_PIXEL).clamp(self.min_pitch(), MAX_PITCH)
            }
            Mode::Fly => {
                self.pitch = (self.pitch - dy * TURN_PER_PIXEL).clamp(-MAX_PITCH, MAX_PITCH)
            }
        }
    }

    /// Mouse dragged with the pan button, pixels, in a viewport `height` pixels high: the
    /// target moves horizontally so the terrain under the cursor follows it (orbit only).
    pub fn pan(&mut self, dx: f64, dy: f64, height: u32) {
        if self.mode != Mode::Orbit {
            return;
        }
        let metres_per_pixel =
            2.0 * (self.fov_y / 2.0).tan() * self.distance / f64::from(height.max(1));
        let (s, c) = self.yaw.sin_cos();
        let right = DVec3::new(c, -s, 0.0);
        let forward = DVec3::new(s, c, 0.0);
        self.target += (-right * dx + forward * dy) * metres_per_pixel;
    }

    /// Wheel turned by `steps` (positive: towards the terrain). Orbit zooms within 10⁻⁴ to 10
    /// extents; fly moves forward by a fraction of the extent.
    pub fn zoom(&mut self, steps: f64) {
        match self.mode {
            Mode::Orbit => {
                self.distance = (self.distance * ZOOM_STEP.powf(steps))
                    .clamp(self.extent * 1e-4, self.extent * 10.0)
            }
            Mode::Fly => self.eye += self.look_dir() * steps * self.fly_scale() * 0.02,
        }
    }

    /// Lowest orbit elevation: [`MIN_PITCH`] above a plane, −[`MAX_PITCH`] around a globe.
    fn min_pitch(&self) -> f64 {
        if self.planet { -MAX_PITCH } else { MIN_PITCH }
    }

    /// Metres that fly speeds are fractions of: the data's extent on a plane; on a planet the
    /// eye's height above the ellipsoid (at least 50 m), so flying slows towards the ground.
    fn fly_scale(&self) -> f64 {
        if self.planet {
            let h = cbdam_codec::geodesy::Geodetic::from_ecef(self.eye.to_array()).height;
            h.max(50.0)
        } else {
            self.extent
        }
    }

    /// Applies held movement keys for `dt` seconds (fly mode; in orbit mode they move the target
    /// horizontally, like panning).
    pub fn update(&mut self, m: Movement, dt: f64) {
        let fast = if m.fast { FAST } else { 1.0 };
        let speed = FLY_SPEED * self.extent * fast * dt;
        let (s, c) = self.yaw.sin_cos();
        let right = DVec3::new(c, -s, 0.0);
        match self.mode {
            Mode::Fly if self.planet => {
                let (east, north, up) = local_frame(self.eye);
                let right = east * c - north * s;
                let speed = FLY_SPEED * self.fly_scale() * fast * dt;
                self.eye += (self.look_dir() * m.forward + right * m.right + up * m.up) * speed;
            }
            Mode::Fly => {
                self.eye +=
                    (self.look_dir() * m.forward + right * m.right + DVec3::Z * m.up) * speed
            }
            Mode::Orbit => {
                let forward = DVec3::new(s, c, 0.0);
                // Scaled by the distance so moving close up is not a jump across the map.
                let k = speed * (self.distance / self.extent).min(1.0);
                self.target += (forward * m.forward + right * m.right + DVec3::Z * m.up) * k;
            }
        }
    }

    /// The eye position.
    pub fn eye(&self) -> DVec3 {
        match self.mode {
            Mode::Orbit => {
                let (sy, cy) = self.yaw.sin_cos();
                let (sp, cp) = self.pitch.sin_cos();
                // The eye is behind the target, opposite the view direction's azimuth.
                self.target + DVec3::new(-sy * cp, -cy * cp, sp) * self.distance
            }
            Mode::Fly => self.eye,
        }
    }

    /// Unit view direction.
    pub fn look_dir(&self) -> DVec3 {
        match self.mode {
            Mode::Orbit => (self.target - self.eye()).normalize(),
            Mode::Fly if self.planet => {
                let (sy, cy) = self.yaw.sin_cos();
                let (sp, cp) = self.pitch.sin_cos();
                let (east, north, up) = local_frame(self.eye);
                east * (sy * cp) + north * (cy * cp) + up * sp
            }
            Mode::Fly => {
                let (sy, cy) = self.yaw.sin_cos();
                let (sp, cp) = self.pitch.sin_cos();
                DVec3::new(sy * cp, cy * cp, sp)
            }
        }
    }

    /// The orbit target (orbit mode) or a point ahead of the eye (fly mode).
    pub fn target(&self) -> DVec3 {
        match self.mode {
            Mode::Orbit => self.target,
            Mode::Fly => self.eye + self.look_dir() * self.distance,
        }
    }

    /// The camera for a viewport of `size` pixels (near and far planes as [`Camera::looking_at`]
    /// chooses them for `world`).
    pub fn camera(&self, world: &World, size: (u32, u32)) -> Camera {
        Camera::looking_at(world, self.eye(), self.target(), self.fov_y, size)
    }

    fn orbit_from(&mut self, eye: DVec3, target: DVec3) {
        let d = eye - target;
        self.target = target;
        self.distance = d.length().max(self.extent * 1e-4);
        let horizontal = d.x.hypot(d.y);
        self.pitch = d.z.atan2(horizontal).clamp(self.min_pitch(), MAX_PITCH);
        self.yaw = if horizontal > 0.0 {
            (-d.x).atan2(-d.y)
        } else {
            0.0
        };
    }
}

/// East, north and up (the ellipsoid normal) at the point under ECEF position `p`.
fn local_frame(p: DVec3) -> (DVec3, DVec3, DVec3) {
    let g = cbdam_codec::geodesy::Geodetic::from_ecef(p.to_array());
    let (sp, cp) = g.lat.to_radians().sin_cos();
    let (sl, cl) = g.lon.to_radians().sin_cos();
    (
        DVec3::new(-sl, cl, 0.0),
        DVec3::new(-sp * cl, -sp * sl, cp),
        DVec3::new(cp * cl, cp * sl, sp),
    )
}

/// The pixel-error target's steps: `+` halves it (finer), `-` doubles it (coarser), within
/// 1/64 to 256 pixels.
pub fn finer(pixel_error: f64) -> f64 {
    (pixel_error / 2.0).max(1.0 / 64.0)
}

/// See [`finer`].
pub fn coarser(pixel_error: f64) -> f64 {
    (pixel_error * 2.0).min(256.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use cbdam_codec::geometry::Domain;

    fn world() -> World {
        World::planar(
            Domain::covering(65, 1000, 800, 0).unwrap(),
            (30.0, 30.0),
            1.0,
            0.0,
            (100.0, 2500.0),
        )
    }

    fn close(a: DVec3, b: DVec3, tol: f64) -> bool {
        (a - b).length() <= tol
    }

    /// Around a planet: the orbit reaches the southern hemisphere; switching to fly keeps the
    /// view direction; flying up moves along the local normal (latitude and longitude stay) and
    /// slower near the ground; a fly camera looking ahead keeps the horizon level.
    #[test]
    fn planet_controls_orbit_the_globe_and_fly_with_the_local_up() {
        use cbdam_codec::geodesy::Geodetic;
        let w = World::planet(Domain::cube_sphere(5, 2).unwrap(), 1.0, 0.0, (0.0, 1000.0));
        let mut c = Controls::new(&w, &Camera::globe(&w, (800, 600)));
        c.rotate(0.0, -20000.0);
        assert!(c.eye().z < -1e6, "orbit reaches the south: {}", c.eye());
        c.rotate(0.0, 20000.0 - 2000.0);
        let dir = c.look_dir();
        c.toggle_mode();
        assert!(close(c.look_dir(), dir, 1e-9), "{} vs {dir}", c.look_dir());
        let before = Geodetic::from_ecef(c.eye().to_array());
        c.update(
            Movement {
                up: 1.0,
                ..Default::default()
            },
            1.0,
        );
        let after = Geodetic::from_ecef(c.eye().to_array());
        assert!((after.lat - before.lat).abs() < 1e-9 && (after.lon - before.lon).abs() < 1e-9);
        let climbed = after.height - before.height;
        assert!((climbed - FLY_SPEED * before.height).abs() < 1e-3 * climbed);
        // Look ahead at a level pitch: the camera's screen right is horizontal.
        c.rotate(0.0, (c.pitch + 0.1) / TURN_PER_PIXEL);
        assert!((c.pitch + 0.1).abs() < 1e-9, "{}", c.pitch);
        let cam = c.camera(&w, (800, 600));
        let right = cam.view().row(0).truncate();
        assert!(right.dot(w.up(cam.eye)).abs() < 1e-9);
        c.toggle_mode();
        assert_eq!(c.mode(), Mode::Orbit);
        assert!(close(c.target(), DVec3::ZERO, 1e-9));
    }

    #[test]
    fn starts_at_the_given_view_and_resets_to_it() {
        let w = world();
        let start = Camera::overview(&w, (800, 600));
        let mut c = Controls::new(&w, &start);
        assert!(
            close(c.eye(), start.eye, 1e-6 * c.extent),
            "{} vs {}",
            c.eye(),
            start.eye
        );
        assert!(close(c.target(), start.target, 1e-9));
        c.rotate(300.0, -40.0);
        c.zoom(3.0);
        c.toggle_mode();
        c.update(
            Movement {
                forward: 1.0,
                ..Default::default()
            },
            1.0,
        );
        assert!(!close(c.eye(), start.eye, 1.0));
        c.reset();
        assert_eq!(c.mode(), Mode::Orbit);
        assert!(close(c.eye(), start.eye, 1e-6 * c.extent));
    }

    #[test]
    fn orbit_stays_above_and_around_the_target() {
        let w = world();
        let mut c = Controls::new(&w, &Camera::overview(&w, (800, 600)));
        let target = c.target();
        let distance = (c.eye() - target).length();
        for (dx, dy) in [
            (500.0, 0.0),
            (0.0, 10_000.0),
            (-123.0, -10_000.0),
            (77.0, 31.0),
        ] {
            c.rotate(dx, dy);
            let eye = c.eye();
            // Rotating neither moves the target nor changes the distance.
            assert!(close(c.target(), target, 1e-9));
            assert!(((eye - target).length() - distance).abs() < 1e-6 * distance);
            // The eye stays above the target, within the pitch limits.
            let elevation = ((eye.z - target.z) / (eye - target).length()).asin();
            assert!(
                (MIN_PITCH - 1e-9..=MAX_PITCH + 1e-9).contains(&elevation),
                "elevation {elevation}"
            );
            // And the camera looks at the target.
            assert!(close(c.look_dir(), (target - eye).normalize(), 1e-9));
        }
        // Zooming in brings the eye closer along the same ray, never through the target.
        let dir = c.look_dir();
        c.zoom(1000.0);
        let d = (c.eye() - target).length();
        assert!(d > 0.0 && d < distance);
        assert!(close(c.look_dir(), dir, 1e-9));
        assert!(c.eye().z > target.z);
    }

    #[test]
    fn fly_moves_in_the_look_direction() {
        let w = world();
        let mut c = Controls::new(&w, &Camera::overview(&w, (800, 600)));
        let look = c.look_dir();
        c.toggle_mode();
        assert_eq!(c.mode(), Mode::Fly);
        // Switching does not turn the view.
        assert!(
            close(c.look_dir(), look, 1e-9),
            "{} vs {look}",
            c.look_dir()
        );
        let before = c.eye();
        c.update(
            Movement {
                forward: 1.0,
                ..Default::default()
            },
            0.5,
        );
        let step = c.eye() - before;
        assert!(step.length() > 0.0);
        assert!(close(step.normalize(), c.look_dir(), 1e-9));
        // Shift is faster by FAST.
        let before = c.eye();
        c.update(
            Movement {
                forward: 1.0,
                fast: true,
                ..Default::default()
            },
            0.5,
        );
        assert!(((c.eye() - before).length() / step.length() - FAST).abs() < 1e-9);
        // Strafing is horizontal and perpendicular to the view.
        let before = c.eye();
        c.update(
            Movement {
                right: 1.0,
                ..Default::default()
            },
            0.5,
        );
        let side = c.eye() - before;
        assert!(side.z.abs() < 1e-9 && side.dot(c.look_dir()).abs() < 1e-6 * side.length());
        // Up is straight up.
        let before = c.eye();
        c.update(
            Movement {
                up: 1.0,
                ..Default::default()
            },
            0.5,
        );
        assert!(close((c.eye() - before).normalize(), DVec3::Z, 1e-12));
        // Turning right (drag right) turns the look direction clockwise seen from above.
        let l0 = c.look_dir();
        c.rotate(50.0, 0.0);
        let l1 = c.look_dir();
        assert!(l0.x * l1.y - l0.y * l1.x < 0.0);
    }

    #[test]
    fn back_to_orbit_keeps_the_view() {
        let w = world();
        let mut c = Controls::new(&w, &Camera::overview(&w, (800, 600)));
        c.toggle_mode();
        c.update(
            Movement {
                forward: 1.0,
                right: 0.5,
                ..Default::default()
            },
            0.3,
        );
        let (eye, look) = (c.eye(), c.look_dir());
        c.toggle_mode();
        assert_eq!(c.mode(), Mode::Orbit);
        assert!(close(c.eye(), eye, 1e-6 * c.extent));
        assert!(close(c.look_dir(), look, 1e-6));
    }

    #[test]
    fn pixel_error_keys_halve_and_double() {
        assert_eq!(finer(1.0), 0.5);
        assert_eq!(coarser(1.0), 2.0);
        assert_eq!(coarser(finer(3.0)), 3.0);
        assert_eq!(finer(1.0 / 64.0), 1.0 / 64.0);
        assert_eq!(coarser(256.0), 256.0);
    }
}
