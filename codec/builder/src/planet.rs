//! `cbdam build --planet`: geographic and UTM DEMs resampled onto the cube-sphere lattice
//! (`docs/PLANET.md`) and encoded as one planet.
//!
//! Every lattice point takes its height from the finest input that covers it (inputs sorted by
//! ground spacing, ties in the order given): **bilinear** between the input's four surrounding
//! samples where the lattice is at least as fine as the input (bilinear never overshoots), the
//! **area average** of the input's samples within the lattice cell's footprint (a box of the
//! lattice's mean spacing around the point) where the lattice is coarser. A point whose
//! neighbourhood holds nodata in the finest input falls through to the next input; a point no
//! input covers is nodata. Coordinates are exact f64: the lattice point's geodetic latitude and
//! longitude ([`cbdam_codec::geodesy::lattice_lat_lon`]) and, for projected inputs, the UTM
//! transform ([`cbdam_codec::geodesy::Utm`]).
//!
//! The L∞ bound of the repository holds against the resampled lattice (that is what the encoder
//! sees). Beside it [`resampling_error`] measures how far the lattice is from the inputs' own
//! samples: each input sample against the bilinear interpolant of the four lattice points
//! around it, wherever those four took their height from that input.

use std::path::{Path, PathBuf};
use std::time::Instant;

use rayon::prelude::*;

use crate::assign::AssignedGeoRef;
use crate::band_cache::Samples;
use crate::error::{Context, Result, bail};
use crate::input::{ReadOptions, TileReader};
use crate::tiles::Tile;
use crate::{BuildOptions, Progress, ProgressEvent, Stage};
use cbdam_codec::error::CodecError;
use cbdam_codec::geodesy::cube_map::{FaceLattice, lat_lon_to_face_st, sin_cos_to_face_st};
use cbdam_codec::geodesy::{LatLon, Utm, lattice_lat_lon};
use cbdam_codec::geometry::Domain;
use cbdam_codec::hierarchy::planet::{tile_log2, tile_of};
use cbdam_codec::hierarchy::resolution::{COARSE_ONLY, HOLE};
use cbdam_codec::hierarchy::{EncodeOptions, PlanetGrid, PlanetTile, encode_planet};
use cbdam_codec::lifting::Alpha;
use cbdam_codec::quant::{HeightGrid, QuantPlan};
use cbdam_codec::repository::GeoRef;
use cbdam_codec::repository::{PlanetProvenance, VerticalDatum, write_planet_repository};
use cbdam_codec::samples::Dem;

/// Metres per degree of arc on the ground (the WGS 84 mean), to compare projected spacings with
/// angular ones.
const METRES_PER_DEGREE: f64 = 111_195.0;

/// EPSG codes of the geographic coordinate systems accepted as latitude/longitude on WGS 84:
/// WGS 84 itself, and NAD83, ETRS89 and GDA94, whose datums are within about 2 m of it.
pub const GEOGRAPHIC_EPSG: [u32; 4] = [4326, 4269, 4258, 4283];

/// Bytes the planet build holds per lattice point its tiles hold ([`PlanetGrid`]), measured on
/// the ETOPO5 planet with margin (`/usr/bin/time -v cbdam build data/etopo5_global.tif --planet
/// --max-error 16`: 482 MB peak for 25.2 M points, 19.6 B a point): the tiles (6 B with
/// classes), the resampling winners (2 B) and the encoder's per-diamond refinements of two
/// levels.
pub const BYTES_PER_LATTICE_POINT: u64 = 24;

/// How an input's pixels lie on the Earth.
#[derive(Clone, Copy, Debug)]
enum Frame {
    /// Latitude/longitude degrees: sample `(c, r)` at `lon0 + c·dlon`, `lat0 − r·dlat`;
    /// `period`: columns per 360° when the input wraps around the globe.
    Geographic {
        lon0: f64,
        lat0: f64,
        dlon: f64,
        dlat: f64,
        period: Option<usize>,
    },
    /// A UTM zone: sample `(c, r)` at easting `x0 + c·dx`, northing `y0 − r·dy`.
    Projected {
        utm: Utm,
        x0: f64,
        y0: f64,
        dx: f64,
        dy: f64,
    },
}

/// One input, read and placed on the Earth.
pub struct PlanetInput {
    /// The file.
    pub path: PathBuf,
    width: usize,
    height: usize,
    samples: Samples,
    nodata: Option<f64>,
    frame: Frame,
    /// Ground spacing of its samples, degrees of arc (north–south).
    pub spacing_deg: f64,
}

impl PlanetInput {
    fn sample(&self, c: usize, r: usize) -> Option<f64> {
        let v = self.samples.get(r * self.width + c);
        (!v.is_nan() && self.nodata != Some(v)).then_some(v)
    }

    /// Fractional column and row of a point, or `None` off the input.
    fn pixel_of(&self, ll: LatLon) -> Option<(f64, f64)> {
        const SLACK: f64 = 1e-9;
        let (w, h) = (self.width as f64, self.height as f64);
        let (c, r) = match self.frame {
            Frame::Geographic {
                lon0,
                lat0,
                dlon,
                dlat,
                period,
            } => {
                let r = (lat0 - ll.lat) / dlat;
                let c = (ll.lon - lon0) / dlon;
                let c = match period {
                    Some(p) => rem_euclid(c, p as f64),
                    None => [c, c + 360.0 / dlon, c - 360.0 / dlon]
                        .into_iter()
                        .find(|c| (-SLACK..=w - 1.0 + SLACK).contains(c))?,
                };
                (c, r)
            }
            Frame::Projected {
                utm,
                x0,
                y0,
                dx,
                dy,
            } => {
                let (e, n) = utm.forward(ll);
                ((e - x0) / dx, (y0 - n) / dy)
            }
        };
        let wraps = matches!(
            self.frame,
            Frame::Geographic {
                period: Some(_),
                ..
            }
        );
        let c_max = if wraps { w } else { w - 1.0 };
        ((-SLACK..=c_max + SLACK).contains(&c) && (-SLACK..=h - 1.0 + SLACK).contains(&r))
            .then_some((c.clamp(0.0, c_max), r.clamp(0.0, h - 1.0)))
    }

    /// The column index of `c`, wrapped for inputs around the globe.
    fn column(&self, c: i64) -> Option<usize> {
        match self.frame {
            Frame::Geographic {
                period: Some(p), ..
            } => Some(c.rem_euclid(p as i64) as usize).filter(|&c| c < self.width),
            _ => usize::try_from(c).ok().filter(|&c| c < self.width),
        }
    }

