#!/usr/bin/env python3
"""Every quantized-mesh tile of the levels asked, served cold by `cbdam serve` to 16 concurrent
clients (with gzip, normals and metadata), compared byte for byte with the files of `cbdam tiles
REPO --format quantized-mesh -o EXPORT_DIR` (docs/RESULTS.md, web-map tiles). A check run by
hand, not a test.

Usage: served_vs_export.py CBDAM_BINARY REPO.cbdam EXPORT_DIR LEVELS (comma-separated)
"""
import http.client, os, re, subprocess, sys, threading
binary, repo, expdir, zs = sys.argv[1], sys.argv[2], sys.argv[3], [int(z) for z in sys.argv[4].split(",")]
p = subprocess.Popen([binary, "serve", f"r={repo}", "--addr", "127.0.0.1:0"], stderr=subprocess.PIPE, text=True)
for line in p.stderr:
    m = re.search(r"listening on http://127.0.0.1:(\d+)", line)
    if m: port = int(m.group(1)); break
threading.Thread(target=lambda: [None for _ in p.stderr], daemon=True).start()
paths = [(z, x, f[:-8]) for z in zs for x in os.listdir(f"{expdir}/{z}") for f in os.listdir(f"{expdir}/{z}/{x}")]
bad, lock = [], threading.Lock()
def work(mine):
    c = http.client.HTTPConnection("127.0.0.1", port, timeout=600)
    for z, x, y in mine:
        c.request("GET", f"/v1/repos/r/quantized-mesh/{z}/{x}/{y}.terrain",
                  headers={"Accept": "application/vnd.quantized-mesh;extensions=octvertexnormals-metadata", "Accept-Encoding": "gzip"})
        r = c.getresponse(); body = r.read()
        if r.status != 200 or body != open(f"{expdir}/{z}/{x}/{y}.terrain", "rb").read():
            with lock: bad.append((z, x, y, r.status))
ts = [threading.Thread(target=work, args=(paths[i::16],)) for i in range(16)]
[t.start() for t in ts]; [t.join() for t in ts]
p.terminate(); p.wait()
print(f"{len(paths)} served tiles compared with the export, {len(bad)} differ: {bad[:5]}")
sys.exit(1 if bad else 0)
