//! The per-frame instance list: culling the cut's half-patches, assigning them cache slots,
//! staging the uploads, and one [`PatchInstance`] per drawn patch sorted by mesh kind.

use std::borrow::Borrow;

use bytemuck::{Pod, Zeroable};
use cbdam_client::camera::Camera;
use cbdam_client::patch::HalfPatch;
use cbdam_client::world::World;
use cbdam_codec::geometry::{Diagonal, Half};
use glam::DVec3;

use crate::{DrawStats, GREY, MeshKind, NODATA_BIT, RenderOptions, Renderer, Residency};

/// One drawn half-patch (`Patch` in the shader).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct PatchInstance {
    /// World x, y of grid point (0, 0) minus the eye's, metres.
    pub origin_rel: [f32; 2],
    /// World step of grid index i, metres.
    pub u_world: [f32; 2],
    /// World step of grid index j, metres.
    pub v_world: [f32; 2],
    /// Lattice point of grid index (0, 0).
    pub origin_lat: [i32; 2],
    /// Lattice step of i.
    pub u_lat: [i32; 2],
    /// Lattice step of j.
    pub v_lat: [i32; 2],
    /// Slot in the height pool.
    pub slot: u32,
    /// Diamond level.
    pub level: u32,
    /// 0 main split diagonal, 1 anti.
    pub diagonal: u32,
    /// 0 positive half, 1 negative.
    pub half: u32,
    /// On a planet: z of the patch origin minus the eye (x and y in `origin_rel`), metres.
    pub origin_z: f32,
    /// On a planet: `+1` when the cross product of the grid's `i` and `j` steps faces out of
    /// the globe on this patch, `−1` when it faces in (the shader turns normals out with it).
    pub facing: f32,
    /// Padding.
    pub pad0: [u32; 2],
    /// On a planet: what rounding `origin_rel` and `origin_z` to `f32` left, x, y, z.
    pub origin_lo: [f32; 3],
    /// Padding to 8 bytes.
    pub pad: u32,
}
const _: () = assert!(std::mem::size_of::<PatchInstance>() == 96);

impl Renderer {
    /// Culls, assigns slots, stages uploads, and writes the uniform and instances.
    pub(crate) fn prepare<P: Borrow<HalfPatch>>(
        &mut self,
        camera: &Camera,
        patches: &[P],
        options: &RenderOptions,
    ) -> Prepared {
        let world = self.world;
        let layout = *world.domain.layout();
        let cull = Culling::new(&world, camera);
        let before = self.cache.stats();
        self.cache.begin_frame();
        let mut stats = DrawStats {
            patches: patches.len(),
            ..Default::default()
        };
        let mut by_kind: [Vec<PatchInstance>; 8] = Default::default();
        let mut upload_slots = Vec::new();
        let mut staging_data: Vec<i32> = Vec::new();
        for p in patches {
            let p = p.borrow();
            if cull.hides(&world, p) {
                stats.culled += 1;
                continue;
            }
            let g = layout.grid(p.id);
            // On a planet the patch's origin: its grid point (0, 0) on the ellipsoid.
            let origin_abs = world
                .is_planet()
                .then(|| world.face_point(p.id.face, g.origin.0, g.origin.1, 0.0));
            let slot = match self.cache.request(p.key()) {
                Residency::Hit(s) => s,
                Residency::Upload(s) => {
                    upload_slots.push(s);
                    self.stage(p, origin_abs, &mut staging_data);
                    s
                }
                Residency::Missing => {
                    stats.missing += 1;
                    continue;
                }
            };
            let kind = MeshKind {
                diagonal: layout.diagonal(p.id),
                half: p.half,
                mirrored: !p.id.is_even(),
            };
            let instance = patch_instance(&world, p, kind, origin_abs, slot, camera.eye);
            by_kind[kind.index()].push(instance);
            stats.drawn += 1;
        }
        let words = self.slot_bytes() as usize / 4;
        debug_assert_eq!(staging_data.len(), upload_slots.len() * words);
        let mut instances = Vec::with_capacity(stats.drawn);
        let mut groups: [std::ops::Range<u32>; 8] = Default::default();
        for (k, list) in by_kind.iter().enumerate() {
            let start = instances.len() as u32;
            instances.extend_from_slice(list);
            groups[k] = start..instances.len() as u32;
        }
        stats.triangles = instances.len() as u64 * u64::from(self.mesh.triangles_per_patch());
        stats.cache = self.cache.stats().since(&before);
        self.write_instances(&instances);
        self.write_uniform(camera, options);
        Prepared {
            stats,
            groups,
            upload_slots,
            staging: staging_data,
        }
    }

    /// Appends the words of `p`'s slot to `staging`: its heights (nodata marked), its colours
    /// when draped, its vertex positions relative to `origin_abs` on a planet.
    fn stage(&self, p: &HalfPatch, origin_abs: Option<DVec3>, staging: &mut Vec<i32>) {
        let n = self.world.domain.layout().n();
        match &p.valid {
            None => staging.extend_from_slice(&p.heights),
            Some(valid) => staging.extend(
                p.heights
                    .iter()
                    .zip(valid)
                    .map(|(&h, &v)| if v { h } else { h ^ NODATA_BIT }),
            ),
        }
        if self.draped() {
            match &p.colour {
                Some(c) => staging.extend(c.iter().map(|&c| c as i32)),
                None => staging.extend(std::iter::repeat_n(GREY, n * n).map(|c| c as i32)),
            }
        }
        if let Some(o) = origin_abs {
            planet_positions(&self.world, p, o, staging);
        }
    }
}

