//! C-BDAM in the browser: the client core (`cbdam-client`: HTTP access through the page's
//! `fetch`, the time-critical refinement loop) and the wgpu renderer (`cbdam-render`) drawing on a
//! canvas through WebGPU, one step per `requestAnimationFrame`. Pointer (mouse and touch),
//! wheel and keys as in `cbdam view` (`input.rs`); the page's slider sets the pixel-error target
//! ([`set_pixel_error`]).
//!
//! Built for `wasm32-unknown-unknown` by `scripts/web-build.sh` (wasm-bindgen `--target web`,
//! with `web/index.html` and `web/main.js`). On other targets this crate is an empty library, so
//! that the workspace's native `cargo clippy` and `cargo test` build it without a browser.
//!
//! The page exposes its state on `window.cbdam` ([`status`]) for people and tests.
//!
//! Decoding runs on the page's thread (the core's `Inline` spawner, within the frame budget).
//! Web Workers running the same module need a decode seam that crosses a `postMessage`: the
//! core's `Spawner` runs closures, and a refinement job holds its parents' decoded nodes
//! (`Arc<Node>`), the decoder and the drape; without shared memory (wasm threads need nightly
//! `build-std`) each job would have to be sent as bytes (record, parents' heights, the header's
//! decoder settings) to a worker that instantiates this module and returns the node's heights,
//! with the refiner collecting results asynchronously.
//!
//! A browser without WebGPU is told so on the page (naming whether it has WebGL2): the renderer
//! reads its instances and heights from storage buffers in the vertex shader, which WebGL2 does
//! not have. A WebGL2 path needs, in `cbdam-render`: the instances as a per-instance vertex
//! buffer, the height pool (and draped colours) as an `R32Sint` texture atlas read with
//! `textureLoad` (a 4096² atlas holds 63² slots of 65²; WebGL2 has too few array layers), slot
//! uploads through `write_texture`, a shader variant, and WebGL2's downlevel limits; here, the
//! `webgl` feature, which takes the module from about 0.9 MB to 3.6 MB (0.3 to 1.2 MB gzipped),
//! over the 2.5 MB target without `wasm-opt`.
#![deny(missing_docs)]

#[cfg(target_arch = "wasm32")]
mod app;
#[cfg(target_arch = "wasm32")]
mod input;
#[cfg(target_arch = "wasm32")]
pub mod status;

#[cfg(target_arch = "wasm32")]
pub use app::{set_pixel_error, start};
