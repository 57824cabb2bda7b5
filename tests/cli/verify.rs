//! `cbdam verify`: damaged repositories and wrong inputs it must catch, the nodata mask, raw
//! inputs.

use cbdam_codec::repository::{Repository, Section, craft_header};

use super::write_asc;
use crate::util::*;

#[test]
fn verify_catches_a_damaged_record_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("t.cbdam");
    let input = data("jacksboro_mpl.tif");
    build_quiet(&input, &out, "1");
    let repo = Repository::open(&out).unwrap();
    let records = repo.head().section_len(Section::Records) as usize;
    // The longest record (some records are empty: all residuals zero).
    let victim = (0..repo.head().entries().len())
        .max_by_key(|&i| repo.head().entries()[i].length)
        .unwrap();
    let e = repo.head().entries()[victim];
    drop(repo);
    let mut bytes = std::fs::read(&out).unwrap();
    let at = bytes.len() - records + e.offset as usize + e.length as usize / 2;
    bytes[at] ^= 0x01;
    std::fs::write(&out, &bytes).unwrap();
    let o = cbdam(&["verify", &s(&out), "--against", &input]);
    assert!(!o.status.success());
    let err = stderr(&o);
    assert!(err.contains(&format!("record {victim}")), "{err}");
    assert!(err.contains(&format!("level {}", e.id.level)), "{err}");
    // Inspect reads only the header and index, which are intact.
    assert!(cbdam(&["inspect", &s(&out)]).status.success());

    // A truncated file fails to open, in both commands.
    std::fs::write(&out, &bytes[..bytes.len() - 1]).unwrap();
    let out_s = s(&out);
    for args in [
        vec!["inspect", &out_s],
        vec!["verify", &out_s, "--against", &input],
    ] {
        let o = cbdam(&args);
        assert!(!o.status.success(), "{args:?}");
        assert!(stderr(&o).contains("truncated"), "{}", stderr(&o));
    }
}

#[test]
fn verify_rejects_the_wrong_input() {
    let dir = tempfile::tempdir().unwrap();
    let rows: Vec<Vec<f64>> = (0..20)
        .map(|y| (0..30).map(|x| f64::from(x * 3 + (y * 2) % 7)).collect())
        .collect();
    let asc = dir.path().join("a.asc");
    write_asc(&asc, &rows, None);
    let out = s(&dir.path().join("a.cbdam"));
    build_quiet(&s(&asc), std::path::Path::new(&out), "2");
    assert!(
        cbdam(&["verify", &out, "--against", &s(&asc)])
            .status
            .success()
    );

    // One sample moved by far more than the tolerance.
    let mut moved = rows.clone();
    moved[11][17] += 10.0;
    let bad = dir.path().join("moved.asc");
    write_asc(&bad, &moved, None);
    let o = cbdam(&["verify", &out, "--against", &s(&bad)]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("violated"), "{}", stderr(&o));

    // A different grid size.
    let o = cbdam(&["verify", &out, "--against", &data("jacksboro_mpl.tif")]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("403×344"), "{}", stderr(&o));
}

