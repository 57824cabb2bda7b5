//! Headerless little-endian `f32` grids, the lowest common denominator of terrain tools.

use std::path::Path;

use super::{Dem, Limits, SampleType};
use cbdam_codec::CodecError;

pub(super) fn read_f32(
    path: &Path,
    width: usize,
    height: usize,
    limits: &Limits,
) -> Result<Dem, CodecError> {
    let n = limits.check(width, height)?;
    let expected = check_len(path, n, width, height)?;
    let bytes = std::fs::read(path)?;
    if bytes.len() as u64 != expected {
        return Err(CodecError::truncated(format!(
            "raw f32 file {} changed size while being read",
            path.display()
        )));
    }
    let values = bytes
        .chunks_exact(4)
        .map(|b| f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])))
        .collect();
    Ok(Dem {
        width,
        height,
        values,
        sample_type: SampleType::F32,
        nodata: None,
        georef: None,
    })
}

/// Checks that the file holds exactly `n = width × height` samples; returns its length.
pub(super) fn check_len(
    path: &Path,
    n: usize,
    width: usize,
    height: usize,
) -> Result<u64, CodecError> {
    let expected = n as u64 * 4;
    let len = super::file_len(path)?;
    if len < expected {
        return Err(CodecError::truncated(format!(
            "raw f32 file {} is {len} bytes; {width} x {height} samples need {expected}",
            path.display()
        )));
    }
    if len > expected {
        // More bytes than samples means the caller's size is wrong (or there is a header):
        // reading a prefix would shear every row.
        return Err(CodecError::invalid(format!(
            "raw f32 file {} is {len} bytes, more than the {expected} of {width} x {height} \
             samples",
            path.display()
        )));
    }
    Ok(expected)
}
