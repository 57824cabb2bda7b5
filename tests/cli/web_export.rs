//! `cbdam web-export`: the viewer's bundle copied as static files, the default repository
//! written into the page and copied beside it, and clear errors for a missing bundle or a file
//! that is not a repository. The page itself is driven in a browser by scripts/web_test.py.

use std::path::Path;

use crate::cli::render_colour::{H, W, build_colour, write_png};
use crate::util::{cbdam, jacksboro, s, stderr};

/// A stand-in for target/web-bundle: the files `cbdam serve --web` and the export require, with
/// the page's default-repository slot as client/web/www/index.html has it.
fn fake_bundle(dir: &Path) {
    std::fs::create_dir_all(dir).unwrap();
    std::fs::write(
        dir.join("index.html"),
        "<head>\n<meta name=\"cbdam-repo\" content=\"\">\n\
         <meta name=\"cbdam-colour\" content=\"\">\n</head>\n",
    )
    .unwrap();
    std::fs::write(dir.join("cbdam_web.js"), "export default 1;\n").unwrap();
    std::fs::write(dir.join("cbdam_web_bg.wasm"), b"\0asm\x01\0\0\0").unwrap();
    std::fs::write(dir.join("main.js"), "// main\n").unwrap();
}

#[test]
fn exports_the_bundle_and_the_repository_it_opens() {
    let tmp = tempfile::tempdir().unwrap();
    let bundle = tmp.path().join("bundle");
    fake_bundle(&bundle);
    let repo = jacksboro(tmp.path());
    let out = tmp.path().join("site");
    let o = cbdam(&[
        "web-export",
        &s(&out),
        "--bundle",
        &s(&bundle),
        "--repo",
        &s(&repo),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    for f in ["cbdam_web.js", "cbdam_web_bg.wasm", "main.js"] {
        assert_eq!(
            std::fs::read(out.join(f)).unwrap(),
            std::fs::read(bundle.join(f)).unwrap(),
            "{f}"
        );
    }
    assert_eq!(
        std::fs::read(out.join("j.cbdam")).unwrap(),
        std::fs::read(&repo).unwrap()
    );
    let page = std::fs::read_to_string(out.join("index.html")).unwrap();
    assert!(
        page.contains("<meta name=\"cbdam-repo\" content=\"j.cbdam\">"),
        "{page}"
    );

    // A URL is written as it is (escaped for the attribute), and nothing is copied.
    let out2 = tmp.path().join("site2");
    let url = "https://example.org/t.cbdam?a=1&b=\"2\"";
    let o = cbdam(&[
        "web-export",
        &s(&out2),
        "--bundle",
        &s(&bundle),
        "--repo",
        url,
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let page = std::fs::read_to_string(out2.join("index.html")).unwrap();
    assert!(
        page.contains("content=\"https://example.org/t.cbdam?a=1&amp;b=&quot;2&quot;\""),
        "{page}"
    );
    assert_eq!(std::fs::read_dir(&out2).unwrap().count(), 4);
}

#[test]
fn refuses_a_missing_bundle_and_a_file_that_is_no_repository() {
    let tmp = tempfile::tempdir().unwrap();
    let bundle = tmp.path().join("bundle");
    fake_bundle(&bundle);
    std::fs::remove_file(bundle.join("cbdam_web_bg.wasm")).unwrap();
    let out = tmp.path().join("site");
    let o = cbdam(&["web-export", &s(&out), "--bundle", &s(&bundle)]);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(
        e.contains("cbdam_web_bg.wasm is missing") && e.contains("scripts/web-build.sh"),
        "{e}"
    );

    fake_bundle(&bundle);
    let o = cbdam(&["web-export", &s(&bundle), "--bundle", &s(&bundle)]);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(e.contains("is the viewer's bundle itself"), "{e}");
    assert_eq!(
        std::fs::read(bundle.join("cbdam_web_bg.wasm")).unwrap(),
        b"\0asm\x01\0\0\0",
        "the bundle is left as it was"
    );

    let not_repo = tmp.path().join("x.cbdam");
    std::fs::write(&not_repo, b"not a repository").unwrap();
    let o = cbdam(&[
        "web-export",
        &s(&out),
        "--bundle",
        &s(&bundle),
        "--repo",
        &s(&not_repo),
    ]);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(e.contains("not a readable repository"), "{e}");
    assert!(!out.exists(), "nothing is written when the input is bad");
}

/// `--colour`: a colour repository copied beside the terrain and written into the page's colour
/// slot; one that does not drape over the terrain (here the terrain itself), or one with the
/// terrain's file name, is refused with the reason and nothing is written.
#[test]
fn exports_a_colour_repository_draped_over_the_terrain() {
    let tmp = tempfile::tempdir().unwrap();
    let bundle = tmp.path().join("bundle");
    fake_bundle(&bundle);
    let repo = jacksboro(tmp.path());
    let img = tmp.path().join("ortho.png");
    write_png(&img, W, H, |x, _| {
        if x < W / 2 {
            [200, 30, 30]
        } else {
            [30, 60, 200]
        }
    });
    let colour = build_colour(tmp.path(), &img, Some(&repo), "ortho.cbdam");
    let out = tmp.path().join("site");
    let export = |out: &Path, colour: &Path| {
        cbdam(&[
            "web-export",
            &s(out),
            "--bundle",
            &s(&bundle),
            "--repo",
            &s(&repo),
            "--colour",
            &s(colour),
        ])
    };
    let o = export(&out, &colour);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(
        std::fs::read(out.join("ortho.cbdam")).unwrap(),
        std::fs::read(&colour).unwrap()
    );
    let page = std::fs::read_to_string(out.join("index.html")).unwrap();
    assert!(
        page.contains("<meta name=\"cbdam-repo\" content=\"j.cbdam\">")
            && page.contains("<meta name=\"cbdam-colour\" content=\"ortho.cbdam\">"),
        "{page}"
    );
    assert!(String::from_utf8_lossy(&o.stdout).contains("with ortho.cbdam draped"));

    let bad = tmp.path().join("bad");
    let o = export(&bad, &repo);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(
        e.contains("the same file name as --repo's (j.cbdam)"),
        "{e}"
    );
    let elevation = tmp.path().join("elevation.cbdam");
    std::fs::copy(&repo, &elevation).unwrap();
    let o = export(&bad, &elevation);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(
        e.contains("draping the colour repository") && e.contains("not a colour one"),
        "{e}"
    );
    assert!(!bad.exists(), "nothing is written when the colour is bad");

    // --colour needs --repo.
    let o = cbdam(&[
        "web-export",
        &s(&bad),
        "--bundle",
        &s(&bundle),
        "--colour",
        &s(&colour),
    ]);
    assert!(
        !o.status.success() && stderr(&o).contains("--repo"),
        "{}",
        stderr(&o)
    );
}
