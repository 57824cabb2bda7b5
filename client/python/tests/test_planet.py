"""Planets: `sample_geo` within the bound of the input DEM at its samples (across cube edges and
corners too), equal to the CLI's own planet sampling (`cbdam tiles` terrarium PNGs), `read_geo`
on its latitude/longitude grid, remote equal to local, and bad arguments refused by name."""

import json
import math
import warnings

import numpy as np
import pytest
import rasterio
from conftest import DATA, run
from rasterio.transform import from_origin

import cbdam


def relief(lon, lat):
    """The smooth relief of the synthetic global DEM, metres, from degrees (polynomials in the
    Earth-centred x, y, z: smooth at the poles too)."""
    lo, la = np.radians(lon), np.radians(lat)
    c = np.cos(la)
    return 2000.0 * c**2 * np.sin(2 * lo) + 700.0 * np.sin(3 * la) + 1500.0 * c**5 * np.cos(5 * lo)


@pytest.fixture(scope="module")
def planet(cbdam_bin, tmp_path_factory):
    """A 1° global DEM of `relief` (GeoTIFF, EPSG:4326) and the planet the CLI builds of it
    (N = 17, K = 3: 0.70° lattice spacing, finer than the input, so resampled bilinearly)."""
    d = tmp_path_factory.mktemp("planet")
    lon = -179.5 + np.arange(360)
    lat = 89.5 - np.arange(180)
    values = relief(lon[None, :], lat[:, None]).astype(np.float32)
    dem = d / "relief.tif"
    profile = dict(driver="GTiff", width=360, height=180, count=1, dtype="float32",
                   crs="EPSG:4326", transform=from_origin(-180.0, 90.0, 1.0, 1.0))
    with rasterio.open(dem, "w", **profile) as dst:
        dst.write(values, 1)
    out = d / "relief.cbdam"
    run([cbdam_bin, "build", str(dem), "--planet", "--diamond-size", "17", "--planet-level", "3",
         "--max-error", "1", "-o", str(out), "--quiet"])
    return {"dem": dem, "repo": out, "lon": lon, "lat": lat, "values": values.astype(np.float64)}


def cube_direction(lon, lat):
    """Unit-free ECEF direction of a geodetic point on WGS84 (for telling faces apart)."""
    e2 = 0.00669437999014
    la, lo = np.radians(lat), np.radians(lon)
    n = 1.0 / np.sqrt(1 - e2 * np.sin(la) ** 2)
    return np.stack([n * np.cos(la) * np.cos(lo), n * np.cos(la) * np.sin(lo),
                     n * (1 - e2) * np.sin(la)])


def test_sample_geo_is_within_the_bound_at_every_input_sample(planet):
    r = cbdam.open(planet["repo"])
    assert r.domain == "cube-sphere"
    rmax, rrms = r.resampling_error
    assert 0 < rrms <= rmax < 5, r.resampling_error
    lon, lat = np.meshgrid(planet["lon"], planet["lat"])
    lon, lat = lon.ravel(), lat.ravel()
    got = r.sample_geo(lon, lat)
    err = np.abs(got - planet["values"].ravel())
    bound = r.max_error + rmax
    assert np.isfinite(got).all()
    assert err.max() <= bound + 1e-6, (err.max(), bound)
    # Misplaced by half a lattice cell (0.35°), the same samples break the bound.
    shifted = np.abs(r.sample_geo(lon + 0.35, lat) - planet["values"].ravel())
    assert shifted.max() > 2 * bound, shifted.max()
    # The samples next to cube edges and corners, on every side, are among those held to it.
    d = np.sort(np.abs(cube_direction(lon, lat)), axis=0)
    near_edge = d[1] > 0.97 * d[2]
    near_corner = d[0] > 0.93 * d[2]
    assert near_edge.sum() > 500 and near_corner.sum() >= 8, (near_edge.sum(), near_corner.sum())
    assert err[near_edge].max() <= bound + 1e-6 and err[near_corner].max() <= bound + 1e-6


def test_sample_geo_is_continuous_across_cube_edges_and_corners(planet):
    r = cbdam.open(planet["repo"])
    h = 1e-7
    # The edge of faces 0 and 1 (45° E on the equator), of faces 0 and 4 (45° N at 0°), and
    # the corner of faces 0, 1, 4 (where the three normals' components are equal).
    corner_lat = math.degrees(math.atan(1 / math.sqrt(2) / (1 - 0.00669437999014)))
    for lon, lat in [(45.0, 0.0), (45.0, 20.0), (0.0, 45.1), (-135.0, -30.0), (45.0, corner_lat),
                     (-135.0, -corner_lat)]:
        around = np.array([(lon + dx, lat + dy) for dx in (-h, 0, h) for dy in (-h, 0, h)])
        got = r.sample_geo(around[:, 0], around[:, 1])
        assert np.isfinite(got).all()
        # 1e-7° is about 1 cm: any jump across the edge shows.
        assert np.ptp(got) < 1e-3, (lon, lat, got)


