//! The server's integration tests, as one test binary: a module per area, the helpers they
//! share (a small real repository, a real server on a loopback port) in `util.rs`.
//! `corrupt.rs` is a binary of its own: it installs a global log subscriber.

mod util;

// Child processes with their own limits, measured through /proc.
#[cfg(target_os = "linux")]
mod answer_memory;
#[cfg(target_os = "linux")]
mod child;
mod examples;
mod file_reads;
#[cfg(target_os = "linux")]
mod hostile;
mod http;
mod mesh_error;
mod priorities;
mod quantized_mesh;
mod tiles;
