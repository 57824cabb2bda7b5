//! Which diamonds an encode stores: the finest diamonds that meet a valid sample, and all
//! their ancestors.

use std::collections::BTreeSet;

use rayon::prelude::*;

use crate::geometry::{DiamondId, Domain};
use crate::quant::HeightGrid;

/// The stored diamonds of every level `0..=L`, sorted: the finest diamonds that meet a valid
/// sample, and all their ancestors (a child's grid comes half from each parent, and some
/// parents do not touch the data themselves).
pub(crate) fn stored_sets(domain: &Domain, grid: &HeightGrid) -> Vec<Vec<DiamondId>> {
    let layout = domain.layout();
    let (w, h) = (grid.width, grid.height);
    let finest = layout.finest_level();
    let r = layout.radius(finest) as usize;
    let (ex, ey) = layout.face_extent();
    // Leaf (a, b) is centred at ((2a+1)r, (2b+1)r); it exists while the centre is inside the
    // domain, and is stored when its closed box [2ar, 2ar + 2r] × [2br, 2br + 2r] holds a valid
    // sample. Scanning each leaf's rows with an early exit keeps this one pass over the mask at
    // worst, with no per-sample table (a summed-area table would cost 4 bytes per sample).
    let count = |extent: i64, len: usize| {
        let in_domain = (extent as usize).div_ceil(2 * r);
        let reaching_data = len.saturating_sub(1) / (2 * r) + 1;
        in_domain.min(reaching_data)
    };
    let (nx, ny) = (count(ex, w), count(ey, h));
    let rows: Vec<Vec<bool>> = (0..ny)
        .into_par_iter()
        .map(|b| {
            let mut hit = vec![false; nx];
            for y in (2 * b * r)..=((2 * b + 2) * r).min(h - 1) {
                let row = &grid.valid[y * w..(y + 1) * w];
                grid.valid.touched(w);
                for (a, hit) in hit.iter_mut().enumerate() {
                    if !*hit {
                        let (x0, x1) = (2 * a * r, ((2 * a + 2) * r).min(w - 1));
                        *hit = row[x0..=x1].iter().any(|&v| v);
                    }
                }
            }
            hit
        })
        .collect();
    let mut leaves = Vec::new();
    for (b, row) in rows.iter().enumerate() {
        for (a, &hit) in row.iter().enumerate() {
            if hit {
                let (cx, cy) = ((2 * a + 1) * r, (2 * b + 1) * r);
                leaves.push(DiamondId::new(finest, cx as u32, cy as u32));
            }
        }
    }
    with_ancestors(domain, leaves)
}

/// The stored sets of every level from the finest level's stored diamonds: each coarser level
/// holds the parents of the next finer level's, in id order.
pub(crate) fn with_ancestors(domain: &Domain, leaves: Vec<DiamondId>) -> Vec<Vec<DiamondId>> {
    let finest = domain.finest_level();
    let mut sets = vec![Vec::new(); finest as usize + 1];
    sets[finest as usize] = leaves;
    for level in (0..finest as usize).rev() {
        let parents: BTreeSet<DiamondId> = sets[level + 1]
            .iter()
            .flat_map(|&d| domain.parents(d))
            .flatten()
            .collect();
        sets[level] = parents.into_iter().collect();
    }
    sets
}
