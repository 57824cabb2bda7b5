#!/usr/bin/env python3
"""CesiumJS and MapLibre GL JS against `cbdam serve`'s web-map tiles, offline, in headless
Chromium (run by scripts/web-maps-test.sh; see docs/WEB-MAPS.md).

Give it a repository (an EPSG:4326 plane), the `cbdam` binary and a directory holding
`node_modules/cesium`, `node_modules/maplibre-gl` and `node_modules/pmtiles`. It serves
scripts/web-maps/*.html, node_modules and a PMTiles archive of the repository's terrarium tiles
from a loopback static server (with Range requests), runs `cbdam serve REPO` on loopback and
drives the system's Chromium (SwiftShader WebGL2) over the DevTools protocol (the Browser of
web_test.py).
Chromium resolves no host name but 127.0.0.1, and every request the pages and their workers
send is watched: one to any other host fails the check. Checked:

- CesiumJS (`CesiumTerrainProvider` on `…/quantized-mesh/`), three camera views: each reaches
  `globe.tilesLoaded`; no `errorEvent`; at least 50 distinct `.terrain` tiles over at least 4
  levels (the server's access log); `sampleTerrainMostDetailed` at 20 points within the stated
  vertex bound (layer.json) plus the largest measured between-vertex deviation
  (`cbdam-deviation-m`) of the tiles holding them, of the bilinear interpolation of
  `cbdam extract --float64`'s samples; the screenshot is not one colour.
- MapLibre (raster-dem from `…/terrarium/tiles.json`, hillshade, terrain), looking straight down
  at `maxzoom`: reaches `idle` with no `error` event; some terrarium tiles fetched; at 20 points
  `queryTerrainElevation` is within the stated `pixel_bound_m` (tiles.json) of the same
  reference resampled as MapLibre samples its DEM (bilinear between the four pixel centres of the
  `maxzoom` tile around the point); the screenshot is not one colour. Then the same with the
  lossless WebP tiles (`…/terrarium/tiles.json?format=webp`): MapLibre reads them alike. Then
  the same on a PMTiles archive of the terrarium tiles (`cbdam tiles REPO -o r.pmtiles`) on
  the loopback static server, read through the npm `pmtiles` package's protocol
  (`pmtiles://…`): every request for the archive carries `Range`, and some read past its root
  directory (tiles). Then on two broken copies of the archive (truncated; root directory one
  byte late): the page stops at the first `error` event within BROKEN_ARCHIVE_LIMIT_S.
- The example pages `cbdam serve --web-libs` links from `/` (`/examples/cesium.html?repo=r`,
  `/examples/maplibre.html?repo=r`): each reaches `loaded` / `idle` with no error, tiles are
  asked of the server, the screenshot is not one colour; an unknown repository is a 404.
- WebP tiles (terrarium and terrain-RGB, `?format=webp`): at `maxzoom`, the tile at the data's
  centre and the one at its north-west corner (with transparent pixels) decoded by Chromium
  (webp-check.html: libwebp, read back unpremultiplied through WebGL) are the RGBA pixels of the
  PNG tile decoded here (web_test.decode_png), transparent pixels' colour included.

Usage: web_maps_check.py REPO.cbdam CBDAM_BINARY NODE_DIR
Screenshots are kept in $CBDAM_WEB_SHOTS when it is set.
"""

import array
import base64
import json
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
import urllib.error
import urllib.parse
import urllib.request

import websocket  # websocket-client, pinned by scripts/web-maps-test.sh
from web_test import Browser, RangeHandler, decode_png, save_screenshot, serve

# No name resolves but loopback: a page reaching for the network fails fast, and is seen.
OFFLINE_FLAGS = ["--use-angle=swiftshader", "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1"]
PAGE_TIMEOUT_S = 180
# A page on a broken source stops at its first error event, long before PAGE_TIMEOUT_S.
BROKEN_ARCHIVE_LIMIT_S = 60
MIN_CESIUM_TILES, MIN_CESIUM_LEVELS = 50, 4
# Where a PMTiles archive's tiles begin (cbdam writes the header and root directory before).
ARCHIVE_TILES_START = 16384


