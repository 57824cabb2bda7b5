//! A planet's inputs (`docs/PLANET.md`, "Building a planet"): each opened from its header and
//! placed on the Earth (latitude/longitude or a UTM zone), its samples read on demand through
//! a bounded cache ([`InputCache`]) when the resampling asks for them, so that a planet of
//! thousands of tiles holds a few at a time; and the arithmetic that takes a height from them
//! (bilinear, area average).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use rayon::prelude::*;

use crate::assign::AssignedGeoRef;
use crate::band_cache::{SampleValues, Samples};
use crate::error::{Context, Result, bail};
use crate::input::{ReadOptions, TileReader};
use crate::input_cache::InputCache;
use crate::planet_overlap::SharedEdges;
use crate::planet_spacing::{input_stride, lattice_spacing_deg};
use crate::tiles::Tile;
use cbdam_codec::error::CodecError;
use cbdam_codec::geodesy::{LatLon, Utm};
use cbdam_codec::repository::GeoRef;

/// Metres per degree of arc on the ground (the WGS 84 mean), to compare projected spacings with
/// angular ones.
pub(crate) const METRES_PER_DEGREE: f64 = 111_195.0;

/// EPSG codes of the geographic coordinate systems accepted as latitude/longitude on WGS 84:
/// WGS 84 itself, and NAD83, ETRS89 and GDA94, whose datums are within about 2 m of it.
pub const GEOGRAPHIC_EPSG: [u32; 4] = [4326, 4269, 4258, 4283];

/// How an input's pixels lie on the Earth.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Frame {
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
    pub(crate) width: usize,
    pub(crate) height: usize,
    pub(crate) source: SampleSource,
    pub(crate) nodata: Option<f64>,
    pub(crate) frame: Frame,
    /// Ground spacing of its samples, degrees of arc (north–south).
    pub spacing_deg: f64,
}

/// Where an input's samples come from.
pub(crate) enum SampleSource {
    /// Held (an input made in memory, in tests).
    #[cfg(test)]
    Held(Arc<Samples>),
    /// Read whole from the file, with these options, when asked for ([`InputCache`]).
    File(ReadOptions),
}

impl PlanetInput {
    /// Sample `(c, r)` of `samples` (this input's), `None` where nodata or NaN.
    #[inline]
    pub(crate) fn sample(&self, samples: &Samples, c: usize, r: usize) -> Option<f64> {
        self.sample_in(samples, c, r)
    }

    /// [`PlanetInput::sample`] from samples in any representation.
    #[inline]
    fn sample_in<S: SampleValues + ?Sized>(&self, samples: &S, c: usize, r: usize) -> Option<f64> {
        let v = samples.value(r * self.width + c);
        (!v.is_nan() && self.nodata != Some(v)).then_some(v)
    }

    /// Fractional column and row of a point, or `None` off the input.
    pub(crate) fn pixel_of(&self, ll: LatLon) -> Option<(f64, f64)> {
        match self.frame {
            Frame::Geographic { .. } => Some((self.pixel_column(ll.lon)?, self.pixel_row(ll.lat)?)),
            Frame::Projected {
                utm,
                x0,
                y0,
                dx,
                dy,
            } => {
                let (e, n) = utm.forward(ll);
                let c_max = self.width as f64 - 1.0;
                let c = in_range((e - x0) / dx, c_max)?;
                Some((c, self.row_in_range((y0 - n) / dy)?))
            }
        }
    }

    /// Whether its samples lie on a latitude/longitude grid.
    pub(crate) fn is_geographic(&self) -> bool {
        matches!(self.frame, Frame::Geographic { .. })
    }

