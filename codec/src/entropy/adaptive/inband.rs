//! The grid-aware token coder with in-band prediction
//! ([`CoderKind::AdaptiveInBand`](crate::entropy::CoderKind::AdaptiveInBand)): each band's
//! indices `v` are coded as `v − p`, `p` an [`InBand`] prediction from the band's own decoded
//! neighbours and, for a diamond's cells, from its grid. The encoder tries the predictors on
//! each band and keeps the one whose band codes smallest; for a diamond's cells it also picks
//! whether the contexts see the grid ([`super::grid`]'s corner spread) or not (the token
//! coder's). The choice goes before the band in the raw stream ([`Choice`]); the rest is the
//! token record of [`super::tokens`]. Lossless on the indices: the reconstruction and the
//! error bound are the other coders'.

use super::Scratch;
use super::grid::{CellActivity, is_cells_of};
use super::tokens::{Activity, Flat, RecordDecoder, RecordEncoder, decode_record};
use super::{NCLASS, all_zero_checked};
use crate::CodecError;
use crate::entropy::secondary::{GridHints, InBand, PREDICTION_LIMIT, forward, inverse};
use crate::entropy::{Band, BandMut, DecodeLimits, ParentGrid};

#[cfg(test)]
#[path = "inband_tests.rs"]
mod tests;

/// The predictors a band may choose besides none, by the 3-bit number written for them.
const PREDICTED: [InBand; 8] = [
    InBand::LocalBest,
    InBand::Flatter,
    InBand::Median,
    InBand::HalfFlatter,
    InBand::HalfBilinear,
    InBand::HalfMean,
    InBand::NegHalfMean,
    InBand::MedianZero,
];

/// What is written before a band, in the raw stream: for a diamond's cells one bit, whether
/// the contexts see the grid; then one bit, whether the band is predicted, and if so 3 bits,
/// the predictor's number in [`PREDICTED`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Choice {
    grid_contexts: bool,
    predictor: InBand,
}

/// The largest magnitude the coder may be given: the limit every decoder enforces.
fn coder_limit() -> i64 {
    i64::from(DecodeLimits::default().max_abs)
}

/// Band `b` coded alone (fresh models) as `v − p` under `predictor`, in `context`: its bytes,
/// with the coded values in `trial`; `None` if a coded value would pass [`coder_limit`].
fn trial_bytes(
    b: &Band<'_>,
    predictor: InBand,
    hints: Option<&GridHints>,
    context: impl Activity,
    trial: &mut Vec<i32>,
) -> Option<usize> {
    let mut wide = Vec::new();
    forward(predictor, b.values, b.width, b.height, hints, &mut wide);
    if wide.iter().any(|v| v.abs() > coder_limit()) {
        return None;
    }
    trial.clear();
    trial.extend(wide.iter().map(|&v| v as i32));
    let mut record = RecordEncoder::<NCLASS>::new();
    record.band(
        &Band {
            values: trial,
            ..*b
        },
        context,
    );
    let mut out = Vec::new();
    record.finish(&mut out);
    Some(out.len())
}

/// The smallest trial so far: its bytes and choice, its coded values in `coded`.
struct Best<'a> {
    bytes: usize,
    choice: Choice,
    coded: &'a mut Vec<i32>,
}

impl Best<'_> {
    /// Keeps `choice` (coded values in `trial`) if its `bytes` are fewer.
    fn offer(&mut self, bytes: Option<usize>, choice: Choice, trial: &mut Vec<i32>) {
        if let Some(bytes) = bytes.filter(|&n| n < self.bytes) {
            (self.bytes, self.choice) = (bytes, choice);
            std::mem::swap(self.coded, trial);
        }
    }
}

/// The choice for band `b` whose cells' grid gives `on_grid` (hints and corner activity), and
/// its coded values in `coded`: every predictor with the grid's contexts, then the best one
/// and none with the token coder's.
fn choose(
    b: &Band<'_>,
    on_grid: Option<(&GridHints, &CellActivity)>,
    coded: &mut Vec<i32>,
) -> Choice {
    let mut trial = Vec::new();
    let none = Choice {
        grid_contexts: false,
        predictor: InBand::None,
    };
    let mut best = Best {
        bytes: usize::MAX,
        choice: none,
        coded,
    };
    let all = std::iter::once(InBand::None).chain(PREDICTED);
    let Some((hints, cells)) = on_grid else {
        for predictor in all {
            let bytes = trial_bytes(b, predictor, None, Flat, &mut trial);
            best.offer(bytes, Choice { predictor, ..none }, &mut trial);
        }
        return best.choice;
    };
    for predictor in all {
        let bytes = trial_bytes(b, predictor, Some(hints), cells.activity(), &mut trial);
        let choice = Choice {
            grid_contexts: true,
            predictor,
        };
        best.offer(bytes, choice, &mut trial);
    }
    for predictor in [InBand::None, best.choice.predictor] {
        let bytes = trial_bytes(b, predictor, Some(hints), Flat, &mut trial);
        best.offer(bytes, Choice { predictor, ..none }, &mut trial);
    }
    best.choice
}

