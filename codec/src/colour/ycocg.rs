//! YCoCg-R (Malvar & Sullivan 2003): the lossless integer colour transform of paper §5, and the
//! error bound it turns a per-component bound into.

/// Smallest Y value (8-bit input).
pub const Y_MIN: i32 = 0;
/// Largest Y value (8-bit input).
pub const Y_MAX: i32 = 255;
/// Co and Cg lie in `−CHROMA_REACH ..= CHROMA_REACH` for 8-bit input.
pub const CHROMA_REACH: i32 = 255;

/// `(Y, Co, Cg)` of an 8-bit RGB triple; exactly invertible by [`to_rgb`]. The shifts are
/// arithmetic (floor), as the transform is defined.
#[inline]
pub fn from_rgb([r, g, b]: [u8; 3]) -> [i32; 3] {
    let (r, g, b) = (i32::from(r), i32::from(g), i32::from(b));
    let co = r - b;
    let t = b + (co >> 1);
    let cg = g - t;
    let y = t + (cg >> 1);
    [y, co, cg]
}

/// The RGB triple of `(Y, Co, Cg)`, each component clamped to `0 ..= 255`. Lossless on what
/// [`from_rgb`] produced; on perturbed components (the codec's reconstruction) the clamp only
/// moves a value towards the original, which lies in range, so it never adds error.
#[inline]
pub fn to_rgb([y, co, cg]: [i32; 3]) -> [u8; 3] {
    let t = y - (cg >> 1);
    let g = cg + t;
    let b = t - (co >> 1);
    let r = b + co;
    [r, g, b].map(|v| v.clamp(0, 255) as u8)
}

/// The largest RGB error, per component, when each of Y, Co, Cg is off by at most `k`:
/// `[R, G, B]` bounds.
///
/// Derivation (write `d(e) = ⌊(c+e)/2⌋ − ⌊c/2⌋` for the change of a halved component when it
/// moves by `e`; `|d(e)| ≤ ⌈|e|/2⌉` and `|e − d(e)| ≤ ⌈|e|/2⌉`):
/// - `t = Y − ⌊Cg/2⌋` is off by `eY − d(eCg)`: at most `k + ⌈k/2⌉`;
/// - `G = Cg + t` is off by `eY + (eCg − d(eCg))`: at most `k + ⌈k/2⌉`;
/// - `B = t − ⌊Co/2⌋` is off by `eY − d(eCg) − d(eCo)`: at most `k + 2⌈k/2⌉`;
/// - `R = B + Co` is off by `eY − d(eCg) + (eCo − d(eCo))`: at most `k + 2⌈k/2⌉`.
///
/// The clamp to `0 ..= 255` cannot increase an error. Every component's bound is attained by
/// some colour and some errors within `±k` (tested), so it cannot be tightened without
/// constraining the three errors jointly.
pub fn rgb_bound(k: u32) -> [u32; 3] {
    let half = k.div_ceil(2);
    [k + 2 * half, k + half, k + 2 * half]
}

/// The largest per-component bound `k` whose RGB bound ([`rgb_bound`]) is at most `max_error`
/// levels in every component: `--max-error` is a promise about RGB, which is what a user
/// compares with the source image.
pub fn channel_k(max_error: u32) -> u32 {
    // rgb_bound is monotone in k and rgb_bound(k) ≥ k, so a linear search from max_error down
    // ends at once for all practical values.
    (0..=max_error)
        .rev()
        .find(|&k| rgb_bound(k).into_iter().all(|b| b <= max_error))
        .unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lossless_on_every_8_bit_triple_and_within_range() {
        for r in 0..=255u8 {
            for g in (0..=255u8).step_by(3) {
                for b in 0..=255u8 {
                    let c = from_rgb([r, g, b]);
                    assert!((Y_MIN..=Y_MAX).contains(&c[0]));
                    assert!(c[1].abs() <= CHROMA_REACH && c[2].abs() <= CHROMA_REACH);
                    assert_eq!(to_rgb(c), [r, g, b]);
                }
            }
        }
    }

    /// Exhaustive over perturbations of up to `k` per component on a sample of colours: the
    /// RGB error never exceeds `rgb_bound(k)`, and for each component some case reaches it.
    #[test]
    fn rgb_bound_holds_and_is_attained() {
        for k in 0..=5u32 {
            let bound = rgb_bound(k);
            let mut worst = [0u32; 3];
            let ki = k as i32;
            for rgb in [
                [0u8, 0, 0],
                [255, 255, 255],
                [17, 200, 93],
                [128, 127, 129],
                [3, 250, 1],
            ]
            .into_iter()
            .chain((0..64u32).map(|i| [(i * 37) as u8, (i * 91 + 5) as u8, (i * 53 + 11) as u8]))
            {
                let c = from_rgb(rgb);
                for ey in -ki..=ki {
                    for eco in -ki..=ki {
                        for ecg in -ki..=ki {
                            let out = to_rgb([c[0] + ey, c[1] + eco, c[2] + ecg]);
                            for ch in 0..3 {
                                let e = (i32::from(out[ch]) - i32::from(rgb[ch])).unsigned_abs();
                                assert!(e <= bound[ch], "k {k} {rgb:?} channel {ch}: {e}");
                                worst[ch] = worst[ch].max(e);
                            }
                        }
                    }
                }
            }
            assert_eq!(worst, bound, "k = {k}: the bound is not tight");
        }
    }

    #[test]
    fn channel_k_is_the_largest_fitting_k() {
        assert_eq!(channel_k(0), 0);
        assert_eq!(rgb_bound(0), [0, 0, 0]);
        for e in 0..40 {
            let k = channel_k(e);
            assert!(rgb_bound(k).iter().all(|&b| b <= e));
            assert!(rgb_bound(k + 1).iter().any(|&b| b > e));
        }
    }
}
