//! The paper's reference coder: a quadtree of "has a non-zero value" bits with Elias-gamma
//! coded leaves.
//!
//! All bands of a record go, in order, into one MSB-first bit stream ([`super::bitio`]). Each
//! non-empty band is a quadtree traversed depth first:
//!
//! * every visited block gets one bit, 1 iff it holds a non-zero value; a 0 ends the block;
//! * a flagged 1×1 block is followed by Elias-gamma(|v|) and one sign bit (1 = negative);
//! * a flagged larger block splits its rows at `⌈h/2⌉` and its columns at `⌈w/2⌉` and visits
//!   the non-empty quadrants in Z order (top-left, top-right, bottom-left, bottom-right).
//!
//! The last byte is padded with zero bits. A zero-size band writes nothing.
//!
//! The decoder accepts exactly the streams the encoder can write: besides range checks it
//! rejects a flagged block none of whose children is flagged, non-zero padding and trailing
//! bytes. So every accepted record is the canonical encoding of what it decodes to, and most
//! bit flips are caught rather than silently changing heights.

use super::bitio::{BitReader, BitWriter};
use super::{Band, BandMut, DecodeLimits, MAX_BAND_SIDE};
use crate::CodecError;

/// Encodes `bands` into one record appended to `out`.
pub(crate) fn encode_bands(bands: &[Band<'_>], out: &mut Vec<u8>) {
    let max_abs = DecodeLimits::default().max_abs;
    let total: usize = bands.iter().map(|b| b.values.len()).sum();
    // Sparse residual bands typically need well under a byte per sample.
    let mut w = BitWriter::with_capacity(total / 4 + 8);
    for band in bands {
        assert_eq!(
            band.values.len(),
            band.width * band.height,
            "band size mismatch"
        );
        if band.width == 0 || band.height == 0 {
            continue;
        }
        let enc = Encoder {
            values: band.values,
            stride: band.width,
            max_abs,
        };
        let nz = enc.any_nonzero(0, 0, band.height, band.width);
        w.put_bit(nz);
        if nz {
            enc.block(&mut w, 0, 0, band.height, band.width);
        }
    }
    w.finish_into(out);
}

struct Encoder<'a> {
    values: &'a [i32],
    stride: usize,
    max_abs: u32,
}

impl Encoder<'_> {
    fn any_nonzero(&self, r0: usize, c0: usize, h: usize, w: usize) -> bool {
        (r0..r0 + h).any(|r| {
            let start = r * self.stride + c0;
            self.values[start..start + w].iter().any(|&v| v != 0)
        })
    }

    /// Writes the contents of a block already flagged non-zero.
    fn block(&self, out: &mut BitWriter, r0: usize, c0: usize, h: usize, w: usize) {
        if h == 1 && w == 1 {
            let v = self.values[r0 * self.stride + c0];
            let m = v.unsigned_abs();
            assert!(
                m <= self.max_abs,
                "value {v} exceeds the coder's magnitude limit {}",
                self.max_abs
            );
            out.put_gamma(m);
            out.put_bit(v < 0);
            return;
        }
        let (h1, w1) = (h.div_ceil(2), w.div_ceil(2));
        let quads = [
            (r0, c0, h1, w1),
            (r0, c0 + w1, h1, w - w1),
            (r0 + h1, c0, h - h1, w1),
        ];
        let last = (r0 + h1, c0 + w1, h - h1, w - w1);
        for (r, c, qh, qw) in quads.into_iter().chain([last]) {
            if qh == 0 || qw == 0 {
                continue;
            }
            let nz = self.any_nonzero(r, c, qh, qw);
            out.put_bit(nz);
            if nz {
                self.block(out, r, c, qh, qw);
            }
        }
    }
}

/// Bits the leaf table looks at: one flag bit plus gamma codes of up to 4 prefix zeros
/// (|v| < 32) and a sign bit, 2·4 + 3 = 11 bits.
const LEAF_BITS: u32 = 11;

