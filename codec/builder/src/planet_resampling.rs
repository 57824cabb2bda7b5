//! How far a planet's resampled lattice is from each input's own samples (the resampling
//! error the build reports and the header records), and the header's summary of it.

use std::path::PathBuf;

use rayon::prelude::*;

use crate::error::Result;
use crate::planet_input::{Frame, PlanetInputs};
use cbdam_codec::geodesy::LatLon;
use cbdam_codec::geodesy::cube_map::{lat_lon_to_face_st, sin_cos_on_face, sin_cos_to_face_st};
use cbdam_codec::hierarchy::PlanetGrid;
use cbdam_codec::quant::QuantPlan;
use cbdam_codec::repository::{PlanetProvenance, VerticalDatum};

/// The resampled lattice: integer heights under `plan`, and per point held which input won.
pub struct Resampled {
    /// The planet's heights (with resolution classes when an input is coarser than the
    /// lattice, [`input_stride`]).
    pub planet: PlanetGrid,
    /// Per face, per tile, per point the tile holds: the winning input's index, `u16::MAX`
    /// for none.
    pub winners: Vec<Vec<Vec<u16>>>,
    /// Per input, `log2` of its stride on the lattice ([`input_stride`]).
    pub strides: Vec<u32>,
}

/// How far the resampled lattice is from one input's own samples.
#[derive(Clone, Debug, PartialEq)]
pub struct InputResampling {
    /// The input.
    pub path: PathBuf,
    /// Its valid samples.
    pub samples: u64,
    /// Of those, the samples compared: those whose four surrounding lattice points all took
    /// their height from this input.
    pub compared: u64,
    /// Largest |lattice − sample|, metres (0 when none was compared).
    pub max_error: f64,
    /// Root mean square of the same, metres.
    pub rms_error: f64,
    /// Where the largest error is: the sample's latitude and longitude.
    pub worst_at: Option<LatLon>,
    /// `log2` of the input's stride on the lattice ([`input_stride`]): 0 when it is sampled at
    /// every lattice point.
    pub stride: u32,
}

/// Measures each input's samples against the bilinear interpolant of the resampled lattice
/// (heights in metres under `plan`) in face coordinates.
pub fn resampling_error(
    inputs: &PlanetInputs,
    resampled: &Resampled,
    plan: &QuantPlan,
) -> Result<Vec<InputResampling>> {
    (0..inputs.inputs.len())
        .map(|i| input_resampling(inputs, i, resampled, plan))
        .collect()
}

/// Input `i`'s samples against the bilinear interpolant of the resampled lattice: only the
/// lattice points that took their height from it are read (`resampled` may hold only the
/// tiles it can cover).
pub(crate) fn input_resampling(
    inputs: &PlanetInputs,
    i: usize,
    resampled: &Resampled,
    plan: &QuantPlan,
) -> Result<InputResampling> {
    let rows = rows_resampling(inputs, i, 0..inputs.inputs[i].height, resampled, plan)?;
    Ok(fold_rows(inputs, i, rows, resampled.strides[i]))
}

/// One row's share of an input's resampling error: valid samples, samples compared, the
/// largest error and where, and the sum of squared errors.
pub(crate) type RowError = (u64, u64, f64, f64, Option<LatLon>);

/// The rows `rows` of input `i` against the bilinear interpolant of the resampled lattice,
/// each on its own ([`fold_rows`] sums them): `resampled` needs to hold only the tiles those
/// rows' samples lie in ([`sample_cell_tiles`]).
pub(crate) fn rows_resampling(
    inputs: &PlanetInputs,
    i: usize,
    rows: std::ops::Range<usize>,
    resampled: &Resampled,
    plan: &QuantPlan,
) -> Result<Vec<RowError>> {
    let input = &inputs.inputs[i];
    let me = u16::try_from(i).unwrap_or(u16::MAX);
    let samples = inputs.samples(i)?;
    // The input's samples are the lattice points on its stride: the surface drawn
    // where it is the finest data interpolates those.
    let step = 1i64 << resampled.strides[i];
    let columns = column_sin_cos(input);
    Ok(rows
        .into_par_iter()
        .map(|r| {
            let mut acc: RowError = (0, 0, 0.0, 0.0, None);
            let row = input.lat_lon_of(0, r).lat.to_radians().sin_cos();
            for c in 0..input.width {
                let Some(v) = input.sample(&samples, c, r) else {
                    continue;
                };
                acc.0 += 1;
                let position = sample_position(input, columns.as_deref(), row, (c, r));
                let Some(l) = lattice_at(resampled, plan, me, position, step) else {
                    continue;
                };
                let e = (l - v).abs();
                acc.1 += 1;
                if e > acc.2 || acc.4.is_none() {
                    acc.2 = e;
                    acc.4 = Some(input.lat_lon_of(c, r));
                }
                acc.3 += e * e;
            }
            acc
        })
        .collect())
}

