//! The C-BDAM client: data access, time-critical refinement and rendering (`cbdam view`).
//!
//! [`patch`] is the unit everything downstream of the decoder handles: the half-patches a cut
//! draws. [`world`] maps the lattice to metres and [`camera`] looks at it. Streaming refinement (issue 5) and the renderer (issue 6) are not implemented yet.
#![deny(missing_docs)]

pub mod camera;
pub mod patch;
pub mod remote;
pub mod world;
