//! The offscreen colour and depth targets a [`Renderer`] draws into, and reading them back.

use crate::{COLOR_FORMAT, DEPTH_FORMAT, Renderer};
#[cfg(not(target_arch = "wasm32"))]
use crate::{DrawError, DrawStats, Frame};

/// The colour and depth textures of the last frame's size.
pub(crate) struct Target {
    pub(crate) size: (u32, u32),
    pub(crate) color: wgpu::Texture,
    pub(crate) depth: wgpu::Texture,
}

impl Renderer {
    /// The offscreen colour target ([`COLOR_FORMAT`]) of the last frame, once there is one.
    pub fn color_texture(&self) -> Option<&wgpu::Texture> {
        self.target.as_ref().map(|t| &t.color)
    }

    /// Reads the colour target back (RGBA8, top row first) after the commands that drew it were
    /// submitted; waits for the GPU (native targets only).
    #[cfg(not(target_arch = "wasm32"))]
    pub fn read_color(&self) -> Result<Frame, DrawError> {
        let target = self
            .target
            .as_ref()
            .ok_or_else(|| DrawError::Gpu("nothing rendered yet".into()))?;
        let rgba = self.read_texture(&target.color, target.size, 4)?;
        Ok(Frame {
            width: target.size.0,
            height: target.size.1,
            rgba,
            depth: None,
            stats: DrawStats::default(),
        })
    }

    /// Makes the targets `size`, unless they are already.
    pub(crate) fn ensure_target(&mut self, size: (u32, u32)) {
        if self.target.as_ref().is_some_and(|t| t.size == size) {
            return;
        }
        let tex = |label, format, usage| {
            self.gpu.device.create_texture(&wgpu::TextureDescriptor {
                label: Some(label),
                size: wgpu::Extent3d {
                    width: size.0,
                    height: size.1,
                    depth_or_array_layers: 1,
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage,
                view_formats: &[],
            })
        };
        let usage = wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC;
        self.target = Some(Target {
            size,
            // A window samples the colour target to present it.
            color: tex(
                "colour",
                COLOR_FORMAT,
                usage | wgpu::TextureUsages::TEXTURE_BINDING,
            ),
            depth: tex("depth", DEPTH_FORMAT, usage),
        });
    }

    #[cfg(not(target_arch = "wasm32"))]
    pub(crate) fn wait(&self) -> Result<(), DrawError> {
        self.gpu
            .device
            .poll(wgpu::PollType::wait_indefinitely())
            .map(|_| ())
            .map_err(|e| DrawError::Gpu(e.to_string()))
    }

    /// Copies a texture with `bpp` bytes per pixel into a tightly packed byte vector.
    #[cfg(not(target_arch = "wasm32"))]
    pub(crate) fn read_texture(
        &self,
        texture: &wgpu::Texture,
        size: (u32, u32),
        bpp: u32,
    ) -> Result<Vec<u8>, DrawError> {
        let row = size.0 * bpp;
        let padded =
            row.div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT) * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
        let buffer = self.gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: u64::from(padded) * u64::from(size.1),
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut encoder = self.gpu.device.create_command_encoder(&Default::default());
        encoder.copy_texture_to_buffer(
            wgpu::TexelCopyTextureInfo {
                texture,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            wgpu::TexelCopyBufferInfo {
                buffer: &buffer,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(padded),
                    rows_per_image: Some(size.1),
                },
            },
            wgpu::Extent3d {
                width: size.0,
                height: size.1,
                depth_or_array_layers: 1,
            },
        );
        self.gpu.queue.submit([encoder.finish()]);
        let (tx, rx) = std::sync::mpsc::channel();
        buffer.map_async(wgpu::MapMode::Read, .., move |r| {
            let _ = tx.send(r);
        });
        self.wait()?;
        rx.recv()
            .map_err(|e| DrawError::Gpu(e.to_string()))?
            .map_err(|e| DrawError::Gpu(e.to_string()))?;
        let mut out = Vec::with_capacity((row * size.1) as usize);
        {
            let view = buffer
                .get_mapped_range(..)
                .map_err(|e| DrawError::Gpu(e.to_string()))?;
            for y in 0..size.1 as usize {
                let start = y * padded as usize;
                out.extend_from_slice(&view[start..start + row as usize]);
            }
        }
        buffer.unmap();
        Ok(out)
    }
}
