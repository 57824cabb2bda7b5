//! The single-file container: round trips, atomic writes, and hostile files (every truncation,
//! single-bit flips, random bytes) that must give an error — never a panic, never silent
//! acceptance.

use crate::util::Rng;
use cbdam_codec::CodecError;
use cbdam_codec::entropy::CoderKind;
use cbdam_codec::hierarchy::{EncodeOptions, Encoded, Encoder, reconstruct_finest, verify};
use cbdam_codec::lifting::Alpha;
use cbdam_codec::quant::{HeightGrid, QuantPlan};
use cbdam_codec::repository::GeoRef;
use cbdam_codec::repository::index::{IndexEntry, range_shift_for};
use cbdam_codec::repository::{
    FORMAT_VERSION, HEADER_FETCH_LEN, MAX_MAGNITUDE, Repository, RepositoryHead, Section,
    craft_header, required_head_len, reseal_checksums, serialize, write_repository,
};

/// A small hierarchy with nodata holes, rough enough that records are non-trivial.
fn fixture(alpha: Alpha, coder: CoderKind) -> (Encoded, QuantPlan, HeightGrid) {
    let (w, h) = (37usize, 23usize);
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    let metres: Vec<f64> = (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as f64, (i / w) as f64);
            if (x - 20.0).hypot(y - 5.0) < 3.0 {
                return -9999.0;
            }
            // A flat strip: records there have only zero residuals, so they are empty.
            if y >= 15.0 {
                return 100.0;
            }
            100.0 + 10.0 * (x / 5.0).sin() * (y / 7.0).cos() + (rng.next() % 100) as f64 / 50.0
        })
        .collect();
    let plan = QuantPlan::new(0.5, None, 85.0, 115.0).unwrap();
    let grid = HeightGrid::from_metres(w, h, &metres, Some(-9999.0), &plan).unwrap();
    let opts = EncodeOptions {
        n: 9,
        alpha,
        coder,
        ..EncodeOptions::default()
    };
    (
        Encoder::new(&grid, plan.quantizer, &opts).encode().unwrap(),
        plan,
        grid,
    )
}

fn georef() -> GeoRef {
    GeoRef {
        epsg: Some(32615),
        origin_x: 500000.5,
        origin_y: 4_900_000.25,
        pixel_x: 1.0,
        pixel_y: 1.0,
        pixel_is_area: true,
        wkt: None,
    }
}

fn image() -> Vec<u8> {
    let (enc, plan, _) = fixture(Alpha::One, CoderKind::Adaptive);
    serialize(&enc, &plan, Some(&georef()), Some(-9999.0)).unwrap()
}

/// `read` is `written` as a repository gives it back: everything identical except each record's
/// height range, which the version-2 index stores rounded outward to multiples of
/// `2^range_shift_for(quantizer)` units (a bound, looser by less than one quantizer step).
fn assert_same_hierarchy(read: &Encoded, written: &Encoded) {
    let q = 1i32 << range_shift_for(written.params.quantizer);
    assert!(q > 1, "the fixture should exercise rounded ranges");
    assert_eq!(read.params, written.params);
    assert_eq!(read.roots, written.roots);
    assert_eq!(read.leaf_error, written.leaf_error);
    assert_eq!(read.records.len(), written.records.len());
    for (r, w) in read.records.iter().zip(&written.records) {
        assert_eq!(
            (r.id, &r.bytes, r.object_error),
            (w.id, &w.bytes, w.object_error)
        );
        assert!(r.min <= w.min && w.max <= r.max, "{}: {r:?} vs {w:?}", w.id);
        assert!(w.min - r.min < q && r.max - w.max < q, "{}", w.id);
    }
}

/// Opening plus checking every record: what a full reader does.
fn load(bytes: Vec<u8>) -> Result<Repository, CodecError> {
    let r = Repository::from_bytes(bytes)?;
    r.check_all()?;
    Ok(r)
}

/// The header length a file states (bytes 10–11).
fn header_len(b: &[u8]) -> usize {
    usize::from(u16::from_le_bytes([b[10], b[11]]))
}