/// Input `i`'s resampling error from its rows' shares, all of them in row order.
pub(crate) fn fold_rows(
    inputs: &PlanetInputs,
    i: usize,
    rows: Vec<RowError>,
    stride: u32,
) -> InputResampling {
    // Rows summed in order, not in rayon's reduction tree (whose shape depends on
    // scheduling): the stored RMS has the same bits every build.
    let (samples, compared, max, sum2, worst_at) =
        rows.into_iter().fold((0, 0, 0.0, 0.0, None), |a, b| {
            let (max, at) = if b.2 > a.2 || a.4.is_none() {
                (b.2, b.4)
            } else {
                (a.2, a.4)
            };
            (a.0 + b.0, a.1 + b.1, max, a.3 + b.3, at)
        });
    InputResampling {
        path: inputs.inputs[i].path.clone(),
        samples,
        compared,
        max_error: max,
        rms_error: if compared > 0 {
            (sum2 / compared as f64).sqrt()
        } else {
            0.0
        },
        worst_at,
        stride,
    }
}

/// On a latitude/longitude grid the longitude's sine and cosine depend on the column only (the
/// latitude's on the row): computed once each; `None` for a projected input.
pub(crate) fn column_sin_cos(input: &crate::planet_input::PlanetInput) -> Option<Vec<(f64, f64)>> {
    match input.frame {
        Frame::Geographic { .. } => Some(
            (0..input.width)
                .map(|c| input.lat_lon_of(c, 0).lon.to_radians().sin_cos())
                .collect(),
        ),
        Frame::Projected { .. } => None,
    }
}

/// Where sample `(c, r)` lies on the cube: face and face coordinates `(s, t)`; `row` is the
/// sine and cosine of its row's latitude, `columns` [`column_sin_cos`].
#[inline]
pub(crate) fn sample_position(
    input: &crate::planet_input::PlanetInput,
    columns: Option<&[(f64, f64)]>,
    row: (f64, f64),
    (c, r): (usize, usize),
) -> (u8, f64, f64) {
    match columns {
        Some(columns) => sin_cos_to_face_st(row, columns[c]),
        None => lat_lon_to_face_st(input.lat_lon_of(c, r)),
    }
}

/// Lattice points `(x0, y0, x1, y1)` of a face, inclusive.
pub(crate) type FaceRect = (i64, i64, i64, i64);

/// The lattice points input `input` (of stride `2^stride` on a lattice of `side` steps a
/// face) can compare its samples with: per face its samples lie on, a rectangle `(x0, y0, x1,
/// y1)` (inclusive, within the face) holding the corners of every lattice cell (on the
/// stride) a sample of that face lies in; `None` where its samples reach more than three
/// faces (a global input: its tiles are read whole).
///
/// Found from every `Q`-th sample of each row and column (and the last): a sample lies within
/// `Q − 1` columns and rows of one of those, and samples one apart are under `2^(stride+1)`
/// lattice steps apart ([`crate::planet_plan::plan_tiles`]' footprint makes the same bound), so
/// a margin of `(Q + 2)·2^(stride+1)` steps and a cell holds them all. A sample near a face's
/// edge counts on the neighbouring face too (in that face's coordinates continued past its
/// edge, [`sin_cos_on_face`]) where it lies within twice the margin of it, so that a sample
/// of that face between the ones looked at is held there as well.
pub(crate) fn sample_footprint(
    input: &crate::planet_input::PlanetInput,
    stride: u32,
    side: i64,
) -> Option<Vec<(u8, FaceRect)>> {
    sample_footprint_of_rows(input, stride, side, 0..input.height)
}

/// [`sample_footprint`] of the samples in rows `rows` of `input` only (not empty).
pub(crate) fn sample_footprint_of_rows(
    input: &crate::planet_input::PlanetInput,
    stride: u32,
    side: i64,
    rows: std::ops::Range<usize>,
) -> Option<Vec<(u8, FaceRect)>> {
    const Q: usize = 8;
    let along = |r: std::ops::Range<usize>| r.clone().step_by(Q).chain([r.end - 1]);
    let step = 1i64 << stride;
    let margin = (Q as i64 + 2) * 2 * step + step;
    let reach = (2 * margin) as f64;
    let mut rects = [None::<(f64, f64, f64, f64)>; 6];
    for r in along(rows) {
        for c in along(0..input.width) {
            let ll = input.lat_lon_of(c, r);
            let (sc_lat, sc_lon) = (ll.lat.to_radians().sin_cos(), ll.lon.to_radians().sin_cos());
            let (own, _, _) = sin_cos_to_face_st(sc_lat, sc_lon);
            for face in 0..6u8 {
                let Some((s, t)) = sin_cos_on_face(sc_lat, sc_lon, face) else {
                    continue;
                };
                let (x, y) = (s * side as f64, t * side as f64);
                let near = |a: f64| (-reach..=side as f64 + reach).contains(&a);
                if face == own || (near(x) && near(y)) {
                    let e = rects[usize::from(face)].get_or_insert((x, y, x, y));
                    *e = (e.0.min(x), e.1.min(y), e.2.max(x), e.3.max(y));
                }
            }
        }
    }
    let faces: Vec<_> = (0..6u8)
        .filter_map(|f| rects[usize::from(f)].map(|r| (f, r)))
        .collect();
    (faces.len() <= 3).then(|| {
        faces
            .into_iter()
            .map(|(f, (x0, y0, x1, y1))| {
                let clip = |a: f64, m: i64| (a as i64 + m).clamp(0, side);
                let rect = (
                    clip(x0.floor(), -margin),
                    clip(y0.floor(), -margin),
                    clip(x1.ceil(), margin),
                    clip(y1.ceil(), margin),
                );
                (f, rect)
            })
            .collect()
    })
}