    /// Of a latitude/longitude input: the fractional column of longitude `lon` (a turn east
    /// or west where that is on the input and the column itself is not), clamped onto the
    /// input, or `None` off it. A point's column depends on its longitude alone, so a caller
    /// whose points share longitudes (the columns of an equatorial face) asks once for each.
    pub(crate) fn pixel_column(&self, lon: f64) -> Option<f64> {
        let Frame::Geographic {
            lon0, dlon, period, ..
        } = self.frame
        else {
            unreachable!("a column of longitude of a latitude/longitude input only")
        };
        let w = self.width as f64;
        let c = (lon - lon0) / dlon;
        match period {
            Some(p) => in_range(rem_euclid(c, p as f64), w),
            // The column itself, else a turn east or west of it (each worked out only
            // where the one before is off the input).
            None => {
                let on = |c: f64| (-PIXEL_SLACK..=w - 1.0 + PIXEL_SLACK).contains(&c);
                let c = if on(c) {
                    c
                } else {
                    let turn = 360.0 / dlon;
                    [c + turn, c - turn].into_iter().find(|&c| on(c))?
                };
                in_range(c, w - 1.0)
            }
        }
    }

    /// Of a latitude/longitude input: the fractional row of latitude `lat`, clamped onto the
    /// input, or `None` off it.
    #[inline]
    fn pixel_row(&self, lat: f64) -> Option<f64> {
        let Frame::Geographic { lat0, dlat, .. } = self.frame else {
            unreachable!("a row of latitude of a latitude/longitude input only")
        };
        self.row_in_range((lat0 - lat) / dlat)
    }

    /// Row `r` clamped onto the input, or `None` more than the slack off it.
    #[inline]
    fn row_in_range(&self, r: f64) -> Option<f64> {
        in_range(r, self.height as f64 - 1.0)
    }

    /// The column index of `c`, wrapped for inputs around the globe.
    fn column(&self, c: i64) -> Option<usize> {
        match self.frame {
            Frame::Geographic {
                period: Some(p), ..
            } => {
                // `rem_euclid` is the identity on `[0, p)` (nearly every column asked): no
                // integer division there.
                let p = p as i64;
                let c = if (0..p).contains(&c) {
                    c
                } else {
                    c.rem_euclid(p)
                };
                Some(c as usize).filter(|&c| c < self.width)
            }
            _ => usize::try_from(c).ok().filter(|&c| c < self.width),
        }
    }

    /// Bilinear interpolation at a fractional pixel; `None` unless all four samples are valid.
    #[inline]
    pub(crate) fn bilinear<S: SampleValues + ?Sized>(
        &self,
        samples: &S,
        (c, r): (f64, f64),
    ) -> Option<f64> {
        let wraps = matches!(
            self.frame,
            Frame::Geographic {
                period: Some(_),
                ..
            }
        );
        let c0 = if wraps {
            floor(c)
        } else {
            floor(c).min(self.width.saturating_sub(2) as f64)
        };
        let r0 = floor(r).min(self.height.saturating_sub(2) as f64);
        let (fx, fy) = (c - c0, r - r0);
        let (c0, r0) = (c0 as i64, r0 as usize);
        let r1 = (r0 + 1).min(self.height - 1);
        let (ca, cb) = (
            self.column(c0)?,
            self.column(c0 + 1).unwrap_or(self.column(c0)?),
        );
        let v = |c, r| self.sample_in(samples, c, r);
        let top = v(ca, r0)? * (1.0 - fx) + v(cb, r0)? * fx;
        let bottom = v(ca, r1)? * (1.0 - fx) + v(cb, r1)? * fx;
        Some(top * (1.0 - fy) + bottom * fy)
    }

    /// Mean of the valid samples whose centres lie within `half` (columns, rows) of a pixel.
    fn area_average<S: SampleValues + ?Sized>(
        &self,
        samples: &S,
        (c, r): (f64, f64),
        half: (f64, f64),
    ) -> Option<f64> {
        let (r_lo, r_hi) = (
            (r - half.1).ceil().max(0.0) as usize,
            ((r + half.1).floor() as usize).min(self.height - 1),
        );
        let (c_lo, c_hi) = ((c - half.0).ceil() as i64, (c + half.0).floor() as i64);
        let (mut sum, mut count) = (0.0, 0u64);
        for row in r_lo..=r_hi {
            for col in c_lo..=c_hi {
                if let Some(v) = self
                    .column(col)
                    .and_then(|col| self.sample_in(samples, col, row))
                {
                    sum += v;
                    count += 1;
                }
            }
        }
        (count > 0).then(|| sum / count as f64)
    }

