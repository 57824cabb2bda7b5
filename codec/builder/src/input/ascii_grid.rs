//! ESRI ASCII grids: a `key value` header, then `nrows` rows of `ncols` numbers, north first.

use std::path::Path;

use super::{Dem, GeoRef, Limits, SampleType};
use cbdam_codec::CodecError;

pub(super) fn read(path: &Path, limits: &Limits) -> Result<Dem, CodecError> {
    let text = std::fs::read(path)?;
    let text = std::str::from_utf8(&text)
        .map_err(|_| CodecError::corrupt(format!("{}: ASCII grid is not text", path.display())))?;
    let mut tokens = text.split_ascii_whitespace().peekable();
    let header = Header::parse(&mut tokens)?;
    let (width, height) = (header.ncols, header.nrows);
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
    Ok(Dem {
        width,
        height,
        values,
        sample_type: if all_int {
            SampleType::I32
        } else {
            SampleType::F64
        },
        nodata: header.nodata,
        georef: Some(header.georef()),
    })
}

/// The header's keywords.
struct Header {
    ncols: usize,
    nrows: usize,
    /// The south-west corner (or centre, `centre`).
    x: f64,
    y: f64,
    centre: bool,
    /// Cell size across and down.
    px: f64,
    py: f64,
    nodata: Option<f64>,
}

/// The keywords as read, in any order.
#[derive(Default)]
struct Keywords {
    ncols: Option<usize>,
    nrows: Option<usize>,
    x: Option<f64>,
    y: Option<f64>,
    x_center: bool,
    y_center: bool,
    cellsize: Option<f64>,
    dx: Option<f64>,
    dy: Option<f64>,
    nodata: Option<f64>,
}

impl Header {
    /// Reads the `key value` lines, up to the first token that is not a keyword.
    fn parse<'a>(
        tokens: &mut std::iter::Peekable<impl Iterator<Item = &'a str>>,
    ) -> Result<Self, CodecError> {
        let mut k = Keywords::default();
        while let Some(&key) = tokens.peek() {
            if !key.starts_with(|c: char| c.is_ascii_alphabetic()) || is_number(key) {
                break;
            }
            tokens.next();
            let value = tokens.next().ok_or_else(|| {
                CodecError::truncated(format!("ASCII grid header ends after '{key}'"))
            })?;
            k.set(key, value)?;
        }
        let missing = |what: &str| CodecError::corrupt(format!("ASCII grid header lacks {what}"));
        let ncols = k.ncols.ok_or_else(|| missing("ncols"))?;
        let nrows = k.nrows.ok_or_else(|| missing("nrows"))?;
        let x = k.x.ok_or_else(|| missing("xllcorner or xllcenter"))?;
        let y = k.y.ok_or_else(|| missing("yllcorner or yllcenter"))?;
        let (px, py) = match (k.cellsize, k.dx, k.dy) {
            (Some(c), _, _) => (c, c),
            (None, Some(dx), Some(dy)) => (dx, dy),
            _ => return Err(missing("cellsize")),
        };
        if k.x_center != k.y_center {
            return Err(CodecError::corrupt(
                "ASCII grid header mixes a corner and a centre reference",
            ));
        }
        Ok(Self {
            ncols,
            nrows,
            x,
            y,
            centre: k.x_center,
            px,
            py,
            nodata: k.nodata,
        })
    }

    /// The header anchors the south-west of the grid; GeoRef anchors raster point (0, 0), the
    /// north-west corner (cells) or north-west centre (points).
    fn georef(&self) -> GeoRef {
        let rows_above = if self.centre {
            self.nrows.saturating_sub(1)
        } else {
            self.nrows
        };
        GeoRef {
            epsg: None,
            origin_x: self.x,
            origin_y: self.y + rows_above as f64 * self.py,
            pixel_x: self.px,
            pixel_y: self.py,
            pixel_is_area: !self.centre,
            wkt: None,
        }
    }
}

impl Keywords {
    /// Records one `key value` pair (keys in any case).
    fn set(&mut self, key: &str, value: &str) -> Result<(), CodecError> {
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
        match key.to_ascii_lowercase().as_str() {
            "ncols" => self.ncols = Some(count()?),
            "nrows" => self.nrows = Some(count()?),
            "xllcorner" => self.x = Some(num()?),
            "xllcenter" => {
                self.x = Some(num()?);
                self.x_center = true;
            }
            "yllcorner" => self.y = Some(num()?),
            "yllcenter" => {
                self.y = Some(num()?);
                self.y_center = true;
            }
            "cellsize" => self.cellsize = Some(num()?),
            // GDAL writes dx/dy instead of cellsize for non-square cells.
            "dx" => self.dx = Some(num()?),
            "dy" => self.dy = Some(num()?),
            "nodata_value" => self.nodata = Some(num()?),
            _ => {
                return Err(CodecError::unsupported(format!(
                    "ASCII grid header keyword '{key}' is not supported"
                )));
            }
        }
        Ok(())
    }
}

/// `nan`, `inf` and `infinity` parse as floats but start with a letter; they are data, not keys.
fn is_number(tok: &str) -> bool {
    tok.parse::<f64>().is_ok()
}
