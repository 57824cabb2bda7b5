//! Heights as the quantizer takes them: a whole grid in memory ([`Dem`]) or rows streamed in
//! blocks ([`SampleSource`]), with the type they were stored as ([`SampleType`]) and the value
//! quantum they were rounded to ([`detect_quantum`]). Reading them from files is the builder's
//! (`cbdam-builder`'s `input`).

mod quantum;

use crate::CodecError;
use crate::repository::GeoRef;

pub use quantum::{QuantumScan, detect_quantum};

/// The numeric type a DEM's samples were stored as.
///
/// Integer types mean every sample is an exact integer; the float types say which precision the
/// values were rounded to, which is what [`detect_quantum`] has to respect.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SampleType {
    /// Signed 8-bit integers.
    I8,
    /// Unsigned 8-bit integers.
    U8,
    /// Signed 16-bit integers (SRTM, most national DEMs).
    I16,
    /// Unsigned 16-bit integers.
    U16,
    /// Signed 32-bit integers.
    I32,
    /// Unsigned 32-bit integers.
    U32,
    /// IEEE single precision.
    F32,
    /// IEEE double precision; also used for heights derived from integer codes by a scale, whose
    /// exactly-rounded decimal value only an `f64` holds.
    F64,
}

impl SampleType {
    /// Bytes a sample of this type takes.
    pub fn bytes(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }

    /// Whether every sample of this type is an integer.
    pub fn is_integer(self) -> bool {
        !matches!(self, Self::F32 | Self::F64)
    }
}

/// A digital elevation model as read from a file.
#[derive(Clone, Debug)]
pub struct Dem {
    /// Number of columns.
    pub width: usize,
    /// Number of rows.
    pub height: usize,
    /// Row-major heights, row 0 = north edge; exact copies of the stored samples.
    pub values: Vec<f64>,
    /// The type the samples were stored as.
    pub sample_type: SampleType,
    /// The value that marks a missing sample, from the file or the reader's options.
    pub nodata: Option<f64>,
    /// Georeferencing, when the file carries it.
    pub georef: Option<GeoRef>,
}

impl Dem {
    /// Whether sample `i` holds a height: it is neither the nodata value nor NaN.
    pub fn is_valid(&self, i: usize) -> bool {
        let v = self.values[i];
        !v.is_nan() && self.nodata != Some(v)
    }

    /// Smallest and largest valid height, or `None` if no sample holds one.
    pub fn valid_range(&self) -> Option<(f64, f64)> {
        let (lo, hi) = (0..self.values.len())
            .filter(|&i| self.is_valid(i))
            .map(|i| self.values[i])
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
                (lo.min(v), hi.max(v))
            });
        (lo <= hi).then_some((lo, hi))
    }

    /// Number of samples that hold a height.
    pub fn valid_count(&self) -> usize {
        (0..self.values.len()).filter(|&i| self.is_valid(i)).count()
    }

    /// The `width × height` window whose north-west sample is `(x0, y0)`, georeferencing moved
    /// to the window's origin.
    pub fn crop(
        &self,
        x0: usize,
        y0: usize,
        width: usize,
        height: usize,
    ) -> Result<Dem, CodecError> {
        let fits =
            |o: usize, len: usize, total: usize| o.checked_add(len).is_some_and(|end| end <= total);
        if width == 0
            || height == 0
            || !fits(x0, width, self.width)
            || !fits(y0, height, self.height)
        {
            return Err(CodecError::invalid(format!(
                "window {width}×{height} at ({x0}, {y0}) does not fit a {}×{} grid",
                self.width, self.height
            )));
        }
        let values = (y0..y0 + height)
            .flat_map(|y| {
                self.values[y * self.width + x0..y * self.width + x0 + width]
                    .iter()
                    .copied()
            })
            .collect();
        let georef = self.georef.clone().map(|g| GeoRef {
            origin_x: g.origin_x + x0 as f64 * g.pixel_x,
            origin_y: g.origin_y - y0 as f64 * g.pixel_y,
            ..g
        });
        Ok(Dem {
            width,
            height,
            values,
            georef,
            ..self.clone()
        })
    }
}

/// What a pass calls on each block: `(first_row, samples)`.
pub type BlockFn<'a> = dyn FnMut(usize, &[f64]) -> Result<(), CodecError> + 'a;

/// Rows of samples in passes: each pass calls `f(first_row, samples)` on consecutive blocks of
/// whole rows that together cover the grid, north to south, samples row-major.
pub trait SampleSource: Sync {
    /// Columns.
    fn width(&self) -> usize;
    /// Rows.
    fn height(&self) -> usize;
    /// The type the samples are stored as.
    fn sample_type(&self) -> SampleType;
    /// The value marking a missing sample.
    fn nodata(&self) -> Option<f64>;
    /// One pass over the samples.
    fn for_each_block(&self, f: &mut BlockFn<'_>) -> Result<(), CodecError>;
}

impl SampleSource for Dem {
    fn width(&self) -> usize {
        self.width
    }
    fn height(&self) -> usize {
        self.height
    }
    fn sample_type(&self) -> SampleType {
        self.sample_type
    }
    fn nodata(&self) -> Option<f64> {
        self.nodata
    }
    fn for_each_block(&self, f: &mut BlockFn<'_>) -> Result<(), CodecError> {
        f(0, &self.values)
    }
}
