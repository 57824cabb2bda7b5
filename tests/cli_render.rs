//! `cbdam render` end to end on lavapipe (or a real GPU): a PNG of the requested size, written
//! atomically, and clean failures for bad arguments.

use std::path::Path;
use std::process::{Command, Output};

fn cbdam(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_cbdam"))
        .args(args)
        .output()
        .expect("run cbdam")
}

fn s(p: &Path) -> String {
    p.to_string_lossy().into_owned()
}

fn png_size(path: &Path) -> (u32, u32) {
    let file = std::io::BufReader::new(std::fs::File::open(path).unwrap());
    let reader = png::Decoder::new(file).read_info().unwrap();
    let info = reader.info();
    (info.width, info.height)
}

#[test]
fn render_writes_a_png_and_rejects_bad_arguments() {
    let dir = tempfile::tempdir().unwrap();
    let repo = dir.path().join("j.cbdam");
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/jacksboro_mpl.tif");
    let o = cbdam(&[
        "build",
        &s(&data),
        "-o",
        &s(&repo),
        "--max-error",
        "2",
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));

    let out = dir.path().join("f.png");
    let o = cbdam(&["render", &s(&repo), "--size", "96x64", "-o", &s(&out)]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(
        text.contains("M triangles") && text.contains("frame"),
        "{text}"
    );
    assert_eq!(png_size(&out), (96, 64));

    let wire = dir.path().join("w.png");
    let o = cbdam(&[
        "render",
        &s(&repo),
        "--size",
        "64x48",
        "-o",
        &s(&wire),
        "--wireframe",
        "--levels",
        "--camera",
        "15000,-42000,5000,15000,-18000,300",
        "--pixel-error",
        "4",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(png_size(&wire), (64, 48));

    // Usage errors: exit 2 from clap's parser.
    let o = cbdam(&["render", &s(&repo), "--size", "0x5", "-o", &s(&out)]);
    assert_eq!(o.status.code(), Some(2));
    // Bad values: exit 1 with a message, nothing written.
    let bad = dir.path().join("bad.png");
    for (args, message) in [
        (vec!["--camera", "1,2,3,4,5"], "six finite numbers"),
        (vec!["--camera", "1,2,3,1,2,3"], "coincide"),
        (vec!["--pixel-error", "0"], "positive"),
        (vec!["--exaggeration", "-1"], "positive"),
    ] {
        let mut all = vec!["render", &s(&repo)]
            .into_iter()
            .map(String::from)
            .collect::<Vec<_>>();
        all.extend(["-o".to_string(), s(&bad)]);
        all.extend(args.iter().map(|a| a.to_string()));
        let all: Vec<&str> = all.iter().map(String::as_str).collect();
        let o = cbdam(&all);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
        assert!(err.contains(message), "{args:?}: {err}");
        assert!(!bad.exists());
    }
    // A directory as output.
    let o = cbdam(&["render", &s(&repo), "--size", "32x32", "-o", &s(dir.path())]);
    assert_eq!(o.status.code(), Some(1));
}
