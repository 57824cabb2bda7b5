#!/usr/bin/env python3
"""Latency of `cbdam serve`'s web-map tiles under concurrent clients on loopback
(docs/RESULTS.md, web-map tiles). A measurement, not a test.

Starts a fresh `cbdam serve REPO`, then CLIENTS threads, each on its own keep-alive HTTP/1.1
connection, fetch every tile of the levels maxzoom-LEVELS…maxzoom (quantized-mesh: those
`layer.json` lists; terrarium: those meeting `tiles.json`'s bounds), shuffled and dealt round
robin, back to back: the "cold" pass (each tile's first request, from a server that has only
read its records) and then the same tiles again ("warm"). Reports per pass p50 / p99 latency
(send to last body byte, ms) and tiles/s, as JSON lines. Every answer must be 200.

Usage: tiles_load.py CBDAM_BINARY REPO.cbdam terrain|png CLIENTS LEVELS [TOP]

TOP, when given, stands for maxzoom: the levels TOP-LEVELS…TOP (a planet's deepest levels
hold more tiles than a measurement can wait for).
"""
import contextlib, http.client, json, math, random, re, subprocess, sys, threading, time

binary, repo, kind, clients, levels = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4]), int(sys.argv[5])
top = int(sys.argv[6]) if len(sys.argv) > 6 else None
ACCEPT = "application/vnd.quantized-mesh;extensions=octvertexnormals-metadata"


@contextlib.contextmanager
def served():
    """A fresh `cbdam serve REPO` on a free loopback port: yields the port, and stops the
    server however the block is left (an exception, a failed print into a closed pipe, Ctrl-C),
    killing it if SIGTERM has not stopped it within 10 s."""
    p = subprocess.Popen([binary, "serve", f"r={repo}", "--addr", "127.0.0.1:0"],
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    said = []
    try:
        for line in p.stderr:
            said.append(line)
            m = re.search(r"listening on http://127.0.0.1:(\d+)", line)
            if m:
                threading.Thread(target=lambda: [None for _ in p.stderr], daemon=True).start()
                yield int(m.group(1))
                return
        raise SystemExit("cbdam serve did not start: " + "".join(said[-5:]))
    finally:
        p.terminate()
        try:
            p.wait(timeout=10)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def tile_paths(port):
    c = http.client.HTTPConnection("127.0.0.1", port)
    if kind == "terrain":
        c.request("GET", "/v1/repos/r/quantized-mesh/layer.json")
        layer = json.loads(c.getresponse().read())
        z = layer["maxzoom"] if top is None else min(top, layer["maxzoom"])
        return [f"/v1/repos/r/quantized-mesh/{zz}/{x}/{y}.terrain"
                for zz in range(max(0, z - levels), z + 1) for r in layer["available"][zz]
                for x in range(r["startX"], r["endX"] + 1) for y in range(r["startY"], r["endY"] + 1)]
    c.request("GET", "/v1/repos/r/terrarium/tiles.json")
    tj = json.loads(c.getresponse().read())
    w, s, e, n = tj["bounds"]
    z = tj["maxzoom"] if top is None else min(top, tj["maxzoom"])
    out = []
    for zz in range(max(0, z - levels), z + 1):
        k = 2 ** zz
        col = lambda lon: min(k - 1, int((lon + 180) / 360 * k))
        row = lambda lat: min(k - 1, int((1 - math.asinh(math.tan(math.radians(lat))) / math.pi) / 2 * k))
        out += [f"/v1/repos/r/terrarium/{zz}/{x}/{y}.png"
                for x in range(col(w), col(e) + 1) for y in range(row(n), row(s) + 1)]
    return out


def run_pass(port, paths):
    lat, lock = [], threading.Lock()
    share = [paths[i::clients] for i in range(clients)]

    def client(mine):
        c = http.client.HTTPConnection("127.0.0.1", port)
        got = []
        for p in mine:
            t = time.perf_counter()
            c.request("GET", p, headers={"Accept": ACCEPT, "Accept-Encoding": "gzip"})
            r = c.getresponse()
            r.read()
            assert r.status == 200, (p, r.status)
            got.append(time.perf_counter() - t)
        with lock:
            lat.extend(got)

    threads = [threading.Thread(target=client, args=(m,)) for m in share]
    t = time.perf_counter()
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    wall = time.perf_counter() - t
    lat.sort()
    q = lambda f: lat[min(len(lat) - 1, int(f * len(lat)))] * 1000
    return {"tiles": len(lat), "p50_ms": round(q(0.5), 1), "p99_ms": round(q(0.99), 1),
            "tiles_per_s": round(len(lat) / wall, 1)}


with served() as port:
    # The first request reads the records (and starts the background decode); not timed here.
    paths = tile_paths(port)
    random.seed(1)
    random.shuffle(paths)
    for name in ("cold", "warm"):
        line = json.dumps({"kind": kind, "clients": clients, "pass": name, **run_pass(port, paths)})
        print(line, flush=True)
