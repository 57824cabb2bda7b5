//! The C-BDAM renderer over the client core (`cbdam-client`): wgpu drawing of the half-patches
//! of a cut from a GPU patch cache, the HUD ([`hud`]) and presenting to a window ([`present`]).
//! The windows are the shells': `cbdam-desktop` (winit) and `cbdam-web` (a browser canvas). The
//! shaders are `shaders/*.wgsl`, built in.
//!
//! Design (docs/DESIGN.md "GPU", paper §6):
//! - **Shared grid.** The `N × N` grid's triangle lists are uploaded once ([`mesh`]): 8 index
//!   lists (split diagonal × half × grid orientation) in one index buffer. There is no vertex
//!   buffer: an index is the grid vertex number `j·N + i`, which *is* its (u, v).
//! - **Height pool.** One storage buffer of `i32` heights, `N²` per slot (or, where vertex
//!   shaders cannot read storage buffers — WebGL2 —, an integer texture of the same words:
//!   [`pool`], [`VertexFetch`]); a slot holds one
//!   half-patch's grid and nothing else. Slots are an LRU cache keyed by [`PatchKey`](cbdam_client::patch::PatchKey)
//!   ([`cache`]); new patches are copied in one batch per frame from a single staging buffer
//!   (into the texture, through the queue), within a byte budget. Normals are computed in the vertex shader from neighbouring heights.
//! - **Instances.** Per drawn patch a 96-byte [`PatchInstance`] (slot, level, half, diagonal,
//!   grid origin and axes relative to the eye in metres, and the same in lattice integers for
//!   clipping) in a storage buffer (an instance-stepped vertex buffer on the texture path),
//!   sorted by mesh kind: the whole cut is at most 8 instanced draw calls (16 with the
//!   wireframe overlay).
//! - **Precision.** Positions are relative to the eye: origins are subtracted in `f64` on the
//!   CPU, and [`Camera::view_proj_relative`] only rotates and projects.
//! - **Data rectangle.** Fragments whose lattice position is outside the data rectangle are
//!   discarded (heights there are unconstrained), and patches entirely outside are not drawn.
//! - **Draped colour.** With a colour repository ([`Renderer::with_colour`]) a slot holds the
//!   `N²` heights followed by `N²` colours, RGB8 packed in a word ([`cbdam_client::patch::pack_rgb`]):
//!   twice the bytes per slot, and the shader lights that colour instead of the hypsometric
//!   ramp. Without one the slots, the shader's work and the image are what they were.
//! - **Nodata.** Heights at points without data (the repository's nodata mask) are marked in the
//!   pool ([`NODATA_BIT`]); fragments of triangles touching such a point are discarded, so no
//!   invented surface is drawn.
//!
//! - **Planets.** On a cube-sphere world positions are ECEF metres, curved: a slot holds, after
//!   the `N²` heights, the `N²` vertex positions relative to the patch's origin (its grid point
//!   (0, 0) on the ellipsoid), computed once in `f64` when the patch is uploaded; per frame only
//!   the origin minus the eye is computed in `f64`. Both are sent as pairs of `f32` (the value
//!   rounded, and what the rounding left), and the shader adds the large parts first: near the
//!   eye they cancel exactly (Sterbenz), so a vertex is placed to about `1e-7` of its distance
//!   from the eye, however large its patch, anywhere on the globe — no Earth radius and no
//!   patch size ever reaches a single `f32`. Depth
//!   is reversed with an infinite far plane ([`Camera::reversed_z`]), normals come from the
//!   neighbouring positions (so they include the ellipsoid's curvature), the sun is given in
//!   the local frame (east, north, up) at the point under the eye, and there is no data
//!   rectangle to clip to.
//!
//! Offscreen rendering ([`Renderer::render`]) reads back colour and optionally depth.

#![deny(missing_docs)]

pub mod cache;
pub mod hud;
pub mod mesh;
pub mod pool;
pub mod present;

mod frame;
mod gpu;
mod instances;
mod pipelines;
mod readback;
mod target;

use std::borrow::Borrow;

use web_time::Instant;

