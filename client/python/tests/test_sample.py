"""`sample`: the finest level's samples at grid points, and between them within the bound of
the same bilinear interpolation of the input."""

import numpy as np
import rasterio
from conftest import DATA

import cbdam


def input_bilinear(values, col, row):
    c0, r0 = np.floor(col).astype(int), np.floor(row).astype(int)
    c1, r1 = np.minimum(c0 + 1, values.shape[1] - 1), np.minimum(r0 + 1, values.shape[0] - 1)
    fx, fy = col - c0, row - r0
    return (
        values[r0, c0] * (1 - fx) * (1 - fy)
        + values[r0, c1] * fx * (1 - fy)
        + values[r1, c0] * (1 - fx) * fy
        + values[r1, c1] * fx * fy
    )


def test_sample_equals_read_at_grid_points_and_stays_within_the_bound(repos):
    r = cbdam.open(repos["lidar"])
    grid = r.read(out_dtype="float64")
    a, _, c, _, e, f = r.transform()
    rng = np.random.default_rng(7)
    rows, cols = r.shape
    # Grid points: the sample centres.
    ci, ri = rng.integers(0, cols, 200), rng.integers(0, rows, 200)
    got = r.sample(c + a * (ci + 0.5), f + e * (ri + 0.5))
    assert np.array_equal(got, grid[ri, ci])
    # Between them: within the bound of the input's own interpolation.
    col, row = rng.uniform(0, cols - 1, 2000), rng.uniform(0, rows - 1, 2000)
    got = r.sample(c + a * (col + 0.5), f + e * (row + 0.5))
    with rasterio.open(DATA / "lidar1m_mn.tif") as src:
        values = src.read(1).astype(np.float64)
    err = np.abs(got - input_bilinear(values, col, row))
    assert np.all(np.isfinite(got))
    assert err.max() <= r.max_error + 1e-9, (err.max(), r.max_error)
    # Outside the grid: NaN.
    out = r.sample(np.array([c - 10 * a, c + a]), np.array([f, f + 1e9 * e]))
    assert np.isnan(out).all()


def test_sample_beside_nodata_is_nan(repos):
    r = cbdam.open(repos["rhine"])
    grid = r.read(out_dtype="float64")
    a, _, c, _, e, f = r.transform()
    rows, cols = np.nonzero(np.isnan(grid))
    got = r.sample(c + a * (cols[:50] + 0.5), f + e * (rows[:50] + 0.5))
    assert np.isnan(got).all()
