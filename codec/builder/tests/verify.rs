//! Verify's comparisons accept a repository against its own input and refuse it against
//! another.

use cbdam_builder::verify::{compare_dem, one_file_in_blocks};
use cbdam_builder::{BuildOptions, NoProgress, build};
use cbdam_codec::repository::Repository;

use crate::util::data;

#[test]
fn a_repository_matches_its_input_and_not_another() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("r.cbdam");
    let rhine = data("rhine_nodata.tif");
    build(
        &BuildOptions::new(vec![rhine.clone()], out.clone(), 1.0),
        &NoProgress,
    )
    .unwrap();
    let repo = Repository::open(&out).unwrap();
    let c = compare_dem(&repo, &rhine).unwrap();
    c.check().unwrap();
    assert!(c.max_error <= 1.0 && c.max_error > 0.0, "{}", c.max_error);
    assert!(c.nodata > 0 && c.mask_mismatches.is_empty());
    // Decoded block by block only when decoding it whole would not fit the limit.
    assert!(one_file_in_blocks(&repo, &rhine, 1 << 20));
    assert!(!one_file_in_blocks(&repo, &rhine, 1 << 30));
    assert!(!one_file_in_blocks(
        &repo,
        &dir.path().join("r.f32"),
        1 << 20
    ));
    // Another DEM of another size is refused by name.
    let other = data("jacksboro_mpl.tif");
    let e = compare_dem(&repo, &other).err().unwrap().to_string();
    assert!(e.contains(&other.display().to_string()), "{e}");
}
