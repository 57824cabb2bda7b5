//! The perspective camera shared by refinement (frustum culling, screen-space error) and the
//! renderer (projection). World positions are `f64`; what reaches the GPU is relative to the eye
//! (`view_proj_relative`), so large extents do not jitter in `f32`.
//!
//! On a planet (ECEF world positions) cameras have an infinite far plane and **reversed-Z**
//! depth (1 at the near plane, 0 at infinity): float depth is then about as precise at 10 000 km
//! as at 1 m, so the ground seen from orbit and a pebble at the eye's feet share one depth
//! buffer. Planar cameras keep the finite 0..1 projection they always had.

use glam::{DMat4, DVec3, DVec4, Mat4};

use crate::world::World;

/// A perspective camera looking from `eye` at `target`, with `up` up on the screen (z on a
/// plane).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Eye position, world metres.
    pub eye: DVec3,
    /// Point looked at, world metres.
    pub target: DVec3,
    /// The world direction shown up on the screen (projected across the view direction): `+z`
    /// on a plane, the local normal (or north, for a whole globe) on a planet.
    pub up: DVec3,
    /// Vertical field of view, radians.
    pub fov_y: f64,
    /// Viewport width, pixels.
    pub width: u32,
    /// Viewport height, pixels.
    pub height: u32,
    /// Near plane distance, metres.
    pub near: f64,
    /// Far plane distance, metres; infinite for a reversed-Z projection (planets).
    pub far: f64,
}

/// What a globe's default view leaves around the globe: its disc spans this fraction of the
/// frame's shorter side.
const GLOBE_FILL: f64 = 0.9;

impl Camera {
    /// A camera with near and far planes chosen for `world`: far enough to see the whole data
    /// from `eye`, near as large as the eye's height above the data allows (depth precision).
    pub fn looking_at(
        world: &World,
        eye: DVec3,
        target: DVec3,
        fov_y: f64,
        size: (u32, u32),
    ) -> Self {
        if world.is_planet() {
            // The local normal up, so the horizon stays level; looking within ~11° of straight
            // down (a globe orbited from afar, where the normal runs along the view) north up.
            let normal = world.up(eye);
            let down = (target - eye).normalize_or_zero().dot(normal).abs();
            let up = if down > 0.98 { DVec3::Z } else { normal };
            return Self::on_planet(world, eye, target, up, fov_y, size);
        }
        let (lo, hi) = world.bounds();
        let far_corner = DVec3::new(
            if eye.x - lo.x > hi.x - eye.x {
                lo.x
            } else {
                hi.x
            },
            if eye.y - lo.y > hi.y - eye.y {
                lo.y
            } else {
                hi.y
            },
            lo.z,
        );
        let far = (far_corner - eye).length() * 1.5 + 1.0;
        let clearance = (eye.z - hi.z).max(0.0);
        let near = (clearance * 0.5).clamp(far * 1e-6, far * 1e-2).max(0.01);
        Self {
            eye,
            target,
            up: DVec3::Z,
            fov_y,
            width: size.0,
            height: size.1,
            near,
            far,
        }
    }

    /// A planet's camera: reversed-Z with an infinite far plane, the near plane half the eye's
    /// clearance above the highest terrain (at least 0.1 m).
    fn on_planet(
        world: &World,
        eye: DVec3,
        target: DVec3,
        up: DVec3,
        fov_y: f64,
        size: (u32, u32),
    ) -> Self {
        let height = cbdam_codec::geodesy::Geodetic::from_ecef(eye.to_array()).height;
        let clearance = height - world.max_height;
        Self {
            eye,
            target,
            up,
            fov_y,
            width: size.0,
            height: size.1,
            near: (clearance * 0.5).max(0.1),
            far: f64::INFINITY,
        }
    }

