//! Word-at-a-time bit writer and reader.
//!
//! Bit order is **MSB-first**: the first bit written is the most significant bit of the first
//! byte, and a multi-bit value is written most significant bit first. This makes a byte stream
//! read as one big-endian integer equal to the concatenated bits, so the reader can keep its
//! buffer left-aligned in a `u64` and use `leading_zeros` directly for unary / Elias-gamma
//! prefixes.
//!
//! The reader never fails: past the end of its input it supplies zero bits and remembers that
//! it did ([`BitReader::is_overrun`]). Decoders check that once, at a point of their choosing,
//! instead of paying for an error path on every bit; a run of zeros always lets the quadtree
//! decoders terminate quickly, so reading on past the end costs nothing but a few nodes.

/// Appends bits MSB-first to a growing byte vector.
#[derive(Debug, Default, Clone)]
pub struct BitWriter {
    bytes: Vec<u8>,
    /// Pending bits, left-aligned: the next bit to flush is bit 63.
    acc: u64,
    /// Number of valid bits in `acc`; always < 32 between calls.
    used: u32,
}

impl BitWriter {
    /// An empty writer.
    pub fn new() -> Self {
        Self::default()
    }

    /// An empty writer whose byte vector has room for `bytes` bytes.
    pub fn with_capacity(bytes: usize) -> Self {
        Self {
            bytes: Vec::with_capacity(bytes),
            acc: 0,
            used: 0,
        }
    }

    /// Writes the low `n` bits of `value`, most significant first. `n` must be at most 32 and
    /// `value` must fit in `n` bits.
    #[inline]
    pub fn put_bits(&mut self, value: u32, n: u32) {
        debug_assert!(n <= 32, "put_bits of {n} bits");
        debug_assert!(
            n == 32 || value >> n == 0,
            "value {value:#x} does not fit in {n} bits"
        );
        if n == 0 {
            return;
        }
        // `used < 32` and `n <= 32`, so the shift is in 0..=63 and nothing falls off the top.
        self.acc |= u64::from(value) << (64 - self.used - n);
        self.used += n;
        if self.used >= 32 {
            self.bytes
                .extend_from_slice(&((self.acc >> 32) as u32).to_be_bytes());
            self.acc <<= 32;
            self.used -= 32;
        }
    }

    /// Writes one bit.
    #[inline]
    pub fn put_bit(&mut self, bit: bool) {
        self.put_bits(u32::from(bit), 1);
    }

    /// Writes the Elias-gamma code of `v >= 1`: `⌊log2 v⌋` zero bits, then `v` in binary
    /// (whose leading bit is the terminating one).
    #[inline]
    pub fn put_gamma(&mut self, v: u32) {
        assert!(v >= 1, "Elias-gamma cannot code 0");
        let k = 31 - v.leading_zeros();
        self.put_bits(0, k);
        self.put_bits(v, k + 1);
    }

    /// Number of bits written so far.
    pub fn bits_written(&self) -> usize {
        self.bytes.len() * 8 + self.used as usize
    }

    /// Pads the last byte with zero bits and returns the bytes.
    pub fn finish(mut self) -> Vec<u8> {
        self.flush_tail();
        self.bytes
    }

    /// Pads the last byte with zero bits and appends the bytes to `out`.
    pub fn finish_into(mut self, out: &mut Vec<u8>) {
        self.flush_tail();
        if out.is_empty() {
            *out = self.bytes;
        } else {
            out.extend_from_slice(&self.bytes);
        }
    }

    fn flush_tail(&mut self) {
        let nbytes = self.used.div_ceil(8) as usize;
        self.bytes
            .extend_from_slice(&self.acc.to_be_bytes()[..nbytes]);
        self.acc = 0;
        self.used = 0;
    }
}

