#!/usr/bin/env python3
"""Adds GeoTIFF georeferencing (EPSG:4326, PixelIsPoint) to a TIFF that has none, in place,
without touching its image data: a new first IFD with the original entries plus
ModelPixelScale (33550), ModelTiepoint (33922) and GeoKeyDirectory (34735) is appended and the
header points at it. Only little- or big-endian classic TIFF with one image is handled.

How `data/etopo5_global.tif` got its georeferencing (issue 19):
    python3 data/tools/georeference_tiff.py data/etopo5_global.tif \
        --lon0 0 --lat0 90 --step 0.08333333333333333
(sample (0, 0) is the point lon 0°, lat 90°; columns run east, rows south, 5′ apart.)
"""
import argparse
import struct
import sys

TYPE_SIZES = {1: 1, 2: 1, 3: 2, 4: 4, 5: 8, 6: 1, 7: 1, 8: 2, 9: 4, 10: 8, 11: 4, 12: 8}
GEO_TAGS = (33550, 33922, 34735)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("tiff")
    ap.add_argument("--lon0", type=float, required=True, help="longitude of sample (0, 0)")
    ap.add_argument("--lat0", type=float, required=True, help="latitude of sample (0, 0)")
    ap.add_argument("--step", type=float, required=True, help="degrees between samples")
    a = ap.parse_args()
    data = bytearray(open(a.tiff, "rb").read())
    if data[:2] not in (b"II", b"MM"):
        sys.exit(f"{a.tiff}: not a TIFF (byte order mark {bytes(data[:2])!r})")
    e = "<" if data[:2] == b"II" else ">"
    magic, ifd = struct.unpack(e + "HI", data[2:8])
    if magic != 42:
        sys.exit(f"{a.tiff}: not a classic TIFF (magic {magic})")
    (n,) = struct.unpack(e + "H", data[ifd : ifd + 2])
    entries = [bytes(data[ifd + 2 + 12 * i : ifd + 14 + 12 * i]) for i in range(n)]
    (next_ifd,) = struct.unpack(e + "I", data[ifd + 2 + 12 * n : ifd + 6 + 12 * n])
    if next_ifd != 0:
        sys.exit(f"{a.tiff}: more than one image; not handled")
    tags = {struct.unpack(e + "H", x[:2])[0]: x for x in entries}
    if any(t in tags for t in GEO_TAGS):
        sys.exit(f"{a.tiff}: already georeferenced")

    def append(payload):
        if len(data) % 2:
            data.append(0)
        at = len(data)
        data.extend(payload)
        return at

    scale = struct.pack(e + "3d", a.step, a.step, 0.0)
    tie = struct.pack(e + "6d", 0.0, 0.0, 0.0, a.lon0, a.lat0, 0.0)
    # GeoKeyDirectory v1.1.0: GTModelType = Geographic (2), GTRasterType = PixelIsPoint (2),
    # GeographicType = WGS 84 (4326), GeogAngularUnits = degree (9102).
    keys = [1, 1, 0, 4, 1024, 0, 1, 2, 1025, 0, 1, 2, 2048, 0, 1, 4326, 2054, 0, 1, 9102]
    geokeys = struct.pack(e + f"{len(keys)}H", *keys)
    tags[33550] = struct.pack(e + "HHII", 33550, 12, 3, append(scale))
    tags[33922] = struct.pack(e + "HHII", 33922, 12, 6, append(tie))
    tags[34735] = struct.pack(e + "HHII", 34735, 3, len(keys), append(geokeys))
    ifd_bytes = struct.pack(e + "H", len(tags))
    ifd_bytes += b"".join(tags[t] for t in sorted(tags)) + struct.pack(e + "I", 0)
    new_ifd = append(ifd_bytes)
    data[4:8] = struct.pack(e + "I", new_ifd)
    tmp = a.tiff + ".tmp"
    with open(tmp, "wb") as f:
        f.write(data)
    import os

    os.replace(tmp, a.tiff)
    print(f"{a.tiff}: georeferenced (EPSG:4326, PixelIsPoint, origin {a.lon0}, {a.lat0}, step {a.step}°)")


if __name__ == "__main__":
    main()
