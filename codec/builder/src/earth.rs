//! A synthetic SRTM-like Earth (`cbdam synth --earth`, `docs/PLANET.md`, "An Earth to measure
//! on"): 1° × 1° tiles of 3″ samples (1201², big-endian `i16`, voids −32768, named
//! `N45E006.hgt`) for the land cells between 56° S and 60° N, as SRTM's, their heights the
//! bundled ETOPO5 interpolated plus fractal detail.
//!
//! The detail is a sum of value-noise octaves of 1 … 64 samples (3″ … 3.2′, finer than
//! ETOPO5's 5′), octave `o` of amplitude `A·2^(o·H)`, laid on the global 3″ sample grid so
//! neighbouring tiles agree on their shared rows and columns. It is scaled at each point by
//! ETOPO5's local relief (the RMS deviation of each 5′ sample's 3 × 3 neighbourhood from its
//! mean, interpolated) over that relief at the bundled SRTM tile. `H` and `A` are fitted to
//! that tile ([`Roughness`]): the synthetic samples over the tile's own area have the real
//! tile's RMS height difference between neighbouring samples and between samples 16 apart.
//! Voids are round patches where a coarse noise is high in rugged land.

use std::path::Path;

use rayon::prelude::*;

use crate::error::{Context, Result, bail};
use crate::input::{ReadOptions, read_dem};

/// Samples a side of a 3″ tile.
pub const HGT_SIDE: usize = 1201;
/// Samples per degree.
const PER_DEGREE: f64 = 1200.0;
/// SRTM's void.
pub const VOID: i16 = i16::MIN;
/// Octaves of detail: periods 1, 2, … 64 samples.
const OCTAVES: u32 = 7;
/// The relief below which detail stops shrinking (metres): plains are not glass.
const RELIEF_FLOOR: f64 = 5.0;

/// ETOPO5 (or any global latitude/longitude grid whose columns go round the globe), with the
/// local relief of each sample.
pub struct Etopo {
    width: usize,
    height: usize,
    lon0: f64,
    lat0: f64,
    step: f64,
    values: Vec<f32>,
    relief: Vec<f32>,
}

impl Etopo {
    /// Reads a global EPSG:4326 grid (pixel-is-point, columns around the globe), or says why
    /// it is not one.
    pub fn read(path: &Path) -> Result<Self> {
        let dem = read_dem(path, &ReadOptions::default())
            .with_context(|| format!("reading {}", path.display()))?;
        let Some(g) = dem.georef.as_ref() else {
            bail!(
                "{}: no georeferencing (a global grid in EPSG:4326 is needed)",
                path.display()
            );
        };
        let per_turn = 360.0 / g.pixel_x;
        if g.epsg != Some(4326)
            || (g.pixel_x - g.pixel_y).abs() > 1e-12
            || (per_turn - per_turn.round()).abs() > 1e-6
            || (dem.width as f64) < per_turn.round()
        {
            bail!(
                "{}: not a global EPSG:4326 grid whose columns go round the globe",
                path.display()
            );
        }
        let half = if g.pixel_is_area { 0.5 } else { 0.0 };
        let (w, h) = (per_turn.round() as usize, dem.height);
        let values: Vec<f32> = (0..h)
            .flat_map(|r| {
                dem.values[r * dem.width..r * dem.width + w]
                    .iter()
                    .map(|&v| v as f32)
            })
            .collect();
        let mut e = Self {
            width: w,
            height: h,
            lon0: g.origin_x + half * g.pixel_x,
            lat0: g.origin_y - half * g.pixel_y,
            step: g.pixel_x,
            relief: Vec::new(),
            values,
        };
        e.relief = e.local_relief();
        Ok(e)
    }

    /// Per sample, the RMS deviation of its 3 × 3 neighbourhood from the neighbourhood's mean.
    fn local_relief(&self) -> Vec<f32> {
        let (w, h) = (self.width, self.height);
        (0..h)
            .into_par_iter()
            .flat_map_iter(|r| {
                (0..w).map(move |c| {
                    let mut v = [0f64; 9];
                    let mut k = 0;
                    for dr in [-1i64, 0, 1] {
                        let rr = (r as i64 + dr).clamp(0, h as i64 - 1) as usize;
                        for dc in [-1i64, 0, 1] {
                            let cc = (c as i64 + dc).rem_euclid(w as i64) as usize;
                            v[k] = f64::from(self.values[rr * w + cc]);
                            k += 1;
                        }
                    }
                    let mean = v.iter().sum::<f64>() / 9.0;
                    (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / 9.0).sqrt() as f32
                })
            })
            .collect()
    }

