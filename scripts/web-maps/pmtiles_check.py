#!/usr/bin/env python3
"""A PMTiles archive written by `cbdam tiles -o OUT.pmtiles`, read back by an independent
reader (the `pmtiles` package from pip, not cbdam's writer): every tile of the directory export
of the same repository and format is in it with the same bytes, and no other; the header's tile
type, zooms and counts and the metadata's TileJSON fields agree with the export's tiles.json.
Run by scripts/web-maps-test.sh. Exits non-zero on the first difference.

Usage: pmtiles_check.py ARCHIVE.pmtiles EXPORT_DIR
"""
import json, os, sys

from pmtiles.reader import MmapSource, Reader, all_tiles
from pmtiles.tile import TileType

archive, export = sys.argv[1], sys.argv[2]
files = {}
for root, _, names in os.walk(export):
    for name in names:
        if name.endswith((".png", ".webp")):
            z, x = os.path.relpath(root, export).split(os.sep)
            files[(int(z), int(x), int(name.split(".")[0]))] = os.path.join(root, name)
ext = {os.path.splitext(p)[1] for p in files.values()}
assert len(ext) == 1, f"the export mixes {ext}"
tilejson = json.load(open(os.path.join(export, "tiles.json")))

with open(archive, "rb") as f:
    source = MmapSource(f)
    reader = Reader(source)
    header, meta = reader.header(), reader.metadata()
    want_type = {".png": TileType.PNG, ".webp": TileType.WEBP}[ext.pop()]
    assert header["tile_type"] == want_type, (header["tile_type"], want_type)
    zooms = [z for z, _, _ in files]
    assert (header["min_zoom"], header["max_zoom"]) == (min(zooms), max(zooms)), header
    assert header["addressed_tiles_count"] == len(files), (header["addressed_tiles_count"], len(files))
    for key in ("encoding", "maxzoom", "tileSize", "bounds"):
        assert meta[key] == tilejson[key], (key, meta[key], tilejson[key])
    seen = set()
    for (z, x, y), data in all_tiles(source):
        assert (z, x, y) in files, f"tile {z}/{x}/{y} is not in the export"
        assert (z, x, y) not in seen, f"tile {z}/{x}/{y} twice"
        seen.add((z, x, y))
        assert data == open(files[(z, x, y)], "rb").read(), f"tile {z}/{x}/{y} differs"
    assert seen == set(files), f"{len(set(files) - seen)} exported tiles missing"
    # Random access too, as a map client reads it (through the leaf directories if any).
    for (z, x, y), path in files.items():
        assert reader.get(z, x, y) == open(path, "rb").read(), f"get {z}/{x}/{y} differs"
    print(json.dumps({"archive": archive, "tiles": len(files), "bytes": os.path.getsize(archive),
                      "entries": header["tile_entries_count"],
                      "contents": header["tile_contents_count"]}))
