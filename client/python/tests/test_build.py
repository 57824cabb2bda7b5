"""`cbdam.build` writes the CLI's bytes and reports progress; `cbdam.verify` checks like the
CLI; bad input raises with the CLI's message."""

import pytest
from conftest import DATA, cli_build

import cbdam


def test_build_from_python_equals_the_cli(cbdam_bin, tmp_path):
    dem = DATA / "jacksboro_mpl.tif"
    want = cli_build(cbdam_bin, dem, tmp_path / "cli.cbdam", "0.5", "--coder", "elias-gamma")
    events = []
    summary = cbdam.build(
        [dem], tmp_path / "py.cbdam", 0.5, coder="elias-gamma", progress=lambda *e: events.append(e)
    )
    assert (tmp_path / "py.cbdam").read_bytes() == want.read_bytes()
    assert summary["kind"] == "elevation" and summary["bytes"] == want.stat().st_size
    stages = [e[0] for e in events]
    assert "prepare" in stages and "encode" in stages and stages[-1] == "write"
    assert all(done <= total for _, done, total in events)
    # Variations of the options reach the builder.
    cbdam.build([str(dem)], tmp_path / "a.cbdam", 0.5, alpha=0.5, extra_levels=0, diamond_size=9)
    assert cbdam.open(tmp_path / "a.cbdam").meta["alpha"] == "0.5"
    assert cbdam.open(tmp_path / "a.cbdam").meta["diamond_size"] == 9


def test_build_errors(tmp_path):
    with pytest.raises(cbdam.Error, match="missing.tif"):
        cbdam.build([tmp_path / "missing.tif"], tmp_path / "x.cbdam", 1.0)
    with pytest.raises(cbdam.InputError, match="coder"):
        cbdam.build([DATA / "jacksboro_mpl.tif"], tmp_path / "x.cbdam", 1.0, coder="zip")
    with pytest.raises(cbdam.InputError, match="extra_levels"):
        cbdam.build([DATA / "jacksboro_mpl.tif"], tmp_path / "x.cbdam", 1.0, extra_levels=9)
    with pytest.raises(ZeroDivisionError):
        cbdam.build(
            [DATA / "jacksboro_mpl.tif"], tmp_path / "x.cbdam", 1.0, progress=lambda *e: 1 / 0
        )


def test_verify(repos, tmp_path):
    assert cbdam.verify(repos["jacksboro"]) == {"checksums": True}
    report = cbdam.verify(repos["rhine"], against=[DATA / "rhine_nodata.tif"])
    assert 0 < report["max_error"] <= report["bound"] == cbdam.open(repos["rhine"]).max_error
    assert all(err <= report["level_bound"] for _, _, err in report["levels"])
    assert len(report["levels"]) == len(cbdam.open(repos["rhine"]).meta["levels"])
    data = bytearray(repos["jacksboro"].read_bytes())
    data[-3] ^= 0x01
    bad = tmp_path / "bad.cbdam"
    bad.write_bytes(bytes(data))
    with pytest.raises(cbdam.CorruptError, match="checking"):
        cbdam.verify(bad)
    with pytest.raises(cbdam.InputError):
        cbdam.verify(repos["jacksboro"], against=[DATA / "lidar1m_mn.tif"])


def test_a_planet_opens_and_read_says_it_is_unsupported(tmp_path):
    # A coarse lattice (K = 2) of ETOPO5: built in a moment.
    out = tmp_path / "earth.cbdam"
    cbdam.build([DATA / "etopo5_global.tif"], out, 16.0, planet=True, planet_level=2)
    r = cbdam.open(out)
    assert r.domain == "cube-sphere" and r.meta["faces"] == 6
    with pytest.raises(cbdam.UnsupportedError, match="planet"):
        r.read()
    with pytest.raises(cbdam.InputError, match="planet_level"):
        cbdam.build([DATA / "etopo5_global.tif"], out, 16.0, planet_level=2)
