//! The C-BDAM client: data access, time-critical refinement and rendering (`cbdam view`).
//!
//! [`patch`] is the unit everything downstream of the decoder handles: the half-patches a cut
//! draws. [`world`] maps the lattice to metres and [`camera`] looks at it. [`draw`] is the wgpu
//! renderer with its GPU patch cache. Streaming refinement (issue 5) is not implemented yet;
//! [`draw::select`] stands in for it.
#![deny(missing_docs)]

pub mod camera;
pub mod draw;
pub mod patch;
pub mod world;