    /// The whole globe of a planet, centred, its disc filling most of the frame
    /// ([`GLOBE_FILL`] of the shorter side), seen from above latitude 25° N, longitude 15° E,
    /// north up.
    pub fn globe(world: &World, size: (u32, u32)) -> Self {
        let (_, hi) = world.bounds();
        let radius = hi.x.max(hi.z);
        let fov_y = 45f64.to_radians();
        let aspect = f64::from(size.0) / f64::from(size.1.max(1));
        let half = (fov_y / 2.0).tan() * aspect.min(1.0) * GLOBE_FILL;
        // A sphere of radius r at distance d subtends a half-angle asin(r/d).
        let distance = radius / half.atan().sin();
        let (lat, lon) = (25f64.to_radians(), 15f64.to_radians());
        let dir = DVec3::new(lat.cos() * lon.cos(), lat.cos() * lon.sin(), lat.sin());
        Self::on_planet(world, dir * distance, DVec3::ZERO, DVec3::Z, fov_y, size)
    }

    /// A camera at geodetic `lat`, `lon` (degrees) and `height` metres above the ellipsoid,
    /// looking towards `heading` degrees (clockwise from north) and `pitch` degrees (negative
    /// down), the local normal up on the screen (the heading's direction when looking straight
    /// down or up). On a plane the same angles in the local frame (x east, y north), `lat` and
    /// `lon` read as world y and x metres.
    pub fn geodetic(
        world: &World,
        (lat, lon, height): (f64, f64, f64),
        (heading, pitch): (f64, f64),
        fov_y: f64,
        size: (u32, u32),
    ) -> Self {
        let (east, north, up, eye) = if world.is_planet() {
            let (sp, cp) = lat.to_radians().sin_cos();
            let (sl, cl) = lon.to_radians().sin_cos();
            let eye =
                DVec3::from_array(cbdam_codec::geodesy::Geodetic::new(lat, lon, height).to_ecef());
            (
                DVec3::new(-sl, cl, 0.0),
                DVec3::new(-sp * cl, -sp * sl, cp),
                DVec3::new(cp * cl, cp * sl, sp),
                eye,
            )
        } else {
            (DVec3::X, DVec3::Y, DVec3::Z, DVec3::new(lon, lat, height))
        };
        let (sh, ch) = heading.to_radians().sin_cos();
        let (spi, cpi) = pitch.to_radians().sin_cos();
        let level = north * ch + east * sh;
        let forward = level * cpi + up * spi;
        let screen_up = if cpi.abs() < 1e-6 { level } else { up };
        let target = eye + forward * height.abs().max(100.0);
        let mut cam = Self::looking_at(world, eye, target, fov_y, size);
        cam.up = screen_up;
        cam
    }

    /// An overview of the whole data: from the south, 35° above the horizon, far enough that the
    /// data rectangle fills most of the view.
    pub fn overview(world: &World, size: (u32, u32)) -> Self {
        let (lo, hi) = world.bounds();
        let centre = (lo + hi) * 0.5;
        let radius = ((hi - lo) * DVec3::new(0.5, 0.5, 0.5)).length().max(1.0);
        let fov_y = 45f64.to_radians();
        let aspect = f64::from(size.0) / f64::from(size.1.max(1));
        let half = (fov_y / 2.0).tan().min((fov_y / 2.0).tan() * aspect);
        let distance = radius / half.atan().sin();
        let elevation = 35f64.to_radians();
        let eye = centre + DVec3::new(0.0, -elevation.cos(), elevation.sin()) * distance;
        Self::looking_at(world, eye, centre, fov_y, size)
    }

