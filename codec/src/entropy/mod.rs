//! Entropy coding of residual matrices ("bands") into records and back.
//!
//! A record is one byte string holding one or more bands, each a row-major `width × height`
//! matrix of `i32` quantizer indices. Three coders sit behind the same interface:
//! [`CoderKind::EliasGamma`], the paper's reference coder (quadtree of split bits, Elias-gamma
//! leaves, [`gamma`]); [`CoderKind::Adaptive`], a context-modelled adaptive binary arithmetic
//! coder with one decision per bit of each coefficient ([`adaptive`]); and
//! [`CoderKind::AdaptiveTokens`], the same quadtree and contexts with a binarisation made for
//! decoding speed (about 1 % larger; the default); and [`CoderKind::FastRice`], the same
//! quadtree and neighbourhood classes with static per-band Golomb–Rice codes instead of
//! arithmetic coding (larger, faster to decode); and [`CoderKind::AdaptiveGrid`], the token
//! coder with each cell's context also seeing the diamond's grid (the spread of the cell's
//! corners, [`ParentGrid`]); and [`CoderKind::AdaptiveInBand`], that coder on each band's indices
//! less a prediction from their decoded neighbours in the band ([`secondary`]). A repository
//! records which one wrote it.

pub mod adaptive;
pub mod bitio;
pub mod gamma;
pub mod references;
pub mod secondary;

use crate::CodecError;

/// Which entropy coder wrote a record.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum CoderKind {
    /// Quadtree with one bit per split and Elias-gamma coded leaves (paper §5).
    EliasGamma = 0,
    /// Context-modelled adaptive binary arithmetic coding, one decision per bit of each
    /// coefficient's binarisation.
    Adaptive = 1,
    /// The same contexts with a binarisation made for decoding speed: a 3-level token tree
    /// on the magnitude's high bits, its low bits and the signs in a separate raw stream.
    AdaptiveTokens = 2,
    /// Golomb–Rice codes whose parameter a per-band table picks by neighbourhood class, no
    /// arithmetic coding: larger files, shorter decode chain.
    FastRice = 3,
    /// The token coder with one more context for cells: the spread of the cell's four corners
    /// on the diamond's grid, which the decoder has before the record ([`ParentGrid`]).
    AdaptiveGrid = 4,
    /// [`CoderKind::AdaptiveGrid`] with each band's indices predicted from their decoded
    /// neighbours in the band, the predictor chosen per band ([`secondary`]).
    AdaptiveInBand = 5,
}

impl CoderKind {
    /// Every coder, for tests and benchmarks.
    pub const ALL: [CoderKind; 6] = [
        CoderKind::EliasGamma,
        CoderKind::Adaptive,
        CoderKind::AdaptiveTokens,
        CoderKind::FastRice,
        CoderKind::AdaptiveGrid,
        CoderKind::AdaptiveInBand,
    ];

    /// The byte stored in a repository header.
    pub fn to_byte(self) -> u8 {
        self as u8
    }

    /// Parses the byte stored in a repository header.
    pub fn from_byte(b: u8) -> Result<Self, CodecError> {
        match b {
            0 => Ok(Self::EliasGamma),
            1 => Ok(Self::Adaptive),
            2 => Ok(Self::AdaptiveTokens),
            3 => Ok(Self::FastRice),
            4 => Ok(Self::AdaptiveGrid),
            5 => Ok(Self::AdaptiveInBand),
            _ => Err(CodecError::corrupt(format!("unknown entropy coder id {b}"))),
        }
    }

    /// A short human-readable name.
    pub fn name(self) -> &'static str {
        match self {
            Self::EliasGamma => "elias-gamma",
            Self::Adaptive => "adaptive",
            Self::AdaptiveTokens => "adaptive-tokens",
            Self::FastRice => "fast-rice",
            Self::AdaptiveGrid => "adaptive-grid",
            Self::AdaptiveInBand => "adaptive-inband",
        }
    }
}

/// What a band holds; coders may use it to pick context models.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BandKind {
    /// Cell-centre residuals ΔC of one diamond refinement, `(N−1)²`.
    Cells,
    /// Inner-vertex residuals ΔV of one refinement (only when α < 1), `(N−2)²`.
    Vertices,
    /// The quantized prediction residuals of the root height field.
    Roots,
}

/// A band to encode.
#[derive(Clone, Copy, Debug)]
pub struct Band<'a> {
    /// What the values are.
    pub kind: BandKind,
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Row-major values, `width * height` of them.
    pub values: &'a [i32],
}

