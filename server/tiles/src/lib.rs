//! Web-map tiles of a cbdam repository: what CesiumJS and MapLibre GL read.
//!
//! - [`raster`]: terrarium and Mapbox terrain-RGB PNG or WebP ([`raster_image`]) tiles in the Web Mercator XYZ scheme,
//!   for MapLibre's `raster-dem` source (and deck.gl, openglobus);
//! - [`quantized_mesh`]: quantized-mesh-1.0 tiles in the geographic TMS scheme, for
//!   CesiumJS's `CesiumTerrainProvider`;
//! - [`tiler::Tiler`]: one repository's surface placed on the Earth, answering tile requests
//!   and the TileJSON / `layer.json` documents; the server and a static exporter both use it.
//!
//! The heights come from the repository's decoded even levels ([`surface`]), placed on
//! WGS84 by [`place`]; the tiling schemes are in [`schemes`]. `docs/WEB-MAPS.md` is the user's
//! guide.
#![deny(missing_docs)]

pub mod bounded;
pub mod coverage;
pub mod geoid;
pub mod mesh_cut;
pub mod place;
pub mod pmtiles;
pub mod quantized_mesh;
pub mod raster;
pub mod raster_image;
pub mod schemes;
pub mod surface;
pub mod tiler;
pub mod windows;

pub use raster::Encoding;
pub use raster_image::ImageFormat;
pub use schemes::{Scheme, TileId};
pub use tiler::Tiler;

/// Why a tile or document cannot be made, sorted by who is to blame.
#[derive(Debug, thiserror::Error)]
pub enum TilesError {
    /// The client asked for something that is not a tile (bad z/x/y, bad tile size).
    #[error("{0}")]
    BadTile(String),
    /// A valid tile outside the repository's data (its bounds, `available`).
    #[error("{0}")]
    OutsideData(String),
    /// The repository cannot be served as web-map tiles (its CRS, a colour repository).
    #[error("{0}")]
    Unsupported(String),
    /// The repository could not be decoded (damaged), or encoding failed.
    #[error("{0}")]
    Internal(String),
}

/// Gzip of `bytes` (quantized-mesh tiles travel gzip-compressed).
pub fn gzip(bytes: &[u8]) -> Vec<u8> {
    use std::io::Write;
    let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    enc.write_all(bytes).expect("writing to memory");
    enc.finish().expect("writing to memory")
}
