//! The codec's integration tests, as one test binary (one link instead of one per file): a
//! module per area, the helpers they share in `util.rs`. Run one area with
//! `cargo test -p cbdam-codec --test tests -- golden::`.

mod util;

mod colour;
mod gamma_coder;
mod golden;
mod hostile_inputs;
mod hostile_records;
mod level_quantizers;
mod linf_bound;
mod nodata_mask;
mod numerical_stress;
mod older_formats;
mod one_decode;
mod parallel_decode;
mod planet_blocks;
mod planet_codec;
mod planet_domain;
mod planet_window_decode;
mod real_dems;
mod repository;
mod variable_resolution;
mod window_decode;
