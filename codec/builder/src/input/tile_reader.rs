//! A DEM opened from its header alone, whose rows are decoded when asked for: what a mosaic of
//! thousands of tiles needs to place them all before reading any, and to read each only where
//! the build has reached.
//!
//! GeoTIFF tiles read their tags ([`GeoTiffSource::open`]) and decode only the strips or tiles
//! that cover the rows asked for; SRTM `.hgt` tiles take their size from the file's length and
//! their position from its name, and read rows by seeking. Other formats (ASCII grids, whose
//! sample type depends on every value, and PNG) are read whole when opened and again when their
//! rows are asked for: their band is the whole file.

use std::ops::Range;
use std::path::{Path, PathBuf};

use super::{Dem, Format, GeoRef, GeoTiffSource, ReadOptions, SampleType};
use cbdam_codec::CodecError;
use cbdam_codec::samples::SampleSource;

/// Samples a band of rows of a tile should hold at least (see [`TileReader::band_rows`]): large
/// enough that reading one amortises opening the file, small next to the build's memory.
const BAND_SAMPLES: usize = 1 << 18;

/// How a tile's rows are read.
enum Rows {
    GeoTiff(Box<GeoTiffSource>),
    Hgt,
    /// Read whole (with these options) whenever rows are asked for.
    Whole(ReadOptions),
}

/// A DEM whose header has been read and checked, and whose samples are read by rows on demand.
pub struct TileReader {
    path: PathBuf,
    /// Size, sample type, nodata value and georeferencing; `values` is empty.
    header: Dem,
    rows: Rows,
}

impl std::fmt::Debug for TileReader {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TileReader")
            .field("path", &self.path)
            .field("width", &self.header.width)
            .field("height", &self.header.height)
            .finish()
    }
}

