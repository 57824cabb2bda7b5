#!/usr/bin/env python3
"""A stand-in orthophoto derived from a DEM, for colour-repository tests and measurements.

Usage: ortho_from_dem.py DEM.f32 WIDTH HEIGHT OUT.png [SCALE]

DEM.f32 is what `cbdam extract REPO --format raw -o DEM.f32` writes (little-endian float32,
row 0 north). The image is (WIDTH-1)*SCALE+1 x (HEIGHT-1)*SCALE+1 pixels (SCALE a power of two,
default 1; heights interpolated bilinearly), so `cbdam build OUT.png --colour --like REPO`
accepts it. Colour: a hypsometric ramp, hillshade from the heights, a field pattern of flat
patches with their own tint below 60 % of the height range, and ±3 levels of hashed noise —
flat regions, smooth gradients, sharp edges and sensor-like noise together. Standard library
only (no numpy / PIL).
"""
import os
import struct
import sys
import zlib


def main():
    path, w, h, out = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
    scale = int(sys.argv[5]) if len(sys.argv) > 5 else 1
    raw = open(path, "rb").read()
    z = struct.unpack("<%df" % (w * h), raw[: 4 * w * h])
    lo, hi = min(z), max(z)
    span = (hi - lo) or 1.0
    ramp = [(0.0, (40, 90, 40)), (0.3, (110, 150, 60)), (0.6, (170, 150, 90)),
            (0.85, (140, 120, 110)), (1.0, (245, 245, 250))]

    def colour(t):
        for (t0, c0), (t1, c1) in zip(ramp, ramp[1:]):
            if t <= t1:
                f = (t - t0) / (t1 - t0)
                return [c0[i] + f * (c1[i] - c0[i]) for i in range(3)]
        return list(ramp[-1][1])

    def height(x, y):
        x0, y0 = min(int(x), w - 2), min(int(y), h - 2)
        fx, fy = x - x0, y - y0
        a, b = z[y0 * w + x0], z[y0 * w + x0 + 1]
        c, d = z[(y0 + 1) * w + x0], z[(y0 + 1) * w + x0 + 1]
        return (a * (1 - fx) + b * fx) * (1 - fy) + (c * (1 - fx) + d * fx) * fy

    W, H = (w - 1) * scale + 1, (h - 1) * scale + 1
    rows = []
    for j in range(H):
        row = bytearray([0])
        for i in range(W):
            x, y = i / scale, j / scale
            e = height(x, y)
            dx = height(min(x + 1, w - 1), y) - height(max(x - 1, 0), y)
            dy = height(x, min(y + 1, h - 1)) - height(x, max(y - 1, 0))
            shade = max(0.35, min(1.2, 0.85 + (dy - dx) / span * 20))
            t = (e - lo) / span
            c = colour(t)
            if t < 0.6:
                field = ((int(x) // 24) * 7 + (int(y) // 18) * 13) % 5
                c = [c[0] + (field - 2) * 9, c[1] + (2 - field) * 6, c[2] + (field % 2) * 12]
            n = ((i * 2654435761 + j * 40503) >> 8) % 7 - 3
            row += bytes(max(0, min(255, int(v * shade) + n)) for v in c)
        rows.append(bytes(row))
    write_png(out, W, H, rows)
    print(f"{out}: {W}x{H} RGB")


def write_png(path, width, height, rows):
    """Writes an 8-bit RGB PNG (atomically) from `rows`, each a filter byte (0) and
    3 * `width` bytes; also used by scripts/web_test.py."""
    def chunk(kind, data):
        return (struct.pack(">I", len(data)) + kind + data
                + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF))
    png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
           + chunk(b"IDAT", zlib.compress(b"".join(rows), 9)) + chunk(b"IEND", b""))
    with open(path + ".tmp", "wb") as f:
        f.write(png)
    os.replace(path + ".tmp", path)


if __name__ == "__main__":
    main()
