//! Half-patches: what a cut draws, what the CPU cache keeps and what a GPU slot holds.
//!
//! The cut rule (docs/DESIGN.md) draws the half of diamond `K` lying in its parent `A` iff `A` is
//! refined and `K` is not; unrefined roots draw both halves. The heights of that half are exactly
//! what refining `A` produced on it, so a half-patch is made from `A`'s [`Refined`] alone, and it
//! never changes once made: it can be cached and uploaded by its [`PatchKey`].

use std::collections::HashMap;

use cbdam_codec::CodecError;
use cbdam_codec::colour::{ColourDecoder, ColourRefined};
use cbdam_codec::geometry::{Cut, DiamondId, Domain, Half};
use cbdam_codec::hierarchy::{Decoder, RefineScratch, Refined, gather, gather_validity};
use cbdam_codec::repository::Repository;

/// Identity of a half-patch: the diamond and which of its halves.
pub type PatchKey = (DiamondId, Half);

/// The heights of one drawn half of a diamond.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct HalfPatch {
    /// The diamond whose half this is.
    pub id: DiamondId,
    /// Which half ([`Domain::parents`](cbdam_codec::geometry::Domain::parents) order: the half lying in that parent).
    pub half: Half,
    /// `N × N` heights on the diamond's grid ([`Layout::grid`]), row-major, integer units
    /// (metres = `plan.offset + plan.unit · h`). The half's own points, split diagonal included,
    /// are the reconstructed heights; the other half holds their mirror image across the
    /// diagonal (the codec's symmetric extension), so finite differences at the diagonal stay
    /// defined. Outside the data rectangle heights are unconstrained and must not be drawn.
    pub heights: Vec<i32>,
    /// Which of those points had data in the input (same layout), from the repository's nodata
    /// mask; `None` when all did. Heights at invalid points are predictions, not data: triangles
    /// touching them are not drawn. Meaningless outside the data rectangle.
    pub valid: Option<Vec<bool>>,
    /// Per-point colour draped from a colour repository (same layout, [`pack_rgb`]), when one
    /// is given; like the heights, the other half mirrors this half's.
    pub colour: Option<Vec<u32>>,
}

/// RGB8 in one word, red in the low byte (what WGSL's `unpack4x8unorm` reads), alpha 255.
pub fn pack_rgb([r, g, b]: [u8; 3]) -> u32 {
    u32::from(r) | u32::from(g) << 8 | u32::from(b) << 16 | 0xFF << 24
}

/// The inverse of [`pack_rgb`] (alpha dropped).
pub fn unpack_rgb(c: u32) -> [u8; 3] {
    [c as u8, (c >> 8) as u8, (c >> 16) as u8]
}

/// Packed colours of Y, Co, Cg grids.
pub fn packed(grids: &[Vec<i32>; 3]) -> Vec<u32> {
    ColourDecoder::rgb(grids)
        .into_iter()
        .map(pack_rgb)
        .collect()
}

/// The colour of the half of `child` lying in `parent`, from `parent`'s colour refinement, as
/// [`HalfPatch::from_parent`] gathers its heights. `None` if `parent` is not one of `child`'s
/// parents.
pub fn colour_from_parent(
    domain: &Domain,
    child: DiamondId,
    parent: DiamondId,
    refined: &ColourRefined,
) -> Option<Vec<u32>> {
    let half = domain.half_in(child, parent)?;
    let nn = domain.n() * domain.n();
    let grids = std::array::from_fn(|c| {
        let mut parents = [None, None];
        parents[half as usize] = Some(&refined[c]);
        let mut g = vec![0i32; nn];
        gather(domain, child, parents, &mut g);
        g
    });
    Some(packed(&grids))
}

impl HalfPatch {
    /// The key the caches use.
    pub fn key(&self) -> PatchKey {
        (self.id, self.half)
    }

    /// Both halves of an unrefined root, from the decoder's root field.
    pub fn root_halves(decoder: &Decoder, root: DiamondId) -> [HalfPatch; 2] {
        let heights = decoder.grid_of(root, [None, None]);
        let valid = decoder.validity_of(root, [None, None]);
        Half::BOTH.map(|half| HalfPatch {
            id: root,
            half,
            heights: heights.clone(),
            valid: valid.clone(),
            colour: None,
        })
    }

