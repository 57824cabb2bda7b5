//! The C-BDAM client core: data access, fetching and time-critical refinement, with no GPU,
//! window or thread pool of its own, so it builds for `wasm32-unknown-unknown` as well as the
//! desktop. The renderer (`cbdam-render`) draws what it refines.
//!
//! [`access`] is the data access layer: one non-blocking [`access::DataSource`] trait with a
//! memory-mapped implementation (native only), an HTTP one over the [`fetch`]er and a flaky test
//! double. [`refine`] keeps a cut of the diamond DAG with the paper's time-critical dual-queue
//! loop and hands the renderer the half-patches to draw ([`patch`]), decoded by an injected
//! [`spawn::Spawner`] (rayon's pool on the desktop). [`world`] maps the lattice to metres,
//! [`camera`] looks at it and [`flight`] moves the camera along keyframed paths; [`controls`]
//! moves it interactively. [`stats`] summarises per-frame figures.
#![deny(missing_docs)]

pub mod access;
pub mod camera;
pub mod controls;
pub mod fetch;
pub mod flight;
pub mod horizon;
pub mod patch;
pub mod refine;
pub mod spawn;
pub mod stats;
pub mod viewer;
pub mod world;