class ArchiveRanges(RangeHandler):
    """The site's static files (RangeHandler), noting the `Range` header (None: none) of every
    request for a `.pmtiles` archive."""

    asked = []

    def send_head(self):
        if self.path.split("?")[0].endswith(".pmtiles"):
            self.asked.append(self.headers.get("Range"))
        return super().send_head()


def archive_tiles(failures):
    """The archive reads past its header and root directory (tiles, leaf directories) since
    the page was opened; a request without `Range` (the whole file) is a failure."""
    whole = [r for r in ArchiveRanges.asked if r is None]
    if whole or not ArchiveRanges.asked:
        failures.append(f"maplibre (pmtiles): {len(whole)} of {len(ArchiveRanges.asked)} archive "
                        "requests without Range")
    starts = [int(re.match(r"bytes=(\d+)", r).group(1)) for r in ArchiveRanges.asked if r]
    return [s for s in starts if s >= ARCHIVE_TILES_START]


class WatchedBrowser(Browser):
    """A Browser that records every request of its page and of the page's workers."""

    def __init__(self):
        self.requests = []
        self.unanswered_id = 1 << 30  # ids of messages whose replies are not waited for
        super().__init__(OFFLINE_FLAGS)
        # Under SwiftShader on a loaded machine a page may hold its main thread for long.
        self.ws.settimeout(PAGE_TIMEOUT_S)
        self.call("Network.enable", session=True)
        self.call("Target.setAutoAttach", session=True, autoAttach=True,
                  waitForDebuggerOnStart=False, flatten=True)

    def note(self, event):
        method = event.get("method", "")
        if method == "Network.requestWillBeSent":
            self.requests.append(event["params"]["request"]["url"])
        elif method == "Target.attachedToTarget":
            # A worker: watch its requests too (the reply is not waited for).
            session = event["params"]["sessionId"]
            for method in ("Network.enable", "Runtime.runIfWaitingForDebugger"):
                self.unanswered_id += 1
                self.ws.send(json.dumps({"id": self.unanswered_id, "method": method, "sessionId": session}))
        super().note(event)

    def foreign(self):
        local = ("http://127.0.0.1:", "data:", "blob:", "about:")
        return sorted({u for u in self.requests if not u.startswith(local)})

    def run_page(self, url):
        """Opens `url` and waits for the page's `window.result`."""
        self.call("Page.navigate", session=True, url=url)
        deadline = time.time() + PAGE_TIMEOUT_S
        while time.time() < deadline:
            result = self.evaluate("window.result ?? null")
            if result is not None:
                return result
            self.wait_quietly(0.5)
        raise RuntimeError(f"the page did not finish within {PAGE_TIMEOUT_S} s: {url}\n"
                           + "\n".join(self.console[-20:]))

    def wait_quietly(self, seconds):
        """Reads events for `seconds` (so worker sessions are attached and watched)."""
        deadline = time.time() + seconds
        try:
            while time.time() < deadline:
                self.ws.settimeout(max(0.05, deadline - time.time()))
                self.note(json.loads(self.ws.recv()))
        except websocket.WebSocketTimeoutException:
            pass  # nothing more to read now
        finally:
            self.ws.settimeout(PAGE_TIMEOUT_S)

    def screenshot(self):
        data = self.call("Page.captureScreenshot", session=True, format="png")["data"]
        return base64.b64decode(data)


def colours_of(png):
    """(distinct colours, share of the commonest colour) of a screenshot."""
    width, height, channels, rows = decode_png(png)
    counts = {}
    for row in rows:
        for x in range(0, width * channels, channels):
            key = bytes(row[x:x + 3])
            counts[key] = counts.get(key, 0) + 1
    return len(counts), max(counts.values()) / (width * height)


