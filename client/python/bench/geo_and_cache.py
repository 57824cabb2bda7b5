"""Planet and remote-cache speed of the Python package (docs/RESULTS.md, "Python package:
planets and the remote cache"). Usage:

    python geo_and_cache.py GLOBAL_DEM.tif PLANAR_DEM.tif CBDAM_BINARY WORKDIR

1. Builds GLOBAL_DEM as a planet (`cbdam.build(..., planet=True)`, the lattice the build picks)
   and times `read_geo` of the whole globe and of a 10° × 10° box at the planet's own spacing
   (its finest level) and at 1°, and `sample_geo` of 100 000 random points: samples/s.
2. Builds PLANAR_DEM and serves it from `cbdam serve` on 127.0.0.1, directly and through
   `cbdam link --profile dsl10` (10 Mbit/s down, 50 ms round trip, docs/NETWORK.md); times a
   windowed read (1 % of the grid) fetched afresh (`cache_bytes=0`), the same window again from
   the cache, and an overlapping window (shifted east by half its width) with and without the
   cache.

Times are medians of 5 runs after one warm-up; each remote figure uses a new reader per run
where the cache must start empty."""

import re
import socket
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import cbdam


def median_seconds(f, runs=5, setup=None):
    """Median wall time of `f(setup())` (setup not timed), after one warm-up."""
    times = []
    for i in range(runs + 1):
        arg = setup() if setup else None
        t = time.perf_counter()
        f(arg)
        if i:
            times.append(time.perf_counter() - t)
    return statistics.median(times)


def planet_figures(dem, work):
    repo = work / "planet.cbdam"
    if not repo.exists():
        cbdam.build([dem], repo, 16.0, planet=True)
    r = cbdam.open(repo)
    finest = r.levels[-1]
    # The finest level's mean spacing: a face's 90° over its S steps (a planet's shape is
    # S + 1 lattice points a side; `read_geo`'s own rule).
    spacing = 90.0 / (r.shape[1] - 1)
    res = 10.0 / round(10.0 / spacing)  # about the spacing, a whole number of cells in 10°
    cases = [
        ("read_geo globe, 1°", dict(bbox=(-180, -90, 180, 90), resolution=1.0)),
        (f"read_geo 10° box, {res:.4f}° (finest)",
         dict(bbox=(0, 40, 10, 50), resolution=res, level=finest)),
        ("read_geo 10° box, 0.1°", dict(bbox=(0, 40, 10, 50), resolution=0.1)),
    ]
    print(f"planet {repo.name}: {r}, finest spacing {spacing:.4f}°")
    for name, kw in cases:
        a = r.read_geo(**kw)
        s = median_seconds(lambda _: r.read_geo(**kw))
        print(f"  {name}: {a.shape[0]} × {a.shape[1]} = {a.size} samples, {s * 1e3:.1f} ms, "
              f"{a.size / s / 1e6:.2f} M samples/s")
    rng = np.random.default_rng(1)
    lons, lats = rng.uniform(-180, 180, 100_000), np.degrees(np.arcsin(rng.uniform(-1, 1, 100_000)))
    s = median_seconds(lambda _: r.sample_geo(lons, lats))
    print(f"  sample_geo 100 000 random points: {s * 1e3:.1f} ms, {1e5 / s / 1e6:.2f} M points/s")


def serve(cbdam_bin, repo):
    proc = subprocess.Popen([cbdam_bin, "serve", str(repo), "--addr", "127.0.0.1:0"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    while True:
        line = proc.stderr.readline()
        m = re.search(r"listening on (http://127\.0\.0\.1:\d+)", line)
        if m:
            return proc, m.group(1)
        if not line:
            raise RuntimeError("cbdam serve did not start")


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def cache_figures(dem, cbdam_bin, work):
    repo = work / "plane.cbdam"
    if not repo.exists():
        cbdam.build([dem], repo, 1.0)
    proc, url = serve(cbdam_bin, repo)
    port = free_port()
    upstream = url.split("//")[1].split("/")[0]
    link = subprocess.Popen([cbdam_bin, "link", "--profile", "dsl10", "--listen",
                             f"127.0.0.1:{port}", "--to", upstream],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    time.sleep(1.0)
    try:
        cache_figures_at(repo, url, "loopback")
        cache_figures_at(repo, url.replace(upstream, f"127.0.0.1:{port}"), "dsl10 link")
    finally:
        link.kill()
        link.wait()
        proc.kill()
        proc.wait()


def cache_figures_at(repo, url, where):
    rows, cols = cbdam.open(repo).shape
    w, h = cols // 10, rows // 10
    first = (cols * 45 // 100, rows * 45 // 100, w, h)
    shifted = (first[0] + w // 2, first[1], w, h)

    def warmed():
        r = cbdam.open(url)
        r.read(window=first)
        return r

    figures = {
        "window, no cache": median_seconds(
            lambda r: r.read(window=first), setup=lambda: cbdam.open(url, cache_bytes=0)),
        "same window again, cached": median_seconds(
            lambda r: r.read(window=first), setup=warmed),
        "overlapping window, no cache": median_seconds(
            lambda r: r.read(window=shifted), setup=lambda: cbdam.open(url, cache_bytes=0)),
        "overlapping window, cached": median_seconds(
            lambda r: r.read(window=shifted), setup=warmed),
    }
    r = warmed()
    before = r.cache_info()
    r.read(window=shifted)
    after = r.cache_info()
    print(f"remote {repo.name} ({rows} × {cols}) over cbdam serve, {where}, 1 % window "
          f"{w} × {h}:")
    for name, s in figures.items():
        print(f"  {name}: {s * 1e3:.1f} ms, {w * h / s / 1e6:.2f} M samples/s")
    print(f"  overlapping window after the first: {after['hits'] - before['hits']} records held, "
          f"{after['misses'] - before['misses']} fetched; cache {after['bytes']} bytes")


def main(global_dem, planar_dem, cbdam_bin, work):
    work = Path(work)
    work.mkdir(parents=True, exist_ok=True)
    planet_figures(global_dem, work)
    cache_figures(planar_dem, cbdam_bin, work)


if __name__ == "__main__":
    main(*sys.argv[1:])
