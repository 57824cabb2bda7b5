//! The build library's tests: one integration-test binary, one module per subject.

mod util;

mod cli;
mod errors;
mod geotiff_stream;
mod input_real;
mod input_synthetic;
mod lattice;
mod progress;
mod rms;
mod streamed;
mod tiles;
mod verify;