def terrarium_heights(png):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with rasterio.open(png) as src:
            rgba = src.read().astype(np.float64)
    h = rgba[0] * 256 + rgba[1] + rgba[2] / 256 - 32768
    if len(rgba) == 4:  # an alpha band only where some pixel has no data
        h[rgba[3] == 0] = np.nan
    return h


def test_sample_geo_equals_the_cli_terrarium_tiles(planet, cbdam_bin, tmp_path):
    # The planet's deepest zoom (0: one 512-pixel tile, pixels about the lattice's spacing) is
    # made from the finest level, bilinear on a face, encoded to 1/256 m (`tiles.json` says so).
    out = tmp_path / "tiles"
    run([cbdam_bin, "tiles", str(planet["repo"]), "--format", "terrarium", "-o", str(out),
         "--quiet"])
    meta = json.loads((out / "tiles.json").read_text())
    z, step = meta["maxzoom"], meta["cbdam"]["encoding_step_m"]
    r = cbdam.open(planet["repo"])
    n, compared = 1 << z, 0
    for x in range(n):
        for y in range(n):
            want = terrarium_heights(out / str(z) / str(x) / f"{y}.png")
            size = want.shape[0]
            centre = (np.arange(size) + 0.5) / size
            lon = -180 + 360 * (x + centre) / n
            lat = np.degrees(np.arctan(np.sinh(np.pi * (1 - 2 * (y + centre) / n))))
            lo, la = np.meshgrid(lon, lat)
            got = r.sample_geo(lo.ravel(), la.ravel()).reshape(want.shape)
            assert np.array_equal(np.isnan(got), np.isnan(want))
            diff = np.abs(got - want)[np.isfinite(want)]
            assert diff.max() <= step / 2 + 1e-9, (x, y, diff.max())
            compared += diff.size
    assert compared >= 256 * 256, compared


def test_read_geo_is_sample_geo_on_its_grid(planet):
    r = cbdam.open(planet["repo"])
    finest = r.levels[-1]
    bbox, res = (30.0, 20.0, 60.0, 50.0), 0.25  # over faces 0, 1 and 4 and their corner
    a = r.read_geo(bbox=bbox, resolution=res, level=finest, out_dtype="float64")
    assert a.shape == (120, 120) and a.dtype == np.float64
    lon = 30.0 + res * (np.arange(120) + 0.5)
    lat = 50.0 - res * (np.arange(120) + 0.5)
    lo, la = np.meshgrid(lon, lat)
    assert np.array_equal(a, r.sample_geo(lo.ravel(), la.ravel()).reshape(a.shape))
    # float32 is each float64 rounded once; the resolution picks the level unless given.
    assert np.array_equal(r.read_geo(bbox=bbox, resolution=res, level=finest), a.astype(np.float32))
    coarse = r.read_geo(bbox=(-180, -90, 180, 90), resolution=10.0, out_dtype="float64")
    assert coarse.shape == (18, 36) and np.isfinite(coarse).all()
    lo, la = np.meshgrid(-175.0 + 10 * np.arange(36), 85.0 - 10 * np.arange(18))
    assert np.abs(coarse - relief(lo, la)).max() < 600  # level 0: a 45° lattice, still the relief
    # Across the antimeridian: longitudes past 180 are the same places.
    wrap = r.read_geo(bbox=(170.0, -10.0, 190.0, 10.0), resolution=0.5, level=finest)
    same = r.read_geo(bbox=(-190.0, -10.0, -170.0, 10.0), resolution=0.5, level=finest)
    assert np.allclose(wrap, same, atol=1e-3)


def test_planet_remote_reads_equal_local(planet, repos, serve, range_server):
    import shutil

    local = cbdam.open(planet["repo"])
    # The static server serves the folder of the sample repositories.
    copy = repos["jacksboro"].parent / "relief_planet.cbdam"
    shutil.copy(planet["repo"], copy)
    _, url = serve(copy)
    bbox = (40.0, 30.0, 50.0, 40.0)  # over the corner of faces 0, 1 and 4
    want = local.read_geo(bbox=bbox, resolution=0.5, out_dtype="float64")
    pts = np.array([0.0, 45.0, -120.0, 10.0]), np.array([0.0, 35.3, -60.0, 89.0])
    for r in [cbdam.open(url), cbdam.open(f"{range_server}/{copy.name}")]:
        assert r.domain == "cube-sphere" and r.resampling_error == local.resampling_error
        assert np.array_equal(r.read_geo(bbox=bbox, resolution=0.5, out_dtype="float64"), want)
        assert np.array_equal(r.sample_geo(*pts), local.sample_geo(*pts))


