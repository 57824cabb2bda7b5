"""`to_xarray`: a DataArray that rioxarray writes to a GeoTIFF georeferenced like the input,
eager or lazily chunked with Dask (each chunk its own window)."""

import numpy as np
import rasterio
import rioxarray  # noqa: F401
from conftest import DATA
from test_read import same

import cbdam


def test_to_raster_keeps_the_inputs_georeferencing(repos, tmp_path):
    r = cbdam.open(repos["jacksboro"])
    da = r.to_xarray()
    assert da.dims == ("y", "x") and da.shape == r.shape
    out = tmp_path / "out.tif"
    da.rio.to_raster(out)
    with rasterio.open(DATA / "jacksboro_mpl.tif") as src, rasterio.open(out) as got:
        assert got.crs == src.crs
        assert got.transform.almost_equals(src.transform, precision=1e-9)
        assert (got.width, got.height) == (src.width, src.height)
        same(got.read(1).astype(np.float64), r.read().astype(np.float64))
        # Within the bound of the input everywhere.
        assert np.nanmax(np.abs(got.read(1) - src.read(1).astype(np.float64))) <= r.max_error + 1e-3


def test_coarse_level_transform(repos):
    r = cbdam.open(repos["jacksboro"])
    level = r.levels[-3]
    da = r.to_xarray(level=level)
    same(da.values, r.read(level=level))
    t = da.rio.transform()
    a, _, c, _, e, f = r.transform(level=level)
    assert (t.a, t.c, t.e, t.f) == (a, c, e, f)
    assert t.a == 4 * r.transform()[0]


def test_lazy_chunks_equal_the_eager_array(repos):
    import dask.array

    r = cbdam.open(repos["rhine"])
    lazy = r.to_xarray(chunks=(100, 128))
    assert isinstance(lazy.data, dask.array.Array)
    assert lazy.data.chunks[0][0] == 100 and lazy.data.chunks[1][0] == 128
    same(lazy.compute().values, r.read())
    level = r.levels[-2]
    same(r.to_xarray(level=level, chunks={"y": 64, "x": 50}).values, r.read(level=level))
