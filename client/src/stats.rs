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

/// CPU time of the calling thread, seconds: what a thread's work costs, without the time the
/// shared machine's scheduler keeps it waiting. `None` where unsupported (not Unix).
#[cfg(unix)]
pub fn thread_cpu_seconds() -> Option<f64> {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; the clock id is a constant the C library
    // defines.
    let ok = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) } == 0;
    ok.then_some(ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9)
}

/// CPU time of the calling thread, seconds: `None` where unsupported (not Unix).
#[cfg(not(unix))]
pub fn thread_cpu_seconds() -> Option<f64> {
    None
}