/// For every 11-bit window starting at a leaf's flag bit: `(value << 8) | bit length` of the
/// whole leaf (flag, gamma code, sign), or 0 when the code is longer than the window.
static LEAF_LUT: [i32; 1 << LEAF_BITS] = build_leaf_lut();

const fn build_leaf_lut() -> [i32; 1 << LEAF_BITS] {
    let mut t = [0i32; 1 << LEAF_BITS];
    let mut i = 0usize;
    while i < t.len() {
        let flag = i >> (LEAF_BITS - 1);
        if flag == 0 {
            t[i] = 1; // value 0, one bit
        } else {
            let rest = (i & ((1 << (LEAF_BITS - 1)) - 1)) as u32; // 10 bits after the flag
            let k = (rest << (32 - (LEAF_BITS - 1))).leading_zeros();
            let len = 2 * k + 3;
            if len <= LEAF_BITS {
                let m = (rest >> (LEAF_BITS - 1 - (2 * k + 1))) & ((1 << (k + 1)) - 1);
                let neg = (rest >> (LEAF_BITS - 1 - (2 * k + 2))) & 1 == 1;
                let v = if neg { -(m as i32) } else { m as i32 };
                t[i] = (v << 8) | len as i32;
            }
        }
        i += 1;
    }
    t
}

/// Why a decode failed, kept small so the hot path returns it in registers.
#[derive(Clone, Copy, Debug)]
enum Fail {
    LongPrefix,
    TooLarge,
    EmptySplit,
}