/// Reads bits MSB-first from a byte slice, 64 bits of lookahead at a time.
///
/// All reads are infallible; reading past the end yields zero bits and sets
/// [`is_overrun`](Self::is_overrun).
#[derive(Debug, Clone)]
pub struct BitReader<'a> {
    data: &'a [u8],
    /// Left-aligned bit buffer: the next bit is bit 63. Bits below `avail` are either zero or
    /// already the correct next stream bits (the fast refill loads whole words), so OR-ing the
    /// same bytes in again later is harmless.
    buf: u64,
    /// Number of valid bits at the top of `buf`; at most 64.
    avail: u32,
    /// Index of the next byte to load into `buf`. Counts zero padding, so it may exceed
    /// `data.len()`. Invariant: `bits consumed + avail == 8 * pos`.
    pos: usize,
}

/// The most bits a single [`BitReader::peek`] / [`BitReader::get_bits`] may ask for is 32;
/// after a refill at least this many are buffered.
const REFILL_MIN: u32 = 56;

impl<'a> BitReader<'a> {
    /// A reader positioned at the first bit of `data`.
    pub fn new(data: &'a [u8]) -> Self {
        let mut r = Self {
            data,
            buf: 0,
            avail: 0,
            pos: 0,
        };
        r.refill();
        r
    }

    /// A reader positioned at bit `bit` of `data` (past the end: an overrun reader).
    pub fn at_bit(data: &'a [u8], bit: usize) -> Self {
        let mut r = Self {
            data,
            buf: 0,
            avail: 0,
            pos: bit / 8,
        };
        r.refill();
        r.consume((bit % 8) as u32);
        r
    }

    /// Tops the buffer up to at least 56 valid bits. Must only be called with `avail < 56`
    /// (the fast path shifts by `avail`, which must stay below 64).
    #[inline(always)]
    fn refill(&mut self) {
        debug_assert!(self.avail < REFILL_MIN);
        if let Some(chunk) = self.data.get(self.pos..self.pos.wrapping_add(8)) {
            // One unaligned big-endian load; take as many whole bytes as fit, leaving the
            // partial byte's bits already in place (they are the right bits, see `buf`).
            let word = u64::from_be_bytes(chunk.try_into().expect("8-byte slice"));
            self.buf |= word >> self.avail;
            self.pos += ((63 - self.avail) >> 3) as usize;
            self.avail |= 56;
        } else {
            // By value, not by reference: a hot loop's reader never has its address taken, so
            // the compiler can keep its state in registers (the slow path copies it).
            *self = self.clone().refilled_slowly();
        }
    }

    /// The reader after [`BitReader::refill`] near the end of the input, byte by byte.
    #[cold]
    #[inline(never)]
    fn refilled_slowly(mut self) -> Self {
        while self.avail <= 56 {
            let byte = self.data.get(self.pos).copied().unwrap_or(0);
            self.buf |= u64::from(byte) << (56 - self.avail);
            self.pos += 1;
            self.avail += 8;
        }
        self
    }

    /// Makes sure at least `n <= 56` bits are buffered.
    #[inline(always)]
    pub fn ensure(&mut self, n: u32) {
        debug_assert!(n <= REFILL_MIN);
        if self.avail < n {
            self.refill();
        }
    }

    /// The next `n` bits (1..=32) without consuming them. Call [`ensure`](Self::ensure) first.
    #[inline(always)]
    pub fn peek(&self, n: u32) -> u32 {
        debug_assert!((1..=32).contains(&n) && n <= self.avail);
        (self.buf >> (64 - n)) as u32
    }

    /// The buffer, left-aligned: the next bit is bit 63. After [`ensure`](Self::ensure)`(n)`
    /// its top `n` bits are the stream's next bits (zero past the end), so a decoder can take
    /// a whole prefix code from one word.
    #[inline(always)]
    pub fn buffered(&self) -> u64 {
        self.buf
    }

    /// Drops `n` buffered bits (`n <= avail`; 64 is allowed).
    #[inline(always)]
    pub fn consume(&mut self, n: u32) {
        debug_assert!(n <= self.avail);
        // `checked_shl` keeps n == 64 defined (it clears the buffer).
        self.buf = self.buf.checked_shl(n).unwrap_or(0);
        self.avail -= n;
    }

