//! Elevation raster tiles: heights at each pixel centre of a Web Mercator tile, written as a
//! terrarium or Mapbox terrain-RGB PNG or WebP (the encodings MapLibre's `raster-dem` source
//! reads; the image files are [`crate::raster_image`]'s).
//!
//! - terrarium: `h = R·256 + G + B/256 − 32768`, a step of 1/256 m over −32 768 … 32 767.996 m;
//! - terrain-RGB: `h = −10 000 + (R·65 536 + G·256 + B)·0.1`, a step of 0.1 m over
//!   −10 000 … 1 667 721.5 m; heights below (the deepest ocean trenches) are clamped to
//!   −10 000 m and counted ([`RasterTile::clamped`]).
//!
//! Heights are rounded to the nearest step, so a pixel is within half a step of the height
//! computed. Pixels without data are transparent (an RGBA image; a tile with data everywhere
//! is RGB) and their colour encodes 0 m, which is what a client ignoring alpha draws there.

use crate::TilesError;
use crate::place::{Placement, coarsen_for};
use crate::raster_image::ImageFormat;
use crate::schemes::{Scheme, TileId, mercator_lat};
use crate::surface::Surface;

/// Equatorial circumference of WGS84, metres (Web Mercator's world width).
pub const EARTH_CIRCUMFERENCE: f64 = 2.0 * std::f64::consts::PI * cbdam_codec::geodesy::wgs84::A;

/// A raster-dem encoding.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Encoding {
    /// Mapzen terrarium.
    Terrarium,
    /// Mapbox terrain-RGB.
    TerrainRgb,
}

impl Encoding {
    /// Its name in URLs and in MapLibre's `encoding` (`terrarium`, `mapbox`).
    pub fn maplibre_name(self) -> &'static str {
        match self {
            Encoding::Terrarium => "terrarium",
            Encoding::TerrainRgb => "mapbox",
        }
    }

    /// Metres between two consecutive encoded heights.
    pub fn step(self) -> f64 {
        match self {
            Encoding::Terrarium => 1.0 / 256.0,
            Encoding::TerrainRgb => 0.1,
        }
    }

    /// Lowest and highest encodable height, metres.
    pub fn range(self) -> (f64, f64) {
        match self {
            Encoding::Terrarium => (-32_768.0, 32_768.0 - 1.0 / 256.0),
            Encoding::TerrainRgb => (-10_000.0, -10_000.0 + f64::from((1u32 << 24) - 1) * 0.1),
        }
    }

    /// The RGB of height `h` (clamped into [`Encoding::range`]) and whether it was clamped.
    pub fn encode(self, h: f64) -> ([u8; 3], bool) {
        let (lo, hi) = self.range();
        let clamped = !(lo..=hi).contains(&h);
        let h = h.clamp(lo, hi);
        let v = match self {
            Encoding::Terrarium => ((h + 32_768.0) * 256.0).round() as u32,
            Encoding::TerrainRgb => ((h + 10_000.0) * 10.0).round() as u32,
        };
        ([(v >> 16) as u8, (v >> 8) as u8, v as u8], clamped)
    }

    /// The height of an RGB (the clients' formula).
    pub fn decode(self, rgb: [u8; 3]) -> f64 {
        let [r, g, b] = rgb.map(f64::from);
        match self {
            Encoding::Terrarium => r * 256.0 + g + b / 256.0 - 32_768.0,
            Encoding::TerrainRgb => -10_000.0 + (r * 65_536.0 + g * 256.0 + b) * 0.1,
        }
    }
}

/// One encoded tile.
#[derive(Clone, Debug)]
pub struct RasterTile {
    /// The image file (PNG or WebP, as asked).
    pub image: Vec<u8>,
    /// Pixels whose height the encoding could not hold (clamped to its range).
    pub clamped: u64,
    /// Pixels without data (transparent).
    pub nodata: u64,
    /// The repository level the heights were taken from (the finest one used).
    pub level: u8,
}

/// The Web Mercator zoom whose `tile`-pixel tiles first have pixels no larger than the data's
/// finest spacing at the data's centre latitude.
pub fn max_zoom(place: &Placement, tile: u32) -> u8 {
    let [_, s, _, n] = place.bounds();
    let lat = (0.5 * (s + n)).clamp(-80.0, 80.0).to_radians();
    let ratio = EARTH_CIRCUMFERENCE * lat.cos() / (f64::from(tile) * place.spacing_m());
    (ratio.log2().ceil().max(0.0) as u8).min(crate::schemes::MAX_ZOOM)
}

/// Where the pixel centres of a raster tile lie on the repository, and which level answers.
#[derive(Clone, Debug)]
pub struct PixelPlan {
    /// Per pixel, row after row: face and lattice position (`None` off the repository).
    pub positions: Vec<Option<(u8, f64, f64)>>,
    /// The level index ([`Surface::levels`]) the tile's pixel spacing calls for.
    pub coarsen: usize,
}

