//! Reading digital elevation models from the formats terrain usually comes in.
//!
//! Every reader produces the same [`Dem`]: a north-up, row-major grid of `f64` heights that are
//! exact copies of what the file stores, with the file's nodata value and georeferencing when it
//! has them. Deciding what to do with nodata or NaN samples, empty grids or odd sizes is left to
//! the builder; the readers only refuse inputs they cannot read faithfully.

mod ascii_grid;
pub mod geokeys;
mod geotiff;
mod geotiff_stream;
mod hgt;
mod png;
mod raw;
mod rgb;
mod stream;
mod tile_reader;

use std::path::Path;

use cbdam_codec::CodecError;
use cbdam_codec::files::check_regular_file;
use cbdam_codec::repository::{GeoRef, MAX_WKT_LEN};
use cbdam_codec::samples::{Dem, SampleType};

pub use geotiff_stream::GeoTiffSource;
pub use rgb::read_rgb;
pub use stream::RawF32Source;
pub use tile_reader::TileReader;

/// The file formats [`read_dem`] understands.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Format {
    /// GeoTIFF or plain TIFF, classic or BigTIFF, single band.
    GeoTiff,
    /// 16-bit grayscale PNG holding `offset + scale * value`.
    Png16 {
        /// Height units per stored count.
        scale: f64,
        /// Height of a stored zero.
        offset: f64,
    },
    /// Mapbox Terrain-RGB PNG: `-10000 + 0.1 * (R * 65536 + G * 256 + B)`.
    TerrainRgb,
    /// SRTM `.hgt` tile: big-endian `i16`, 1201 or 3601 samples square.
    Hgt,
    /// ESRI ASCII grid (`.asc`).
    AsciiGrid,
    /// Headerless little-endian `f32`, row-major, north-up.
    RawF32 {
        /// Number of columns.
        width: usize,
        /// Number of rows.
        height: usize,
    },
}

/// Resource bounds, checked against the declared size of an input before anything is allocated.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limits {
    /// Largest number of samples (width × height) a file may declare.
    pub max_samples: usize,
}

impl Default for Limits {
    fn default() -> Self {
        // 2^32 samples is a 65536² grid, already far more than fits in memory as f64 on most
        // machines; on 32-bit targets the address space is the tighter bound anyway.
        Self {
            max_samples: usize::try_from(1u64 << 32).unwrap_or(usize::MAX),
        }
    }
}

impl Limits {
    /// Checks a declared `width × height` against the bound, overflow included.
    pub fn check(&self, width: usize, height: usize) -> Result<usize, CodecError> {
        match width.checked_mul(height) {
            Some(n) if n <= self.max_samples => Ok(n),
            _ => Err(CodecError::limit(format!(
                "DEM of {width} x {height} samples exceeds the limit of {} samples",
                self.max_samples
            ))),
        }
    }
}

/// How [`read_dem`] should read a file.
#[derive(Clone, Debug, Default)]
pub struct ReadOptions {
    /// The file's format; `None` detects it from the extension, then from the leading bytes.
    pub format: Option<Format>,
    /// Nodata value to use instead of the file's own.
    pub nodata: Option<f64>,
    /// Resource bounds.
    pub limits: Limits,
}

/// Reads a DEM from `path`.
///
/// # Errors
/// [`CodecError::Io`] when the file cannot be read, [`CodecError::Truncated`] /
/// [`CodecError::Corrupt`] for damaged files, [`CodecError::Unsupported`] for well-formed files
/// using a feature no reader here implements (the message names it),
/// [`CodecError::LimitExceeded`] when the declared size exceeds [`Limits::max_samples`] and
/// [`CodecError::InvalidParameter`] when the format cannot be determined or the given format
/// does not fit the file.
pub fn read_dem(path: &Path, opts: &ReadOptions) -> Result<Dem, CodecError> {
    check_regular_file(path)?;
    let format = match opts.format {
        Some(f) => f,
        None => detect_format(path)?,
    };
    let mut dem = match format {
        Format::GeoTiff => geotiff_stream::read(path, &opts.limits)?,
        Format::Png16 { scale, offset } => png::read_png16(path, scale, offset, &opts.limits)?,
        Format::TerrainRgb => png::read_terrain_rgb(path, &opts.limits)?,
        Format::Hgt => hgt::read(path, &opts.limits)?,
        Format::AsciiGrid => ascii_grid::read(path, &opts.limits)?,
        Format::RawF32 { width, height } => raw::read_f32(path, width, height, &opts.limits)?,
    };
    if opts.nodata.is_some() {
        dem.nodata = opts.nodata;
    }
    check_nodata(dem.nodata, path)?;
    dem.georef = with_sidecar_crs(dem.georef, path)?;
    Ok(dem)
}

/// Refuses an infinite nodata value, the file's own or an override: a sample of ±inf is no
/// height, and consumers (extracts, GDAL) would meet the value as a height or mistake it for
/// overflow. NaN (or none) is how "no data" is said without a sentinel.
pub(crate) fn check_nodata(nodata: Option<f64>, path: &Path) -> Result<(), CodecError> {
    match nodata {
        Some(v) if v.is_infinite() => Err(CodecError::invalid(format!(
            "{}: the nodata value {v} is infinite; give a finite one (or NaN) with --nodata",
            path.display()
        ))),
        _ => Ok(()),
    }
}

