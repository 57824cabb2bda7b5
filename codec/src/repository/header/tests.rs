//! The header's tests: both layouts round-trip, and damaged or hostile bytes are refused.

use super::*;

fn sample(geo: bool) -> HeaderFields {
    HeaderFields {
        version: 3,
        header_len: 0,
        flags: 1,
        n: 65,
        level_pairs: 3,
        alpha: 0,
        coder: 1,
        lattice: 1,
        geo_flags: if geo { 3 } else { 0 },
        nodata_policy: 0,
        vertical_unit: 0,
        roots_x: 1,
        roots_y: 2,
        data_width: 400,
        data_height: 333,
        quantizer_k: 100,
        root_k: None,
        leaf_error: 57,
        epsg: if geo { 26915 } else { 0 },
        unit: 0.01,
        offset: -431.5,
        epsilon: 1.0,
        representation_error: 0.0,
        geo: if geo {
            [512_345.0, 4_900_000.5, 1.0, 1.0]
        } else {
            [0.0; 4]
        },
        nodata: f64::NAN,
        wkt: None,
        provenance: None,
        rms: None,
        level_ks: None,
        sections: [
            SectionEntry {
                offset: 0,
                length: 453,
                crc: 0xDEAD_BEEF,
            },
            SectionEntry {
                offset: 0,
                length: 81,
                crc: 1,
            },
            SectionEntry {
                offset: 0,
                length: 8,
                crc: 0,
            },
            SectionEntry {
                offset: 0,
                length: 7,
                crc: u32::MAX,
            },
        ],
        record_count: 69,
        crc: 0,
    }
}

/// Everything the bytes carry, floats by their bits (NaN payloads and −0 included).
fn key(h: &HeaderFields) -> String {
    let floats: Vec<u64> = [
        h.unit,
        h.offset,
        h.epsilon,
        h.representation_error,
        h.nodata,
    ]
    .into_iter()
    .chain(h.geo)
    .chain(h.rms.into_iter().flat_map(|(t, m)| [t, m]))
    .map(f64::to_bits)
    .collect();
    let lengths: Vec<(u64, u32)> = h.sections.iter().map(|s| (s.length, s.crc)).collect();
    format!(
        "{:?}",
        (
            (h.flags, h.n, h.level_pairs, h.alpha, h.coder, h.lattice),
            (h.geo_flags, h.nodata_policy, h.vertical_unit),
            (h.roots_x, h.roots_y, h.data_width, h.data_height),
            (h.quantizer_k, h.leaf_error, h.epsg, h.record_count),
            &h.level_ks,
            floats,
            lengths
        )
    )
}

#[test]
fn compact_headers_round_trip_and_imply_the_section_offsets() {
    for geo in [false, true] {
        let h = sample(geo);
        let b = write_compact(&h).unwrap();
        let r = read_header(&b).unwrap();
        assert_eq!(key(&r), key(&h));
        assert_eq!(r.header_len, b.len());
        assert_eq!(r.root_k, None);
        // Sections follow the header without gaps.
        assert_eq!(r.sections[0].offset, b.len() as u64);
        assert_eq!(r.sections[1].offset, b.len() as u64 + 453);
        assert_eq!(r.sections[3].offset, b.len() as u64 + 453 + 81 + 8);
        // The point of version 3: well under the fixed layout's 256 bytes.
        assert!(b.len() < if geo { 110 } else { 80 }, "{} bytes", b.len());
    }
}

#[test]
fn an_rms_bound_round_trips_under_flag_bit_4_and_bad_ones_are_refused() {
    let mut h = sample(false);
    let plain = write_compact(&h).unwrap();
    h.flags |= FLAG_RMS_ERROR;
    h.rms = Some((1.0, 0.8140239554214606));
    let b = write_compact(&h).unwrap();
    assert_eq!(key(&read_header(&b).unwrap()), key(&h));
    // Only the flag's two floats are added.
    assert!(b.len() > plain.len() && b.len() <= plain.len() + 2 * 10);
    for bad in [
        (1.0, 1.5),
        (0.0, 0.0),
        (-1.0, -2.0),
        (f64::INFINITY, 1.0),
        (1.0, f64::NAN),
    ] {
        h.rms = Some(bad);
        let e = read_header(&write_compact(&h).unwrap()).unwrap_err();
        assert!(e.to_string().contains("RMS error bound"), "{bad:?}: {e}");
    }
}

