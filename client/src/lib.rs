//! The C-BDAM client: data access, time-critical refinement and rendering (`cbdam view`).
//!
//! [`access`] is the data access layer: one non-blocking [`access::DataSource`] trait with a
//! memory-mapped implementation, an HTTP one ([`remote`]) and a flaky test double.
//! [`refine`] keeps a cut of the diamond DAG with the paper's time-critical dual-queue loop and
//! hands the renderer the half-patches to draw ([`patch`]), decoded on worker threads.
//! [`world`] maps the lattice to metres, [`camera`] looks at it and [`flight`] moves the camera
//! along keyframed paths; [`controls`] moves it interactively. [`draw`] is the wgpu renderer
//! with its GPU patch cache.
#![deny(missing_docs)]

pub mod access;
pub mod camera;
pub mod controls;
pub mod draw;
pub mod flight;
pub mod patch;
pub mod refine;
pub mod remote;
pub mod world;
