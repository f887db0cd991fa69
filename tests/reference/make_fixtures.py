#!/usr/bin/env python3
"""Writes small synthetic files with the reference libraries (nibabel, pydicom, tifffile,
VTK) covering the format variants the shared data does not: every NIfTI datatype, NIfTI-2,
both byte orders, .hdr/.img pairs, 4-D; DICOM series that are oblique, non-uniform, have a
missing slice, several series in one directory; GeoTIFF compressions, predictors, tiles,
sample types and georeferencing forms; VTK legacy and XML encodings.

Usage: make_fixtures.py OUT_DIR   (writes the files and OUT_DIR/expected.json)

The files are tiny (a few KB) and committed; the expectations come from reading each file
back with the same reference library, not from volterra.
"""
import json
import os
import sys

import numpy as np

OUT = sys.argv[1]
EXPECT = {}


def rng(seed):
    return np.random.default_rng(seed)


def values_for(dtype, shape, seed):
    r = rng(seed)
    dt = np.dtype(dtype)
    if dt.kind == "f":
        return (r.standard_normal(shape) * 1000).astype(dt)
    info = np.iinfo(dt)
    return r.integers(info.min, info.max, size=shape, endpoint=True, dtype=dt)


def flat_xyz(a):
    """volterra's order: i fastest."""
    return np.asarray(a).transpose(2, 1, 0).ravel() if a.ndim == 3 else np.asarray(a).ravel()


def record_volume(name, stored_xyz, affine, slope=1.0, inter=0.0, dtype=None, **extra):
    flat = flat_xyz(stored_xyz).astype(np.float64)
    EXPECT[name] = {
        "kind": "volume",
        "dims": list(map(int, stored_xyz.shape)),
        "affine": np.asarray(affine, dtype=np.float64).tolist(),
        "rescale": [float(slope), float(inter)],
        "dtype": dtype,
        "values": flat.tolist(),
        **extra,
    }


