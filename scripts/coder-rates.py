#!/usr/bin/env python3
"""Bits per sample of two entropy coders on every bundled DEM, beside JPEG-LS and SZ3.

Builds each DEM in data/ at each max error with `cbdam build --coder C` for both coders and
prints a Markdown table: the bits/sample `cbdam build` reports for each, their ratio, and the
peers' figures at the same bound from ../shared/data/PEERS.md where it has that bound (JPEG-LS
NEAR on the lattice and SZ3 3.x via pysz; `–` where it has none).

    python3 scripts/coder-rates.py [--cbdam target/release/cbdam] [--eps 0.5,1,2,16]
        [--coders adaptive-tokens,fast-rice] [--peers ../shared/data/PEERS.md]
"""

import argparse
import pathlib
import re
import subprocess
import sys
import tempfile

DEMS = [
    "etopo5_global.tif",
    "srtm3_demcompare.tif",
    "fuji_terrainrgb.tif",
    "lidar1m_mn.tif",
    "jacksboro_mpl.tif",
    "rhine_nodata.tif",
]
PEER_ROWS = {"JPEG-LS": "JPEG-LS NEAR (CharLS, lattice)", "SZ3": "SZ3 3.x (pysz, interp+lorenzo)"}


def peer_figures(path):
    """{dem stem: {peer: {eps: bps}}} from the 'Bits per sample' tables of PEERS.md."""
    figures, dem, columns = {}, None, None
    if not path.exists():
        return figures
    for line in path.read_text().splitlines():
        heading = re.match(r"## (\S+) ", line)
        if heading:
            dem, columns = heading.group(1), None
            figures[dem] = {}
        elif line.startswith("| codec | t="):
            columns = [float(m) for m in re.findall(r"t=([0-9.]+) m", line)]
        elif line.startswith("| codec") or line.startswith("Throughput"):
            columns = None if line.startswith("Throughput") else columns
        elif columns and dem and line.startswith("| "):
            cells = [c.strip() for c in line.strip("|").split("|")]
            for peer, row in PEER_ROWS.items():
                if cells[0] == row:
                    values = [float(c.split()[0]) for c in cells[1:]]
                    figures[dem][peer] = dict(zip(columns, values))
    return figures


def bits_per_sample(cbdam, dem, eps, coder, out):
    """The bits/sample `cbdam build` reports for one build."""
    run = subprocess.run(
        [cbdam, "build", str(dem), "-o", out, "--max-error", str(eps), "--coder", coder],
        capture_output=True,
        text=True,
    )
    if run.returncode != 0:
        sys.exit(f"cbdam build {dem} --max-error {eps} --coder {coder} failed:\n{run.stderr}")
    found = re.search(r"([0-9.]+) bits/sample", run.stdout + run.stderr)
    if not found:
        sys.exit(f"no bits/sample in the output of cbdam build {dem}")
    return float(found.group(1))


def main():
    root = pathlib.Path(__file__).resolve().parent.parent
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cbdam", default=str(root / "target/release/cbdam"))
    p.add_argument("--eps", default="0.5,1,2,16")
    p.add_argument("--coders", default="adaptive-tokens,fast-rice")
    p.add_argument("--data", default=str(root / "data"))
    p.add_argument("--peers", default=str(root / "../shared/data/PEERS.md"))
    a = p.parse_args()
    eps_list = [float(e) for e in a.eps.split(",")]
    coders = a.coders.split(",")
    if len(coders) != 2:
        sys.exit("--coders takes two coders: the second is given as a ratio of the first")
    peers = peer_figures(pathlib.Path(a.peers))
    print(f"| DEM | ε (m) | {coders[0]} | {coders[1]} | ratio | JPEG-LS | SZ3 |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    with tempfile.TemporaryDirectory() as tmp:
        out = str(pathlib.Path(tmp) / "r.cbdam")
        for dem in DEMS:
            path = pathlib.Path(a.data) / dem
            stem = dem.removesuffix(".tif")
            for eps in eps_list:
                rates = [bits_per_sample(a.cbdam, path, eps, c, out) for c in coders]
                peer = [peers.get(stem, {}).get(name, {}).get(eps) for name in PEER_ROWS]
                cells = ["–" if v is None else f"{v:.3f}" for v in peer]
                print(
                    f"| {stem} | {eps:g} | {rates[0]:.3f} | {rates[1]:.3f} | "
                    f"{rates[1] / rates[0]:.3f} | {cells[0]} | {cells[1]} |",
                    flush=True,
                )


if __name__ == "__main__":
    main()
