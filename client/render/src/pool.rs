//! The GPU height pool: where the vertex shader reads the slots' words from.
//!
//! Two ways, chosen per adapter ([`VertexFetch`]): a storage buffer of `i32` words (WebGPU and the
//! native backends), or, where vertex shaders cannot read storage buffers (WebGL2), an `R32Sint`
//! 2-D texture of [`POOL_TEXTURE_WIDTH`] texels a row holding the same words in the same order,
//! row after row, read with `textureLoad`. The slots' layout, the cache and the shader's maths are
//! the same; only `pool_word` in the shader and the copies here differ. The texture's width is
//! fixed (2048 texels, what WebGL2 guarantees for any texture side) and it grows in rows, up to
//! the adapter's `max_texture_dimension_2d`; slots are not aligned to rows (no texel is wasted),
//! so a slot's upload is up to three rectangles ([`texel_runs`]).

use crate::DrawError;

/// Texels a row of the texture height pool (`POOL_WIDTH` in `shaders/terrain_texture.wgsl`).
pub const POOL_TEXTURE_WIDTH: u32 = 2048;

/// Where the terrain's vertex shader reads the patches and the height pool from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum VertexFetch {
    /// Storage buffers where the adapter lets vertex shaders read them ([`crate::Gpu::vertex_storage`]),
    /// else [`VertexFetch::Texture`].
    #[default]
    Auto,
    /// The patches and the height pool in storage buffers (`shaders/terrain_storage.wgsl`).
    StorageBuffers,
    /// The patches as an instance-stepped vertex buffer, the height pool in an `R32Sint` texture
    /// (`shaders/terrain_texture.wgsl`): what WebGL2 can do. Any adapter can be made to use it
    /// (the tests draw both ways on the same device).
    Texture,
}

impl VertexFetch {
    /// `self` with [`VertexFetch::Auto`] decided for an adapter that has (or lacks) storage
    /// buffers in vertex shaders; an error when storage buffers are asked for and missing.
    pub fn resolve(self, vertex_storage: bool) -> Result<VertexFetch, DrawError> {
        match self {
            VertexFetch::Auto if vertex_storage => Ok(VertexFetch::StorageBuffers),
            VertexFetch::Auto => Ok(VertexFetch::Texture),
            VertexFetch::StorageBuffers if !vertex_storage => Err(DrawError::Unsupported(
                "this adapter's vertex shaders cannot read storage buffers \
                 (DownlevelFlags::VERTEX_STORAGE): use VertexFetch::Texture or Auto"
                    .into(),
            )),
            other => Ok(other),
        }
    }
}

/// The height pool on the GPU.
pub(crate) enum HeightPool {
    /// A storage buffer of words.
    Buffer(wgpu::Buffer),
    /// An `R32Sint` texture, [`POOL_TEXTURE_WIDTH`] words a row.
    Texture(wgpu::Texture),
}

impl HeightPool {
    /// Most bytes a pool of this kind may have on `device`.
    pub(crate) fn max_bytes(fetch: VertexFetch, limits: &wgpu::Limits) -> u64 {
        match fetch {
            VertexFetch::Texture => {
                u64::from(POOL_TEXTURE_WIDTH) * u64::from(limits.max_texture_dimension_2d) * 4
            }
            _ => limits
                .max_storage_buffer_binding_size
                .min(limits.max_buffer_size),
        }
    }

    /// A pool of `bytes` (a whole number of words, at most [`HeightPool::max_bytes`]).
    pub(crate) fn new(
        device: &wgpu::Device,
        fetch: VertexFetch,
        bytes: u64,
    ) -> Result<Self, DrawError> {
        if fetch != VertexFetch::Texture {
            return Ok(HeightPool::Buffer(device.create_buffer(
                &wgpu::BufferDescriptor {
                    label: Some("height pool"),
                    size: bytes,
                    usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                    mapped_at_creation: false,
                },
            )));
        }
        let max_side = device.limits().max_texture_dimension_2d;
        if max_side < POOL_TEXTURE_WIDTH {
            return Err(DrawError::Unsupported(format!(
                "textures of at most {max_side} texels a side; the height pool texture needs \
                 {POOL_TEXTURE_WIDTH}"
            )));
        }
        let rows = (bytes / 4).div_ceil(u64::from(POOL_TEXTURE_WIDTH)).max(1);
        let rows = u32::try_from(rows)
            .ok()
            .filter(|&r| r <= max_side)
            .ok_or_else(|| {
                DrawError::Unsupported(format!(
                    "a height pool of {bytes} bytes needs {rows} texture rows; the adapter \
                     allows {max_side}"
                ))
            })?;
        Ok(HeightPool::Texture(device.create_texture(
            &wgpu::TextureDescriptor {
                label: Some("height pool"),
                size: wgpu::Extent3d {
                    width: POOL_TEXTURE_WIDTH,
                    height: rows,
                    depth_or_array_layers: 1,
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: wgpu::TextureFormat::R32Sint,
                usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
                view_formats: &[],
            },
        )))
    }

    /// The pool's entry (binding 2) of the terrain's bind group layout.
    pub(crate) fn layout_entry(&self) -> wgpu::BindGroupLayoutEntry {
        let ty = match self {
            HeightPool::Buffer(_) => wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only: true },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            HeightPool::Texture(_) => wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Sint,
                view_dimension: wgpu::TextureViewDimension::D2,
                multisampled: false,
            },
        };
        wgpu::BindGroupLayoutEntry {
            binding: 2,
            visibility: wgpu::ShaderStages::VERTEX,
            ty,
            count: None,
        }
    }

    /// Writes `words` at word `first` of the pool through the queue (before the next submitted
    /// commands run). The buffer pool is written by copies in the frame's encoder instead
    /// ([`crate::Renderer::encode`]): this is for the texture.
    pub(crate) fn write_texture(&self, queue: &wgpu::Queue, first: u64, words: &[i32]) {
        let HeightPool::Texture(texture) = self else {
            return;
        };
        let bytes: &[u8] = bytemuck::cast_slice(words);
        for run in texel_runs(first, words.len() as u64, POOL_TEXTURE_WIDTH) {
            queue.write_texture(
                wgpu::TexelCopyTextureInfo {
                    texture,
                    mip_level: 0,
                    origin: wgpu::Origin3d {
                        x: run.x,
                        y: run.y,
                        z: 0,
                    },
                    aspect: wgpu::TextureAspect::All,
                },
                &bytes[run.word as usize * 4..],
                wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(run.width * 4),
                    rows_per_image: Some(run.rows),
                },
                wgpu::Extent3d {
                    width: run.width,
                    height: run.rows,
                    depth_or_array_layers: 1,
                },
            );
        }
    }
}