impl TileReader {
    /// Opens `path` like [`super::read_dem`] would read it (same format detection, nodata
    /// override and `.prj` sidecar), decoding no sample of a GeoTIFF or `.hgt` tile.
    ///
    /// # Errors
    /// As [`super::read_dem`], for what the header holds.
    pub fn open(path: &Path, opts: &ReadOptions) -> Result<Self, CodecError> {
        cbdam_codec::files::check_regular_file(path)?;
        let format = match opts.format {
            Some(f) => f,
            None => super::detect_format(path)?,
        };
        let (mut header, rows) = match format {
            Format::GeoTiff => {
                let src = GeoTiffSource::open(path, opts.nodata, &opts.limits)?;
                let header = Dem {
                    width: src.width(),
                    height: src.height(),
                    values: Vec::new(),
                    sample_type: src.sample_type(),
                    nodata: src.nodata(),
                    georef: src.georef().cloned(),
                };
                (header, Rows::GeoTiff(Box::new(src)))
            }
            Format::Hgt => (super::hgt::read_header(path, &opts.limits)?, Rows::Hgt),
            _ => {
                let whole = ReadOptions {
                    format: Some(format),
                    ..opts.clone()
                };
                let mut dem = super::read_dem(path, &whole)?;
                dem.values = Vec::new();
                (dem, Rows::Whole(whole))
            }
        };
        if opts.nodata.is_some() {
            header.nodata = opts.nodata;
        }
        super::check_nodata(header.nodata, path)?;
        header.georef = super::with_sidecar_crs(header.georef, path)?;
        Ok(Self {
            path: path.to_path_buf(),
            header,
            rows,
        })
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Columns.
    pub fn width(&self) -> usize {
        self.header.width
    }

    /// Rows.
    pub fn height(&self) -> usize {
        self.header.height
    }

    /// The type the samples are stored as.
    pub fn sample_type(&self) -> SampleType {
        self.header.sample_type
    }

    /// The value marking a missing sample (the override, else the file's).
    pub fn nodata(&self) -> Option<f64> {
        self.header.nodata
    }

    /// Georeferencing, when the file carries it.
    pub fn georef(&self) -> Option<&GeoRef> {
        self.header.georef.as_ref()
    }

    /// Rows a band should hold so that reading bands decodes each stored chunk once and
    /// amortises opening the file: a multiple of the GeoTIFF's strip or tile height of at least
    /// `BAND_SAMPLES` samples (or the whole image), and the whole file for formats read whole.
    pub fn band_rows(&self) -> usize {
        let (w, h) = (self.header.width.max(1), self.header.height.max(1));
        let wanted = BAND_SAMPLES.div_ceil(w);
        let rows = match &self.rows {
            Rows::GeoTiff(src) => wanted.div_ceil(src.chunk_rows()) * src.chunk_rows(),
            Rows::Hgt => wanted,
            Rows::Whole(_) => h,
        };
        rows.clamp(1, h)
    }

    /// Rows `rows` into `out` (replacing its contents), row-major, as [`super::read_dem`] would
    /// give them.
    ///
    /// # Errors
    /// Decoding errors (naming the chunk), a file that changed since it was opened, rows outside
    /// the image.
    pub fn read_rows(&self, rows: Range<usize>, out: &mut Vec<f64>) -> Result<(), CodecError> {
        match &self.rows {
            Rows::GeoTiff(src) => src.read_rows(rows, out),
            Rows::Hgt => super::hgt::read_rows(&self.path, self.header.width, rows, out),
            Rows::Whole(opts) => {
                let dem = super::read_dem(&self.path, opts)?;
                if (dem.width, dem.height) != (self.header.width, self.header.height) {
                    return Err(CodecError::corrupt(format!(
                        "{} changed while being read: now {} x {} samples, was {} x {}",
                        self.path.display(),
                        dem.width,
                        dem.height,
                        self.header.width,
                        self.header.height
                    )));
                }
                if rows.start >= rows.end || rows.end > dem.height {
                    return Err(CodecError::invalid(format!(
                        "rows {}..{} of a {}-row image",
                        rows.start, rows.end, dem.height
                    )));
                }
                out.clear();
                out.extend_from_slice(&dem.values[rows.start * dem.width..rows.end * dem.width]);
                Ok(())
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rows read in bands are the rows of the whole read, for GeoTIFFs, a PNG (read whole) and
    /// an `.hgt` tile; the header is the whole read's.
    #[test]
    fn bands_of_rows_equal_the_whole_read() {
        let data = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data");
        let tmp = tempfile::tempdir().unwrap();
        let hgt = tmp.path().join("N45E006.hgt");
        let side = 1201usize;
        let bytes: Vec<u8> = (0..side * side)
            .flat_map(|i| (((i * 7919) % 6000) as i16 - 500).to_be_bytes())
            .collect();
        std::fs::write(&hgt, bytes).unwrap();
        let mut paths = vec![hgt];
        for name in [
            "srtm3_demcompare.tif",
            "rhine_nodata.tif",
            "lidar1m_mn.tif",
            "fuji_terrainrgb.png",
        ] {
            paths.push(data.join(name));
        }
        for p in paths {
            let opts = ReadOptions::default();
            let whole = super::super::read_dem(&p, &opts).unwrap();
            let t = TileReader::open(&p, &opts).unwrap();
            assert_eq!((t.width(), t.height()), (whole.width, whole.height));
            assert_eq!(t.sample_type(), whole.sample_type);
            assert_eq!(t.nodata(), whole.nodata);
            assert_eq!(t.georef(), whole.georef.as_ref());
            // A PNG is read whole for every band: one band is enough.
            let whole_file = p.extension().is_some_and(|e| e == "png");
            let bands = if whole_file {
                vec![t.band_rows()]
            } else {
                vec![1, 7, t.band_rows()]
            };
            for band in bands {
                let mut got = Vec::new();
                let mut out = Vec::new();
                for r in (0..t.height()).step_by(band) {
                    t.read_rows(r..(r + band).min(t.height()), &mut out)
                        .unwrap();
                    got.extend_from_slice(&out);
                }
                assert!(
                    got.iter()
                        .zip(&whole.values)
                        .all(|(a, b)| a.to_bits() == b.to_bits())
                        && got.len() == whole.values.len(),
                    "{} in bands of {band} rows",
                    p.display()
                );
            }
            assert!(t.read_rows(0..t.height() + 1, &mut Vec::new()).is_err());
        }
    }
}
