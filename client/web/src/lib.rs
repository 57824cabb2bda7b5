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
//! This first slice decodes on the page's thread (the core's `Inline` spawner, within the frame
//! budget); Web Workers running the same module are the next step. A browser without WebGPU is
//! told so on the page (naming whether it has WebGL2): the renderer reads heights and instances
//! from storage buffers in the vertex shader, which WebGL2 does not have. wgpu's WebGL2 backend is the `webgl` feature (off:
//! it would only name the adapter it refuses, at four times the module's size).
#![deny(missing_docs)]

#[cfg(target_arch = "wasm32")]
mod app;
#[cfg(target_arch = "wasm32")]
mod input;
#[cfg(target_arch = "wasm32")]
pub mod status;

#[cfg(target_arch = "wasm32")]
pub use app::{set_pixel_error, start};
