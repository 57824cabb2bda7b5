//! The decoded surface's digest in the page (`window.cbdamDecodedDigest(url)` in `main.js`):
//! the codec's `decoded_digest` compiled to wasm32, over a whole repository file's bytes. The
//! browser test compares it with `cbdam inspect --digest` of the same file: wasm32 decodes what
//! native decodes, bit for bit.

use cbdam_codec::repository::{Repository, decoded_digest as digest_of};
use wasm_bindgen::JsError;
use wasm_bindgen::prelude::wasm_bindgen;

/// The digest of the surface `repository` (a whole `.cbdam` file) decodes to, as
/// `fnv1a64 diamonds samples` (the hash in 16 hex digits), or the reason it cannot be decoded.
#[wasm_bindgen]
pub fn decoded_digest(repository: &[u8]) -> Result<String, JsError> {
    let fail = |e: cbdam_codec::CodecError| JsError::new(&e.to_string());
    let repo = Repository::from_bytes(repository.to_vec()).map_err(fail)?;
    let d = digest_of(&repo).map_err(fail)?;
    Ok(format!("{:016x} {} {}", d.fnv1a64, d.diamonds, d.samples))
}
