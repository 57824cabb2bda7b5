//! `cbdam upgrade`: older format versions rewritten as today's build.

use crate::util::*;

#[test]
fn upgrade_rewrites_version_1_as_the_build_of_today() {
    let dir = tempfile::tempdir().unwrap();
    let v1 = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/codec/tests/data/v1/lidar1m_eps1.cbdam"
    );
    let copy = dir.path().join("old.cbdam");
    std::fs::copy(v1, &copy).unwrap();
    let copy_s = s(&copy);
    assert!(stdout(&cbdam(&["inspect", &copy_s])).contains("format          version 1"));

    // In place: the input is replaced atomically, nothing else is left behind.
    let o = cbdam(&["upgrade", &copy_s, "-o", &copy_s]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stdout(&o).contains("format version 1 → 3, 1318 → "),
        "{}",
        stdout(&o)
    );
    assert_eq!(listing(dir.path()), vec![copy.clone()]);
    assert!(stdout(&cbdam(&["inspect", &copy_s])).contains("format          version 3"));
    let o = cbdam(&["verify", &copy_s, "--against", &data("lidar1m_mn.tif")]);
    assert!(o.status.success(), "{}", stderr(&o));

    // The same bytes as building the same input today with the fixture's options (the
    // defaults of its day: the upgrade keeps the records, so the coder stays the bitwise one).
    let fresh = dir.path().join("fresh.cbdam");
    let o = cbdam(&[
        "build",
        &data("lidar1m_mn.tif"),
        "-o",
        &s(&fresh),
        "--max-error",
        "1",
        "--coder",
        "adaptive",
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(
        std::fs::read(&copy).unwrap(),
        std::fs::read(&fresh).unwrap()
    );

    // Not a repository: exit 1, the problem named, no output.
    let junk = dir.path().join("junk.cbdam");
    std::fs::write(&junk, b"not a repository").unwrap();
    let out = dir.path().join("out.cbdam");
    let o = cbdam(&["upgrade", &s(&junk), "-o", &s(&out)]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("bad magic"), "{}", stderr(&o));
    assert!(!out.exists());
}
