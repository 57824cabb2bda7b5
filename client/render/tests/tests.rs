//! The renderer's integration tests, one binary (as ripgrep's `tests/tests.rs`), drawing for
//! real (lavapipe where there is no GPU); [`util`] holds what they share.

/// Adaptive cuts drawn within the pixel-error bound.
mod accuracy;
/// The GPU patch cache: a small pool or upload budget never draws a wrong patch.
mod cache;
/// Draped colour: patches and pixels follow the colour image.
mod colour;
/// Mixed-level cuts have no cracks.
mod cracks;
/// Images against the golden files in `tests/golden/`.
mod golden;
/// Nodata is not drawn; data is.
mod nodata;
/// A planet drawn as a globe: framing, cracks at cube corners and edges, precision near the eye.
mod planet;
mod util;
/// The texture path (WebGL2's) draws exactly the storage-buffer path's images.
mod vertex_fetch;
