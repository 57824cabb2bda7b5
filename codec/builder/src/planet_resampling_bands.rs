//! An input's resampling error measured a band of its rows at a time, holding only the lattice
//! tiles that band's samples lie in: for an input whose samples span several faces (a global
//! grid covers every tile of the planet), where holding every tile it covers at once would
//! hold the whole lattice at its stride. The rows are measured as the whole view measures
//! them and summed in the same order, so the figures have the same bits.

use std::collections::BTreeSet;

use rayon::prelude::*;

use super::{Held, LatticeTiles};
use crate::error::Result;
use crate::planet_resampling::{
    InputResampling, Resampled, column_sin_cos, fold_rows, rows_resampling, sample_cell_tiles,
    sample_position,
};
use cbdam_codec::hierarchy::PlanetGrid;

/// Samples a band holds at most (about): a band of a 5′ global grid is 60 rows, 5°.
const BAND_SAMPLES: usize = 1 << 18;

impl LatticeTiles<'_> {
    /// Input `input`'s resampling error, a band of rows at a time (see the module
    /// documentation): the same figures as [`LatticeTiles::input_view`] of every tile it can
    /// cover gives.
    pub(super) fn resampling_in_bands(&self, input: usize) -> Result<InputResampling> {
        let r = &self.resampler;
        let of = &r.inputs.inputs[input];
        let stride = r.strides[input];
        let me = u16::try_from(input).expect("at most MAX_PLANET_INPUTS inputs");
        // The tiles it can cover: the others hold none of its winners.
        let candidate: Vec<Vec<bool>> = (0..r.domain().faces())
            .map(|f| {
                (0..r.tiles_per_face())
                    .map(|t| r.tiles.candidates(f, t).any(|(i, _)| i == me))
                    .collect()
            })
            .collect();
        let band = (BAND_SAMPLES / of.width.max(1)).max(1);
        let mut rows = Vec::with_capacity(of.height);
        for start in (0..of.height).step_by(band) {
            let band = start..(start + band).min(of.height);
            let wanted = self.band_tiles(input, band.clone(), &candidate)?;
            let view = self.band_view(input, wanted)?;
            rows.extend(rows_resampling(r.inputs, input, band, &view, r.plan)?);
        }
        Ok(fold_rows(r.inputs, input, rows, stride))
    }

    /// The tiles holding the lattice points around the valid samples of `band`'s rows of input
    /// `input`, among those it can cover (`candidate`, per face, per tile).
    fn band_tiles(
        &self,
        input: usize,
        band: std::ops::Range<usize>,
        candidate: &[Vec<bool>],
    ) -> Result<BTreeSet<(u8, usize)>> {
        let r = &self.resampler;
        let of = &r.inputs.inputs[input];
        let samples = r.inputs.samples(input)?;
        let step = 1i64 << r.strides[input];
        let columns = column_sin_cos(of);
        Ok(band
            .into_par_iter()
            .map(|row| {
                let sin_cos = of.lat_lon_of(0, row).lat.to_radians().sin_cos();
                let mut tiles = BTreeSet::new();
                for c in 0..of.width {
                    if of.sample(&samples, c, row).is_none() {
                        continue;
                    }
                    let at = sample_position(of, columns.as_deref(), sin_cos, (c, row));
                    for (f, i) in sample_cell_tiles(r.side, r.tile_log2, step, at) {
                        if candidate[usize::from(f)][i] {
                            tiles.insert((f, i));
                        }
                    }
                }
                tiles
            })
            .reduce(BTreeSet::new, |mut a, b| {
                a.extend(b);
                a
            }))
    }

    /// A lattice holding `wanted`'s tiles at input `input`'s stride, with their winners.
    fn band_view(&self, input: usize, wanted: BTreeSet<(u8, usize)>) -> Result<Resampled> {
        let r = &self.resampler;
        let d = r.domain();
        let stride = r.strides[input];
        let held: Vec<((u8, usize), Held)> = wanted
            .into_par_iter()
            .map(|(f, i)| Ok(((f, i), self.held(f, i, stride)?)))
            .collect::<Result<_>>()?;
        let mut winners = vec![vec![Vec::new(); r.tiles_per_face()]; usize::from(d.faces())];
        let mut tiles = std::collections::HashMap::new();
        for ((f, i), h) in held {
            winners[usize::from(f)][i] = h.1.clone();
            tiles.insert((f, i), std::sync::Arc::clone(&h.0));
        }
        let planet = PlanetGrid::partial(d.n(), d.layout().k(), r.tile_log2, r.variable, tiles)?;
        Ok(Resampled {
            planet,
            winners,
            strides: r.strides.clone(),
        })
    }
}
