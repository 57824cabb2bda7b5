//! The viewer's text overlay (HUD): a few short lines of ASCII text in an 8×8 bitmap font over
//! a translucent box in the top-left corner, drawn over a frame already in the offscreen colour
//! target. It is meant as a small label, not a panel: the viewer keeps its text within
//! [`MAX_LINES`] lines of [`MAX_COLUMNS`] characters, and glyphs are drawn at their own size
//! (8 pixels) unless the window is very tall.
//!
//! [`layout`] is pure (one [`HudQuad`] per visible glyph plus the box) so it can be tested
//! without a GPU; [`Hud`] uploads the font once as an R8 texture and draws the quads instanced
//! (`shaders/hud.wgsl`).

use bytemuck::{Pod, Zeroable};

use super::COLOR_FORMAT;

/// The HUD shader (entry points `vs_main`, `fs_main`).
pub const HUD_WGSL: &str = include_str!("../../../shaders/hud.wgsl");

/// Text colour, RGBA8 (opaque, so text pixels have exactly this colour).
pub const TEXT_RGBA: [u8; 4] = [255, 214, 64, 255];
/// Background box colour, RGBA8: black at 50 % opacity, so the terrain under it stays visible
/// (every channel under it is half, + rounding, of what was there) and the text stays legible.
pub const BOX_RGBA: [u8; 4] = [0, 0, 0, 128];
/// Glyph code of the background box in [`HudQuad::glyph`] (past ASCII).
pub const BOX_GLYPH: u32 = 0x100;

/// Pixels from the viewport's top-left corner to the box, at scale 1.
const MARGIN: u32 = 8;
/// Pixels between the box edge and the text, at scale 1.
const PADDING: u32 = 4;
/// Line pitch at scale 1: 8-pixel glyphs and a 2-pixel gap.
const LINE: u32 = 10;
/// Most lines the viewer shows (its tests check its text against this budget).
pub const MAX_LINES: usize = 9;
/// Most characters in a line the viewer shows.
pub const MAX_COLUMNS: usize = 44;
/// Windows this tall and taller (4K and most 1440p screens, whose pixels are small) get glyphs
/// at twice their size.
const LARGE_ROWS: u32 = 1440;

/// One instanced quad: a glyph cell or the box, in viewport pixels (y down).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct HudQuad {
    /// Top-left corner, pixels.
    pub pos: [f32; 2],
    /// Width and height, pixels.
    pub size: [f32; 2],
    /// ASCII code, or [`BOX_GLYPH`].
    pub glyph: u32,
    /// RGBA8 (straight alpha).
    pub rgba: [u8; 4],
}

/// Glyph scale for a viewport: 8-pixel text, 16-pixel from [`LARGE_ROWS`] rows up.
pub fn scale_for(viewport: (u32, u32)) -> u32 {
    if viewport.1 >= LARGE_ROWS { 2 } else { 1 }
}

/// The box (first) and glyph quads of `lines` at `scale` in a `viewport`. Characters outside
/// printable ASCII show as `?`; spaces make no quad. Nothing is placed outside the viewport:
/// the box is clipped to it and glyphs that would not fit whole are dropped.
pub fn layout(lines: &[String], viewport: (u32, u32), scale: u32) -> Vec<HudQuad> {
    let scale = scale.max(1);
    let (vw, vh) = (viewport.0 as f32, viewport.1 as f32);
    let cell = (8 * scale) as f32;
    let pitch = (LINE * scale) as f32;
    let pad = (PADDING * scale) as f32;
    let origin = (MARGIN * scale) as f32;
    let columns = lines.iter().map(|l| l.chars().count()).max().unwrap_or(0);
    let mut quads = Vec::new();
    if columns == 0 || origin >= vw || origin >= vh {
        return quads;
    }
    let box_w = (columns as f32 * cell + 2.0 * pad).min(vw - origin);
    let box_h = (lines.len() as f32 * pitch - (pitch - cell) + 2.0 * pad).min(vh - origin);
    quads.push(HudQuad {
        pos: [origin, origin],
        size: [box_w, box_h],
        glyph: BOX_GLYPH,
        rgba: BOX_RGBA,
    });
    for (row, line) in lines.iter().enumerate() {
        let y = origin + pad + row as f32 * pitch;
        if y + cell > vh {
            break;
        }
        for (col, ch) in line.chars().enumerate() {
            let x = origin + pad + col as f32 * cell;
            if x + cell > vw {
                break;
            }
            let code = match ch {
                ' ' => continue,
                '!'..='~' => ch as u32,
                _ => u32::from(b'?'),
            };
            quads.push(HudQuad {
                pos: [x, y],
                size: [cell, cell],
                glyph: code,
                rgba: TEXT_RGBA,
            });
        }
    }
    quads
}

