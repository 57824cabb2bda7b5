//! The integer lanes of the object-error scans (32 or 64 bits, wrapping) and the straight
//! loops over them: a row's extremes against the input, and the prefetch of rows ahead.

/// Integer lanes of the scan. Arithmetic wraps: exact for valid samples (the caller picks a
/// lane wide enough), and nodata samples, whose values are arbitrary, are masked out afterwards.
pub(super) trait Lane: Copy + Ord + Default + Send {
    fn of(v: i64) -> Self;
    fn add(self, o: Self) -> Self;
    fn sub(self, o: Self) -> Self;
    fn mul(self, o: Self) -> Self;
    fn shl(self, k: u32) -> Self;
    fn widen(self) -> i64;
}

macro_rules! lane {
    ($t:ty) => {
        impl Lane for $t {
            #[inline(always)]
            fn of(v: i64) -> Self {
                v as $t
            }
            #[inline(always)]
            fn add(self, o: Self) -> Self {
                self.wrapping_add(o)
            }
            #[inline(always)]
            fn sub(self, o: Self) -> Self {
                self.wrapping_sub(o)
            }
            #[inline(always)]
            fn mul(self, o: Self) -> Self {
                self.wrapping_mul(o)
            }
            #[inline(always)]
            fn shl(self, k: u32) -> Self {
                self.wrapping_shl(k)
            }
            #[inline(always)]
            fn widen(self) -> i64 {
                self as i64
            }
        }
    };
}
lane!(i32);
lane!(i64);

/// The extremes of `surface − value·2^shift` over the valid samples of a row, starting from
/// `(hi, lo)`: `valid` is `None` when every sample is. Nodata contributes 0, neutral for both.
/// Straight, so it vectorises.
#[inline(always)]
pub(super) fn extremes<T: Lane>(
    surface: &[T],
    values: &[i32],
    valid: Option<&[bool]>,
    shift: u32,
    mut hi: T,
    mut lo: T,
) -> (T, T) {
    let diff = |s: T, v: i32| s.sub(T::of(i64::from(v)).shl(shift));
    match valid {
        Some(valid) => {
            for ((&s, &v), &ok) in surface.iter().zip(values).zip(valid) {
                let d = if ok { diff(s, v) } else { T::default() };
                hi = hi.max(d);
                lo = lo.min(d);
            }
        }
        None => {
            for (&s, &v) in surface.iter().zip(values) {
                let d = diff(s, v);
                hi = hi.max(d);
                lo = lo.min(d);
            }
        }
    }
    (hi, lo)
}

/// Input rows ahead of the one being compared whose samples are prefetched: a diamond's row
/// of samples is short (a few cache lines), too short for the hardware prefetcher to follow
/// the jump to the next input row, so each row would wait on memory.
pub(super) const PREFETCH_ROWS: i64 = 4;

/// Asks for `values[k..k + count]` and `valid[k..k + count]` (clipped to the slices) to be
/// brought into the cache. A hint only: no effect on results.
#[inline(always)]
pub(super) fn prefetch(values: &[i32], valid: Option<&[bool]>, k: usize, count: usize) {
    let end = (k + count).min(values.len());
    if k >= end {
        return;
    }
    crate::cache::prefetch(&values[k..end]);
    if let Some(valid) = valid {
        crate::cache::prefetch(&valid[k..end]);
    }
}