    /// The height at a point at `ll`, whose pixel on the input is `px`
    /// ([`PlanetInput::pixel_of`]) and whose lattice cell is `lattice_deg` degrees across:
    /// bilinear where the lattice is at least as fine as the input, the area average where
    /// it is coarser.
    #[inline]
    fn height_at_pixel<S: SampleValues + ?Sized>(
        &self,
        samples: &S,
        ll: LatLon,
        px: (f64, f64),
        lattice_deg: f64,
    ) -> Option<f64> {
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
            if let Some(v) = self.area_average(samples, px, half) {
                return Some(v);
            }
        }
        self.bilinear(samples, px)
    }

    /// Latitude and longitude of sample `(c, r)`.
    pub(crate) fn lat_lon_of(&self, c: usize, r: usize) -> LatLon {
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
    fn range(&self, samples: &Samples) -> Option<(f64, f64)> {
        (0..self.height)
            .into_par_iter()
            .filter_map(|r| {
                (0..self.width)
                    .filter_map(|c| self.sample(samples, c, r))
                    .fold(None, |acc: Option<(f64, f64)>, v| {
                        Some(acc.map_or((v, v), |(lo, hi)| (lo.min(v), hi.max(v))))
                    })
            })
            .reduce_with(|a, b| (a.0.min(b.0), a.1.max(b.1)))
    }
}

/// `x.floor()` bit for bit, without the libm call `floor` is on the baseline x86-64 target
/// (no SSE4.1 `roundsd`): below 2⁵² in magnitude the truncating conversion is exact, one less
/// where it rounded up, and the sign copied keeps `floor(−0.0) = −0.0` (every other result has
/// the sign of `x` already); larger, infinite and NaN values go to `floor`.
#[inline]
pub(crate) fn floor(x: f64) -> f64 {
    if x.abs() < 4_503_599_627_370_496.0 {
        let t = x as i64 as f64;
        (if t > x { t - 1.0 } else { t }).copysign(x)
    } else {
        x.floor()
    }
}

/// How far off an input (in samples) a point may lie and still be clamped onto it.
const PIXEL_SLACK: f64 = 1e-9;