    /// Bilinear interpolation at a fractional pixel; `None` unless all four samples are valid.
    fn bilinear(&self, (c, r): (f64, f64)) -> Option<f64> {
        let wraps = matches!(
            self.frame,
            Frame::Geographic {
                period: Some(_),
                ..
            }
        );
        let c0 = if wraps {
            c.floor()
        } else {
            c.floor().min(self.width.saturating_sub(2) as f64)
        };
        let r0 = r.floor().min(self.height.saturating_sub(2) as f64);
        let (fx, fy) = (c - c0, r - r0);
        let (c0, r0) = (c0 as i64, r0 as usize);
        let r1 = (r0 + 1).min(self.height - 1);
        let (ca, cb) = (
            self.column(c0)?,
            self.column(c0 + 1).unwrap_or(self.column(c0)?),
        );
        let v = |c, r| self.sample(c, r);
        let top = v(ca, r0)? * (1.0 - fx) + v(cb, r0)? * fx;
        let bottom = v(ca, r1)? * (1.0 - fx) + v(cb, r1)? * fx;
        Some(top * (1.0 - fy) + bottom * fy)
    }

    /// Mean of the valid samples whose centres lie within `half` (columns, rows) of a pixel.
    fn area_average(&self, (c, r): (f64, f64), half: (f64, f64)) -> Option<f64> {
        let (r_lo, r_hi) = (
            (r - half.1).ceil().max(0.0) as usize,
            ((r + half.1).floor() as usize).min(self.height - 1),
        );
        let (c_lo, c_hi) = ((c - half.0).ceil() as i64, (c + half.0).floor() as i64);
        let (mut sum, mut count) = (0.0, 0u64);
        for row in r_lo..=r_hi {
            for col in c_lo..=c_hi {
                if let Some(v) = self.column(col).and_then(|col| self.sample(col, row)) {
                    sum += v;
                    count += 1;
                }
            }
        }
        (count > 0).then(|| sum / count as f64)
    }

    /// The height at a point whose lattice cell is `lattice_deg` degrees across: bilinear where
    /// the lattice is at least as fine as the input, the area average where it is coarser.
    fn height_at(&self, ll: LatLon, lattice_deg: f64) -> Option<f64> {
        let px = self.pixel_of(ll)?;
        if lattice_deg > self.spacing_deg {
            let half_deg = lattice_deg / 2.0;
            let half = match self.frame {
                Frame::Geographic { dlon, dlat, .. } => {
                    let cos = ll.lat.to_radians().cos().max(1e-9);
                    ((half_deg / cos / dlon).min(180.0 / dlon), half_deg / dlat)
                }
                Frame::Projected { dx, dy, .. } => (
                    half_deg * METRES_PER_DEGREE / dx,
                    half_deg * METRES_PER_DEGREE / dy,
                ),
            };
            if let Some(v) = self.area_average(px, half) {
                return Some(v);
            }
        }
        self.bilinear(px)
    }

    /// Latitude and longitude of sample `(c, r)`.
    fn lat_lon_of(&self, c: usize, r: usize) -> LatLon {
        match self.frame {
            Frame::Geographic {
                lon0,
                lat0,
                dlon,
                dlat,
                ..
            } => {
                let mut lon = lon0 + c as f64 * dlon;
                lon -= 360.0 * ((lon - 1e-12) / 360.0).round();
                LatLon {
                    lat: lat0 - r as f64 * dlat,
                    lon,
                }
            }
            Frame::Projected {
                utm,
                x0,
                y0,
                dx,
                dy,
            } => utm.inverse(x0 + c as f64 * dx, y0 - r as f64 * dy),
        }
    }

    /// The valid height range, metres.
    fn range(&self) -> Option<(f64, f64)> {
        (0..self.height)
            .into_par_iter()
            .filter_map(|r| {
                (0..self.width).filter_map(|c| self.sample(c, r)).fold(
                    None,
                    |acc: Option<(f64, f64)>, v| {
                        Some(acc.map_or((v, v), |(lo, hi)| (lo.min(v), hi.max(v))))
                    },
                )
            })
            .reduce_with(|a, b| (a.0.min(b.0), a.1.max(b.1)))
    }
}

/// `c.rem_euclid(p)` bit for bit, without the `fmod` of `%` where `c` is less than a period
/// out of `[0, p)` (every longitude of a global input): below 0, `c % p` is `c` and
/// `rem_euclid` adds `p`, as here; in `[p, 2p)` the exact remainder is `c − p`, which is exact
/// in floating point there (Sterbenz).
#[inline]
fn rem_euclid(c: f64, p: f64) -> f64 {
    if (0.0..p).contains(&c) {
        c
    } else if (-p..0.0).contains(&c) {
        c + p
    } else if (p..2.0 * p).contains(&c) {
        c - p
    } else {
        c.rem_euclid(p)
    }
}

/// [`crate::input::read_dem`], with the bands of a GeoTIFF's strips or tiles decoded on
/// all the build's workers (the same samples: [`TileReader`] reads rows as `read_dem` would).
fn read_whole(path: &Path, opts: &ReadOptions) -> std::result::Result<Dem, CodecError> {
    let reader = TileReader::open(path, opts)?;
    let (width, height) = (reader.width(), reader.height());
    let band = reader.band_rows().max(1);
    let mut values = vec![0.0; width * height];
    values
        .par_chunks_mut((band * width).max(1))
        .enumerate()
        .try_for_each(|(b, out)| {
            let start = b * band;
            let mut rows = Vec::new();
            reader.read_rows(start..(start + band).min(height), &mut rows)?;
            out.copy_from_slice(&rows);
            Ok::<_, CodecError>(())
        })?;
    Ok(Dem {
        width,
        height,
        values,
        sample_type: reader.sample_type(),
        nodata: reader.nodata(),
        georef: reader.georef().cloned(),
    })
}

/// Reads one input and places it on the Earth, or says why it cannot be. An input without
/// georeferencing of its own takes `assign`'s (`--bounds`/`--crs`); the flag says it did.
fn read_input(
    tile: &Tile,
    nodata: Option<f64>,
    assign: Option<&AssignedGeoRef>,
) -> Result<(PlanetInput, bool)> {
    let path = &tile.path;
    // A tile a VRT places keeps its own georeferencing (checked against the VRT's) or takes
    // the VRT's, and the VRT's nodata value where none is given, as in a planar mosaic.
    let opts = ReadOptions {
        nodata: nodata.or(tile.vrt.as_ref().and_then(|v| v.nodata)),
        ..ReadOptions::default()
    };
    let dem = read_whole(path, &opts).with_context(|| format!("reading {}", path.display()))?;
    let mut georef = dem.georef.clone();
    if let Some(v) = &tile.vrt {
        crate::mosaic::place_vrt_tile(path, (dem.width, dem.height), &mut georef, v)?;
    }
    let assigned = georef.is_none() && assign.is_some();
    if let (None, Some(a)) = (&georef, assign) {
        georef = Some(a.georef(dem.width, dem.height));
    }
    let Some(georef) = georef else {
        bail!(
            "{} carries no georeferencing: a planet needs to know where each input lies \
             (EPSG:4326 latitude/longitude or a UTM zone; --bounds and --crs give it to one \
             input without)",
            path.display()
        );
    };
    let frame = frame_of(&georef, dem.width).with_context(|| path.display().to_string())?;
    let spacing_deg = match frame {
        Frame::Geographic { dlat, .. } => dlat,
        Frame::Projected { dy, .. } => dy / METRES_PER_DEGREE,
    };
    let width = dem.width;
    let height = dem.height;
    if width < 2 || height < 2 {
        bail!(
            "{} is {width}×{height} samples: a planet input needs at least 2×2",
            path.display()
        );
    }
    Ok((
        PlanetInput {
            path: path.clone(),
            width,
            height,
            samples: Samples::compact(dem.values),
            nodata: dem.nodata,
            frame,
            spacing_deg,
        },
        assigned,
    ))
}

