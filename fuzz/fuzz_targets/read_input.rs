//! Hostile input files into every reader `cbdam build` uses: `read_dem` for each format (by
//! file extension), the streamed GeoTIFF source the builder reads large files with, and the
//! colour reader. Never a panic; a declared size above the limit is an error before anything of
//! that size is allocated (libFuzzer's RSS limit turns an allocation of the declared size into a
//! reported crash).
//!
//! Input layout: `[selector byte, file bytes..]`; the selector picks the extension. Seed with small
//! real files of each format (`fuzz/seeds/read_input/README.md`); run with
//! `cargo +nightly fuzz run read_input corpus/read_input seeds/read_input`.
#![no_main]

use std::io::Write;

use cbdam_builder::input::{GeoTiffSource, Limits, ReadOptions, read_dem, read_rgb};
use cbdam_codec::samples::SampleSource;
use libfuzzer_sys::fuzz_target;

/// 2^20 samples: far above any seed, far below what would trip the RSS limit.
const MAX_SAMPLES: usize = 1 << 20;

const EXTENSIONS: [&str; 5] = ["tif", "hgt", "asc", "png", "dem"];

fuzz_target!(|data: &[u8]| {
    let Some((&selector, file)) = data.split_first() else {
        return;
    };
    let ext = EXTENSIONS[usize::from(selector) % EXTENSIONS.len()];
    let mut tmp = tempfile::Builder::new()
        .suffix(&format!(".{ext}"))
        .tempfile_in("/dev/shm")
        .or_else(|_| tempfile::Builder::new().suffix(&format!(".{ext}")).tempfile())
        .expect("temporary file");
    tmp.write_all(file).expect("write temporary file");
    let path = tmp.path();
    let limits = Limits {
        max_samples: MAX_SAMPLES,
    };
    let opts = ReadOptions {
        limits,
        ..ReadOptions::default()
    };
    if let Ok(dem) = read_dem(path, &opts) {
        assert_eq!(dem.values.len(), dem.width * dem.height);
        assert!(dem.width * dem.height <= MAX_SAMPLES);
    }
    match ext {
        "tif" => {
            if let Ok(source) = GeoTiffSource::open(path, None, &limits) {
                let (w, h) = (source.width(), source.height());
                assert!(w * h <= MAX_SAMPLES);
                let mut rows = 0;
                let _ = source.for_each_block(&mut |first, samples| {
                    assert_eq!(first, rows, "blocks arrive in row order");
                    assert_eq!(samples.len() % w.max(1), 0);
                    rows += samples.len() / w.max(1);
                    assert!(rows <= h);
                    Ok(())
                });
            }
            let _ = read_rgb(path, &limits);
        }
        "png" => {
            let _ = read_rgb(path, &limits);
        }
        _ => {}
    }
});
