//! `cbdam build` refusing what it cannot build, each by name and leaving nothing behind: bad
//! tolerances and inputs, special files (FIFOs) given or placed, an output that is one of the
//! inputs, a VRT with a non-finite geotransform, an infinite nodata value.

use std::path::Path;

use super::write_asc;
use crate::util::*;

/// Runs a build that must fail with `message` and leave `dir` as it was.
fn build_fails(dir: &Path, input: &str, out: &Path, extra: &[&str], message: &str) {
    let out_s = s(out);
    let mut args = vec!["build", input, "-o", &out_s];
    args.extend_from_slice(extra);
    run_refused_leaving(dir, &args, &[message]);
}

#[test]
fn bad_inputs_fail_without_output() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.cbdam");
    let jb = data("jacksboro_mpl.tif");
    for (e, msg) in [
        ("0", "positive"),
        ("-1", "positive"),
        ("NaN", "positive"),
        ("inf", "positive"),
        // Jacksboro spans 236…1076 m.
        ("900", "height range"),
    ] {
        build_fails(dir.path(), &jb, &out, &[&format!("--max-error={e}")], msg);
    }
    // Every sample nodata.
    let asc = dir.path().join("nodata.asc");
    write_asc(&asc, &vec![vec![-9999.0; 5]; 4], Some(-9999.0));
    build_fails(
        dir.path(),
        &s(&asc),
        &out,
        &["--max-error", "1"],
        "no valid sample",
    );
    // The same file becomes valid once its nodata value is overridden, so --nodata is honoured.
    let o = cbdam(&[
        "build",
        &s(&asc),
        "-o",
        &s(&out),
        "--max-error",
        "1",
        "--nodata",
        "-1",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    std::fs::remove_file(&out).unwrap();
    // --nodata can also make every sample invalid.
    let flat = dir.path().join("flat.asc");
    write_asc(&flat, &vec![vec![7.0; 5]; 4], None);
    build_fails(
        dir.path(),
        &s(&flat),
        &out,
        &["--max-error", "1", "--nodata", "7"],
        "no valid sample",
    );
    // Unreadable inputs.
    let missing = s(&dir.path().join("missing.tif"));
    build_fails(
        dir.path(),
        &missing,
        &out,
        &["--max-error", "1"],
        "missing.tif",
    );
    let garbage = dir.path().join("garbage.tif");
    std::fs::write(&garbage, b"this is not a tiff at all").unwrap();
    build_fails(
        dir.path(),
        &s(&garbage),
        &out,
        &["--max-error", "1"],
        "garbage.tif",
    );
    // Output is a directory.
    let sub = dir.path().join("sub");
    std::fs::create_dir(&sub).unwrap();
    build_fails(
        dir.path(),
        &jb,
        &sub,
        &["--max-error", "1"],
        "is a directory",
    );
    assert!(listing(&sub).is_empty());
    // Output directory missing: an error naming it before any work (it used to surface only
    // when the finished repository was written, after the encode), nothing created.
    let deep = dir.path().join("no").join("such").join("out.cbdam");
    build_fails(
        dir.path(),
        &jb,
        &deep,
        &["--max-error", "1"],
        "such does not exist",
    );
    let o = cbdam(&["build", &jb, "-o", &s(&deep), "--max-error", "1"]);
    assert!(!stderr(&o).contains("encod"), "{}", stderr(&o));
}

#[cfg(unix)]
fn mkfifo(path: &Path) {
    use std::os::unix::ffi::OsStrExt;
    let c = std::ffi::CString::new(path.as_os_str().as_bytes()).unwrap();
    // SAFETY: `c` is a NUL-terminated path that outlives the call.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0, "mkfifo");
}

/// A VRT placing `source` (relative to the VRT) with this `GeoTransform`.
fn write_vrt(path: &Path, source: &str, geo_transform: &str) {
    std::fs::write(
        path,
        format!(
            r#"<VRTDataset rasterXSize="5" rasterYSize="4">
  <GeoTransform>{geo_transform}</GeoTransform>
  <VRTRasterBand dataType="Float32" band="1">
    <SimpleSource>
      <SourceFilename relativeToVRT="1">{source}</SourceFilename>
      <SourceBand>1</SourceBand>
      <SrcRect xOff="0" yOff="0" xSize="5" ySize="4" />
      <DstRect xOff="0" yOff="0" xSize="5" ySize="4" />
    </SimpleSource>
  </VRTRasterBand>
</VRTDataset>
"#
        ),
    )
    .unwrap();
}

/// A FIFO (or any file that is not a regular file) given as an input, listed in an @LIST or
/// placed by a VRT is refused by its type, naming it, instead of blocking the build forever on
/// the open.
#[cfg(unix)]
#[test]
fn special_files_are_refused_by_type_not_waited_on() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.cbdam");
    let fifo = dir.path().join("pipe.asc");
    mkfifo(&fifo);
    let vrt = dir.path().join("tiles.vrt");
    write_vrt(&vrt, "pipe.asc", "0, 1, 0, 4, 0, -1");
    let list = dir.path().join("inputs.txt");
    std::fs::write(&list, "pipe.asc\n").unwrap();
    let fifo_vrt = dir.path().join("pipe.vrt");
    mkfifo(&fifo_vrt);
    let at_list = format!("@{}", s(&list));
    for input in [s(&fifo), s(&vrt), at_list, s(&fifo_vrt)] {
        let before = listing(dir.path());
        let o = cbdam_within(&["build", &input, "-o", &s(&out), "--max-error", "1"], 60);
        assert!(!o.status.success(), "{input}: {}", stderr(&o));
        let err = stderr(&o);
        assert!(
            err.contains("a FIFO (named pipe), not a regular file"),
            "{input}: {err}"
        );
        assert!(err.contains("pipe."), "{input}: {err}");
        assert_eq!(listing(dir.path()), before, "{input} left files behind");
    }
    // And where a repository is expected.
    let o = cbdam_within(&["inspect", &s(&fifo)], 60);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("not a regular file"), "{}", stderr(&o));
}

