#!/usr/bin/env python3
"""A PMTiles archive with leaf directories, written by cbdam's writer
(`server/tiles/examples/pmtiles_many_tiles.rs`: every tile of levels 0…Z, each tile's bytes a
function of its tile id, computed here again), read back by an independent reader (the
`pmtiles` package from pip): the header says there are leaf directories, iterating the
archive gives every tile once with its bytes, and so does `Reader.get` of each. Run by
scripts/web-maps-test.sh. Exits non-zero on the first difference.

Usage: pmtiles_leaves_check.py ARCHIVE.pmtiles MAX_ZOOM
"""
import json, os, sys

from pmtiles.reader import MmapSource, Reader, all_tiles
from pmtiles.tile import zxy_to_tileid


def source(tile):
    """The tile whose bytes `tile` holds (as the writer's example says, written again)."""
    if tile % 5 == 4:
        return source(tile - 1)
    if tile % 11 == 10 and tile > 20:
        return 7
    return tile


def payload(s):
    n = (s * 2654435761) % 301
    return f"tile {s}:".encode() + bytes((s * 7 + i * 13) % 251 for i in range(n))


archive, max_zoom = sys.argv[1], int(sys.argv[2])
want = {(z, x, y): payload(source(zxy_to_tileid(z, x, y)))
        for z in range(max_zoom + 1) for x in range(1 << z) for y in range(1 << z)}
with open(archive, "rb") as f:
    src = MmapSource(f)
    reader = Reader(src)
    header = reader.header()
    assert header["leaf_directory_length"] > 0, f"no leaf directories: {header}"
    assert header["addressed_tiles_count"] == len(want), header
    assert header["tile_entries_count"] < len(want), "no runs were made"
    assert header["tile_contents_count"] < header["tile_entries_count"], "no repeat stored once"
    seen = set()
    for zxy, data in all_tiles(src):
        assert zxy in want, f"tile {zxy} is not one written"
        assert zxy not in seen, f"tile {zxy} twice"
        assert data == want[zxy], f"tile {zxy} differs"
        seen.add(zxy)
    assert seen == set(want), f"{len(set(want) - seen)} tiles missing"
    # Random access as a map client reads it, root then leaf directory, for one tile in 37
    # (this reader decompresses the directories again for each tile).
    for (z, x, y), data in list(want.items())[::37]:
        assert reader.get(z, x, y) == data, f"get {z}/{x}/{y} differs"
    print(json.dumps({"archive": archive, "tiles": len(want), "bytes": os.path.getsize(archive),
                      "root_directory_bytes": header["root_length"],
                      "leaf_directories_bytes": header["leaf_directory_length"],
                      "entries": header["tile_entries_count"],
                      "contents": header["tile_contents_count"]}))
