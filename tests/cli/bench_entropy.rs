//! `cbdam bench entropy`: the coder's bits against the entropy references, consistent with the
//! file `cbdam build` writes.

use crate::util::*;

/// The figure of the row of the totals table whose label starts with `label`, and the label.
fn total(md: &str, label: &str) -> (String, f64) {
    let line = md
        .lines()
        .find(|l| l.starts_with(&format!("| {label}")))
        .unwrap_or_else(|| panic!("no row {label:?} in\n{md}"));
    let cells: Vec<&str> = line.trim_matches('|').rsplitn(2, '|').collect();
    (
        cells[1].trim().to_string(),
        cells[0].trim().parse().unwrap(),
    )
}

#[test]
fn the_references_add_up_to_the_file_cbdam_build_writes() {
    let dir = tempfile::tempdir().unwrap();
    // The Rhine has nodata, so its records carry masks.
    for (dem, eps, coder) in [
        ("rhine_nodata.tif", "1", "adaptive-tokens"),
        ("jacksboro_mpl.tif", "2", "adaptive"),
    ] {
        let o = cbdam(&[
            "bench",
            "entropy",
            &data(dem),
            "--max-error",
            eps,
            "--coder",
            coder,
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
        let md = stdout(&o);
        let file = dir.path().join("t.cbdam");
        let b = cbdam(&[
            "build",
            &data(dem),
            "-o",
            &s(&file),
            "--max-error",
            eps,
            "--coder",
            coder,
            "--quiet",
        ]);
        assert!(b.status.success(), "{}", stderr(&b));
        let built = std::fs::metadata(&file).unwrap().len();
        let (label, whole) = total(&md, "whole file");
        assert_eq!(label, format!("whole file ({built} B)"), "{dem}: {md}");
        // The parts add up to the whole.
        let parts: f64 = ["records' bands, coded", "fixed:", "nodata masks"]
            .iter()
            .map(|l| total(&md, l).1)
            .sum();
        assert!(
            (parts - whole).abs() < 2e-4,
            "{dem}: {parts} against {whole}"
        );
        if dem.starts_with("rhine") {
            assert!(total(&md, "nodata masks").1 > 0.0, "{md}");
        }
        // Conditioning never adds information. (An adaptive coder can spend less than the
        // static entropy: it follows each record's own statistics.)
        let h0 = total(&md, "bands' H0").1;
        let hc = total(&md, "bands' H(v \\| coder ctx)").1;
        assert!(hc <= h0, "{dem}: {md}");
        // The codec's own prediction on the decoded grids gives back the coded indices.
        let again = total(&md, "codec (Neville)").1;
        assert!((again - hc).abs() < 2e-4, "{dem}: {again} against {hc}");
        let med0 = total(&md, "MED residuals (NEAR").1;
        let med_ctx = total(&md, "MED residuals: H(v \\| 365").1;
        assert!(med_ctx <= med0 && med_ctx > 0.0, "{dem}: {md}");
    }
}

#[test]
fn a_negative_tolerance_is_refused_by_name() {
    let o = cbdam(&[
        "bench",
        "entropy",
        &data("jacksboro_mpl.tif"),
        "--max-error=-1",
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("--max-error -1"), "{}", stderr(&o));
}