impl PixelPlan {
    /// The pixels of tile `t`, `tile` pixels a side.
    pub fn of(place: &Placement, t: TileId, tile: u32) -> PixelPlan {
        let [w, s, e, n] = Scheme::WebMercator.bounds(t);
        let centre_lat = (0.5 * (s + n)).to_radians();
        let pixel_m =
            EARTH_CIRCUMFERENCE * centre_lat.cos() / (f64::from(tile) * f64::from(1u32 << t.z));
        let size = tile as usize;
        let world = f64::from(1u32 << t.z);
        let mut positions = Vec::with_capacity(size * size);
        for row in 0..size {
            let yn = (f64::from(t.y) + (row as f64 + 0.5) / f64::from(tile)) / world;
            let lat = mercator_lat(yn);
            for col in 0..size {
                let lon = w + (e - w) * (col as f64 + 0.5) / f64::from(tile);
                positions.push(place.locate(lat, lon));
            }
        }
        PixelPlan {
            positions,
            coarsen: coarsen_for(place.spacing_m(), pixel_m),
        }
    }

    /// The lattice rectangle `(x0, y0, x1, y1)` holding every located pixel, rounded outwards
    /// (`None` when no pixel lies on the repository).
    pub fn lattice_rect(&self) -> Option<(i64, i64, i64, i64)> {
        let mut rect: Option<(f64, f64, f64, f64)> = None;
        for &(_, x, y) in self.positions.iter().flatten() {
            let r = rect.get_or_insert((x, y, x, y));
            *r = (r.0.min(x), r.1.min(y), r.2.max(x), r.3.max(y));
        }
        rect.map(|(x0, y0, x1, y1)| {
            let (lo, hi) = (|v: f64| v.floor() as i64, |v: f64| v.ceil() as i64);
            (lo(x0), lo(y0), hi(x1), hi(y1))
        })
    }
}

/// Renders tile `t` of `tile` pixels from `surface`.
pub fn render(
    surface: &Surface,
    place: &Placement,
    t: TileId,
    tile: u32,
    (encoding, format): (Encoding, ImageFormat),
) -> Result<RasterTile, TilesError> {
    render_plan(
        Some(surface),
        &PixelPlan::of(place, t, tile),
        tile,
        (encoding, format),
    )
}

/// Renders the pixels `plan` places (a tile of `tile` pixels) from `surface`, which holds the
/// plan's level and coarser ones wherever its pixels lie (`None`: no pixel on the data), as
/// an image file of `format`.
pub fn render_plan(
    surface: Option<&Surface>,
    plan: &PixelPlan,
    tile: u32,
    (encoding, format): (Encoding, ImageFormat),
) -> Result<RasterTile, TilesError> {
    let mut rgba = vec![0u8; plan.positions.len() * 4];
    let (mut clamped, mut nodata, mut level) = (0u64, 0u64, u8::MAX);
    let zero = encoding.encode(0.0).0;
    for (px, at) in rgba.chunks_exact_mut(4).zip(&plan.positions) {
        let h = surface
            .zip(*at)
            .and_then(|(s, (face, x, y))| s.height(face, x, y, plan.coarsen));
        match h {
            Some((h, l)) => {
                let (rgb, c) = encoding.encode(h);
                px.copy_from_slice(&[rgb[0], rgb[1], rgb[2], 255]);
                clamped += u64::from(c);
                level = level.min(l);
            }
            None => {
                px.copy_from_slice(&[zero[0], zero[1], zero[2], 0]);
                nodata += 1;
            }
        }
    }
    let image = format.write(&rgba, tile, nodata > 0)?;
    Ok(RasterTile {
        image,
        clamped,
        nodata,
        level: if level == u8::MAX { 0 } else { level },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every encodable height comes back within half a step; outside the range it is clamped
    /// and said so.
    #[test]
    fn encodings_round_trip_within_half_a_step_and_clamp() {
        for enc in [Encoding::Terrarium, Encoding::TerrainRgb] {
            let (lo, hi) = enc.range();
            for k in 0..10_000 {
                let h = -12_000.0 + 0.731_3 * f64::from(k) * 3.7;
                let (rgb, clamped) = enc.encode(h);
                let back = enc.decode(rgb);
                assert_eq!(clamped, !(lo..=hi).contains(&h), "{enc:?} {h}");
                let expected = h.clamp(lo, hi);
                assert!(
                    (back - expected).abs() <= enc.step() / 2.0 + 1e-9,
                    "{enc:?} {h}: {back}"
                );
            }
        }
        assert_eq!(Encoding::TerrainRgb.encode(-10_500.0), ([0, 0, 0], true));
    }
}