/// `-o` naming one of the build's inputs — the same path, a symlink or hard link to it, a VRT's
/// tile, the VRT itself — is refused before anything is written; the input is untouched.
#[cfg(unix)]
#[test]
fn an_output_that_is_an_input_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let asc = dir.path().join("a.asc");
    write_asc(&asc, &vec![vec![1.0, 2.0, 3.0, 4.0, 5.0]; 4], None);
    let original = std::fs::read(&asc).unwrap();
    let link = dir.path().join("link.cbdam");
    std::os::unix::fs::symlink(&asc, &link).unwrap();
    let hard = dir.path().join("hard.cbdam");
    std::fs::hard_link(&asc, &hard).unwrap();
    let vrt = dir.path().join("tiles.vrt");
    write_vrt(&vrt, "a.asc", "0, 1, 0, 4, 0, -1");
    let spelled = dir.path().join(".").join("a.asc");
    let cases = [
        (s(&asc), s(&asc)),
        (s(&asc), s(&spelled)),
        (s(&asc), s(&link)),
        (s(&asc), s(&hard)),
        (s(&vrt), s(&asc)),
        (s(&vrt), s(&vrt)),
    ];
    for (input, out) in &cases {
        let before = listing(dir.path());
        let o = cbdam(&["build", input, "-o", out, "--max-error", "1"]);
        assert!(!o.status.success(), "{input} -o {out} succeeded");
        let err = stderr(&o);
        assert!(
            err.contains("would overwrite what it reads"),
            "{input} -o {out}: {err}"
        );
        assert_eq!(
            listing(dir.path()),
            before,
            "{input} -o {out} left files behind"
        );
        assert_eq!(std::fs::read(&asc).unwrap(), original, "{input} -o {out}");
    }
    let vrt_text = std::fs::read_to_string(&vrt).unwrap();
    assert!(vrt_text.contains("a.asc"));
    // A different output still builds.
    let o = cbdam(&[
        "build",
        &s(&asc),
        "-o",
        &s(&dir.path().join("b.cbdam")),
        "--max-error",
        "1",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
}

/// A VRT whose `GeoTransform` holds NaN or an infinity is refused by name, not accepted with
/// a NaN origin.
#[test]
fn a_vrt_with_a_non_finite_geotransform_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let asc = dir.path().join("a.asc");
    write_asc(&asc, &vec![vec![1.0, 2.0, 3.0, 4.0, 5.0]; 4], None);
    let out = dir.path().join("out.cbdam");
    for gt in [
        "NaN, 1, 0, 4, 0, -1",
        "0, 1, 0, inf, 0, -1",
        "-inf, 1, 0, 4, 0, -1",
    ] {
        let vrt = dir.path().join("tiles.vrt");
        write_vrt(&vrt, "a.asc", gt);
        build_fails(
            dir.path(),
            &s(&vrt),
            &out,
            &["--max-error", "1"],
            "every term must be a finite number",
        );
    }
}

/// An infinite nodata value, the file's own or `--nodata`'s, is refused by name: it used to be
/// recorded in the header as the nodata value, and extracts wrote ±inf.
#[test]
fn an_infinite_nodata_value_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("o.cbdam");
    let minus_inf = dir.path().join("minus_inf.asc");
    std::fs::write(
        &minus_inf,
        "ncols 3\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1\nNODATA_value -inf\n\
         1 2 -inf\n4 5 6\n",
    )
    .unwrap();
    let plain = dir.path().join("plain.asc");
    write_asc(&plain, &[vec![1.0, 2.0, 3.0], vec![4.0, 5.0, 6.0]], None);
    for (input, extra, value) in [
        (&minus_inf, None, "-inf"),
        (&plain, Some("--nodata=inf"), "inf"),
    ] {
        let mut args = vec!["build", "--max-error", "1", "-o"];
        let (input, out) = (s(input), s(&out));
        args.extend([out.as_str(), input.as_str()]);
        args.extend(extra);
        let o = cbdam(&args);
        assert!(!o.status.success(), "{args:?} was accepted");
        let err = stderr(&o);
        assert!(
            err.contains(&format!("nodata value {value} is infinite")),
            "{args:?}: {err}"
        );
    }
    assert!(!out.exists());
}
