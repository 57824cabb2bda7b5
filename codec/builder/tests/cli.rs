//! A build through the library writes, byte for byte, what `cbdam build` writes as a process
//! (elevation, with the default `--extra-levels auto`, and colour).

use std::ffi::OsStr;

use cbdam_builder::{BuildOptions, BuildSummary, NoProgress, build};

use crate::util::{cbdam, data};

/// Builds `inputs` both ways and compares the files; returns the library's summary.
fn compare(inputs: &[&str], max_error: &str, colour: bool) -> BuildSummary {
    let dir = tempfile::tempdir().unwrap();
    let (lib, cli) = (dir.path().join("lib.cbdam"), dir.path().join("cli.cbdam"));
    let paths: Vec<_> = inputs.iter().map(|n| data(n)).collect();
    let mut opts = BuildOptions::new(paths.clone(), lib.clone(), max_error.parse().unwrap());
    opts.colour = colour;
    let summary = build(&opts, &NoProgress).unwrap();
    assert_eq!(matches!(summary, BuildSummary::Colour(_)), colour);
    let mut args: Vec<&OsStr> = vec![OsStr::new("build")];
    args.extend(paths.iter().map(|p| p.as_os_str()));
    args.extend(["--max-error", max_error, "--quiet", "-o"].map(OsStr::new));
    args.push(cli.as_os_str());
    if colour {
        args.push(OsStr::new("--colour"));
    }
    let o = cbdam(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (a, b) = (std::fs::read(&lib).unwrap(), std::fs::read(&cli).unwrap());
    assert!(a.len() > 100, "{inputs:?}: {} bytes", a.len());
    assert!(
        a == b,
        "{inputs:?}: library {} bytes, cbdam build {} bytes",
        a.len(),
        b.len()
    );
    summary
}

#[test]
fn library_build_equals_the_cli_build() {
    compare(&["srtm3_demcompare.tif"], "1", false);
    // The root field dominates here: `auto` encodes twice and keeps the smaller file.
    let BuildSummary::Elevation(s) = compare(&["lidar1m_mn.tif"], "5", false) else {
        panic!("not an elevation build")
    };
    assert!(
        s.stages
            .iter()
            .any(|(name, _)| *name == "encode with coarser roots"),
        "{:?}",
        s.stages
    );
}

#[test]
fn library_colour_build_equals_the_cli_build() {
    compare(&["fuji_terrainrgb.png"], "2", true);
}
