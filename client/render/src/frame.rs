//! What one frame is drawn with and what it reports: the options a caller sets, the uniform
//! block the shaders read (written per frame from the camera and the world), and the draw
//! statistics.

use bytemuck::{Pod, Zeroable};
use glam::DVec3;

use cbdam_client::camera::Camera;

use crate::{CacheStats, Renderer};

/// Per-frame constants (`Frame` in the shader).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct FrameUniform {
    /// World-minus-eye to clip.
    pub view_proj: [[f32; 4]; 4],
    /// Unit vector towards the sun; w unused.
    pub sun: [f32; 4],
    /// z relative to the eye of height 0 units.
    pub z_base: f32,
    /// Metres per height unit (vertically exaggerated if asked).
    pub z_scale: f32,
    /// True metres of height 0 units (colour ramp).
    pub m_offset: f32,
    /// True metres per height unit (colour ramp).
    pub m_unit: f32,
    /// Colour ramp start, metres.
    pub ramp_lo: f32,
    /// Colour ramp end, metres.
    pub ramp_hi: f32,
    /// Grid side N.
    pub n: u32,
    /// 0 hypsometric, 1 level colours.
    pub mode: u32,
    /// Largest lattice x and y of the data rectangle.
    pub data_max: [f32; 2],
    /// 1 when the data reaches below sea level.
    pub has_sea: u32,
    /// 1 when slots hold draped colours after the heights.
    pub draped: u32,
    /// 1 on a planet: slots hold positions after the heights, no data rectangle.
    pub planet: u32,
    /// Padding to 16 bytes.
    pub pad: [u32; 3],
}
const _: () = assert!(std::mem::size_of::<FrameUniform>() == 144);

/// How a frame looks.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderOptions {
    /// Colour by diamond level instead of by height (debug).
    pub level_colours: bool,
    /// Draw triangle edges over the surface (debug; needs `POLYGON_MODE_LINE`).
    pub wireframe: bool,
    /// Clear colour, RGBA 0–1 as written to the image.
    pub background: [f64; 4],
    /// Unit vector towards the sun (default: from the north-west, 45° high — the cartographic
    /// convention, so valleys read as valleys).
    pub sun: DVec3,
    /// Read the depth buffer back into [`Frame::depth`].
    pub read_depth: bool,
}

impl Default for RenderOptions {
    fn default() -> Self {
        Self {
            level_colours: false,
            wireframe: false,
            background: [0.62, 0.74, 0.86, 1.0],
            sun: DVec3::new(-0.5, 0.5, std::f64::consts::FRAC_1_SQRT_2).normalize(),
            read_depth: false,
        }
    }
}

/// What one frame drew.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DrawStats {
    /// Half-patches in the cut handed over.
    pub patches: usize,
    /// Half-patches drawn.
    pub drawn: usize,
    /// Not drawn: entirely outside the data rectangle or the view frustum.
    pub culled: usize,
    /// Not drawn: not resident and not uploadable this frame (budget or pool size).
    pub missing: usize,
    /// Triangles submitted.
    pub triangles: u64,
    /// Draw calls issued.
    pub draw_calls: u32,
    /// Cache counters of this frame.
    pub cache: CacheStats,
    /// CPU time preparing the frame (culling, cache, staging), seconds.
    pub prepare_s: f64,
    /// Time from submitting the frame to the GPU finishing it, seconds (readback excluded).
    pub gpu_s: f64,
}

impl Renderer {
    /// Writes the frame's uniform block: the camera's projection, the sun (on a planet, in the
    /// local frame under the eye), the colour ramp and what the slots hold.
    pub(crate) fn write_uniform(&self, camera: &Camera, options: &RenderOptions) {
        let w = &self.world;
        let sun = options.sun.normalize_or_zero();
        // On a planet the sun is given in the local frame under the eye.
        let sun = if w.is_planet() {
            let g = cbdam_codec::geodesy::Geodetic::from_ecef(camera.eye.to_array());
            let (sp, cp) = g.lat.to_radians().sin_cos();
            let (sl, cl) = g.lon.to_radians().sin_cos();
            let east = DVec3::new(-sl, cl, 0.0);
            let north = DVec3::new(-sp * cl, -sp * sl, cp);
            let up = DVec3::new(cp * cl, cp * sl, sp);
            east * sun.x + north * sun.y + up * sun.z
        } else {
            sun
        };
        // The colour ramp spans the land's true heights; below sea level is water when present.
        let ramp_lo = w.min_height.max(0.0);
        let uniform = FrameUniform {
            view_proj: camera.view_proj_relative().to_cols_array_2d(),
            sun: [sun.x as f32, sun.y as f32, sun.z as f32, 0.0],
            z_base: (w.offset - camera.eye.z) as f32,
            z_scale: w.unit as f32,
            m_offset: w.offset as f32,
            m_unit: w.unit as f32,
            ramp_lo: ramp_lo as f32,
            ramp_hi: w.max_height.max(ramp_lo + 1.0) as f32,
            n: w.domain.n() as u32,
            mode: u32::from(options.level_colours),
            data_max: {
                let data = w.domain.data();
                [
                    data.width.saturating_sub(1) as f32,
                    data.height.saturating_sub(1) as f32,
                ]
            },
            has_sea: u32::from(w.min_height < 0.0),
            draped: u32::from(self.draped()),
            planet: u32::from(w.is_planet()),
            pad: [0; 3],
        };
        self.gpu
            .queue
            .write_buffer(&self.uniform, 0, bytemuck::bytes_of(&uniform));
    }
}
