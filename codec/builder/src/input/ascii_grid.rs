//! ESRI ASCII grids: a `key value` header, then `nrows` rows of `ncols` numbers, north first.

use std::path::Path;

use super::{Dem, GeoRef, Limits, SampleType};
use cbdam_codec::CodecError;

pub(super) fn read(path: &Path, limits: &Limits) -> Result<Dem, CodecError> {
    let text = std::fs::read(path)?;
    let text = std::str::from_utf8(&text)
        .map_err(|_| CodecError::corrupt(format!("{}: ASCII grid is not text", path.display())))?;
    let mut tokens = text.split_ascii_whitespace().peekable();

    let mut ncols = None;
    let mut nrows = None;
    let mut x = None;
    let mut y = None;
    let mut x_center = false;
    let mut y_center = false;
    let mut cellsize = None;
    let mut dx = None;
    let mut dy = None;
    let mut nodata = None;
    // Header lines are keyword/value pairs in any order; the data starts at the first token
    // that is not a keyword.
    while let Some(&key) = tokens.peek() {
        if !key.starts_with(|c: char| c.is_ascii_alphabetic()) || is_number(key) {
            break;
        }
        tokens.next();
        let key_lc = key.to_ascii_lowercase();
        let value = tokens.next().ok_or_else(|| {
            CodecError::truncated(format!("ASCII grid header ends after '{key}'"))
        })?;
        let num = || -> Result<f64, CodecError> {
            value.parse::<f64>().map_err(|_| {
                CodecError::corrupt(format!("ASCII grid header {key} '{value}' is not a number"))
            })
        };
        let count = || -> Result<usize, CodecError> {
            value.parse::<usize>().map_err(|_| {
                CodecError::corrupt(format!(
                    "ASCII grid header {key} '{value}' is not a non-negative integer"
                ))
            })
        };
        match key_lc.as_str() {
            "ncols" => ncols = Some(count()?),
            "nrows" => nrows = Some(count()?),
            "xllcorner" => x = Some(num()?),
            "xllcenter" => {
                x = Some(num()?);
                x_center = true;
            }
            "yllcorner" => y = Some(num()?),
            "yllcenter" => {
                y = Some(num()?);
                y_center = true;
            }
            "cellsize" => cellsize = Some(num()?),
            // GDAL writes dx/dy instead of cellsize for non-square cells.
            "dx" => dx = Some(num()?),
            "dy" => dy = Some(num()?),
            "nodata_value" => nodata = Some(num()?),
            _ => {
                return Err(CodecError::unsupported(format!(
                    "ASCII grid header keyword '{key}' is not supported"
                )));
            }
        }
    }
    let missing = |what: &str| CodecError::corrupt(format!("ASCII grid header lacks {what}"));
    let width = ncols.ok_or_else(|| missing("ncols"))?;
    let height = nrows.ok_or_else(|| missing("nrows"))?;
    let x = x.ok_or_else(|| missing("xllcorner or xllcenter"))?;
    let y = y.ok_or_else(|| missing("yllcorner or yllcenter"))?;
    let (px, py) = match (cellsize, dx, dy) {
        (Some(c), _, _) => (c, c),
        (None, Some(dx), Some(dy)) => (dx, dy),
        _ => return Err(missing("cellsize")),
    };
    if x_center != y_center {
        return Err(CodecError::corrupt(
            "ASCII grid header mixes a corner and a centre reference",
        ));
    }
    let n = limits.check(width, height)?;

    // A tiny file may declare a huge grid; every value takes at least two bytes of text, so
    // reserve no more than the file could hold.
    let mut values = Vec::with_capacity(n.min(text.len() / 2 + 1));
    // Integer grids are integer-typed so that the quantum is found as 1 without float tests.
    let mut all_int = true;
    for tok in tokens {
        if values.len() == n {
            return Err(CodecError::corrupt(format!(
                "ASCII grid has more than the {width} x {height} values its header declares"
            )));
        }
        let v: f64 = tok.parse().map_err(|_| {
            CodecError::corrupt(format!(
                "ASCII grid value {} ('{tok}') is not a number",
                values.len()
            ))
        })?;
        all_int &= tok.parse::<i32>().is_ok();
        values.push(v);
    }
    if values.len() < n {
        return Err(CodecError::truncated(format!(
            "ASCII grid holds {} values; its header declares {width} x {height} = {n}",
            values.len()
        )));
    }

    // The header anchors the south-west of the grid; GeoRef anchors raster point (0, 0), the
    // north-west corner (cells) or north-west centre (points).
    let georef = if x_center {
        GeoRef {
            epsg: None,
            origin_x: x,
            origin_y: y + height.saturating_sub(1) as f64 * py,
            pixel_x: px,
            pixel_y: py,
            pixel_is_area: false,
            wkt: None,
        }
    } else {
        GeoRef {
            epsg: None,
            origin_x: x,
            origin_y: y + height as f64 * py,
            pixel_x: px,
            pixel_y: py,
            pixel_is_area: true,
            wkt: None,
        }
    };
    Ok(Dem {
        width,
        height,
        values,
        sample_type: if all_int {
            SampleType::I32
        } else {
            SampleType::F64
        },
        nodata,
        georef: Some(georef),
    })
}

/// `nan`, `inf` and `infinity` parse as floats but start with a letter; they are data, not keys.
fn is_number(tok: &str) -> bool {
    tok.parse::<f64>().is_ok()
}
