//! The C-BDAM codec (Gobbetti et al. 2006, with the decisions of `DESIGN.md`).
//!
//! Pipeline, fine to coarse and back: [`input`] reads a DEM, [`quant`] maps it onto an integer
//! lattice of heights, [`geometry`] lays the diamond DAG over it, [`lifting`] holds the Neville
//! quincunx filters, [`hierarchy`] runs the closed-loop two-stage near-lossless encoder and the
//! decoder diamond by diamond, and [`entropy`] turns residual matrices into bytes and back.
#![deny(missing_docs)]

pub mod atomic;
pub mod colour;
pub mod entropy;
pub mod error;
pub mod geometry;
pub mod hierarchy;
pub mod input;
pub mod lifting;
pub mod quant;
pub mod repository;

pub use error::CodecError;
