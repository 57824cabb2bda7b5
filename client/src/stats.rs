//! Summaries of per-frame figures.

/// The `q`-quantile of sorted values (nearest rank), or the default of an empty list. Shared by
/// the replay, render, bench and viewer summaries.
pub fn percentile<T: Copy + Default>(sorted: &[T], q: f64) -> T {
    if sorted.is_empty() {
        return T::default();
    }
    let i = ((sorted.len() - 1) as f64 * q).round() as usize;
    sorted[i]
}
