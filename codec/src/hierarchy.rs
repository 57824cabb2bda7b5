//! Encoder/decoder hierarchy (being written).