/// The CRS definition (WKT) in an ESRI `.prj` file beside `path` — same name, extension `prj`
/// or `PRJ` —, if there is one. ASCII grids carry their CRS only there; GeoTIFFs whose CRS has
/// no EPSG code often come with one too.
///
/// # Errors
/// A `.prj` that cannot be read, is not UTF-8, is empty or is longer than [`MAX_WKT_LEN`].
pub fn sidecar_wkt(path: &Path) -> Result<Option<String>, CodecError> {
    let Some(prj) = ["prj", "PRJ"]
        .iter()
        .map(|e| path.with_extension(e))
        .find(|p| p.is_file())
    else {
        return Ok(None);
    };
    let bad = |why: String| CodecError::invalid(format!("CRS file {}: {why}", prj.display()));
    let len = std::fs::metadata(&prj)?.len();
    if len > MAX_WKT_LEN as u64 {
        return Err(bad(format!(
            "{len} bytes, more than the {MAX_WKT_LEN} a repository keeps"
        )));
    }
    let text =
        String::from_utf8(std::fs::read(&prj)?).map_err(|_| bad("not UTF-8 text".to_owned()))?;
    let wkt = text.trim();
    if wkt.is_empty() {
        return Err(bad("empty".to_owned()));
    }
    Ok(Some(wkt.to_owned()))
}

/// `georef` with the WKT of a `.prj` beside `path` ([`sidecar_wkt`]) when it has none yet.
/// Without georeferencing a CRS locates nothing, so it is not read.
pub fn with_sidecar_crs(georef: Option<GeoRef>, path: &Path) -> Result<Option<GeoRef>, CodecError> {
    Ok(match georef {
        Some(g) if g.wkt.is_none() => Some(GeoRef {
            wkt: sidecar_wkt(path)?,
            ..g
        }),
        other => other,
    })
}

/// Picks a format from the file name, falling back to the leading bytes when the extension is
/// unknown, so that e.g. a GeoTIFF saved without extension still reads.
///
/// # Errors
/// [`CodecError::InvalidParameter`] when neither tells (and for raw float32, which needs a size),
/// [`CodecError::Io`] when the file cannot be read.
pub fn detect_format(path: &Path) -> Result<Format, CodecError> {
    check_regular_file(path)?;
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("tif" | "tiff" | "gtif" | "gtiff") => return Ok(Format::GeoTiff),
        Some("hgt") => return Ok(Format::Hgt),
        Some("asc") => return Ok(Format::AsciiGrid),
        Some("png") => return png::detect(path),
        Some("raw" | "f32" | "bin") => {
            return Err(CodecError::invalid(format!(
                "{}: raw float32 files carry no size; give its width and height",
                path.display()
            )));
        }
        _ => {}
    }
    let mut head = [0u8; 16];
    let n = read_prefix(path, &mut head)?;
    let head = &head[..n];
    if head.starts_with(b"II*\0")
        || head.starts_with(b"MM\0*")
        || head.starts_with(b"II+\0")
        || head.starts_with(b"MM\0+")
    {
        return Ok(Format::GeoTiff);
    }
    if head.starts_with(b"\x89PNG\r\n\x1a\n") {
        return png::detect(path);
    }
    let text = String::from_utf8_lossy(head);
    if text.trim_start().to_ascii_lowercase().starts_with("ncols") {
        return Ok(Format::AsciiGrid);
    }
    Err(CodecError::invalid(format!(
        "{}: cannot tell the DEM format from the extension {} or the contents; set \
         ReadOptions::format",
        path.display(),
        ext.map_or_else(|| "(none)".to_string(), |e| format!("'.{e}'"))
    )))
}

/// Reads up to `buf.len()` leading bytes; fewer only at end of file.
fn read_prefix(path: &Path, buf: &mut [u8]) -> Result<usize, CodecError> {
    use std::io::Read;
    let mut f = std::fs::File::open(path)?;
    let mut n = 0;
    while n < buf.len() {
        match f.read(&mut buf[n..])? {
            0 => break,
            k => n += k,
        }
    }
    Ok(n)
}

/// The length of the file at `path`, in bytes.
fn file_len(path: &Path) -> Result<u64, CodecError> {
    Ok(std::fs::metadata(path)?.len())
}

#[cfg(test)]
mod sidecar_tests {
    use super::*;

    #[test]
    fn prj_sidecars_are_read_trimmed_and_bad_ones_refused_by_name() {
        let dir = tempfile::tempdir().unwrap();
        let dem = dir.path().join("a.asc");
        assert_eq!(sidecar_wkt(&dem).unwrap(), None);
        std::fs::write(dir.path().join("a.PRJ"), " GEOGCS[\"x\"]\r\n").unwrap();
        assert_eq!(sidecar_wkt(&dem).unwrap().as_deref(), Some("GEOGCS[\"x\"]"));
        // Only georeferenced inputs take one, and a WKT already there is kept.
        assert_eq!(with_sidecar_crs(None, &dem).unwrap(), None);
        let g = GeoRef {
            epsg: None,
            origin_x: 0.0,
            origin_y: 0.0,
            pixel_x: 1.0,
            pixel_y: 1.0,
            pixel_is_area: true,
            wkt: Some("kept".to_owned()),
        };
        let kept = with_sidecar_crs(Some(g.clone()), &dem).unwrap().unwrap();
        assert_eq!(kept.wkt.as_deref(), Some("kept"));
        let read = with_sidecar_crs(Some(GeoRef { wkt: None, ..g }), &dem).unwrap();
        assert_eq!(read.unwrap().wkt.as_deref(), Some("GEOGCS[\"x\"]"));
        for (bytes, why) in [
            (b" \n".to_vec(), "empty"),
            (vec![b'x'; MAX_WKT_LEN + 1], "more than"),
        ] {
            std::fs::write(dir.path().join("a.PRJ"), bytes).unwrap();
            let e = sidecar_wkt(&dem).unwrap_err().to_string();
            assert!(e.contains("a.PRJ") && e.contains(why), "{e}");
        }
    }
}