/// A band to decode into.
#[derive(Debug)]
pub struct BandMut<'a> {
    /// What the values are.
    pub kind: BandKind,
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Row-major output, `width * height` of them; fully overwritten on success.
    pub values: &'a mut [i32],
}

/// Bounds a decoder enforces, so that hostile bytes cannot make it produce values that later
/// arithmetic would overflow on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DecodeLimits {
    /// Largest magnitude a decoded value may have; larger ones are [`CodecError::Corrupt`].
    pub max_abs: u32,
}

impl Default for DecodeLimits {
    fn default() -> Self {
        // Encoders never write more than this (values are i32 and we keep a bit of headroom);
        // the decoder rejects anything larger as corrupt.
        Self {
            max_abs: (1 << 30) - 1,
        }
    }
}

/// The grid a diamond's cell band refines, which the decoder has before it decodes the
/// diamond's record: coders whose contexts look at it ([`CoderKind::AdaptiveGrid`]) need the
/// same grid on both sides; the others ignore it.
#[derive(Clone, Copy, Debug)]
pub struct ParentGrid<'a> {
    /// The diamond's `n × n` grid, row-major: the corners of the `(n − 1)²` cells, whose band
    /// is `(n − 1) × (n − 1)`.
    pub values: &'a [i32],
    /// Grid side.
    pub n: usize,
    /// The quantizer's step in lattice units (values below 1 are taken as 1).
    pub step: i32,
}

impl ParentGrid<'_> {
    /// Whether the grid is `n × n` and every cell band of `shapes` (kind, width, height) is
    /// `(n − 1) × (n − 1)`.
    fn fits(&self, mut shapes: impl Iterator<Item = (BandKind, usize, usize)>) -> bool {
        self.values.len() == self.n * self.n
            && shapes
                .all(|(kind, w, h)| kind != BandKind::Cells || (w + 1, h + 1) == (self.n, self.n))
    }
}

/// Largest band dimension any coder accepts (root fields of huge datasets are the largest bands).
pub const MAX_BAND_SIDE: usize = 1 << 20;