# --- NIfTI -------------------------------------------------------------------------------
def nifti_fixtures():
    import nibabel as nib
    dtypes = {"u8": "uint8", "i8": "int8", "u16": "uint16", "i16": "int16", "u32": "uint32", "i32": "int32", "f32": "float32", "f64": "float64"}
    shape = (5, 4, 3)
    aff = np.array([[-1.5, 0.1, 0, 10], [0.2, 1.25, 0, -20], [0, 0, 2.5, 30], [0, 0, 0, 1]])
    for n, (short, dt) in enumerate(dtypes.items()):
        for variant in ("n1le", "n2be", "pair"):
            data = values_for(dt, shape, 100 + n)
            if variant == "n2be":
                data = data.astype(np.dtype(dt).newbyteorder(">"))
                img = nib.Nifti2Image(data, aff)
                fname = f"nifti/{short}_nifti2_be.nii.gz"
            elif variant == "pair":
                img = nib.Nifti1Pair(data, aff)
                fname = f"nifti/{short}_pair.hdr"
            else:
                img = nib.Nifti1Image(data, aff)
                fname = f"nifti/{short}_nifti1.nii"
            img.set_sform(aff, code=2)
            img.set_qform(aff, code=1)
            path = os.path.join(OUT, fname)
            nib.save(img, path)
            back = nib.load(path)
            record_volume(fname, np.asanyarray(back.dataobj.get_unscaled()), back.affine, dtype=short)
    # scl_slope / scl_inter, and slope 0 meaning none
    data = values_for("int16", shape, 7)
    img = nib.Nifti1Image(data, aff)
    img.header.set_slope_inter(0.5, -100.0)
    nib.save(img, os.path.join(OUT, "nifti/scaled.nii"))
    record_volume("nifti/scaled.nii", data, nib.load(os.path.join(OUT, "nifti/scaled.nii")).affine, 0.5, -100.0, dtype="i16")
    # qform only (sform_code 0): the rotated qform must be used
    theta = 0.4
    rot = np.array([[np.cos(theta), -np.sin(theta), 0, 0], [np.sin(theta), np.cos(theta), 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    qaff = rot @ np.diag([2.0, 3.0, 4.0, 1.0])
    qaff[:3, 3] = [1, 2, 3]
    img = nib.Nifti1Image(data, None)
    img.set_qform(qaff, code=1)
    img.set_sform(np.diag([9, 9, 9, 1]), code=0)
    nib.save(img, os.path.join(OUT, "nifti/qform_only.nii"))
    back = nib.load(os.path.join(OUT, "nifti/qform_only.nii"))
    record_volume("nifti/qform_only.nii", data, back.header.get_qform(), dtype="i16")
    # 4-D: volume 2 of 3
    d4 = values_for("uint16", shape + (3,), 8)
    nib.save(nib.Nifti1Image(d4, aff), os.path.join(OUT, "nifti/four_d.nii.gz"))
    record_volume("nifti/four_d.nii.gz#2", d4[..., 2], aff, dtype="u16", volume_count=3)


# --- DICOM -------------------------------------------------------------------------------
def dicom_slice(path, pixels, ipp, iop, spacing, series_uid, instance, modality="CT", slope=1.0, inter=-1024.0, signed=True):
    import pydicom
    from pydicom.dataset import FileDataset, FileMetaDataset
    from pydicom.uid import ExplicitVRLittleEndian, generate_uid
    meta = FileMetaDataset()
    meta.MediaStorageSOPClassUID = "1.2.840.10008.5.1.4.1.1.2"
    meta.MediaStorageSOPInstanceUID = generate_uid(entropy_srcs=[path])
    meta.TransferSyntaxUID = ExplicitVRLittleEndian
    ds = FileDataset(path, {}, file_meta=meta, preamble=b"\0" * 128)
    ds.SOPClassUID = meta.MediaStorageSOPClassUID
    ds.SOPInstanceUID = meta.MediaStorageSOPInstanceUID
    ds.Modality = modality
    ds.SeriesInstanceUID = series_uid
    ds.StudyInstanceUID = "1.2.3.4"
    ds.FrameOfReferenceUID = "1.2.3.5"
    ds.SeriesDescription = "fixture " + series_uid[-4:]
    ds.InstanceNumber = instance
    ds.ImagePositionPatient = [float(x) for x in ipp]
    ds.ImageOrientationPatient = [float(x) for x in iop]
    ds.PixelSpacing = [float(spacing[0]), float(spacing[1])]
    ds.SliceThickness = 1.0
    ds.Rows, ds.Columns = pixels.shape
    ds.SamplesPerPixel = 1
    ds.PhotometricInterpretation = "MONOCHROME2"
    ds.BitsAllocated = 16
    ds.BitsStored = 12
    ds.HighBit = 11
    ds.PixelRepresentation = 1 if signed else 0
    ds.RescaleSlope = slope
    ds.RescaleIntercept = inter
    ds.PixelData = pixels.astype(np.int16 if signed else np.uint16).tobytes()
    ds.save_as(path, enforce_file_format=True)


def dicom_fixtures():
    import pydicom
    rows, cols = 6, 7
    iop_axial = [1, 0, 0, 0, 1, 0]
    # oblique series, files named in reverse of their order along the normal
    c, s = np.cos(0.3), np.sin(0.3)
    iop_obl = [c, s, 0, 0, c * 0 + np.cos(0.2), np.sin(0.2)]
    row, col = np.array(iop_obl[:3]), np.array(iop_obl[3:])
    col = col - row * np.dot(row, col)
    col /= np.linalg.norm(col)
    iop_obl = list(row) + list(col)
    normal = np.cross(row, col)
    d = os.path.join(OUT, "dicom/oblique")
    os.makedirs(d, exist_ok=True)
    vols = []
    for k in range(5):
        px = rng(200 + k).integers(-2048, 2047, size=(rows, cols))
        vols.append(px)
        ipp = np.array([10.0, -5.0, 3.0]) + normal * 2.0 * k
        dicom_slice(os.path.join(d, f"z{9 - k}.dcm"), px, ipp, iop_obl, (0.8, 0.6), "1.2.3.4.100", k + 1)
    m = np.eye(4)
    m[:3, 0] = row * 0.6
    m[:3, 1] = col * 0.8
    m[:3, 2] = normal * 2.0
    m[:3, 3] = [10.0, -5.0, 3.0]
    m[0, :] *= -1
    m[1, :] *= -1
    stack = np.stack(vols).transpose(2, 1, 0)
    record_volume("dicom/oblique", stack, m, 1.0, -1024.0, dtype="i16", modality="CT")
    # missing slice (gap of 2 at k=3) and non-uniform spacing
    for name, zs in (("dicom/missing_slice", [0, 1, 2, 4, 5]), ("dicom/nonuniform", [0, 1, 2, 3.4, 4.4])):
        d = os.path.join(OUT, name)
        os.makedirs(d, exist_ok=True)
        for k, z in enumerate(zs):
            px = np.full((rows, cols), 10 * k, dtype=np.int16)
            dicom_slice(os.path.join(d, f"s{k}.dcm"), px, [0, 0, z], iop_axial, (1, 1), "1.2.3.4.2" + str(len(name)), k + 1)
        EXPECT[name] = {"kind": "error", "positions": zs}
    # two series in one directory
    d = os.path.join(OUT, "dicom/two_series")
    os.makedirs(d, exist_ok=True)
    for sidx, uid in enumerate(("1.2.3.4.301", "1.2.3.4.302")):
        for k in range(3):
            px = np.full((rows, cols), 100 * sidx + k, dtype=np.int16)
            dicom_slice(os.path.join(d, f"a{sidx}_{k}.dcm"), px, [0, 0, 2 * k], iop_axial, (1, 1), uid, k + 1)
    EXPECT["dicom/two_series"] = {"kind": "series_list", "uids": ["1.2.3.4.301", "1.2.3.4.302"]}
    enhanced_multiframe()


def enhanced_multiframe():
    """An Enhanced MR-style multi-frame file: geometry only in the functional groups, frames
    stored out of spatial order, a per-frame rescale that differs between frames."""
    from pydicom.dataset import Dataset, FileDataset, FileMetaDataset
    from pydicom.sequence import Sequence
    from pydicom.uid import ExplicitVRLittleEndian
    path = os.path.join(OUT, "dicom/enhanced_multiframe.dcm")
    meta = FileMetaDataset()
    meta.MediaStorageSOPClassUID = "1.2.840.10008.5.1.4.1.1.4.1"
    meta.MediaStorageSOPInstanceUID = "1.2.3.4.500.1"
    meta.TransferSyntaxUID = ExplicitVRLittleEndian
    ds = FileDataset(path, {}, file_meta=meta, preamble=b"\0" * 128)
    ds.SOPClassUID = meta.MediaStorageSOPClassUID
    ds.SOPInstanceUID = meta.MediaStorageSOPInstanceUID
    ds.Modality = "MR"
    ds.SeriesInstanceUID = "1.2.3.4.500"
    rows, cols, frames = 5, 6, 4
    z_order = [2, 0, 3, 1]  # frame f lies at slice z_order[f]
    slopes = [1.0, 2.0, 1.0, 0.5]
    pix = rng(600).integers(0, 4000, size=(frames, rows, cols)).astype(np.uint16)
    ds.NumberOfFrames = frames
    ds.Rows, ds.Columns = rows, cols
    ds.SamplesPerPixel = 1
    ds.PhotometricInterpretation = "MONOCHROME2"
    ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation = 16, 16, 15, 0
    shared = Dataset()
    po = Dataset()
    po.ImageOrientationPatient = [0, 1, 0, 0, 0, -1]  # sagittal
    shared.PlaneOrientationSequence = Sequence([po])
    pm = Dataset()
    pm.PixelSpacing = [0.9, 0.7]
    pm.SliceThickness = 1.2
    shared.PixelMeasuresSequence = Sequence([pm])
    ds.SharedFunctionalGroupsSequence = Sequence([shared])
    per = []
    for f in range(frames):
        item = Dataset()
        pp = Dataset()
        pp.ImagePositionPatient = [-20.0 + 1.2 * z_order[f], 5.0, 30.0]
        item.PlanePositionSequence = Sequence([pp])
        pvt = Dataset()
        pvt.RescaleSlope = slopes[f]
        pvt.RescaleIntercept = 0
        pvt.RescaleType = "US"
        item.PixelValueTransformationSequence = Sequence([pvt])
        per.append(item)
    ds.PerFrameFunctionalGroupsSequence = Sequence(per)
    ds.PixelData = pix.tobytes()
    ds.save_as(path, enforce_file_format=True)
    # Expected: frames sorted by position along the normal; real values as f32.
    row, col = np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, -1.0])
    normal = np.cross(row, col)
    order = sorted(range(frames), key=lambda f: float(np.dot(normal, [-20.0 + 1.2 * z_order[f], 5.0, 30.0])))
    real = np.stack([pix[f].astype(np.float64) * slopes[f] for f in order])  # (k, rows, cols)
    m = np.eye(4)
    m[:3, 0] = row * 0.7
    m[:3, 1] = col * 0.9
    p0 = np.array([-20.0 + 1.2 * z_order[order[0]], 5.0, 30.0])
    p1 = np.array([-20.0 + 1.2 * z_order[order[-1]], 5.0, 30.0])
    m[:3, 2] = (p1 - p0) / (frames - 1)
    m[:3, 3] = p0
    m[0, :] *= -1
    m[1, :] *= -1
    record_volume("dicom/enhanced_multiframe.dcm", real.transpose(2, 1, 0), m, 1.0, 0.0, dtype="f32", modality="MR")


# --- GeoTIFF -----------------------------------------------------------------------------
def geotiff_fixtures():
    import tifffile
    h, w = 37, 45
    geokeys_utm = [1, 1, 0, 4, 1024, 0, 1, 1, 1025, 0, 1, 1, 3072, 0, 1, 32610, 4099, 0, 1, 9001]
    cases = [
        ("i16_none_strips", "int16", None, None, None),
        ("u16_lzw_pred2_tiles", "uint16", "lzw", 2, (16, 16)),
        ("i32_deflate_pred2", "int32", "zlib", 2, None),
        ("f32_deflate_pred3_tiles", "float32", "zlib", 3, (16, 32)),
        ("f64_packbits", "float64", "packbits", None, None),
        ("f32_lzw_pred3", "float32", "lzw", 3, None),
        ("f32_zstd_pred3", "float32", "zstd", 3, None),
        ("i16_zstd_tiles", "int16", "zstd", None, (16, 16)),
    ]
    for n, (name, dt, comp, pred, tile) in enumerate(cases):
        data = values_for(dt, (h, w), 300 + n)
        if np.dtype(dt).kind == "f":
            data[3, 4] = -9999.0
        else:
            data[3, 4] = -9999 if np.dtype(dt).kind == "i" else 0
        nodata = data[3, 4]
        extratags = [
            (33550, "d", 3, (30.0, 20.0, 0.0), True),
            (33922, "d", 6, (0.0, 0.0, 0.0, 500000.0, 5200000.0, 0.0), True),
            (34735, "H", len(geokeys_utm), geokeys_utm, True),
            (42113, "s", 0, f"{nodata}", True),
        ]
        path = os.path.join(OUT, f"geotiff/{name}.tif")
        os.makedirs(os.path.dirname(path), exist_ok=True)
        tifffile.imwrite(path, data, compression=comp, predictor=pred, tile=tile, extratags=extratags, photometric="minisblack")
        back = tifffile.imread(path).astype(np.float64)
        mask = back == float(nodata)
        EXPECT[f"geotiff/{name}.tif"] = {
            "kind": "heightfield", "dims": [w, h], "cell_size": [30.0, 20.0], "origin": [500015.0, 5199990.0],
            "epsg": 32610, "geographic": False, "nodata_count": int(mask.sum()),
            "values": np.where(mask, np.nan, back).ravel().tolist(),
        }
    # A reduced-resolution image first, the full-resolution one second: readers must pick
    # the full one, not the first or the last directory.
    full = values_for("int16", (h, w), 398)
    path = os.path.join(OUT, "geotiff/overview_first.tif")
    with tifffile.TiffWriter(path) as tw:
        tw.write(full[::4, ::4].copy(), subfiletype=1, photometric="minisblack")
        tw.write(full, photometric="minisblack", extratags=[
            (33550, "d", 3, (30.0, 20.0, 0.0), True),
            (33922, "d", 6, (0.0, 0.0, 0.0, 500000.0, 5200000.0, 0.0), True),
            (34735, "H", len(geokeys_utm), geokeys_utm, True)])
        tw.write(full[::2, ::2].copy(), subfiletype=1, photometric="minisblack")
    EXPECT["geotiff/overview_first.tif"] = {
        "kind": "heightfield", "dims": [w, h], "cell_size": [30.0, 20.0], "origin": [500015.0, 5199990.0],
        "epsg": 32610, "geographic": False, "nodata_count": 0, "values": full.astype(np.float64).ravel().tolist(),
    }
    # ModelTransformation + PixelIsPoint, geographic
    data = values_for("float32", (h, w), 399)
    keys = [1, 1, 0, 3, 1024, 0, 1, 2, 1025, 0, 1, 2, 2048, 0, 1, 4326]
    mt = (0.001, 0, 0, -122.5, 0, -0.002, 0, 47.8, 0, 0, 0, 0, 0, 0, 0, 1)
    path = os.path.join(OUT, "geotiff/f32_transform_point_geographic.tif")
    tifffile.imwrite(path, data, extratags=[(34264, "d", 16, mt, True), (34735, "H", len(keys), keys, True)], photometric="minisblack")
    EXPECT["geotiff/f32_transform_point_geographic.tif"] = {
        "kind": "heightfield", "dims": [w, h], "cell_size": [0.001, 0.002], "origin": [-122.5, 47.8],
        "epsg": 4326, "geographic": True, "nodata_count": 0, "values": data.astype(np.float64).ravel().tolist(),
    }


# --- VTK ---------------------------------------------------------------------------------
def vtk_fixtures():
    import vtk
    from vtk.util.numpy_support import numpy_to_vtk
    n = 50
    r = rng(500)
    pts = r.random((n, 3)) * [2.0, 1.0, 0.5] - [1.0, 0.5, 0.0]
    arrays = {"mass": r.random(n) * 1e-3, "h": 0.05 + r.random(n) * 0.01, "density": r.random(n) * 3, "temperature": r.random(n),
              "velocity": r.standard_normal((n, 3)), "id": np.arange(n, dtype=np.int32)}

    def polydata():
        pd = vtk.vtkPolyData()
        p = vtk.vtkPoints()
        p.SetData(numpy_to_vtk(pts.astype(np.float32), deep=True))
        pd.SetPoints(p)
        verts = vtk.vtkCellArray()
        for i in range(n):
            verts.InsertNextCell(1)
            verts.InsertCellPoint(i)
        pd.SetVerts(verts)
        for name, a in arrays.items():
            arr = numpy_to_vtk(a.astype(np.float32) if a.dtype != np.int32 else a, deep=True)
            arr.SetName(name)
            pd.GetPointData().AddArray(arr)
        return pd

    def ugrid():
        ug = vtk.vtkUnstructuredGrid()
        pd = polydata()
        ug.SetPoints(pd.GetPoints())
        for i in range(n):
            ug.InsertNextCell(vtk.VTK_VERTEX, 1, [i])
        for k in range(pd.GetPointData().GetNumberOfArrays()):
            ug.GetPointData().AddArray(pd.GetPointData().GetArray(k))
        return ug

    os.makedirs(os.path.join(OUT, "vtk"), exist_ok=True)
    files = []
    for name, ascii_, version in (("legacy_ascii_42.vtk", True, 42), ("legacy_binary_42.vtk", False, 42), ("legacy_binary_51.vtk", False, 51)):
        w = vtk.vtkPolyDataWriter()
        w.SetInputData(polydata())
        w.SetFileName(os.path.join(OUT, "vtk", name))
        if ascii_:
            w.SetFileTypeToASCII()
        else:
            w.SetFileTypeToBinary()
        if version == 42:
            w.SetFileVersion(42)
        w.Write()
        files.append(name)
    w = vtk.vtkUnstructuredGridWriter()
    w.SetInputData(ugrid())
    w.SetFileName(os.path.join(OUT, "vtk", "legacy_ugrid_42.vtk"))
    w.SetFileVersion(42)
    w.SetFileTypeToBinary()
    w.Write()
    files.append("legacy_ugrid_42.vtk")
    for mode, comp, ext in (("ascii", False, "vtp"), ("binary", False, "vtp"), ("binary", True, "vtp"), ("appended_raw", False, "vtp"),
                            ("appended_raw", True, "vtu"), ("appended_base64", True, "vtp"), ("binary", True, "vtu")):
        w = vtk.vtkXMLPolyDataWriter() if ext == "vtp" else vtk.vtkXMLUnstructuredGridWriter()
        w.SetInputData(polydata() if ext == "vtp" else ugrid())
        name = f"xml_{mode}{'_zlib' if comp else ''}.{ext}"
        w.SetFileName(os.path.join(OUT, "vtk", name))
        if mode == "ascii":
            w.SetDataModeToAscii()
        elif mode == "binary":
            w.SetDataModeToBinary()
        else:
            w.SetDataModeToAppended()
            w.SetEncodeAppendedData(mode == "appended_base64")
        if comp:
            w.SetCompressorTypeToZLib()
        else:
            w.SetCompressorTypeToNone()
        w.Write()
        files.append(name)
    import pyvista as pv
    for name in files:
        m = pv.read(os.path.join(OUT, "vtk", name))
        EXPECT["vtk/" + name] = {
            "kind": "particles", "count": int(m.n_points),
            "positions": np.asarray(m.points, dtype=np.float64).ravel().tolist(),
            "arrays": {k: np.asarray(m.point_data[k], dtype=np.float64).ravel().tolist() for k in m.point_data.keys()},
        }


def no_nan(x):
    """JSON has no NaN: NoData becomes null."""
    if isinstance(x, dict):
        return {k: no_nan(v) for k, v in x.items()}
    if isinstance(x, list):
        return [no_nan(v) for v in x]
    if isinstance(x, float) and x != x:
        return None
    return x


def main():
    os.makedirs(os.path.join(OUT, "nifti"), exist_ok=True)
    nifti_fixtures()
    dicom_fixtures()
    geotiff_fixtures()
    vtk_fixtures()
    with open(os.path.join(OUT, "expected.json"), "w") as f:
        json.dump(no_nan(EXPECT), f, sort_keys=True, allow_nan=False)
        f.write("\n")
    print(f"{len(EXPECT)} fixtures in {OUT}", file=sys.stderr)


if __name__ == "__main__":
    main()