def start_cbdam(cbdam, repo, node_dir):
    """`cbdam serve` of `repo` as `r` on loopback, serving the example pages' libraries."""
    proc = subprocess.Popen([cbdam, "serve", f"r={repo}", "--addr", "127.0.0.1:0",
                             "--web-libs", os.path.join(node_dir, "node_modules")],
                            stderr=subprocess.PIPE, text=True, env={**os.environ, "RUST_LOG": "info"})
    log = []
    for line in proc.stderr:
        log.append(line)
        m = re.search(r"listening on http://(\S+)", line)
        if m:
            threading.Thread(target=lambda: log.extend(proc.stderr), daemon=True).start()
            return proc, m.group(1), log
    raise SystemExit("cbdam serve exited early:\n" + "".join(log))


def reference_surface(cbdam, repo, tmp):
    """The bilinear interpolation of `cbdam extract --float64`'s samples, at (lon, lat)."""
    out = os.path.join(tmp, "x.f64")
    subprocess.run([cbdam, "extract", repo, "-o", out, "--format", "raw", "--float64", "--quiet"], check=True)
    meta = json.load(open(os.path.join(tmp, "x.json")))
    values = array.array("d")
    values.frombytes(open(out, "rb").read())
    g, w = meta["georef"], meta["width"]
    half = 0.5 if g["pixel_is"] == "area" else 0.0
    if g["epsg"] != 4326:
        raise SystemExit("this check places samples in EPSG:4326 only")

    def at(lon, lat):
        c = (lon - g["origin_x"]) / g["pixel_x"] - half
        r = (g["origin_y"] - lat) / g["pixel_y"] - half
        ci, ri = int(c), int(r)
        tx, ty = c - ci, r - ri
        v = lambda cc, rr: values[rr * w + cc]  # noqa: E731
        return ((1 - ty) * ((1 - tx) * v(ci, ri) + tx * v(ci + 1, ri))
                + ty * ((1 - tx) * v(ci, ri + 1) + tx * v(ci + 1, ri + 1)))
    return at


def inner_points(bounds, count, margin):
    """`count` points spread over the middle of `bounds` (west, south, east, north)."""
    w, s, e, n = bounds
    return [(w + (e - w) * (margin + (1 - 2 * margin) * ((i * 0.618) % 1)),
             s + (n - s) * (margin + (1 - 2 * margin) * ((i * 0.382 + 0.1) % 1))) for i in range(count)]


def served_tiles(log, kind, ext=r"\w+", status="200"):
    """Distinct (z, x, y) of the tiles of `kind` (files ending `.ext`) answered with `status`
    (a regular expression)."""
    found = set()
    for line in log:
        m = re.search(kind + r"/(\d+)/(\d+)/(\d+)\." + ext + r"[ ?].*status=(?:" + status + ")", line)
        if m:
            found.add(tuple(int(v) for v in m.groups()))
    return found