#[test]
fn per_level_quantizers_round_trip_under_flag_bit_5_and_bad_counts_are_refused() {
    let mut h = sample(false);
    h.flags |= FLAG_RMS_ERROR;
    h.rms = Some((1.0, 0.9));
    let without = write_compact(&h).unwrap();
    h.flags |= FLAG_LEVEL_QUANTIZERS;
    h.level_ks = Some(vec![100, 7, 0, 100, 300, 2]);
    let b = write_compact(&h).unwrap();
    assert_eq!(key(&read_header(&b).unwrap()), key(&h));
    // A count and six varints: 1 + 1 + 1 + 1 + 1 + 2 + 1 bytes.
    assert_eq!(b.len(), without.len() + 8);
    // Without the flag the list is neither written nor read.
    h.flags &= !FLAG_LEVEL_QUANTIZERS;
    assert_eq!(write_compact(&h).unwrap(), without);
    h.flags |= FLAG_LEVEL_QUANTIZERS;
    for (ks, says) in [
        (vec![], "0 per-level quantizers"),
        (
            vec![1; crate::quant::MAX_LEVELS + 1],
            "81 per-level quantizers",
        ),
    ] {
        h.level_ks = Some(ks);
        let e = read_header(&write_compact(&h).unwrap()).unwrap_err();
        assert!(e.to_string().contains(says), "{e}");
    }
    // A value past 32 bits: the list [5] with its value respelled as the varint of 2^32.
    h.level_ks = Some(vec![5]);
    let one = write_compact(&h).unwrap();
    let at = (13..).find(|&i| one[i] != without[i]).unwrap();
    assert_eq!(one[at..at + 2], [1, 5]);
    let mut b = one[..=at].to_vec();
    b.extend_from_slice(&[0x80, 0x80, 0x80, 0x80, 0x10]);
    b.extend_from_slice(&one[at + 2..one.len() - 4]);
    let len = (b.len() + 4) as u16;
    b[10..12].copy_from_slice(&len.to_le_bytes());
    let crc = crc32(&b);
    b.extend_from_slice(&crc.to_le_bytes());
    let e = read_header(&b).unwrap_err();
    assert!(e.to_string().contains("per-level quantizer"), "{e}");
}

#[test]
fn extreme_fields_round_trip_within_the_maximum_length() {
    let mut h = sample(true);
    (h.flags, h.n, h.roots_x, h.roots_y) = (u32::MAX, u32::MAX, u32::MAX, u32::MAX);
    (h.data_width, h.data_height, h.quantizer_k) = (u32::MAX, u32::MAX, u32::MAX);
    (h.leaf_error, h.epsg, h.record_count) = (u32::MAX, u32::MAX, u64::MAX);
    (h.level_pairs, h.alpha, h.coder, h.lattice) = (255, 255, 255, 255);
    (h.nodata_policy, h.vertical_unit, h.geo_flags) = (255, 255, 255);
    h.unit = f64::from_bits(u64::MAX);
    h.offset = -0.0;
    h.epsilon = f64::MIN_POSITIVE / 3.0;
    h.representation_error = f64::INFINITY;
    h.geo = [f64::MAX, f64::MIN, f64::NEG_INFINITY, f64::from_bits(1)];
    h.nodata = f64::from_bits(0x7FF8_0000_0000_0001);
    // Flag bit 4 is among the flags: the RMS bound's extremes (measured ≤ target).
    h.rms = Some((f64::MAX, f64::MIN_POSITIVE / 3.0));
    // And bit 5: the most per-level quantizers, each the largest number.
    h.level_ks = Some(vec![u32::MAX; crate::quant::MAX_LEVELS]);
    for s in &mut h.sections {
        s.length = u64::MAX / 8;
    }
    let b = write_compact(&h).unwrap();
    assert!(b.len() <= MAX_HEADER_LEN);
    assert_eq!(key(&read_header(&b).unwrap()), key(&h));
    // Lengths that add up past u64 are refused, not wrapped.
    h.sections[3].length = u64::MAX;
    let b = write_compact(&h).unwrap();
    assert!(read_header(&b).is_err());
}

