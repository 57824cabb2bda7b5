//! Errors name the file or option at fault.

use std::path::PathBuf;

use cbdam_builder::{BuildOptions, ExtraLevels, NoProgress, build};

use crate::util::data;

fn error(opts: &BuildOptions) -> String {
    match build(opts, &NoProgress) {
        Ok(_) => panic!("{opts:?} built"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn a_missing_input_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.cbdam");
    let missing = dir.path().join("no such dem.tif");
    let e = error(&BuildOptions::new(vec![missing.clone()], out.clone(), 1.0));
    assert!(e.contains(&missing.display().to_string()), "{e}");
    // One missing input among several.
    let e = error(&BuildOptions::new(
        vec![data("srtm3_demcompare.tif"), missing.clone()],
        out.clone(),
        1.0,
    ));
    assert!(e.contains(&missing.display().to_string()), "{e}");
    // A missing image of a colour build, and a missing elevation repository under it.
    let mut colour = BuildOptions::new(vec![missing.clone()], out.clone(), 2.0);
    colour.colour = true;
    let e = error(&colour);
    assert!(e.contains(&missing.display().to_string()), "{e}");
    let like = dir.path().join("no such repo.cbdam");
    colour.inputs = vec![data("fuji_terrainrgb.png")];
    colour.like = Some(like.clone());
    let e = error(&colour);
    assert!(e.contains(&like.display().to_string()), "{e}");
    assert!(!out.exists());
}

#[test]
fn bad_options_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.cbdam");
    let srtm = || vec![data("srtm3_demcompare.tif")];
    let mut o = BuildOptions::new(srtm(), out.clone(), -1.0);
    assert!(error(&o).contains("--max-error"));
    o.max_error = 1.0;
    o.threads = Some(0);
    assert!(error(&o).contains("--threads"));
    o.threads = None;
    o.extra_levels = ExtraLevels::Fixed(3);
    assert!(error(&o).contains("--extra-levels"));
    o.extra_levels = ExtraLevels::Auto;
    o.like = Some(PathBuf::from("x.cbdam"));
    assert!(error(&o).contains("--like"));
    o.like = None;
    // A tolerance above the height range is a unit mistake.
    o.max_error = 1e6;
    assert!(error(&o).contains("--max-error"));
    // A raw float32 file without its size names the file and the option.
    let raw = dir.path().join("t.f32");
    std::fs::write(&raw, [0u8; 16]).unwrap();
    let e = error(&BuildOptions::new(vec![raw.clone()], out.clone(), 1.0));
    assert!(
        e.contains(&raw.display().to_string()) && e.contains("--size"),
        "{e}"
    );
    // The output is a directory.
    let e = error(&BuildOptions::new(srtm(), dir.path().to_path_buf(), 1.0));
    assert!(e.contains(&dir.path().display().to_string()), "{e}");
    assert!(!out.exists());
}