    /// Bilinear interpolation of `grid` (one of this grid's layers) at a point.
    fn interpolate(&self, grid: &[f32], lat: f64, lon: f64) -> f64 {
        let r = ((self.lat0 - lat) / self.step).clamp(0.0, (self.height - 1) as f64);
        let c = ((lon - self.lon0) / self.step).rem_euclid(self.width as f64);
        let (r0, c0) = (r.floor() as usize, c.floor() as usize);
        let (r1, c1) = ((r0 + 1).min(self.height - 1), (c0 + 1) % self.width);
        let (fr, fc) = (r - r0 as f64, c - c0 as f64);
        let v = |r: usize, c: usize| f64::from(grid[r * self.width + c]);
        (v(r0, c0) * (1.0 - fc) + v(r0, c1) * fc) * (1.0 - fr)
            + (v(r1, c0) * (1.0 - fc) + v(r1, c1) * fc) * fr
    }

    /// The height at a point, metres.
    pub fn height(&self, lat: f64, lon: f64) -> f64 {
        self.interpolate(&self.values, lat, lon)
    }

    /// The local relief at a point, metres.
    pub fn relief(&self, lat: f64, lon: f64) -> f64 {
        self.interpolate(&self.relief, lat, lon)
    }

    /// The 1° cells (south-west corners, latitude then longitude) between 56° S and 60° N,
    /// with south-west corners in `[west, east) × [south, north)`, where a sample of the grid
    /// on the cell (its edges included) is above sea level: north to south, west to east.
    pub fn land_cells(&self, (west, south, east, north): (i32, i32, i32, i32)) -> Vec<(i32, i32)> {
        let lats: Vec<i32> = (south.max(-56)..north.min(60)).rev().collect();
        lats.into_par_iter()
            .flat_map_iter(|lat| {
                (west.max(-180)..east.min(180))
                    .filter(move |&lon| self.has_land(lat, lon))
                    .map(move |lon| (lat, lon))
            })
            .collect()
    }

    fn has_land(&self, lat: i32, lon: i32) -> bool {
        let r0 = ((self.lat0 - f64::from(lat + 1)) / self.step)
            .ceil()
            .max(0.0) as usize;
        let r1 = (((self.lat0 - f64::from(lat)) / self.step).floor() as usize).min(self.height - 1);
        let c0 = ((f64::from(lon) - self.lon0) / self.step).ceil() as i64;
        let c1 = ((f64::from(lon + 1) - self.lon0) / self.step).floor() as i64;
        (r0..=r1).any(|r| {
            (c0..=c1).any(|c| {
                let c = c.rem_euclid(self.width as i64) as usize;
                self.values[r * self.width + c] > 0.0
            })
        })
    }
}

/// A uniform value in `[-1, 1)` from a grid position, an octave and a seed (splitmix64).
#[inline]
fn hash(x: i64, y: i64, salt: u64) -> f64 {
    let mut z = (x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (y as u64)
            .rotate_left(29)
            .wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ salt.wrapping_mul(0x1656_67B1_9E37_79F9);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 52) as f64 - 1.0
}

/// Value noise of period `2^o` samples at global sample `(x, y)`: hashed values at multiples of
/// the period, bilinear between.
#[inline]
fn value_noise(x: i64, y: i64, o: u32, salt: u64) -> f64 {
    if o == 0 {
        return hash(x, y, salt);
    }
    let p = 1i64 << o;
    let (x0, y0) = (x.div_euclid(p) * p, y.div_euclid(p) * p);
    let (fx, fy) = ((x - x0) as f64 / p as f64, (y - y0) as f64 / p as f64);
    let h = |dx, dy| hash(x0 + dx * p, y0 + dy * p, salt);
    (h(0, 0) * (1.0 - fx) + h(1, 0) * fx) * (1.0 - fy) + (h(0, 1) * (1.0 - fx) + h(1, 1) * fx) * fy
}