pub use cache::{CacheStats, Residency, SlotCache};
pub use frame::{DrawStats, FrameUniform, RenderOptions};
pub use gpu::Gpu;
pub use instances::PatchInstance;
use instances::Prepared;
pub use mesh::{MeshKind, SharedMesh};
use pipelines::{TerrainPipelines, bind_group, buffer_init, instance_buffer, terrain_layout};
use pool::HeightPool;
pub use pool::{POOL_TEXTURE_WIDTH, VertexFetch};
pub use readback::{Frame, encode_png, write_png};
use target::Target;

use cbdam_client::camera::Camera;
use cbdam_client::patch::HalfPatch;
use cbdam_client::world::World;

/// Marks a height of the pool as nodata (`h ^ NODATA_BIT`): heights satisfy
/// `|h| ≤ MAX_ABS_HEIGHT < 2^30`, so the flipped bit 30 puts a marked height outside that range
/// in either sign, and the shader undoes it. Keeping the mark inside the heights costs no
/// memory, no extra buffer and no extra upload; `shaders/terrain.wgsl` has the same constant.
pub const NODATA_BIT: i32 = 1 << 30;

/// The terrain shader's shared part (`fs_main`, `fs_wire` and the vertex maths), completed by
/// one of the two variants below ([`terrain_shader`]).
pub const TERRAIN_WGSL: &str = include_str!("../../../shaders/terrain.wgsl");
/// The terrain shader's storage-buffer variant (`vs_main`, the patches and the pool in storage).
pub const TERRAIN_STORAGE_WGSL: &str = include_str!("../../../shaders/terrain_storage.wgsl");
/// The terrain shader's texture variant (`vs_main`, the patches as instance attributes, the pool
/// in an integer texture): for WebGL2.
pub const TERRAIN_TEXTURE_WGSL: &str = include_str!("../../../shaders/terrain_texture.wgsl");

/// The whole terrain shader for a vertex fetch path ([`VertexFetch::Auto`] is the storage one).
///
/// One source and two small variants appended as text, rather than two shaders or overrides:
/// the variants differ in binding types (storage buffer or texture) and in the entry point's
/// inputs (instance index or vertex attributes), which pipeline overrides cannot change, and a
/// second copy of the maths would drift; every assembled module is validated when the pipeline
/// is made, and the tests draw through both.
pub fn terrain_shader(fetch: VertexFetch) -> String {
    let variant = match fetch {
        VertexFetch::Texture => TERRAIN_TEXTURE_WGSL,
        VertexFetch::Auto | VertexFetch::StorageBuffers => TERRAIN_STORAGE_WGSL,
    };
    format!("{TERRAIN_WGSL}\n{variant}")
}

/// Colour and depth formats of the offscreen targets.
pub const COLOR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;
/// See [`COLOR_FORMAT`].
pub const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

/// Colour of a patch without draped colours in a draped renderer.
const GREY: u32 = 0xFF80_8080;

/// Default size of the height pool when the adapter allows it.
pub const DEFAULT_POOL_BYTES: u64 = 256 << 20;

/// Why rendering failed.
#[derive(Debug, thiserror::Error)]
pub enum DrawError {
    /// No GPU adapter (on Linux without a GPU: Mesa's lavapipe is missing).
    #[error(
        "no GPU adapter found ({0}); on a machine without a GPU install Mesa's software Vulkan \
         driver: apt-get install mesa-vulkan-drivers libvulkan1"
    )]
    NoAdapter(String),
    /// The adapter refused a device.
    #[error("cannot open the GPU device: {0}")]
    Device(String),
    /// The adapter lacks something this request needs.
    #[error("unsupported: {0}")]
    Unsupported(String),
    /// A wgpu validation or runtime error.
    #[error("GPU error: {0}")]
    Gpu(String),
    /// Writing an image failed.
    #[error("PNG: {0}")]
    Png(String),
}

/// Sizes of the GPU patch cache.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CacheConfig {
    /// Height pool size in bytes (rounded down to whole slots). `None`: the smaller of
    /// [`DEFAULT_POOL_BYTES`] and what one storage binding (or, on the texture path, the
    /// largest pool texture) may hold on this adapter.
    pub pool_bytes: Option<u64>,
    /// Bytes of heights copied to the GPU per frame at most.
    pub upload_budget: u64,
    /// Where the vertex shader reads patches and heights from: by default storage buffers
    /// where the adapter allows it, else a texture (WebGL2).
    pub vertex_fetch: VertexFetch,
}