/// The header's summary of the resampling: the largest error over all inputs and the root mean
/// square over all compared samples; heights as the inputs give them (DEMs are orthometric —
/// the inputs' vertical GeoKeys are not read yet).
pub fn provenance_of(resampling: &[InputResampling]) -> PlanetProvenance {
    let compared: u64 = resampling.iter().map(|r| r.compared).sum();
    let sum2: f64 = resampling
        .iter()
        .map(|r| r.rms_error * r.rms_error * r.compared as f64)
        .sum();
    PlanetProvenance {
        vertical_datum: VerticalDatum::Orthometric,
        resampling_max: resampling.iter().map(|r| r.max_error).fold(0.0, f64::max),
        resampling_rms: if compared > 0 {
            (sum2 / compared as f64).sqrt()
        } else {
            0.0
        },
    }
}

/// The lattice cell (on multiples of `step`, of a face of `side` steps) that face point
/// `(s, t)` lies in: its first corner in cells, and where in it the point lies.
#[inline]
fn lattice_cell(side: i64, step: i64, (s, t): (f64, f64)) -> ((i64, i64), (f64, f64)) {
    let (x, y) = (s * side as f64 / step as f64, t * side as f64 / step as f64);
    let cells = side / step;
    let (x0, y0) = (
        (x.floor() as i64).min(cells - 1),
        (y.floor() as i64).min(cells - 1),
    );
    ((x0, y0), (x - x0 as f64, y - y0 as f64))
}

/// The tiles (of `2^tile_log2` steps) holding the four lattice points (on multiples of `step`)
/// around face point `(face, s, t)`: those [`lattice_at`] reads.
pub(crate) fn sample_cell_tiles(
    side: i64,
    tile_log2: u32,
    step: i64,
    (face, s, t): (u8, f64, f64),
) -> [(u8, usize); 4] {
    let ((x0, y0), _) = lattice_cell(side, step, (s, t));
    [(0, 0), (1, 0), (0, 1), (1, 1)].map(|(dx, dy)| {
        let (px, py) = ((x0 + dx) * step, (y0 + dy) * step);
        (
            face,
            cbdam_codec::hierarchy::planet::tile_of(side, tile_log2, px, py),
        )
    })
}

/// The bilinear interpolant, metres, at face point `(face, s, t)` of the lattice points on
/// multiples of `step` around it, `None` unless all four took their height from input `me`.
fn lattice_at(
    resampled: &Resampled,
    plan: &QuantPlan,
    me: u16,
    (face, s, t): (u8, f64, f64),
    step: i64,
) -> Option<f64> {
    let planet = &resampled.planet;
    let side = planet.domain().cube().expect("a cube-sphere").side();
    let ((x0, y0), (fx, fy)) = lattice_cell(side, step, (s, t));
    // Corners inside the face (x0, y0 < S): its own tiles hold them (the
    // input's samples made them dense enough, `plan_tiles`), equal to every
    // other face's on shared points.
    // The four corners lie in the tile of the first but where the cell
    // crosses a tile's side.
    let winners = &resampled.winners[usize::from(face)];
    // (Looked up once: a sparse lattice finds its tiles by hashing.)
    let first = planet.tile_index(x0 * step, y0 * step);
    let first_tile = planet.tile(face, first);
    let (_, _, tx1, ty1) = first_tile.rect;
    let one_tile = (x0 + 1) * step <= tx1 && (y0 + 1) * step <= ty1;
    let corner = |dx: i64, dy: i64| {
        let (px, py) = ((x0 + dx) * step, (y0 + dy) * step);
        let (i, t) = if one_tile {
            (first, first_tile)
        } else {
            let i = planet.tile_index(px, py);
            (i, planet.tile(face, i))
        };
        let k = t.index(px, py)?;
        (winners[i][k] == me && t.grid.valid[k]).then(|| plan.metres(t.grid.values[k]))
    };
    let (a, b, cc, d) = (corner(0, 0)?, corner(1, 0)?, corner(0, 1)?, corner(1, 1)?);
    Some((a * (1.0 - fx) + b * fx) * (1.0 - fy) + (cc * (1.0 - fx) + d * fx) * fy)
}
