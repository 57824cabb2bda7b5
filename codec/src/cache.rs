//! Cache hints: asking for memory a loop will soon read, where the hardware prefetcher cannot
//! guess it (short runs far apart, or data the next diamond needs while this one decodes).

/// Asks for the cache lines of `values` to be brought into the cache. A hint only: no effect on
/// results; nothing on targets other than x86-64.
#[inline(always)]
pub(crate) fn prefetch<T>(values: &[T]) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        const LINE: usize = 64;
        let bytes = std::mem::size_of_val(values);
        let start = values.as_ptr().cast::<u8>();
        for offset in (0..bytes).step_by(LINE) {
            // SAFETY: SSE is part of the x86-64 baseline, and a prefetch neither reads into
            // the program nor faults; the address is inside `values` (`offset < bytes`).
            unsafe { _mm_prefetch::<_MM_HINT_T0>(start.add(offset).cast()) };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = values;
}
