//! C-BDAM in the browser: the client core (`cbdam-client`: HTTP access through the page's
//! `fetch`, the time-critical refinement loop) and the wgpu renderer (`cbdam-render`) drawing on a
//! canvas through WebGPU (or WebGL2), one step per `requestAnimationFrame`. Pointer (mouse and touch),
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
//! Where the browser offers no WebGPU adapter, the viewer draws through WebGL2 (the `webgl`
//! feature, on by default: wgpu's GL backend, `new_instance_with_webgpu_detection`): WebGL2 has
//! no storage buffers in vertex shaders, so the renderer takes its texture path
//! (`cbdam_render::VertexFetch::Texture`: the instances as a per-instance vertex buffer, the
//! height pool as an `R32Sint` texture read with `textureLoad`), the same shader maths; the
//! status's `backend` and `vertexFetch` and the overlay say which. A browser with neither is
//! told so on the page. The GL backend brings wgpu-core and naga (WGSL → GLSL) into the module
//! (1.0 MB → 3.7 MB), so `scripts/web-build.sh` builds the crate twice, without the feature
//! (`cbdam_web`) and with it (`cbdam_web_gl`), and the page's `main.js` loads the second only
//! in browsers without a WebGPU adapter.
#![deny(missing_docs)]

#[cfg(target_arch = "wasm32")]
mod app;
#[cfg(target_arch = "wasm32")]
mod input;
#[cfg(target_arch = "wasm32")]
pub mod status;
#[cfg(target_arch = "wasm32")]
pub mod workers;

#[cfg(target_arch = "wasm32")]
pub use app::{set_pixel_error, start};
#[cfg(target_arch = "wasm32")]
pub use workers::{decode_job, init_worker};
