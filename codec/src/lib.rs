//! The C-BDAM codec (Gobbetti et al. 2006, with the decisions of `docs/DESIGN.md`).
//!
//! The repository format and the coding, fine to coarse and back: [`samples`] are a DEM's
//! heights as the builder (`cbdam-builder`) reads them, [`quant`] maps them onto an integer
//! lattice of heights, [`geometry`] lays the diamond DAG over it, [`lifting`] holds the Neville
//! quincunx filters, [`hierarchy`] runs the closed-loop two-stage near-lossless encoder and the
//! decoder diamond by diamond, and [`entropy`] turns residual matrices into bytes and back.
#![deny(missing_docs)]

pub mod atomic;
mod cache;
pub mod colour;
pub mod entropy;
pub mod error;
pub mod files;
pub mod geodesy;
pub mod geometry;
pub mod hierarchy;
pub mod lifting;
pub mod quant;
pub mod repository;
pub mod samples;
pub mod temp;

/// Deterministic junk for the decoders' never-panic tests: `len` bytes from an LCG seeded by
/// `seed`.
#[cfg(test)]
pub(crate) fn test_junk(seed: u64, len: u64) -> Vec<u8> {
    (0..len)
        .map(|k| {
            (seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(k.wrapping_mul(1442695040888963407))
                >> 33) as u8
        })
        .collect()
}

pub use error::CodecError;
