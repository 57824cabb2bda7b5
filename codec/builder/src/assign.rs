//! Georeferencing given on the command line (`--bounds MINX,MINY,MAXX,MAXY --crs EPSG:N`) for an
//! input that carries none: a raw float32 file or a plain TIFF, which would otherwise become a
//! grid of 1 m cells.

use crate::error::{Result, bail};
use cbdam_codec::repository::GeoRef;

/// EPSG codes of geographic (degree) coordinate systems, whose bounds must be longitudes and
/// latitudes: WGS 84, NAD83, ETRS89, GDA94, NAD27.
const GEOGRAPHIC_EPSG: [u32; 5] = [4326, 4269, 4258, 4283, 4267];

/// The outer edges of an input's raster in its CRS, and the CRS.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AssignedGeoRef {
    /// West edge (minimum x).
    pub min_x: f64,
    /// South edge (minimum y).
    pub min_y: f64,
    /// East edge (maximum x).
    pub max_x: f64,
    /// North edge (maximum y).
    pub max_y: f64,
    /// EPSG code of the CRS the bounds are in.
    pub epsg: u32,
}

impl AssignedGeoRef {
    /// Parses `MINX,MINY,MAXX,MAXY` and `EPSG:N` (or `N`), checking that the box is a box and,
    /// for a geographic CRS, that it lies on the globe.
    pub fn parse(bounds: &str, crs: &str) -> Result<Self> {
        let values: Vec<&str> = bounds.split(',').map(str::trim).collect();
        let [min_x, min_y, max_x, max_y] = values.as_slice() else {
            bail!("--bounds {bounds:?}: expected four numbers MINX,MINY,MAXX,MAXY");
        };
        let num = |t: &str| -> Result<f64> {
            match t.parse::<f64>() {
                Ok(v) if v.is_finite() => Ok(v),
                _ => bail!("--bounds {bounds:?}: {t:?} is not a finite number"),
            }
        };
        let (min_x, min_y, max_x, max_y) = (num(min_x)?, num(min_y)?, num(max_x)?, num(max_y)?);
        if min_x >= max_x || min_y >= max_y {
            bail!(
                "--bounds {bounds:?}: the minimum must be below the maximum on both axes \
                 (MINX,MINY,MAXX,MAXY: west, south, east, north)"
            );
        }
        let code = crs.trim();
        let code = code
            .strip_prefix("EPSG:")
            .or_else(|| code.strip_prefix("epsg:"))
            .unwrap_or(code);
        let epsg = match code.parse::<u32>() {
            Ok(n) if (1024..=32767).contains(&n) => n,
            _ => bail!("--crs {crs:?}: expected EPSG:N with N an EPSG code (1024 … 32767)"),
        };
        if GEOGRAPHIC_EPSG.contains(&epsg)
            && (min_x < -180.0 || max_x > 360.0 || min_y < -90.0 || max_y > 90.0)
        {
            bail!(
                "--bounds {bounds:?}: EPSG:{epsg} is geographic, so the bounds are degrees \
                 (longitude −180 … 360, latitude −90 … 90)"
            );
        }
        Ok(Self {
            min_x,
            min_y,
            max_x,
            max_y,
            epsg,
        })
    }

    /// The georeferencing of a `width × height` raster whose outer edges are these bounds
    /// (each sample a cell, GDAL's convention for `-a_ullr` and `-te`).
    pub fn georef(&self, width: usize, height: usize) -> GeoRef {
        GeoRef {
            epsg: Some(self.epsg),
            origin_x: self.min_x,
            origin_y: self.max_y,
            pixel_x: (self.max_x - self.min_x) / width as f64,
            pixel_y: (self.max_y - self.min_y) / height as f64,
            pixel_is_area: true,
            wkt: None,
        }
    }

    /// Gives `path`'s input this georeferencing, refusing one that has its own.
    pub fn apply(
        &self,
        path: &std::path::Path,
        own: &mut Option<GeoRef>,
        size: (usize, usize),
    ) -> Result<()> {
        if let Some(g) = own {
            bail!(
                "{} carries its own georeferencing ({}); --bounds and --crs are for inputs without \
                 one",
                path.display(),
                g.epsg
                    .map_or("no EPSG code".to_string(), |e| format!("EPSG:{e}"))
            );
        }
        *own = Some(self.georef(size.0, size.1));
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_maps_edges_to_cells() {
        let a = AssignedGeoRef::parse("-10, 40, 2, 46", "EPSG:4326").unwrap();
        let g = a.georef(120, 60);
        // 12° over 120 columns, 6° over 60 rows: 0.1° cells, origin at the north-west corner.
        assert_eq!((g.pixel_x, g.pixel_y), (0.1, 0.1));
        assert_eq!((g.origin_x, g.origin_y), (-10.0, 46.0));
        assert!(g.pixel_is_area);
        assert_eq!(
            AssignedGeoRef::parse("0,0,1,1", "32633").unwrap().epsg,
            32633
        );
    }

    #[test]
    fn refuses_bad_boxes_and_codes() {
        for (b, c, says) in [
            ("1,2,3", "EPSG:4326", "four numbers"),
            ("0,0,1,nan", "EPSG:4326", "finite"),
            ("5,0,1,1", "EPSG:4326", "below the maximum"),
            ("0,0,1,1", "WGS84", "EPSG code"),
            ("0,0,1,1", "EPSG:7", "EPSG code"),
            ("0,-95,1,1", "EPSG:4326", "geographic"),
        ] {
            let e = AssignedGeoRef::parse(b, c).unwrap_err().to_string();
            assert!(e.contains(says), "{b} {c}: {e}");
        }
    }
}