/// `v` clamped onto `[0, max]` where it lies within [`PIXEL_SLACK`] of it, else `None`.
#[inline]
fn in_range(v: f64, max: f64) -> Option<f64> {
    (-PIXEL_SLACK..=max + PIXEL_SLACK)
        .contains(&v)
        .then_some(v.clamp(0.0, max))
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

/// The samples of the `width` × `height` input at `path`, read whole as [`crate::input::read_dem`]
/// would read them ([`TileReader`] reads rows as `read_dem` does), kept in the narrowest exact
/// type; with `parallel`, the bands of a GeoTIFF's strips or tiles decoded on all the build's
/// workers.
fn read_samples(
    path: &Path,
    opts: &ReadOptions,
    (width, height): (usize, usize),
    parallel: bool,
) -> std::result::Result<Samples, CodecError> {
    let reader = TileReader::open(path, opts)?;
    if (reader.width(), reader.height()) != (width, height) {
        return Err(CodecError::invalid(format!(
            "{} is now {}×{} samples, {width}×{height} when the build began",
            path.display(),
            reader.width(),
            reader.height()
        )));
    }
    let band = reader.band_rows().max(1);
    if !parallel && let Some(samples) = read_band_by_band(&reader, band, width * height)? {
        return Ok(samples);
    }
    let mut values = vec![0.0; width * height];
    let read_band = |(b, out): (usize, &mut [f64])| {
        let start = b * band;
        let mut rows = Vec::new();
        reader.read_rows(start..(start + band).min(height), &mut rows)?;
        out.copy_from_slice(&rows);
        Ok::<_, CodecError>(())
    };
    let chunk = (band * width).max(1);
    if parallel {
        values
            .par_chunks_mut(chunk)
            .enumerate()
            .try_for_each(read_band)?;
    } else {
        values
            .chunks_mut(chunk)
            .enumerate()
            .try_for_each(read_band)?;
    }
    Ok(Samples::compact(values))
}

/// The samples `reader` gives, `len` of them, read `band` rows at a time into their narrowest
/// representation as they come ([`Samples::push_band`]: an SRTM tile holds its 2 bytes a
/// sample and one band of `f64`, not 8 bytes a sample and a copy): `None` where a band needed
/// a wider representation than the samples before it (read whole then).
fn read_band_by_band(
    reader: &TileReader,
    band: usize,
    len: usize,
) -> std::result::Result<Option<Samples>, CodecError> {
    let height = reader.height();
    let mut samples = Samples::with_capacity(len);
    let mut rows = Vec::new();
    for start in (0..height).step_by(band) {
        reader.read_rows(start..(start + band).min(height), &mut rows)?;
        if !samples.push_band(&rows) {
            return Ok(None);
        }
    }
    Ok(Some(samples))
}

/// Opens one input from its header and places it on the Earth, or says why it cannot be. An input without
/// georeferencing of its own takes `assign`'s (`--bounds`/`--crs`); the flag says it did.
fn open_input(
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
    let dem =
        TileReader::open(path, &opts).with_context(|| format!("reading {}", path.display()))?;
    let (width, height) = (dem.width(), dem.height());
    let mut georef = dem.georef().cloned();
    if let Some(v) = &tile.vrt {
        crate::mosaic::place_vrt_tile(path, (width, height), &mut georef, v)?;
    }
    let assigned = georef.is_none() && assign.is_some();
    if let (None, Some(a)) = (&georef, assign) {
        georef = Some(a.georef(width, height));
    }
    let Some(georef) = georef else {
        bail!(
            "{} carries no georeferencing: a planet needs to know where each input lies \
             (EPSG:4326 latitude/longitude or a UTM zone; --bounds and --crs give it to one \
             input without)",
            path.display()
        );
    };
    let frame = frame_of(&georef, width).with_context(|| path.display().to_string())?;
    let spacing_deg = match frame {
        Frame::Geographic { dlat, .. } => dlat,
        Frame::Projected { dy, .. } => dy / METRES_PER_DEGREE,
    };
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
            source: SampleSource::File(opts),
            nodata: dem.nodata(),
            frame,
            spacing_deg,
        },
        assigned,
    ))
}

/// How the `width` columns of an input georeferenced by `g` lie on the Earth.
pub(crate) fn frame_of(g: &GeoRef, width: usize) -> Result<Frame> {
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
    /// Their samples, read when asked for ([`PlanetInputs::samples`]).
    pub(crate) cache: InputCache,
}

impl PlanetInputs {
    /// Opens every input ([`crate::tiles::expand_inputs`] already expanded them) from its
    /// header, and places it on the Earth; their samples are read when asked for, keeping at
    /// most `cache_budget` bytes of them besides those in use. `assign` (`--bounds`/`--crs`)
    /// georeferences the one input that carries none, and is refused when none or several do.
    pub fn read(
        tiles: &[Tile],
        nodata: Option<f64>,
        assign: Option<&AssignedGeoRef>,
        cache_budget: u64,
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
            .map(|t| open_input(t, nodata, assign))
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
        // Every lattice tile asks for the inputs around the globe: kept once read.
        let global = inputs
            .iter()
            .enumerate()
            .filter(|(_, i)| {
                matches!(
                    i.frame,
                    Frame::Geographic {
                        period: Some(_),
                        ..
                    }
                )
            })
            .map(|(k, _)| k)
            .collect();
        Ok(Self {
            inputs,
            cache: InputCache::with_pinned(cache_budget, global),
        })
    }

