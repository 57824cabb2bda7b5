//! The repository format: how an encoded hierarchy is laid out in bytes.
//!
//! So far only the record index ([`index`]); the single-file container with its header and
//! checksums is issue 3.

pub mod index;
