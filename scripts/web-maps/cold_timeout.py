#!/usr/bin/env python3
"""Cold quantized-mesh tiles against `cbdam serve --timeout SECONDS` (docs/RESULTS.md, web-map
tiles, tiles7): 128 shuffled tiles of levels 3 and 4 of `layer.json`'s `available`, asked by 16
concurrent clients from a fresh server, then those answered 408 asked again one after the
other. Prints the statuses of both rounds and their latencies as JSON lines. A measurement,
not a test.

Usage: cold_timeout.py CBDAM_BINARY REPO.cbdam TIMEOUT_SECONDS
"""
import http.client, json, random, re, subprocess, sys, threading, time

binary, repo, timeout = sys.argv[1], sys.argv[2], sys.argv[3]
ACCEPT = "application/vnd.quantized-mesh;extensions=octvertexnormals-metadata"
p = subprocess.Popen([binary, "serve", f"r={repo}", "--addr", "127.0.0.1:0", "--timeout", timeout],
                     stderr=subprocess.PIPE, text=True)
for line in p.stderr:
    m = re.search(r"listening on http://127.0.0.1:(\d+)", line)
    if m:
        port = int(m.group(1))
        threading.Thread(target=lambda: [None for _ in p.stderr], daemon=True).start()
        break


def get(path):
    """(status, milliseconds) of one GET on a new connection."""
    c = http.client.HTTPConnection("127.0.0.1", port, timeout=600)
    started = time.time()
    c.request("GET", path, headers={"Accept": ACCEPT})
    r = c.getresponse()
    r.read()
    return r.status, (time.time() - started) * 1000


c = http.client.HTTPConnection("127.0.0.1", port)
c.request("GET", "/v1/repos/r/quantized-mesh/layer.json")
layer = json.loads(c.getresponse().read())
tiles = []
for z in (3, 4):
    for r in layer["available"][z]:
        tiles += [(z, x, y) for x in range(r["startX"], r["endX"] + 1) for y in range(r["startY"], r["endY"] + 1)]
random.seed(1)
random.shuffle(tiles)
tiles = tiles[:128]
answers = {}


def client(k):
    for t in tiles[k::16]:
        answers[t] = get("/v1/repos/r/quantized-mesh/%d/%d/%d.terrain" % t)


threads = [threading.Thread(target=client, args=(k,)) for k in range(16)]
for t in threads:
    t.start()
for t in threads:
    t.join()
late = [t for t, (status, _) in answers.items() if status == 408]
statuses = sorted({s for s, _ in answers.values()})
print(json.dumps({"timeout_s": float(timeout), "tiles": len(tiles),
                  "statuses": {s: sum(1 for v in answers.values() if v[0] == s) for s in statuses},
                  "slowest_200_ms": max([ms for s, ms in answers.values() if s == 200] or [0])}))
again = [get("/v1/repos/r/quantized-mesh/%d/%d/%d.terrain" % t) for t in late]
print(json.dumps({"asked_again": len(late), "statuses": sorted({s for s, _ in again}),
                  "p50_ms": sorted(ms for _, ms in again)[len(again) // 2] if again else None,
                  "max_ms": max([ms for _, ms in again] or [0])}))
p.terminate()
p.wait()