fn is_data_error(e: &CodecError) -> bool {
    matches!(
        e,
        CodecError::Corrupt(_) | CodecError::Truncated(_) | CodecError::Unsupported(_)
    )
}

#[test]
fn round_trip_every_configuration() {
    for alpha in [Alpha::One, Alpha::Half] {
        for coder in CoderKind::ALL {
            let (enc, plan, grid) = fixture(alpha, coder);
            for geo in [None, Some(georef())] {
                let bytes = serialize(&enc, &plan, geo.as_ref(), None).unwrap();
                let repo = load(bytes.clone()).unwrap();
                assert_same_hierarchy(&repo.to_encoded().unwrap(), &enc);
                // Written again, what was read is the same file: rounding is idempotent.
                assert_eq!(
                    serialize(&repo.to_encoded().unwrap(), &plan, geo.as_ref(), None).unwrap(),
                    bytes
                );
                assert_eq!(*repo.head().plan(), plan);
                assert_eq!(repo.head().georef(), geo.as_ref());
                assert_eq!(repo.head().nodata(), None);
                assert_eq!(repo.head().leaf_error(), enc.leaf_error);
                let ids = |e: &[IndexEntry]| {
                    e.iter()
                        .map(|e| (e.id, e.offset, e.length))
                        .collect::<Vec<_>>()
                };
                assert_eq!(ids(repo.head().entries()), ids(&enc.index_entries()));
                assert_eq!(repo.head().file_len(), bytes.len() as u64);
                let non_empty = enc.records.iter().filter(|r| !r.bytes.is_empty()).count();
                assert_eq!(
                    repo.head().section_len(Section::Checksums),
                    4 * non_empty as u64
                );
                for r in &enc.records {
                    assert_eq!(repo.record(r.id).unwrap(), &r.bytes[..]);
                }
                let report = verify(&repo.to_encoded().unwrap(), &grid).unwrap();
                assert!(report.within_bound());
                // The decoder from the file decodes the same root field as the in-memory one.
                assert_eq!(repo.head().decoder().unwrap().params(), &enc.params);
                assert_eq!(
                    reconstruct_finest(&repo.to_encoded().unwrap()).unwrap(),
                    reconstruct_finest(&enc).unwrap()
                );
            }
        }
    }
}

#[test]
fn write_is_atomic_and_open_maps_the_same_bytes() {
    let (enc, plan, _) = fixture(Alpha::One, CoderKind::Adaptive);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t.cbdam");
    std::fs::write(&path, b"old contents").unwrap();
    write_repository(&path, &enc, &plan, Some(&georef()), Some(-9999.0)).unwrap();
    let expected = serialize(&enc, &plan, Some(&georef()), Some(-9999.0)).unwrap();
    assert_eq!(std::fs::read(&path).unwrap(), expected);
    let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
    assert_eq!(names.len(), 1, "temporary file left behind: {names:?}");
    let repo = Repository::open(&path).unwrap();
    repo.check_all().unwrap();
    assert_eq!(repo.head().nodata(), Some(-9999.0));
    assert_same_hierarchy(&repo.to_encoded().unwrap(), &enc);

    // A directory is refused and left alone.
    let e = write_repository(dir.path(), &enc, &plan, None, None).unwrap_err();
    assert!(e.to_string().contains("is a directory"), "{e}");
    // A missing directory: an error, and nothing created.
    let missing = dir.path().join("nope").join("t.cbdam");
    assert!(write_repository(&missing, &enc, &plan, None, None).is_err());
    assert!(!dir.path().join("nope").exists());
    // Tiny files are reported as truncated, not as mapping failures.
    let tiny = dir.path().join("tiny.cbdam");
    std::fs::write(&tiny, b"").unwrap();
    assert!(matches!(
        Repository::open(&tiny).unwrap_err(),
        CodecError::Truncated(_)
    ));
}