impl Default for CacheConfig {
    fn default() -> Self {
        Self {
            pool_bytes: None,
            upload_budget: u64::MAX,
            vertex_fetch: VertexFetch::Auto,
        }
    }
}

/// The terrain renderer of one repository's world.
pub struct Renderer {
    gpu: Gpu,
    world: World,
    mesh: SharedMesh,
    index_buffer: wgpu::Buffer,
    pool: HeightPool,
    fetch: VertexFetch,
    instances: wgpu::Buffer,
    instance_capacity: u64,
    uniform: wgpu::Buffer,
    layout: wgpu::BindGroupLayout,
    bind_group: wgpu::BindGroup,
    fill: wgpu::RenderPipeline,
    fill_under_lines: wgpu::RenderPipeline,
    lines: Option<wgpu::RenderPipeline>,
    cache: SlotCache,
    target: Option<Target>,
    /// How the terrain is coloured; draped: slots hold colours after the heights.
    colouring: Colouring,
}

/// How a [`Renderer`] colours the terrain.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Colouring {
    /// By height (and slope and light): the terrain's own colours.
    #[default]
    ByHeight,
    /// With the colours of a colour repository draped over the terrain (`cbdam build --colour`).
    Draped,
}

impl Colouring {
    /// Draped when `draped`, else by height.
    pub fn draped_if(draped: bool) -> Self {
        if draped {
            Colouring::Draped
        } else {
            Colouring::ByHeight
        }
    }
}

impl Renderer {
    /// A renderer for `world` (possibly vertically [`exaggerated`]), coloured by height.
    pub fn new(gpu: Gpu, world: World, config: CacheConfig) -> Result<Self, DrawError> {
        Self::with_colour(gpu, world, config, Colouring::ByHeight)
    }

    /// A renderer that colours the terrain as `colouring` says: by height, or with the
    /// patches' draped colours ([`HalfPatch::colour`]; a patch without colours is then drawn
    /// mid-grey).
    pub fn with_colour(
        gpu: Gpu,
        world: World,
        config: CacheConfig,
        colouring: Colouring,
    ) -> Result<Self, DrawError> {
        let draped = colouring == Colouring::Draped;
        let n = world.domain.n();
        let (ex, ey) = world.domain.layout().face_extent();
        if ex > i64::from(i32::MAX) || ey > i64::from(i32::MAX) {
            return Err(DrawError::Unsupported(format!(
                "lattice extent {ex}×{ey} exceeds the shader's 32-bit lattice coordinates"
            )));
        }
        let slot_bytes = slot_bytes(n, draped, world.is_planet());
        let fetch = config.vertex_fetch.resolve(gpu.vertex_storage)?;
        let limits = gpu.device.limits();
        let max_pool = HeightPool::max_bytes(fetch, &limits);
        let pool = config
            .pool_bytes
            .unwrap_or(DEFAULT_POOL_BYTES)
            .min(max_pool);
        let slots = (pool / slot_bytes).min(u64::from(u32::MAX)) as u32;
        if slots == 0 {
            return Err(DrawError::Unsupported(format!(
                "a height pool of {pool} bytes holds no {slot_bytes}-byte slot"
            )));
        }
        let device = &gpu.device;
        let mesh = SharedMesh::new(n);
        let index_buffer = buffer_init(
            device,
            "shared grid indices",
            bytemuck::cast_slice(&mesh.indices),
            wgpu::BufferUsages::INDEX,
        );
        let heights = HeightPool::new(device, fetch, u64::from(slots) * slot_bytes)?;
        let uniform = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("frame uniform"),
            size: std::mem::size_of::<FrameUniform>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let layout = terrain_layout(device, fetch, &heights);
        // Planets draw with reversed depth (nearer is greater).
        let pipelines = TerrainPipelines::new(device, &layout, fetch, world.is_planet());
        let instance_capacity = 1024;
        let instances = instance_buffer(device, fetch, instance_capacity);
        let bind_group = bind_group(device, &layout, &uniform, &instances, &heights);
        Ok(Self {
            cache: SlotCache::new(slots, slot_bytes, config.upload_budget),
            gpu,
            world,
            mesh,
            index_buffer,
            pool: heights,
            fetch,
            instances,
            instance_capacity,
            uniform,
            layout,
            bind_group,
            fill: pipelines.fill,
            fill_under_lines: pipelines.fill_under_lines,
            lines: pipelines.lines,
            target: None,
            colouring,
        })
    }