    /// A view that frames the data: from the south, 55° above the horizon, as close as it can
    /// be with every corner of the data box inside the middle 95 % of the frame, the box
    /// centred vertically in the frame, so the data fills most of it ([`Camera::overview`]
    /// keeps a whole sphere around the box in view, which leaves much of a frame empty). The
    /// first view of the browser, `cbdam render` without `--camera` and `cbdam view`.
    pub fn framed(world: &World, size: (u32, u32)) -> Self {
        if world.is_planet() {
            return Self::globe(world, size);
        }
        const MARGIN: f64 = 0.95;
        let (lo, hi) = world.bounds();
        let fov_y = 45f64.to_radians();
        let elevation = 55f64.to_radians();
        let dir = DVec3::new(0.0, -elevation.cos(), elevation.sin());
        let corners = box_corners(lo, hi);
        let at = |target: DVec3, distance: f64| {
            Self::looking_at(world, target + dir * distance, target, fov_y, size)
        };
        // The corners' vertical extent in normalised device coordinates, when all of them are
        // inside the margin.
        let fits = |target: DVec3, distance: f64| {
            let cam = at(target, distance);
            let m = cam.projection() * cam.view();
            let (mut y0, mut y1) = (f64::MAX, f64::MIN);
            for c in &corners {
                let p = m * c.extend(1.0);
                let (x, y) = (p.x / p.w, p.y / p.w);
                if p.w <= 0.0 || x.abs() > MARGIN || y.abs() > MARGIN {
                    return None;
                }
                y0 = y0.min(y);
                y1 = y1.max(y);
            }
            Some((y0, y1))
        };
        // The closest distance that fits, to a thousandth, for a target.
        let closest = |target: DVec3| {
            let mut far = (hi - lo).length().max(1.0);
            for _ in 0..64 {
                if fits(target, far).is_some() {
                    break;
                }
                far *= 2.0;
            }
            let mut near = 0.0;
            while far - near > far * 1e-3 {
                let mid = 0.5 * (near + far);
                if fits(target, mid).is_some() {
                    far = mid;
                } else {
                    near = mid;
                }
            }
            far
        };
        let mut target = (lo + hi) * 0.5;
        let mut distance = closest(target);
        // Perspective shows the near edge lower and larger than the far one: slide the target
        // along the ground until the box is centred vertically, coming closer each time.
        for _ in 0..4 {
            let Some((y0, y1)) = fits(target, distance) else {
                break;
            };
            let centre = 0.5 * (y0 + y1);
            // Moving the target by s along the ground (towards the north) moves its image by
            // about s·sin(elevation) / (distance·tan(fov/2)) in device coordinates.
            let metres = centre * distance * (fov_y / 2.0).tan() / elevation.sin();
            target.y += metres;
            distance = closest(target);
        }
        at(target, distance)
    }

    /// World to view (right-handed, looking down −z).
    pub fn view(&self) -> DMat4 {
        look_at(self.eye, self.target, self.up)
    }

    /// View to clip space, depth 0 (near) to 1 (far), as wgpu expects; with an infinite far
    /// plane, reversed: 1 at the near plane, 0 at infinity ([`Camera::reversed_z`]).
    pub fn projection(&self) -> DMat4 {
        if self.reversed_z() {
            reversed_infinite(self.fov_y, self.aspect(), self.near)
        } else {
            perspective(self.fov_y, self.aspect(), self.near, self.far)
        }
    }

    /// Whether depth is reversed (infinite far plane): nearer is greater, cleared to 0.
    pub fn reversed_z(&self) -> bool {
        self.far.is_infinite()
    }

    /// World-minus-eye to clip space, in `f32` for the GPU: vertices are sent relative to the eye.
    pub fn view_proj_relative(&self) -> Mat4 {
        let rotation = look_at(DVec3::ZERO, self.target - self.eye, self.up);
        (self.projection() * rotation).as_mat4()
    }

    /// Width over height.
    pub fn aspect(&self) -> f64 {
        f64::from(self.width) / f64::from(self.height.max(1))
    }

    /// Pixels per metre of a length facing the camera at `distance` metres.
    pub fn pixels_per_metre(&self, distance: f64) -> f64 {
        f64::from(self.height) / (2.0 * (self.fov_y / 2.0).tan() * distance.max(self.near))
    }

    /// The view frustum in world space.
    pub fn frustum(&self) -> Frustum {
        Frustum::from_matrix(self.projection() * self.view())
    }
}

