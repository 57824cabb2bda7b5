//! The Rice coder's decoder ([`super`]): the two rows of each pair read side by side from
//! their own streams, each coefficient one table lookup, one count-leading-zeros and a shift.

use std::cell::Cell;

use super::super::{B, MAG_SAT, Scratch, code_node};
use super::{ESCAPE, ESCAPE_BITS, KBySum, RawFlags, check_padding, get_k_table, no_models};
use crate::CodecError;
use crate::entropy::adaptive::tokens::split_streams;
use crate::entropy::bitio::{BitReader, PaddedBitReader};
use crate::entropy::{BandMut, DecodeLimits};

/// Decodes one coefficient with Rice parameter `k`: `(magnitude, value)`. A quotient above
/// [`ESCAPE`] (which no encoder writes) sets `bad`; magnitudes stay below 2^31 whatever the
/// bytes.
#[inline(always)]
fn decode_one(r: &mut PaddedBitReader<'_>, k: u32, bad: &mut bool) -> (u32, i32) {
    let word = r.window();
    let q = word.leading_zeros();
    let u = if q < ESCAPE {
        // Drop the q zeros and the one, then keep the top k bits (k = 0 keeps none); the
        // window's 57 bits hold any code below the escape (at most 47).
        let low = (((word << q) << 1) >> 1) >> (63 - k);
        r.consume(q + 1 + k);
        (q << k) | low as u32
    } else {
        let (after, u, broken) = escaped(*r, q);
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
fn escaped(mut r: PaddedBitReader<'_>, q: u32) -> (PaddedBitReader<'_>, u32, bool) {
    r.consume(ESCAPE + 1);
    let u = (r.window() >> (64 - ESCAPE_BITS)) as u32;
    r.consume(ESCAPE_BITS);
    (r, u, q != ESCAPE)
}

/// Decodes the coded coefficients of one band whose leaf flags are set: even rows from `ra`,
/// odd rows from `rb`. Damage is checked once per row pair.
// The readers go by value and come back: their state stays in registers through the loop
// (nothing takes their address; the cold paths copy them).
#[allow(clippy::too_many_arguments)]
fn decode_coeffs<'a>(
    mut ra: PaddedBitReader<'a>,
    mut rb: PaddedBitReader<'a>,
    ks: &KBySum,
    s: &mut Scratch,
    values: &mut [i32],
    w: usize,
    h: usize,
    max_abs: u32,
) -> Result<(PaddedBitReader<'a>, PaddedBitReader<'a>), CodecError> {
    let stride = w + 4;
    let mut state = PairState::default();
    for y0 in (0..h).step_by(2) {
        if y0 % B == 0 {
            s.coded_block_starts(y0);
        }
        if s.slots.is_empty() {
            continue;
        }
        // Magnitude rows (two padding columns either side): `up` above row y0, `ma` row y0,
        // `mb` row y0 + 1. Cells, because the odd row reads the even row's magnitudes while
        // the even row, one block ahead, writes them.
        let mag = Cell::from_mut(&mut s.mag[(y0 + 1) * stride..]).as_slice_of_cells();
        let (up, rest) = mag.split_at(stride);
        let (ma, rest) = rest.split_at(stride);
        let rows = Rows {
            up,
            ma,
            mb: &rest[..stride.min(rest.len())],
            w,
        };
        let (va, vb) = values[y0 * w..].split_at_mut(w);
        let odd = if y0 + 1 < h { Some(&mut vb[..w]) } else { None };
        (ra, rb) = decode_row_pair(ra, rb, ks, &s.slots, &rows, va, odd, &mut state);
        state.check(&ra, &rb, max_abs)?;
    }
    Ok((ra, rb))
}

/// What a band's rows found so far: the largest magnitude and whether a quotient was past the
/// escape.
#[derive(Default)]
struct PairState {
    worst: u32,
    bad: bool,
}

impl PairState {
    /// The row pair's verdict: an overrun first, then a bad quotient, then a magnitude.
    fn check(
        &self,
        ra: &PaddedBitReader<'_>,
        rb: &PaddedBitReader<'_>,
        max_abs: u32,
    ) -> Result<(), CodecError> {
        if ra.is_overrun() || rb.is_overrun() {
            return Err(CodecError::truncated("fast-rice record ends early"));
        }
        if self.bad {
            return Err(CodecError::corrupt(format!(
                "fast-rice: Rice quotient of more than {ESCAPE} zeros"
            )));
        }
        if self.worst > max_abs {
            return Err(CodecError::corrupt(format!(
                "fast-rice: magnitude {} exceeds the limit {max_abs}",
                self.worst
            )));
        }
        Ok(())
    }
}

/// The magnitude rows of a row pair, padded by two zero columns either side: `up` above the
/// even row, `ma` the even row, `mb` the odd row (empty when there is none).
struct Rows<'m> {
    up: &'m [Cell<u16>],
    ma: &'m [Cell<u16>],
    mb: &'m [Cell<u16>],
    w: usize,
}

/// One row's view of a leaf block starting at column `x0`: the magnitudes above from column
/// `x0 − 1` (`above[i..i + 3]` is the top-left, top and top-right of column `x0 + i`), this
/// row's magnitudes from column `x0 − 1` (`mags[i]` is the left neighbour of `x0 + i`, whose own
/// goes to `mags[i + 1]`), and the values from `x0`.
struct BlockView<'m, 'v> {
    above: &'m [Cell<u16>],
    mags: &'m [Cell<u16>],
    out: &'v mut [i32],
    /// The left neighbour's magnitude, carried in a register along the block.
    left: u32,
}

