//! Where one input lies on the mosaic's lattice, and how its rows are read.

use crate::band_cache::Samples;
use crate::error::{Context, Result, bail};
use crate::input::TileReader;
use cbdam_codec::samples::SampleType;
use std::path::PathBuf;

/// Where one input lies on the lattice, and how its rows are read.
#[derive(Debug)]
pub struct Placement {
    /// The file.
    pub path: PathBuf,
    /// Lattice column of its first sample.
    pub x0: usize,
    /// Lattice row of its first sample.
    pub y0: usize,
    /// Its stride in lattice points, `2^log2`.
    pub log2: u8,
    /// Samples per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// The type its samples are stored as.
    pub sample_type: SampleType,
    /// Its nodata value (the override, a VRT's, else the file's).
    pub nodata: Option<f64>,
    /// Header read; rows decoded on demand.
    pub(super) reader: TileReader,
    /// Rows per band of decoded samples ([`TileReader::band_rows`]).
    pub(super) band_rows: usize,
}

impl Placement {
    pub(super) fn stride(&self) -> usize {
        1 << self.log2
    }

    /// The last lattice row and column its samples reach.
    pub(super) fn last_row(&self) -> usize {
        self.y0 + (self.height - 1) * self.stride()
    }

    pub(super) fn last_col(&self) -> usize {
        self.x0 + (self.width - 1) * self.stride()
    }

    /// Whether `v` is a height ([`cbdam_codec::samples::Dem::is_valid`]).
    #[inline]
    pub(super) fn is_valid(&self, v: f64) -> bool {
        !v.is_nan() && self.nodata != Some(v)
    }

    /// Its rows with a sample on lattice rows `ya..yb`.
    pub(super) fn rows_on(&self, ya: usize, yb: usize) -> std::ops::Range<usize> {
        let s = self.stride();
        let lo = ya.saturating_sub(self.y0).div_ceil(s);
        let hi = if yb <= self.y0 {
            0
        } else {
            ((yb - 1 - self.y0) / s + 1).min(self.height)
        };
        lo..hi.max(lo)
    }

    /// Its rows bounding the cells that lattice rows `ya..yb` cross (one more on each side than
    /// [`Placement::rows_on`]): what [`COARSE_ONLY`] points are drawn from.
    pub(super) fn rows_around(&self, ya: usize, yb: usize) -> std::ops::Range<usize> {
        if yb <= self.y0 || ya > self.last_row() {
            return 0..0;
        }
        let s = self.stride();
        let lo = (ya.saturating_sub(self.y0) / s).saturating_sub(1);
        let hi = ((yb - 1 - self.y0) / s + 2).min(self.height);
        lo..hi
    }

    /// Reads band `band` of its rows, narrowed ([`Samples::compact`]).
    pub(super) fn read_band(&self, band: usize) -> Result<Samples> {
        let r0 = band * self.band_rows;
        let r1 = (r0 + self.band_rows).min(self.height);
        let mut values = Vec::new();
        self.reader
            .read_rows(r0..r1, &mut values)
            .with_context(|| format!("reading {}", self.path.display()))?;
        if values.len() != (r1 - r0) * self.width {
            bail!(
                "reading {}: rows {r0}..{r1} came back as {} samples, not {} × {}",
                self.path.display(),
                values.len(),
                r1 - r0,
                self.width
            );
        }
        Ok(Samples::compact(values))
    }
}
