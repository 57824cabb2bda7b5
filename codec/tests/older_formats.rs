//! Repositories written by older format versions still open, check and decode, and hold
//! exactly what today's encoder produces apart from what the versions changed. Version 1 coded
//! the record index as varints; version 2 range-codes it; version 3 (today's) changed only the
//! header (compact instead of 256 fixed bytes).
//!
//! The fixtures in `tests/data/v1/` were written by the version-1 `cbdam` (commit 278d5a6):
//!
//! - `lidar1m_eps1.cbdam`: `cbdam build data/lidar1m_mn.tif --max-error 1` (N = 65,
//!   georeferenced; 69 records, 13 non-empty).
//! - `holes_n9.cbdam`: a 30×30 raw f32 plane with a disc of -9999, `--nodata -9999
//!   --max-error 0.5 --diamond-size 9` (nodata masks in the root field and the records).
//! - `colour33_n9.cbdam`: a 33×33 RGB PNG of coordinate gradients, `--colour --max-error 4
//!   --diamond-size 9` (three channels per record).
//!
//! `tests/data/v2/` holds the same three, rewritten by the version-2 `cbdam upgrade` (commit
//! 2a2aeb0).
//!
//! `tests/data/v3/lidar5_before_wkt.cbdam` is a version-3 file written before the CRS definition
//! joined the header's georeferencing fields without a new version number (commit 08ba422):
//! `cbdam build data/lidar1m_mn.tif --max-error 5` (N = 65, georeferenced, all records empty),
//! the fuzz seed of that name until it was rebuilt.

use std::path::{Path, PathBuf};

use cbdam_builder::input::{ReadOptions, read_dem};
use cbdam_codec::colour::reconstruct_rgb;
use cbdam_codec::entropy::CoderKind;
use cbdam_codec::hierarchy::{EncodeOptions, Encoder, RepoKind, verify, walk_all_with_validity};
use cbdam_codec::quant::{HeightGrid, QuantPlan};
use cbdam_codec::repository::{FORMAT_VERSION, Repository, Section, serialize};

fn fixture(version: u16, name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join(format!("tests/data/v{version}"))
        .join(name)
}

#[test]
fn version_1_lidar_opens_and_equals_todays_encoding_but_for_the_index() {
    let old = Repository::open(&fixture(1, "lidar1m_eps1.cbdam")).unwrap();
    assert_eq!(old.head().format_version(), 1);
    assert_eq!(FORMAT_VERSION, 3);
    old.check_all().unwrap();

    let dem = read_dem(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/lidar1m_mn.tif"),
        &ReadOptions::default(),
    )
    .unwrap();
    let plan = QuantPlan::for_dem(&dem, 1.0, None).unwrap();
    assert_eq!(*old.head().plan(), plan);
    let grid = HeightGrid::from_dem(&dem, &plan).unwrap();
    // With the defaults of its day: the bitwise adaptive coder (the token coder, id 2, came
    // with version 3 and is today's default).
    let opts = EncodeOptions {
        coder: CoderKind::Adaptive,
        ..EncodeOptions::default()
    };
    let enc = Encoder::new(&grid, plan.quantizer, &opts).encode().unwrap();
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
    assert_eq!(new.head().format_version(), FORMAT_VERSION);
    new.check_all().unwrap();
    for s in [Section::Roots, Section::Checksums, Section::Records] {
        assert_eq!(
            old.head().section_len(s),
            new.head().section_len(s),
            "{s:?}"
        );
    }
    assert_eq!(old.head().root_bytes(), new.head().root_bytes());
    let (v1, v2) = (
        old.head().section_len(Section::Index),
        new.head().section_len(Section::Index),
    );
    assert!(v2 * 2 < v1, "index: {v2} bytes today, {v1} in version 1");
    for (a, b) in old.head().entries().iter().zip(new.head().entries()) {
        assert_eq!(
            (a.id, a.offset, a.length, a.object_error),
            (b.id, b.offset, b.length, b.object_error)
        );
        assert!(b.min <= a.min && a.max <= b.max);
    }
}

