"""volterra.read against the independent readers (nibabel, pydicom, pyvista, tifffile) on
the shared data, the zero-copy promises, the exceptions, and the GIL released while a
file is read. Run by tests/python.sh (the README's test command) with pytest."""

import threading
import time

import numpy as np
import pytest

import volterra
from _support import shared


NIFTI = [
    "volumes/aneurism/aneurism.nii.gz",
    "volumes/angio/CT_AVM.nii.gz",
    "volumes/mr/nibabel_anatomical.nii",
    "volumes/mr/mni_icbm152_t1_tal_nlin_sym_09a_converted.nii.gz",
    "volumes/pet/FDOPA_fluorodopa_hc12_gomez.nii",
]


@pytest.mark.parametrize("rel", NIFTI)
def test_nifti_values_and_affine_equal_nibabels(rel):
    nib = pytest.importorskip("nibabel")
    path = shared(rel)
    ours = volterra.read(path)
    theirs = nib.load(str(path))
    expected = theirs.get_fdata()
    assert ours.array.shape == expected.shape
    np.testing.assert_array_equal(np.asarray(ours.array, dtype=np.float64), expected)
    np.testing.assert_allclose(ours.affine, theirs.affine, rtol=0, atol=1e-5)
    zooms = theirs.header.get_zooms()[:3]
    np.testing.assert_allclose(ours.spacing, zooms, rtol=1e-6)
    assert ours.meta["dims"] == list(expected.shape[:3])


def test_a_4d_niftis_volumes_by_index():
    nib = pytest.importorskip("nibabel")
    path = shared("volumes/mr/nibabel_example4d.nii.gz")
    theirs = nib.load(str(path)).get_fdata()
    for k in (0, theirs.shape[3] - 1):
        ours = volterra.read(path, volume=k)
        np.testing.assert_array_equal(np.asarray(ours.array, dtype=np.float64), theirs[..., k])
        assert ours.meta["volume_index"] == k


def test_stored_values_are_handed_over_without_a_copy():
    path = shared("volumes/aneurism/aneurism.nii.gz")
    v = volterra.read(path)
    assert v.slope == 1.0 and v.intercept == 0.0
    # The real values are the stored ones: one buffer, the reader's, in Fortran order.
    assert np.shares_memory(v.array, v.raw)
    assert v.raw.flags.f_contiguous and v.raw.dtype == np.uint8
    assert v.array.base is not None, "a view over the buffer volterra read into"


def test_a_rescaled_volume_gives_real_values_beside_the_stored_ones():
    path = shared("volumes/dicom_real/mr_t1_vestibular_schwannoma_20slices")
    v = volterra.read(path)
    np.testing.assert_allclose(v.array, v.raw * v.slope + v.intercept)
    if v.slope != 1.0 or v.intercept != 0.0:
        assert v.array.dtype == np.float64 and not np.shares_memory(v.array, v.raw)


def test_dicom_series_values_equal_pydicoms_stack():
    pydicom = pytest.importorskip("pydicom")
    directory = shared("volumes/aneurism/dicom_ct")
    files = [pydicom.dcmread(str(p)) for p in sorted(directory.iterdir()) if p.is_file()]
    normal = np.cross(np.array(files[0].ImageOrientationPatient[:3], float), np.array(files[0].ImageOrientationPatient[3:], float))
    files.sort(key=lambda d: float(np.dot(normal, np.array(d.ImagePositionPatient, float))))
    slices = [d.pixel_array * float(getattr(d, "RescaleSlope", 1)) + float(getattr(d, "RescaleIntercept", 0)) for d in files]
    # pydicom's pixel_array is [row, column]; volterra's (i, j, k) is (column, row, slice).
    expected = np.stack(slices, axis=-1).transpose(1, 0, 2)
    ours = volterra.read(directory)
    assert ours.array.shape == expected.shape
    np.testing.assert_array_equal(np.asarray(ours.array, dtype=np.float64), expected)
    assert ours.modality == files[0].Modality
    dx, dy = (float(s) for s in files[0].PixelSpacing)
    assert ours.spacing[0] == pytest.approx(dy) and ours.spacing[1] == pytest.approx(dx)


def test_list_series_and_reading_one_of_several():
    directory = shared("volumes/dicom_real")
    found = volterra.list_series(directory)
    assert len(found) >= 2
    assert {"uid", "description", "modality", "files", "rows", "columns"} <= set(found[0])
    with pytest.raises(volterra.AmbiguousError) as e:
        volterra.read(directory)
    assert str(directory) in str(e.value)
    first = volterra.read(directory, series=1)
    by_uid = volterra.read(directory, series=found[0]["uid"])
    np.testing.assert_array_equal(first.raw, by_uid.raw)
    assert first.raw.shape[2] == found[0]["files"]