    /// Inputs held in memory (made, not read), with room for none in the cache.
    #[cfg(test)]
    pub(crate) fn held(inputs: Vec<PlanetInput>) -> Self {
        Self {
            inputs,
            cache: InputCache::new(0),
        }
    }

    /// The samples of input `i`: from the cache, or read (naming the file if that fails) on
    /// this thread alone. The cache holds an input's lock while reading it; a read that forked
    /// work onto the pool could, while waiting, take up another lattice tile's task asking for
    /// the same input — and wait on its own lock.
    pub(crate) fn samples(&self, i: usize) -> Result<Arc<Samples>> {
        self.samples_read(i, false)
    }

    /// [`Self::samples`], a read decoding on all workers: only where nothing else runs on the
    /// pool (the height range, one input at a time).
    fn samples_read(&self, i: usize, parallel: bool) -> Result<Arc<Samples>> {
        let input = &self.inputs[i];
        match &input.source {
            #[cfg(test)]
            SampleSource::Held(s) => Ok(Arc::clone(s)),
            SampleSource::File(opts) => self.cache.get(i, || {
                read_samples(&input.path, opts, (input.width, input.height), parallel)
                    .with_context(|| format!("reading {}", input.path.display()))
            }),
        }
    }

    /// Bytes of the samples of the inputs kept for the whole build (those around the globe),
    /// each read now if it was not yet.
    pub(crate) fn pinned_bytes(&self) -> Result<u64> {
        (0..self.inputs.len())
            .filter(|&i| self.cache.is_pinned(i))
            .map(|i| Ok(self.samples(i)?.bytes()))
            .sum()
    }

    /// Keeps at most `budget` bytes of the inputs' samples besides those in use from now on.
    pub(crate) fn set_cache_budget(&self, budget: u64) {
        self.cache.set_budget(budget);
    }

    /// Inputs read from their files so far (one read again after the cache let it go counts
    /// again), and the cache's budget in bytes.
    pub fn reads(&self) -> (u64, u64) {
        (self.cache.reads(), self.cache.budget())
    }

    /// The finest input's spacing, degrees.
    pub fn finest_deg(&self) -> f64 {
        self.inputs[0].spacing_deg
    }

    /// The height range over all inputs, metres.
    /// Every input is read (one at a time, through the cache), so a damaged one is found here,
    /// and so are inputs of one spacing that disagree where they overlap ([`SharedEdges`]).
    pub fn range(&self) -> Result<Option<(f64, f64)>> {
        let mut range: Option<(f64, f64)> = None;
        let mut edges = SharedEdges::new(&self.inputs);
        for (i, input) in self.inputs.iter().enumerate() {
            let samples = self.samples_read(i, true)?;
            edges.check(&self.inputs, i, &samples)?;
            if let Some((lo, hi)) = input.range(&samples) {
                range = Some(range.map_or((lo, hi), |r| (r.0.min(lo), r.1.max(hi))));
            }
        }
        Ok(range)
    }

    /// The stride of each input on a lattice of `n`, `k` (see [`input_stride`]).
    pub fn strides(&self, n: usize, k: u32) -> Vec<u32> {
        self.inputs
            .iter()
            .map(|i| input_stride(i.spacing_deg, lattice_spacing_deg(n, k), k))
            .collect()
    }

    /// Input `i` (whose samples are `samples`; `strides` each input's, on a lattice of
    /// `lattice_deg`) ready to say what lattice points take from it
    /// ([`InputProbe::source_of`]), for a run of points: what depends on the input alone
    /// worked out once.
    pub(crate) fn probe<'s, S: SampleValues + ?Sized>(
        &'s self,
        samples: &'s S,
        i: u16,
        lattice_deg: f64,
        strides: &[u32],
    ) -> InputProbe<'s, S> {
        let j = strides[usize::from(i)];
        let step = 1i64 << j;
        InputProbe {
            input: &self.inputs[usize::from(i)],
            samples,
            index: i,
            stride_log2: j,
            step,
            cell_deg: lattice_deg * step as f64,
        }
    }
}

