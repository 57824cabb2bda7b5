//! The terrain pipelines and the GPU objects they bind: the bind group layout, the
//! pipelines (fill, wireframe, level colours), the instance buffer and the bind group.

use crate::instances::PatchInstance;
use crate::pool::HeightPool;
use crate::{COLOR_FORMAT, DEPTH_FORMAT, VertexFetch, terrain_shader};

/// The terrain bind group's layout: the frame uniform, the patch instances when vertices read
/// storage buffers, and the height pool.
pub(crate) fn terrain_layout(
    device: &wgpu::Device,
    fetch: VertexFetch,
    heights: &HeightPool,
) -> wgpu::BindGroupLayout {
    let storage = |binding| wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::VERTEX,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only: true },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    };
    let mut entries = vec![wgpu::BindGroupLayoutEntry {
        binding: 0,
        visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }];
    if fetch == VertexFetch::StorageBuffers {
        entries.push(storage(1));
    }
    entries.push(heights.layout_entry());
    device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some("terrain"),
        entries: &entries,
    })
}

/// The terrain's three pipelines: filled, filled under a wireframe, and the wireframe (where the
/// device draws lines).
pub(crate) struct TerrainPipelines {
    pub(crate) fill: wgpu::RenderPipeline,
    pub(crate) fill_under_lines: wgpu::RenderPipeline,
    pub(crate) lines: Option<wgpu::RenderPipeline>,
}

impl TerrainPipelines {
    /// The pipelines over `layout` for `fetch`, with reversed depth (nearer is greater) when
    /// `reversed`.
    pub(crate) fn new(
        device: &wgpu::Device,
        layout: &wgpu::BindGroupLayout,
        fetch: VertexFetch,
        reversed: bool,
    ) -> Self {
        let shader = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("terrain.wgsl"),
            source: wgpu::ShaderSource::Wgsl(terrain_shader(fetch).into()),
        });
        // The texture path's patches: one `PatchInstance` per instance (terrain_texture.wgsl).
        let instance_attributes = patch_attributes();
        let instance_layout = [Some(wgpu::VertexBufferLayout {
            array_stride: std::mem::size_of::<PatchInstance>() as u64,
            step_mode: wgpu::VertexStepMode::Instance,
            attributes: &instance_attributes,
        })];
        let vertex_buffers: &[Option<wgpu::VertexBufferLayout>] = if fetch == VertexFetch::Texture {
            &instance_layout
        } else {
            &[]
        };
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("terrain"),
            bind_group_layouts: &[Some(layout)],
            immediate_size: 0,
        });
        let base = PipelineBase {
            device,
            layout: &pipeline_layout,
            shader: &shader,
            vertex_buffers,
        };
        let (less, less_equal, back) = if reversed {
            (
                wgpu::CompareFunction::Greater,
                wgpu::CompareFunction::GreaterEqual,
                -1,
            )
        } else {
            (
                wgpu::CompareFunction::Less,
                wgpu::CompareFunction::LessEqual,
                1,
            )
        };
        let fill = base.pipeline(wgpu::PolygonMode::Fill, Default::default(), less, "fs_main");
        // Under a wireframe the surface is pushed back a little so the lines win the depth test.
        let fill_under_lines = base.pipeline(
            wgpu::PolygonMode::Fill,
            wgpu::DepthBiasState {
                constant: 2 * back,
                slope_scale: back as f32,
                clamp: 0.0,
            },
            less,
            "fs_main",
        );
        let lines = device
            .features()
            .contains(wgpu::Features::POLYGON_MODE_LINE)
            .then(|| {
                base.pipeline(
                    wgpu::PolygonMode::Line,
                    Default::default(),
                    less_equal,
                    "fs_wire",
                )
            });
        TerrainPipelines {
            fill,
            fill_under_lines,
            lines,
        }
    }
}

/// What the terrain's pipelines share: the device, the layout, the shader and the vertex
/// buffers (the texture path's patch instances, or none).
struct PipelineBase<'a> {
    device: &'a wgpu::Device,
    layout: &'a wgpu::PipelineLayout,
    shader: &'a wgpu::ShaderModule,
    vertex_buffers: &'a [Option<wgpu::VertexBufferLayout<'a>>],
}

