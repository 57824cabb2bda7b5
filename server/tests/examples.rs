//! The web-map example pages and their libraries (`--web-libs`), and the `attribution` of the
//! tiles' documents: over real HTTP on 127.0.0.1, with a stand-in `node_modules` (the pages in
//! real browsers: scripts/web_maps_check.py).

use std::path::Path;
use std::sync::Arc;

use cbdam_server::{AppState, Config, WebLibs};

use crate::tiles::{geographic_dem, get_json, serve};
use crate::util::{client, error_body, start};

/// A `node_modules` holding the two files the pages need, and one more of each library.
fn stand_in_libs(dir: &Path) {
    for (file, body) in [
        ("cesium/Build/Cesium/Cesium.js", "var Cesium = {};"),
        ("cesium/Build/Cesium/Widgets/widgets.css", "body {}"),
        ("maplibre-gl/dist/maplibre-gl.mjs", "export default {};"),
        ("maplibre-gl/package.json", "{}"),
    ] {
        let path = dir.join("node_modules").join(file);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(path, body).unwrap();
    }
}

async fn served_with(libs: Option<&Path>, attribution: Option<&str>) -> crate::util::Running {
    let config = Config {
        web_libs: libs.map(|d| Arc::new(WebLibs::open(d).unwrap())),
        attribution: attribution.map(str::to_string),
        ..Config::default()
    };
    // A repository in a CRS web-map tiles are not made from.
    let mut mercator = geographic_dem();
    mercator.georef.epsg = Some(3857);
    let repos = vec![
        ("g".to_string(), geographic_dem().repository()),
        ("plain".to_string(), mercator.repository()),
    ];
    start(AppState::new(repos, config).unwrap()).await
}

async fn page(s: &crate::util::Running, path: &str) -> (u16, String) {
    let r = client().get(s.url(path)).send().await.unwrap();
    let status = r.status().as_u16();
    assert_eq!(
        r.headers()["content-type"],
        "text/html; charset=utf-8",
        "{path}"
    );
    (status, r.text().await.unwrap())
}

#[tokio::test]
async fn the_front_page_links_the_examples_of_repositories_made_into_tiles() {
    let dir = tempfile::tempdir().unwrap();
    stand_in_libs(dir.path());
    let s = served_with(Some(dir.path()), None).await;
    let (status, index) = page(&s, "/").await;
    assert_eq!(status, 200);
    for p in ["cesium", "maplibre"] {
        assert!(
            index.contains(&format!("href=\"/examples/{p}.html?repo=g\"")),
            "{index}"
        );
        // Not of a repository in EPSG:3857: it is not made into tiles.
        assert!(
            !index.contains(&format!("/examples/{p}.html?repo=plain")),
            "{index}"
        );
        let (status, body) = page(&s, &format!("/examples/{p}.html?repo=g")).await;
        assert_eq!(status, 200);
        assert!(body.contains("const repo = \"g\";"), "{body}");
        assert!(body.contains("/web-libs/"), "{body}");
        // Every script and style from this server: no URL of another host.
        assert!(
            !body.contains("https://") && !body.contains("http://"),
            "{body}"
        );
    }
    s.stop().await;
}

#[tokio::test]
async fn example_pages_refuse_what_they_cannot_show_with_a_message() {
    let dir = tempfile::tempdir().unwrap();
    stand_in_libs(dir.path());
    let s = served_with(Some(dir.path()), None).await;
    let cases = [
        (
            "/examples/cesium.html?repo=nosuch",
            404,
            "no repository named \"nosuch\"",
        ),
        (
            "/examples/maplibre.html?repo=plain",
            404,
            "is not made into web-map tiles",
        ),
        ("/examples/cesium.html", 400, "?repo=NAME"),
        (
            "/examples/leaflet.html?repo=g",
            404,
            "there is no example page",
        ),
    ];
    for (path, want, says) in cases {
        let (status, body) = page(&s, path).await;
        assert_eq!(status, want, "{path}: {body}");
        let says = says.replace('"', "&quot;");
        assert!(body.contains(&says), "{path}: {body}");
    }
    s.stop().await;
    // Without --web-libs the page says what to install, and loads nothing.
    let s = served_with(None, None).await;
    let (status, body) = page(&s, "/examples/cesium.html?repo=g").await;
    assert_eq!(status, 404);
    assert!(body.contains("CesiumJS is not served"), "{body}");
    assert!(body.contains("npm install cesium maplibre-gl"), "{body}");
    assert!(!body.contains("<script"), "{body}");
    s.stop().await;
}