def check_cesium(browser, site, addr, log, at, failures):
    base = f"http://{addr}/v1/repos/r/quantized-mesh/"
    layer = json.load(urllib.request.urlopen(base + "layer.json"))
    result = browser.run_page(f"{site}/cesium-check.html?terrain={base}")
    shot = browser.screenshot()
    save_screenshot(shot, "cesium.png")
    tiles = served_tiles(log, "quantized-mesh")
    levels = {z for z, _, _ in tiles}
    worst, deviation = 0.0, 0.0
    z = layer["maxzoom"]
    size = 180 / 2 ** z
    for lon, lat, h in result.get("samples", []):
        worst = max(worst, abs(h - at(lon, lat)))
        x, y = int((lon + 180) / size), int((lat + 90) / size)
        head = urllib.request.urlopen(f"{base}{z}/{x}/{y}.terrain").headers
        deviation = max(deviation, float(head["cbdam-deviation-m"]))
    bound = layer["cbdam"]["vertex_bound_m"] + deviation
    colours, commonest = colours_of(shot)
    print(f"cesium: views {result.get('views')}, {len(tiles)} tiles over levels {sorted(levels)}, "
          f"max |Cesium - extract| {worst:.3f} m, bound {bound:.3f} m (vertex "
          f"{layer['cbdam']['vertex_bound_m']:.3f} + deviation {deviation:.3f}), screenshot "
          f"{colours} colours, commonest {commonest:.0%}")
    if result["errors"]:
        failures.append(f"cesium: errors {result['errors']}")
    if not all(v["tilesLoaded"] for v in result.get("views", [])) or len(result.get("views", [])) != 3:
        failures.append(f"cesium: not every view reached tilesLoaded: {result.get('views')}")
    if len(tiles) < MIN_CESIUM_TILES or len(levels) < MIN_CESIUM_LEVELS:
        failures.append(f"cesium: {len(tiles)} tiles over {len(levels)} levels "
                        f"(at least {MIN_CESIUM_TILES} over {MIN_CESIUM_LEVELS} wanted)")
    if len(result.get("samples", [])) != 20 or worst > bound:
        failures.append(f"cesium: sampled heights off by {worst:.3f} m, bound {bound:.3f} m")
    if colours < 2 or commonest > 0.98:
        failures.append(f"cesium: the screenshot is one colour ({colours} colours)")


def mercator_tile(lon, lat, z):
    """Global pixel coordinates (512-pixel tiles) of (lon, lat) at zoom z, Web Mercator."""
    scale = 512 * 2 ** z
    px = (lon + 180) / 360 * scale
    py = (1 - math.log(math.tan(math.radians(lat)) + 1 / math.cos(math.radians(lat))) / math.pi) / 2 * scale
    return px, py


def pixel_centre(px, py, z):
    """(lon, lat) of the global pixel coordinates (px, py) at zoom z."""
    scale = 512 * 2 ** z
    lon = px / scale * 360 - 180
    lat = math.degrees(math.atan(math.sinh(math.pi * (1 - 2 * py / scale))))
    return lon, lat


def resampled(at, lon, lat, z):
    """The reference resampled as a raster-dem client reads a `maxzoom` tile: each pixel holds
    the reference at its centre, and a point takes the bilinear mix of the four around it."""
    px, py = mercator_tile(lon, lat, z)
    cx, cy = px - 0.5, py - 0.5
    ix, iy = math.floor(cx), math.floor(cy)
    tx, ty = cx - ix, cy - iy
    h = lambda i, j: at(*pixel_centre(i + 0.5, j + 0.5, z))  # noqa: E731
    return ((1 - ty) * ((1 - tx) * h(ix, iy) + tx * h(ix + 1, iy))
            + ty * ((1 - tx) * h(ix, iy + 1) + tx * h(ix + 1, iy + 1)))