/// The 128 ASCII glyphs side by side, 1024×8 R8 texels (255 where a glyph pixel is set).
fn font_texels() -> Vec<u8> {
    let mut texels = vec![0u8; 128 * 8 * 8];
    for (code, rows) in font8x8::legacy::BASIC_LEGACY.iter().enumerate() {
        for (y, bits) in rows.iter().enumerate() {
            for x in 0..8 {
                // font8x8 stores the leftmost pixel in the lowest bit.
                if bits >> x & 1 == 1 {
                    texels[y * 1024 + code * 8 + x] = 255;
                }
            }
        }
    }
    texels
}

/// Draws HUD quads over the renderer's colour target ([`COLOR_FORMAT`]).
pub struct Hud {
    pipeline: wgpu::RenderPipeline,
    bind_group: wgpu::BindGroup,
    screen: wgpu::Buffer,
    quads: wgpu::Buffer,
    capacity: u64,
}

impl Hud {
    /// Compiles the shader and uploads the font.
    pub fn new(device: &wgpu::Device, queue: &wgpu::Queue) -> Self {
        let font = font_texture(device, queue);
        let screen = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("hud screen"),
            size: 16,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("hud"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::VERTEX,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: false },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
            ],
        });
        let font_view = font.create_view(&Default::default());
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("hud"),
            layout: &layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: screen.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::TextureView(&font_view),
                },
            ],
        });
        let pipeline = pipeline(device, &layout);
        let capacity = 256;
        Self {
            quads: quad_buffer(device, capacity),
            pipeline,
            bind_group,
            screen,
            capacity,
        }
    }

    /// Records drawing `quads` (from [`layout`]) over `target` (a [`COLOR_FORMAT`] view of
    /// `viewport` pixels), keeping what is there.
    pub fn draw(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        encoder: &mut wgpu::CommandEncoder,
        target: &wgpu::TextureView,
        viewport: (u32, u32),
        quads: &[HudQuad],
    ) {
        if quads.is_empty() {
            return;
        }
        if quads.len() as u64 > self.capacity {
            self.capacity = (quads.len() as u64).next_power_of_two();
            self.quads = quad_buffer(device, self.capacity);
        }
        queue.write_buffer(&self.quads, 0, bytemuck::cast_slice(quads));
        let screen = [viewport.0 as f32, viewport.1 as f32, 0.0, 0.0];
        queue.write_buffer(&self.screen, 0, bytemuck::cast_slice(&screen));
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("hud"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: target,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Load,
                    store: wgpu::StoreOp::Store,
                },
            })],
            depth_stencil_attachment: None,
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &self.bind_group, &[]);
        pass.set_vertex_buffer(0, self.quads.slice(..));
        pass.draw(0..4, 0..quads.len() as u32);
    }
}

fn quad_buffer(device: &wgpu::Device, capacity: u64) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("hud quads"),
        size: capacity * std::mem::size_of::<HudQuad>() as u64,
        usage: wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