/// Right-handed world-to-view matrix (view looks down −z, y up on screen), `up` up on the screen.
fn look_at(eye: DVec3, target: DVec3, up: DVec3) -> DMat4 {
    let f = (target - eye).normalize();
    let s = f.cross(up_for(f, up)).normalize();
    let u = s.cross(f);
    DMat4::from_cols(
        DVec4::new(s.x, u.x, -f.x, 0.0),
        DVec4::new(s.y, u.y, -f.y, 0.0),
        DVec4::new(s.z, u.z, -f.z, 0.0),
        DVec4::new(-s.dot(eye), -u.dot(eye), f.dot(eye), 1.0),
    )
}

/// Right-handed perspective projection with depth 0 at `near` and 1 at `far` (wgpu's clip space).
fn perspective(fov_y: f64, aspect: f64, near: f64, far: f64) -> DMat4 {
    let f = 1.0 / (fov_y / 2.0).tan();
    let r = far / (near - far);
    DMat4::from_cols(
        DVec4::new(f / aspect, 0.0, 0.0, 0.0),
        DVec4::new(0.0, f, 0.0, 0.0),
        DVec4::new(0.0, 0.0, r, -1.0),
        DVec4::new(0.0, 0.0, r * near, 0.0),
    )
}

/// Perspective projection with an infinite far plane and reversed depth: `near / distance`,
/// 1 at `near`, towards 0 at infinity.
fn reversed_infinite(fov_y: f64, aspect: f64, near: f64) -> DMat4 {
    let f = 1.0 / (fov_y / 2.0).tan();
    DMat4::from_cols(
        DVec4::new(f / aspect, 0.0, 0.0, 0.0),
        DVec4::new(0.0, f, 0.0, 0.0),
        DVec4::new(0.0, 0.0, 0.0, -1.0),
        DVec4::new(0.0, 0.0, near, 0.0),
    )
}

/// An up vector that is never parallel to the viewing direction (looking straight down works):
/// `up`, or when the view runs along it, +y for a z up and any perpendicular otherwise.
fn up_for(dir: DVec3, up: DVec3) -> DVec3 {
    let d = dir.normalize_or_zero();
    if d.cross(up).length_squared() < 1e-12 {
        if up == DVec3::Z {
            DVec3::Y
        } else {
            up.any_orthonormal_vector()
        }
    } else {
        up
    }
}

/// Six planes `a·x + b·y + c·z + d ≥ 0` inside, world space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frustum {
    /// Left, right, bottom, top, near, far.
    pub planes: [DVec4; 6],
}

impl Frustum {
    /// The planes of a world-to-clip matrix with 0..1 depth (Gribb–Hartmann).
    pub fn from_matrix(m: DMat4) -> Self {
        let r = |i: usize| m.row(i);
        let planes = [
            r(3) + r(0),
            r(3) - r(0),
            r(3) + r(1),
            r(3) - r(1),
            r(2),
            r(3) - r(2),
        ]
        // A reversed infinite projection's depth ≥ 0 plane is no plane at all (0, 0, 0, near):
        // always inside.
        .map(|p| {
            let l = p.truncate().length();
            if l > 0.0 {
                p / l
            } else {
                DVec4::new(0.0, 0.0, 0.0, 1.0)
            }
        });
        Self { planes }
    }

    /// The same frustum with every side plane pushed out by `margin` metres (prefetching asks for
    /// what an enlarged frustum sees).
    pub fn enlarged(&self, margin: f64) -> Self {
        let mut planes = self.planes;
        for p in &mut planes[..4] {
            p.w += margin;
        }
        Self { planes }
    }

    /// Whether the box `min..max` is at least partly inside (conservative: may say yes for a box
    /// just outside a corner, never no for a box inside).
    pub fn intersects_box(&self, min: DVec3, max: DVec3) -> bool {
        self.planes.iter().all(|p| {
            let corner = DVec3::new(
                if p.x >= 0.0 { max.x } else { min.x },
                if p.y >= 0.0 { max.y } else { min.y },
                if p.z >= 0.0 { max.z } else { min.z },
            );
            p.truncate().dot(corner) + p.w >= 0.0
        })
    }
}