/// What hides a patch from a camera: the view frustum, the horizon (planets) and, on a plane,
/// the data rectangle.
struct Culling {
    frustum: cbdam_client::camera::Frustum,
    horizon: Option<cbdam_client::horizon::Horizon>,
    /// The data rectangle's last lattice column and row, on a plane.
    data_max: Option<(i64, i64)>,
}

impl Culling {
    fn new(world: &World, camera: &Camera) -> Self {
        let data = world.domain.data();
        Self {
            frustum: camera.frustum(),
            horizon: world.occluder().and_then(|o| o.from_eye(camera.eye)),
            data_max: (!world.is_planet())
                .then(|| (i64::from(data.width) - 1, i64::from(data.height) - 1)),
        }
    }

    /// Whether `p` cannot be seen: outside the data rectangle, the frustum, or beyond the
    /// horizon.
    fn hides(&self, world: &World, p: &HalfPatch) -> bool {
        let (x0, y0, x1, y1) = world.domain.layout().bounds(p.id);
        if let Some((dw, dh)) = self.data_max
            && (x1 < 0 || y1 < 0 || x0 > dw || y0 > dh)
        {
            return true;
        }
        let (lo, hi) = p
            .heights
            .iter()
            .fold((i32::MAX, i32::MIN), |(a, b), &h| (a.min(h), b.max(h)));
        let (blo, bhi) = world.diamond_box(p.id, lo, hi);
        !self.frustum.intersects_box(blo, bhi)
            || self.horizon.as_ref().is_some_and(|h| h.hides_box(blo, bhi))
    }
}

/// The instance of `p` drawn from `slot`, placed relative to `eye`.
fn patch_instance(
    world: &World,
    p: &HalfPatch,
    kind: MeshKind,
    origin_abs: Option<DVec3>,
    slot: u32,
    eye: DVec3,
) -> PatchInstance {
    let g = world.domain.layout().grid(p.id);
    let planet = origin_abs.is_some();
    let origin = origin_abs.unwrap_or_else(|| world.point(g.origin.0, g.origin.1, 0)) - eye;
    let facing = origin_abs.map_or(1.0, |o| {
        // The grid map keeps or flips orientation on the whole patch: its first cell says which.
        let at = |i, j| {
            let (x, y) = g.point(i, j);
            world.face_point(p.id.face, x, y, 0.0) - o
        };
        if at(1, 0).cross(at(0, 1)).dot(o) >= 0.0 {
            1.0
        } else {
            -1.0
        }
    });
    let lattice = |(x, y): (i64, i64)| [x as i32, y as i32];
    let metres = |(x, y): (i64, i64)| {
        let (x, y) = world.lattice_vector(x, y);
        [x as f32, y as f32]
    };
    PatchInstance {
        origin_rel: [origin.x as f32, origin.y as f32],
        u_world: metres(g.u),
        v_world: metres(g.v),
        origin_lat: lattice(g.origin),
        u_lat: lattice(g.u),
        v_lat: lattice(g.v),
        slot,
        level: u32::from(p.id.level),
        diagonal: u32::from(kind.diagonal == Diagonal::Anti),
        half: u32::from(p.half == Half::Negative),
        origin_z: if planet { origin.z as f32 } else { 0.0 },
        facing,
        pad0: [0; 2],
        origin_lo: if planet { split(origin).1 } else { [0.0; 3] },
        pad: 0,
    }
}

/// `v` as `f32` pairs: the rounded value and what the rounding left.
fn split(v: DVec3) -> ([f32; 3], [f32; 3]) {
    let hi = v.as_vec3();
    let lo = (v - hi.as_dvec3()).as_vec3();
    (hi.to_array(), lo.to_array())
}

/// Appends a planet patch's vertex positions relative to `origin` (ECEF, metres): per grid
/// vertex in grid order, the [`split`] pair as 6 words of `f32` bits (x, y, z rounded, then
/// what rounding left), computed in `f64` from each vertex's canonical point.
fn planet_positions(world: &World, p: &HalfPatch, origin: DVec3, out: &mut Vec<i32>) {
    let g = world.domain.layout().grid(p.id);
    let n = g.n;
    for j in 0..n {
        for i in 0..n {
            let (x, y) = g.point(i as i64, j as i64);
            let h = world.height(p.heights[j * n + i]);
            let (hi, lo) = split(world.face_point(p.id.face, x, y, h) - origin);
            out.extend(hi.iter().chain(&lo).map(|c| c.to_bits() as i32));
        }
    }
}

pub(crate) struct Prepared {
    pub(crate) stats: DrawStats,
    pub(crate) groups: [std::ops::Range<u32>; 8],
    pub(crate) upload_slots: Vec<u32>,
    /// The uploaded slots' words, slot after slot in `upload_slots` order.
    pub(crate) staging: Vec<i32>,
}
