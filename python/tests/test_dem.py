"""volterra.dem and volterra.compare against the command line: each product computed in
Python equals the GeoTIFF `volterra dem` writes (read by tifffile, its NoData as NaN), the
contours equal its GeoJSON, and compare() equals `volterra compare --json`; a plane's slope
and aspect against their closed form. Run by tests/python.sh with pytest."""

import json

import numpy as np
import pytest

import volterra
import volterra.dem
from _support import cli, shared


@pytest.fixture(scope="module")
def dem_path():
    return shared("terrain/pysheds_dem.tif")


def cli_raster(tmp_path, product, dem, *flags):
    tifffile = pytest.importorskip("tifffile")
    out = tmp_path / f"{product}.tif"
    cli("dem", product, dem, out, *flags)
    return tifffile.imread(out)


CASES = [
    ("hillshade", [], {}),
    ("hillshade", ["--azimuth", "200", "--altitude", "30", "--z", "3", "--scale", "111120"],
     {"azimuth": 200, "altitude": 30, "z": 3, "scale": 111120}),
    ("hillshade", ["--multidirectional", "--compute-edges"], {"multidirectional": True, "compute_edges": True}),
    ("slope", ["--scale", "111120"], {"scale": 111120}),
    ("slope", ["--percent", "--alg", "ZevenbergenThorne", "--scale", "111120"],
     {"percent": True, "alg": "ZevenbergenThorne", "scale": 111120}),
    ("aspect", [], {}),
    ("aspect", ["--zero-for-flat"], {"zero_for_flat": True}),
    ("TRI", ["--alg", "Wilson"], {"alg": "Wilson"}),
    ("TPI", [], {}),
    ("roughness", ["--compute-edges"], {"compute_edges": True}),
]


@pytest.mark.parametrize("product, flags, options", CASES)
def test_products_equal_the_clis_geotiff(tmp_path, dem_path, product, flags, options):
    theirs = cli_raster(tmp_path, product, dem_path, *flags)
    fn = getattr(volterra.dem, product.lower())
    ours = fn(dem_path, **options)
    assert ours.shape == theirs.shape and ours.dtype == theirs.dtype
    if ours.dtype == np.float32 and not options.get("zero_for_flat"):
        theirs = np.where(theirs == -9999, np.nan, theirs)
    np.testing.assert_array_equal(ours, theirs)
    # The same from the heightfield read, and from its array and transform.
    hf = volterra.read(dem_path)
    np.testing.assert_array_equal(fn(hf, **options), ours)


def test_color_relief_equals_the_clis(tmp_path, dem_path):
    palette = tmp_path / "palette.txt"
    palette.write_text("nv 0 0 0 0\n0% 20 60 20\n50% 200 180 90\n100% 255 255 255\n")
    theirs = cli_raster(tmp_path, "color-relief", dem_path, "--palette", palette, "--alpha")
    ours = volterra.dem.color_relief(dem_path, palette, alpha=True)
    np.testing.assert_array_equal(ours, theirs)
    # The palette as text and as rows gives the same.
    np.testing.assert_array_equal(volterra.dem.color_relief(dem_path, palette.read_text(), alpha=True), ours)
    rows = [("nv", 0, 0, 0, 0), ("0%", 20, 60, 20), ("50%", 200, 180, 90), ("100%", 255, 255, 255)]
    np.testing.assert_array_equal(volterra.dem.color_relief(dem_path, rows, alpha=True), ours)


def test_contours_equal_the_clis_geojson(tmp_path, dem_path):
    out = tmp_path / "contours.geojson"
    cli("dem", "contours", dem_path, out, "--interval", "25")
    features = json.loads(out.read_text())["features"]
    theirs = sorted((f["properties"]["elev"], np.round(np.array(f["geometry"]["coordinates"]), 6).tolist()) for f in features)
    ours = sorted((level, np.round(xy, 6).tolist()) for level, xy in volterra.dem.contours(dem_path, interval=25))
    assert len(ours) == len(theirs) > 10
    for (la, a), (lb, b) in zip(ours, theirs):
        assert la == lb
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-6)


def test_a_planes_slope_and_aspect_are_its_closed_form():
    # z = 0.3 x − 0.4 y metres on a 10 m grid: slope atan(0.5), aspect (downhill) toward
    # −gradient = (−0.3, +0.4), i.e. north-west of north by atan(0.3/0.4).
    rows, cols, cell = 20, 30, 10.0
    y, x = np.mgrid[0:rows, 0:cols]
    east, north = x * cell, -y * cell
    z = (0.3 * east - 0.4 * north).astype(np.float32)
    transform = (1000.0, cell, 0.0, 5000.0, 0.0, -cell)
    slope = volterra.dem.slope(z, transform)
    aspect = volterra.dem.aspect(z, transform)
    inner = (slice(1, -1), slice(1, -1))
    np.testing.assert_allclose(slope[inner], np.degrees(np.arctan(0.5)), atol=1e-4)
    np.testing.assert_allclose(aspect[inner], 360 - np.degrees(np.arctan2(0.3, 0.4)), atol=1e-4)
    # gdaldem leaves the edges NoData (NaN here) unless compute_edges.
    assert np.isnan(slope[0]).all() and np.isfinite(volterra.dem.slope(z, transform, compute_edges=True)).all()


def test_bad_dem_inputs_raise_clear_errors(dem_path):
    with pytest.raises(ValueError, match="alg 'Wilson'"):
        volterra.dem.slope(dem_path, alg="Wilson")
    with pytest.raises(ValueError, match="interval or levels"):
        volterra.dem.contours(dem_path)
    with pytest.raises(ValueError, match="geotransform"):
        volterra.dem.hillshade(np.zeros((5, 5)))
    with pytest.raises(volterra.FormatError, match="not a DEM"):
        volterra.dem.slope(shared("volumes/aneurism/aneurism.nii.gz"))
    with pytest.raises(volterra.ReadError):
        volterra.dem.slope("/nonexistent/dem.tif")


def test_compare_equals_the_clis(tmp_path):
    a, b = volterra.Scene(width=40, height=30), volterra.Scene(width=40, height=30)
    data = np.fromfunction(lambda i, j, k: 100 * np.sin(i / 3.0) * np.cos(j / 4.0) + k, (20, 24, 28), dtype=np.float32)
    a.add_volume(data, renderer="shear-warp")
    b.add_volume(data, renderer="reference")
    fa, fb = a.render(), b.render()
    fa.save(tmp_path / "a.exr")
    fb.save(tmp_path / "b.exr")
    theirs = json.loads(cli("compare", tmp_path / "a.exr", tmp_path / "b.exr", "--json"))
    assert volterra.compare(tmp_path / "a.exr", tmp_path / "b.exr") == theirs
    assert volterra.compare(fa, fb) == theirs
    ours = volterra.compare(fa.rgb, fb.rgb)
    assert ours["overall"]["rmse"] > 0 and [c["channel"] for c in ours["channels"]] == ["R", "G", "B"]
    assert volterra.compare(fb, fb)["overall"]["rmse"] == 0