/// The eight corners of the box `lo`–`hi`.
fn box_corners(lo: DVec3, hi: DVec3) -> [DVec3; 8] {
    std::array::from_fn(|i| {
        DVec3::new(
            if i & 1 == 0 { lo.x } else { hi.x },
            if i & 2 == 0 { lo.y } else { hi.y },
            if i & 4 == 0 { lo.z } else { hi.z },
        )
    })
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

    /// The overview sees every corner of the data box, and the target is at the screen centre.
    #[test]
    fn overview_sees_the_whole_data() {
        let w = world();
        let cam = Camera::overview(&w, (1920, 1080));
        let (lo, hi) = w.bounds();
        let m = cam.projection() * cam.view();
        for i in 0..8 {
            let c = DVec3::new(
                if i & 1 == 0 { lo.x } else { hi.x },
                if i & 2 == 0 { lo.y } else { hi.y },
                if i & 4 == 0 { lo.z } else { hi.z },
            );
            let p = m * c.extend(1.0);
            let ndc = p.truncate() / p.w;
            assert!(
                ndc.x.abs() <= 1.0 && ndc.y.abs() <= 1.0,
                "corner {i} at {ndc}"
            );
            assert!((0.0..=1.0).contains(&ndc.z), "corner {i} depth {}", ndc.z);
            assert!(cam.frustum().intersects_box(c, c));
        }
        let t = m * cam.target.extend(1.0);
        assert!((t.x / t.w).abs() < 1e-9 && (t.y / t.w).abs() < 1e-9);
    }

    /// The corners of the data box in normalised device coordinates.
    fn projected_corners(cam: &Camera, w: &World) -> Vec<DVec3> {
        let (lo, hi) = w.bounds();
        let m = cam.projection() * cam.view();
        box_corners(lo, hi)
            .iter()
            .map(|c| {
                let p = m * c.extend(1.0);
                p.truncate() / p.w
            })
            .collect()
    }

    /// Area (in NDC, the frame is 4) of the rectangle around the projected corners.
    fn covered(ndc: &[DVec3]) -> f64 {
        let (x0, x1) = ndc
            .iter()
            .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.x), b.max(p.x)));
        let (y0, y1) = ndc
            .iter()
            .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.y), b.max(p.y)));
        (x1 - x0) * (y1 - y0)
    }

    /// The framed view keeps every corner of the data in the frame (inside the 95 % margin, in
    /// front of the near plane), centred vertically, touches the margin (no closer view would
    /// fit), and covers more
    /// of the frame than the overview, in landscape and portrait frames.
    #[test]
    fn framed_view_fills_the_frame_with_the_whole_data() {
        let w = world();
        for size in [(640, 480), (1280, 720), (480, 800)] {
            let cam = Camera::framed(&w, size);
            let ndc = projected_corners(&cam, &w);
            for (i, p) in ndc.iter().enumerate() {
                assert!(
                    p.x.abs() <= 0.95 && p.y.abs() <= 0.95,
                    "{size:?}: corner {i} at {p}"
                );
                assert!(
                    (0.0..=1.0).contains(&p.z),
                    "{size:?}: corner {i} depth {}",
                    p.z
                );
            }
            let reach = ndc
                .iter()
                .map(|p| p.x.abs().max(p.y.abs()))
                .fold(0.0, f64::max);
            assert!(
                reach > 0.94,
                "{size:?}: the data reaches only {reach} of the margin"
            );
            let overview = covered(&projected_corners(&Camera::overview(&w, size), &w));
            assert!(
                covered(&ndc) > 1.25 * overview,
                "{size:?}: framed covers {} of 4, the overview {overview}",
                covered(&ndc)
            );
        }
    }

    /// Camera-relative projection equals the absolute one up to f32 rounding, even far from the
    /// origin where absolute f32 positions would lose metres.
    #[test]
    fn relative_projection_matches_absolute() {
        let w = world();
        let mut cam = Camera::overview(&w, (800, 600));
        let shift = DVec3::new(3.0e6, -5.0e6, 0.0);
        cam.eye += shift;
        cam.target += shift;
        let abs = cam.projection() * cam.view();
        let rel = cam.view_proj_relative();
        let p = cam.target + DVec3::new(123.25, -77.5, 40.0);
        let a = abs * p.extend(1.0);
        let r = rel * (p - cam.eye).as_vec3().extend(1.0);
        let (a, r) = (a.truncate() / a.w, r.truncate().as_dvec3() / f64::from(r.w));
        assert!((a - r).abs().max_element() < 1e-5, "{a} vs {r}");
    }

    /// On a planet: a camera near the ground keeps the horizon level (the screen's right is
    /// perpendicular to the local normal, whatever the heading), a camera orbiting the globe
    /// from afar has north up, and the projection is reversed-Z: 1 at the near plane, towards 0
    /// far away, the frustum's near plane still culling what is behind the eye.
    #[test]
    fn planet_cameras_keep_the_horizon_level_and_reverse_depth() {
        let w = World::planet(
            Domain::cube_sphere(5, 2).unwrap(),
            1.0,
            0.0,
            (-100.0, 2000.0),
        );
        for heading in [0.0, 37.0, 90.0, 200.0] {
            let cam = Camera::geodetic(&w, (41.0, -73.0, 3000.0), (heading, -5.0), 0.8, (64, 48));
            let right = cam.view().row(0).truncate();
            assert!(right.dot(w.up(cam.eye)).abs() < 1e-9, "heading {heading}");
            // The same from the generic constructor, whose up is chosen for it.
            let again = Camera::looking_at(&w, cam.eye, cam.target, 0.8, (64, 48));
            assert!(again.view().row(0).truncate().dot(w.up(cam.eye)).abs() < 1e-9);
            assert!(cam.reversed_z() && cam.far.is_infinite());
            let m = cam.projection() * cam.view();
            let depth = |p: DVec3| {
                let c = m * p.extend(1.0);
                c.z / c.w
            };
            let fwd = (cam.target - cam.eye).normalize();
            assert!((depth(cam.eye + fwd * cam.near) - 1.0).abs() < 1e-9);
            // near / distance: 1 at the near plane, towards 0 at infinity.
            let d = depth(cam.eye + fwd * 1e7);
            assert!((d - cam.near / 1e7).abs() < 1e-12, "{d}");
            let behind = cam.eye - fwd * 10.0;
            assert!(!cam.frustum().intersects_box(behind, behind));
            let ahead = cam.eye + fwd * cam.near * 2.0;
            assert!(cam.frustum().intersects_box(ahead, ahead));
        }
        let far = Camera::looking_at(&w, DVec3::new(2e7, 1e7, 5e6), DVec3::ZERO, 0.8, (64, 48));
        let up_on_screen = far.view().row(1).truncate();
        assert!(up_on_screen.z > 0.9, "{up_on_screen}");
    }

    /// Boxes behind the camera or beside the frustum are culled; boxes in front are kept.
    #[test]
    fn frustum_culls_boxes_outside() {
        let w = world();
        let cam = Camera::overview(&w, (800, 600));
        let f = cam.frustum();
        let behind = cam.eye + (cam.eye - cam.target);
        assert!(!f.intersects_box(behind - DVec3::ONE, behind + DVec3::ONE));
        let right = cam.view().inverse().transform_vector3(DVec3::X);
        let beside = cam.target + right * 1e7;
        assert!(!f.intersects_box(beside - DVec3::ONE, beside + DVec3::ONE));
        assert!(f.intersects_box(cam.target - DVec3::ONE, cam.target + DVec3::ONE));
        assert!(
            f.enlarged(2e7)
                .intersects_box(beside - DVec3::ONE, beside + DVec3::ONE)
        );
    }
}