    /// Where the vertex shader reads patches and heights from on this renderer: storage
    /// buffers or a texture (never [`VertexFetch::Auto`]).
    pub fn vertex_fetch(&self) -> VertexFetch {
        self.fetch
    }

    /// Whether slots hold draped colours.
    pub fn draped(&self) -> bool {
        self.colouring == Colouring::Draped
    }

    /// Bytes of one slot of the height pool: `4 N²`, twice that with draped colour, and
    /// `12 N²` more of positions on a planet.
    pub fn slot_bytes(&self) -> u64 {
        slot_bytes(self.mesh.n, self.draped(), self.world.is_planet())
    }

    /// The device.
    pub fn gpu(&self) -> &Gpu {
        &self.gpu
    }

    /// Cumulative cache counters.
    pub fn cache_stats(&self) -> CacheStats {
        self.cache.stats()
    }

    /// The patch cache's bookkeeping (capacity, residency).
    pub fn cache(&self) -> &SlotCache {
        &self.cache
    }

    /// Triangles one half-patch draws.
    pub fn triangles_per_patch(&self) -> u32 {
        self.mesh.triangles_per_patch()
    }

    /// Renders `patches` (a cut's drawn halves, owned or shared like [`Refiner::drawn`]'s) from
    /// `camera` offscreen and reads the image back. Waits for the GPU: native targets only.
    ///
    /// [`Refiner::drawn`]: cbdam_client::refine::Refiner::drawn
    #[cfg(not(target_arch = "wasm32"))]
    pub fn render<P: Borrow<HalfPatch>>(
        &mut self,
        camera: &Camera,
        patches: &[P],
        options: &RenderOptions,
    ) -> Result<Frame, DrawError> {
        let error_scope = self
            .gpu
            .device
            .push_error_scope(wgpu::ErrorFilter::Validation);
        let size = (camera.width, camera.height);
        let (encoder, mut stats) = self.encode(camera, patches, options)?;
        let t = Instant::now();
        self.gpu.queue.submit([encoder.finish()]);
        self.wait()?;
        stats.gpu_s = t.elapsed().as_secs_f64();
        let target = self.target.as_ref().expect("made by encode");
        let rgba = self.read_texture(&target.color, size, 4)?;
        let depth = if options.read_depth {
            let bytes = self.read_texture(&target.depth, size, 4)?;
            Some(bytemuck::pod_collect_to_vec::<u8, f32>(&bytes))
        } else {
            None
        };
        if let Some(e) = pollster::block_on(error_scope.pop()) {
            return Err(DrawError::Gpu(e.to_string()));
        }
        Ok(Frame {
            width: size.0,
            height: size.1,
            rgba,
            depth,
            stats,
        })
    }

