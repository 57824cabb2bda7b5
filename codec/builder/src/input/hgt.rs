//! SRTM `.hgt` tiles: big-endian `i16`, square, size known only from the file length.

use std::path::Path;

use super::{Dem, GeoRef, Limits, SampleType};
use cbdam_codec::CodecError;

/// SRTM's void marker.
const HGT_NODATA: f64 = -32768.0;
/// 3 and 1 arc-second tiles: one degree plus the shared edge row and column.
const SIDES: [usize; 2] = [1201, 3601];

/// The side of the square tile at `path`, from its length.
fn side_of(path: &Path, limits: &Limits) -> Result<usize, CodecError> {
    let len = super::file_len(path)?;
    let side = SIDES
        .into_iter()
        .find(|&s| (s * s * 2) as u64 == len)
        .ok_or_else(|| {
            let msg = format!(
                "HGT file {} is {len} bytes; an SRTM tile is {} (3\") or {} (1\") bytes",
                path.display(),
                SIDES[0] * SIDES[0] * 2,
                SIDES[1] * SIDES[1] * 2
            );
            if len < (SIDES[1] * SIDES[1] * 2) as u64 {
                CodecError::truncated(msg)
            } else {
                CodecError::corrupt(msg)
            }
        })?;
    limits.check(side, side)?;
    Ok(side)
}

/// What [`read`] returns but the samples (`values` empty): size from the length, position from
/// the name. Nothing but the file's length is read.
pub(super) fn read_header(path: &Path, limits: &Limits) -> Result<Dem, CodecError> {
    let side = side_of(path, limits)?;
    Ok(Dem {
        width: side,
        height: side,
        values: Vec::new(),
        sample_type: SampleType::I16,
        nodata: Some(HGT_NODATA),
        georef: georef_from_name(path, side),
    })
}

/// Rows `rows` of the `side`-sample tile at `path` into `out` (replacing its contents).
pub(super) fn read_rows(
    path: &Path,
    side: usize,
    rows: std::ops::Range<usize>,
    out: &mut Vec<f64>,
) -> Result<(), CodecError> {
    use std::io::{Read, Seek, SeekFrom};
    if rows.start >= rows.end || rows.end > side {
        return Err(CodecError::invalid(format!(
            "rows {}..{} of a {side}-row HGT tile",
            rows.start, rows.end
        )));
    }
    let mut f = std::fs::File::open(path)?;
    if f.metadata()?.len() != (side * side * 2) as u64 {
        return Err(CodecError::truncated(format!(
            "HGT file {} changed size while being read",
            path.display()
        )));
    }
    f.seek(SeekFrom::Start((rows.start * side * 2) as u64))?;
    let mut bytes = vec![0u8; rows.len() * side * 2];
    f.read_exact(&mut bytes)?;
    out.clear();
    out.extend(
        bytes
            .chunks_exact(2)
            .map(|b| f64::from(i16::from_be_bytes([b[0], b[1]]))),
    );
    Ok(())
}

pub(super) fn read(path: &Path, limits: &Limits) -> Result<Dem, CodecError> {
    let side = side_of(path, limits)?;
    let bytes = std::fs::read(path)?;
    if bytes.len() != side * side * 2 {
        return Err(CodecError::truncated(format!(
            "HGT file {} changed size while being read",
            path.display()
        )));
    }
    let values = bytes
        .chunks_exact(2)
        .map(|b| f64::from(i16::from_be_bytes([b[0], b[1]])))
        .collect();
    Ok(Dem {
        values,
        ..read_header(path, limits)?
    })
}

/// `N39E040.hgt` names the south-west corner of the tile in whole degrees; samples sit on the
/// degree lines (pixel-is-point), so the north-west sample is at (lon, lat + 1). A name that does
/// not follow the pattern just leaves the tile without georeferencing.
fn georef_from_name(path: &Path, side: usize) -> Option<GeoRef> {
    let name = path.file_name()?.to_str()?.as_bytes();
    if name.len() < 7 {
        return None;
    }
    let lat_sign = match name[0].to_ascii_uppercase() {
        b'N' => 1.0,
        b'S' => -1.0,
        _ => return None,
    };
    let lon_sign = match name[3].to_ascii_uppercase() {
        b'E' => 1.0,
        b'W' => -1.0,
        _ => return None,
    };
    let digits = |s: &[u8]| -> Option<f64> {
        s.iter()
            .all(u8::is_ascii_digit)
            .then(|| std::str::from_utf8(s).ok()?.parse::<f64>().ok())
            .flatten()
    };
    let lat = lat_sign * digits(&name[1..3])?;
    let lon = lon_sign * digits(&name[4..7])?;
    if lat.abs() > 90.0 || lon.abs() > 180.0 {
        return None;
    }
    let pixel = 1.0 / (side - 1) as f64;
    Some(GeoRef {
        epsg: Some(4326),
        origin_x: lon,
        origin_y: lat + 1.0,
        pixel_x: pixel,
        pixel_y: pixel,
        pixel_is_area: false,
        wkt: None,
    })
}