    /// [`consume`](Self::consume) for `n < 64`, without the guard for a whole-word shift.
    #[inline(always)]
    pub fn consume_short(&mut self, n: u32) {
        debug_assert!(n < 64 && n <= self.avail);
        self.buf <<= n & 63;
        self.avail -= n;
    }

    /// Reads one bit.
    #[inline(always)]
    pub fn get_bit(&mut self) -> bool {
        self.ensure(1);
        let b = self.buf >> 63 != 0;
        self.buf <<= 1;
        self.avail -= 1;
        b
    }

    /// Reads `n` bits (0..=32) as an unsigned integer, most significant first.
    #[inline(always)]
    pub fn get_bits(&mut self, n: u32) -> u32 {
        debug_assert!(n <= 32);
        if n == 0 {
            return 0;
        }
        self.ensure(n);
        let v = self.peek(n);
        self.consume(n);
        v
    }

    /// Counts a run of zero bits terminated by a one bit, consuming the zeros but not the one.
    /// Returns `None` if more than `max_zeros` zeros (at most 55) come first; it then consumes
    /// the `max_zeros + 1` zeros it looked at, so that [`is_overrun`](Self::is_overrun) tells
    /// whether the verdict rested on padding past the end.
    #[inline(always)]
    pub fn read_zero_run(&mut self, max_zeros: u32) -> Option<u32> {
        debug_assert!(max_zeros < REFILL_MIN);
        self.ensure(REFILL_MIN);
        // With >= 56 valid bits buffered, a count <= 55 is entirely within real/padded bits.
        let k = self.buf.leading_zeros();
        if k > max_zeros {
            self.consume(max_zeros + 1);
            return None;
        }
        self.consume(k);
        Some(k)
    }

    /// Reads an Elias-gamma code (see [`BitWriter::put_gamma`]); `None` if its zero prefix is
    /// longer than `max_zeros` (at most 31), which no writer produces for a `u32`; like
    /// [`read_zero_run`](Self::read_zero_run) it then consumes the `max_zeros + 1` zeros.
    #[inline(always)]
    pub fn get_gamma(&mut self, max_zeros: u32) -> Option<u32> {
        debug_assert!(max_zeros <= 31);
        self.ensure(REFILL_MIN);
        let k = self.buf.leading_zeros();
        if k > max_zeros {
            self.consume(max_zeros + 1);
            return None;
        }
        let len = 2 * k + 1;
        if len <= self.avail {
            // Whole code buffered (always the case for values below 2^27).
            let v = (self.buf << k) >> (64 - (k + 1));
            self.consume(len);
            Some(v as u32)
        } else {
            self.consume(k);
            Some(self.get_bits(k + 1))
        }
    }

    /// Bits consumed so far, including zero padding read past the end.
    pub fn bits_consumed(&self) -> usize {
        self.pos * 8 - self.avail as usize
    }

    /// Total number of bits in the input.
    pub fn bits_total(&self) -> usize {
        self.data.len() * 8
    }

    /// Whether more bits were consumed than the input holds.
    pub fn is_overrun(&self) -> bool {
        self.bits_consumed() > self.bits_total()
    }

    /// The unread bits up to the end of the input, at most 7 of them, as
    /// `(count, value)`; `None` if more than 7 bits (or whole bytes) remain or the reader is
    /// overrun. Decoders use it to check that only zero padding follows the last code.
    pub fn remaining_padding(&mut self) -> Option<(u32, u32)> {
        let left = self.bits_total().checked_sub(self.bits_consumed())?;
        if left > 7 {
            return None;
        }
        let n = left as u32;
        if n == 0 {
            return Some((0, 0));
        }
        self.ensure(n);
        Some((n, self.peek(n)))
    }
}