/// Decodes one record written by [`encode_bands`] with the same band shapes.
pub(crate) fn decode_bands(
    bytes: &[u8],
    bands: &mut [BandMut<'_>],
    limits: DecodeLimits,
) -> Result<(), CodecError> {
    // Magnitudes above i32::MAX cannot be negated into an i32.
    let max_abs = limits.max_abs.min(i32::MAX as u32);
    let mut rd = BitReader::new(bytes);
    for (i, band) in bands.iter_mut().enumerate() {
        let (w, h) = (band.width, band.height);
        if w > MAX_BAND_SIDE || h > MAX_BAND_SIDE {
            return Err(CodecError::limit(format!(
                "band {i} of {w}×{h} is too large"
            )));
        }
        if band.values.len() != w * h {
            return Err(CodecError::invalid(
                "band buffer does not match its width × height",
            ));
        }
        if w == 0 || h == 0 {
            continue;
        }
        // Zero blocks are never visited, so clear first and write only flagged leaves.
        band.values.fill(0);
        if !rd.get_bit() {
            continue;
        }
        let mut d = Decoder {
            rd,
            out: band.values,
            stride: w,
            max_abs,
        };
        let res = if w == h && w.is_power_of_two() {
            d.square(0, w)
        } else {
            d.block(0, 0, h, w)
        };
        rd = d.rd;
        // Past the end the reader supplies zeros, which can look like any of these faults;
        // blame the truncation then.
        if rd.is_overrun() {
            return Err(truncated(i));
        }
        if let Err(f) = res {
            return Err(CodecError::corrupt(match f {
                Fail::LongPrefix => format!("band {i}: Elias-gamma prefix longer than 31 bits"),
                Fail::TooLarge => format!("band {i}: value magnitude above {max_abs}"),
                Fail::EmptySplit => format!("band {i}: non-zero block with only zero children"),
            }));
        }
    }
    if rd.is_overrun() {
        return Err(truncated(bands.len().saturating_sub(1)));
    }
    match rd.remaining_padding() {
        None => Err(CodecError::corrupt(format!(
            "{} trailing bits after the last band",
            rd.bits_total() - rd.bits_consumed()
        ))),
        Some((_, 0)) => Ok(()),
        Some(_) => Err(CodecError::corrupt(
            "non-zero padding bits after the last band",
        )),
    }
}

fn truncated(band: usize) -> CodecError {
    CodecError::truncated(format!("record ends inside band {band}"))
}

struct Decoder<'a, 'b> {
    rd: BitReader<'a>,
    out: &'b mut [i32],
    stride: usize,
    max_abs: u32,
}

impl Decoder<'_, '_> {
    /// Reads Elias-gamma magnitude and sign of a flagged 1×1 block.
    #[inline(always)]
    fn value(&mut self) -> Result<i32, Fail> {
        let m = self.rd.get_gamma(31).ok_or(Fail::LongPrefix)?;
        if m > self.max_abs {
            return Err(Fail::TooLarge);
        }
        // `m <= i32::MAX`, so the cast and the negation cannot overflow.
        Ok(if self.rd.get_bit() {
            -(m as i32)
        } else {
            m as i32
        })
    }

    /// Reads a 1×1 child of a flagged block: its flag and, if set, its value.
    #[inline(always)]
    fn leaf(&mut self) -> Result<i32, Fail> {
        self.rd.ensure(LEAF_BITS);
        let e = LEAF_LUT[self.rd.peek(LEAF_BITS) as usize];
        let len = (e & 0xFF) as u32;
        if len != 0 {
            self.rd.consume(len);
            let v = e >> 8;
            if v.unsigned_abs() > self.max_abs {
                return Err(Fail::TooLarge);
            }
            Ok(v)
        } else {
            // Only long codes miss the table, and those start with a set flag.
            self.rd.consume(1);
            self.value()
        }
    }

    /// Contents of a flagged block of at most 2×2 whose children are all 1×1.
    #[inline(always)]
    fn small(&mut self, base: usize, h: usize, w: usize) -> Result<(), Fail> {
        if h == 1 && w == 1 {
            self.out[base] = self.value()?;
            return Ok(());
        }
        let a = self.leaf()?;
        self.out[base] = a;
        let mut any = a;
        if w == 2 {
            let b = self.leaf()?;
            self.out[base + 1] = b;
            any |= b;
        }
        if h == 2 {
            let c = self.leaf()?;
            self.out[base + self.stride] = c;
            any |= c;
            if w == 2 {
                let d = self.leaf()?;
                self.out[base + self.stride + 1] = d;
                any |= d;
            }
        }
        if any == 0 {
            Err(Fail::EmptySplit)
        } else {
            Ok(())
        }
    }

    /// Contents of a flagged `s × s` block, `s` a power of two, starting at index `base`.
    fn square(&mut self, base: usize, s: usize) -> Result<(), Fail> {
        if s <= 2 {
            return self.small(base, s, s);
        }
        let half = s / 2;
        let mut any = false;
        for off in [0, half, half * self.stride, half * self.stride + half] {
            if self.rd.get_bit() {
                any = true;
                self.square(base + off, half)?;
            }
        }
        if any { Ok(()) } else { Err(Fail::EmptySplit) }
    }

    /// Contents of a flagged `h × w` block at row `r0`, column `c0`.
    fn block(&mut self, r0: usize, c0: usize, h: usize, w: usize) -> Result<(), Fail> {
        if h <= 2 && w <= 2 {
            return self.small(r0 * self.stride + c0, h, w);
        }
        let (h1, w1) = (h.div_ceil(2), w.div_ceil(2));
        let (h2, w2) = (h - h1, w - w1);
        let mut any = self.child(r0, c0, h1, w1)?;
        if w2 > 0 {
            any |= self.child(r0, c0 + w1, h1, w2)?;
        }
        if h2 > 0 {
            any |= self.child(r0 + h1, c0, h2, w1)?;
            if w2 > 0 {
                any |= self.child(r0 + h1, c0 + w1, h2, w2)?;
            }
        }
        if any { Ok(()) } else { Err(Fail::EmptySplit) }
    }

    #[inline(always)]
    fn child(&mut self, r0: usize, c0: usize, h: usize, w: usize) -> Result<bool, Fail> {
        if self.rd.get_bit() {
            self.block(r0, c0, h, w)?;
            Ok(true)
        } else {
            Ok(false)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::entropy::BandKind;

    fn enc(shapes: &[(usize, usize, &[i32])]) -> Vec<u8> {
        let bands: Vec<Band<'_>> = shapes
            .iter()
            .map(|&(width, height, values)| Band {
                kind: BandKind::Cells,
                width,
                height,
                values,
            })
            .collect();
        let mut out = Vec::new();
        encode_bands(&bands, &mut out);
        out
    }

    fn dec(bytes: &[u8], shapes: &[(usize, usize)]) -> Result<Vec<Vec<i32>>, CodecError> {
        dec_lim(bytes, shapes, DecodeLimits::default())
    }

    fn dec_lim(
        bytes: &[u8],
        shapes: &[(usize, usize)],
        limits: DecodeLimits,
    ) -> Result<Vec<Vec<i32>>, CodecError> {
        let mut bufs: Vec<Vec<i32>> = shapes.iter().map(|&(w, h)| vec![7; w * h]).collect();
        let mut bands: Vec<BandMut<'_>> = bufs
            .iter_mut()
            .zip(shapes)
            .map(|(v, &(width, height))| BandMut {
                kind: BandKind::Cells,
                width,
                height,
                values: v,
            })
            .collect();
        decode_bands(bytes, &mut bands, limits)?;
        Ok(bufs)
    }

    /// Hand-derived encodings: (width, height, values) and the expected bytes.
    #[test]
    fn hand_computed_examples() {
        let zeros = vec![0; 64 * 64];
        // One "block is zero" bit, padded to a byte.
        assert_eq!(enc(&[(64, 64, &zeros)]), [0x00]);
        // flag 1, gamma(3) = 0 11, sign 1: 1011_1 + 000 padding.
        assert_eq!(enc(&[(1, 1, &[-3])]), [0b1011_1000]);
        // flag 1, gamma(1) = 1, sign 0: 110 + padding.
        assert_eq!(enc(&[(1, 1, &[1])]), [0b1100_0000]);
        // 2×2 [0 5; 0 0]: 1 | TL 0 | TR 1 00101 0 | BL 0 | BR 0 = 1010_0101 000 + padding.
        assert_eq!(enc(&[(2, 2, &[0, 5, 0, 0])]), [0b1010_0101, 0b0000_0000]);
        // 1 wide, 3 high [0; 2; 0]: rows split at 2. 1 | top 2×1: 1 | 0 | 1 010 0 | bottom 0
        // = 1101_0100 0 + padding.
        assert_eq!(enc(&[(1, 3, &[0, 2, 0])]), [0b1101_0100, 0b0000_0000]);
        // 3 wide, 1 high [0 0 -1]: columns split at 2. 1 | left 1×2: 0 | right: 1 1 1.
        assert_eq!(enc(&[(3, 1, &[0, 0, -1])]), [0b1011_1000]);
        // Two bands share the stream: 0 | 1 011 1 = 0101_1100.
        assert_eq!(enc(&[(64, 64, &zeros), (1, 1, &[-3])]), [0b0101_1100]);
        // Zero-size bands write nothing.
        assert_eq!(enc(&[(0, 5, &[]), (7, 0, &[])]), Vec::<u8>::new());
        // Largest magnitude: flag, 29 zeros, 30 ones, sign 0, three padding bits = 8 bytes.
        let max = DecodeLimits::default().max_abs as i32;
        let want = (1u64 << 63) | (((1u64 << 30) - 1) << 4);
        assert_eq!(enc(&[(1, 1, &[max])]), want.to_be_bytes());
        // Same, negative: the sign bit is bit 3.
        assert_eq!(enc(&[(1, 1, &[-max])]), (want | 8).to_be_bytes());
    }

    #[test]
    fn hand_computed_examples_decode() {
        assert_eq!(dec(&[0x00], &[(64, 64)]).unwrap(), [vec![0; 4096]]);
        assert_eq!(dec(&[0b1011_1000], &[(1, 1)]).unwrap(), [vec![-3]]);
        assert_eq!(
            dec(&[0b1010_0101, 0], &[(2, 2)]).unwrap(),
            [vec![0, 5, 0, 0]]
        );
        assert_eq!(dec(&[0b1101_0100, 0], &[(1, 3)]).unwrap(), [vec![0, 2, 0]]);
        assert_eq!(dec(&[0b1011_1000], &[(3, 1)]).unwrap(), [vec![0, 0, -1]]);
        assert_eq!(dec(&[], &[(0, 5), (7, 0)]).unwrap(), [vec![], vec![]]);
    }

    #[test]
    fn rejects_what_no_encoder_writes() {
        let corrupt =
            |r: Result<Vec<Vec<i32>>, CodecError>| matches!(r, Err(CodecError::Corrupt(_)));
        // 2×2 block flagged but all four children zero: 1 0000 + padding.
        assert!(corrupt(dec(&[0b1000_0000], &[(2, 2)])));
        // Same for a 4×4 (the power-of-two path) and a 3×3 (the general path).
        assert!(corrupt(dec(&[0b1000_0000], &[(4, 4)])));
        assert!(corrupt(dec(&[0b1000_0000], &[(3, 3)])));
        // Gamma prefix of 32 zeros after the flag.
        assert!(corrupt(dec(&[0x80, 0, 0, 0, 0b0100_0000], &[(1, 1)])));
        // A trailing zero byte, and non-zero padding.
        assert!(corrupt(dec(&[0b1011_1000, 0], &[(1, 1)])));
        assert!(corrupt(dec(&[0b1011_1001], &[(1, 1)])));
        // An all-zero band followed by a spare byte.
        assert!(corrupt(dec(&[0, 0], &[(64, 64)])));
        // Bytes for bands that have no samples.
        assert!(corrupt(dec(&[0], &[(0, 0)])));
    }

    #[test]
    fn enforces_max_abs_on_table_and_slow_paths() {
        let lim = DecodeLimits { max_abs: 2 };
        for (v, ok) in [
            (2, true),
            (-2, true),
            (3, false),
            (-3, false),
            (1000, false),
        ] {
            for (w, h) in [(1, 1), (2, 2), (4, 4), (3, 2)] {
                let mut vals = vec![0; w * h];
                *vals.last_mut().unwrap() = v;
                let bytes = enc(&[(w, h, &vals)]);
                let r = dec_lim(&bytes, &[(w, h)], lim);
                if ok {
                    assert_eq!(r.unwrap(), [vals]);
                } else {
                    assert!(matches!(r, Err(CodecError::Corrupt(_))), "{v} in {w}×{h}");
                }
            }
        }
    }

    #[test]
    fn leaf_table_agrees_with_bit_reader() {
        for i in 0..(1u32 << LEAF_BITS) {
            let bytes = (i << (32 - LEAF_BITS)).to_be_bytes();
            let mut r = BitReader::new(&bytes);
            let e = LEAF_LUT[i as usize];
            let len = (e & 0xFF) as u32;
            if !r.get_bit() {
                assert_eq!((e >> 8, len), (0, 1));
                continue;
            }
            let Some(m) = r.get_gamma(31) else {
                assert_eq!(
                    len, 0,
                    "index {i:#b} has no complete code and should escape"
                );
                continue;
            };
            let neg = r.get_bit();
            if r.bits_consumed() as u32 > LEAF_BITS {
                assert_eq!(len, 0, "index {i:#b} should escape");
            } else {
                let v = if neg { -(m as i32) } else { m as i32 };
                assert_eq!((e >> 8, len), (v, r.bits_consumed() as u32), "index {i:#b}");
            }
        }
    }
}
