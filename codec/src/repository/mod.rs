//! The repository format: how an encoded hierarchy is laid out in one file.
//!
//! [`index`] is the compact record index; [`container`] is the single-file, memory-mappable
//! container around it (header, root field, index, per-record checksums, records), specified
//! byte by byte in `docs/FORMAT.md`. [`batch`] is the framing of many records in one HTTP
//! response, written by the server and read by the client.

pub mod batch;
pub mod container;
mod digest;
mod georef;
mod header;
#[doc(hidden)]
pub mod hostile;
pub mod index;
mod level_decode;
mod level_grid;

#[doc(hidden)]
pub use container::{CRAFTABLE_FIELDS, craft_header};
pub use container::{
    FORMAT_VERSION, HEADER_FETCH_LEN, MAGIC, MAX_HEADER_LEN, MAX_MAGNITUDE, PlanetProvenance,
    Repository, RepositoryHead, Section, VerticalDatum, header_len, required_head_len,
    reseal_checksums, serialize, write_planet_repository, write_repository,
};
pub use digest::{DecodedDigest, decoded_digest};
pub use georef::{GeoRef, MAX_WKT_LEN};
pub use level_grid::{LevelGrid, bbox_window};