    /// Records a frame into the offscreen colour target ([`Renderer::color_texture`]) without
    /// submitting it, so that a window can draw an overlay over it and present it; uploads are
    /// part of the returned commands. [`DrawStats::gpu_s`] is left 0.
    pub fn encode<P: Borrow<HalfPatch>>(
        &mut self,
        camera: &Camera,
        patches: &[P],
        options: &RenderOptions,
    ) -> Result<(wgpu::CommandEncoder, DrawStats), DrawError> {
        if options.wireframe && self.lines.is_none() {
            return Err(DrawError::Unsupported(
                "wireframe needs the POLYGON_MODE_LINE feature, which this adapter lacks".into(),
            ));
        }
        if camera.reversed_z() != self.world.is_planet() {
            return Err(DrawError::Unsupported(
                "planets are drawn with reversed-Z cameras (infinite far plane) and planes \
                 with finite ones: make the camera with Camera::looking_at for this world"
                    .into(),
            ));
        }
        let size = (camera.width, camera.height);
        self.ensure_target(size);
        let start = Instant::now();
        let prepared = self.prepare(camera, patches, options);
        let mut stats = prepared.stats;
        let device = &self.gpu.device;
        let mut encoder = device.create_command_encoder(&Default::default());
        self.upload(&mut encoder, &prepared);
        let target = self.target.as_ref().expect("target made above");
        let color_view = target.color.create_view(&Default::default());
        let depth_view = target.depth.create_view(&Default::default());
        {
            let bg = options.background;
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("terrain"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &color_view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color {
                            r: bg[0],
                            g: bg[1],
                            b: bg[2],
                            a: bg[3],
                        }),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &depth_view,
                    depth_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Clear(if camera.reversed_z() { 0.0 } else { 1.0 }),
                        store: wgpu::StoreOp::Store,
                    }),
                    stencil_ops: None,
                }),
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            stats.draw_calls += self.draw(&mut pass, &prepared.groups, options);
        }
        stats.prepare_s = start.elapsed().as_secs_f64();
        Ok((encoder, stats))
    }

    /// Records the draw calls of a prepared frame into `pass`; returns how many.
    fn draw(
        &self,
        pass: &mut wgpu::RenderPass<'_>,
        groups: &[std::ops::Range<u32>; 8],
        options: &RenderOptions,
    ) -> u32 {
        let mut calls = 0;
        pass.set_bind_group(0, &self.bind_group, &[]);
        pass.set_index_buffer(self.index_buffer.slice(..), wgpu::IndexFormat::Uint32);
        let fill = if options.wireframe {
            &self.fill_under_lines
        } else {
            &self.fill
        };
        let mut passes = vec![fill];
        if options.wireframe {
            passes.push(self.lines.as_ref().expect("checked by render"));
        }
        let stride = std::mem::size_of::<PatchInstance>() as u64;
        for pipeline in passes {
            pass.set_pipeline(pipeline);
            for (kind, instances) in groups.iter().enumerate() {
                if instances.is_empty() {
                    continue;
                }
                let indices = self.mesh.ranges[kind].clone();
                if self.fetch == VertexFetch::Texture {
                    // The group's instances through the buffer's offset, not `first_instance`
                    // (which some GL versions lack: wgpu would emulate it by rebinding).
                    let bytes =
                        u64::from(instances.start) * stride..u64::from(instances.end) * stride;
                    pass.set_vertex_buffer(0, self.instances.slice(bytes));
                    pass.draw_indexed(indices, 0, 0..instances.len() as u32);
                } else {
                    pass.draw_indexed(indices, 0, instances.clone());
                }
                calls += 1;
            }
        }
        calls
    }

    /// Copies the frame's staged slots into the height pool: by `encoder` from a staging
    /// buffer, or through the queue into the pool texture.
    fn upload(&self, encoder: &mut wgpu::CommandEncoder, prepared: &Prepared) {
        let device = &self.gpu.device;
        let slot_bytes = self.slot_bytes();
        match &self.pool {
            HeightPool::Buffer(heights) if !prepared.staging.is_empty() => {
                let staging = buffer_init(
                    device,
                    "height uploads",
                    bytemuck::cast_slice(&prepared.staging),
                    wgpu::BufferUsages::COPY_SRC,
                );
                for (k, &slot) in prepared.upload_slots.iter().enumerate() {
                    encoder.copy_buffer_to_buffer(
                        &staging,
                        k as u64 * slot_bytes,
                        heights,
                        u64::from(slot) * slot_bytes,
                        slot_bytes,
                    );
                }
            }
            HeightPool::Buffer(_) => {}
            HeightPool::Texture(_) => {
                // Through the queue: done before this encoder's commands run once submitted.
                let words = slot_bytes as usize / 4;
                for (k, &slot) in prepared.upload_slots.iter().enumerate() {
                    self.pool.write_texture(
                        &self.gpu.queue,
                        u64::from(slot) * words as u64,
                        &prepared.staging[k * words..(k + 1) * words],
                    );
                }
            }
        }
    }

    fn write_instances(&mut self, instances: &[PatchInstance]) {
        let needed = instances.len() as u64;
        if needed > self.instance_capacity {
            self.instance_capacity = needed.next_power_of_two();
            self.instances = instance_buffer(&self.gpu.device, self.fetch, self.instance_capacity);
            self.bind_group = bind_group(
                &self.gpu.device,
                &self.layout,
                &self.uniform,
                &self.instances,
                &self.pool,
            );
        }
        if !instances.is_empty() {
            self.gpu
                .queue
                .write_buffer(&self.instances, 0, bytemuck::cast_slice(instances));
        }
    }
}

/// Bytes of one slot: `N²` heights, `N²` colours when draped, `6 N²` position words on a planet.
fn slot_bytes(n: usize, draped: bool, planet: bool) -> u64 {
    (n * n * 4) as u64 * (1 + u64::from(draped) + 6 * u64::from(planet))
}
