//! The streamed GeoTIFF path ([`cbdam_builder::plan::prepare`]) writes the same repository bytes
//! as reading the whole file (decoded by the `tiff` crate's own whole-image reader, not by the
//! chunk reader under test), on every bundled GeoTIFF.

use cbdam_builder::input::{ReadOptions, read_dem};
use cbdam_builder::plan::{InputSpec, prepare};
use cbdam_codec::hierarchy::EncodeOptions;
use cbdam_codec::quant::{HeightGrid, QuantPlan};
use cbdam_codec::repository::write_repository;
use tiff::decoder::{Decoder, DecodingResult};

use crate::util::bundled_tifs;

#[test]
fn streamed_geotiff_builds_the_same_repository_as_the_whole_file() {
    let dir = tempfile::tempdir().unwrap();
    let inputs = bundled_tifs();
    assert!(inputs.len() >= 6, "{inputs:?}");
    let opts = EncodeOptions::default();
    for path in inputs {
        let spec = InputSpec {
            path: &path,
            raw_size: None,
            nodata: None,
            quantum: None,
            max_error: 1.0,
            memory_limit: u64::MAX,
            lattice_dir: None,
        };
        let streamed = prepare(&spec).unwrap();
        let mut dem = read_dem(&path, &ReadOptions::default()).unwrap();
        let mut dec = Decoder::new(std::fs::File::open(&path).unwrap()).unwrap();
        let whole: Vec<f64> = match dec.read_image().unwrap() {
            DecodingResult::I16(v) => v.into_iter().map(f64::from).collect(),
            DecodingResult::F32(v) => v.into_iter().map(f64::from).collect(),
            _ => panic!(
                "{}: a sample type the bundled data does not use",
                path.display()
            ),
        };
        assert_eq!(dem.values, whole, "{}", path.display());
        dem.values = whole;
        let plan = QuantPlan::for_dem(&dem, 1.0, None).unwrap();
        let grid = HeightGrid::from_dem(&dem, &plan).unwrap();
        assert_eq!(plan, streamed.plan, "{}", path.display());
        assert_eq!(grid, streamed.grid, "{}", path.display());
        let mut bytes = Vec::new();
        for (grid, plan, georef, nodata) in [
            (&grid, &plan, dem.georef.as_ref(), dem.nodata),
            (
                &streamed.grid,
                &streamed.plan,
                streamed.georef.as_ref(),
                streamed.nodata,
            ),
        ] {
            let enc = cbdam_codec::hierarchy::Encoder::new(grid, plan.quantizer, &opts)
                .encode()
                .unwrap();
            let out = dir.path().join("r.cbdam");
            write_repository(&out, &enc, plan, georef, nodata).unwrap();
            bytes.push(std::fs::read(&out).unwrap());
        }
        assert!(
            bytes[0] == bytes[1],
            "{}: repositories differ",
            path.display()
        );
    }
}
