"""Fixtures of the Python package's tests (run by scripts/python-test.sh): the cbdam binary,
repositories built from the sample DEMs, `cbdam extract` output to compare with, and loopback
servers (`cbdam serve`, and a static server with only Range support)."""

import http.server
import json
import os
import re
import socketserver
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[3]
DATA = ROOT / "data"


@pytest.fixture(scope="session")
def cbdam_bin():
    """The CLI these tests compare with: $CBDAM_BIN, else target/debug/cbdam."""
    path = Path(os.environ.get("CBDAM_BIN", ROOT / "target" / "debug" / "cbdam"))
    assert path.is_file(), f"no cbdam binary at {path} (cargo build --bin cbdam, or set CBDAM_BIN)"
    return str(path)


def run(cmd):
    p = subprocess.run(cmd, capture_output=True, text=True)
    assert p.returncode == 0, f"{cmd}: {p.stderr}"
    return p


def cli_build(cbdam_bin, dem, out, max_error="1", *extra):
    run([cbdam_bin, "build", str(dem), "-o", str(out), "--max-error", max_error, "--quiet", *extra])
    return out


@pytest.fixture(scope="session")
def repos(cbdam_bin, tmp_path_factory):
    """Repositories of the sample DEMs, built by the CLI: 'jacksboro' (georeferenced, 403 ×
    344), 'rhine' (48 % nodata), 'lidar' (float32, 1 m) — each within 1 m (lidar 0.1 m)."""
    d = tmp_path_factory.mktemp("repos")
    return {
        "jacksboro": cli_build(cbdam_bin, DATA / "jacksboro_mpl.tif", d / "jacksboro.cbdam"),
        "rhine": cli_build(cbdam_bin, DATA / "rhine_nodata.tif", d / "rhine.cbdam"),
        "lidar": cli_build(cbdam_bin, DATA / "lidar1m_mn.tif", d / "lidar.cbdam", "0.1"),
    }


@pytest.fixture(scope="session")
def extract(cbdam_bin, tmp_path_factory):
    """`cbdam extract --format raw --float64` of a repository (optionally a level and a bbox) as
    a float64 array, its nodata value as NaN."""
    d = tmp_path_factory.mktemp("extract")
    count = [0]

    def extract(repo, level=None, bbox=None):
        count[0] += 1
        out = d / f"x{count[0]}.f64"
        cmd = [cbdam_bin, "extract", str(repo), "-o", str(out), "--format", "raw", "--float64"]
        cmd += ["--quiet"]
        if level is not None:
            cmd += ["--level", str(level)]
        if bbox is not None:
            cmd += ["--bbox", ",".join(repr(float(v)) for v in bbox)]
        run(cmd)
        meta = json.loads(out.with_suffix(".json").read_text())
        a = np.fromfile(out, dtype="<f8").reshape(meta["height"], meta["width"])
        if meta["nodata"] is not None:
            a[a == meta["nodata"]] = np.nan
        return a

    return extract


class RangeHandler(http.server.SimpleHTTPRequestHandler):
    """Static files answering only single-range `Range: bytes=a-b` GETs with 206 (python's own
    server has no Range support): what a `.cbdam` on a plain static server looks like."""

    # Every request answered, `(path, first byte, last byte)` (None, None without a Range): what
    # the cache tests count.
    requests = []

    def log_message(self, *args):
        pass

    def send_head(self):
        header = self.headers.get("Range")
        if header is None:
            RangeHandler.requests.append((self.path, None, None))
        path = self.translate_path(self.path)
        if header is None or not os.path.isfile(path):
            return super().send_head()
        m = re.fullmatch(r"bytes=(\d+)-(\d*)", header.strip())
        size = os.path.getsize(path)
        if not m or int(m.group(1)) >= size:
            self.send_response(416)
            self.send_header("Content-Range", f"bytes */{size}")
            self.send_header("Content-Length", "0")
            self.end_headers()
            return None
        start = int(m.group(1))
        end = min(int(m.group(2)) if m.group(2) else size - 1, size - 1)
        RangeHandler.requests.append((self.path, start, end))
        with open(path, "rb") as f:
            f.seek(start)
            data = f.read(end - start + 1)
        self.send_response(206)
        self.send_header("Content-Type", "application/octet-stream")
        self.send_header("Content-Range", f"bytes {start}-{end}/{size}")
        self.send_header("Content-Length", str(len(data)))
        self.end_headers()
        import io

        return io.BytesIO(data)


class ThreadingServer(socketserver.ThreadingMixIn, http.server.HTTPServer):
    daemon_threads = True


@pytest.fixture(scope="session")
def range_server(repos):
    """A loopback static server of the repositories' folder; yields its base URL."""
    root = str(Path(repos["jacksboro"]).parent)
    server = ThreadingServer(("127.0.0.1", 0), lambda *a, **k: RangeHandler(*a, directory=root, **k))
    threading.Thread(target=server.serve_forever, daemon=True).start()
    yield f"http://127.0.0.1:{server.server_address[1]}"
    server.shutdown()


def start_serve(cbdam_bin, repository):
    """`cbdam serve REPOSITORY` on a free loopback port: the process and its base URL."""
    proc = subprocess.Popen(
        [cbdam_bin, "serve", str(repository), "--addr", "127.0.0.1:0"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.time() + 30
    while time.time() < deadline:
        line = proc.stderr.readline()
        m = re.search(r"listening on (http://127\.0\.0\.1:\d+)", line)
        if m:
            threading.Thread(target=proc.stderr.read, daemon=True).start()
            return proc, m.group(1)
        if not line and proc.poll() is not None:
            break
    proc.kill()
    raise RuntimeError("cbdam serve did not start")


@pytest.fixture
def serve(cbdam_bin):
    """Starts `cbdam serve` on a repository; every server is stopped after the test."""
    procs = []

    def serve(repository):
        proc, url = start_serve(cbdam_bin, repository)
        procs.append(proc)
        return proc, url

    yield serve
    for p in procs:
        p.kill()
        p.wait()
