#!/usr/bin/env python3
"""cbdam's quantized-mesh tiles against @mapbox/martini's RTIN meshes and delatin's Delaunay
refinement meshes (mourner's, npm `delatin`) at the same error
(docs/RESULTS.md, web-map tiles; docs/WEB-MAPS.md). A measurement, not a test.

For every available quantized-mesh tile of the levels asked (`cbdam tiles REPO --format
quantized-mesh`), both meshes are made on the tile's 65 x 65 grid (the grid cbdam's vertices are
chosen from): Martini (`getMesh(maxError)`, maxError = layer.json's `triangulation_threshold_m`
of the level; delatin: `run(maxError)` with the same maxError) on the repository's heights at the grid points (the bilinear interpolation of
`cbdam extract --float64`'s finest level; 0 m without data, as cbdam's vertices), cbdam's as
exported. Both are then written by the same quantized-mesh encoder (below: the tile's own
88-byte header, zig-zag delta u/v/height, high-water-mark indices, edge lists; no extensions)
and gzip-compressed at the same level (zlib level 1, as cbdam's tiles), so the bytes compare
like for like. The encoder is checked on cbdam's tiles first: re-encoding a decoded cbdam tile
gives its bytes exactly. Martini's error is measured at the grid points only; cbdam's also at
every repository sample inside each triangle (docs/WEB-MAPS.md), so at the same threshold it
keeps at least as many vertices where the terrain is rough between grid points. Delatin also
measures its error at the grid points only, but its triangles are not bound to the RTIN
hierarchy (any grid point can be a vertex, Delaunay-refined).

Usage: martini_compare.py CBDAM_BINARY REPO.cbdam LEVELS [MAX_TILES_PER_LEVEL]
  LEVELS: comma-separated quantized-mesh levels, e.g. 9,10,11,12. An EPSG:4326 plane only.
  MAX_TILES_PER_LEVEL: every k-th available tile (in x, then y order) so that at most this
  many are compared.
  Installs @mapbox/martini and delatin (scripts/web-maps/martini/package-lock.json) with npm into
  target/web-maps-node/martini (set CBDAM_MARTINI_DIR to use another directory).
"""
import array
import gzip
import json
import math
import os
import shutil
import struct
import subprocess
import sys
import tempfile
import zlib

GRID, QMAX = 64, 32767
HERE = os.path.dirname(os.path.abspath(__file__))
R_AUTHALIC_KM = 6371.007


def install_martini():
    node_dir = os.environ.get("CBDAM_MARTINI_DIR",
                              os.path.join(HERE, "..", "..", "target", "web-maps-node", "martini"))
    lock = os.path.join(HERE, "martini", "package-lock.json")
    have = os.path.join(node_dir, "package-lock.json")
    if not (os.path.exists(have) and open(have, "rb").read() == open(lock, "rb").read()
            and os.path.isdir(os.path.join(node_dir, "node_modules", "@mapbox", "martini"))
            and os.path.isdir(os.path.join(node_dir, "node_modules", "delatin"))):
        os.makedirs(node_dir, exist_ok=True)
        for f in ("package.json", "package-lock.json"):
            shutil.copy(os.path.join(HERE, "martini", f), node_dir)
        r = subprocess.run(["npm", "ci", "--ignore-scripts", "--no-audit", "--no-fund", "--loglevel=error"],
                           cwd=node_dir)
        if r.returncode:
            raise SystemExit("npm ci of @mapbox/martini failed (no registry?)")
    return node_dir


def decode_tile(data):
    """(header bytes, u, v, h, triangles, edges, bytes before the extensions) of a tile."""
    header = data[:88]
    (n,) = struct.unpack_from("<I", data, 88)
    pos = 92
    arrays = []
    for _ in range(3):
        zz = struct.unpack_from(f"<{n}H", data, pos)
        pos += 2 * n
        out, prev = [], 0
        for z in zz:
            prev += (z >> 1) ^ -(z & 1)
            out.append(prev)
        arrays.append(out)
    wide = n > 65536
    size, code = (4, "I") if wide else (2, "H")
    pos += (-pos) % size
    (t,) = struct.unpack_from("<I", data, pos)
    pos += 4
    coded = struct.unpack_from(f"<{3 * t}{code}", data, pos)
    pos += 3 * t * size
    highest, triangles = 0, []
    for c in coded:
        k = highest - c
        triangles.append(k)
        if c == 0:
            highest += 1
    edges = []
    for _ in range(4):
        (m,) = struct.unpack_from("<I", data, pos)
        pos += 4
        edges.append(list(struct.unpack_from(f"<{m}{code}", data, pos)))
        pos += m * size
    return header, arrays[0], arrays[1], arrays[2], triangles, edges, pos