impl<'m, 'v> BlockView<'m, 'v> {
    /// The view of `n` columns from `x0` (`x0 + n <= w`); the row above and this row are
    /// padded magnitude rows, `out` this row's values.
    #[inline(always)]
    fn new(
        above: &'m [Cell<u16>],
        mags: &'m [Cell<u16>],
        out: &'v mut [i32],
        x0: usize,
        n: usize,
    ) -> Self {
        let mags = &mags[x0 + 1..x0 + 2 + n];
        Self {
            above: &above[x0 + 1..x0 + 3 + n],
            left: u32::from(mags[0].get()),
            mags,
            out: &mut out[x0..x0 + n],
        }
    }

    /// Decodes column `x0 + i` from `r`.
    #[inline(always)]
    fn step(&mut self, r: &mut PaddedBitReader<'_>, ks: &KBySum, i: usize, st: &mut PairState) {
        let t = &self.above[i..i + 3];
        let sum =
            2 * (self.left + u32::from(t[1].get())) + u32::from(t[0].get()) + u32::from(t[2].get());
        let (a, v) = decode_one(r, ks.k(sum), &mut st.bad);
        st.worst = st.worst.max(a);
        self.out[i] = v;
        self.left = a.min(MAG_SAT);
        self.mags[i + 1].set(self.left as u16);
    }
}

/// Decodes one row pair (or a last even row alone, `odd` `None`) over the coded leaf blocks
/// starting at `starts`. The odd row runs one block behind the even one, its steps interleaved
/// with the even row's, so the two dependency chains overlap; its last column's top-right
/// neighbour is the even row's next block's first column, decoded first.
// The block loops spell out the order step by step, by index (`j` and `j − 1`).
#[allow(clippy::too_many_arguments, clippy::needless_range_loop)]
fn decode_row_pair<'a>(
    mut ra: PaddedBitReader<'a>,
    mut rb: PaddedBitReader<'a>,
    ks: &KBySum,
    starts: &[u32],
    rows: &Rows<'_>,
    even: &mut [i32],
    odd: Option<&mut [i32]>,
    st: &mut PairState,
) -> (PaddedBitReader<'a>, PaddedBitReader<'a>) {
    let w = rows.w;
    // Only the band's last block column can be narrower than a block.
    let full = starts
        .iter()
        .take_while(|&&x0| x0 as usize + B <= w)
        .count();
    let width = |j: usize| (w - starts[j] as usize).min(B);
    let Some(odd) = odd else {
        for j in 0..starts.len() {
            let mut e = BlockView::new(rows.up, rows.ma, even, starts[j] as usize, width(j));
            for i in 0..width(j) {
                e.step(&mut ra, ks, i, st);
            }
        }
        return (ra, rb);
    };
    if full > 0 {
        let mut e = BlockView::new(rows.up, rows.ma, even, starts[0] as usize, B);
        for i in 0..B {
            e.step(&mut ra, ks, i, st);
        }
    }
    for j in 1..full {
        let mut e = BlockView::new(rows.up, rows.ma, even, starts[j] as usize, B);
        let mut o = BlockView::new(rows.ma, rows.mb, odd, starts[j - 1] as usize, B);
        for i in 0..B {
            e.step(&mut ra, ks, i, st);
            o.step(&mut rb, ks, i, st);
        }
    }
    if full < starts.len() {
        let mut e = BlockView::new(rows.up, rows.ma, even, starts[full] as usize, width(full));
        for i in 0..width(full) {
            e.step(&mut ra, ks, i, st);
        }
    }
    for j in full.saturating_sub(1)..starts.len() {
        let mut o = BlockView::new(rows.ma, rows.mb, odd, starts[j] as usize, width(j));
        for i in 0..width(j) {
            o.step(&mut rb, ks, i, st);
        }
    }
    (ra, rb)
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
    // The padded copies live in the scratch between records; taken out while the readers
    // borrow them.
    let [mut store_a, mut store_b] = std::mem::take(&mut s.padded_streams);
    let fast = [
        PaddedBitReader::new(a_bytes, &mut store_a),
        PaddedBitReader::new(b_bytes, &mut store_b),
    ];
    let result = decode_streams(a_bytes, b_bytes, fast, bands, limits, s);
    s.padded_streams = [store_a, store_b];
    result
}

/// [`decode_bands`] after the split: each band's header from stream A by `BitReader`, its
/// coefficients by the padded readers `fast` (A and B), the padding checked at the end.
fn decode_streams(
    a_bytes: &[u8],
    b_bytes: &[u8],
    fast: [PaddedBitReader<'_>; 2],
    bands: &mut [BandMut<'_>],
    limits: DecodeLimits,
    s: &mut Scratch,
) -> Result<(), CodecError> {
    let [mut fa, mut fb] = fast;
    let mut ra = BitReader::new(a_bytes);
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
        fa.seek(ra.bits_consumed());
        (fa, fb) = decode_coeffs(fa, fb, &ks, s, b.values, w, h, limits.max_abs)?;
        ra = BitReader::at_bit(a_bytes, fa.bits_consumed());
    }
    check_padding(&mut ra, "A")?;
    check_padding(&mut BitReader::at_bit(b_bytes, fb.bits_consumed()), "B")
}