/// Writes `choice` before a band (`cells`: a diamond's cells on their grid).
fn write_choice(record: &mut RecordEncoder<NCLASS>, choice: Choice, cells: bool) {
    if cells {
        record.raw_bits(choice.grid_contexts as u32, 1);
    }
    match PREDICTED.iter().position(|&p| p == choice.predictor) {
        Some(k) => record.raw_bits(0b1000 | k as u32, 4),
        None => record.raw_bits(0, 1),
    }
}

/// Reads what [`write_choice`] wrote.
fn read_choice(record: &mut RecordDecoder<'_, '_, NCLASS>, cells: bool) -> Choice {
    let grid_contexts = cells && record.raw_bits(1) != 0;
    let predictor = if record.raw_bits(1) != 0 {
        PREDICTED[record.raw_bits(3) as usize]
    } else {
        InBand::None
    };
    Choice {
        grid_contexts,
        predictor,
    }
}

/// Encodes `bands` as one record appended to `out`, the cell bands' hints and contexts from
/// `grid`.
pub(crate) fn encode_bands(bands: &[Band<'_>], grid: Option<ParentGrid<'_>>, out: &mut Vec<u8>) {
    if all_zero_checked(bands) {
        return;
    }
    let mut cells = CellActivity::default();
    let mut hints = GridHints::default();
    let mut record = RecordEncoder::<NCLASS>::new();
    let mut coded = Vec::new();
    for b in bands.iter().filter(|b| b.width > 0 && b.height > 0) {
        let on_grid = grid.filter(|g| is_cells_of(b.kind, b.width, b.height, g));
        if let Some(g) = &on_grid {
            cells.fill(g);
            hints.fill(g);
        }
        let choice = choose(b, on_grid.map(|_| (&hints, &cells)), &mut coded);
        write_choice(&mut record, choice, on_grid.is_some());
        let band = Band {
            values: &coded,
            ..*b
        };
        match choice.grid_contexts {
            true => record.band(&band, cells.activity()),
            false => record.band(&band, Flat),
        }
    }
    record.finish(out);
}

/// Decodes one record written by [`encode_bands`] with the same `grid` into `bands`.
pub(crate) fn decode_bands(
    bytes: &[u8],
    bands: &mut [BandMut<'_>],
    grid: Option<ParentGrid<'_>>,
    limits: DecodeLimits,
    s: &mut Scratch,
    cells: &mut CellActivity,
    hints: &mut GridHints,
) -> Result<(), CodecError> {
    // A coded value is the index less a prediction of at most PREDICTION_LIMIT.
    let coded_limits = DecodeLimits {
        max_abs: limits
            .max_abs
            .saturating_add(PREDICTION_LIMIT as u32)
            .min(DecodeLimits::default().max_abs),
    };
    decode_record::<NCLASS>(bytes, bands, s, |_, record, b| {
        if b.width == 0 || b.height == 0 {
            return Ok(());
        }
        let on_grid = grid.filter(|g| is_cells_of(b.kind, b.width, b.height, g));
        let choice = read_choice(record, on_grid.is_some());
        if let Some(g) = &on_grid {
            cells.fill(g);
            hints.fill(g);
        }
        match choice.grid_contexts {
            true => record.band(b, coded_limits, cells.activity())?,
            false => record.band(b, coded_limits, Flat)?,
        }
        let hints = on_grid.map(|_| &*hints);
        inverse(choice.predictor, b.values, b.width, b.height, hints);
        match b.values.iter().find(|v| v.unsigned_abs() > limits.max_abs) {
            Some(v) => Err(CodecError::corrupt(format!(
                "adaptive in-band: magnitude {} exceeds the limit {}",
                v.unsigned_abs(),
                limits.max_abs
            ))),
            None => Ok(()),
        }
    })
}
