//! C-BDAM in the browser: the client core (`cbdam-client`: HTTP access through the page's
//! `fetch`, the time-critical refinement loop) and the wgpu renderer (`cbdam-render`) drawing on a
//! canvas through WebGPU (or WebGL2), one step per `requestAnimationFrame`. Pointer (mouse and touch),
//! wheel and keys as in `cbdam view` (`input.rs`); the page's slider sets the pixel-error target
//! ([`set_pixel_error`]).
//!
//! Built for `wasm32-unknown-unknown` by `scripts/web-build.sh` (wasm-bindgen `--target web`,
//! with `www/index.html`, `www/main.js` and `www/worker.js`). On other targets this crate is an empty library, so
//! that the workspace's native `cargo clippy` and `cargo test` build it without a browser.
//!
//! The page exposes its state on `window.cbdam` ([`status`]) for people and tests.
//! `index.html?flight=URL` plays a camera flight of `cbdam render --path` ([`flight`]) and
//! measures its frames; `index.html?colour=URL` drapes a colour repository over the terrain
//! (the core's `ColouredSource`, decoded in the workers beside the heights).
//! `window.cbdamDecodedDigest(url)` digests a whole repository's decoded surface in wasm32
//! ([`decoded_digest`]), for the test that it equals the native decode's.
//!
//! Decoding runs in Web Workers ([`workers`]): `navigator.hardwareConcurrency − 1` of them (at
//! least 1, at most 4), each running `worker.js`, which instantiates this same module (the
//! WebGPU or the WebGL2 build, whichever the page loaded) and calls [`init_worker`] with the
//! repository head's bytes, then [`decode_job`] per job. Without shared memory (wasm threads
//! need nightly `build-std`, and cross-origin isolation headers static hosts lack) a job crosses
//! a `postMessage` as bytes: the core's decode-job seam (`cbdam_client::spawn::Portable`,
//! `cbdam_client::refine::WorkerDecoder`: the records, the given parents' refinements, the
//! results), the buffers transferred. The results go into the refiner's channel and are applied
//! by the next frame within its budget. Where no worker can start (or one fails) the jobs run on
//! the page, as the core's `Inline` spawner would, and the status and overlay say so;
//! `index.html?workers=0` decodes on the page on purpose (for comparisons).
//!
//! Where the browser offers no WebGPU adapter, the viewer draws through WebGL2 (the `webgl`
//! feature, on by default: wgpu's GL backend, `new_instance_with_webgpu_detection`): WebGL2 has
//! no storage buffers in vertex shaders, so the renderer takes its texture path
//! (`cbdam_render::VertexFetch::Texture`: the instances as a per-instance vertex buffer, the
//! height pool as an `R32Sint` texture read with `textureLoad`), the same shader maths; the
//! status's `backend` and `vertexFetch` and the overlay say which. A browser with neither is
//! told so on the page. The GL backend brings wgpu-core and naga (WGSL → GLSL) into the module
//! (0.74 MB → 2.45 MB after wasm-opt), so `scripts/web-build.sh` builds the crate twice, with
//! the `webgpu` feature alone (`cbdam_web`) and with the `webgl` feature alone (`cbdam_web_gl`),
//! and the page's `main.js` loads the second only in browsers without a WebGPU adapter. The
//! default features (both) give one module that picks its backend at run time.
#![deny(missing_docs)]

#[cfg(target_arch = "wasm32")]
mod app;
#[cfg(target_arch = "wasm32")]
mod digest;
#[cfg(target_arch = "wasm32")]
pub mod flight;
#[cfg(target_arch = "wasm32")]
mod input;
#[cfg(target_arch = "wasm32")]
pub mod status;
#[cfg(target_arch = "wasm32")]
pub mod workers;

#[cfg(target_arch = "wasm32")]
pub use app::{set_pixel_error, start};
#[cfg(target_arch = "wasm32")]
pub use digest::decoded_digest;
#[cfg(target_arch = "wasm32")]
pub use flight::play_flight;
#[cfg(target_arch = "wasm32")]
pub use workers::{decode_job, init_worker};