def test_bad_geo_arguments_are_refused_by_name(planet, repos):
    r = cbdam.open(planet["repo"])
    bad = [
        (dict(bbox=(0, 0, 1), resolution=1), "bbox"),
        (dict(bbox=(0, 0, 1, 1), resolution=0), "resolution"),
        (dict(bbox=(0, 0, 1, 1), resolution=float("nan")), "resolution"),
        (dict(bbox=(0, 0, 1, 1), resolution=0.3), "whole number"),
        (dict(bbox=(0, -91, 1, 1), resolution=1), "globe"),
        (dict(bbox=(-180, 0, 181, 1), resolution=1), "globe"),
        (dict(bbox=(1, 0, 0, 1), resolution=1), "west < east"),
        (dict(bbox=(0, 0, float("inf"), 1), resolution=1), "bbox"),
        (dict(bbox=(-180, -90, 180, 90), resolution=1e-4), "more than"),
        (dict(bbox=(0, 0, 1, 1), resolution=1, level=1), "level=1"),
        (dict(bbox=(0, 0, 1, 1), resolution=1, out_dtype="int8"), "out_dtype"),
    ]
    for kwargs, name in bad:
        with pytest.raises(cbdam.InputError, match=name):
            r.read_geo(**kwargs)
    with pytest.raises(cbdam.InputError, match="lats"):
        r.sample_geo(np.array([0.0]), np.array([91.0]))
    with pytest.raises(cbdam.InputError, match="differ in length"):
        r.sample_geo(np.array([0.0, 1.0]), np.array([1.0]))
    assert np.isnan(r.sample_geo(np.array([np.nan]), np.array([0.0]))).all()
    for call in (r.read, lambda: r.sample(np.zeros(1), np.zeros(1)), r.to_xarray):
        with pytest.raises(cbdam.UnsupportedError, match="read_geo"):
            call()
    plane = cbdam.open(repos["jacksboro"])
    with pytest.raises(cbdam.UnsupportedError, match="planar"):
        plane.sample_geo(np.zeros(1), np.zeros(1))
    with pytest.raises(cbdam.UnsupportedError, match="planar"):
        plane.read_geo(bbox=(0, 0, 1, 1), resolution=1)
    assert plane.resampling_error is None


def test_a_planet_of_a_real_dem_holds_the_bound_at_its_samples(cbdam_bin, tmp_path):
    # ETOPO5 on a coarse lattice (K = 2, 1.4°): resampled by area means, so the resampling error
    # is large, but the stated bound holds at each of its 9.3 M samples' every 7th row and column.
    out = tmp_path / "earth.cbdam"
    run([cbdam_bin, "build", str(DATA / "etopo5_global.tif"), "--planet", "--planet-level", "2",
         "--max-error", "16", "-o", str(out), "--quiet"])
    r = cbdam.open(out)
    with rasterio.open(DATA / "etopo5_global.tif") as src:
        values = src.read(1).astype(np.float64)[::7, ::7]
        t = src.transform
    rows, cols = np.mgrid[0:src.height:7, 0:src.width:7]
    lon, lat = t.c + t.a * (cols + 0.5), t.f + t.e * (rows + 0.5)
    got = r.sample_geo(lon.ravel(), lat.ravel())
    err = np.abs(got - values.ravel())
    assert np.isfinite(got).all()
    assert err.max() <= r.max_error + r.resampling_error[0] + 1e-6, err.max()


def test_verify_compares_a_planet_with_its_input(planet, tmp_path):
    report = cbdam.verify(planet["repo"], against=[planet["dem"]])
    r = cbdam.open(planet["repo"])
    assert report["bound"] == r.max_error and report["max_error"] <= report["level_bound"]
    [one] = report["inputs"]
    assert one["path"].endswith("relief.tif") and one["samples"] == 360 * 180
    assert one["compared"] > 0.98 * one["samples"], one
    assert one["resampling_max"] == pytest.approx(r.resampling_error[0], rel=1e-6)
    assert 0 < one["surface_max"] <= one["allowed"] == one["resampling_max"] + r.max_error
    # Against a DEM 50 m higher east of 45° E (a cube edge on the equator) the planet fails:
    # its levels are far from the lattice resampled from it.
    with rasterio.open(planet["dem"]) as src:
        values, profile = src.read(1), src.profile
    values[:, 225:] += 50.0  # east of 45° E
    other = tmp_path / "other.tif"
    with rasterio.open(other, "w", **profile) as dst:
        dst.write(values, 1)
    with pytest.raises(cbdam.Error, match="exceeds the bound"):
        cbdam.verify(planet["repo"], against=[other])
