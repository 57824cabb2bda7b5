//! Repositories written by format version 1 (the varint record index) still open, check and
//! decode with a version-2 reader, and hold exactly what today's encoder produces apart from the
//! index's coding. The fixtures in `tests/data/v1/` were written by the version-1 `cbdam`
//! (commit 278d5a6), before version 2 existed:
//!
//! - `lidar1m_eps1.cbdam`: `cbdam build data/lidar1m_mn.tif --max-error 1` (N = 65,
//!   georeferenced; 69 records, 13 non-empty).
//! - `holes_n9.cbdam`: a 30×30 raw f32 plane with a disc of -9999, `--nodata -9999
//!   --max-error 0.5 --diamond-size 9` (nodata masks in the root field and the records).
//! - `colour33_n9.cbdam`: a 33×33 RGB PNG of coordinate gradients, `--colour --max-error 4
//!   --diamond-size 9` (three channels per record).

use std::path::{Path, PathBuf};

use cbdam_codec::colour::reconstruct_rgb;
use cbdam_codec::hierarchy::{EncodeOptions, RepoKind, encode, verify, walk_all_with_validity};
use cbdam_codec::input::{ReadOptions, read_dem};
use cbdam_codec::quant::{HeightGrid, QuantPlan};
use cbdam_codec::repository::{FORMAT_VERSION, Repository, Section, serialize};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/v1")
        .join(name)
}

#[test]
fn version_1_lidar_opens_and_equals_todays_encoding_but_for_the_index() {
    let old = Repository::open(&fixture("lidar1m_eps1.cbdam")).unwrap();
    assert_eq!(old.head().format_version(), 1);
    assert_eq!(FORMAT_VERSION, 2);
    old.check_all().unwrap();

    let dem = read_dem(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/lidar1m_mn.tif"),
        &ReadOptions::default(),
    )
    .unwrap();
    let plan = QuantPlan::for_dem(&dem, 1.0, None).unwrap();
    assert_eq!(*old.plan(), plan);
    let grid = HeightGrid::from_dem(&dem, &plan).unwrap();
    let enc = encode(&grid, plan.quantizer, &EncodeOptions::default()).unwrap();
    // Version 1 stored exact height ranges, so the whole hierarchy compares equal.
    assert_eq!(old.to_encoded().unwrap(), enc);
    assert!(
        verify(&old.to_encoded().unwrap(), &grid)
            .unwrap()
            .within_bound()
    );

    // The same hierarchy written today: same root field and records, a smaller index.
    let new =
        Repository::from_bytes(serialize(&enc, &plan, dem.georef.as_ref(), dem.nodata).unwrap())
            .unwrap();
    assert_eq!(new.head().format_version(), 2);
    new.check_all().unwrap();
    for s in [Section::Roots, Section::Checksums, Section::Records] {
        assert_eq!(old.section_len(s), new.section_len(s), "{s:?}");
    }
    assert_eq!(old.root_bytes(), new.root_bytes());
    let (v1, v2) = (
        old.section_len(Section::Index),
        new.section_len(Section::Index),
    );
    assert!(
        v2 * 2 < v1,
        "index: {v2} bytes in version 2, {v1} in version 1"
    );
    for (a, b) in old.entries().iter().zip(new.entries()) {
        assert_eq!(
            (a.id, a.offset, a.length, a.object_error),
            (b.id, b.offset, b.length, b.object_error)
        );
        assert!(b.min <= a.min && a.max <= b.max);
    }
}

#[test]
fn version_1_nodata_and_colour_repositories_open_and_decode() {
    for name in ["holes_n9.cbdam", "colour33_n9.cbdam"] {
        let old = Repository::open(&fixture(name)).unwrap();
        assert_eq!(old.head().format_version(), 1, "{name}");
        old.check_all().unwrap();
        let enc = old.to_encoded().unwrap();
        match enc.params.kind {
            RepoKind::Elevation => {
                let mut diamonds = 0;
                walk_all_with_validity(&enc, |_, _, _| diamonds += 1).unwrap();
                assert!(diamonds > 1, "{name}");
            }
            RepoKind::Colour => {
                let rgb = reconstruct_rgb(&enc).unwrap();
                assert_eq!(rgb.len(), 33 * 33, "{name}");
            }
        }
        // Rewritten as version 2: the same records, and it opens again.
        let again = Repository::from_bytes(
            serialize(&enc, old.plan(), old.georef(), old.nodata()).unwrap(),
        )
        .unwrap();
        again.check_all().unwrap();
        assert_eq!(again.head().format_version(), 2);
        assert_eq!(again.root_bytes(), old.root_bytes());
        for (i, e) in old.entries().iter().enumerate() {
            assert_eq!(
                again.record(e.id).unwrap(),
                old.record_at(i).unwrap(),
                "{name} {}",
                e.id
            );
        }
    }
}
