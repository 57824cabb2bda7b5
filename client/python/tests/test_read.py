"""Local reads: the header as Python values, and `read` equal to `cbdam extract` sample for
sample (whole, windows, bboxes, levels, nodata); errors raised, never a crash; threads."""

import json
import subprocess
import threading

import numpy as np
import pytest
import rasterio
from conftest import DATA

import cbdam


def same(a, b):
    """Equal sample for sample, NaN where the other is NaN."""
    assert a.shape == b.shape, (a.shape, b.shape)
    assert np.array_equal(np.isnan(a), np.isnan(b)), "nodata differs"
    ok = ~np.isnan(a)
    assert np.array_equal(a[ok], b[ok]), f"max diff {np.max(np.abs(a[ok] - b[ok]))}"


def test_header_matches_the_cli_and_the_input(repos, cbdam_bin):
    r = cbdam.open(repos["jacksboro"])
    inspect = json.loads(
        subprocess.run(
            [cbdam_bin, "inspect", str(repos["jacksboro"]), "--json"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout
    )
    # `inspect --json` is the description `/meta` serves, plus the nodata mask's statistics
    # (which it decodes the mask for).
    extra = {"nodata_fraction", "nodata_mask", "nodata_samples"}
    assert set(inspect) - set(r.meta) == extra
    assert r.meta == {k: v for k, v in inspect.items() if k not in extra}
    with rasterio.open(DATA / "jacksboro_mpl.tif") as src:
        assert r.shape == (src.height, src.width)
        assert np.allclose(r.bounds, tuple(src.bounds), rtol=0, atol=1e-9)
        assert r.transform() == pytest.approx(tuple(src.transform)[:6], abs=1e-12)
        assert r.crs == f"EPSG:{src.crs.to_epsg()}"
    assert r.domain == "planar"
    assert r.levels[-1] == inspect["finest_level"] and r.levels[0] == 0
    assert isinstance(r.levels, list) and all(level % 2 == 0 for level in r.levels)
    assert r.max_error == inspect["max_error_guaranteed_m"]
    assert "jacksboro" in repr(r)


@pytest.mark.parametrize("name", ["jacksboro", "rhine", "lidar"])
def test_whole_grid_equals_extract(repos, extract, name):
    r = cbdam.open(repos[name])
    want = extract(repos[name])
    got = r.read(out_dtype="float64")
    assert got.dtype == np.float64 and got.shape == r.shape
    same(got, want)
    # float32: the same heights rounded once.
    same(r.read(), want.astype(np.float32))
    if name == "rhine":
        assert np.isnan(got).mean() > 0.3, "the nodata test needs nodata"
        masked = r.read_masked(out_dtype="float64")
        assert np.array_equal(masked.mask, np.isnan(got))


@pytest.mark.parametrize("name", ["jacksboro", "rhine"])
def test_windows_equal_extract(repos, extract, name):
    r = cbdam.open(repos[name])
    whole = extract(repos[name])
    rows, cols = r.shape
    windows = [(0, 0, 1, 1), (5, 7, 64, 33), (cols - 40, rows - 30, 40, 30), (0, 0, cols, rows)]
    windows += [(cols // 3, rows // 4, cols // 2, 1), (1, 2, 1, rows - 2)]
    for col, row, width, height in windows:
        got = r.read(window=(col, row, width, height), out_dtype="float64")
        same(got, whole[row : row + height, col : col + width])


def test_rasterio_window_and_bbox_equal_extract(repos, extract):
    from rasterio.windows import Window

    r = cbdam.open(repos["jacksboro"])
    whole = extract(repos["jacksboro"])
    got = r.read(window=Window(10, 20, 30, 40), out_dtype="float64")
    same(got, whole[20:60, 10:40])
    left, bottom, right, top = r.bounds
    bbox = (left + 0.3 * (right - left), bottom + 0.2 * (top - bottom), right - 0.1 * (right - left), top)
    same(r.read(bbox=bbox, out_dtype="float64"), extract(repos["jacksboro"], bbox=bbox))


def test_levels_equal_extract(repos, extract):
    r = cbdam.open(repos["jacksboro"])
    for level in r.levels[:-1]:
        want = extract(repos["jacksboro"], level=level)
        same(r.read(level=level, out_dtype="float64"), want)
        # A window at a coarse level: the level's samples inside it.
        lvl, step, col_off, row_off, width, height = r.grid(level=level, window=(3, 5, 100, 80))
        assert (lvl, col_off % step, row_off % step) == (level, 0, 0)
        got = r.read(level=level, window=(3, 5, 100, 80), out_dtype="float64")
        assert got.shape == (height, width)
        same(got, want[row_off // step : row_off // step + height, col_off // step : col_off // step + width])


def test_bad_arguments_raise_input_errors(repos):
    r = cbdam.open(repos["jacksboro"])
    rows, cols = r.shape
    finest = r.levels[-1]
    with pytest.raises(cbdam.InputError, match="only even levels"):
        r.read(level=finest - 1)
    with pytest.raises(cbdam.InputError, match="only even levels"):
        r.read(level=finest + 2)
    with pytest.raises(cbdam.InputError, match="not inside"):
        r.read(window=(cols - 5, 0, 10, 10))
    with pytest.raises(cbdam.InputError, match="not inside"):
        r.read(window=(0, 0, 0, 5))
    with pytest.raises(cbdam.InputError, match="holds no sample"):
        r.read(bbox=(0, 0, 1, 1))
    with pytest.raises(cbdam.InputError, match="not both"):
        r.read(window=(0, 0, 1, 1), bbox=r.bounds)
    with pytest.raises(cbdam.InputError, match="out_dtype"):
        r.read(out_dtype="int16")
    with pytest.raises(cbdam.InputError, match="rasterio Window"):
        r.read(window="everything")
    assert issubclass(cbdam.InputError, cbdam.Error)


def test_missing_and_corrupt_files_raise(repos, tmp_path):
    with pytest.raises(cbdam.IoError, match="opening"):
        cbdam.open(tmp_path / "nothing.cbdam")
    junk = tmp_path / "junk.cbdam"
    junk.write_bytes(b"not a repository" * 100)
    with pytest.raises(cbdam.CorruptError, match="opening"):
        cbdam.open(junk)
    # A damaged record: the header opens, the read names the record's checksum.
    data = bytearray(repos["jacksboro"].read_bytes())
    r = cbdam.open(repos["jacksboro"])
    records = r.meta["sections"]["records"]
    at = records["offset"] + records["length"] // 2
    data[at] ^= 0x5A
    bad = tmp_path / "bad.cbdam"
    bad.write_bytes(bytes(data))
    with pytest.raises(cbdam.CorruptError, match="checksum mismatch"):
        cbdam.open(bad).read()
    # Damaged header: refused at open.
    data = bytearray(repos["jacksboro"].read_bytes())
    data[20] ^= 0xFF
    bad.write_bytes(bytes(data))
    with pytest.raises(cbdam.CorruptError):
        cbdam.open(bad)
    # Truncated file.
    bad.write_bytes(repos["jacksboro"].read_bytes()[:-10])
    with pytest.raises(cbdam.CorruptError):
        cbdam.open(bad)


def test_eight_threads_read_identical_arrays(repos):
    r = cbdam.open(repos["lidar"])
    want = r.read()
    got = [None] * 8
    barrier = threading.Barrier(8)

    def work(i):
        barrier.wait()
        got[i] = r.read() if i % 2 == 0 else r.read(window=(10, 10, 200, 100))

    threads = [threading.Thread(target=work, args=(i,)) for i in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for i, a in enumerate(got):
        same(a, want if i % 2 == 0 else want[10:110, 10:210])


def test_decoding_releases_the_gil(repos):
    """While a read decodes, another Python thread runs: with a long switch interval the
    counting thread gets the GIL during a read only if the read lets it go (on a loaded machine
    the thread may not be scheduled during every read, hence five)."""
    import sys

    r = cbdam.open(repos["rhine"])
    ticks = [0]
    done = threading.Event()

    def count():
        while not done.is_set():
            ticks[0] += 1

    interval = sys.getswitchinterval()
    sys.setswitchinterval(0.5)
    t = threading.Thread(target=count)
    t.start()
    try:
        during = []
        for _ in range(5):
            before = ticks[0]
            r.read()
            during.append(ticks[0] - before)
    finally:
        done.set()
        t.join()
        sys.setswitchinterval(interval)
    assert max(during) > 0, f"the counting thread did not run during any read: {during}"