/// A rectangle of texels holding consecutive pool words.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct TexelRun {
    /// First texel's column and row.
    pub x: u32,
    /// See `x`.
    pub y: u32,
    /// Texels a row.
    pub width: u32,
    /// Rows.
    pub rows: u32,
    /// Index of its first word among the words written.
    pub word: u64,
}

/// The rectangles holding `words` consecutive words from word `first` in a texture `width`
/// texels wide: the rest of the first row, whole rows, the start of the last row (each only
/// where not empty).
pub(crate) fn texel_runs(first: u64, words: u64, width: u32) -> Vec<TexelRun> {
    let w = u64::from(width);
    let mut runs = Vec::with_capacity(3);
    let (mut at, mut done) = (first, 0);
    let mut push = |at: u64, texels: u64, rows: u64, done: u64| {
        runs.push(TexelRun {
            x: (at % w) as u32,
            y: (at / w) as u32,
            width: texels as u32,
            rows: rows as u32,
            word: done,
        });
    };
    if at % w != 0 && words > 0 {
        let head = (w - at % w).min(words);
        push(at, head, 1, done);
        at += head;
        done += head;
    }
    let rows = (words - done) / w;
    if rows > 0 {
        push(at, w, rows, done);
        at += rows * w;
        done += rows * w;
    }
    if done < words {
        push(at, words - done, 1, done);
    }
    runs
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every word lands at texel (i mod W, i div W), exactly once, for starts and lengths
    /// around row boundaries.
    #[test]
    fn runs_cover_each_word_once_in_row_order() {
        let width = 8;
        for first in 0..20u64 {
            for words in 0..30u64 {
                let mut seen = vec![None; 64];
                let runs = texel_runs(first, words, width);
                assert!(runs.len() <= 3, "{first} {words}: {runs:?}");
                for r in &runs {
                    assert!(r.width > 0 && r.rows > 0 && r.x + r.width <= width, "{r:?}");
                    assert!(r.rows == 1 || (r.x == 0 && r.width == width), "{r:?}");
                    for row in 0..r.rows {
                        for col in 0..r.width {
                            let word = r.word + u64::from(row * r.width + col);
                            let texel = u64::from((r.y + row) * width + r.x + col);
                            assert!(seen[texel as usize].is_none(), "{first} {words}: twice");
                            seen[texel as usize] = Some(word);
                        }
                    }
                }
                for (texel, word) in seen.iter().enumerate() {
                    let inside = (first..first + words).contains(&(texel as u64));
                    assert_eq!(
                        *word,
                        inside.then(|| texel as u64 - first),
                        "{first} {words}"
                    );
                }
            }
        }
    }

    #[test]
    fn shader_width_matches() {
        let wgsl = include_str!("../../../shaders/terrain_texture.wgsl");
        assert!(wgsl.contains(&format!("const POOL_WIDTH: u32 = {POOL_TEXTURE_WIDTH}u;")));
    }

    #[test]
    fn auto_picks_storage_only_where_vertex_shaders_read_it() {
        assert_eq!(
            VertexFetch::Auto.resolve(true).unwrap(),
            VertexFetch::StorageBuffers
        );
        assert_eq!(
            VertexFetch::Auto.resolve(false).unwrap(),
            VertexFetch::Texture
        );
        assert_eq!(
            VertexFetch::Texture.resolve(true).unwrap(),
            VertexFetch::Texture
        );
        assert!(VertexFetch::StorageBuffers.resolve(false).is_err());
    }
}