def check_maplibre(browser, site, addr, log, at, failures, image="png", archive=None):
    """MapLibre on the served terrarium tiles (PNG or WebP), or with `archive` (the name of a
    PMTiles archive of them on the site) on that archive through `pmtiles://`."""
    query = "" if image == "png" else f"?format={image}"
    tiles_url = f"http://{addr}/v1/repos/r/terrarium/tiles.json{query}"
    info = json.load(urllib.request.urlopen(tiles_url))
    label = f"{image}, pmtiles" if archive else image
    w, s, e, n = info["bounds"]
    z = info["maxzoom"]
    centre = [(w + e) / 2, (s + n) / 2]
    # Looking straight down two and a half zooms past maxzoom: MapLibre's terrain draws (and
    # queryTerrainElevation samples) 512-pixel DEM tiles two zooms coarser than the map's, so
    # these are maxzoom's. The points lie in the middle third of the 320 x 240 map.
    zoom = z + 2.5
    span_lon = 360 * 320 / (512 * 2 ** zoom) / 6
    span_lat = span_lon * math.cos(math.radians(centre[1])) * 0.75
    points = inner_points((centre[0] - span_lon, centre[1] - span_lat,
                           centre[0] + span_lon, centre[1] + span_lat), 20, 0.0)
    source = {"pmtiles": f"{site}/{archive}", "encoding": info["encoding"]} if archive else {"tiles": tiles_url}
    query = urllib.parse.urlencode({**source, "points": json.dumps(points),
                                    "view": json.dumps({"center": centre, "zoom": zoom, "pitch": 0})})
    ArchiveRanges.asked.clear()
    result = browser.run_page(f"{site}/maplibre-check.html?{query}")
    if result["errors"] or not result.get("idle"):
        # The page stops at the first error event (no canvas, no samples).
        failures.append(f"maplibre ({label}): idle {result.get('idle')}, errors {result['errors']}")
        return
    # The canvas as the page read it: a DevTools screenshot waits for a compositor frame, which
    # MapLibre's terrain on SwiftShader takes up to a minute to give under load.
    shot = base64.b64decode(result.get("png", ",").split(",", 1)[1])
    save_screenshot(shot, f"maplibre-{image}{'-pmtiles' if archive else ''}.png")
    tiles = archive_tiles(failures) if archive else served_tiles(log, "terrarium", image)
    worst = 0.0
    for lon, lat, h in result.get("samples", []):
        worst = max(worst, abs(h - resampled(at, lon, lat, z)) if h is not None else math.inf)
    bound = info["cbdam"]["pixel_bound_m"]
    colours, commonest = colours_of(shot)
    fetched = (f"{len(tiles)} range reads past the archive's root directory" if archive
               else f"{len(tiles)} tiles at levels {sorted({t[0] for t in tiles})}")
    print(f"maplibre ({label}): load {result.get('loadMs')} ms, idle {result.get('idleMs')} ms after navigation "
          f"({result.get('frames')} frames), {fetched}, max |queryTerrainElevation - reference| {worst:.4f} m, "
          f"bound {bound:.4f} m, screenshot {colours} colours, commonest {commonest:.0%}")
    if not tiles:
        failures.append(f"maplibre ({label}): no terrarium tile was fetched")
    if len(result.get("samples", [])) != 20 or worst > bound:
        failures.append(f"maplibre ({label}): queryTerrainElevation off by {worst:.4f} m, bound {bound:.4f} m")
    if colours < 2 or commonest > 0.98:
        failures.append(f"maplibre ({label}): the screenshot is one colour ({colours} colours)")


def broken_archives(root):
    """Broken copies of the site's archive: (name, what is wrong). One truncated after its root
    directory (tiles and metadata cut off); one whose header points its root directory one byte
    late (its gzip then fails), a fault on which the page once waited out PAGE_TIMEOUT_S."""
    whole = open(os.path.join(root, "r.pmtiles"), "rb").read()
    cut = ARCHIVE_TILES_START + 1000
    with open(os.path.join(root, "truncated.pmtiles"), "wb") as f:
        f.write(whole[:cut])
    moved = bytearray(whole)
    root_offset = int.from_bytes(moved[8:16], "little")
    moved[8:16] = (root_offset + 1).to_bytes(8, "little")
    with open(os.path.join(root, "moved-root.pmtiles"), "wb") as f:
        f.write(moved)
    return [("truncated.pmtiles", f"truncated to {cut} of {len(whole)} bytes"),
            ("moved-root.pmtiles", "root directory offset one byte late")]


def check_broken_archive(browser, site, root, addr, failures):
    """MapLibre on broken copies of the archive, in the view of check_maplibre: the page must
    stop at the first error event, well within BROKEN_ARCHIVE_LIMIT_S, and say what went wrong."""
    info = json.load(urllib.request.urlopen(f"http://{addr}/v1/repos/r/terrarium/tiles.json"))
    w, s, e, n = info["bounds"]
    view = {"center": [(w + e) / 2, (s + n) / 2], "zoom": info["maxzoom"] + 2.5, "pitch": 0}
    for name, fault in broken_archives(root):
        query = urllib.parse.urlencode({"pmtiles": f"{site}/{name}", "encoding": "terrarium",
                                        "points": "[]", "view": json.dumps(view)})
        started = time.time()
        result = browser.run_page(f"{site}/maplibre-check.html?{query}")
        took = time.time() - started
        print(f"maplibre (archive {fault}): stopped after {took:.1f} s, idle {result.get('idle')}, "
              f"errors {result['errors'][:2]}")
        if result.get("idle") or not result["errors"]:
            failures.append(f"maplibre (archive {fault}): no error event stopped the page "
                            f"(idle {result.get('idle')})")
        if took > BROKEN_ARCHIVE_LIMIT_S:
            failures.append(f"maplibre (archive {fault}): the page took {took:.1f} s to stop "
                            f"(at most {BROKEN_ARCHIVE_LIMIT_S} s wanted)")