#[test]
fn every_truncation_is_an_error() {
    let bytes = image();
    load(bytes.clone()).expect("the intact image loads");
    for len in 0..bytes.len() {
        match load(bytes[..len].to_vec()) {
            Ok(_) => panic!("truncation to {len} of {} bytes accepted", bytes.len()),
            Err(e) => assert!(is_data_error(&e), "truncation to {len}: {e}"),
        }
    }
    // One byte too many is not a valid file either.
    let mut longer = bytes.clone();
    longer.push(0);
    assert!(load(longer).is_err());
}

#[test]
fn every_single_bit_flip_is_an_error() {
    let bytes = image();
    load(bytes.clone()).expect("the intact image loads");
    assert!(
        bytes.len() * 8 <= 40_000,
        "fixture grew: sample the bits instead"
    );
    let repo = Repository::from_bytes(bytes.clone()).unwrap();
    // Enough records that flips land in several of them and in the index's mask and fields.
    assert!(
        repo.head().entries().len() >= 8,
        "{} records",
        repo.head().entries().len()
    );
    let empty = repo
        .head()
        .entries()
        .iter()
        .filter(|e| e.length == 0)
        .count();
    assert!(
        empty > 0 && empty < repo.head().entries().len() - 4,
        "{empty} empty records: the fixture should have both kinds"
    );
    for bit in 0..bytes.len() * 8 {
        let mut b = bytes.clone();
        b[bit / 8] ^= 1 << (bit % 8);
        match load(b) {
            Ok(_) => panic!("flip of bit {bit} (byte {}) accepted", bit / 8),
            Err(e) => assert!(is_data_error(&e), "bit {bit}: {e}"),
        }
    }
}

#[test]
fn a_damaged_record_names_itself() {
    let bytes = image();
    let repo = load(bytes.clone()).unwrap();
    let records_at = bytes.len() - repo.head().section_len(Section::Records) as usize;
    // Some records are empty (all residuals zero); damage the longest.
    let victim = (0..repo.head().entries().len())
        .max_by_key(|&i| repo.head().entries()[i].length)
        .unwrap();
    let e = repo.head().entries()[victim];
    let mut b = bytes;
    b[records_at + e.offset as usize] ^= 0x10;
    // Opening does not scan records; reading the damaged one does, and only that one fails.
    let repo = Repository::from_bytes(b).unwrap();
    let err = repo.record(e.id).unwrap_err().to_string();
    assert!(err.contains(&format!("record {victim}")), "{err}");
    for i in (0..repo.head().entries().len()).filter(|&i| i != victim) {
        assert!(repo.record_at(i).is_ok(), "record {i}");
    }
    assert!(repo.to_encoded().is_err());
}

#[test]
fn random_files_are_errors() {
    let good = image();
    let mut rng = Rng(0xDEAD_BEEF);
    for round in 0..3000 {
        let len = (rng.next() % 2048) as usize;
        let mut b: Vec<u8> = (0..len).map(|_| rng.next() as u8).collect();
        // Most rounds get a valid magic and version, some a valid header, so the parser is
        // exercised past its first checks.
        if round % 3 != 0 && len >= 10 {
            b[..8].copy_from_slice(&good[..8]);
            b[8..10].copy_from_slice(&FORMAT_VERSION.to_le_bytes());
        }
        let hl = header_len(&good);
        if round % 3 == 2 && len >= hl {
            b[..hl].copy_from_slice(&good[..hl]);
        }
        if let Err(e) = load(b) {
            assert!(is_data_error(&e), "round {round}: {e}");
        } else {
            panic!("random file of round {round} accepted");
        }
    }
}

#[test]
fn newer_versions_are_refused_by_name() {
    let mut b = image();
    b[8..10].copy_from_slice(&(FORMAT_VERSION + 1).to_le_bytes());
    let e = load(b).unwrap_err();
    assert!(matches!(e, CodecError::Unsupported(_)), "{e}");
    assert!(e.to_string().contains("newer"), "{e}");
}