/// Reads bits MSB-first from a copy of its input followed by eight zero bytes, a whole 57-bit
/// window with one load: its only state is the bit position, so a decoder's loop can keep two
/// of them in registers. Like [`BitReader`] it never fails: past the end it gives zero bits,
/// and [`is_overrun`](Self::is_overrun) tells.
#[derive(Debug, Clone, Copy)]
pub struct PaddedBitReader<'a> {
    /// The input, then at least eight zero bytes.
    padded: &'a [u8],
    /// Length of the input.
    len: usize,
    /// Bits consumed, including zero bits past the end.
    bit: usize,
}

impl<'a> PaddedBitReader<'a> {
    /// A reader at the first bit of `data`, whose copy it keeps in `store`.
    pub fn new(data: &[u8], store: &'a mut Vec<u8>) -> Self {
        store.clear();
        store.extend_from_slice(data);
        store.extend_from_slice(&[0; 8]);
        Self {
            padded: store,
            len: data.len(),
            bit: 0,
        }
    }

    /// The next bits, left-aligned: at least the top 57 are the stream's (zero past its end).
    #[inline(always)]
    pub fn window(&self) -> u64 {
        // At `len` the load is the padding: zeros, as past the end.
        let i = (self.bit >> 3).min(self.len);
        let word = match self.padded.get(i..i + 8) {
            Some(bytes) => u64::from_be_bytes(bytes.try_into().unwrap_or([0; 8])),
            None => 0,
        };
        word << (self.bit & 7)
    }

    /// Drops `n` bits.
    #[inline(always)]
    pub fn consume(&mut self, n: u32) {
        self.bit += n as usize;
    }

    /// Bits consumed so far, including zero padding read past the end.
    pub fn bits_consumed(&self) -> usize {
        self.bit
    }

    /// Moves to bit `bit` of the input.
    pub fn seek(&mut self, bit: usize) {
        self.bit = bit;
    }

    /// Whether more bits were consumed than the input holds.
    #[inline(always)]
    pub fn is_overrun(&self) -> bool {
        self.bit > self.len * 8
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn msb_first_layout() {
        let mut w = BitWriter::new();
        w.put_bit(true);
        w.put_bits(0b011, 3);
        w.put_bits(0xABCD, 16);
        // 1 011 then 1010 1011 1100 1101, padded: 1011_1010 1011_1100 1101_0000
        assert_eq!(w.bits_written(), 20);
        assert_eq!(w.finish(), vec![0b1011_1010, 0b1011_1100, 0b1101_0000]);
    }

    #[test]
    fn overrun_reads_zero_and_is_tracked() {
        let data = [0xFFu8; 3];
        let mut r = BitReader::new(&data);
        assert_eq!(r.get_bits(20), 0xFFFFF);
        assert!(!r.is_overrun());
        assert_eq!(r.get_bits(4), 0xF);
        assert!(!r.is_overrun());
        assert_eq!(r.bits_consumed(), 24);
        assert_eq!(r.get_bits(32), 0);
        assert!(r.is_overrun());
        assert_eq!(r.bits_consumed(), 56);
        for _ in 0..100 {
            assert!(!r.get_bit());
        }
        let before = r.bits_consumed();
        assert_eq!(r.read_zero_run(40), None);
        assert_eq!(r.bits_consumed(), before + 41);
    }

    #[test]
    fn zero_run_and_padding() {
        // bits: 000 1 1 0 | 00 0000_0000 (ten zeros) 1 | 000_0000 padding
        let data = [0b0001_1000u8, 0b0000_0000, 0b1000_0000];
        let mut r = BitReader::new(&data);
        assert_eq!(r.read_zero_run(10), Some(3));
        assert!(r.get_bit());
        assert_eq!(r.read_zero_run(10), Some(0));
        assert_eq!(r.get_bits(2), 0b10);
        let mut probe = r.clone();
        assert_eq!(
            probe.read_zero_run(9),
            None,
            "ten zeros exceed the limit of nine"
        );
        assert_eq!(
            probe.bits_consumed(),
            16,
            "a rejected run consumes the zeros it inspected"
        );
        assert_eq!(r.read_zero_run(10), Some(10));
        assert_eq!(r.read_zero_run(1), Some(0));
        r.consume(1);
        assert_eq!(r.bits_consumed(), 17);
        assert_eq!(r.remaining_padding(), Some((7, 0)));
    }

    #[derive(Debug, Clone)]
    enum Op {
        Bits(u32, u32),
        Gamma(u32),
    }

    fn op() -> impl Strategy<Value = Op> {
        prop_oneof![
            (0u32..=32, any::<u32>()).prop_map(|(n, v)| {
                let v = if n == 32 { v } else { v & ((1u32 << n) - 1) };
                Op::Bits(n, v)
            }),
            // Gamma values spread over all magnitudes, not just large ones.
            (0u32..32, any::<u32>()).prop_map(|(k, v)| Op::Gamma((v >> (31 - k)) | (1 << k))),
        ]
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(512))]
        #[test]
        fn writer_reader_round_trip(ops in proptest::collection::vec(op(), 0..300)) {
            let mut w = BitWriter::new();
            let mut expected_bits = 0usize;
            for o in &ops {
                match *o {
                    Op::Bits(n, v) => { w.put_bits(v, n); expected_bits += n as usize; }
                    Op::Gamma(v) => {
                        w.put_gamma(v);
                        expected_bits += 2 * (31 - v.leading_zeros() as usize) + 1;
                    }
                }
            }
            prop_assert_eq!(w.bits_written(), expected_bits);
            let bytes = w.finish();
            prop_assert_eq!(bytes.len(), expected_bits.div_ceil(8));
            let mut r = BitReader::new(&bytes);
            for o in &ops {
                match *o {
                    Op::Bits(n, v) => prop_assert_eq!(r.get_bits(n), v),
                    Op::Gamma(v) => prop_assert_eq!(r.get_gamma(31), Some(v)),
                }
            }
            prop_assert_eq!(r.bits_consumed(), expected_bits);
            prop_assert!(!r.is_overrun());
            let (n, pad) = r.remaining_padding().expect("at most 7 padding bits");
            prop_assert_eq!(n as usize, bytes.len() * 8 - expected_bits);
            prop_assert_eq!(pad, 0);
        }

