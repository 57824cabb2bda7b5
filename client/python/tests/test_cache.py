"""The remote reader's cache: a record fetched once is not fetched again by a later read that
needs it (requests counted at a loopback Range server), the cache stays within its budget, and
`cache_bytes=0` fetches every read afresh."""

import numpy as np
import pytest
from conftest import RangeHandler
from test_read import same

import cbdam


def fetched(during):
    """(requests, bytes) the Range server answered while `during()` ran, and its result."""
    log = RangeHandler.requests
    n = len(log)
    result = during()
    new = log[n:]
    return len(new), sum(e - s + 1 for _, s, e in new if s is not None), result


def test_a_record_fetched_once_is_not_fetched_again(repos, range_server):
    url = f"{range_server}/{repos['jacksboro'].name}"
    local = cbdam.open(repos["jacksboro"])
    r, fresh = cbdam.open(url), cbdam.open(url, cache_bytes=0)
    first, second = (100, 100, 64, 64), (150, 100, 150, 64)
    n, size, a = fetched(lambda: r.read(window=first, out_dtype="float64"))
    assert n > 0 and size > 0
    same(a, local.read(window=first, out_dtype="float64"))
    # The same window again: nothing fetched, the same array.
    n, size, b = fetched(lambda: r.read(window=first, out_dtype="float64"))
    assert (n, size) == (0, 0)
    same(a, b)
    # An overlapping window: fewer bytes than a reader without a cache fetches for it.
    n_fresh, size_fresh, want = fetched(lambda: fresh.read(window=second, out_dtype="float64"))
    n, size, got = fetched(lambda: r.read(window=second, out_dtype="float64"))
    assert 0 < size < size_fresh and n <= n_fresh, (size, size_fresh, n, n_fresh)
    same(got, want)
    same(got, local.read(window=second, out_dtype="float64"))
    info = r.cache_info()
    assert info["hits"] > 0 and 0 < info["bytes"] <= info["limit"] == 64 << 20, info
    # Without a cache every read fetches again, and nothing is held.
    assert fetched(lambda: fresh.read(window=second))[:2] == (n_fresh, size_fresh)
    assert fresh.cache_info()["records"] == 0 and local.cache_info() is None


def test_the_cache_stays_within_its_budget(repos, range_server):
    url = f"{range_server}/{repos['rhine'].name}"
    local = cbdam.open(repos["rhine"])
    budget = 20_000
    r = cbdam.open(url, cache_bytes=budget)
    rows, cols = r.shape
    for k in range(6):
        window = (k * (cols // 8), k * (rows // 8), cols // 4, rows // 4)
        same(r.read(window=window), local.read(window=window))
        info = r.cache_info()
        assert 0 < info["bytes"] <= budget, info
    # The whole grid needs more than the budget: read again, part of it is fetched again.
    whole = r.read()
    n, size, again = fetched(r.read)
    assert n > 0 and size > budget // 2, (n, size)
    same(again, whole)
    same(whole, local.read())
    assert r.cache_info()["bytes"] <= budget


def test_the_cache_serves_cbdam_serve_reads_too(repos, serve):
    _, url = serve(repos["jacksboro"])
    r = cbdam.open(url)
    a = r.read(window=(0, 0, 100, 80))
    before = r.cache_info()
    assert before["misses"] > 0
    b = r.read(window=(0, 0, 100, 80))
    after = r.cache_info()
    assert after["misses"] == before["misses"] and after["hits"] > before["hits"]
    assert np.array_equal(a, b, equal_nan=True)


def test_a_negative_budget_is_refused():
    with pytest.raises(cbdam.InputError, match="cache_bytes"):
        cbdam.open("http://127.0.0.1:9/x.cbdam", cache_bytes=-1)