/// A hostile writer can compute checksums too: every header byte set to a few values, every
/// CRC fixed up, must still give an error or a repository that decodes without panicking.
#[test]
fn hostile_headers_with_valid_checksums_never_panic() {
    let good = image();
    let mut rng = Rng(99);
    let mut refused = 0;
    let mut tried = 0;
    let hl = header_len(&good);
    for at in 0..hl - 4 {
        let values = [0u8, 1, 2, 0x7F, 0x80, 0xFF, rng.next() as u8];
        for v in values {
            if good[at] == v {
                continue;
            }
            let mut b = good.clone();
            b[at] = v;
            // Every checksum made to match, so the field checks behind them are what answers.
            reseal_checksums(&mut b);
            tried += 1;
            match load(b) {
                Err(e) => {
                    assert!(is_data_error(&e), "byte {at} = {v}: {e}");
                    refused += 1;
                }
                // Accepted: a field without structural meaning (georeferencing, tolerance,
                // leaf error…). The hierarchy must still decode without panicking.
                Ok(repo) => {
                    if let Ok(enc) = repo.to_encoded() {
                        let _ = reconstruct_finest(&enc);
                    }
                }
            }
        }
    }
    // Most header bytes are structural; the test must be reaching the field checks.
    assert!(
        refused * 2 > tried,
        "only {refused} of {tried} hostile headers refused"
    );
}

/// Fields that are each finite but make what readers derive from them infinite or absurd,
/// written by a hostile writer with every checksum matching: each is refused when the file is
/// opened (the repository and the head a remote client parses alike), by an error that names
/// the field and its value, so no reader, server or viewer meets a non-finite height or
/// coordinate.
#[test]
fn crafted_headers_with_valid_checksums_and_absurd_derived_values_are_refused_by_name() {
    let good = image();
    // The fixture's plan: unit 1/16 m, not lattice input; 1 m pixels.
    let cases: &[(&str, f64, &str)] = &[
        // offset ± unit · 44 000 000 overflows to ±inf.
        ("unit", 1e308, "height unit 1e308"),
        ("unit", 1e300, "height unit 1e300"),
        ("offset", 1e308, "offset 1e308"),
        ("offset", -f64::MAX, "heights it spans"),
        // origin + pixel · extent overflows, or lies past any planet.
        ("pixel_x", 1e307, "pixel size x 1e307"),
        ("pixel_y", -f64::MAX, "pixel size y"),
        ("origin_x", 1e308, "origin x"),
        ("origin_y", MAX_MAGNITUDE * 2.0, "origin y 2000000000000000"),
        // Not lattice input: the representation error must be 0.
        ("representation_error", 0.01, "representation error 0.01"),
    ];
    for &(field, value, named) in cases {
        let b = craft_header(&good, field, value.to_bits()).unwrap();
        let e = Repository::from_bytes(b.clone()).unwrap_err();
        assert!(
            matches!(e, CodecError::Corrupt(_)),
            "{field} = {value}: {e}"
        );
        assert!(e.to_string().contains(named), "{field} = {value}: {e}");
        let head = RepositoryHead::parse(&b, b.len() as u64).unwrap_err();
        assert_eq!(head.to_string(), e.to_string());
    }
    // Large but sane values still open: the check is on meaning, not on a value's size.
    for (field, value) in [("origin_x", 6.4e6), ("origin_y", -1e9), ("offset", 8848.0)] {
        let b = craft_header(&good, field, f64::to_bits(value)).unwrap();
        let repo = load(b).unwrap_or_else(|e| panic!("{field} = {value}: {e}"));
        let plan = repo.head().plan();
        for h in [-44_000_000, 44_000_000] {
            assert!(plan.metres(h).is_finite());
        }
    }
    // Crafting rewrites the header only: the same value gives back the same bytes.
    let same = craft_header(&good, "unit", (1.0f64 / 16.0).to_bits()).unwrap();
    assert_eq!(same, good);
}

/// A writer never writes what a reader would refuse: a plan whose heights overflow is refused
/// before anything is written.
#[test]
fn repositories_readers_would_refuse_are_not_written() {
    let (enc, mut plan, _) = fixture(Alpha::One, CoderKind::Adaptive);
    plan.unit = 1e300;
    let e = serialize(&enc, &plan, Some(&georef()), None).unwrap_err();
    assert!(matches!(e, CodecError::InvalidParameter(_)), "{e}");
    assert!(e.to_string().contains("height unit 1e300"), "{e}");
}

