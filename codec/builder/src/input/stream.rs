//! Headerless float32 files delivered block of rows by block of rows (a
//! [`cbdam_codec::samples::SampleSource`]), so that inputs larger than memory can be planned and
//! quantized in passes without ever holding 8 bytes per sample.

use std::fs::File;
use std::io::{BufReader, Read};
use std::path::{Path, PathBuf};

use super::Limits;
use cbdam_codec::CodecError;
use cbdam_codec::samples::{BlockFn, SampleSource, SampleType};

/// A headerless little-endian `f32` file (see [`super::Format::RawF32`]) read in blocks of rows
/// on every pass: memory is one block, whatever the file's size.
#[derive(Clone, Debug)]
pub struct RawF32Source {
    path: PathBuf,
    width: usize,
    height: usize,
    nodata: Option<f64>,
    block_rows: usize,
}

/// Samples per block: large enough for sequential reads, small next to any grid worth streaming.
pub(super) const BLOCK_SAMPLES: usize = 1 << 20;

impl RawF32Source {
    /// Opens `path` as `width × height` samples, checking its length like
    /// [`super::read_dem`] does; `nodata` marks missing samples (NaN always does).
    pub fn open(
        path: &Path,
        width: usize,
        height: usize,
        nodata: Option<f64>,
        limits: &Limits,
    ) -> Result<Self, CodecError> {
        cbdam_codec::files::check_regular_file(path)?;
        let n = limits.check(width, height)?;
        super::raw::check_len(path, n, width, height)?;
        Ok(Self {
            path: path.to_path_buf(),
            width,
            height,
            nodata,
            block_rows: (BLOCK_SAMPLES / width.max(1)).max(1),
        })
    }
}

impl SampleSource for RawF32Source {
    fn width(&self) -> usize {
        self.width
    }
    fn height(&self) -> usize {
        self.height
    }
    fn sample_type(&self) -> SampleType {
        SampleType::F32
    }
    fn nodata(&self) -> Option<f64> {
        self.nodata
    }
    fn for_each_block(&self, f: &mut BlockFn<'_>) -> Result<(), CodecError> {
        let file = File::open(&self.path)?;
        // The size was checked at open; a file that shrank since is caught by read_exact.
        let mut reader = BufReader::with_capacity(1 << 20, file);
        let mut bytes = Vec::new();
        let mut samples = Vec::new();
        let mut row = 0;
        while row < self.height {
            let rows = self.block_rows.min(self.height - row);
            bytes.resize(rows * self.width * 4, 0);
            reader.read_exact(&mut bytes).map_err(|e| {
                CodecError::truncated(format!(
                    "raw f32 file {} changed while being read: {e}",
                    self.path.display()
                ))
            })?;
            samples.clear();
            samples.extend(
                bytes
                    .chunks_exact(4)
                    .map(|b| f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]]))),
            );
            f(row, &samples)?;
            row += rows;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocks_cover_the_file_in_order_and_match_the_whole_read() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("g.f32");
        let (w, h) = (5, 7);
        let values: Vec<f32> = (0..w * h).map(|k| k as f32 * 0.5 - 3.0).collect();
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        std::fs::write(&path, bytes).unwrap();
        let mut src = RawF32Source::open(&path, w, h, None, &Limits::default()).unwrap();
        src.block_rows = 3; // blocks of 3, 3 and 1 rows
        let mut got = Vec::new();
        let mut firsts = Vec::new();
        src.for_each_block(&mut |row, block| {
            firsts.push(row);
            got.extend_from_slice(block);
            Ok(())
        })
        .unwrap();
        assert_eq!(firsts, [0, 3, 6]);
        let dem = super::super::raw::read_f32(&path, w, h, &Limits::default()).unwrap();
        assert_eq!(got, dem.values);
        assert!(RawF32Source::open(&path, w, h + 1, None, &Limits::default()).is_err());
        assert!(RawF32Source::open(&path, w, h - 1, None, &Limits::default()).is_err());
    }
}