def zigzag(values):
    out, prev = [], 0
    for v in values:
        d = v - prev
        prev = v
        out.append(((d << 1) ^ (d >> 31)) & 0xFFFF)
    return out


def encode_tile(header, u, v, h, triangles):
    """The quantized-mesh bytes (no extensions) of vertices in first-use order."""
    n = len(u)
    out = bytearray(header)
    out += struct.pack("<I", n)
    for a in (u, v, h):
        out += struct.pack(f"<{n}H", *zigzag(a))
    wide = n > 65536
    size, code = (4, "I") if wide else (2, "H")
    out += b"\0" * ((-len(out)) % size)
    out += struct.pack("<I", len(triangles) // 3)
    highest, coded = 0, []
    for k in triangles:
        coded.append(highest - k)
        if k == highest:
            highest += 1
    out += struct.pack(f"<{len(coded)}{code}", *coded)
    for on, along in ((lambda a, b: a == 0, 1), (lambda a, b: b == 0, 0),
                      (lambda a, b: a == QMAX, 1), (lambda a, b: b == QMAX, 0)):
        side = sorted(((u[k], v[k])[along], k) for k in range(n) if on(u[k], v[k]))
        out += struct.pack("<I", len(side)) + struct.pack(f"<{len(side)}{code}", *[k for _, k in side])
    return bytes(out)


def gz(data):
    c = zlib.compressobj(1, zlib.DEFLATED, 31)
    return c.compress(data) + c.flush()


def reference(cbdam, repo, tmp):
    """The bilinear interpolation of the finest level's samples at (lat, lon); None without data."""
    out = os.path.join(tmp, "x.f64")
    subprocess.run([cbdam, "extract", repo, "-o", out, "--format", "raw", "--float64", "--quiet"], check=True)
    meta = json.load(open(os.path.join(tmp, "x.json")))
    values = array.array("d")
    values.frombytes(open(out, "rb").read())
    g, w, hgt = meta["georef"], meta["width"], meta["height"]
    if g["epsg"] != 4326:
        raise SystemExit("this comparison places samples in EPSG:4326 only")
    half = 0.5 if g["pixel_is"] == "area" else 0.0
    nodata = meta.get("nodata")

    def at(lat, lon):
        c = (lon - g["origin_x"]) / g["pixel_x"] - half
        r = (g["origin_y"] - lat) / g["pixel_y"] - half
        ci, ri = math.floor(c), math.floor(r)
        tx, ty = c - ci, r - ri
        total = weight = 0.0
        for dc, dr, wt in ((0, 0, (1 - tx) * (1 - ty)), (1, 0, tx * (1 - ty)),
                           (0, 1, (1 - tx) * ty), (1, 1, tx * ty)):
            cc, rr = ci + dc, ri + dr
            if 0 <= cc < w and 0 <= rr < hgt and wt > 0:
                s = values[rr * w + cc]
                if not math.isnan(s) and s != nodata:
                    total += wt * s
                    weight += wt
        return total / weight if weight > 0 else None
    return at


def tile_area_km2(z, y):
    cell = 180.0 / 2 ** z
    s, n = math.radians(-90 + y * cell), math.radians(-90 + (y + 1) * cell)
    return R_AUTHALIC_KM ** 2 * math.radians(cell) * (math.sin(n) - math.sin(s))


def find(doc, key):
    if isinstance(doc, dict):
        if key in doc:
            return doc[key]
        for v in doc.values():
            found = find(v, key)
            if found is not None:
                return found
    return None


def mesh_of(proc, mesher, heights, max_error):
    job = {"mesher": mesher, "size": GRID + 1, "heights": heights, "maxError": max_error}
    proc.stdin.write(json.dumps(job) + "\n")
    proc.stdin.flush()
    mesh = json.loads(proc.stdout.readline())
    return mesh["vertices"], mesh["triangles"]


def compare_tile(proc, at, data, z, x, y, threshold):
    header, u, v, h, tri, _, core_end = decode_tile(data)
    assert encode_tile(header, u, v, h, tri) == data[:core_end], f"{z}/{x}/{y}: the encoder differs"
    lo, hi = struct.unpack_from("<ff", header, 24)
    cell = 180.0 / (2 ** z * GRID)
    heights = []  # row j (from the south), column i
    for j in range(GRID + 1):
        for i in range(GRID + 1):
            value = at(-90 + (y * GRID + j) * cell, -180 + (x * GRID + i) * cell)
            heights.append(0.0 if value is None else value)
    ours = gz(data[:core_end])
    out = [(len(u), len(tri) // 3, len(ours))]
    for mesher in MESHERS:
        verts, tris = mesh_of(proc, mesher, heights, threshold)
        out.append(encoded_size(header, verts, tris, heights, (lo, hi)))
    return out


def encoded_size(header, verts, tris, heights, lo_hi):
    """Vertices, triangles and gzip bytes of a mesh on the tile's grid, by the same encoder."""
    lo, hi = lo_hi
    order, renumber, triangles = [], {}, []
    for k in tris:
        if k not in renumber:
            renumber[k] = len(order)
            order.append(k)
        triangles.append(renumber[k])
    grid_q = lambda g: (g * QMAX + GRID // 2) // GRID  # noqa: E731
    mu = [grid_q(verts[2 * k]) for k in order]
    mv = [grid_q(verts[2 * k + 1]) for k in order]
    quant = lambda hh: round(min(1.0, max(0.0, (hh - lo) / (hi - lo))) * QMAX)  # noqa: E731
    mh = [quant(heights[verts[2 * k + 1] * (GRID + 1) + verts[2 * k]]) for k in order]
    return len(order), len(triangles) // 3, len(gz(encode_tile(header, mu, mv, mh, triangles)))


MESHERS = ("martini", "delatin")


def main():
    cbdam, repo, levels = sys.argv[1], sys.argv[2], [int(v) for v in sys.argv[3].split(",")]
    cap = int(sys.argv[4]) if len(sys.argv) > 4 else 10 ** 9
    node_dir = install_martini()
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "qm")
        subprocess.run([cbdam, "tiles", repo, "--format", "quantized-mesh", "-o", out,
                        "--max-zoom", str(max(levels)), "--quiet"], check=True)
        thresholds = find(json.load(open(os.path.join(out, "layer.json"))), "triangulation_threshold_m")
        at = reference(cbdam, repo, tmp)
        proc = subprocess.Popen(["node", os.path.join(HERE, "martini_mesh.js"), node_dir],
                                stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        print("| level | tiles | threshold m | cbdam vertices / triangles / gzip bytes a tile "
              "| Martini v / t / B | Delatin v / t / B | bytes Martini / cbdam "
              "| bytes Delatin / cbdam | B/km² cbdam / Martini / Delatin |")
        print("|---:|---:|---:|---|---|---|---:|---:|---|")
        for z in levels:
            zdir = os.path.join(out, str(z))
            if not os.path.isdir(zdir):
                continue
            tiles = sorted((int(xd), int(f[:-8])) for xd in os.listdir(zdir)
                           for f in os.listdir(os.path.join(zdir, xd)))
            tiles = tiles[::math.ceil(len(tiles) / cap)]  # spread over the level
            sums = [[0, 0, 0] for _ in range(1 + len(MESHERS))]
            area = 0.0
            for x, y in tiles:
                data = gzip.decompress(open(os.path.join(zdir, str(x), f"{y}.terrain"), "rb").read())
                for s, r in zip(sums, compare_tile(proc, at, data, z, x, y, thresholds[z])):
                    for k in range(3):
                        s[k] += r[k]
                area += tile_area_km2(z, y)
            n = len(tiles)
            (cv, ct, cb), (mv, mt, mb), (dv, dt, db) = sums
            print(f"| {z} | {n} | {thresholds[z]:.2f} | {cv / n:.0f} / {ct / n:.0f} / {cb / n:.0f} "
                  f"| {mv / n:.0f} / {mt / n:.0f} / {mb / n:.0f} "
                  f"| {dv / n:.0f} / {dt / n:.0f} / {db / n:.0f} | {mb / cb:.2f} | {db / cb:.2f} "
                  f"| {cb / area:.3g} / {mb / area:.3g} / {db / area:.3g} |", flush=True)
        proc.stdin.close()
        proc.wait()


if __name__ == "__main__":
    main()
