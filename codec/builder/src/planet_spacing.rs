//! The cube-sphere lattice's spacing in degrees and an input's stride on it: the two numbers
//! every stage of a planet build (inputs, plan, lattice) shares.

/// `log2` of the stride at which an input of ground spacing `input_deg` samples a lattice of
/// spacing `lattice_deg` with `k` level pairs: the largest `j ≤ k` with `2^j` lattice steps no
/// wider than the input's spacing. Its samples are the lattice points on multiples of `2^j`,
/// vertices of level `2K − 2j`, and the lattice points between them are *coarse only*: the
/// hierarchy ends at that level where this input is the finest data (variable resolution: an
/// ETOPO ocean stays as coarse as ETOPO under a fine inset's lattice).
pub fn input_stride(input_deg: f64, lattice_deg: f64, k: u32) -> u32 {
    (0..=k)
        .rev()
        .find(|&j| lattice_deg * f64::from(1u32 << j) <= input_deg * (1.0 + 1e-9))
        .unwrap_or(0)
}

/// Mean spacing of a cube-sphere lattice, degrees of arc: a face spans 90° over `S` steps.
pub fn lattice_spacing_deg(n: usize, k: u32) -> f64 {
    90.0 / ((n as f64 - 1.0) * f64::from(1u32 << k))
}
