//! An input's resampling error measured a band of its rows at a time, holding only the lattice
//! tiles that band's samples lie in: for an input whose samples span several faces (a global
//! grid covers every tile of the planet), where holding every tile it covers at once would
//! hold the whole lattice at its stride; and for an inset whose tiles together are more than
//! the lattice cache's budget (a 1° SRTM tile meets up to nine 8 MiB tiles at 3″), each band
//! painting only the parts of its tiles around its own samples. The rows are measured as the
//! whole view measures them and summed in the same order, so the figures have the same bits.

use std::collections::BTreeSet;

use rayon::prelude::*;

use super::{Held, LatticeTiles, Rect, tile_bytes};
use crate::error::Result;
use crate::planet_resampling::{
    InputResampling, Resampled, column_sin_cos, fold_rows, rows_resampling, sample_cell_tiles,
    sample_footprint_of_rows, sample_position,
};
use cbdam_codec::hierarchy::PlanetGrid;

/// Samples a band holds at most (about): a band of a 5′ global grid is 60 rows, 5°.
const BAND_SAMPLES: usize = 1 << 18;

impl LatticeTiles<'_> {
    /// Input `input`'s resampling error where its samples lie on at most three faces, `parts`
    /// ([`crate::planet_resampling::sample_footprint`]): its rows in as few bands as keep the
    /// tiles a band paints (whole arrays, though only the part around the band's samples is
    /// painted) within the lattice cache's budget, each band's part of its tiles painted only
    /// while that band is measured; the same figures as all its rows against all its tiles.
    pub(super) fn resampling_of_inset(
        &self,
        input: usize,
        parts: &[(u8, Rect)],
    ) -> Result<InputResampling> {
        let r = &self.resampler;
        let of = &r.inputs.inputs[input];
        let stride = r.strides[input];
        let whole = self.input_tiles_in(input, Some(parts));
        let bytes: u64 = whole
            .iter()
            .map(|&(f, i, _)| {
                let (w, h) = r.tile_size(i, self.view_stride(f, i, stride));
                tile_bytes(w * h)
            })
            .sum();
        let budget = self.cache.lock().expect("the tile cache").budget.max(1);
        let bands = usize::try_from(bytes.div_ceil(budget)).map_or(of.height, |b| b.max(1));
        let band = of.height.div_ceil(bands.min(of.height).max(1)).max(1);
        let mut rows = Vec::with_capacity(of.height);
        for start in (0..of.height).step_by(band) {
            let band = start..(start + band).min(of.height);
            let tiles = if band.len() == of.height {
                whole.clone()
            } else {
                let footprint = sample_footprint_of_rows(of, stride, r.side, band.clone());
                self.input_tiles_in(input, Some(footprint.as_deref().unwrap_or(parts)))
            };
            let view = self.input_view(input, tiles)?;
            rows.extend(rows_resampling(r.inputs, input, band, &view, r.plan)?);
        }
        Ok(fold_rows(r.inputs, input, rows, stride))
    }

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
            tiles.insert((f, i), self.measured(f, i, &h.0)?);
        }
        let planet = PlanetGrid::partial(d.n(), d.layout().k(), r.tile_log2, r.variable, tiles)?;
        Ok(Resampled {
            planet,
            winners,
            strides: r.strides.clone(),
        })
    }
}
