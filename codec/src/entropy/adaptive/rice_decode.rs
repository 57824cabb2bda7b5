//! The Rice coder's decoder ([`super`]): the two rows of each pair read side by side from
//! their own streams, each coefficient one table lookup, one count-leading-zeros and a shift.

use super::super::{MAG_SAT, Scratch, code_node};
use super::{ESCAPE, ESCAPE_BITS, KBySum, RawFlags, check_padding, get_k_table, no_models};
use crate::CodecError;
use crate::entropy::adaptive::tokens::split_streams;
use crate::entropy::bitio::BitReader;
use crate::entropy::{BandMut, DecodeLimits};

/// How many coefficients the odd row of a pair trails the even one by: its top-right
/// neighbour at slot `i` is the even row's slot `i + 1`, already decoded.
const LAG: usize = 2;

/// Decodes one coefficient with Rice parameter `k`: `(magnitude, value)`. A quotient above
/// [`ESCAPE`] (which no encoder writes) sets `bad`; magnitudes stay below 2^31 whatever the
/// bytes.
#[inline(always)]
fn decode_one(r: &mut BitReader<'_>, k: u32, bad: &mut bool) -> (u32, i32) {
    r.ensure(56);
    let word = r.buffered();
    let q = word.leading_zeros();
    let u = if q < ESCAPE {
        // Drop the q zeros and the one, then keep the top k bits (k = 0 keeps none).
        let low = (((word << q) << 1) >> 1) >> (63 - k);
        r.consume_short(q + 1 + k);
        (q << k) | low as u32
    } else {
        let (after, u, broken) = escaped(r.clone(), q);
        *r = after;
        *bad |= broken;
        u
    };
    let a = (u >> 1) + (u & 1);
    let v = ((u >> 1) as i32) ^ ((u & 1) as i32).wrapping_neg();
    (a, v)
}

/// The rare escaped code: `ESCAPE` zeros, a one, `u` in [`ESCAPE_BITS`] bits; gives the reader
/// after it, `u`, and whether the quotient was out of range. The reader goes by value, so that
/// the hot loop's readers never have their address taken and stay in registers.
#[cold]
#[inline(never)]
fn escaped(mut r: BitReader<'_>, q: u32) -> (BitReader<'_>, u32, bool) {
    r.consume_short(ESCAPE + 1);
    let u = r.get_bits(ESCAPE_BITS);
    (r, u, q != ESCAPE)
}

/// Decodes the coded coefficients of one band whose leaf flags are set: even rows from `ra`,
/// odd rows from `rb`, two coefficients behind. Magnitudes are checked once per row pair.
// The slot loops spell out the pair order step by step, by index, so that they can be compared.
// The readers go by value and come back: their state stays in registers through the loop
// (nothing takes their address; the cold paths copy them).
#[allow(clippy::too_many_arguments, clippy::needless_range_loop)]
fn decode_coeffs<'a>(
    mut ra: BitReader<'a>,
    mut rb: BitReader<'a>,
    ks: &KBySum,
    s: &mut Scratch,
    values: &mut [i32],
    w: usize,
    h: usize,
    max_abs: u32,
) -> Result<(BitReader<'a>, BitReader<'a>), CodecError> {
    let stride = w + 4;
    let mut worst = 0u32;
    let mut bad = false;
    for y0 in (0..h).step_by(2) {
        if y0 % super::super::B == 0 {
            s.rice_slots(y0, w);
        }
        let slots = s.slots.as_slice();
        let n = slots.len();
        if n == 0 {
            continue;
        }
        // Magnitude rows (two padding columns either side): `up` above row y0, `ma` row y0,
        // `mb` row y0 + 1.
        let (above, below) = s.mag.split_at_mut((y0 + 2) * stride);
        let up = &above[(y0 + 1) * stride..];
        let (ma, below) = below.split_at_mut(stride);
        let (va, vb) = values[y0 * w..].split_at_mut(w);
        let (mut left_a, mut next_a) = (0u32, usize::MAX);
        let (mut left_b, mut next_b) = (0u32, usize::MAX);
        macro_rules! step {
            ($r:expr, $i:expr, $up:expr, $cur:expr, $out:expr, $left:ident, $next:ident) => {{
                let x = slots[$i] as usize;
                let t = &$up[x + 1..x + 4];
                // A zero block's magnitudes are zero: the previous coefficient of this row is
                // the left neighbour only when adjacent.
                let left = if $next == x { $left } else { 0 };
                let sum = 2 * (left + u32::from(t[1])) + u32::from(t[0]) + u32::from(t[2]);
                let (a, v) = decode_one(&mut $r, ks.k(sum), &mut bad);
                worst = worst.max(a);
                $out[x] = v;
                $left = a.min(MAG_SAT);
                $cur[x + 2] = $left as u16;
                $next = x + 1;
            }};
        }
        if y0 + 1 >= h {
            for i in 0..n {
                step!(ra, i, up, ma, va, left_a, next_a);
            }
        } else {
            let mb = &mut below[..stride];
            for i in 0..n.min(LAG) {
                step!(ra, i, up, ma, va, left_a, next_a);
            }
            for i in LAG..n {
                step!(ra, i, up, ma, va, left_a, next_a);
                step!(rb, i - LAG, ma, mb, vb, left_b, next_b);
            }
            for i in n.saturating_sub(LAG)..n {
                step!(rb, i, ma, mb, vb, left_b, next_b);
            }
        }
        if ra.is_overrun() || rb.is_overrun() {
            return Err(CodecError::truncated("fast-rice record ends early"));
        }
        if bad {
            return Err(CodecError::corrupt(format!(
                "fast-rice: Rice quotient of more than {ESCAPE} zeros"
            )));
        }
        if worst > max_abs {
            return Err(CodecError::corrupt(format!(
                "fast-rice: magnitude {worst} exceeds the limit {max_abs}"
            )));
        }
    }
    Ok((ra, rb))
}

/// Decodes one record written by [`super::encode_bands`] into `bands`.
pub(crate) fn decode_bands(
    bytes: &[u8],
    bands: &mut [BandMut<'_>],
    limits: DecodeLimits,
    s: &mut Scratch,
) -> Result<(), CodecError> {
    for b in bands.iter_mut() {
        b.values.fill(0);
    }
    if bytes.is_empty() {
        return Ok(());
    }
    let (a_bytes, b_bytes) = split_streams(bytes, "fast-rice", "stream A")?;
    let (mut ra, mut rb) = (BitReader::new(a_bytes), BitReader::new(b_bytes));
    for b in bands.iter_mut() {
        let (w, h) = (b.width, b.height);
        if w == 0 || h == 0 {
            continue;
        }
        s.reset(w, h);
        if ra.get_bit() {
            s.set_dense();
        } else {
            let top = s.dims.len() - 1;
            if !code_node(
                &mut RawFlags(&mut ra),
                &mut no_models(),
                s,
                top,
                0,
                0,
                false,
            ) {
                continue;
            }
        }
        if ra.is_overrun() {
            return Err(CodecError::truncated(
                "fast-rice record ends in a band header",
            ));
        }
        let ks = KBySum::new(&get_k_table(&mut ra)?);
        (ra, rb) = decode_coeffs(ra, rb, &ks, s, b.values, w, h, limits.max_abs)?;
    }
    check_padding(&mut ra, "A")?;
    check_padding(&mut rb, "B")
}