/// The fractal detail of unit scale at global 3″ sample `(x, y)` (column east of 180° W, row
/// south of 90° N) for exponent `h`.
fn detail(x: i64, y: i64, h: f64, seed: u64) -> f64 {
    (0..OCTAVES)
        .map(|o| 2f64.powf(f64::from(o) * h) * value_noise(x, y, o, seed ^ u64::from(o)))
        .sum()
}

/// RMS height differences of a grid between neighbouring samples and between samples 16
/// apart, along rows and columns, over pairs of valid samples: the measure the detail is
/// fitted to.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Roughness {
    /// Lag 1 (3″), metres.
    pub lag1: f64,
    /// Lag 16 (48″), metres.
    pub lag16: f64,
}

impl Roughness {
    /// Measured on a `w`-wide row-major grid (`None`: void).
    pub fn of(values: &[Option<f64>], w: usize) -> Self {
        let h = values.len() / w;
        let rms = |d: usize| {
            let (mut sum, mut n) = (0.0, 0u64);
            for r in 0..h {
                for c in 0..w {
                    let Some(a) = values[r * w + c] else { continue };
                    for (rr, cc) in [(r, c + d), (r + d, c)] {
                        if rr < h
                            && cc < w
                            && let Some(b) = values[rr * w + cc]
                        {
                            sum += (a - b) * (a - b);
                            n += 1;
                        }
                    }
                }
            }
            (sum / n.max(1) as f64).sqrt()
        };
        Self {
            lag1: rms(1),
            lag16: rms(16),
        }
    }
}

/// How the Earth is made: the detail's exponent `h` and amplitude `amplitude` (metres at the
/// reference relief), the reference relief, and the seed.
#[derive(Clone, Copy, Debug)]
pub struct EarthDetail {
    /// Exponent of the octaves' amplitudes.
    pub h: f64,
    /// Amplitude of the finest octave where the local relief is `reference_relief`.
    pub amplitude: f64,
    /// ETOPO5's local relief at the tile the detail was fitted to, metres.
    pub reference_relief: f64,
    /// Seed of the noise.
    pub seed: u64,
}

/// A region of 3″ samples: `w` × `h` from global sample `(x0, y0)`.
type Region = (i64, i64, usize, usize);

/// Global 3″ sample of a latitude and longitude (nearest).
fn global_sample(lat: f64, lon: f64) -> (i64, i64) {
    (
        ((lon + 180.0) * PER_DEGREE).round() as i64,
        ((90.0 - lat) * PER_DEGREE).round() as i64,
    )
}

impl EarthDetail {
    /// Fits the detail to `tile` (the real 3″ samples of `region`, row-major, `None` for
    /// voids) over ETOPO5: `h` by bisection so that the synthetic relief's lag-16 / lag-1
    /// ratio is the tile's, then the amplitude so that its lag-1 difference is.
    pub fn fit(etopo: &Etopo, tile: &[Option<f64>], region: Region, seed: u64) -> Result<Self> {
        let target = Roughness::of(tile, region.2);
        if !(target.lag1 > 0.0 && target.lag16 > target.lag1) {
            bail!("the reference tile is flat or rougher at 3″ than at 48″: {target:?}");
        }
        let (cx, cy) = (
            region.0 + region.2 as i64 / 2,
            region.1 + region.3 as i64 / 2,
        );
        let reference_relief = etopo
            .relief(
                90.0 - cy as f64 / PER_DEGREE,
                cx as f64 / PER_DEGREE - 180.0,
            )
            .max(RELIEF_FLOOR);
        let measure = |h: f64, amplitude: f64| {
            let d = Self {
                h,
                amplitude,
                reference_relief,
                seed,
            };
            Roughness::of(&d.region(etopo, region), region.2)
        };
        // The detail and ETOPO5's own slope are independent: their squared differences add,
        // so the amplitude that gives the tile's lag-1 difference is found from two measures.
        let base = measure(0.5, 0.0);
        let amplitude_for = |h: f64| {
            let unit = measure(h, 1.0);
            let unit_detail = (unit.lag1.powi(2) - base.lag1.powi(2)).max(1e-12).sqrt();
            (target.lag1.powi(2) - base.lag1.powi(2)).max(0.0).sqrt() / unit_detail
        };
        let (mut lo, mut hi) = (0.0, 1.5);
        for _ in 0..12 {
            let h = (lo + hi) / 2.0;
            let r = measure(h, amplitude_for(h));
            if r.lag16 / r.lag1 < target.lag16 / target.lag1 {
                lo = h;
            } else {
                hi = h;
            }
        }
        let h = (lo + hi) / 2.0;
        Ok(Self {
            h,
            amplitude: amplitude_for(h),
            reference_relief,
            seed,
        })
    }

