//! Tests of the container: cube-sphere headers and a planet's provenance.

use super::validate::{parse_header, parse_layout, parse_params};
use super::write::serialize_with;
use super::{FLAG_COLOUR, FLAG_CUBE_SPHERE, RepositoryHead, serialize};
use crate::geometry::DomainKind;
use crate::hierarchy::{EncodeOptions, Encoded, PlanetGrid, encode_planet};
use crate::quant::QuantPlan;
use crate::repository::header::{
    FLAG_LEVEL_QUANTIZERS, FLAG_PLANET_PROVENANCE, HeaderFields, PlanetProvenance, VerticalDatum,
    read_header, write_compact,
};

/// A small planet (N = 3, K = 1), its plan and its encoding.
fn small_planet() -> (PlanetGrid, QuantPlan, Encoded) {
    let planet = PlanetGrid::from_fn(3, 1, |p| Some(p.x as i32 - p.y as i32)).unwrap();
    let plan = QuantPlan::new(1.0, Some(1.0), -2.0, 2.0).unwrap();
    let opts = EncodeOptions {
        n: 3,
        ..EncodeOptions::default()
    };
    let encoded = encode_planet(&planet, plan.quantizer, &opts).unwrap();
    (planet, plan, encoded)
}

#[test]
fn a_cube_sphere_header_is_checked_field_by_field() {
    let (planet, plan, encoded) = small_planet();
    let bytes = serialize(&encoded, &plan, None, None).unwrap();
    let h = parse_header(&bytes).unwrap();
    assert_eq!(h.flags, FLAG_CUBE_SPHERE);
    let (domain, ..) = parse_layout(&h).unwrap();
    assert_eq!(domain, *planet.domain());
    let refused = |change: &dyn Fn(&mut HeaderFields), says: &str| {
        let mut bad = h.clone();
        change(&mut bad);
        let e = parse_layout(&bad).unwrap_err().to_string();
        assert!(e.contains(says), "{e}");
    };
    refused(&|h| h.roots_y = 2, "one root per face");
    refused(&|h| h.geo_flags = 1, "georeferencing");
    refused(&|h| h.data_width -= 1, "points, the header says");
    refused(&|h| h.flags |= FLAG_COLOUR, "colour cube-sphere");
    refused(&|h| h.flags |= 64, "unknown header flags");
    refused(
        &|h| h.flags |= FLAG_LEVEL_QUANTIZERS,
        "per-level quantizers (flag bit 5) without an RMS error bound",
    );
    refused(
        &|h| h.flags = FLAG_PLANET_PROVENANCE,
        "provenance (flag bit 3) in a planar",
    );
    // Without the flag the same header is a plane.
    let mut plane = h.clone();
    plane.flags = 0;
    let (domain, ..) = parse_layout(&plane).unwrap();
    assert_eq!(domain.kind(), DomainKind::Planar);
}

/// A planet's provenance round-trips through the header (flag bit 3), is absent without
/// it, and a planar repository cannot carry it.
#[test]
fn a_planet_provenance_round_trips() {
    let (_, plan, encoded) = small_planet();
    let pv = PlanetProvenance {
        vertical_datum: VerticalDatum::Orthometric,
        resampling_max: 12.25,
        resampling_rms: 0.5,
    };
    let bytes = serialize_with(&encoded, &plan, None, None, Some(&pv)).unwrap();
    let head = RepositoryHead::parse(&bytes, bytes.len() as u64).unwrap();
    assert_eq!(head.provenance(), Some(&pv));
    assert_eq!(
        parse_header(&bytes).unwrap().flags,
        FLAG_CUBE_SPHERE | FLAG_PLANET_PROVENANCE
    );
    let plain = serialize(&encoded, &plan, None, None).unwrap();
    assert_eq!(
        RepositoryHead::parse(&plain, plain.len() as u64)
            .unwrap()
            .provenance(),
        None
    );
    // An rms above the max is corrupt (the CRC is resealed so the field check is reached).
    let mut h = parse_header(&bytes).unwrap();
    h.provenance = Some(PlanetProvenance {
        resampling_rms: 20.0,
        ..pv
    });
    let bad = write_compact(&h).unwrap();
    let e = read_header(&bad).unwrap_err().to_string();
    assert!(e.contains("resampling error"), "{e}");
}

/// Per-level quantizers (flag bit 5) are read back; a list whose count is not the hierarchy's
/// number of levels of records, or whose largest `k` is not the header's, is refused by name.
#[test]
fn per_level_quantizers_must_fit_the_hierarchy_and_the_header_k() {
    let grid = crate::quant::HeightGrid::all_valid(17, 17, (0..289).map(|i| i * 7 % 23).collect());
    let opts = EncodeOptions {
        n: 5,
        ..EncodeOptions::default()
    };
    let levels = crate::quant::LevelQuantizers::new(&[0, 3, 1, 2]).unwrap();
    let top = crate::quant::Quantizer::new(3).unwrap();
    let encoded = crate::hierarchy::Encoder::new(&grid, top, &opts)
        .per_level(Some(levels))
        .encode()
        .unwrap();
    let mut plan = QuantPlan::new(3.0, Some(1.0), 0.0, 22.0).unwrap();
    (plan.levels, plan.rms) = (
        Some(levels),
        Some(crate::quant::RmsBound {
            target: 2.0,
            measured: 1.0,
        }),
    );
    let bytes = serialize(&encoded, &plan, None, None).unwrap();
    let head = RepositoryHead::parse(&bytes, bytes.len() as u64).unwrap();
    assert_eq!(head.params().levels, Some(levels));
    assert_eq!(head.params().root_quantizer.k(), 0, "half of level 0's k");
    let h = parse_header(&bytes).unwrap();
    let refused = |ks: &[u32], says: &str| {
        let mut bad = h.clone();
        bad.level_ks = Some(ks.to_vec());
        let e = parse_params(&bad).unwrap_err().to_string();
        assert!(e.contains(says), "{ks:?}: {e}");
    };
    refused(
        &[0, 3, 1],
        "3 per-level quantizers for a hierarchy of 4 levels",
    );
    refused(
        &[0, 3, 1, 2, 2],
        "5 per-level quantizers for a hierarchy of 4 levels",
    );
    refused(
        &[0, 2, 1, 2],
        "largest per-level quantizer k = 2 is not the header's k = 3",
    );
    // The encoder refuses the same mismatches.
    let wrong = crate::quant::LevelQuantizers::new(&[0, 3, 1]).unwrap();
    let e = crate::hierarchy::Encoder::new(&grid, top, &opts)
        .per_level(Some(wrong))
        .encode()
        .unwrap_err();
    assert!(e.to_string().contains("3 per-level quantizers"), "{e}");
}