def test_a_geotiff_dem_equals_tifffiles_raster_and_gdals_transform():
    tifffile = pytest.importorskip("tifffile")
    path = shared("terrain/pysheds_dem.tif")
    dem = volterra.read(path)
    raw = tifffile.imread(str(path)).astype(np.float32)
    assert dem.array.shape == raw.shape and dem.array.dtype == np.float32
    if dem.nodata is not None:
        raw[raw == np.float32(dem.nodata)] = np.nan
    np.testing.assert_array_equal(dem.array, raw)
    with tifffile.TiffFile(str(path)) as tif:
        tags = tif.pages[0].tags
        scale = tags["ModelPixelScaleTag"].value
        tie = tags["ModelTiepointTag"].value
    # A PixelIsArea raster: the tie point is the north-west corner, as GDAL's transform.
    x0, sx, _, y0, _, sy = dem.transform
    assert (sx, -sy) == pytest.approx((scale[0], scale[1]))
    assert (x0, y0) == pytest.approx((tie[3], tie[4]))
    assert dem.meta["geotransform"] == list(dem.transform)


def test_particles_equal_pyvistas():
    pv = pytest.importorskip("pyvista")
    path = shared("particles/smoke_plume_110k.vtp")
    ours = volterra.read(path)
    theirs = pv.read(str(path))
    np.testing.assert_array_equal(ours.positions, np.asarray(theirs.points, dtype=np.float64))
    assert len(ours) == theirs.n_points
    for name in theirs.point_data.keys():
        np.testing.assert_array_equal(ours.arrays[name], np.asarray(theirs.point_data[name], dtype=ours.arrays[name].dtype))


def test_to_nibabel_and_to_pyvista_keep_the_grid():
    nib = pytest.importorskip("nibabel")
    pv = pytest.importorskip("pyvista")
    v = volterra.read(shared("volumes/aneurism/aneurism.nii.gz"))
    img = volterra.to_nibabel(v)
    assert isinstance(img, nib.Nifti1Image)
    np.testing.assert_array_equal(img.get_fdata(), np.asarray(v.array, dtype=np.float64))
    grid = volterra.to_pyvista(v)
    assert tuple(grid.dimensions) == v.array.shape
    # Voxel (i, j, k) lands where the affine puts it.
    ijk = np.array([3, 5, 7])
    world = v.affine @ np.append(ijk, 1.0)
    point = grid.points[ijk[0] + grid.dimensions[0] * (ijk[1] + grid.dimensions[1] * ijk[2])]
    np.testing.assert_allclose(point, world[:3], atol=1e-6)
    assert grid.point_data["values"][ijk[0] + grid.dimensions[0] * (ijk[1] + grid.dimensions[1] * ijk[2])] == v.array[tuple(ijk)]
    cloud = volterra.to_pyvista(volterra.read(shared("particles/smoke_plume_110k.vtp")))
    assert isinstance(cloud, pv.PolyData)


def test_errors_are_exceptions_with_the_commands_one_line_message(tmp_path):
    missing = tmp_path / "nothing.nii"
    with pytest.raises(volterra.ReadError) as e:
        volterra.read(missing)
    assert isinstance(e.value, OSError) and str(missing) in str(e.value)
    broken = tmp_path / "broken.nii"
    broken.write_bytes(b"\x5c\x01\x00\x00" + b"\x00" * 100)
    with pytest.raises(volterra.FormatError) as e:
        volterra.read(broken)
    assert isinstance(e.value, ValueError) and str(broken) in str(e.value) and "\n" not in str(e.value)
    with pytest.raises(volterra.MemoryLimitError) as e:
        volterra.read(shared("volumes/aneurism/aneurism.nii.gz"), max_memory="1M")
    assert isinstance(e.value, MemoryError)
    with pytest.raises(ValueError):
        volterra.read(shared("volumes/aneurism/aneurism.nii.gz"), max_memory="lots")
    with pytest.raises(TypeError):
        volterra.read(shared("volumes/aneurism/aneurism.nii.gz"), 3)


def test_reading_releases_the_gil():
    path = shared("volumes/mr/mni_icbm152_t1_tal_nlin_sym_09a_converted.nii.gz")
    done = threading.Event()
    result = {}

    def work():
        result["volume"] = volterra.read(path)
        done.set()

    t = threading.Thread(target=work)
    ticks = 0
    start = time.perf_counter()
    t.start()
    while not done.is_set():
        ticks += 1
    t.join()
    elapsed = time.perf_counter() - start
    assert result["volume"].array.size > 0
    # Python ran meanwhile: with the GIL held through the read (tens of ms at least) this
    # loop would not run until it ended; released, it spins millions of times a second.
    assert elapsed > 0.01, "the read is too short to tell"
    assert ticks > 10_000, f"{ticks} iterations in {elapsed:.3f} s"
