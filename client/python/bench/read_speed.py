"""Read speed of the Python package against `cbdam extract` and rasterio (docs/RESULTS.md,
"Python package"): whole-grid reads in samples/s, a windowed read of 1 % of the grid, import
time. Usage: python read_speed.py DEM.tif CBDAM_BINARY WORKDIR [MAX_ERROR]

Builds DEM into a repository with cbdam.build, writes the same data as a deflate-compressed
tiled COG with rasterio, then times (median of 5 runs, after one warm-up) each reader."""

import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import rasterio
from rasterio.windows import Window

import cbdam


def median_seconds(f, runs=5):
    f()
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        f()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def rasterio_read(path, window=None):
    with rasterio.open(path) as src:
        return src.read(1, window=window)


def main(dem, cbdam_bin, work, max_error="1"):
    work = Path(work)
    work.mkdir(parents=True, exist_ok=True)
    repo = work / "bench.cbdam"
    cbdam.build([dem], repo, float(max_error))
    cog = work / "bench_cog.tif"
    with rasterio.open(dem) as src:
        profile = src.profile
        data = src.read(1)
    profile.update(driver="COG", compress="DEFLATE", blocksize=512)
    with rasterio.open(cog, "w", **profile) as dst:
        dst.write(data, 1)
    r = cbdam.open(repo)
    rows, cols = r.shape
    samples = rows * cols
    # 1 % of the samples: a window a tenth of each side, in the middle.
    w = Window(cols * 45 // 100, rows * 45 // 100, cols // 10, rows // 10)
    window = (w.col_off, w.row_off, w.width, w.height)
    out = work / "extract.tif"
    figures = {
        "cbdam read (whole)": median_seconds(lambda: r.read()),
        "cbdam extract (whole, to GeoTIFF)": median_seconds(
            lambda: subprocess.run(
                [cbdam_bin, "extract", str(repo), "-o", str(out), "--quiet"], check=True
            ),
            runs=3,
        ),
        "rasterio GeoTIFF (whole)": median_seconds(lambda: rasterio_read(dem)),
        "rasterio deflate COG (whole)": median_seconds(lambda: rasterio_read(cog)),
        "cbdam read (1 % window)": median_seconds(lambda: r.read(window=window)),
        "rasterio deflate COG (1 % window)": median_seconds(lambda: rasterio_read(cog, w)),
    }
    print(f"{dem}: {cols} x {rows} samples, repository {repo.stat().st_size} bytes, "
          f"COG {cog.stat().st_size} bytes, input {Path(dem).stat().st_size} bytes")
    for name, s in figures.items():
        n = samples if "whole" in name else w.width * w.height
        print(f"{name:40s} {s * 1000:9.1f} ms  {n / s / 1e6:8.1f} M samples/s")
    assert np.array_equal(np.isnan(r.read(window=window)), np.isnan(r.read()[w.toslices()]))
    # Import time: python -X importtime's cumulative microseconds of the package, median of 5.
    def import_us():
        p = subprocess.run(
            [sys.executable, "-X", "importtime", "-c", "import cbdam"],
            capture_output=True, text=True, check=True,
        )
        line = [x for x in p.stderr.splitlines() if x.rstrip().endswith("| cbdam")][-1]
        return int(line.split("|")[1])

    print(f"import cbdam: {statistics.median(import_us() for _ in range(5)) / 1000:.1f} ms")


if __name__ == "__main__":
    main(*sys.argv[1:])
