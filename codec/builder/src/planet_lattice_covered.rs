//! The outline's shortcut: squares of a tile whose every point provably takes a valid sample
//! of a fine latitude/longitude input, found from the positions of the square's border alone.
//!
//! The outline ([`super::LatticeTiles::outline`]) needs of a tile only each point's class and
//! validity, not its height. Where a point is asked of a fine input (stride 0, bilinear) that
//! covers it with four valid samples around it, its class is 0 and it is valid, whatever its
//! exact position. A square of the tile is *covered* when:
//! - the inputs its points are asked first (a prefix of the tile's candidates, in their order)
//!   are all such inputs, each asked of the whole square or of none of it;
//! - the latitude/longitude box of its points lies in the union of those inputs' rectangles of
//!   sample centres, and every sample of those inputs within a sample of the box is valid and
//!   finite.
//!
//! The box comes from the square's border: a lattice point's latitude and longitude have no
//! critical point inside a face (away from the poles, which are the centres of the polar faces
//! and refused here), so over the square they take their extremes on its border; between two
//! border points a curve's extreme exceeds theirs by less than [`MARGIN_DEG`], which the box
//! is widened by (it also covers the rounding of the positions, about 1e-14°).

use rayon::prelude::*;

use super::Resampler;
use crate::band_cache::Samples;
use crate::error::Result;
use crate::planet_input::{Frame, PlanetInput};
use cbdam_codec::geodesy::LatLon;

/// Side of the squares the outline tries to prove covered, in lattice points.
const SQUARE: usize = 64;

/// Degrees the box of a square's border positions is widened by: the most a latitude or
/// longitude can exceed its border points' between two of them a lattice step apart (at most
/// about 1e-7° for a cell of 2.5″ at 89° of latitude; squares closer to a pole are refused),
/// with room to spare.
const MARGIN_DEG: f64 = 1e-6;

/// Squares within this of a pole or of the antimeridian are not tried (degrees).
const POLE_LAT: f64 = 89.0;
const ANTIMERIDIAN_LON: f64 = 179.0;

/// A fine latitude/longitude input asked of a square: its index, spans of lattice points it is
/// asked over in the tile (columns, rows, inclusive), its samples, and its rectangle of sample
/// centres (degrees).
struct FineInput<'s> {
    input: &'s PlanetInput,
    span: (usize, usize, usize, usize),
    samples: std::sync::Arc<Samples>,
    lat: (f64, f64),
    lon: (f64, f64),
}

/// A latitude/longitude box, degrees: `(south, north)`, `(west, east)`.
type GeoBox = ((f64, f64), (f64, f64));