/// Version 2 differs from today's files only in the header: the same sections byte for byte,
/// and a header of under half the size.
#[test]
fn version_2_files_hold_todays_sections_under_a_longer_header() {
    for name in ["lidar1m_eps1.cbdam", "holes_n9.cbdam", "colour33_n9.cbdam"] {
        let old = Repository::open(&fixture(2, name)).unwrap();
        assert_eq!(old.head().format_version(), 2, "{name}");
        assert_eq!(old.head().header_len(), 256, "{name}");
        old.check_all().unwrap();
        let enc = old.to_encoded().unwrap();
        let bytes = serialize(
            &enc,
            old.head().plan(),
            old.head().georef(),
            old.head().nodata(),
        )
        .unwrap();
        let new = Repository::from_bytes(bytes).unwrap();
        assert_eq!(new.head().format_version(), 3);
        let h = new.head().header_len();
        assert!(h < 128, "{name}: {h}-byte header");
        let old_bytes = std::fs::read(fixture(2, name)).unwrap();
        assert_eq!(new.as_bytes()[h..], old_bytes[256..], "{name}");
        assert_eq!(new.to_encoded().unwrap(), enc, "{name}");
        assert_eq!(
            (
                new.head().params(),
                new.head().plan(),
                new.head().georef(),
                new.head().nodata()
            ),
            (
                old.head().params(),
                old.head().plan(),
                old.head().georef(),
                old.head().nodata()
            ),
            "{name}"
        );
        assert_eq!(new.head().leaf_error(), old.head().leaf_error(), "{name}");
        assert_eq!(new.head().entries(), old.head().entries(), "{name}");
    }
}

#[test]
fn older_nodata_and_colour_repositories_open_and_decode() {
    for (version, name) in [1, 2]
        .into_iter()
        .flat_map(|v| ["holes_n9.cbdam", "colour33_n9.cbdam"].map(|n| (v, n)))
    {
        let old = Repository::open(&fixture(version, name)).unwrap();
        assert_eq!(old.head().format_version(), version, "{name}");
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
        // Rewritten today: the same records, and it opens again.
        let again = Repository::from_bytes(
            serialize(
                &enc,
                old.head().plan(),
                old.head().georef(),
                old.head().nodata(),
            )
            .unwrap(),
        )
        .unwrap();
        again.check_all().unwrap();
        assert_eq!(again.head().format_version(), FORMAT_VERSION);
        assert_eq!(again.head().root_bytes(), old.head().root_bytes());
        for (i, e) in old.head().entries().iter().enumerate() {
            assert_eq!(
                again.record(e.id).unwrap(),
                old.record_at(i).unwrap(),
                "{name} {}",
                e.id
            );
        }
    }
}

#[test]
fn version_3_files_from_before_the_crs_definition_still_open() {
    let old = Repository::open(&fixture(3, "lidar5_before_wkt.cbdam")).unwrap();
    assert_eq!(old.head().format_version(), 3);
    old.check_all().unwrap();
    let g = old.head().georef().expect("georeferenced");
    assert!(g.wkt.is_none());
    // The georeferencing the input has today.
    let dem = read_dem(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/lidar1m_mn.tif"),
        &ReadOptions::default(),
    )
    .unwrap();
    let today = dem.georef.expect("a georeferenced input");
    assert_eq!(
        (g.epsg, g.origin_x, g.origin_y, g.pixel_x, g.pixel_y),
        (
            today.epsg,
            today.origin_x,
            today.origin_y,
            today.pixel_x,
            today.pixel_y
        )
    );
    let enc = old.to_encoded().unwrap();
    let mut diamonds = 0;
    walk_all_with_validity(&enc, |_, _, _| diamonds += 1).unwrap();
    assert!(diamonds > 1);
}