def check_examples(browser, addr, log, failures):
    """The example pages `cbdam serve --web-libs` links from `/`: each reaches its loaded /
    idle state with no error, loading its library and tiles from the server alone."""
    index = urllib.request.urlopen(f"http://{addr}/").read().decode()
    for page, state, kind in (("cesium.html", "loaded", r"quantized-mesh"), ("maplibre.html", "idle", "terrarium")):
        url = f"/examples/{page}?repo=r"
        if f'href="{url}"' not in index:
            failures.append(f"examples: / does not link {url}")
        mark = len(log)
        started = time.time()
        result = browser.run_page(f"http://{addr}{url}")
        took = time.time() - started
        shot = browser.screenshot()
        save_screenshot(shot, f"example-{page[:-5]}.png")
        colours, commonest = colours_of(shot)
        # Tiles the browser has from the checks before are revalidated: 304.
        tiles = served_tiles(log[mark:], kind, status="200|304")
        print(f"example {page}: {result.get('state')} after {took:.1f} s, errors {result['errors']}, "
              f"{len(tiles)} {kind} tiles served, screenshot {colours} colours, commonest {commonest:.0%}")
        if result.get("state") != state or result["errors"]:
            failures.append(f"example {page}: state {result.get('state')} (want {state}), errors {result['errors']}")
        if not tiles:
            failures.append(f"example {page}: no {kind} tile was served")
        if colours < 2 or commonest > 0.98:
            failures.append(f"example {page}: the screenshot is one colour ({colours} colours)")
    try:
        urllib.request.urlopen(f"http://{addr}/examples/cesium.html?repo=nosuch")
        failures.append("example page of an unknown repository answered 200")
    except urllib.error.HTTPError as e:
        body = e.read().decode()
        if e.code != 404 or "no repository named" not in body:
            failures.append(f"example page of an unknown repository: {e.code} {body[:200]!r}")


def png_rgba(data):
    """A PNG's pixels as RGBA bytes (decoded here, by web_test.decode_png)."""
    width, height, channels, rows = decode_png(data)
    if channels == 4:
        return width, b"".join(rows)
    out = bytearray()
    for row in rows:
        for x in range(0, len(row), 3):
            out += row[x:x + 3] + b"\xff"
    return width, bytes(out)


