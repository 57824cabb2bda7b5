//! Frames read back from the GPU, and their PNG encoding.

use crate::{DrawError, DrawStats};

/// An offscreen frame read back.
#[derive(Clone, Debug)]
pub struct Frame {
    /// Pixels across.
    pub width: u32,
    /// Pixels down.
    pub height: u32,
    /// RGBA8, row-major, top row first.
    pub rgba: Vec<u8>,
    /// Depth 0 (near) – 1 (far, background), when asked for.
    pub depth: Option<Vec<f32>>,
    /// What was drawn.
    pub stats: DrawStats,
}

impl Frame {
    /// RGBA of pixel `(x, y)`.
    pub fn pixel(&self, x: u32, y: u32) -> [u8; 4] {
        let i = 4 * (y as usize * self.width as usize + x as usize);
        [
            self.rgba[i],
            self.rgba[i + 1],
            self.rgba[i + 2],
            self.rgba[i + 3],
        ]
    }

    /// The image as PNG bytes.
    pub fn to_png(&self) -> Result<Vec<u8>, DrawError> {
        encode_png(self.width, self.height, &self.rgba)
    }
}

/// RGBA8 pixels as PNG bytes.
pub fn encode_png(width: u32, height: u32, rgba: &[u8]) -> Result<Vec<u8>, DrawError> {
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, width, height);
    enc.set_color(png::ColorType::Rgba);
    enc.set_depth(png::BitDepth::Eight);
    let mut w = enc
        .write_header()
        .map_err(|e| DrawError::Png(e.to_string()))?;
    w.write_image_data(rgba)
        .map_err(|e| DrawError::Png(e.to_string()))?;
    w.finish().map_err(|e| DrawError::Png(e.to_string()))?;
    Ok(out)
}

/// Writes `frame` as a PNG, atomically (a reader never sees half a file).
pub fn write_png(path: &std::path::Path, frame: &Frame) -> anyhow::Result<()> {
    use anyhow::Context;
    let png = frame.to_png()?;
    cbdam_codec::atomic::write_atomically::<anyhow::Error>(path, |f| {
        use std::io::Write;
        f.write_all(&png)?;
        Ok(())
    })
    .with_context(|| format!("writing {}", path.display()))
}
