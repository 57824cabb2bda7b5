"""``Reader.to_xarray``: a level of a repository as a georeferenced ``xarray.DataArray``.

The coordinates are the sample centres from ``Reader.transform``; the CRS and the transform are
written with rioxarray (``da.rio.crs``, ``da.rio.transform()``) when it is installed. With
``chunks=`` the array is a lazy Dask array whose chunks each decode only their own window (the
records reaching it), in parallel on Dask's threads.
"""


def _chunk_sizes(total, size):
    sizes = [size] * (total // size)
    if total % size:
        sizes.append(total % size)
    return sizes


def _chunks_of(chunks, shape):
    """``chunks`` (an int, a ``(rows, cols)`` pair or a dict with 'y'/'x') as row and column
    chunk sizes."""
    if isinstance(chunks, dict):
        rows, cols = chunks.get("y", shape[0]), chunks.get("x", shape[1])
    elif isinstance(chunks, int):
        rows = cols = chunks
    else:
        rows, cols = chunks
    rows = shape[0] if rows in (None, -1) else int(rows)
    cols = shape[1] if cols in (None, -1) else int(cols)
    if rows < 1 or cols < 1:
        raise ValueError(f"chunks={chunks!r}: chunk sizes must be positive")
    return _chunk_sizes(shape[0], rows), _chunk_sizes(shape[1], cols)


def _lazy(reader, level, step, col_off, row_off, shape, chunks, dtype):
    """A Dask array of ``shape`` whose chunks read their own windows of ``level``."""
    import dask
    import dask.array as da
    import numpy as np

    row_sizes, col_sizes = _chunks_of(chunks, shape)
    read = dask.delayed(reader.read, pure=True)
    blocks = []
    r0 = 0
    for rows in row_sizes:
        line = []
        c0 = 0
        for cols in col_sizes:
            # The chunk's samples of the level, as a window of the input grid's samples.
            window = (
                col_off + c0 * step,
                row_off + r0 * step,
                (cols - 1) * step + 1,
                (rows - 1) * step + 1,
            )
            part = read(level=level, window=window, out_dtype=dtype)
            line.append(da.from_delayed(part, shape=(rows, cols), dtype=np.dtype(dtype)))
            c0 += cols
        blocks.append(line)
        r0 += rows
    return da.block(blocks)


def to_xarray(self, level=None, chunks=None, out_dtype="float32"):
    """The whole grid of ``level`` (default: the finest) as an ``xarray.DataArray`` with dims
    ``('y', 'x')``, sample-centre coordinates, NaN where there is no data, and the CRS and
    transform rioxarray reads; lazy with ``chunks=`` (an int, ``(rows, cols)`` or
    ``{'y': rows, 'x': cols}``)."""
    import numpy as np
    import xarray as xr

    level, step, col_off, row_off, width, height = self.grid(level=level)
    a, b, c, d, e, f = self.transform(level=level)
    xs = c + a * (np.arange(width) + 0.5)
    ys = f + e * (np.arange(height) + 0.5)
    if chunks is None:
        data = self.read(level=level, out_dtype=out_dtype)
    else:
        data = _lazy(self, level, step, col_off, row_off, (height, width), chunks, out_dtype)
    da = xr.DataArray(
        data,
        dims=("y", "x"),
        coords={"y": ys, "x": xs},
        name="elevation",
        attrs={
            "units": "m",
            "level": level,
            "max_error_m": self.max_error,
        },
    )
    crs = self.crs
    try:
        import rioxarray  # noqa: F401  (registers the .rio accessor)
    except ImportError:
        da.attrs["crs"] = crs
        da.attrs["transform"] = (a, b, c, d, e, f)
        return da
    from affine import Affine

    if crs is not None:
        da = da.rio.write_crs(crs)
    da = da.rio.write_transform(Affine(a, b, c, d, e, f))
    return da.rio.write_nodata(np.nan, encoded=False)
