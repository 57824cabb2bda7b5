//! The GeoTIFF key vocabulary (GeoTIFF 1.1, OGC 19-008), shared by the reader here and by
//! writers of GeoTIFF output, so that what we write is what we read.

/// GTModelTypeGeoKey: projected or geographic model.
pub const KEY_MODEL_TYPE: u16 = 1024;
/// GTRasterTypeGeoKey: pixel is area or pixel is point.
pub const KEY_RASTER_TYPE: u16 = 1025;
/// GeographicTypeGeoKey: EPSG code of a geographic CRS.
pub const KEY_GEOGRAPHIC_TYPE: u16 = 2048;
/// ProjectedCSTypeGeoKey: EPSG code of a projected CRS.
pub const KEY_PROJECTED_CS_TYPE: u16 = 3072;
/// VerticalUnitsGeoKey: EPSG code of the unit of the sample values (heights).
pub const KEY_VERTICAL_UNITS: u16 = 4099;
/// EPSG unit: metre.
pub const UNIT_METRE: u16 = 9001;
/// EPSG unit: (international) foot.
pub const UNIT_FOOT: u16 = 9002;
/// EPSG unit: US survey foot.
pub const UNIT_US_SURVEY_FOOT: u16 = 9003;
/// Model type value: projected.
pub const MODEL_PROJECTED: u16 = 1;
/// Model type value: geographic.
pub const MODEL_GEOGRAPHIC: u16 = 2;
/// Raster type value: each sample covers its cell.
pub const RASTER_PIXEL_IS_AREA: u16 = 1;
/// Raster type value: each sample is taken at its point.
pub const RASTER_PIXEL_IS_POINT: u16 = 2;
/// "User-defined": the CRS is spelled out in other keys, not an EPSG code.
pub const USER_DEFINED: u16 = 32767;
