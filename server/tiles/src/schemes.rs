//! The two tiling schemes web maps use: Web Mercator XYZ (MapLibre, deck.gl: `y` from the
//! north, one root tile) and the geographic TMS of quantized-mesh (CesiumJS: `y` from the
//! south, two root tiles side by side at z = 0).

use crate::TilesError;

/// Deepest zoom level accepted (tile indices then fit `u32` and pixel maths `f64` exactly).
pub const MAX_ZOOM: u8 = 24;

/// Web Mercator's latitude limit, degrees: `atan(sinh(π))`.
pub const MERCATOR_MAX_LAT: f64 = 85.051_128_779_806_59;

/// A tile address `z/x/y`, checked against its scheme's grid.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct TileId {
    /// Zoom level.
    pub z: u8,
    /// Column, from the west.
    pub x: u32,
    /// Row: from the north (Web Mercator) or from the south (geographic TMS).
    pub y: u32,
}

/// Which tiling scheme.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Scheme {
    /// Web Mercator XYZ, `2^z × 2^z` tiles, `y` from the north.
    WebMercator,
    /// Geographic (EPSG:4326) TMS, `2^(z+1) × 2^z` tiles, `y` from the south.
    Geographic,
}

impl Scheme {
    /// Columns and rows at level `z`.
    pub fn tiles_at(self, z: u8) -> (u32, u32) {
        match self {
            Scheme::WebMercator => (1 << z, 1 << z),
            Scheme::Geographic => (2 << z, 1 << z),
        }
    }

    /// The tile `z/x/y`, or why it is not one.
    pub fn tile(self, z: u32, x: u32, y: u32) -> Result<TileId, TilesError> {
        if z > u32::from(MAX_ZOOM) {
            return Err(TilesError::BadTile(format!(
                "zoom {z} is beyond the deepest level served, {MAX_ZOOM}"
            )));
        }
        let z = z as u8;
        let (nx, ny) = self.tiles_at(z);
        if x >= nx || y >= ny {
            return Err(TilesError::BadTile(format!(
                "tile {z}/{x}/{y} does not exist: level {z} has columns 0…{} and rows 0…{}",
                nx - 1,
                ny - 1
            )));
        }
        Ok(TileId { z, x, y })
    }

    /// West, south, east, north of a tile, degrees.
    pub fn bounds(self, t: TileId) -> [f64; 4] {
        match self {
            Scheme::WebMercator => {
                let n = f64::from(1u32 << t.z);
                let lon = |x: f64| x / n * 360.0 - 180.0;
                [
                    lon(f64::from(t.x)),
                    mercator_lat((f64::from(t.y) + 1.0) / n),
                    lon(f64::from(t.x) + 1.0),
                    mercator_lat(f64::from(t.y) / n),
                ]
            }
            Scheme::Geographic => {
                let size = 180.0 / f64::from(1u32 << t.z);
                let (w, s) = (
                    -180.0 + f64::from(t.x) * size,
                    -90.0 + f64::from(t.y) * size,
                );
                [w, s, w + size, s + size]
            }
        }
    }

    /// Whether a tile meets the rectangle `b` (west, south, east, north, degrees) with an
    /// area, not only along an edge.
    pub fn meets(self, t: TileId, b: [f64; 4]) -> bool {
        let tb = self.bounds(t);
        tb[0] < b[2] && b[0] < tb[2] && tb[1] < b[3] && b[1] < tb[3]
    }

    /// The inclusive range of tiles `(x0, y0, x1, y1)` at level `z` that meet `b`; `None` if
    /// none does.
    pub fn range(self, z: u8, b: [f64; 4]) -> Option<(u32, u32, u32, u32)> {
        let (nx, ny) = self.tiles_at(z);
        let col = |lon: f64| ((lon + 180.0) / 360.0 * f64::from(nx)).floor();
        let row = |lat: f64| match self {
            Scheme::WebMercator => {
                let lat = lat.clamp(-MERCATOR_MAX_LAT, MERCATOR_MAX_LAT).to_radians();
                let m = (1.0 - lat.tan().asinh() / std::f64::consts::PI) / 2.0;
                (m * f64::from(ny)).floor()
            }
            Scheme::Geographic => ((lat + 90.0) / 180.0 * f64::from(ny)).floor(),
        };
        let clamp_x = |v: f64| v.clamp(0.0, f64::from(nx - 1)) as u32;
        let clamp_y = |v: f64| v.clamp(0.0, f64::from(ny - 1)) as u32;
        let (ya, yb) = (row(b[1]), row(b[3]));
        let r = (
            clamp_x(col(b[0])),
            clamp_y(ya.min(yb)),
            clamp_x(col(b[2])),
            clamp_y(ya.max(yb)),
        );
        // The floor of an edge lying on a tile boundary names the tile beyond it: trim.
        let mut r = r;
        while r.2 > r.0 && !self.meets(TileId { z, x: r.2, y: r.1 }, [b[0], -90.0, b[2], 90.0]) {
            r.2 -= 1;
        }
        while r.3 > r.1 && !self.meets(TileId { z, x: r.0, y: r.3 }, [-180.0, b[1], 180.0, b[3]]) {
            r.3 -= 1;
        }
        self.meets(TileId { z, x: r.0, y: r.1 }, b).then_some(r)
    }
}

/// Latitude, degrees, of Web Mercator's normalised `y ∈ [0, 1]` (0 = north edge).
pub fn mercator_lat(y: f64) -> f64 {
    (std::f64::consts::PI * (1.0 - 2.0 * y))
        .sinh()
        .atan()
        .to_degrees()
}

/// The geometric error CesiumJS allows a level-`z` tile of the geographic scheme
/// (`TerrainProvider.getEstimatedLevelZeroGeometricErrorForAHeightmap` with a 65-sample
/// heightmap and 0.25 quality on WGS84, halved each level): ≈ 77 067 m / 2^z.
pub fn cesium_level_error(z: u8) -> f64 {
    let level_zero =
        cbdam_codec::geodesy::wgs84::A * 2.0 * std::f64::consts::PI * 0.25 / (65.0 * 2.0);
    level_zero / f64::from(1u32 << z)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Bounds lying on tile edges take no tile beyond them; a point's tile is its range.
    #[test]
    fn ranges_hold_exactly_the_tiles_meeting_the_bounds() {
        let g = Scheme::Geographic;
        // Level 1: 4 × 2 tiles of 90°. The eastern hemisphere's north half.
        assert_eq!(g.range(1, [0.0, 0.0, 180.0, 90.0]), Some((2, 1, 3, 1)));
        assert_eq!(g.range(0, [-180.0, -90.0, 180.0, 90.0]), Some((0, 0, 1, 0)));
        let m = Scheme::WebMercator;
        assert_eq!(m.range(1, [0.0, 0.0, 180.0, 85.0]), Some((1, 0, 1, 0)));
        for z in 0..12 {
            let (x0, y0, x1, y1) = m.range(z, [7.1, 46.2, 7.11, 46.21]).unwrap();
            assert!(x1 - x0 <= 1 && y1 - y0 <= 1);
            for (x, y) in [(x0, y0), (x1, y1)] {
                assert!(m.meets(TileId { z, x, y }, [7.1, 46.2, 7.11, 46.21]));
            }
        }
        assert!(Scheme::Geographic.tile(2, 8, 0).is_err());
        assert!(Scheme::WebMercator.tile(25, 0, 0).is_err());
    }

    #[test]
    fn cesium_level_zero_error_is_cesiums() {
        assert!((cesium_level_error(0) - 77_067.34).abs() < 0.01);
    }
}