/// How the `width` columns of an input georeferenced by `g` lie on the Earth.
fn frame_of(g: &GeoRef, width: usize) -> Result<Frame> {
    let epsg = g.epsg.unwrap_or(0);
    if !(g.pixel_x > 0.0 && g.pixel_y > 0.0) {
        bail!(
            "pixel size {} × {}: rows must run south and columns east",
            g.pixel_x,
            g.pixel_y
        );
    }
    // Sample centres: half a pixel in from the corner when pixels are areas.
    let half = if g.pixel_is_area { 0.5 } else { 0.0 };
    let (x0, y0) = (g.origin_x + half * g.pixel_x, g.origin_y - half * g.pixel_y);
    if GEOGRAPHIC_EPSG.contains(&epsg) {
        // It wraps only when its columns go all the way round: a spacing that divides 360°
        // (3″, 5′, 2⁻¹⁰ of 90°) is not enough — an inset of it would take the point up to one
        // column east of its last one as its own, clamped onto the last column.
        let per_turn = 360.0 / g.pixel_x;
        let period = ((per_turn - per_turn.round()).abs() < 1e-6
            && width as f64 >= per_turn.round())
        .then_some(per_turn.round() as usize);
        return Ok(Frame::Geographic {
            lon0: x0,
            lat0: y0,
            dlon: g.pixel_x,
            dlat: g.pixel_y,
            period,
        });
    }
    if let Some(utm) = Utm::from_epsg(epsg) {
        return Ok(Frame::Projected {
            utm,
            x0,
            y0,
            dx: g.pixel_x,
            dy: g.pixel_y,
        });
    }
    bail!(
        "EPSG:{epsg} cannot be placed on a planet: accepted are latitude/longitude ({}) and UTM \
         zones (EPSG 32601–32660, 32701–32760 on WGS 84; 26901–26923 NAD83; 25828–25838 ETRS89)",
        GEOGRAPHIC_EPSG.map(|e| format!("EPSG:{e}")).join(", ")
    )
}

/// Inputs a planet combines at most: which one wins a lattice point is kept in 16 bits,
/// `u16::MAX` meaning none.
pub const MAX_PLANET_INPUTS: usize = u16::MAX as usize - 1;

/// All inputs of a planet, finest first.
pub struct PlanetInputs {
    /// The inputs, by ground spacing (finest first; ties in the order given).
    pub inputs: Vec<PlanetInput>,
}

impl PlanetInputs {
    /// Reads every input ([`crate::tiles::expand_inputs`] already expanded them); `assign`
    /// (`--bounds`/`--crs`) georeferences the one input that carries none, and is refused when
    /// none or several do.
    pub fn read(
        tiles: &[Tile],
        nodata: Option<f64>,
        assign: Option<&AssignedGeoRef>,
    ) -> Result<Self> {
        if tiles.is_empty() {
            bail!("no input given");
        }
        if tiles.len() > MAX_PLANET_INPUTS {
            bail!(
                "{} inputs: a planet combines at most {MAX_PLANET_INPUTS}; merge tiles of the \
                 same source into larger ones first",
                tiles.len(),
            );
        }
        let read = tiles
            .iter()
            .map(|t| read_input(t, nodata, assign))
            .collect::<Result<Vec<_>>>()?;
        if assign.is_some() {
            let assigned: Vec<&PlanetInput> =
                read.iter().filter(|(_, a)| *a).map(|(i, _)| i).collect();
            match assigned.as_slice() {
                [] => bail!(
                    "--bounds and --crs georeference an input that carries none, and every \
                     input here has its own"
                ),
                [_] => {}
                [a, b, ..] => bail!(
                    "--bounds and --crs georeference one input, but {} and {} both carry none \
                     (give each its own georeferencing)",
                    a.path.display(),
                    b.path.display()
                ),
            }
        }
        let mut inputs: Vec<PlanetInput> = read.into_iter().map(|(i, _)| i).collect();
        inputs.sort_by(|a, b| a.spacing_deg.total_cmp(&b.spacing_deg));
        Ok(Self { inputs })
    }

    /// The finest input's spacing, degrees.
    pub fn finest_deg(&self) -> f64 {
        self.inputs[0].spacing_deg
    }

    /// The height range over all inputs, metres.
    pub fn range(&self) -> Option<(f64, f64)> {
        self.inputs
            .iter()
            .filter_map(PlanetInput::range)
            .reduce(|a, b| (a.0.min(b.0), a.1.max(b.1)))
    }

    /// The stride of each input on a lattice of `n`, `k` (see [`input_stride`]).
    pub fn strides(&self, n: usize, k: u32) -> Vec<u32> {
        self.inputs
            .iter()
            .map(|i| input_stride(i.spacing_deg, lattice_spacing_deg(n, k), k))
            .collect()
    }

    /// What lattice point `(x, y)` at `ll` takes from input `i`, if it covers it: on that
    /// input's stride the point is one of its samples ([`PointSource::Sample`]; the height for
    /// a lattice cell `2^stride` times the lattice's, `lattice_deg` across); between them it is
    /// coarse only. A point takes the first input (finest first) that covers it.
    fn source_of(
        &self,
        i: u16,
        ll: LatLon,
        (x, y): (i64, i64),
        lattice_deg: f64,
        strides: &[u32],
    ) -> Option<PointSource> {
        let j = strides[usize::from(i)];
        let step = 1i64 << j;
        let v = self.inputs[usize::from(i)].height_at(ll, lattice_deg * step as f64)?;
        Some(if x % step == 0 && y % step == 0 {
            PointSource::Sample(v, i, j as u8)
        } else {
            PointSource::CoarseOnly(i)
        })
    }
}

/// What a lattice point takes from the inputs.
#[derive(Clone, Copy, Debug, PartialEq)]
enum PointSource {
    /// Height (metres), the winning input and its stride's `log2`.
    Sample(f64, u16, u8),
    /// Between the samples of this (coarser) input: drawn from its level, not constrained.
    CoarseOnly(u16),
}