/// The font ([`font_texels`]) as a texture.
fn font_texture(device: &wgpu::Device, queue: &wgpu::Queue) -> wgpu::Texture {
    let font = device.create_texture(&wgpu::TextureDescriptor {
        label: Some("hud font"),
        size: wgpu::Extent3d {
            width: 1024,
            height: 8,
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: wgpu::TextureFormat::R8Unorm,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    });
    queue.write_texture(
        wgpu::TexelCopyTextureInfo {
            texture: &font,
            mip_level: 0,
            origin: wgpu::Origin3d::ZERO,
            aspect: wgpu::TextureAspect::All,
        },
        &font_texels(),
        wgpu::TexelCopyBufferLayout {
            offset: 0,
            bytes_per_row: Some(1024),
            rows_per_image: Some(8),
        },
        wgpu::Extent3d {
            width: 1024,
            height: 8,
            depth_or_array_layers: 1,
        },
    );
    font
}

/// The HUD's pipeline: instanced quads blended over the colour target.
fn pipeline(device: &wgpu::Device, layout: &wgpu::BindGroupLayout) -> wgpu::RenderPipeline {
    let shader = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some("hud.wgsl"),
        source: wgpu::ShaderSource::Wgsl(HUD_WGSL.into()),
    });
    let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some("hud"),
        bind_group_layouts: &[Some(layout)],
        immediate_size: 0,
    });
    let attributes = wgpu::vertex_attr_array![
        0 => Float32x2, 1 => Float32x2, 2 => Uint32, 3 => Unorm8x4
    ];
    device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some("hud"),
        layout: Some(&pipeline_layout),
        vertex: wgpu::VertexState {
            module: &shader,
            entry_point: Some("vs_main"),
            compilation_options: Default::default(),
            buffers: &[Some(wgpu::VertexBufferLayout {
                array_stride: std::mem::size_of::<HudQuad>() as u64,
                step_mode: wgpu::VertexStepMode::Instance,
                attributes: &attributes,
            })],
        },
        primitive: wgpu::PrimitiveState {
            topology: wgpu::PrimitiveTopology::TriangleStrip,
            ..Default::default()
        },
        depth_stencil: None,
        multisample: Default::default(),
        fragment: Some(wgpu::FragmentState {
            module: &shader,
            entry_point: Some("fs_main"),
            compilation_options: Default::default(),
            targets: &[Some(wgpu::ColorTargetState {
                format: COLOR_FORMAT,
                // Colour blends over the frame; alpha stays opaque (screenshots, PNGs).
                blend: Some(wgpu::BlendState {
                    color: wgpu::BlendState::ALPHA_BLENDING.color,
                    alpha: wgpu::BlendComponent::OVER,
                }),
                write_mask: wgpu::ColorWrites::ALL,
            })],
        }),
        multiview_mask: None,
        cache: None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lines(v: &[&str]) -> Vec<String> {
        v.iter().map(|s| s.to_string()).collect()
    }

    fn inside(q: &HudQuad, viewport: (u32, u32)) -> bool {
        q.pos[0] >= 0.0
            && q.pos[1] >= 0.0
            && q.pos[0] + q.size[0] <= viewport.0 as f32
            && q.pos[1] + q.size[1] <= viewport.1 as f32
    }

    #[test]
    fn one_quad_per_visible_character_plus_the_box() {
        let text = lines(&["fps 12.5", "cut: 300 diamonds", "é"]);
        let quads = layout(&text, (1920, 1080), 2);
        let visible: usize = text
            .iter()
            .map(|l| l.chars().filter(|c| *c != ' ').count())
            .sum();
        assert_eq!(quads.len(), visible + 1);
        assert_eq!(quads[0].glyph, BOX_GLYPH);
        assert!(
            quads[1..]
                .iter()
                .all(|q| q.glyph < 128 && q.rgba == TEXT_RGBA)
        );
        // Non-ASCII shows as '?'.
        assert_eq!(quads.last().unwrap().glyph, u32::from(b'?'));
        // Every glyph lies inside the box, in reading order.
        let b = quads[0];
        for q in &quads[1..] {
            assert!(q.pos[0] >= b.pos[0] && q.pos[0] + q.size[0] <= b.pos[0] + b.size[0]);
            assert!(q.pos[1] >= b.pos[1] && q.pos[1] + q.size[1] <= b.pos[1] + b.size[1]);
        }
        assert!(quads[1..].windows(2).all(|w| w[0].pos[1] < w[1].pos[1]
            || (w[0].pos[1] == w[1].pos[1] && w[0].pos[0] < w[1].pos[0])));
    }

    #[test]
    fn nothing_outside_a_small_viewport() {
        let text = lines(&["a line much too long for a tiny window", "x", "y", "z", "w"]);
        for viewport in [(64, 30), (120, 48), (7, 7), (1, 1), (300, 200)] {
            let quads = layout(&text, viewport, 1);
            assert!(
                quads.iter().all(|q| inside(q, viewport)),
                "{viewport:?}: {quads:?}"
            );
        }
        // A small window shows fewer glyphs than a large one, never partial ones.
        let small = layout(&text, (64, 30), 1).len();
        let large = layout(&text, (1000, 1000), 1).len();
        assert!(small < large, "{small} vs {large}");
        assert!(layout(&[], (100, 100), 1).is_empty());
    }

    #[test]
    fn glyphs_are_doubled_only_on_very_tall_windows() {
        for size in [
            (320, 240),
            (1280, 720),
            (1920, 1080),
            (1920, 1200),
            (2560, 1439),
        ] {
            assert_eq!(scale_for(size), 1, "{size:?}");
        }
        for size in [(2560, 1440), (3840, 2160)] {
            assert_eq!(scale_for(size), 2, "{size:?}");
        }
    }

    /// The fullest HUD the viewer shows (its budget of lines and columns, every cell a glyph)
    /// is a label in the top-left corner, not a panel over the view: under 2 % of a full-HD
    /// window (360 × 96 pixels; the HUD before this budget covered about 13 %, 1 380 × 200),
    /// under 4 % of the viewer's default 1280×720 window and of the common screen sizes, and
    /// nowhere past the top-left quarter of the window.
    #[test]
    fn a_full_hud_is_a_small_label_in_the_corner() {
        let text = vec!["W".repeat(MAX_COLUMNS); MAX_LINES];
        let area = |viewport: (u32, u32)| {
            let quads = layout(&text, viewport, scale_for(viewport));
            assert_eq!(
                quads.len(),
                1 + MAX_LINES * MAX_COLUMNS,
                "{viewport:?}: all shown"
            );
            let b = quads[0];
            assert_eq!(b.glyph, BOX_GLYPH);
            assert_eq!(b.pos, [(MARGIN * scale_for(viewport)) as f32; 2]);
            assert!(
                b.pos[0] + b.size[0] <= viewport.0 as f32 / 2.0,
                "{viewport:?}: {b:?}"
            );
            assert!(
                b.pos[1] + b.size[1] <= viewport.1 as f32 / 2.0,
                "{viewport:?}: {b:?}"
            );
            f64::from(b.size[0] * b.size[1]) / f64::from(viewport.0 * viewport.1)
        };
        let full_hd = area((1920, 1080));
        assert!(full_hd < 0.02, "{:.1} % of 1920×1080", 100.0 * full_hd);
        for viewport in [(1280, 720), (1366, 768), (2560, 1440), (3840, 2160)] {
            let a = area(viewport);
            assert!(a < 0.04, "{:.1} % of {viewport:?}", 100.0 * a);
        }
    }

    #[test]
    fn font_has_the_letters() {
        let texels = font_texels();
        let lit = |code: usize| {
            (0..8)
                .flat_map(|y| (0..8).map(move |x| (x, y)))
                .filter(|&(x, y)| texels[y * 1024 + code * 8 + x] == 255)
                .count()
        };
        assert_eq!(lit(usize::from(b' ')), 0);
        assert!(lit(usize::from(b'A')) > 10);
        assert_ne!(lit(usize::from(b'I')), lit(usize::from(b'W')));
    }
}
