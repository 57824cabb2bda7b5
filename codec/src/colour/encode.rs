//! Encoding an RGB image: YCoCg-R, the elevation encoder once per channel, records joined.

use super::channels::join;
use super::{RgbImage, ycocg};
use crate::CodecError;
use crate::hierarchy::{EncodeOptions, Encoded, Encoder, Record, RepoKind};
use crate::quant::{HeightGrid, QuantPlan, Quantizer};

/// The plan a colour repository is written with: integer unit 1 (one colour level), offset 0,
/// lattice input, per-channel quantizer [`ycocg::channel_k`]`(max_error)`, and `max_error` (RGB
/// levels) as the tolerance.
pub fn colour_plan(max_error: u32) -> Result<QuantPlan, CodecError> {
    if max_error > 127 {
        return Err(CodecError::invalid(format!(
            "a colour tolerance of {max_error} levels allows any colour; use at most 127"
        )));
    }
    Ok(QuantPlan {
        unit: 1.0,
        offset: 0.0,
        quantizer: Quantizer::new(ycocg::channel_k(max_error))?,
        lattice: true,
        representation_error: 0.0,
        epsilon: f64::from(max_error),
        rms: None,
        levels: None,
    })
}

/// Encodes `img` so that every decoded RGB component is within `max_error` levels of the input
/// (see [`ycocg::rgb_bound`]). `progress(done, total)` as for the elevation encoder, over the
/// three channels together.
pub fn encode_colour(
    img: &RgbImage,
    max_error: u32,
    opts: &EncodeOptions,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<(Encoded, QuantPlan), CodecError> {
    if img.pixels.len() != img.width * img.height || img.pixels.is_empty() {
        return Err(CodecError::invalid(format!(
            "{} pixels for a {}×{} image",
            img.pixels.len(),
            img.width,
            img.height
        )));
    }
    let plan = colour_plan(max_error)?;
    let ycc: Vec<[i32; 3]> = img.pixels.iter().map(|&p| ycocg::from_rgb(p)).collect();
    let mut channels = Vec::with_capacity(3);
    for c in 0..3 {
        let grid = HeightGrid::all_valid(img.width, img.height, ycc.iter().map(|v| v[c]).collect());
        let tick = |done: usize, total: usize| progress(c * total + done, 3 * total);
        channels.push(
            Encoder::new(&grid, plan.quantizer, opts)
                .progress(&tick)
                .encode()?,
        );
    }
    let [y, co, cg]: [Encoded; 3] = channels.try_into().expect("three channels");
    // Same grid size, all samples valid: the three hierarchies have the same layout and the
    // same stored diamonds, in the same (id) order.
    assert!(y.params == co.params && y.params == cg.params);
    assert!(
        y.records.len() == co.records.len()
            && y.records.iter().zip(&co.records).all(|(a, b)| a.id == b.id)
            && y.records.iter().zip(&cg.records).all(|(a, b)| a.id == b.id)
    );
    let records = (0..y.records.len())
        .map(|i| {
            let (a, b, c) = (&y.records[i], &co.records[i], &cg.records[i]);
            Record {
                id: a.id,
                bytes: join([&a.bytes, &b.bytes, &c.bytes], false).into(),
                // The client's refinement is driven by the elevation repository; the index keeps
                // the worst channel's error (YCoCg levels) and the luma range.
                object_error: a.object_error.max(b.object_error).max(c.object_error),
                min: a.min,
                max: a.max,
            }
        })
        .collect();
    let mut params = y.params;
    params.kind = RepoKind::Colour;
    Ok((
        Encoded {
            params,
            roots: join([&y.roots, &co.roots, &cg.roots], true),
            records,
            leaf_error: y.leaf_error.max(co.leaf_error).max(cg.leaf_error),
        },
        plan,
    ))
}