        #[test]
        fn padded_reader_and_at_bit_match_naive_bit_indexing(
            data in proptest::collection::vec(any::<u8>(), 0..40),
            steps in proptest::collection::vec(0u32..=57, 0..40),
        ) {
            let bit = |i: usize| -> u64 {
                data.get(i / 8).map_or(0, |b| u64::from(b >> (7 - i % 8) & 1))
            };
            let mut store = vec![0xFF; 3];
            let mut r = PaddedBitReader::new(&data, &mut store);
            let mut at = 0usize;
            for &n in &steps {
                // The window's top 57 bits are the stream's next bits, zero past the end.
                let want = (0..57).fold(0u64, |acc, j| (acc << 1) | bit(at + j));
                prop_assert_eq!(r.window() >> 7, want);
                let mut careful = BitReader::at_bit(&data, at);
                prop_assert_eq!(careful.bits_consumed(), at);
                prop_assert_eq!(u64::from(careful.get_bits(32)), want >> 25);
                r.consume(n);
                at += n as usize;
                prop_assert_eq!(r.bits_consumed(), at);
                prop_assert_eq!(r.is_overrun(), at > data.len() * 8);
            }
        }

        #[test]
        fn reader_matches_naive_bit_indexing(
            data in proptest::collection::vec(any::<u8>(), 0..40),
            widths in proptest::collection::vec(1u32..=32, 0..40),
        ) {
            let bit = |i: usize| -> u32 {
                data.get(i / 8).map_or(0, |b| u32::from(b >> (7 - i % 8) & 1))
            };
            let mut r = BitReader::new(&data);
            let mut at = 0usize;
            for &n in &widths {
                let want = (0..n as usize).fold(0u32, |acc, j| (acc << 1) | bit(at + j));
                prop_assert_eq!(r.get_bits(n), want);
                at += n as usize;
                prop_assert_eq!(r.bits_consumed(), at);
                prop_assert_eq!(r.is_overrun(), at > data.len() * 8);
            }
        }
    }
}
