#!/usr/bin/env python3
"""CesiumJS against `cbdam serve`'s quantized-mesh tiles, offline, in headless Chromium.

Builds nothing: give it a repository (EPSG:4326 or UTM plane), the `cbdam` binary and a
directory holding `node_modules/cesium` (`npm install cesium` there). It serves
scripts/web-maps/cesium-check.html and node_modules from a loopback static server, runs
`cbdam serve REPO` on loopback, opens the page in the system's Chromium (SwiftShader WebGL) with
`--dump-dom`, and checks:

- no `errorEvent` from the terrain provider and no request to a host other than 127.0.0.1;
- at least 20 `.terrain` tiles requested, over at least 4 levels (from the server's access log);
- `sampleTerrainMostDetailed` heights within the stated vertex bound (layer.json) plus the
  largest measured between-vertex deviation (`cbdam-deviation-m`) of the tiles holding the
  points, of the bilinear interpolation of `cbdam extract --float64`'s samples.

Usage: web_maps_check.py REPO.cbdam CBDAM_BINARY NODE_DIR
"""

import array
import functools
import http.server
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import urllib.request


class QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass


def static_server(root):
    handler = functools.partial(QuietHandler, directory=root)
    srv = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    return srv


def start_cbdam(cbdam, repo, log):
    proc = subprocess.Popen([cbdam, "serve", f"r={repo}", "--addr", "127.0.0.1:0"],
                            stderr=subprocess.PIPE, text=True, env={**os.environ, "RUST_LOG": "info"})
    for line in proc.stderr:
        log.append(line)
        m = re.search(r"listening on http://(\S+)", line)
        if m:
            threading.Thread(target=lambda: log.extend(proc.stderr), daemon=True).start()
            return proc, m.group(1)
    raise SystemExit("cbdam serve exited early:\n" + "".join(log))


def extract_bilinear(cbdam, repo, tmp):
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
        v = lambda cc, rr: values[rr * w + cc]
        return ((1 - ty) * ((1 - tx) * v(ci, ri) + tx * v(ci + 1, ri))
                + ty * ((1 - tx) * v(ci, ri + 1) + tx * v(ci + 1, ri + 1)))
    return at


def main():
    repo, cbdam, node_dir = sys.argv[1:4]
    here = os.path.dirname(os.path.abspath(__file__))
    with tempfile.TemporaryDirectory() as tmp:
        root = os.path.join(tmp, "site")
        os.makedirs(root)
        shutil.copy(os.path.join(here, "web-maps", "cesium-check.html"), root)
        os.symlink(os.path.join(os.path.abspath(node_dir), "node_modules"), os.path.join(root, "node_modules"))
        site = static_server(root)
        log = []
        proc, addr = start_cbdam(cbdam, repo, log)
        try:
            base = f"http://{addr}/v1/repos/r/quantized-mesh/"
            layer = json.load(urllib.request.urlopen(base + "layer.json"))
            page = f"http://127.0.0.1:{site.server_port}/cesium-check.html?terrain={base}"
            dom = subprocess.run(
                ["chromium", "--headless=new", "--no-sandbox", "--enable-unsafe-swiftshader",
                 "--use-angle=swiftshader", "--disable-gpu-sandbox", "--dump-dom",
                 "--virtual-time-budget=400000", page],
                capture_output=True, text=True, timeout=300).stdout
            m = re.search(r"RESULT (\{.*\})</pre>", dom)
            if not m:
                raise SystemExit("the page did not finish")
            result = json.loads(m.group(1))
            tiles = [re.search(r"quantized-mesh/(\d+)/(\d+)/(\d+)\.terrain", l) for l in log]
            tiles = {t.groups() for t in tiles if t}
            levels = {z for z, _, _ in tiles}
            at = extract_bilinear(cbdam, repo, tmp)
            size = lambda z: 180 / 2 ** int(z)
            worst, deviation = 0.0, 0.0
            z = str(layer["maxzoom"])
            for lon, lat, h in result["samples"]:
                worst = max(worst, abs(h - at(lon, lat)))
                x, y = int((lon + 180) / size(z)), int((lat + 90) / size(z))
                head = urllib.request.urlopen(f"{base}{z}/{x}/{y}.terrain").headers
                deviation = max(deviation, float(head["cbdam-deviation-m"]))
            bound = layer["cbdam"]["vertex_bound_m"] + deviation
            print(f"errors {result['errors']}, foreign {result['foreign']}, {len(tiles)} tiles over "
                  f"levels {sorted(levels, key=int)}, max |Cesium - extract| {worst:.3f} m, "
                  f"bound {bound:.3f} m (vertex {layer['cbdam']['vertex_bound_m']:.3f} + deviation {deviation:.3f})")
            ok = (not result["errors"] and not result["foreign"] and len(tiles) >= 20
                  and len(levels) >= 4 and len(result["samples"]) == 20 and worst <= bound)
            if not ok:
                raise SystemExit("FAILED")
            print("OK")
        finally:
            proc.terminate()
            proc.wait()


if __name__ == "__main__":
    main()
