//! Quantization (being written).