/// `verify` checks the nodata mask sample by sample: an input whose nodata differs in a single
/// sample (valid there, within the tolerance of the decoded surface) is rejected by name.
#[test]
fn verify_checks_the_nodata_mask() {
    let dir = tempfile::tempdir().unwrap();
    let rows: Vec<Vec<f64>> = (0..20)
        .map(|y| (0..30).map(|x| f64::from(x * 3 + (y * 2) % 7)).collect())
        .collect();
    let mut holed = rows.clone();
    for (y, row) in holed.iter_mut().enumerate() {
        for (x, v) in row.iter_mut().enumerate() {
            if (x + 2 * y) % 9 == 0 || (10..14).contains(&x) {
                *v = -9999.0;
            }
        }
    }
    let asc = dir.path().join("h.asc");
    write_asc(&asc, &holed, Some(-9999.0));
    let out = s(&dir.path().join("h.cbdam"));
    build_quiet(&s(&asc), std::path::Path::new(&out), "2");
    let o = cbdam(&["verify", &out, "--against", &s(&asc)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("0 mismatches"), "{}", stdout(&o));

    // Sample (12, 5) had no data; give it its true height.
    let mut filled = holed.clone();
    filled[5][12] = rows[5][12];
    let bad = dir.path().join("filled.asc");
    write_asc(&bad, &filled, Some(-9999.0));
    let o = cbdam(&["verify", &out, "--against", &s(&bad)]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("nodata mask disagrees with the input at 1 samples")
            && stderr(&o).contains("column 12, row 5"),
        "{}",
        stderr(&o)
    );
}

/// `verify --against` a raw float32 file: it carries no size, so the repository's is used; a
/// file of another length is refused with both sizes named. (It used to fail on every raw
/// input, asking for a size `verify` has no option for.)
#[test]
fn verify_reads_a_raw_input_at_the_repositorys_size() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (40usize, 30usize);
    let values: Vec<f32> = (0..w * h)
        .map(|i| 250.0 + ((i % w) as f32 * 0.3).sin() * 20.0 + (i / w) as f32 * 0.5)
        .collect();
    let raw = dir.path().join("plane.f32");
    std::fs::write(
        &raw,
        values
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect::<Vec<u8>>(),
    )
    .unwrap();
    let repo = dir.path().join("plane.cbdam");
    let o = cbdam(&[
        "build",
        &s(&raw),
        "--size",
        "40x30",
        "-o",
        &s(&repo),
        "--max-error",
        "0.5",
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = cbdam(&["verify", &s(&repo), "--against", &s(&raw)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("OK"), "{}", stdout(&o));
    let short = dir.path().join("short.f32");
    std::fs::write(&short, &std::fs::read(&raw).unwrap()[..1000]).unwrap();
    let o = cbdam(&["verify", &s(&repo), "--against", &s(&short)]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains("1000 bytes") && stderr(&o).contains("40 x 30"),
        "{}",
        stderr(&o)
    );
}

/// One input file decoded block by block (what a file too large to decode whole gets): the same
/// per-level findings as decoding it whole, and the same DEM 10 m higher refused.
#[test]
fn one_file_verifies_block_by_block() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("r.cbdam");
    let input = data("rhine_nodata.tif");
    build_quiet(&input, &out, "1");
    let verify_in_blocks = |against: &str| {
        cbdam(&[
            "verify",
            &s(&out),
            "--against",
            against,
            "--block-plan",
            "2,64",
        ])
    };
    let blocks = verify_in_blocks(&input);
    let text = stdout(&blocks);
    assert!(blocks.status.success(), "{text}{}", stderr(&blocks));
    assert!(text.contains("decoded in") && text.contains("OK"), "{text}");
    let whole = stdout(&cbdam(&["verify", &s(&out), "--against", &input]));
    let levels = |t: &str| -> Vec<String> {
        t.lines()
            .filter(|l| l.trim_start().starts_with(|c: char| c.is_ascii_digit()))
            .map(String::from)
            .collect()
    };
    assert!(!levels(&whole).is_empty());
    assert_eq!(levels(&text), levels(&whole));
    // Every sample with data 10 m higher (nodata left as it is).
    let mut dem = cbdam_builder::input::read_dem(
        std::path::Path::new(&input),
        &cbdam_builder::input::ReadOptions::default(),
    )
    .unwrap();
    let nodata = dem.nodata;
    for v in &mut dem.values {
        if Some(*v) != nodata && !v.is_nan() {
            *v += 10.0;
        }
    }
    let shifted = dir.path().join("shifted.tif");
    let raster = cbdam_builder::write::Raster {
        width: dem.width,
        height: dem.height,
        values: dem.values,
        georef: dem.georef,
    };
    let file = std::fs::File::create(&shifted).unwrap();
    cbdam_builder::write::write_geotiff(file, &raster, nodata, false).unwrap();
    let o = verify_in_blocks(&s(&shifted));
    assert!(!o.status.success(), "{}", stdout(&o));
    // 10 m is 80 units: every level is past the bound of 7.
    assert!(stderr(&o).contains("L∞ bound violated"), "{}", stderr(&o));
}

/// `verify` compares the georeferencing and the nodata value the header records with the
/// input's: a repository whose header places the data elsewhere, or forgets the input's nodata
/// value, fails with a message naming what differs (the heights alone would pass).
#[test]
fn verify_compares_georeferencing_and_nodata_with_the_input() {
    let dir = tempfile::tempdir().unwrap();
    let asc = dir.path().join("a.asc");
    let mut rows = vec![vec![10.0, 12.0, 15.0, 11.0, 9.0]; 4];
    rows[1][2] = -9999.0;
    write_asc(&asc, &rows, Some(-9999.0));
    let out = dir.path().join("t.cbdam");
    build_quiet(&s(&asc), &out, "0.5");
    let verify = |repo: &std::path::Path| cbdam(&["verify", &s(repo), "--against", &s(&asc)]);
    let o = verify(&out);
    assert!(o.status.success(), "{}", stderr(&o));
    let good = std::fs::read(&out).unwrap();
    let crafted = dir.path().join("crafted.cbdam");
    for (field, value, message) in [
        ("origin_x", 1000.0, "georeferencing differs"),
        ("pixel_y", 2.0, "georeferencing differs"),
        (
            "nodata",
            f64::NAN,
            "declares the nodata value -9999, the repository records none",
        ),
    ] {
        std::fs::write(
            &crafted,
            craft_header(&good, field, f64::to_bits(value)).unwrap(),
        )
        .unwrap();
        let o = verify(&crafted);
        assert!(!o.status.success(), "{field} = {value}: verify passed");
        assert!(
            stderr(&o).contains(message),
            "{field} = {value}: {}",
            stderr(&o)
        );
    }
    // The build's --nodata overrides the file's value: that is no mismatch.
    let o = cbdam(&[
        "build",
        &s(&asc),
        "-o",
        &s(&out),
        "--max-error",
        "0.5",
        "--quiet",
        "--nodata",
        "-9999.5",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = verify(&out);
    assert!(!stderr(&o).contains("nodata differs"), "{}", stderr(&o));
}

/// Issue 50, item 4: with a decimal `--quantum`, heights are reconstructed as
/// `offset + n·unit` in `f64`, which rounds by up to ~2e-13 m at ±8000 m. The build stated
/// "0.001 m guaranteed" and its own `verify` then failed by that much; now the guarantee names
/// the rounding term and `verify` checks against exactly it. Float64 input (an ASCII grid), a
/// ±8000 m checkerboard and a ramp of whole metres, at quanta from 0.001 to 0.2 m.
#[test]
fn decimal_quanta_builds_verify_against_their_stated_bound() {
    let dir = tempfile::tempdir().unwrap();
    let side = 48;
    let checkerboard: Vec<Vec<f64>> = (0..side)
        .map(|y| {
            (0..side)
                .map(|x| {
                    if (x / 4 + y / 4) % 2 == 0 {
                        8000.0
                    } else {
                        -8000.0
                    }
                })
                .collect()
        })
        .collect();
    let ramp: Vec<Vec<f64>> = (0..side)
        .map(|y| {
            (0..side)
                .map(|x| f64::from(x + y) * 170.0 - 8000.0)
                .collect()
        })
        .collect();
    for (name, rows) in [("checkerboard", &checkerboard), ("ramp", &ramp)] {
        let input = dir.path().join(format!("{name}.asc"));
        write_asc(&input, rows, None);
        for q in ["0.001", "0.01", "0.05", "0.1", "0.2"] {
            let out = dir.path().join(format!("{name}-{q}.cbdam"));
            let o = cbdam(&[
                "build",
                &s(&input),
                "--quantum",
                q,
                "--max-error",
                q,
                "-o",
                &s(&out),
            ]);
            assert!(o.status.success(), "{name} at {q}: {}", stderr(&o));
            let said = stdout(&o);
            assert!(
                said.contains(&format!("max error {q} m + ")) && said.contains("of float rounding"),
                "{name} at {q}: {said}"
            );
            let o = cbdam(&["verify", &s(&out), "--against", &s(&input)]);
            assert!(
                o.status.success(),
                "{name} at {q}: {}{}",
                stdout(&o),
                stderr(&o)
            );
        }
    }
}
