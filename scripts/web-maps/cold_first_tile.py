#!/usr/bin/env python3
"""Cold first raster tile of `cbdam serve` (a plane: decoded through windows) against the whole
decode the first quantized-mesh request or layer.json pays, and every exported terrarium tile
served again compared byte for byte (docs/RESULTS.md, web-map tiles). A measurement, not a test.

Usage: cold_first_tile.py CBDAM_BINARY REPO.cbdam EXPORT_DIR RUNS
  (EXPORT_DIR: `cbdam tiles REPO --format terrarium -o EXPORT_DIR`)
"""
import http.client, json, re, subprocess, sys, time, threading, statistics, os, math
binary, repo, expdir, runs = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
def start():
    p = subprocess.Popen([binary, "serve", f"r={repo}", "--addr", "127.0.0.1:0"], stderr=subprocess.PIPE, text=True)
    for line in p.stderr:
        m = re.search(r"listening on http://127.0.0.1:(\d+)", line)
        if m:
            threading.Thread(target=lambda: [None for _ in p.stderr], daemon=True).start()
            return p, http.client.HTTPConnection("127.0.0.1", int(m.group(1)))
def get(c, path):
    t = time.perf_counter(); c.request("GET", path); r = c.getresponse(); b = r.read()
    return r.status, b, time.perf_counter() - t
tiles = []
for root, _, files in os.walk(expdir):
    for f in files:
        if f.endswith(".png"):
            z, x = root[len(expdir) + 1:].split("/"); tiles.append((int(z), int(x), int(f[:-4])))
zmax = max(t[0] for t in tiles)
centre = sorted(t for t in tiles if t[0] == zmax)[len([t for t in tiles if t[0] == zmax]) // 2]
first, decode, warm = [], [], []
for run in range(runs):
    p, c = start()
    s, b, dt = get(c, f"/v1/repos/r/terrarium/{centre[0]}/{centre[1]}/{centre[2]}.png"); assert s == 200; first.append(dt)
    if run == 0:
        same = 0
        for z, x, y in tiles:
            s, b, _ = get(c, f"/v1/repos/r/terrarium/{z}/{x}/{y}.png")
            assert s == 200 and b == open(f"{expdir}/{z}/{x}/{y}.png", "rb").read(), (z, x, y)
            same += 1
        print(f"{same} terrarium tiles served through windows == the exported files, byte for byte")
    p.terminate(); p.wait()
    p, c = start()
    s, b, dt = get(c, "/v1/repos/r/quantized-mesh/layer.json"); assert s == 200; decode.append(dt)
    s, b, dt = get(c, f"/v1/repos/r/terrarium/{centre[0]}/{centre[1]}/{centre[2]}.png"); warm.append(dt)
    p.terminate(); p.wait()
ms = lambda v: f"median {statistics.median(v)*1000:.1f} ms (min {min(v)*1000:.1f}, max {max(v)*1000:.1f})"
print(f"tile {centre}: cold first tile (window decode) {ms(first)}; cold layer.json (whole decode) {ms(decode)}; the tile after it {ms(warm)}")