#[tokio::test]
async fn library_files_are_served_from_their_trees_only() {
    let dir = tempfile::tempdir().unwrap();
    stand_in_libs(dir.path());
    let s = served_with(Some(dir.path()), None).await;
    let get = |path: &'static str| client().get(s.url(path)).send();
    let r = get("/web-libs/cesium/Build/Cesium/Cesium.js")
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    assert_eq!(
        r.headers()["content-type"],
        "text/javascript; charset=utf-8"
    );
    assert_eq!(r.text().await.unwrap(), "var Cesium = {};");
    let r = get("/web-libs/maplibre-gl/dist/maplibre-gl.mjs")
        .await
        .unwrap();
    assert_eq!(
        r.headers()["content-type"],
        "text/javascript; charset=utf-8"
    );
    let refused = [
        (
            "/web-libs/maplibre-gl/package.json",
            404,
            "serves cesium/Build/Cesium/ and",
        ),
        // (the client resolves `..` and `%2E%2E` in a URL: this is asked as /web-libs/x)
        (
            "/web-libs/cesium/Build/Cesium/../../../x",
            404,
            "serves cesium/Build/Cesium/ and",
        ),
        (
            "/web-libs/cesium/Build/Cesium/.hidden",
            400,
            "malformed library path",
        ),
        (
            "/web-libs/cesium/Build/Cesium/Nothing.js",
            404,
            "no library file",
        ),
        (
            "/web-libs/cesium/Build/Cesium/Widgets",
            404,
            "no library file",
        ),
    ];
    for (path, status, says) in refused {
        let message = error_body(get(path).await.unwrap(), status).await;
        assert!(message.contains(says), "{path}: {message}");
    }
    // `..` sent as is, as a client that does not resolve it would.
    for path in [
        "cesium/Build/Cesium/../../../../etc/passwd",
        "cesium/Build/Cesium/%2e%2e/x",
    ] {
        let head = raw_get(s.addr, &format!("/web-libs/{path}")).await;
        assert!(head.starts_with("HTTP/1.1 400"), "{path}: {head}");
    }
    s.stop().await;
    let s = served_with(None, None).await;
    let r = client().get(s.url("/web-libs/cesium/Build/Cesium/Cesium.js"));
    let message = error_body(r.send().await.unwrap(), 404).await;
    assert!(message.contains("--web-libs"), "{message}");
    s.stop().await;
}

/// The answer to `GET path` sent byte for byte (no URL normalization), up to its body.
async fn raw_get(addr: std::net::SocketAddr, path: &str) -> String {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let mut conn = tokio::net::TcpStream::connect(addr).await.unwrap();
    let request = format!("GET {path} HTTP/1.1\r\nHost: t\r\nConnection: close\r\n\r\n");
    conn.write_all(request.as_bytes()).await.unwrap();
    let mut answer = Vec::new();
    conn.read_to_end(&mut answer).await.unwrap();
    String::from_utf8_lossy(&answer).into_owned()
}

#[test]
fn a_libraries_directory_without_the_libraries_is_refused_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let e = WebLibs::open(&dir.path().join("nope"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("not a directory"), "{e}");
    std::fs::create_dir_all(dir.path().join("cesium/Build/Cesium")).unwrap();
    std::fs::write(dir.path().join("cesium/Build/Cesium/Cesium.js"), "").unwrap();
    let e = WebLibs::open(dir.path()).unwrap_err().to_string();
    assert!(e.contains("maplibre-gl/dist/maplibre-gl.mjs"), "{e}");
    assert!(e.contains("npm install cesium maplibre-gl"), "{e}");
    // The directory holding node_modules does as well as node_modules itself.
    let both = tempfile::tempdir().unwrap();
    stand_in_libs(both.path());
    WebLibs::open(both.path()).unwrap();
    WebLibs::open(&both.path().join("node_modules")).unwrap();
}

#[tokio::test]
async fn attribution_is_the_flags_or_what_the_repository_records() {
    let s = serve(vec![("g", geographic_dem().repository())]).await;
    for path in ["quantized-mesh/layer.json", "terrarium/tiles.json"] {
        let doc = get_json(&s, &format!("/v1/repos/g/{path}")).await;
        let text = doc["attribution"].as_str().unwrap();
        let bound = doc["cbdam"]["repository_max_error_m"].as_f64().unwrap();
        // The bound to the millimetre.
        let said = text
            .strip_prefix("cbdam repository g (heights within ")
            .and_then(|t| t.strip_suffix(" m of its input)"))
            .unwrap_or_else(|| panic!("{path}: {text}"));
        let said: f64 = said.parse().unwrap();
        assert!(
            (said - bound).abs() <= 0.0005,
            "{path}: {text}, bound {bound}"
        );
    }
    s.stop().await;
    let s = served_with(None, Some("SRTM: NASA / USGS")).await;
    for path in ["quantized-mesh/layer.json", "terrain-rgb/tiles.json"] {
        let doc = get_json(&s, &format!("/v1/repos/g/{path}")).await;
        assert_eq!(doc["attribution"], "SRTM: NASA / USGS", "{path}");
    }
    s.stop().await;
}
