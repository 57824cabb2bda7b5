"""Remote reads: a loopback `cbdam serve` and a static server with only Range support give the
local file's arrays; a server that is gone raises, never hangs or crashes."""

import socket

import numpy as np
import pytest
from test_read import same

import cbdam


def remote_sources(repos, serve, range_server, name):
    _, url = serve(repos[name])
    return {
        "serve": cbdam.open(url),
        "range": cbdam.open(f"{range_server}/{repos[name].name}"),
    }


@pytest.mark.parametrize("name", ["jacksboro", "rhine"])
def test_remote_equals_local(repos, serve, range_server, name):
    local = cbdam.open(repos[name])
    rows, cols = local.shape
    for kind, r in remote_sources(repos, serve, range_server, name).items():
        assert r.meta == local.meta, kind
        assert (r.shape, r.levels, r.max_error, r.crs, r.bounds) == (
            local.shape,
            local.levels,
            local.max_error,
            local.crs,
            local.bounds,
        ), kind
        same(r.read(out_dtype="float64"), local.read(out_dtype="float64"))
        window = (cols // 4, rows // 5, cols // 3, rows // 2)
        same(r.read(window=window), local.read(window=window))
        level = local.levels[-2]
        same(r.read(level=level), local.read(level=level))
        xs = np.linspace(local.bounds[0], local.bounds[2], 7)[1:-1]
        ys = np.linspace(local.bounds[1], local.bounds[3], 7)[1:-1]
        same(r.sample(xs, ys), local.sample(xs, ys))


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_no_server_raises_network_error():
    with pytest.raises(cbdam.NetworkError):
        cbdam.open(f"http://127.0.0.1:{free_port()}/v1/repos/nothing", timeout=2)


def test_server_gone_mid_session_raises(repos, serve):
    proc, url = serve(repos["jacksboro"])
    r = cbdam.open(url, timeout=1)
    proc.kill()
    proc.wait()
    with pytest.raises(cbdam.NetworkError, match="no record arrived"):
        r.read()


def test_not_a_repository_url_raises(range_server):
    with pytest.raises(cbdam.Error):
        cbdam.open(f"{range_server}/missing.cbdam", timeout=2)