/// `log2` of the stride at which an input of ground spacing `input_deg` samples a lattice of
/// spacing `lattice_deg` with `k` level pairs: the largest `j ≤ k` with `2^j` lattice steps no
/// wider than the input's spacing. Its samples are the lattice points on multiples of `2^j`,
/// vertices of level `2K − 2j`, and the lattice points between them are *coarse only*: the
/// hierarchy ends at that level where this input is the finest data (variable resolution: an
/// ETOPO ocean stays as coarse as ETOPO under a fine inset's lattice).
pub fn input_stride(input_deg: f64, lattice_deg: f64, k: u32) -> u32 {
    (0..=k)
        .rev()
        .find(|&j| lattice_deg * f64::from(1u32 << j) <= input_deg * (1.0 + 1e-9))
        .unwrap_or(0)
}

/// Mean spacing of a cube-sphere lattice, degrees of arc: a face spans 90° over `S` steps.
pub fn lattice_spacing_deg(n: usize, k: u32) -> f64 {
    90.0 / ((n as f64 - 1.0) * f64::from(1u32 << k))
}

/// The lattice's level pairs `K`: the given one, or the coarsest at least as fine as the finest
/// input; in both cases refused if the build would need more than `memory_limit` bytes
/// ([`BYTES_PER_LATTICE_POINT`] per point its tiles hold, [`plan_tiles`]).
pub fn choose_level(
    inputs: &PlanetInputs,
    n: usize,
    forced: Option<u32>,
    memory_limit: u64,
) -> Result<u32> {
    const MAX_K: u32 = 16;
    let need = |k: u32| -> Result<u64> {
        Ok(held_points(n, k, &plan_tiles(inputs, n, k)?.strides)? * BYTES_PER_LATTICE_POINT)
    };
    if let Some(k) = forced {
        if k > MAX_K {
            bail!("--planet-level {k}: at most {MAX_K}");
        }
        let need = need(k)?;
        if need > memory_limit {
            bail!(
                "--planet-level {k} ({:.3}° lattice) needs about {} MiB, over the memory limit \
                 of {} MiB",
                lattice_spacing_deg(n, k),
                need >> 20,
                memory_limit >> 20
            );
        }
        return Ok(k);
    }
    let finest = inputs.finest_deg();
    let wanted = (0..=MAX_K)
        .find(|&k| lattice_spacing_deg(n, k) <= finest * (1.0 + 1e-9))
        .unwrap_or(MAX_K);
    for k in (0..=wanted).rev() {
        if need(k)? <= memory_limit {
            return Ok(k);
        }
    }
    bail!(
        "even the coarsest planet lattice needs about {} MiB, over the memory limit of {} MiB",
        need(0)? >> 20,
        memory_limit >> 20
    )
}

/// The points the tiles of an `n`, `k` planet hold under `plan` (per face, per tile, `log2` of
/// the stride).
fn held_points(n: usize, k: u32, plan: &[Vec<u32>]) -> Result<u64> {
    let domain = Domain::cube_sphere(n, k)?;
    let side = domain.cube().expect("a cube-sphere").side();
    let rects = PlanetGrid::tile_rects(&domain, tile_log2(side));
    Ok(plan
        .iter()
        .flat_map(|strides| {
            strides.iter().zip(&rects).map(|(&s, &(x0, y0, x1, y1))| {
                (((x1 - x0) >> s) as u64 + 1) * (((y1 - y0) >> s) as u64 + 1)
            })
        })
        .sum())
}

/// An input that can cover part of a lattice tile: its index, and the rectangle of the tile
/// (`(x0, y0, x1, y1)`, inclusive) it can cover (`None`: the whole tile).
pub type Candidate = (u16, Option<(i64, i64, i64, i64)>);

/// What each tile of a planet's faces holds ([`plan_tiles`]).
pub struct TilePlan {
    /// Per face, per tile: `log2` of the stride of the points it holds.
    pub strides: Vec<Vec<u32>>,
    /// Per face, per tile: the inputs that can cover a point of it, finest first (indices into
    /// [`PlanetInputs::inputs`]), each with the rectangle of the tile it can cover: the inputs
    /// around the globe (`None`: all of it), and the others whose samples lie in or near the
    /// tile. Only these are asked, and only inside their rectangles, so a planet of thousands
    /// of tiles asks a handful for each point.
    pub candidates: Vec<Vec<Vec<Candidate>>>,
}

/// The stride (`log2`) at which each tile of each face of the `n`, `k` lattice holds its
/// points ([`PlanetGrid`]), and the inputs that can cover it: the finest stride (at most the
/// tile's side) of the inputs around the globe and of those whose samples lie in or near it
/// (within a few of their cells, across face edges too); the tile's side where none does
/// (its corners only, holes). An input's
/// footprint is found from its sample positions (every `q`-th, close enough that no covered
/// lattice point is farther than the margin from one), so a fine inset makes only the tiles
/// around it dense. [`resample`] makes a tile denser still should one of its points turn out to
/// take a finer input's sample.
pub fn plan_tiles(inputs: &PlanetInputs, n: usize, k: u32) -> Result<TilePlan> {
    let domain = Domain::cube_sphere(n, k)?;
    let cube = *domain.cube().expect("a cube-sphere");
    let side = cube.side();
    let t = tile_log2(side);
    let rects = PlanetGrid::tile_rects(&domain, t);
    let strides = inputs.strides(n, k);
    let faces = usize::from(domain.faces());
    // A tile no input reaches holds its corners only (holes all).
    let mut plan = vec![vec![t; rects.len()]; faces];
    let mut candidates: Vec<Vec<Vec<Candidate>>> = vec![vec![Vec::new(); rects.len()]; faces];
    for (i, (input, &j)) in inputs.inputs.iter().zip(&strides).enumerate() {
        let i = u16::try_from(i).expect("at most MAX_PLANET_INPUTS inputs");
        let mark = j.min(t);
        if matches!(
            input.frame,
            Frame::Geographic {
                period: Some(_),
                ..
            }
        ) {
            // Around the globe: a candidate everywhere.
            for (tiles, strides) in candidates.iter_mut().zip(&mut plan) {
                for (c, s) in tiles.iter_mut().zip(strides.iter_mut()) {
                    c.push((i, None));
                    *s = (*s).min(mark);
                }
            }
            continue;
        }
        // Sample positions `q` apart are at most `q·2^(j+1)` lattice steps apart (an input's
        // spacing is under twice its stride); a lattice point it covers lies within one cell
        // of its samples.
        let cell = 2i64 << j;
        // At most a quarter of the tile or of the input apart.
        let q = ((1i64 << t) / (4 * cell))
            .min((input.width.min(input.height) / 4) as i64)
            .max(1) as usize;
        let margin = ((q as i64 + 2) * cell).min(side);
        // Offsets no farther apart than half a tile, so that every tile within the margin is
        // met.
        let step = margin.min(1 << (t - 1)).max(1);
        let mut offsets: Vec<i64> = (0..)
            .map(|m| -margin + m * step)
            .take_while(|&o| o < margin)
            .collect();
        offsets.push(margin);
        let along = |len: usize| (0..len).step_by(q).chain([len - 1]);
        let positions: Vec<(usize, usize)> = along(input.height)
            .flat_map(|r| along(input.width).map(move |c| (c, r)))
            .collect();
        let hits: Vec<(u8, usize, i64, i64)> = positions
            .par_iter()
            .flat_map_iter(|&(c, r)| {
                let (face, s, tt) = lat_lon_to_face_st(input.lat_lon_of(c, r));
                let (x, y) = (
                    (s * side as f64).round() as i64,
                    (tt * side as f64).round() as i64,
                );
                let mut hits = Vec::new();
                for &dy in &offsets {
                    for &dx in &offsets {
                        let Some(p) = cube.locate(face, x + dx, y + dy) else {
                            continue;
                        };
                        let (reps, len) = cube.representations(p);
                        for r in &reps[..len] {
                            hits.push((r.face, tile_of(side, t, r.x, r.y), r.x, r.y));
                        }
                    }
                }
                hits
            })
            .collect();
        // Per tile met, the rectangle of the points met (the footprint and its margin there).
        let mut reach_of: std::collections::BTreeMap<(u8, usize), (i64, i64, i64, i64)> =
            std::collections::BTreeMap::new();
        for (face, tile, x, y) in hits {
            let r = reach_of.entry((face, tile)).or_insert((x, y, x, y));
            *r = (r.0.min(x), r.1.min(y), r.2.max(x), r.3.max(y));
        }
        // A covered point of a tile lies within one offset step of a point met there (the
        // offsets are a grid no coarser than `step` over each position's square, and a tile
        // is wider than that).
        for ((face, tile), r) in reach_of {
            let f = usize::from(face);
            plan[f][tile] = plan[f][tile].min(mark);
            let (tx0, ty0, tx1, ty1) = rects[tile];
            let grown = (
                (r.0 - step).max(tx0),
                (r.1 - step).max(ty0),
                (r.2 + step).min(tx1),
                (r.3 + step).min(ty1),
            );
            candidates[f][tile].push((i, Some(grown)));
        }
    }
    Ok(TilePlan {
        strides: plan,
        candidates,
    })
}

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