impl PipelineBase<'_> {
    /// A terrain pipeline drawing `polygon_mode` with depth `bias` and `compare`, coloured by
    /// the fragment entry point `fs` (the wireframe's, `fs_wire`, blends).
    fn pipeline(
        &self,
        polygon_mode: wgpu::PolygonMode,
        bias: wgpu::DepthBiasState,
        compare: wgpu::CompareFunction,
        fs: &str,
    ) -> wgpu::RenderPipeline {
        let blend = (fs == "fs_wire").then_some(wgpu::BlendState::ALPHA_BLENDING);
        self.device
            .create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some("terrain"),
                layout: Some(self.layout),
                vertex: wgpu::VertexState {
                    module: self.shader,
                    entry_point: Some("vs_main"),
                    compilation_options: Default::default(),
                    buffers: self.vertex_buffers,
                },
                primitive: wgpu::PrimitiveState {
                    topology: wgpu::PrimitiveTopology::TriangleList,
                    front_face: wgpu::FrontFace::Ccw,
                    // Terrain is a height field seen from above: back faces are never wanted,
                    // and culling them makes any crack show the background.
                    cull_mode: Some(wgpu::Face::Back),
                    polygon_mode,
                    ..Default::default()
                },
                depth_stencil: Some(wgpu::DepthStencilState {
                    format: DEPTH_FORMAT,
                    depth_write_enabled: Some(true),
                    depth_compare: Some(compare),
                    stencil: Default::default(),
                    bias,
                }),
                multisample: Default::default(),
                fragment: Some(wgpu::FragmentState {
                    module: self.shader,
                    entry_point: Some(fs),
                    compilation_options: Default::default(),
                    targets: &[Some(wgpu::ColorTargetState {
                        format: COLOR_FORMAT,
                        blend,
                        write_mask: wgpu::ColorWrites::ALL,
                    })],
                }),
                multiview_mask: None,
                cache: None,
            })
    }
}

pub(crate) fn buffer_init(
    device: &wgpu::Device,
    label: &str,
    contents: &[u8],
    usage: wgpu::BufferUsages,
) -> wgpu::Buffer {
    use wgpu::util::DeviceExt;
    device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some(label),
        contents,
        usage,
    })
}

pub(crate) fn instance_buffer(
    device: &wgpu::Device,
    fetch: VertexFetch,
    capacity: u64,
) -> wgpu::Buffer {
    let usage = if fetch == VertexFetch::Texture {
        wgpu::BufferUsages::VERTEX
    } else {
        wgpu::BufferUsages::STORAGE
    };
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("patch instances"),
        size: capacity * std::mem::size_of::<PatchInstance>() as u64,
        usage: usage | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

/// `PatchInstance` as the texture path's vertex attributes (`PatchAttributes` in
/// `shaders/terrain_texture.wgsl`); the padding is not read.
fn patch_attributes() -> [wgpu::VertexAttribute; 7] {
    use std::mem::offset_of;
    use wgpu::VertexFormat as F;
    let attribute = |shader_location, format, offset: usize| wgpu::VertexAttribute {
        format,
        offset: offset as u64,
        shader_location,
    };
    [
        attribute(0, F::Float32x4, offset_of!(PatchInstance, origin_rel)),
        attribute(1, F::Float32x2, offset_of!(PatchInstance, v_world)),
        attribute(2, F::Sint32x4, offset_of!(PatchInstance, origin_lat)),
        attribute(3, F::Sint32x2, offset_of!(PatchInstance, v_lat)),
        attribute(4, F::Uint32x4, offset_of!(PatchInstance, slot)),
        attribute(5, F::Float32x2, offset_of!(PatchInstance, origin_z)),
        attribute(6, F::Float32x3, offset_of!(PatchInstance, origin_lo)),
    ]
}

pub(crate) fn bind_group(
    device: &wgpu::Device,
    layout: &wgpu::BindGroupLayout,
    uniform: &wgpu::Buffer,
    instances: &wgpu::Buffer,
    pool: &HeightPool,
) -> wgpu::BindGroup {
    let view;
    let mut entries = vec![wgpu::BindGroupEntry {
        binding: 0,
        resource: uniform.as_entire_binding(),
    }];
    match pool {
        HeightPool::Buffer(heights) => entries.extend([
            wgpu::BindGroupEntry {
                binding: 1,
                resource: instances.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 2,
                resource: heights.as_entire_binding(),
            },
        ]),
        HeightPool::Texture(texture) => {
            view = texture.create_view(&Default::default());
            entries.push(wgpu::BindGroupEntry {
                binding: 2,
                resource: wgpu::BindingResource::TextureView(&view),
            });
        }
    }
    device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("terrain"),
        layout,
        entries: &entries,
    })
}