#[cfg(test)]
mod plan_tests {
    use super::*;
    use crate::input::{Format, ReadOptions, read_dem};
    use cbdam_codec::quant::{HeightGrid, QuantPlan};

    /// Streaming and whole-file reading of the same raw samples give the same plan and grid, on
    /// lattice (decimetre) data with NaN holes and on float data.
    #[test]
    fn streamed_plan_and_grid_equal_the_whole_dem_ones() {
        let dir = tempfile::tempdir().unwrap();
        let (w, h) = (37, 23);
        for lattice in [true, false] {
            let path = dir.path().join(format!("{lattice}.f32"));
            let values: Vec<f32> = (0..w * h)
                .map(|k| {
                    let v = (k as f32 * 0.731).sin() * 55.0 + 812.0;
                    if k % 17 == 5 {
                        f32::NAN
                    } else if lattice {
                        (v * 10.0).round() / 10.0
                    } else {
                        v
                    }
                })
                .collect();
            let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
            std::fs::write(&path, bytes).unwrap();
            let opts = ReadOptions {
                format: Some(Format::RawF32 {
                    width: w,
                    height: h,
                }),
                ..ReadOptions::default()
            };
            let dem = read_dem(&path, &opts).unwrap();
            let mut src = RawF32Source::open(&path, w, h, None, &Limits::default()).unwrap();
            src.block_rows = 4;
            for eps in [0.05, 0.3, 1.0] {
                let whole = QuantPlan::for_dem(&dem, eps, None).unwrap();
                let streamed = QuantPlan::for_source(&src, eps, None).unwrap();
                assert_eq!(whole, streamed, "lattice {lattice}, ε {eps}");
                // At 0.3 m the float32 decimetres' representation error costs the lattice plan a
                // step (k = 2, step 0.5 m), and the float plan's is coarser (0.59 m).
                assert_eq!(whole.lattice, lattice && eps != 0.3, "ε {eps}");
                assert_eq!(
                    HeightGrid::from_dem(&dem, &whole).unwrap(),
                    HeightGrid::from_source(&src, &streamed).unwrap()
                );
            }
        }
    }

    /// Float32 decimetres at ε = 0.1 m: the representation error leaves the lattice plan
    /// lossless (step 0.1 m), the float plan's step is coarser, so the float plan is chosen —
    /// by both planners, with the same grid — and keeps the bound; a quantum the caller gives
    /// keeps the lattice.
    #[test]
    fn float32_decimetres_at_one_quantum_use_the_coarser_float_plan() {
        let dir = tempfile::tempdir().unwrap();
        let (w, h) = (41, 29);
        let path = dir.path().join("dm.f32");
        let values: Vec<f32> = (0..w * h)
            .map(|k| (((k as f32 * 0.37).sin() * 90.0 + 2400.0) * 10.0).round() / 10.0)
            .collect();
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        std::fs::write(&path, bytes).unwrap();
        let src = RawF32Source::open(&path, w, h, None, &Limits::default()).unwrap();
        let plan = QuantPlan::for_source(&src, 0.1, None).unwrap();
        assert!(!plan.lattice, "{plan:?}");
        assert!(
            f64::from(plan.quantizer.step()) * plan.unit > 0.19,
            "{plan:?}"
        );
        assert!(plan.max_error() <= 0.1);
        let (q_plan, grid) = QuantPlan::quantize_source(&src, 0.1, None).unwrap();
        assert_eq!(q_plan, plan);
        assert_eq!(grid, HeightGrid::from_source(&src, &plan).unwrap());
        let given = QuantPlan::for_source(&src, 0.1, Some(0.1)).unwrap();
        assert!(given.lattice && given.quantizer.k() == 0, "{given:?}");
        let (g_plan, _) = QuantPlan::quantize_source(&src, 0.1, Some(0.1)).unwrap();
        assert_eq!(g_plan, given);
    }
}