/// One input asked what lattice points take from it ([`PlanetInputs::probe`]).
pub(crate) struct InputProbe<'s, S: ?Sized> {
    input: &'s PlanetInput,
    samples: &'s S,
    index: u16,
    stride_log2: u32,
    step: i64,
    /// The lattice cell at the input's stride, degrees across.
    cell_deg: f64,
}

impl<S: SampleValues + ?Sized> InputProbe<'_, S> {
    /// What lattice point `(x, y)` at `ll` takes from the input, if it covers it: on the
    /// input's stride the point is one of its samples ([`PointSource::Sample`]; the height for
    /// a lattice cell `2^stride` times the lattice's across); between them it is coarse only.
    /// A point takes the first input (finest first) that covers it.
    #[inline]
    pub(crate) fn source_of(&self, ll: LatLon, xy: (i64, i64)) -> Option<PointSource> {
        self.source_at_pixel(ll, self.input.pixel_of(ll)?, xy)
    }

    /// [`InputProbe::source_of`] of a point of a latitude/longitude input whose column on it
    /// is `column` ([`PlanetInput::pixel_column`] of its longitude, worked out once for the
    /// points of a lattice column that share it).
    #[inline]
    pub(crate) fn source_in_column(
        &self,
        ll: LatLon,
        column: f64,
        xy: (i64, i64),
    ) -> Option<PointSource> {
        let px = (column, self.input.pixel_row(ll.lat)?);
        self.source_at_pixel(ll, px, xy)
    }

    /// [`InputProbe::source_of`] where the point's pixel `px` on the input is known.
    #[inline]
    fn source_at_pixel(
        &self,
        ll: LatLon,
        px: (f64, f64),
        (x, y): (i64, i64),
    ) -> Option<PointSource> {
        let v = self
            .input
            .height_at_pixel(self.samples, ll, px, self.cell_deg)?;
        // `step` is a power of two: a multiple of it (negative too) has its low bits clear,
        // tested without the integer division `%` costs a point.
        let off_stride = self.step - 1;
        Some(if x & off_stride == 0 && y & off_stride == 0 {
            PointSource::Sample(v, self.index, self.stride_log2 as u8)
        } else {
            PointSource::CoarseOnly(self.index)
        })
    }
}