def check_webp(browser, site, addr, failures):
    urls, pngs = [], []
    for kind in ("terrarium", "terrain-rgb"):
        info = json.load(urllib.request.urlopen(f"http://{addr}/v1/repos/r/{kind}/tiles.json?format=webp"))
        w, s, e, n = info["bounds"]
        z = info["maxzoom"]
        for lon, lat in (((w + e) / 2, (s + n) / 2), (w + 1e-9, n - 1e-9)):
            x, y = (int(v // 512) for v in mercator_tile(lon, lat, z))  # tiles.json's are 512 px
            url = info["tiles"][0].replace("{z}", str(z)).replace("{x}", str(x)).replace("{y}", str(y))
            urls.append(url)
            pngs.append(urllib.request.urlopen(url.replace(".webp", ".png")).read())
    result = browser.run_page(f"{site}/webp-check.html?" + urllib.parse.urlencode({"urls": json.dumps(urls)}))
    same = transparent = webp_bytes = png_bytes = 0
    for url, png, tile in zip(urls, pngs, result.get("tiles", [])):
        width, rgba = png_rgba(png)
        got = base64.b64decode(tile["rgba"])
        if tile["type"] != "image/webp" or tile["width"] != width or got != rgba:
            differing = sum(1 for i in range(0, min(len(got), len(rgba)), 4) if got[i:i + 4] != rgba[i:i + 4])
            failures.append(f"webp: {url} ({tile['type']}, {tile['width']} px) differs from the PNG "
                            f"in {differing} pixels")
        else:
            same += 1
        transparent += rgba[3::4].count(0)
        webp_bytes += len(urllib.request.urlopen(url).read())
        png_bytes += len(png)
    print(f"webp: {same} of {len(urls)} tiles decoded by Chromium equal to their PNG's pixels "
          f"({transparent} transparent pixels); WebP {webp_bytes} bytes, PNG {png_bytes}")
    if result["errors"] or len(result.get("tiles", [])) != len(urls):
        failures.append(f"webp: the page decoded {len(result.get('tiles', []))} of {len(urls)} tiles, "
                        f"errors {result['errors']}")
    if transparent == 0:
        failures.append("webp: no tile with transparent pixels was compared")


def main():
    repo, cbdam, node_dir = sys.argv[1:4]
    here = os.path.dirname(os.path.abspath(__file__))
    failures = []
    with tempfile.TemporaryDirectory() as tmp:
        root = os.path.join(tmp, "site")
        os.makedirs(root)
        for page in ("cesium-check.html", "maplibre-check.html", "webp-check.html"):
            shutil.copy(os.path.join(here, "web-maps", page), root)
        os.symlink(os.path.join(os.path.abspath(node_dir), "node_modules"), os.path.join(root, "node_modules"))
        subprocess.run([cbdam, "tiles", repo, "--format", "terrarium", "-o",
                        os.path.join(root, "r.pmtiles"), "--quiet"], check=True)
        site_server = serve(root, handler_class=ArchiveRanges)
        site = f"http://127.0.0.1:{site_server.server_port}"
        at = reference_surface(cbdam, repo, tmp)
        proc, addr, log = start_cbdam(cbdam, repo, node_dir)
        browser = WatchedBrowser()
        try:
            started = time.time()
            check_cesium(browser, site, addr, log, at, failures)
            cesium_s = time.time() - started
            check_maplibre(browser, site, addr, log, at, failures)
            maplibre_s = time.time() - started - cesium_s
            check_maplibre(browser, site, addr, log, at, failures, image="webp")
            maplibre_webp_s = time.time() - started - cesium_s - maplibre_s
            check_maplibre(browser, site, addr, log, at, failures, archive="r.pmtiles")
            check_broken_archive(browser, site, root, addr, failures)
            maplibre_pmtiles_s = time.time() - started - cesium_s - maplibre_s - maplibre_webp_s
            check_webp(browser, site, addr, failures)
            examples_started = time.time()
            check_examples(browser, addr, log, failures)
            print(f"the example pages took {time.time() - examples_started:.1f} s")
            print(f"times: cesium {cesium_s:.1f} s, maplibre {maplibre_s:.1f} s, maplibre on webp "
                  f"{maplibre_webp_s:.1f} s, on pmtiles {maplibre_pmtiles_s:.1f} s, webp pixels "
                  f"{time.time() - started - cesium_s - maplibre_s - maplibre_webp_s - maplibre_pmtiles_s:.1f} s")
            browser.wait_quietly(0.5)
            foreign = browser.foreign()
            if foreign:
                failures.append(f"requests to hosts other than 127.0.0.1: {foreign[:5]}")
            print(f"{len(browser.requests)} requests watched, {len(foreign)} not to 127.0.0.1")
        finally:
            browser.close()
            proc.terminate()
            proc.wait()
    if failures:
        raise SystemExit("FAILED:\n  " + "\n  ".join(failures))
    print("OK")


if __name__ == "__main__":
    main()
