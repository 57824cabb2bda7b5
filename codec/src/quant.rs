//! From metres to integer heights, and the near-lossless quantizer.
//!
//! Heights are stored as integers `n` in a unit `u` around an offset: `h = offset + n·u`.
//! Two cases, decided by [`QuantPlan::new`]:
//! - **Lattice input**: the samples lie on a grid of values `u` (whole metres, 0.1 m Terrain-RGB;
//!   detected or given). Mapping to integers is exact, and residuals are quantized with step
//!   `(2k+1)·u`, `k = ⌊ε/u⌋`: error ≤ `k·u ≤ ε`, lossless when `ε < u`.
//! - **Float input** (no quantum): the samples are first pre-quantized to the power of two
//!   `u ∈ (ε/16, ε/8]` (error ≤ `u/2`), then quantized with `k = ⌊(ε − u/2)/u⌋ ≥ 7`: total error
//!   ≤ `k·u + u/2 ≤ ε`. A binary `u` keeps `offset + n·u` exact in `f64`. When that unit is so
//!   fine that heights would overflow (ε of a few mm over a whole planet's relief), `u = ε/8`.
//!
//! Either way every reconstructed value is within `k` units of the integer input, which the
//! tests check exactly in integers.
//!
//! `quantizer.rs` is the residual quantizer, `levels.rs` a quantizer per level (RMS builds), `plan.rs` chooses the unit, offset and `k` for a
//! dataset, and `height_grid.rs` holds the integer heights the encoder takes.

use crate::lifting::{MAX_ABS_HEIGHT, PREDICTION_LIMIT};

mod height_grid;
mod levels;
mod plan;
mod quantizer;
mod rounding;
#[cfg(test)]
mod tests;

pub use height_grid::{HeightGrid, RowsWritten};
pub use levels::{LevelQuantizers, MAX_LEVELS};
pub use plan::{QuantPlan, RmsBound};
pub use quantizer::Quantizer;

/// Samples per parallel work item of the passes over the input.
const CHUNK: usize = 1 << 16;

/// Largest magnitude of an input height in units: no larger than the clamp on predictions, so a
/// clamped prediction plus a residual within `k` always reaches a valid target.
pub const MAX_ABS_INPUT: i32 = PREDICTION_LIMIT;

/// Largest quantizer half-step `k`: reconstructions are bounded by `PREDICTION_LIMIT + k`.
pub const MAX_K: i32 = MAX_ABS_HEIGHT - PREDICTION_LIMIT;

/// `x` rounded half away from zero. `f64::round` is a library call on baseline x86-64 (no
/// SSE4.1), a visible cost at one call per input sample; the truncating conversion is one
/// instruction. Saturates for |x| ≥ 2⁶³, which every caller rejects as out of range anyway.
#[inline]
fn round_to_i64(x: f64) -> i64 {
    (x + 0.5f64.copysign(x)) as i64
}