    /// The half of `child` lying in `parent`, from `parent`'s refinement. `None` if `parent`
    /// is not one of `child`'s parents.
    pub fn from_parent(
        domain: &Domain,
        child: DiamondId,
        parent: DiamondId,
        refined: &Refined,
    ) -> Option<HalfPatch> {
        let half = domain.half_in(child, parent)?;
        let mut parents = [None, None];
        parents[half as usize] = Some(refined);
        let mut heights = vec![0i32; domain.n() * domain.n()];
        gather(domain, child, parents, &mut heights);
        Some(HalfPatch {
            id: child,
            half,
            heights,
            valid: gather_validity(domain, child, parents),
            colour: None,
        })
    }
}

/// Decodes every refined diamond of `cut` and returns the half-patches it draws, in
/// [`Cut::drawn_halves`] order: the synchronous reference that the streaming client must agree
/// with, and what offscreen tests render. Every refined diamond must be stored in `repo`.
pub fn decode_cut(repo: &Repository, cut: &Cut) -> Result<Vec<HalfPatch>, CodecError> {
    let decoder = repo.head().decoder()?;
    let domain = repo.head().params().domain;
    let mut refined: HashMap<DiamondId, Refined> = HashMap::new();
    let mut scratch = RefineScratch::default();
    // `Cut::refined` runs coarse to fine, so parents are refined before their children.
    for id in cut.refined() {
        let parents = domain.parents(id).map(|p| p.and_then(|p| refined.get(&p)));
        let grid = decoder.grid_of(id, parents);
        let r = decoder.refine(id, &grid, repo.record(id)?, &mut scratch)?;
        refined.insert(id, r);
    }
    let mut out = Vec::new();
    for (id, half) in cut.drawn_halves(&domain) {
        if id.level == 0 {
            let [pos, neg] = HalfPatch::root_halves(&decoder, id);
            out.push(if half == Half::Positive { pos } else { neg });
            continue;
        }
        let parent = domain
            .parent(id, half)
            .expect("a drawn child half has its parent");
        let r = &refined[&parent];
        out.push(HalfPatch::from_parent(&domain, id, parent, r).expect("parent of its half"));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use cbdam_codec::hierarchy::{EncodeOptions, Encoder, walk};
    use cbdam_codec::quant::{HeightGrid, QuantPlan};
    use cbdam_codec::repository::serialize;

    fn repository() -> Repository {
        let (w, h) = (40usize, 29usize);
        let metres: Vec<f64> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f64, (i / w) as f64);
                50.0 + 9.0 * (x / 4.0).sin() * (y / 5.0).cos() + ((i * 7919) % 13) as f64 / 6.0
            })
            .collect();
        let plan = QuantPlan::new(0.25, None, 35.0, 65.0).unwrap();
        let grid = HeightGrid::from_metres(w, h, &metres, None, &plan).unwrap();
        let opts = EncodeOptions {
            n: 5,
            ..EncodeOptions::default()
        };
        let enc = Encoder::new(&grid, plan.quantizer, &opts).encode().unwrap();
        Repository::from_bytes(serialize(&enc, &plan, None, None).unwrap()).unwrap()
    }

    /// Every drawn half-patch of random cuts agrees with the full decoder's grid of its diamond
    /// on every point of its half, and mirrors it across the diagonal.
    #[test]
    fn decode_cut_matches_walk() {
        let repo = repository();
        let domain = repo.head().params().domain;
        let layout = *domain.layout();
        let n = layout.n();
        let mut full: HashMap<DiamondId, Vec<i32>> = HashMap::new();
        walk(&repo.to_encoded().unwrap(), |id, g| {
            full.insert(id, g.to_vec());
        })
        .unwrap();
        let stored: Vec<DiamondId> = repo.head().entries().iter().map(|e| e.id).collect();
        let mut state = 0x1234_5678_u64;
        for round in 0..8 {
            let mut cut = Cut::new();
            for _ in 0..round * 6 {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                cut.refine(&domain, stored[(state >> 33) as usize % stored.len()]);
            }
            let patches = decode_cut(&repo, &cut).unwrap();
            assert_eq!(patches.len(), cut.drawn_halves(&domain).len());
            let mut checked = 0;
            for p in &patches {
                // `walk` visits the stored diamonds and the finest ones; others (unstored, outside
                // the data) have no reference grid.
                let Some(g) = full.get(&p.id) else { continue };
                checked += 1;
                for j in 0..n {
                    for i in 0..n {
                        if layout.half_of_point(p.id, i, j).is_none_or(|h| h == p.half) {
                            assert_eq!(p.heights[j * n + i], g[j * n + i], "{} {i},{j}", p.id);
                        }
                    }
                }
            }
            assert!(
                checked * 2 >= patches.len(),
                "{checked} of {}",
                patches.len()
            );
        }
    }
}
