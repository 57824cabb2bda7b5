//! Decoding a colour repository: the elevation decoder once per channel.

use super::channels::split;
use super::{RgbImage, ycocg};
use crate::CodecError;
use crate::geometry::DiamondId;
use crate::hierarchy::{
    CodecParams, Decoder, Encoded, Record, RefineScratch, Refined, RepoKind, VerifyReport,
    reconstruct_finest, refine, verify,
};
use crate::quant::HeightGrid;

/// One refined diamond of a colour repository: Y, Co, Cg.
pub type ColourRefined = [Refined; 3];

/// The three channel decoders of a colour repository.
#[derive(Clone, Debug)]
pub struct ColourDecoder {
    channels: [Decoder; 3],
}

/// The per-channel parameters of a colour repository's parameters.
fn channel_params(params: &CodecParams) -> Result<CodecParams, CodecError> {
    if params.kind != RepoKind::Colour {
        return Err(CodecError::invalid("not a colour repository"));
    }
    let mut p = *params;
    p.kind = RepoKind::Elevation;
    Ok(p)
}

impl ColourDecoder {
    /// Decodes the three root fields of a colour repository.
    pub fn new(params: CodecParams, root_bytes: &[u8]) -> Result<Self, CodecError> {
        let p = channel_params(&params)?;
        let parts = split(root_bytes, false, "root field")?;
        let [y, co, cg] = parts.map(|b| Decoder::new(p, b));
        Ok(Self {
            channels: [y?, co?, cg?],
        })
    }

    /// The parameters of each channel (kind elevation: one channel).
    pub fn params(&self) -> &CodecParams {
        self.channels[0].params()
    }

    /// The `N × N` Y, Co, Cg grids of `id` (see [`Decoder::grid_of`]).
    pub fn grid_of(&self, id: DiamondId, parents: [Option<&ColourRefined>; 2]) -> [Vec<i32>; 3] {
        std::array::from_fn(|c| self.channels[c].grid_of(id, parents.map(|p| p.map(|p| &p[c]))))
    }

    /// Refines a diamond with grids `p` by its (three-channel) record. A colour repository has
    /// one quantizer for every level (no RMS bound, so no flag bit 5), so no level is asked.
    pub fn refine(
        &self,
        p: &[Vec<i32>; 3],
        record: &[u8],
        scratch: &mut RefineScratch,
    ) -> Result<ColourRefined, CodecError> {
        let parts = split(record, true, "record")?;
        let mut out = Vec::with_capacity(3);
        for c in 0..3 {
            let params = self.channels[c].params();
            let q = params.quantizer;
            out.push(refine(params, q, &p[c], parts[c], scratch)?);
        }
        Ok(out.try_into().expect("three channels"))
    }

    /// RGB of grids `p` point by point ([`ycocg::to_rgb`]).
    pub fn rgb(p: &[Vec<i32>; 3]) -> Vec<[u8; 3]> {
        (0..p[0].len())
            .map(|i| ycocg::to_rgb([p[0][i], p[1][i], p[2][i]]))
            .collect()
    }
}

/// The three channels of an in-memory colour hierarchy as elevation hierarchies (object errors
/// and ranges copied from the joined index: the walkers ignore them).
fn split_encoded(encoded: &Encoded) -> Result<[Encoded; 3], CodecError> {
    let params = channel_params(&encoded.params)?;
    let roots = split(&encoded.roots, false, "root field")?;
    let mut parts: Vec<[&[u8]; 3]> = Vec::with_capacity(encoded.records.len());
    for r in &encoded.records {
        parts.push(split(&r.bytes, true, "record")?);
    }
    Ok(std::array::from_fn(|c| Encoded {
        params,
        roots: roots[c].to_vec(),
        records: encoded
            .records
            .iter()
            .zip(&parts)
            .map(|(r, p)| Record {
                id: r.id,
                bytes: p[c].to_vec().into(),
                object_error: r.object_error,
                min: r.min,
                max: r.max,
            })
            .collect(),
        leaf_error: encoded.leaf_error,
    }))
}

/// Decodes the finest level of a colour hierarchy onto its image grid (the domain's data
/// rectangle, row-major) as RGB.
pub fn reconstruct_rgb(encoded: &Encoded) -> Result<Vec<[u8; 3]>, CodecError> {
    let [y, co, cg] = split_encoded(encoded)?;
    let (y, co, cg) = (
        reconstruct_finest(&y)?,
        reconstruct_finest(&co)?,
        reconstruct_finest(&cg)?,
    );
    Ok((0..y.len())
        .map(|i| ycocg::to_rgb([y[i], co[i], cg[i]]))
        .collect())
}

/// What [`verify_colour`] found.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ColourVerifyReport {
    /// Per channel (Y, Co, Cg), every level against the channel's input: within `k`.
    pub channels: [VerifyReport; 3],
    /// Largest |decoded − input| of the finest level in R, G, B, levels.
    pub rgb_max: [u32; 3],
    /// What the RGB errors must respect: the derived bound of `k` ([`ycocg::rgb_bound`]).
    pub rgb_bound: [u32; 3],
}

impl ColourVerifyReport {
    /// Whether every channel of every level, and the RGB of the finest level, are within their
    /// bounds.
    pub fn within_bound(&self) -> bool {
        self.channels.iter().all(|c| c.within_bound())
            && self
                .rgb_max
                .iter()
                .zip(&self.rgb_bound)
                .all(|(e, b)| e <= b)
    }
}

/// Decodes the whole colour hierarchy and checks it against `img`: every level of every channel
/// within `k` of the channel's input, and the finest level's RGB within the derived bound.
pub fn verify_colour(encoded: &Encoded, img: &RgbImage) -> Result<ColourVerifyReport, CodecError> {
    let p = &encoded.params;
    let data = p.domain.data();
    if data.size() != (img.width, img.height) {
        return Err(CodecError::invalid(format!(
            "the repository holds a {}×{} image, the input is {}×{}",
            data.width, data.height, img.width, img.height
        )));
    }
    let split = split_encoded(encoded)?;
    let ycc: Vec<[i32; 3]> = img.pixels.iter().map(|&px| ycocg::from_rgb(px)).collect();
    let mut channels = Vec::with_capacity(3);
    let mut finest = Vec::with_capacity(3);
    for (c, enc) in split.iter().enumerate() {
        let grid = HeightGrid::all_valid(img.width, img.height, ycc.iter().map(|v| v[c]).collect());
        channels.push(verify(enc, &grid)?);
        finest.push(reconstruct_finest(enc)?);
    }
    let mut rgb_max = [0u32; 3];
    for (i, px) in img.pixels.iter().enumerate() {
        let got = ycocg::to_rgb([finest[0][i], finest[1][i], finest[2][i]]);
        for c in 0..3 {
            rgb_max[c] = rgb_max[c].max((i32::from(got[c]) - i32::from(px[c])).unsigned_abs());
        }
    }
    Ok(ColourVerifyReport {
        channels: channels.try_into().expect("three channels"),
        rgb_max,
        rgb_bound: ycocg::rgb_bound(p.quantizer.k() as u32),
    })
}