/// Resamples the inputs onto the `N`, `K` cube-sphere (see the module documentation): the
/// finest input covering a point gives its height where the point lies on that input's
/// stride ([`input_stride`]), and makes it coarse only between. Tile by tile, each at the
/// stride [`plan_tiles`] gives it.
pub fn resample(inputs: &PlanetInputs, n: usize, k: u32, plan: &QuantPlan) -> Result<Resampled> {
    let domain = Domain::cube_sphere(n, k)?;
    let side = domain.cube().expect("a cube-sphere").side();
    let lattice_deg = lattice_spacing_deg(n, k);
    let strides = inputs.strides(n, k);
    let variable = strides.iter().any(|&j| j > 0);
    let TilePlan {
        strides: tile_strides,
        candidates,
    } = plan_tiles(inputs, n, k)?;
    let rects = PlanetGrid::tile_rects(&domain, tile_log2(side));
    let lattices: Vec<FaceLattice> = (0..domain.faces())
        .map(|face| FaceLattice::new(face, side))
        .collect();
    // One tile's points at stride 2^s: heights, validity, classes and winners.
    // One tile's points at stride 2^s: heights, validity, classes and winners. The inputs
    // that can cover the tile paint it finest first, each over its own rectangle, each point
    // taking the first that covers it.
    let evaluate = |face: u8, tile: usize, rect: (i64, i64, i64, i64), s: u32| {
        let (x0, y0, x1, y1) = rect;
        let (w, h) = (((x1 - x0) >> s) as usize + 1, ((y1 - y0) >> s) as usize + 1);
        let lattice = &lattices[usize::from(face)];
        let mut values = vec![0; w * h];
        let mut valid = vec![false; w * h];
        let mut won = vec![u16::MAX; w * h];
        let mut class = vec![HOLE; w * h];
        let mut done = vec![false; w * h];
        let step = 1i64 << s;
        for &(input, reach) in &candidates[usize::from(face)][tile] {
            // The tile's points (on its stride) in the input's rectangle.
            let (rx0, ry0, rx1, ry1) = reach.unwrap_or(rect);
            let first = |lo: i64, o: i64| ((lo.max(o) - o + step - 1) / step) as usize;
            let last = |hi: i64, o: i64, n: usize| (((hi - o) / step) as usize).min(n - 1);
            if rx1 < x0 || ry1 < y0 || rx0 > x1 || ry0 > y1 {
                continue;
            }
            let (c0, c1) = (first(rx0, x0), last(rx1, x0, w));
            let (r0, r1) = (first(ry0, y0), last(ry1, y0, h));
            if c0 > c1 || r0 > r1 {
                continue;
            }
            let rows = (r0 * w)..((r1 + 1) * w);
            values[rows.clone()]
                .par_chunks_mut(w)
                .zip(valid[rows.clone()].par_chunks_mut(w))
                .zip(won[rows.clone()].par_chunks_mut(w))
                .zip(class[rows.clone()].par_chunks_mut(w))
                .zip(done[rows].par_chunks_mut(w))
                .enumerate()
                .for_each(|(row, ((((values, valid), won), class), done))| {
                    let y = y0 + (((r0 + row) as i64) << s);
                    for i in c0..=c1 {
                        if done[i] {
                            continue;
                        }
                        let x = x0 + ((i as i64) << s);
                        // Interior points are their own canonical point; edge and corner
                        // points are computed from their owner, so every face holding one sees
                        // the same bits.
                        let ll = if 0 < x && x < side && 0 < y && y < side {
                            lattice.lat_lon(x as usize, y as usize)
                        } else {
                            lattice_lat_lon(&domain, face, x, y).expect("a point of the face")
                        };
                        match inputs.source_of(input, ll, (x, y), lattice_deg, &strides) {
                            Some(PointSource::Sample(v, wi, j)) => {
                                if let Some(u) = plan.to_units(v).ok().flatten() {
                                    values[i] = u;
                                    valid[i] = true;
                                    won[i] = wi;
                                    class[i] = j;
                                }
                                done[i] = true;
                            }
                            Some(PointSource::CoarseOnly(wi)) => {
                                won[i] = wi;
                                class[i] = COARSE_ONLY;
                                done[i] = true;
                            }
                            None => {}
                        }
                    }
                });
        }
        let finest = class.iter().copied().filter(|&c| c < 32).min();
        (values, valid, won, class, finest)
    };
    let faces: Vec<Vec<(PlanetTile, Vec<u16>)>> = (0..domain.faces())
        .map(|face| {
            rects
                .par_iter()
                .zip(&tile_strides[usize::from(face)])
                .enumerate()
                .map(|(i, (&rect, &planned))| {
                    let mut s = planned;
                    let mut tile = evaluate(face, i, rect, s);
                    // A point that took a finer input's sample than planned: the tile holds
                    // every point of that input's stride.
                    if let Some(j) = tile.4.filter(|&j| u32::from(j) < s) {
                        s = u32::from(j);
                        tile = evaluate(face, i, rect, s);
                    }
                    let (values, valid, won, class, _) = tile;
                    let (x0, y0, x1, y1) = rect;
                    let grid = HeightGrid {
                        width: ((x1 - x0) >> s) as usize + 1,
                        height: ((y1 - y0) >> s) as usize + 1,
                        values: values.into(),
                        valid: valid.into(),
                    };
                    let tile = PlanetTile::new(s, rect, grid, variable.then_some(class))?;
                    Ok((tile, won))
                })
                .collect::<std::result::Result<Vec<_>, CodecError>>()
        })
        .collect::<std::result::Result<Vec<_>, CodecError>>()?;
    let mut winners = Vec::with_capacity(faces.len());
    let mut tiles = Vec::with_capacity(faces.len());
    for face in faces {
        let (t, w): (Vec<_>, Vec<_>) = face.into_iter().unzip();
        tiles.push(t);
        winners.push(w);
    }
    let planet = PlanetGrid::from_tiles(n, k, tile_log2(side), tiles, variable)?;
    Ok(Resampled {
        planet,
        winners,
        strides,
    })
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
) -> Vec<InputResampling> {
    let planet = &resampled.planet;
    let side = planet.domain().cube().expect("a cube-sphere").side();
    inputs
        .inputs
        .iter()
        .enumerate()
        .map(|(i, input)| {
            let me = u16::try_from(i).unwrap_or(u16::MAX);
            // The input's samples are the lattice points on its stride: the surface drawn
            // where it is the finest data interpolates those.
            let step = 1i64 << resampled.strides[i];
            // On a latitude/longitude grid the longitude's sine and cosine depend on the
            // column only (the latitude's on the row): computed once each.
            let columns: Option<Vec<(f64, f64)>> = match input.frame {
                Frame::Geographic { .. } => Some(
                    (0..input.width)
                        .map(|c| input.lat_lon_of(c, 0).lon.to_radians().sin_cos())
                        .collect(),
                ),
                Frame::Projected { .. } => None,
            };
            let (samples, compared, max, sum2, worst_at) = (0..input.height)
                .into_par_iter()
                .map(|r| {
                    let mut acc = (0u64, 0u64, 0f64, 0f64, None);
                    let row = input.lat_lon_of(0, r).lat.to_radians().sin_cos();
                    for c in 0..input.width {
                        let Some(v) = input.sample(c, r) else {
                            continue;
                        };
                        acc.0 += 1;
                        let (face, s, t) = match &columns {
                            Some(columns) => sin_cos_to_face_st(row, columns[c]),
                            None => lat_lon_to_face_st(input.lat_lon_of(c, r)),
                        };
                        let (x, y) = (s * side as f64 / step as f64, t * side as f64 / step as f64);
                        let cells = side / step;
                        let (x0, y0) = (
                            (x.floor() as i64).min(cells - 1),
                            (y.floor() as i64).min(cells - 1),
                        );
                        let (fx, fy) = (x - x0 as f64, y - y0 as f64);
                        // Corners inside the face (x0, y0 < S): its own tiles hold them (the
                        // input's samples made them dense enough, `plan_tiles`), equal to every
                        // other face's on shared points.
                        // The four corners lie in the tile of the first but where the cell
                        // crosses a tile's side.
                        let tiles = planet.tiles(face);
                        let winners = &resampled.winners[usize::from(face)];
                        let first = planet.tile_index(x0 * step, y0 * step);
                        let (_, _, tx1, ty1) = tiles[first].rect;
                        let one_tile = (x0 + 1) * step <= tx1 && (y0 + 1) * step <= ty1;
                        let corner = |dx: i64, dy: i64| {
                            let (px, py) = ((x0 + dx) * step, (y0 + dy) * step);
                            let i = if one_tile {
                                first
                            } else {
                                planet.tile_index(px, py)
                            };
                            let t = &tiles[i];
                            let k = t.index(px, py)?;
                            (winners[i][k] == me && t.grid.valid[k])
                                .then(|| plan.metres(t.grid.values[k]))
                        };
                        let (Some(a), Some(b), Some(cc), Some(d)) =
                            (corner(0, 0), corner(1, 0), corner(0, 1), corner(1, 1))
                        else {
                            continue;
                        };
                        let l = (a * (1.0 - fx) + b * fx) * (1.0 - fy)
                            + (cc * (1.0 - fx) + d * fx) * fy;
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
                // Rows summed in order, not in rayon's reduction tree (whose shape depends on
                // scheduling): the stored RMS has the same bits every build.
                .collect::<Vec<_>>()
                .into_iter()
                .fold((0, 0, 0.0, 0.0, None), |a, b| {
                    let (max, at) = if b.2 > a.2 || a.4.is_none() {
                        (b.2, b.4)
                    } else {
                        (a.2, a.4)
                    };
                    (a.0 + b.0, a.1 + b.1, max, a.3 + b.3, at)
                });
            InputResampling {
                path: input.path.clone(),
                samples,
                compared,
                max_error: max,
                rms_error: if compared > 0 {
                    (sum2 / compared as f64).sqrt()
                } else {
                    0.0
                },
                worst_at,
                stride: resampled.strides[i],
            }
        })
        .collect()
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

/// What a planet build made.
#[derive(Clone, Debug)]
pub struct PlanetSummary {
    /// Diamond grid side `N`.
    pub n: usize,
    /// Level pairs `K`.
    pub level_pairs: u32,
    /// Whether `K` is coarser than the finest input asks for (the memory limit capped it).
    pub capped: bool,
    /// Mean lattice spacing, degrees.
    pub lattice_deg: f64,
    /// Distinct lattice points (`6·S² + 2`).
    pub lattice_points: u64,
    /// Points the planet's tiles held ([`PlanetGrid::held_points`]): what the build's memory
    /// and time follow.
    pub held_points: u64,
    /// Lattice points with data.
    pub valid: u64,
    /// Records in the repository.
    pub records: usize,
    /// The integer mapping.
    pub plan: QuantPlan,
    /// Per input, the resampling error against its samples.
    pub resampling: Vec<InputResampling>,
    /// Wall time of each stage.
    pub stages: Vec<(&'static str, std::time::Duration)>,
}

/// Distinct lattice points with data (a point on a cube edge or corner counted once, a point
/// on a tile's side once).
pub fn count_valid(planet: &PlanetGrid) -> u64 {
    let d = planet.domain();
    let side = d.cube().expect("a cube-sphere").side();
    (0..d.faces())
        .flat_map(|f| planet.tiles(f).iter().map(move |t| (f, t)))
        .collect::<Vec<_>>()
        .into_par_iter()
        .map(|(f, t)| {
            let (x0, y0, x1, y1) = t.rect;
            let step = 1usize << t.stride;
            let mut count = 0u64;
            for (j, y) in (y0..=y1).step_by(step).enumerate() {
                // A tile owns its first row and column, and its last only on the face's edge.
                if y == y1 && y1 < side {
                    continue;
                }
                for (i, x) in (x0..=x1).step_by(step).enumerate() {
                    if (x == x1 && x1 < side) || !t.grid.valid[j * t.grid.width + i] {
                        continue;
                    }
                    // Interior points are their own; an edge point is counted on the face
                    // that owns it.
                    let edge = x == 0 || y == 0 || x == side || y == side;
                    if !edge || d.canonical_point(f, x, y).is_some_and(|c| c.face == f) {
                        count += 1;
                    }
                }
            }
            count
        })
        .sum()
}

/// Checks the options a planet build does not take.
fn refuse_planar_options(opts: &BuildOptions) -> Result<()> {
    if opts.colour || opts.like.is_some() {
        bail!("--planet builds elevation; colour planets are not supported yet");
    }
    if opts.raw_size.is_some() {
        bail!("--planet: raw float32 inputs carry no georeferencing");
    }
    if opts.alpha != Alpha::One {
        bail!("--planet needs --alpha one (the α = ½ analysis filter is planar)");
    }
    if opts.block_plan.is_some() {
        bail!("--planet does not take --block-plan (planets are encoded whole)");
    }
    if opts.quantum.is_some() {
        bail!("--planet: resampled heights lie on no value grid, so --quantum does not apply");
    }
    Ok(())
}

/// Builds a planet repository from `opts.inputs` (each a geographic or UTM DEM, a directory,
/// glob or `@list` of them).
pub fn build_planet(
    opts: &BuildOptions,
    planet_level: Option<u32>,
    progress: &dyn Progress,
) -> Result<PlanetSummary> {
    refuse_planar_options(opts)?;
    crate::check_tolerance_and_output(opts)?;
    let limit = opts
        .memory_limit
        .unwrap_or_else(crate::plan::default_memory_limit);
    let event = |stage, done| {
        progress.event(ProgressEvent {
            stage,
            done,
            total: 1,
        })
    };
    let mut stages = Vec::new();
    event(Stage::Prepare, 0);
    // Every stage runs on the build's own workers (`--threads`).
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(opts.threads.unwrap_or(0))
        .build()
        .context("starting the build's threads")?;
    let t = Instant::now();
    let tiles = crate::tiles::expand_inputs(&opts.inputs)?;
    crate::check_output_is_not_an_input(opts, &tiles)?;
    let inputs =
        pool.install(|| PlanetInputs::read(&tiles, opts.nodata, opts.assign_georef.as_ref()))?;
    stages.push(("read", t.elapsed()));
    let n = opts.diamond_size;
    let k = choose_level(&inputs, n, planet_level, limit)?;
    let wanted = choose_level(&inputs, n, None, u64::MAX)?;
    let Some((lo, hi)) = inputs.range() else {
        bail!("the inputs have no valid sample (all nodata or NaN)");
    };
    let plan = QuantPlan::new(opts.max_error, None, lo, hi)?;
    let t = Instant::now();
    let resampled = pool.install(|| resample(&inputs, n, k, &plan))?;
    stages.push(("resample", t.elapsed()));
    event(Stage::Prepare, 1);
    event(Stage::Encode, 0);
    let t = Instant::now();
    let enc = EncodeOptions {
        n,
        extra_level_pairs: 0,
        alpha: Alpha::One,
        coder: opts.coder,
    };
    // The resampling error only reads the lattice, as the encoder does: measured alongside, it
    // fills the cores the encoder's coarse levels leave idle.
    let (encoded, resampling) = pool.install(|| {
        rayon::join(
            || encode_planet(&resampled.planet, plan.quantizer, &enc),
            || resampling_error(&inputs, &resampled, &plan),
        )
    });
    let encoded = encoded?;
    stages.push(("encode and measure resampling error", t.elapsed()));
    event(Stage::Encode, 1);
    event(Stage::Write, 0);
    let t = Instant::now();
    write_planet_repository(
        &opts.output,
        &encoded,
        &plan,
        opts.nodata,
        &provenance_of(&resampling),
    )
    .with_context(|| format!("writing {}", opts.output.display()))?;
    stages.push(("write", t.elapsed()));
    event(Stage::Write, 1);
    let valid = count_valid(&resampled.planet);
    Ok(PlanetSummary {
        n,
        level_pairs: k,
        capped: k < wanted && planet_level.is_none(),
        lattice_deg: lattice_spacing_deg(n, k),
        lattice_points: resampled.planet.lattice_points(),
        held_points: resampled.planet.held_points(),
        valid,
        records: encoded.records.len(),
        plan,
        resampling,
        stages,
    })
}

/// A planet repository checked against its inputs ([`compare_planet`]).
#[derive(Clone, Debug)]
pub struct PlanetComparison {
    /// Every level of the hierarchy against the resampled lattice (units; bound `k`).
    pub report: cbdam_codec::hierarchy::VerifyReport,
    /// The resampled lattice against each input's samples (what the build reported).
    pub resampling: Vec<InputResampling>,
    /// The decoded finest level against each input's samples, measured the same way.
    pub end_to_end: Vec<InputResampling>,
    /// The repository's bound in metres.
    pub max_error: f64,
}

impl PlanetComparison {
    /// Errors unless every level is within the bound and, per input, the decoded surface is
    /// within the bound plus the resampling error of the samples (the triangle inequality: the
    /// bilinear weights are non-negative and sum to 1).
    pub fn check(&self) -> Result<()> {
        if !self.report.within_bound() {
            bail!(
                "a level exceeds the bound: max error {} units, bound {}",
                self.report.max_error(),
                self.report.bound
            );
        }
        for (r, e) in self.resampling.iter().zip(&self.end_to_end) {
            let allowed = r.max_error + self.max_error + 1e-9;
            if e.max_error > allowed {
                bail!(
                    "{}: the decoded surface is {:.6} m from a sample, over the {:.6} m of the \
                     bound plus the resampling error",
                    e.path.display(),
                    e.max_error,
                    allowed
                );
            }
        }
        Ok(())
    }
}

/// Checks a planet repository against the inputs it was built from: the inputs are resampled
/// again onto the repository's lattice (the same arithmetic as the build, so the same integer
/// lattice), every level is compared with it exactly
/// ([`cbdam_codec::hierarchy::verify_planet`]), and both the lattice and the decoded finest
/// level are measured against the inputs' samples.
pub fn compare_planet(
    repo: &cbdam_codec::repository::Repository,
    tiles: &[Tile],
    nodata: Option<f64>,
    assign: Option<&AssignedGeoRef>,
) -> Result<PlanetComparison> {
    use cbdam_codec::hierarchy::{reconstruct_planet_like, verify_planet};
    let domain = repo.head().params().domain;
    if domain.cube().is_none() {
        bail!("this repository is planar: compare it with compare_dem or compare_tiles");
    }
    let plan = *repo.head().plan();
    let inputs = PlanetInputs::read(tiles, nodata, assign)?;
    let (n, k) = (domain.n(), domain.layout().k());
    let resampled = resample(&inputs, n, k, &plan)?;
    let encoded = repo.to_encoded()?;
    let report = verify_planet(&encoded, &resampled.planet)?;
    let resampling = resampling_error(&inputs, &resampled, &plan);
    let decoded = Resampled {
        planet: reconstruct_planet_like(&encoded, &resampled.planet)?,
        winners: resampled.winners,
        strides: resampled.strides,
    };
    let end_to_end = resampling_error(&inputs, &decoded, &plan);
    Ok(PlanetComparison {
        report,
        resampling,
        end_to_end,
        max_error: plan.max_error(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn input(spacing_deg: f64) -> PlanetInput {
        PlanetInput {
            path: PathBuf::from("x.tif"),
            width: 2,
            height: 2,
            samples: Samples::compact(vec![0.0; 4]),
            nodata: None,
            frame: Frame::Geographic {
                lon0: 0.0,
                lat0: 1.0,
                dlon: spacing_deg,
                dlat: spacing_deg,
                period: None,
            },
            spacing_deg,
        }
    }

    /// The lattice is the coarsest at least as fine as the finest input, and the memory limit
    /// caps it (or refuses a forced level above it).
    #[test]
    fn the_level_follows_the_finest_input_within_the_memory_limit() {
        let inputs = PlanetInputs {
            inputs: vec![input(0.25), input(2.0)],
        };
        // 90°/(16·2^K) ≤ 0.25° first at K = 5 (0.176°); K = 4 is 0.352°.
        assert_eq!(choose_level(&inputs, 17, None, u64::MAX).unwrap(), 5);
        // Faces of 512 (K = 5) and 256 (K = 4) steps are one tile each: the face under the two
        // inputs (both near 0° N 0° E) holds every point for the fine one, the five others,
        // which no input reaches, their 4 corners.
        let at = |k: u32| {
            let side = 16u64 << k;
            ((side + 1) * (side + 1) + 5 * 4) * BYTES_PER_LATTICE_POINT
        };
        assert_eq!(
            held_points(17, 5, &plan_tiles(&inputs, 17, 5).unwrap().strides).unwrap()
                * BYTES_PER_LATTICE_POINT,
            at(5)
        );
        assert_eq!(choose_level(&inputs, 17, None, at(5)).unwrap(), 5);
        assert_eq!(choose_level(&inputs, 17, None, at(5) - 1).unwrap(), 4);
        assert!(choose_level(&inputs, 17, Some(5), at(5) - 1).is_err());
        // Beyond the finest input's spacing a lattice holds every 2nd point (or 4th...) of
        // the input's tiles: K = 6 costs what K = 5 did, so a forced finer level fits too.
        assert_eq!(choose_level(&inputs, 17, Some(6), at(5)).unwrap(), 6);
        assert_eq!(choose_level(&inputs, 17, Some(3), at(5)).unwrap(), 3);
    }

    /// More inputs than a winner index holds are refused by count, before any is read.
    #[test]
    fn more_inputs_than_a_planet_tells_apart_are_refused_before_reading() {
        let tiles: Vec<Tile> = (0..=MAX_PLANET_INPUTS)
            .map(|i| Tile {
                path: PathBuf::from(format!("/nonexistent/{i}.tif")),
                vrt: None,
            })
            .collect();
        let e = PlanetInputs::read(&tiles, None, None)
            .err()
            .unwrap()
            .to_string();
        assert!(
            e.contains("65535 inputs") && e.contains("at most 65534"),
            "{e}"
        );
        // One fewer is read (and fails on the first missing file, naming it).
        let e = PlanetInputs::read(&tiles[1..], None, None).err().unwrap();
        assert!(format!("{e:#}").contains("/nonexistent/1.tif"), "{e:#}");
    }

    /// Bilinear interpolation reproduces a function linear in columns and rows, wraps across
    /// the seam of a global input, and needs all four samples valid.
    #[test]
    fn bilinear_wraps_and_needs_four_valid_samples() {
        // 4 columns of 90°: a global input; value = 10·column + row.
        let mut values: Vec<f64> = (0..12).map(|i| f64::from(10 * (i % 4) + i / 4)).collect();
        let mut g = PlanetInput {
            path: PathBuf::from("g.tif"),
            width: 4,
            height: 3,
            samples: Samples::compact(values.clone()),
            nodata: Some(-1.0),
            frame: Frame::Geographic {
                lon0: 0.0,
                lat0: 90.0,
                dlon: 90.0,
                dlat: 90.0,
                period: Some(4),
            },
            spacing_deg: 90.0,
        };
        let at = |g: &PlanetInput, lat, lon| g.bilinear(g.pixel_of(LatLon { lat, lon }).unwrap());
        assert_eq!(at(&g, 45.0, 45.0), Some(5.0 + 0.5));
        // Between column 3 (270°) and column 0 (360° = 0°): halfway is 315° = −45°.
        assert_eq!(at(&g, 0.0, -45.0), Some(0.5 * 30.0 + 0.5 * 0.0 + 1.0));
        values[4] = -1.0;
        g.samples = Samples::compact(values);
        assert_eq!(at(&g, 45.0, 45.0), None);
    }

    /// Only an input whose columns go all the way round wraps: an inset whose spacing divides
    /// 360° (3″, as SRTM's) covers nothing east of its last column.
    #[test]
    fn only_inputs_around_the_globe_wrap() {
        let georef = |pixel: f64| GeoRef {
            epsg: Some(4326),
            origin_x: 10.0,
            origin_y: 50.0,
            pixel_x: pixel,
            pixel_y: pixel,
            pixel_is_area: false,
            wkt: None,
        };
        let wraps = |f: Frame| {
            matches!(
                f,
                Frame::Geographic {
                    period: Some(_),
                    ..
                }
            )
        };
        assert!(wraps(frame_of(&georef(5.0 / 60.0), 4320).unwrap()));
        assert!(!wraps(frame_of(&georef(5.0 / 60.0), 100).unwrap()));
        assert!(!wraps(frame_of(&georef(3.0 / 3600.0), 1201).unwrap()));
        let mut inset = input(0.5);
        inset.width = 3;
        inset.samples = Samples::compact(vec![0.0; 6]);
        inset.frame = frame_of(&georef(0.5), 3).unwrap();
        // Columns at 10°, 10.5° and 11° E: 11.2° E is off the inset, 10.9° E on it.
        assert!(
            inset
                .pixel_of(LatLon {
                    lat: 49.8,
                    lon: 11.2
                })
                .is_none()
        );
        assert!(
            inset
                .pixel_of(LatLon {
                    lat: 49.8,
                    lon: 10.9
                })
                .is_some()
        );
    }
}