/// What a lattice point takes from the inputs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum PointSource {
    /// Height (metres), the winning input and its stride's `log2`.
    Sample(f64, u16, u8),
    /// Between the samples of this (coarser) input: drawn from its level, not constrained.
    CoarseOnly(u16),
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `pixel_of` as it was written before its column and row were split apart (column, row,
    /// then one range test of both): the reference the split must give bit for bit.
    fn pixel_of_whole(input: &PlanetInput, ll: LatLon) -> Option<(f64, f64)> {
        const SLACK: f64 = 1e-9;
        let (w, h) = (input.width as f64, input.height as f64);
        let Frame::Geographic {
            lon0,
            lat0,
            dlon,
            dlat,
            period,
        } = input.frame
        else {
            unreachable!("latitude/longitude inputs here")
        };
        let r = (lat0 - ll.lat) / dlat;
        let c = (ll.lon - lon0) / dlon;
        let c = match period {
            Some(p) => c.rem_euclid(p as f64),
            None => {
                let on = |c: f64| (-SLACK..=w - 1.0 + SLACK).contains(&c);
                if on(c) {
                    c
                } else {
                    let turn = 360.0 / dlon;
                    [c + turn, c - turn].into_iter().find(|&c| on(c))?
                }
            }
        };
        let c_max = if period.is_some() { w } else { w - 1.0 };
        ((-SLACK..=c_max + SLACK).contains(&c) && (-SLACK..=h - 1.0 + SLACK).contains(&r))
            .then_some((c.clamp(0.0, c_max), r.clamp(0.0, h - 1.0)))
    }

    /// A pixel found from its column of longitude and row of latitude apart is the one found
    /// whole, bit for bit: inputs around the globe, astride the antimeridian and small, at
    /// random points and at points just on and off their edges.
    #[test]
    fn a_pixel_from_its_column_and_row_is_the_pixel_found_whole() {
        let frame = |lon0: f64, lat0: f64, deg: f64, period: Option<usize>| Frame::Geographic {
            lon0,
            lat0,
            dlon: deg,
            dlat: deg,
            period,
        };
        let inputs = [
            (frame(-180.0, 90.0, 5.0 / 60.0, Some(4320)), (4320, 2161)),
            (frame(179.5, 10.0, 1.0 / 1200.0, None), (1201, 1201)),
            (frame(6.0, 47.0, 1.0 / 1200.0, None), (1201, 1201)),
        ];
        let mut seed = 5u64;
        let mut next = || {
            seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        for (frame, (width, height)) in inputs {
            let input = PlanetInput {
                path: PathBuf::from("t.tif"),
                width,
                height,
                source: SampleSource::Held(Arc::new(Samples::compact(vec![0.0; 4]))),
                nodata: None,
                frame,
                spacing_deg: 1.0 / 1200.0,
            };
            let Frame::Geographic {
                lon0, lat0, dlon, ..
            } = frame
            else {
                unreachable!()
            };
            let (lon1, lat1) = (
                lon0 + (width - 1) as f64 * dlon,
                lat0 - (height - 1) as f64 * dlon,
            );
            let mut points = Vec::new();
            for _ in 0..200_000 {
                let lat = lat1 - 0.5 + (lat0 - lat1 + 1.0) * next();
                let lon = lon0 - 0.5 + (lon1 - lon0 + 1.0) * next();
                let lon = lon - 360.0 * ((lon - 1e-12) / 360.0).round();
                points.push(LatLon { lat, lon });
            }
            for (lat, lon) in [(lat0, lon0), (lat1, lon1), (lat0, lon1), (lat1, lon0)] {
                for (a, b) in [(0.0, 0.0), (1e-12, -1e-12), (-1e-9, 1e-9), (1e-7, -1e-7)] {
                    let lon = lon + b;
                    let lon = lon - 360.0 * ((lon - 1e-12) / 360.0).round();
                    points.push(LatLon { lat: lat + a, lon });
                }
            }
            let mut on = 0;
            for ll in points {
                let want = pixel_of_whole(&input, ll);
                let got = input.pixel_of(ll);
                let bits = |p: Option<(f64, f64)>| p.map(|(c, r)| (c.to_bits(), r.to_bits()));
                assert_eq!(bits(got), bits(want), "{ll:?}");
                let apart = input
                    .pixel_column(ll.lon)
                    .and_then(|c| Some((c, input.pixel_row(ll.lat)?)));
                assert_eq!(bits(apart), bits(want), "{ll:?}");
                on += usize::from(want.is_some());
            }
            assert!(on > 1000, "{on} points on the input");
        }
    }

    /// The inlined `floor` is `f64::floor` bit for bit: around every integer of a wide range
    /// (just below, on, just above), at ±0, at the edge of exactness 2⁵², beyond it, at the
    /// infinities and at NaN, and at a million pseudo-random values of every magnitude.
    #[test]
    fn floor_is_f64_floor_bit_for_bit() {
        let mut values = vec![0.0, -0.0, f64::INFINITY, f64::NEG_INFINITY, f64::NAN, 1e300];
        for k in -3000i64..3000 {
            let v = k as f64 * 0.5;
            values.extend([v, v.next_down(), v.next_up()]);
        }
        for e in [52, 53, 62, 63, 64] {
            let v = 2f64.powi(e);
            for s in [v, -v] {
                values.extend([s, s.next_down(), s.next_up()]);
            }
        }
        let mut seed = 7u64;
        for _ in 0..1_000_000 {
            seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
            values.push(f64::from_bits(seed));
        }
        for v in values {
            assert_eq!(
                super::floor(v).to_bits(),
                v.floor().to_bits(),
                "floor({v:e})"
            );
        }
    }
}
