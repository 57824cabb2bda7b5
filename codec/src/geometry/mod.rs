//! Diamond geometry (being written).
