//! Where a repository's grid lies on the Earth: the georeferencing the header records.

/// Where a DEM lies: an axis-aligned grid in some coordinate reference system.
///
/// `(origin_x, origin_y)` are the model coordinates of raster point (0, 0): the outer corner of
/// the north-west sample when `pixel_is_area`, its centre otherwise. Column `c`, row `r` lies at
/// `(origin_x + c * pixel_x, origin_y - r * pixel_y)`, i.e. rows run south for positive `pixel_y`.
#[derive(Clone, Debug, PartialEq)]
pub struct GeoRef {
    /// EPSG code of the coordinate reference system, when the file names one.
    pub epsg: Option<u32>,
    /// Model x (easting or longitude) of raster point (0, 0).
    pub origin_x: f64,
    /// Model y (northing or latitude) of raster point (0, 0).
    pub origin_y: f64,
    /// Sample spacing along x.
    pub pixel_x: f64,
    /// Sample spacing along y, positive when rows run south.
    pub pixel_y: f64,
    /// True when a sample stands for a cell (GeoTIFF `PixelIsArea`), false when it is a point
    /// measurement at the cell centre (`PixelIsPoint`, SRTM `.hgt`).
    pub pixel_is_area: bool,
    /// The CRS as WKT, when the input came with one (an ESRI `.prj` file beside it) — the
    /// definition for CRSs without an EPSG code, kept verbatim.
    pub wkt: Option<String>,
}

/// Longest CRS definition (WKT) a repository keeps, bytes: it lives in the header, whose length
/// is a `u16`. Real ones are a few hundred bytes to a few kilobytes.
pub const MAX_WKT_LEN: usize = 32 * 1024;