    /// The synthetic heights of a region (before rounding; `None` for voids).
    pub fn region(&self, etopo: &Etopo, (x0, y0, w, h): Region) -> Vec<Option<f64>> {
        (0..h)
            .into_par_iter()
            .flat_map_iter(|r| (0..w).map(move |c| self.at(etopo, x0 + c as i64, y0 + r as i64)))
            .collect()
    }

    /// The synthetic height at global 3″ sample `(x, y)`: ETOPO5, then above sea level the
    /// detail scaled by the local relief; `None` in a void.
    pub fn at(&self, etopo: &Etopo, x: i64, y: i64) -> Option<f64> {
        let (lat, lon) = (90.0 - y as f64 / PER_DEGREE, x as f64 / PER_DEGREE - 180.0);
        let base = etopo.height(lat, lon);
        if base <= 0.0 {
            return Some(0.0);
        }
        let scale = etopo.relief(lat, lon).max(RELIEF_FLOOR) / self.reference_relief;
        // Voids: where a noise of 128-sample period is high, in land at least as rugged as the
        // reference tile.
        if scale >= 1.0 && value_noise(x, y, 7, self.seed ^ 0xDEAD) > 0.9 {
            return None;
        }
        let d = self.amplitude * scale * detail(x, y, self.h, self.seed);
        Some((base + d).max(1.0))
    }

    /// The tile of the cell whose south-west corner is `(lat, lon)`, as SRTM stores it:
    /// big-endian `i16`, north row first.
    pub fn hgt_tile(&self, etopo: &Etopo, lat: i32, lon: i32) -> Vec<u8> {
        let (x0, y0) = global_sample(f64::from(lat + 1), f64::from(lon));
        let values = self.region(etopo, (x0, y0, HGT_SIDE, HGT_SIDE));
        values
            .iter()
            .flat_map(|v| {
                v.map_or(VOID, |v| v.round().clamp(-32767.0, 32767.0) as i16)
                    .to_be_bytes()
            })
            .collect()
    }
}

/// SRTM's name of the cell whose south-west corner is `(lat, lon)`: `N45E006.hgt`.
pub fn hgt_name(lat: i32, lon: i32) -> String {
    format!(
        "{}{:02}{}{:03}.hgt",
        if lat < 0 { 'S' } else { 'N' },
        lat.unsigned_abs(),
        if lon < 0 { 'W' } else { 'E' },
        lon.unsigned_abs()
    )
}

/// The region of global 3″ samples a real 3″ grid covers: its north-west sample and size.
pub fn region_of(north_west: (f64, f64), (w, h): (usize, usize)) -> Region {
    let (x, y) = global_sample(north_west.0, north_west.1);
    (x, y, w, h)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_srtms() {
        assert_eq!(hgt_name(45, 6), "N45E006.hgt");
        assert_eq!(hgt_name(-56, -70), "S56W070.hgt");
        assert_eq!(hgt_name(0, -1), "N00W001.hgt");
    }

    /// The noise is continuous across a period's lattice and in [-1, 1].
    #[test]
    fn value_noise_interpolates_its_lattice() {
        for o in 1..OCTAVES {
            let p = 1i64 << o;
            assert_eq!(value_noise(3 * p, -5 * p, o, 9), hash(3 * p, -5 * p, 9));
            for x in -70..70 {
                let v = value_noise(x, 11, o, 9);
                assert!((-1.0..=1.0).contains(&v), "{v}");
            }
        }
    }
}