impl Resampler<'_> {
    /// Per point of tile `tile` of `face` at stride 1 (row-major), whether it lies in a square
    /// proved covered ([the module](self)); `None` where no square is, or the tile is not held
    /// at stride 1.
    pub(super) fn covered_points(&self, face: u8, tile: usize) -> Result<Option<Vec<bool>>> {
        if self.tiles.strides[usize::from(face)][tile] != 0 {
            return Ok(None);
        }
        let fine = self.fine_prefix(face, tile)?;
        if fine.is_empty() {
            return Ok(None);
        }
        let (w, h) = self.tile_size(tile, 0);
        let squares: Vec<(usize, usize)> = (0..h.div_ceil(SQUARE))
            .flat_map(|sy| (0..w.div_ceil(SQUARE)).map(move |sx| (sx, sy)))
            .collect();
        let proved: Vec<bool> = squares
            .par_iter()
            .map(|&(sx, sy)| {
                let cols = (sx * SQUARE, ((sx + 1) * SQUARE).min(w) - 1);
                let rows = (sy * SQUARE, ((sy + 1) * SQUARE).min(h) - 1);
                self.square_covered(face, tile, (cols, rows), &fine)
            })
            .collect();
        if !proved.contains(&true) {
            return Ok(None);
        }
        let mut mask = vec![false; w * h];
        for (&(sx, sy), _) in squares.iter().zip(&proved).filter(|(_, p)| **p) {
            for row in sy * SQUARE..((sy + 1) * SQUARE).min(h) {
                mask[row * w + sx * SQUARE..row * w + ((sx + 1) * SQUARE).min(w)].fill(true);
            }
        }
        Ok(Some(mask))
    }

    /// The tile's first candidates (in the order a point asks them) that are fine
    /// latitude/longitude inputs: stride 1 on the lattice, bilinear (no finer than the
    /// lattice), not around the globe, within a degree of longitude of [−180°, 180°].
    fn fine_prefix(&self, face: u8, tile: usize) -> Result<Vec<FineInput<'_>>> {
        let mut fine = Vec::new();
        for (index, span) in self.reaching(face, tile, 0, None) {
            let input = &self.inputs.inputs[usize::from(index)];
            let Frame::Geographic {
                lon0,
                lat0,
                dlon,
                dlat,
                period: None,
            } = input.frame
            else {
                break;
            };
            let east = lon0 + (input.width - 1) as f64 * dlon;
            let south = lat0 - (input.height - 1) as f64 * dlat;
            let fits = self.strides[usize::from(index)] == 0
                && self.lattice_deg <= input.spacing_deg
                && lon0 >= -181.0
                && east <= 181.0;
            if !fits {
                break;
            }
            fine.push(FineInput {
                input,
                span,
                samples: self.inputs.samples(usize::from(index))?,
                lat: (south, lat0),
                lon: (lon0, east),
            });
        }
        Ok(fine)
    }

    /// Whether the square of columns `cols` and rows `rows` (inclusive, points of the tile)
    /// is covered by the `fine` inputs ([the module](self)).
    fn square_covered(
        &self,
        face: u8,
        tile: usize,
        (cols, rows): ((usize, usize), (usize, usize)),
        fine: &[FineInput],
    ) -> bool {
        // The inputs asked of the square: each of all of it or of none of it.
        let mut asked = Vec::new();
        for f in fine {
            let (c0, c1, r0, r1) = f.span;
            if c0 <= cols.0 && cols.1 <= c1 && r0 <= rows.0 && rows.1 <= r1 {
                asked.push(f);
            } else if !(c1 < cols.0 || cols.1 < c0 || r1 < rows.0 || rows.1 < r0) {
                return false;
            }
        }
        let Some(bbox) = self.square_box(face, tile, (cols, rows)) else {
            return false;
        };
        in_union(bbox, &asked) && asked.iter().all(|f| samples_valid_around(f, bbox))
    }

    /// The box of the positions of the square's border points, widened by [`MARGIN_DEG`];
    /// `None` near a pole or the antimeridian.
    fn square_box(
        &self,
        face: u8,
        tile: usize,
        (cols, rows): ((usize, usize), (usize, usize)),
    ) -> Option<GeoBox> {
        let (x0, y0, _, _) = self.rects[tile];
        let at = |c: usize, r: usize| self.lat_lon(face, x0 + c as i64, y0 + r as i64);
        let border = (cols.0..=cols.1)
            .flat_map(|c| [at(c, rows.0), at(c, rows.1)])
            .chain((rows.0..=rows.1).flat_map(|r| [at(cols.0, r), at(cols.1, r)]));
        let mut bbox = (
            (f64::INFINITY, f64::NEG_INFINITY),
            (f64::INFINITY, f64::NEG_INFINITY),
        );
        for LatLon { lat, lon } in border {
            bbox.0 = (bbox.0.0.min(lat), bbox.0.1.max(lat));
            bbox.1 = (bbox.1.0.min(lon), bbox.1.1.max(lon));
        }
        let ((south, north), (west, east)) = bbox;
        let clear = south > -POLE_LAT
            && north < POLE_LAT
            && west > -ANTIMERIDIAN_LON
            && east < ANTIMERIDIAN_LON;
        clear.then_some((
            (south - MARGIN_DEG, north + MARGIN_DEG),
            (west - MARGIN_DEG, east + MARGIN_DEG),
        ))
    }
}

/// Whether `bbox` lies in the union of the inputs' rectangles: every cell of the grid their
/// edges cut it into lies in one of them.
fn in_union(bbox: GeoBox, inputs: &[&FineInput]) -> bool {
    let cuts = |(lo, hi): (f64, f64), edges: &mut dyn Iterator<Item = f64>| {
        let mut at: Vec<f64> = edges.filter(|&e| lo < e && e < hi).collect();
        at.extend([lo, hi]);
        at.sort_by(f64::total_cmp);
        at.dedup();
        at
    };
    let lats = cuts(bbox.0, &mut inputs.iter().flat_map(|f| [f.lat.0, f.lat.1]));
    let lons = cuts(bbox.1, &mut inputs.iter().flat_map(|f| [f.lon.0, f.lon.1]));
    lats.windows(2).all(|la| {
        lons.windows(2).all(|lo| {
            inputs.iter().any(|f| {
                f.lat.0 <= la[0] && la[1] <= f.lat.1 && f.lon.0 <= lo[0] && lo[1] <= f.lon.1
            })
        })
    })
}

/// Whether every sample of the input within a sample of `bbox` (and one more on the far side,
/// where the bilinear's second column and row lie) is valid and finite.
fn samples_valid_around(f: &FineInput, ((south, north), (west, east)): GeoBox) -> bool {
    let Frame::Geographic {
        lon0,
        lat0,
        dlon,
        dlat,
        ..
    } = f.input.frame
    else {
        return false;
    };
    let (w, h) = (f.input.width as i64, f.input.height as i64);
    let (c_lo, c_hi) = ((west - lon0) / dlon, (east - lon0) / dlon);
    let (r_lo, r_hi) = ((lat0 - north) / dlat, (lat0 - south) / dlat);
    if c_hi < -1.0 || c_lo > w as f64 || r_hi < -1.0 || r_lo > h as f64 {
        return true;
    }
    let window = |lo: f64, hi: f64, n: i64| {
        let first = (lo.max(0.0).floor() as i64 - 1).max(0);
        let last = (hi.min((n - 1) as f64).floor() as i64 + 2).min(n - 1);
        first as usize..=last as usize
    };
    let (cs, rs) = (window(c_lo, c_hi, w), window(r_lo, r_hi, h));
    rs.into_iter().all(|r| {
        cs.clone()
            .all(|c| f.input.sample(&f.samples, c, r).is_some_and(f64::is_finite))
    })
}
