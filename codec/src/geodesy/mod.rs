//! Where the cube-sphere's lattice lies on the Earth: the WGS84 ellipsoid ([`wgs84`]) and the
//! map from a face point to geodetic latitude and longitude ([`cube_map`]). Exact f64
//! arithmetic of our own; `docs/PLANET.md` describes the datum, the mapping and why the
//! latitude is geodetic.

pub mod cube_map;
pub mod transverse_mercator;
pub mod wgs84;

pub use cube_map::{CubeWarp, LatLon, lattice_lat_lon};
pub use transverse_mercator::Utm;
pub use wgs84::Geodetic;