/// A CRS definition rides in the header, past the usual first fetch when it is long; one
/// that is not UTF-8 or over the limit is refused.
#[test]
fn crs_definitions_round_trip_and_bad_ones_are_refused() {
    let mut h = sample(true);
    let wkt = format!("PROJCS[\"x\",{}]", "GEOGCS[\"é\"],".repeat(200));
    h.wkt = Some(wkt.clone());
    let b = write_compact(&h).unwrap();
    assert!(b.len() > HEADER_FETCH_LEN);
    assert_eq!(header_len(&b[..HEADER_FETCH_LEN]).unwrap(), b.len());
    let r = read_header(&b).unwrap();
    assert_eq!(r.wkt.as_deref(), Some(wkt.as_str()));
    assert_eq!(key(&r), key(&h));
    assert!(read_header(&b[..HEADER_FETCH_LEN]).is_err());
    // Without georeferencing nothing is written, even if a WKT is given.
    let mut plain = sample(false);
    plain.wkt = Some(wkt);
    assert_eq!(
        read_header(&write_compact(&plain).unwrap()).unwrap().wkt,
        None
    );
    h.wkt = Some("x".repeat(crate::repository::MAX_WKT_LEN + 1));
    assert!(write_compact(&h).is_err());
    // Invalid UTF-8 in place of the definition, checksums matching.
    h.wkt = Some("PROJCS[]".to_owned());
    let mut b = write_compact(&h).unwrap();
    let at = b.windows(8).position(|w| w == b"PROJCS[]").unwrap();
    b[at] = 0xFF;
    let n = b.len();
    let crc = crc32(&b[..n - 4]);
    b[n - 4..].copy_from_slice(&crc.to_le_bytes());
    let e = read_header(&b).unwrap_err();
    assert!(e.to_string().contains("UTF-8"), "{e}");
}

#[test]
fn every_truncation_and_bit_flip_of_a_compact_header_is_an_error() {
    let b = write_compact(&sample(true)).unwrap();
    for cut in 0..b.len() {
        assert!(read_header(&b[..cut]).is_err(), "cut at {cut}");
    }
    for bit in 0..b.len() * 8 {
        let mut f = b.clone();
        f[bit / 8] ^= 1 << (bit % 8);
        assert!(read_header(&f).is_err(), "bit {bit}");
    }
}

/// Fields re-checksummed by a hostile writer: a redundant varint byte, a field running past
/// the CRC, an extra byte before it, a length outside the bounds.
#[test]
fn malformed_fields_with_valid_checksums_are_errors() {
    let good = write_compact(&sample(false)).unwrap();
    let reseal = |mut f: Vec<u8>| {
        let len = f.len() + 4;
        f[10..12].copy_from_slice(&(len as u16).to_le_bytes());
        let crc = crc32(&f);
        f.extend_from_slice(&crc.to_le_bytes());
        f
    };
    let body = &good[..good.len() - 4];
    // flags = 1 written as the two bytes 0x81 0x00.
    assert_eq!(body[12], 1);
    let mut f = body[..12].to_vec();
    f.extend_from_slice(&[0x81, 0x00]);
    f.extend_from_slice(&body[13..]);
    let e = read_header(&reseal(f)).unwrap_err();
    assert!(e.to_string().contains("redundant"), "{e}");
    // One byte too many, one too few.
    let mut f = body.to_vec();
    f.push(0);
    assert!(
        read_header(&reseal(f))
            .unwrap_err()
            .to_string()
            .contains("unexpected")
    );
    let f = body[..body.len() - 1].to_vec();
    assert!(
        read_header(&reseal(f))
            .unwrap_err()
            .to_string()
            .contains("end early")
    );
    // A stated length past the bytes there are, or too short for a CRC.
    for len in [good.len() + 1, 3] {
        let mut f = good.clone();
        f[10..12].copy_from_slice(&(len as u16).to_le_bytes());
        assert!(read_header(&f).is_err(), "length {len}");
    }
    // Not the magic.
    let mut f = good.clone();
    f[0] ^= 1;
    assert!(read_header(&f).unwrap_err().to_string().contains("magic"));
}