/// Encodes `bands` into one record appended to `out`.
///
/// # Panics
/// If a band's `values.len() != width * height`, a side exceeds [`MAX_BAND_SIDE`], or a value's
/// magnitude exceeds `DecodeLimits::default().max_abs` — all caller bugs, not data errors (the
/// decoder refuses such bands, so writing one would produce an undecodable record).
pub fn encode_bands(kind: CoderKind, bands: &[Band<'_>], out: &mut Vec<u8>) {
    encode_bands_on_grid(kind, bands, None, out);
}

/// [`encode_bands`] for the cells of a diamond whose grid is `grid` (`None`: not known, as for
/// root fields; the decoder must then be given `None` too).
///
/// # Panics
/// As [`encode_bands`], and if `grid` does not fit the bands ([`ParentGrid`]).
pub fn encode_bands_on_grid(
    kind: CoderKind,
    bands: &[Band<'_>],
    grid: Option<ParentGrid<'_>>,
    out: &mut Vec<u8>,
) {
    if let Some(g) = &grid {
        assert!(
            g.fits(bands.iter().map(|b| (b.kind, b.width, b.height))),
            "the grid does not fit the cell band"
        );
    }
    for b in bands {
        assert!(
            b.width <= MAX_BAND_SIDE && b.height <= MAX_BAND_SIDE,
            "band of {}×{} exceeds the {MAX_BAND_SIDE} side limit",
            b.width,
            b.height
        );
        assert_eq!(b.values.len(), b.width * b.height, "band size mismatch");
    }
    match kind {
        CoderKind::EliasGamma => gamma::encode_bands(bands, out),
        CoderKind::Adaptive => adaptive::encode_bands(bands, out),
        CoderKind::AdaptiveTokens => adaptive::tokens::encode_bands(bands, out),
        CoderKind::FastRice => adaptive::rice::encode_bands(bands, out),
        CoderKind::AdaptiveGrid => adaptive::grid::encode_bands(bands, grid, out),
        CoderKind::AdaptiveInBand => adaptive::inband::encode_bands(bands, grid, out),
    }
}

/// Working memory of [`decode_bands_with`], kept between records so that decoding one does not
/// allocate. Holds no state that affects a result: any scratch decodes any record the same.
#[derive(Debug, Default)]
pub struct DecodeScratch {
    adaptive: adaptive::Scratch,
    cells: adaptive::grid::CellActivity,
    hints: secondary::GridHints,
}

/// Decodes one record written by [`encode_bands`] with the same band shapes.
///
/// Never panics on any input bytes: garbage gives [`CodecError::Corrupt`] or
/// [`CodecError::Truncated`]. Trailing bytes beyond what the bands need are an error as well
/// (beyond the final partial byte / coder flush).
pub fn decode_bands(
    kind: CoderKind,
    bytes: &[u8],
    bands: &mut [BandMut<'_>],
    limits: DecodeLimits,
) -> Result<(), CodecError> {
    decode_bands_with(kind, bytes, bands, limits, &mut DecodeScratch::default())
}

/// [`decode_bands`] with working memory reused from earlier calls.
pub fn decode_bands_with(
    kind: CoderKind,
    bytes: &[u8],
    bands: &mut [BandMut<'_>],
    limits: DecodeLimits,
    scratch: &mut DecodeScratch,
) -> Result<(), CodecError> {
    decode_bands_on_grid_with(kind, bytes, bands, None, limits, scratch)
}

/// [`decode_bands_with`] for a record written by [`encode_bands_on_grid`] with `grid`.
pub fn decode_bands_on_grid_with(
    kind: CoderKind,
    bytes: &[u8],
    bands: &mut [BandMut<'_>],
    grid: Option<ParentGrid<'_>>,
    limits: DecodeLimits,
    scratch: &mut DecodeScratch,
) -> Result<(), CodecError> {
    if let Some(g) = &grid
        && !g.fits(bands.iter().map(|b| (b.kind, b.width, b.height)))
    {
        return Err(CodecError::invalid(
            "the diamond's grid does not fit its cell band",
        ));
    }
    for b in bands.iter() {
        if b.width > MAX_BAND_SIDE || b.height > MAX_BAND_SIDE {
            return Err(CodecError::limit(format!(
                "band of {}×{} exceeds the {MAX_BAND_SIDE} side limit",
                b.width, b.height
            )));
        }
        if b.values.len() != b.width * b.height {
            return Err(CodecError::invalid(
                "band buffer does not match its width × height",
            ));
        }
    }
    match kind {
        CoderKind::EliasGamma => gamma::decode_bands(bytes, bands, limits),
        CoderKind::Adaptive => adaptive::decode_bands(bytes, bands, limits, &mut scratch.adaptive),
        CoderKind::AdaptiveTokens => {
            adaptive::tokens::decode_bands(bytes, bands, limits, &mut scratch.adaptive)
        }
        CoderKind::FastRice => {
            adaptive::rice::decode_bands(bytes, bands, limits, &mut scratch.adaptive)
        }
        CoderKind::AdaptiveGrid => adaptive::grid::decode_bands(
            bytes,
            bands,
            grid,
            limits,
            &mut scratch.adaptive,
            &mut scratch.cells,
        ),
        CoderKind::AdaptiveInBand => adaptive::inband::decode_bands(
            bytes,
            bands,
            grid,
            limits,
            &mut scratch.adaptive,
            &mut scratch.cells,
            &mut scratch.hints,
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn empty_band(width: usize, height: usize) -> Band<'static> {
        Band {
            kind: BandKind::Roots,
            width,
            height,
            values: &[],
        }
    }

    #[test]
    fn bands_at_the_side_limit_round_trip() {
        // Zero-area bands keep the test cheap while exercising the side check at the limit.
        for kind in CoderKind::ALL {
            for (w, h) in [(MAX_BAND_SIDE, 0), (0, MAX_BAND_SIDE)] {
                let mut out = Vec::new();
                encode_bands(kind, &[empty_band(w, h)], &mut out);
                let mut bands = [BandMut {
                    kind: BandKind::Roots,
                    width: w,
                    height: h,
                    values: &mut [],
                }];
                decode_bands(kind, &out, &mut bands, DecodeLimits::default())
                    .unwrap_or_else(|e| panic!("{}: {w}×{h}: {e}", kind.name()));
            }
        }
    }

    #[test]
    #[should_panic(expected = "side limit")]
    fn encoding_a_band_wider_than_the_limit_is_a_caller_bug() {
        encode_bands(
            CoderKind::Adaptive,
            &[empty_band(MAX_BAND_SIDE + 1, 0)],
            &mut Vec::new(),
        );
    }

    #[test]
    #[should_panic(expected = "side limit")]
    fn encoding_a_band_taller_than_the_limit_is_a_caller_bug() {
        encode_bands(
            CoderKind::EliasGamma,
            &[empty_band(0, MAX_BAND_SIDE + 1)],
            &mut Vec::new(),
        );
    }
}