/// What a remote client does: fetch the header, learn the head's length, fetch the head, then
/// check each record it fetches. The head must agree with the mapped repository, accept every
/// true record and refuse altered ones, and refuse every too-short prefix without panicking.
#[test]
fn head_from_a_prefix_checks_records_like_the_repository() {
    let bytes = image();
    let repo = load(bytes.clone()).unwrap();
    let hl = header_len(&bytes);
    let len = required_head_len(&bytes[..HEADER_FETCH_LEN.min(bytes.len())]).unwrap() as usize;
    assert_eq!(len, required_head_len(&bytes[..hl]).unwrap() as usize);
    assert!(len < bytes.len());
    let head = RepositoryHead::parse(&bytes[..len], bytes.len() as u64).unwrap();
    assert_eq!(head.entries(), repo.head().entries());
    assert_eq!(head.params(), repo.head().params());
    assert_eq!(head.root_bytes(), repo.head().root_bytes());
    assert_eq!(head.records_offset() as usize, len);
    let mut non_empty = 0;
    for (i, _) in head.entries().iter().enumerate() {
        let r = head.record_range(i).unwrap();
        let record = &bytes[r.start as usize..r.end as usize];
        assert_eq!(record, repo.record_at(i).unwrap());
        head.check_record(i, record).unwrap();
        if record.is_empty() {
            continue;
        }
        non_empty += 1;
        let mut bad = record.to_vec();
        bad[record.len() / 2] ^= 0x10;
        assert!(matches!(
            head.check_record(i, &bad),
            Err(CodecError::Corrupt(_))
        ));
        assert!(head.check_record(i, &record[1..]).is_err());
    }
    assert!(non_empty > 3, "the fixture should have real records");
    assert!(head.check_record(head.entries().len(), &[]).is_err());
    for cut in 0..len {
        let e = RepositoryHead::parse(&bytes[..cut], bytes.len() as u64).unwrap_err();
        assert!(is_data_error(&e), "prefix {cut}: {e}");
    }
    // The same head bytes claiming a different file length contradict the section table.
    assert!(RepositoryHead::parse(&bytes[..len], bytes.len() as u64 + 1).is_err());
    for cut in 0..hl {
        assert!(
            required_head_len(&bytes[..cut]).is_err(),
            "header prefix {cut}"
        );
    }
}

/// The accessors a server needs to serve the file verbatim agree with the writer's layout.
#[test]
fn raw_accessors_match_the_layout() {
    let (enc, plan, _) = fixture(Alpha::One, CoderKind::Adaptive);
    let bytes = serialize(&enc, &plan, Some(&georef()), None).unwrap();
    let repo = Repository::from_bytes(bytes.clone()).unwrap();
    let hl = header_len(&bytes);
    assert_eq!(repo.as_bytes(), &bytes[..]);
    assert_eq!(
        repo.head().header_crc(),
        u32::from_le_bytes(bytes[hl - 4..hl].try_into().unwrap())
    );
    assert_eq!(repo.head().header_len(), hl);
    assert_eq!(repo.head().section_offset(Section::Roots), hl as u64);
    // The records area is last: everything before it is header + roots + index + checksums.
    let head = repo.head().section_offset(Section::Records);
    assert_eq!(
        head + repo.head().section_len(Section::Records),
        repo.head().file_len()
    );
    assert_eq!(
        head,
        hl as u64
            + repo.head().section_len(Section::Roots)
            + repo.head().section_len(Section::Index)
            + repo.head().section_len(Section::Checksums)
    );
    let mut empty = 0;
    for (i, r) in enc.records.iter().enumerate() {
        match repo.head().record_checksum(i) {
            Some(c) => assert_eq!(c, crc32fast::hash(&r.bytes)),
            None => {
                assert!(r.bytes.is_empty());
                empty += 1;
            }
        }
    }
    assert!(empty > 0, "the fixture has a flat strip of empty records");
    assert_eq!(repo.head().record_checksum(enc.records.len()), None);
}
