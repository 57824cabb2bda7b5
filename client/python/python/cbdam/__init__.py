"""cbdam: C-BDAM terrain repositories as NumPy and xarray arrays, local or remote, and builds.

``cbdam.open(path_or_url)`` gives a :class:`Reader`; ``Reader.read`` decodes the whole grid or
a window at the finest or a coarser level (in parallel, without the GIL), ``read_masked`` the
same as a masked array, ``sample`` heights at points, ``to_xarray`` a georeferenced
``xarray.DataArray`` (lazy Dask chunks with ``chunks=``). ``cbdam.build`` and ``cbdam.verify``
are the CLI's ``build`` and ``verify``. The guide is docs/PYTHON.md of the repository.
"""

from ._cbdam import (
    CorruptError,
    Error,
    InputError,
    IoError,
    NetworkError,
    Reader,
    UnsupportedError,
    build,
    open,
    verify,
)
from ._xarray import to_xarray

__all__ = [
    "CorruptError",
    "Error",
    "InputError",
    "IoError",
    "NetworkError",
    "Reader",
    "UnsupportedError",
    "build",
    "open",
    "read_masked",
    "to_xarray",
    "verify",
]


def read_masked(self, level=None, window=None, bbox=None, out_dtype="float32"):
    """``read`` as a ``numpy.ma.MaskedArray``: masked where the repository has no data."""
    import numpy as np

    a = self.read(level=level, window=window, bbox=bbox, out_dtype=out_dtype)
    return np.ma.masked_invalid(a, copy=False)


Reader.read_masked = read_masked
Reader.to_xarray = to_xarray
