#!/usr/bin/env python3
"""Differential test of volterra's volume readers against pydicom, nibabel, pyvista/VTK,
SimpleITK and pynrrd, over the test files those libraries ship (pydicom/data/test_files,
nibabel/tests/data: read in place from the reference venv, nothing copied), every DICOM,
NIfTI, VTK image (.vtk STRUCTURED_POINTS, .vti), MetaImage and NRRD file in ../shared/data,
and files the reference libraries write themselves at test time (suite "written": oblique
directions, odd spacings, negative and scaled values, every encoding and byte order).

Each file is converted with `volterra convert FILE out.nii`; the NIfTI volterra wrote is read
back with nibabel and compared with what the reference library reads from the original:
values (after RescaleSlope/Intercept, DoseGridScaling or scl_slope/scl_inter), dimensions and
the voxel-to-world affine (RAS+ millimetres). Each file ends in one row:

  equal     volterra's values, dims and affine match the reference's
  refused   volterra exits non-zero with a one-line reason (justified in the table)
  wrong     volterra wrote something that differs from the reference, or crashed
  no reference  the reference library cannot read it either way (listed, not compared)

Usage: differential.py VOLTERRA_BINARY OUT_MARKDOWN [SHARED_DATA_DIR]
Exits 1 when any file is wrong. The table is written to OUT_MARKDOWN (docs/differential.md).
"""
import os
import subprocess
import sys
import tempfile
import warnings

import numpy as np

warnings.filterwarnings("ignore")

VOLTERRA, OUT = sys.argv[1], sys.argv[2]
SHARED = sys.argv[3] if len(sys.argv) > 3 else None
LOSSY = {
    "1.2.840.10008.1.2.4.50": 2,  # JPEG baseline: decoders differ by a grey level or two
    "1.2.840.10008.1.2.4.51": 2,  # 12-bit extended: libjpeg-turbo and pylibjpeg's libjpeg differ by 1
    "1.2.840.10008.1.2.4.91": 2,  # JPEG 2000 (lossy allowed)
}


# --- reference readers ----------------------------------------------------------------------
def dicom_reference(path):
    """(values [i, j, k] after the modality rescale, RAS affine or None, transfer syntax)."""
    import pydicom
    from pydicom.uid import ImplicitVRLittleEndian, ExplicitVRLittleEndian, ExplicitVRBigEndian

    ds = pydicom.dcmread(path, force=True)
    if "PixelData" not in ds:
        return None
    ts = ds.file_meta.get("TransferSyntaxUID") if hasattr(ds, "file_meta") else None
    if ts is None:
        # No file meta (ACR-NEMA, bare data sets): the encoding pydicom detected on reading.
        implicit, little = ds.original_encoding
        ds.file_meta.TransferSyntaxUID = ImplicitVRLittleEndian if implicit else (ExplicitVRLittleEndian if little else ExplicitVRBigEndian)
        ts = ds.file_meta.TransferSyntaxUID
    frames = int(ds.get("NumberOfFrames", 1) or 1)
    spp = int(ds.get("SamplesPerPixel", 1))
    native_ybr = spp == 3 and ds.PhotometricInterpretation.startswith("YBR_FULL") and not ds.file_meta.TransferSyntaxUID.is_compressed
    if native_ybr:
        # Native YBR_FULL: Y is BT.601 luminance; volterra keeps it, so compare with pydicom's Y.
        from pydicom.pixels import pixel_array

        arr = pixel_array(ds, as_rgb=False).astype(np.float64)[..., 0]
    else:
        arr = ds.pixel_array.astype(np.float64)
    if spp == 3 and not native_ybr:
        # volterra loads colour as BT.601 luminance of RGB, rounded to the stored type
        # (pydicom's pixel_array has converted YBR to RGB already).
        arr = np.floor(0.299 * arr[..., 0] + 0.587 * arr[..., 1] + 0.114 * arr[..., 2] + 0.5)
    if frames == 1:
        arr = arr[np.newaxis]
    # Per-frame, shared or top-level rescale (enhanced multi-frame files may vary it per frame).
    slopes, inters = [], []
    pf = ds.get("PerFrameFunctionalGroupsSequence")
    shared = ds.get("SharedFunctionalGroupsSequence")

    def transform(item):
        t = item.get("PixelValueTransformationSequence") if item is not None else None
        return t[0] if t else None

    for f in range(frames):
        t = transform(pf[f]) if pf and f < len(pf) else None
        t = t or (transform(shared[0]) if shared else None) or ds
        slopes.append(float(t.get("RescaleSlope", 1) or 1))
        inters.append(float(t.get("RescaleIntercept", 0) or 0))
    if ds.get("Modality") == "RTDOSE" and ds.get("DoseGridScaling") is not None:
        slopes = [float(ds.DoseGridScaling)] * frames
    arr = arr * np.array(slopes)[:, None, None] + np.array(inters)[:, None, None]

    # Geometry: rows along IOP[0:3] at PixelSpacing[1], columns along IOP[3:6] at
    # PixelSpacing[0], frames ordered by their position along the normal.
    def first(seq, name, attr):
        for holder in ([pf[0]] if pf else []) + ([shared[0]] if shared else []):
            s = holder.get(seq)
            if s and attr in s[0]:
                return s[0][attr].value
        return None

    iop = ds.get("ImageOrientationPatient") or first("PlaneOrientationSequence", "", "ImageOrientationPatient")
    ps = ds.get("PixelSpacing") or first("PixelMeasuresSequence", "", "PixelSpacing")
    positions = None
    if frames > 1 and pf:
        p = [f.get("PlanePositionSequence") for f in pf]
        if all(x and "ImagePositionPatient" in x[0] for x in p) and len(p) == frames:
            positions = np.array([[float(v) for v in x[0].ImagePositionPatient] for x in p])
    elif frames > 1 and ds.get("GridFrameOffsetVector") is not None and ds.get("ImagePositionPatient") and iop:
        r, c = np.array(iop[:3], float), np.array(iop[3:], float)
        n = np.cross(r, c)
        positions = np.array([np.array(ds.ImagePositionPatient, float) + float(d) * n for d in ds.GridFrameOffsetVector])
    elif frames == 1 and ds.get("ImagePositionPatient"):
        positions = np.array([[float(v) for v in ds.ImagePositionPatient]])
    affine = None
    if iop is not None and ps is not None and positions is not None:
        r, c = np.array(iop[:3], float), np.array(iop[3:], float)
        n = np.cross(r, c)
        n /= np.linalg.norm(n)
        order = np.argsort(positions @ n, kind="stable")
        arr = arr[order]
        positions = positions[order]
        if len(positions) > 1:
            slice_vec = (positions[-1] - positions[0]) / (len(positions) - 1)
        else:
            s = ds.get("SpacingBetweenSlices") or ds.get("SliceThickness") or 1.0
            slice_vec = n * float(s)
        lps = np.eye(4)
        lps[:3, 0] = r * float(ps[1])
        lps[:3, 1] = c * float(ps[0])
        lps[:3, 2] = slice_vec
        lps[:3, 3] = positions[0]
        affine = np.diag([-1.0, -1.0, 1.0, 1.0]) @ lps
    return arr.transpose(2, 1, 0), affine, str(ts)


def nifti_reference(path):
    import nibabel as nib

    try:
        img = nib.load(path)
    except nib.filebasedimages.ImageFileError:
        if path.endswith((".nii", ".nii.gz", ".hdr")):
            raise
        return None  # not an image nibabel knows (streamlines, surfaces, text)
    if isinstance(img, nib.Cifti2Image):
        img = nib.Nifti2Image.from_filename(path)  # its NIfTI-2 container, as volterra reads it
    if not isinstance(img, (nib.Nifti1Image, nib.Nifti2Image, nib.Nifti1Pair, nib.Nifti2Pair)):
        return "other format", type(img).__name__
    h = img.header
    data = np.asarray(img.get_fdata(dtype=np.float64))
    data = data.reshape(data.shape[:3] + (-1,)) if data.ndim > 3 else data
    sform, qform = int(h["sform_code"]), int(h["qform_code"])
    if sform == 0 and qform == 0:
        # NIfTI's method 1 (no transform): pixdim scaling only. nibabel's img.affine is its
        # Analyze-style centred default here, which the standard does not define.
        affine = np.diag(list(h["pixdim"][1:4]) + [1.0])
    else:
        affine = img.affine.copy()
    unit = h.get_xyzt_units()[0]
    scale = {"meter": 1000.0, "micron": 0.001}.get(unit, 1.0)
    affine[:3, :] *= scale
    return data, affine, "nifti"


def axes_affine(point, dims):
    """The affine whose columns step index axes by one, from a function index -> world."""
    o = np.array(point(0, 0, 0), dtype=np.float64)
    a = np.eye(4)
    a[:3, 3] = o
    for c, ijk in enumerate([(1, 0, 0), (0, 1, 0), (0, 0, 1)]):
        if dims[c] > 1:
            a[:3, c] = np.array(point(*ijk), dtype=np.float64) - o
        else:
            a[:3, c] = 0.0
    return a


def vtk_reference(path):
    """VTK image data through pyvista/VTK's own readers (legacy STRUCTURED_POINTS, .vti, and
    NRRD files only VTK's reader takes): the active scalars, x fastest; VTK's coordinates
    are world coordinates. The affine comes from the grid's own point positions."""
    import pyvista as pv

    mesh = pv.read(path)
    if not isinstance(mesh, pv.ImageData):
        return "other format", type(mesh).__name__
    name = mesh.point_data.active_scalars_name or next(n for n in mesh.point_data.keys() if mesh.point_data[n].ndim == 1)
    dims = mesh.dimensions
    values = np.asarray(mesh.point_data[name], dtype=np.float64).reshape(dims, order="F")
    affine = axes_affine(lambda i, j, k: mesh.GetPoint(i + dims[0] * (j + dims[1] * k)), dims)
    if dims[2] == 1:
        affine[:3, 2] = np.array(mesh.direction_matrix)[:, 2] * mesh.spacing[2]
    return values, affine, "vtk"


def metaimage_reference(path):
    """MetaImage through SimpleITK: values x fastest, geometry from ITK's own index-to-
    physical mapping (LPS), turned to RAS."""
    import SimpleITK as sitk

    img = sitk.ReadImage(path)
    if img.GetNumberOfComponentsPerPixel() != 1:
        return "other format", f"{img.GetNumberOfComponentsPerPixel()}-component image"
    arr = sitk.GetArrayFromImage(img).astype(np.float64)
    arr = arr.transpose(tuple(reversed(range(arr.ndim))))
    dims = list(img.GetSize()) + [1] * (3 - img.GetDimension())
    arr = arr.reshape(dims, order="C") if arr.ndim < 3 else arr
    point = lambda i, j, k: img.TransformIndexToPhysicalPoint((i, j, k)[: img.GetDimension()]) + (0.0,) * (3 - img.GetDimension())
    affine = axes_affine(point, dims)
    affine[:2, :] *= -1  # LPS -> RAS
    return arr, affine, "metaimage"


NRRD_SPACE = {
    "right-anterior-superior": [1, 1, 1], "ras": [1, 1, 1],
    "left-anterior-superior": [-1, 1, 1], "las": [-1, 1, 1],
    "left-posterior-superior": [-1, -1, 1], "lps": [-1, -1, 1],
    "scanner-xyz": [1, 1, 1], "3d-right-handed": [1, 1, 1], "3d-left-handed": [1, 1, 1],
}


def nrrd_reference(path):
    """NRRD through pynrrd: data x fastest; the affine from `space directions` (one vector per
    axis) and `space origin`, the space turned to RAS (LPS negates x and y, LAS x); without
    directions, `spacings` from the origin. Data split over a pattern of files (which pynrrd
    does not read): pynrrd's header, the files read here. (VTK's NRRD reader is no reference:
    it reads rows top-down, mirroring j.)"""
    import nrrd

    try:
        data, h = nrrd.read(path, index_order="F")
    except FileNotFoundError:
        # pynrrd reads one data file; a `data file: PATTERN min max step` header is read
        # here: pynrrd's header, each slice file by numpy (raw encoding).
        h = nrrd.read_header(path)
        pattern, lo, hi, step = h["data file"].split()[:4]
        if h.get("encoding", "raw") != "raw":
            raise
        dtype = np.dtype(nrrd.reader._determine_datatype(h))
        files = [os.path.join(os.path.dirname(path), pattern % k) for k in range(int(lo), int(hi) + 1, int(step))]
        data = np.concatenate([np.fromfile(f, dtype=dtype) for f in files]).reshape(h["sizes"], order="F")
    data = np.asarray(data, dtype=np.float64)
    dims = list(data.shape) + [1] * (3 - data.ndim)
    data = data.reshape(dims, order="F")
    affine = np.eye(4)
    if "space directions" in h:
        d = np.asarray(h["space directions"], dtype=np.float64)
        affine[:3, : d.shape[0]] = d.T
        if "space origin" in h:
            affine[:3, 3] = np.asarray(h["space origin"], dtype=np.float64)
    elif "spacings" in h:
        for i, sp in enumerate(h["spacings"]):
            affine[i, i] = 1.0 if np.isnan(sp) else sp
    signs = np.array(NRRD_SPACE.get(str(h.get("space", "ras")).lower(), [1, 1, 1]), dtype=np.float64)
    affine[:3, :] *= signs[:, None]
    return data, affine, "nrrd"


def write_fixtures(work):
    """Files written by the reference libraries themselves, with non-unit spacing, negative
    and scaled values and oblique orientations: (path, kind)."""
    import nrrd
    import pyvista as pv
    import SimpleITK as sitk

    rng = np.random.default_rng(19)
    out = []
    vol = (rng.normal(0, 300, (13, 9, 7)) - 1000).astype(np.int16)  # x, y, z
    c, s = np.cos(0.4), np.sin(0.4)
    rot = np.array([[c, -s, 0], [s * 0.8, c * 0.8, -0.6], [s * 0.6, c * 0.6, 0.8]])
    # SimpleITK: oblique direction, odd spacing, compressed and not, detached .mhd + .raw.
    img = sitk.GetImageFromArray(vol.transpose(2, 1, 0))
    img.SetSpacing((0.7, 1.3, 2.1))
    img.SetOrigin((-10.0, 20.5, 30.25))
    img.SetDirection(tuple(rot.flatten()))
    for name, compress in [("oblique.mha", False), ("oblique_zlib.mha", True), ("oblique.mhd", False)]:
        p = os.path.join(work, name)
        sitk.WriteImage(img, p, compress)
        out.append((p, "metaimage"))
    flt = sitk.GetImageFromArray((rng.random((5, 6, 4)) * 1e3).astype(np.float64))
    flt.SetSpacing((0.25, 0.5, 4.0))
    p = os.path.join(work, "double.mha")
    sitk.WriteImage(flt, p)
    out.append((p, "metaimage"))
    # The same int16 volume big-endian: the header edited, the bytes swapped.
    p = os.path.join(work, "oblique.mha")
    with open(p, "rb") as f:
        raw = f.read()
    head, _, body = raw.partition(b"ElementDataFile = LOCAL\n")
    head = head.replace(b"BinaryDataByteOrderMSB = False", b"BinaryDataByteOrderMSB = True").replace(b"ElementByteOrderMSB = False", b"ElementByteOrderMSB = True")
    swapped = np.frombuffer(body, dtype="<i2").astype(">i2").tobytes()
    p = os.path.join(work, "oblique_msb.mha")
    with open(p, "wb") as f:
        f.write(head + b"ElementDataFile = LOCAL\n" + swapped)
    out.append((p, "metaimage"))
    # pynrrd: spaces LPS and RAS with oblique directions, raw / gzip / ascii, big endian,
    # detached data.
    dirs = (rot * np.array([0.9, 1.1, 2.5])).T  # one row per axis
    for name, opts in [
        ("lps_raw.nrrd", {"encoding": "raw", "space": "left-posterior-superior"}),
        ("ras_gzip.nrrd", {"encoding": "gzip", "space": "right-anterior-superior"}),
        ("las_ascii.nrrd", {"encoding": "ascii", "space": "left-anterior-superior"}),
        ("lps_big.nrrd", {"encoding": "raw", "space": "left-posterior-superior", "endian": "big"}),
    ]:
        p = os.path.join(work, name)
        h = {"space directions": dirs, "space origin": np.array([5.5, -3.25, 12.0]), "kinds": ["domain"] * 3, **opts}
        nrrd.write(p, vol, h, index_order="F")
        out.append((p, "nrrd"))
    p = os.path.join(work, "detached.nhdr")
    nrrd.write(p, (vol.astype(np.float32) * 0.125), {"spacings": [0.5, 0.75, 3.0], "encoding": "raw"}, detached_header=True, index_order="F")
    out.append((p, "nrrd"))
    # pyvista: ImageData with origin, spacing and a direction, as .vti (binary, compressed:
    # pyvista's default; and ascii) and legacy .vtk (binary and ascii; legacy files keep no
    # direction, so that grid is axis-aligned).
    grid = pv.ImageData(dimensions=vol.shape, spacing=(0.6, 1.7, 2.2), origin=(-4.0, 7.5, 1.25))
    grid.point_data["density"] = (vol.astype(np.float32) * 0.01).flatten(order="F")
    for name, binary in [("legacy_binary.vtk", True), ("legacy_ascii.vtk", False)]:
        p = os.path.join(work, name)
        grid.save(p, binary=binary)
        out.append((p, "vtk"))
    oblique = grid.copy()
    oblique.direction_matrix = rot
    for name, binary in [("oblique.vti", True), ("oblique_ascii.vti", False)]:
        p = os.path.join(work, name)
        oblique.save(p, binary=binary)
        out.append((p, "vtk"))
    return out


# --- particles: points and every point array, as pyvista reads them --------------------------
def particle_fixtures(work):
    """Point sets as pyvista / VTK 9 write them (the way most users make a .vtk today):
    PolyData.save as legacy 5.1 (VERTICES with OFFSETS / CONNECTIVITY; the active scalars as
    SCALARS, normals, texture coordinates, colours as COLOR_SCALARS, every other array in a
    FIELD block; a dataset-level FIELD block before POINTS), binary and ASCII, with NaN and
    infinite values in positions and arrays; VTK's 4.2 writer; XML .vtp and .vtu; an
    UnstructuredGrid as legacy .vtk; a .vtp named .vtk. (path, reference path): VTK's own
    ASCII readers cannot read NaN ("Unrecognized keyword: nan"), so an ASCII file with NaN is
    compared with pyvista's reading of its binary twin; the values are multiples of 1/64,
    which ASCII's 6 significant digits hold exactly."""
    import pyvista as pv
    import vtk

    rng = np.random.default_rng(23)
    n = 57
    q = lambda a: np.round(a * 64) / 64  # below 1 in magnitude: exact in 6 significant digits
    pts = (np.round(rng.random((n, 3)) * [128, 32, 120]) / [64, 64, 4] - 1.0).astype(np.float32)

    def cloud(with_nan):
        p = pts.copy()
        h = q(rng.random(n) * 10 + 1) / 1000
        if with_nan:
            p[5, 0], p[9, 2], h[3] = np.nan, np.inf, np.nan
        pd = pv.PolyData(p)
        pd.point_data["mass"] = q(rng.random(n)).astype(np.float32)
        pd.point_data["h"] = h
        pd.point_data["velocity"] = q(np.clip(rng.normal(0, 0.5, (n, 3)), -0.98, 0.98)).astype(np.float32)
        pd.point_data["id"] = np.arange(n, dtype=np.int32)
        pd.point_data["particle age"] = np.round(rng.random(n) * 400) / 4
        pd.point_data["n"] = q(np.clip(rng.normal(0, 0.5, (n, 3)), -0.98, 0.98)).astype(np.float32)
        pd.point_data.active_normals_name = "n"
        pd.point_data["uv"] = q(rng.random((n, 2))).astype(np.float32)
        pd.point_data.active_texture_coordinates_name = "uv"
        pd.point_data["rgb"] = (rng.random((n, 3)) * 255).astype(np.uint8)
        pd.point_data.active_scalars_name = "mass"
        pd.field_data["time"] = np.array([1.5])
        pd.field_data["title"] = np.array([3, 4, 5], dtype=np.int16)
        return pd

    out = []

    def save(mesh, name, binary, reference=None):
        p = os.path.join(work, name)
        mesh.save(p, binary=binary)
        out.append((p, os.path.join(work, reference) if reference else p))

    clean, nan = cloud(False), cloud(True)
    for ext in ["vtk", "vtp"]:
        save(clean, f"pyvista_binary.{ext}", True)
        save(clean, f"pyvista_ascii.{ext}", False)
        save(nan, f"pyvista_nan_binary.{ext}", True)
        save(nan, f"pyvista_nan_ascii.{ext}", False, f"pyvista_nan_binary.{ext}")
    colours = clean.copy()
    colours.point_data.active_scalars_name = "rgb"
    save(colours, "colours_binary.vtk", True)
    save(colours, "colours_ascii.vtk", False)
    for ftype in ["binary", "ascii"]:
        p = os.path.join(work, f"vtk42_{ftype}.vtk")
        w = vtk.vtkPolyDataWriter()
        w.SetInputData(clean)
        w.SetFileName(p)
        w.SetFileVersion(42)
        w.SetFileTypeToBinary() if ftype == "binary" else w.SetFileTypeToASCII()
        w.Write()
        out.append((p, p))
    grid = pv.UnstructuredGrid({pv.CellType.VERTEX: np.arange(n).reshape(-1, 1)}, pts.astype(np.float64))
    grid.point_data["mass"] = clean.point_data["mass"]
    grid.point_data["h"] = clean.point_data["h"]
    save(grid, "ugrid.vtk", True)
    save(grid, "ugrid_ascii.vtk", False)
    save(grid, "ugrid.vtu", True)
    xml = os.path.join(work, "xml_named.vtk")
    with open(os.path.join(work, "pyvista_nan_binary.vtp"), "rb") as src, open(xml, "wb") as dst:
        dst.write(src.read())
    out.append((xml, os.path.join(work, "pyvista_nan_binary.vtp")))
    return out


def particle_reference(path):
    """Points (f64) and every point array (f64, one row per point) as pyvista reads them."""
    import pyvista as pv

    mesh = pv.read(path)
    pts = np.asarray(mesh.points, dtype=np.float64)
    arrays = {k: np.asarray(mesh.point_data[k], dtype=np.float64).reshape(len(pts), -1) for k in mesh.point_data.keys()}
    return pts, arrays


def same_values(a, b):
    """Equal where finite (exactly, as f32 where volterra writes f32), NaN and infinities in
    the same places."""
    if a.shape != b.shape:
        return False
    if not np.array_equal(np.isnan(a), np.isnan(b)):
        return False
    fin = np.isfinite(a) & np.isfinite(b)
    if not np.array_equal(a[~np.isnan(a) & ~fin], b[~np.isnan(b) & ~fin]):
        return False
    return np.array_equal(a[fin], b[fin]) or np.array_equal(a[fin].astype(np.float32), b[fin].astype(np.float32))


def compare_particles(path, reference_path, work):
    """`volterra convert FILE out.vtp`, read back by pyvista, against pyvista's reading of
    the original: (verdict, detail)."""
    try:
        ref = particle_reference(reference_path)
    except Exception as e:
        ref = None
        why = f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"
    out = os.path.join(work, "out.vtp")
    if os.path.exists(out):
        os.remove(out)
    r = subprocess.run([VOLTERRA, "convert", path, out], capture_output=True, text=True, timeout=120)
    if r.returncode != 0:
        err = r.stderr.strip().splitlines()
        if r.returncode == 101 or any("panicked" in line for line in err):
            return "wrong", "panicked: " + " ".join(err)[:300], ""
        reason = (err[-1] if err else f"exit {r.returncode}").removeprefix("error: ").replace(path, os.path.basename(path))
        return "refused", reason, justify(reason) if ref is not None else f"the reference cannot read it either ({why})"
    if ref is None:
        return "no reference", f"the reference cannot read it ({why}); volterra reads it", ""
    pts, arrays = particle_reference(out)
    if not same_values(ref[0], pts):
        return "wrong", f"points differ ({len(pts)} read, {len(ref[0])} in the reference)", ""
    if sorted(arrays) != sorted(ref[1]):
        return "wrong", f"point arrays {sorted(arrays)}, reference {sorted(ref[1])}", ""
    for k, v in ref[1].items():
        if not same_values(v, arrays[k]):
            return "wrong", f"point array '{k}' differs", ""
    return "equal", f"{len(pts)} points, arrays {', '.join(sorted(ref[1]))}", ""


# --- the comparison -------------------------------------------------------------------------
def volterra_convert(path, work):
    out = os.path.join(work, "out.nii")
    if os.path.exists(out):
        os.remove(out)
    try:
        r = subprocess.run([VOLTERRA, "convert", path, out], capture_output=True, text=True, timeout=120)
    except subprocess.TimeoutExpired:
        return "crash", "timed out after 120 s"
    err = r.stderr.strip().splitlines()
    if r.returncode != 0:
        if r.returncode == 101 or any("panicked" in line for line in err):
            return "crash", "panicked: " + " ".join(err)[:300]
        lines = [line for line in err if line.startswith("error:")]
        reason = lines[-1][len("error: "):] if lines else (err[-1] if err else f"exit {r.returncode}")
        # The table must not depend on where the files are: the path becomes the file's name.
        return "refused", reason.replace(path, os.path.basename(path)).replace(os.path.dirname(path) + os.sep, "")
    import nibabel as nib

    img = nib.load(out)
    data = np.asarray(img.get_fdata(dtype=np.float64))
    data = data.reshape(data.shape[:3] + (-1,)) if data.ndim > 3 else data
    return "ok", (data, img.affine)


def compare(ref, got, syntax):
    rv, ra = ref
    gv, ga = got
    if rv.ndim == 2:
        rv = rv[:, :, np.newaxis]
    if gv.ndim == 4 and gv.shape[3] == 1:
        gv = gv[..., 0]
    if rv.ndim == 4 and rv.shape[3] == 1:
        rv = rv[..., 0]
    if rv.shape != gv.shape:
        return "wrong", f"dims {list(gv.shape)}, reference {list(rv.shape)}"
    finite = np.isfinite(rv) & np.isfinite(gv)
    if not np.array_equal(np.isnan(rv), np.isnan(gv)):
        return "wrong", "NaN voxels differ"
    diff = np.abs(rv - gv)[finite]
    scale = max(np.abs(rv[finite]).max(initial=0.0), 1e-30)
    maxdiff = float(diff.max(initial=0.0))
    tol = float(LOSSY.get(syntax, 0))
    exact_tol = 1e-6 * scale  # volterra writes f32 where the values are real
    if maxdiff > max(tol, exact_tol):
        where = np.unravel_index(np.argmax(np.where(finite, np.abs(rv - gv), -1)), rv.shape)
        return "wrong", f"values differ by up to {maxdiff:.6g} (at {list(map(int, where))}: {gv[where]:.6g} vs {rv[where]:.6g})"
    note = f"max |Δ| {maxdiff:.3g} (lossy {syntax})" if tol and maxdiff > exact_tol else ""
    if ra is None:
        return "equal", ("values and dims; the file has no geometry to compare" + (", " + note if note else ""))
    if not np.allclose(ra, ga, atol=1e-3 * max(1.0, np.abs(ra).max()), rtol=0):
        return "wrong", f"affine {np.round(ga, 4).tolist()}, reference {np.round(ra, 4).tolist()}"
    return "equal", note


JUSTIFY = [
    ("unknown file type", "not a format volterra reads (NIfTI, DICOM, MetaImage, NRRD, VTK, GeoTIFF, PNG only)"),
    ("unsupported transfer syntax", "no decoder for this transfer syntax in dicom-rs"),
    ("not a scalar image", "a colour image that is not 8-bit RGB/YBR: volumes are scalar"),
    ("Analyze 7.5", "Analyze 7.5 (no NIfTI magic): its orientation is undefined, so no world geometry can be given"),
    ("is not a scalar layout", "a bit depth volterra does not store as a scalar volume"),
    ("truncated", "the file is truncated (pydicom reads what is there; volterra refuses partial data)"),
    ("missing or malformed", "a required image element is missing"),
    ("holds no image", "not an image: the data set has no Rows, Columns or pixel data"),
    ("datatype", "a NIfTI data type volterra does not keep (complex, RGB, 128-bit)"),
    ("several multi-frame", "a series of multi-frame files"),
    ("does not parse", "the data set does not parse"),
    ("image file", "the .img half of the pair is not shipped"),
    ("not a DICOM file", "not a DICOM data set"),
]


def justify(reason):
    for key, why in JUSTIFY:
        if key.lower() in reason.lower():
            return why
    return "UNJUSTIFIED — review"


def main():
    import nibabel
    import pydicom

    cases = []
    pyd = os.path.join(os.path.dirname(pydicom.__file__), "data", "test_files")
    for root, _, files in os.walk(pyd):
        for f in sorted(files):
            cases.append(("pydicom", os.path.join(root, f), "dicom"))
    nib_dir = os.path.join(os.path.dirname(nibabel.__file__), "tests", "data")
    for f in sorted(os.listdir(nib_dir)):
        p = os.path.join(nib_dir, f)
        if os.path.isfile(p) and not f.endswith((".img", ".img.gz", ".py", ".pyc", ".txt", ".json", ".rst", ".m", ".npy", ".npz")):
            cases.append(("nibabel", p, "dicom" if f.endswith(".dcm") else "nifti"))
    if SHARED:
        vol = os.path.join(SHARED, "volumes")
        for root, dirs, files in os.walk(vol):
            dirs.sort()
            dcm = [f for f in files if f.endswith(".dcm")]
            if len(dcm) > 2 and len(series_uids(root, dcm)) == 1:
                cases.append(("shared", root, "dicom-series"))  # one series: read as the directory
                continue
            for f in sorted(files):
                p = os.path.join(root, f)
                if f.endswith((".nii", ".nii.gz")):
                    cases.append(("shared", p, "nifti"))
                elif f.endswith(".dcm"):
                    cases.append(("shared", p, "dicom"))
                elif f.endswith((".vti", ".vtk")):
                    cases.append(("shared", p, "vtk"))
                elif f.endswith((".mha", ".mhd")):
                    cases.append(("shared", p, "metaimage"))
                elif f.endswith((".nrrd", ".nhdr")):
                    cases.append(("shared", p, "nrrd"))
    particle_cases = []
    if SHARED:
        pdir = os.path.join(SHARED, "particles")
        for f in sorted(os.listdir(pdir)) if os.path.isdir(pdir) else []:
            if f.endswith((".vtk", ".vtp", ".vtu")):
                particle_cases.append(("shared particles", os.path.join(pdir, f), os.path.join(pdir, f), pdir))
    rows = []
    with tempfile.TemporaryDirectory() as work, tempfile.TemporaryDirectory() as written:
        particle_cases += [("written particles", p, ref, written) for p, ref in particle_fixtures(written)]
        for suite, path, reference_path, base in particle_cases:
            verdict, detail, why = compare_particles(path, reference_path, work)
            rows.append((suite, os.path.relpath(path, base), verdict, detail, why))
        cases += [("written", p, kind) for p, kind in write_fixtures(written)]
        readers = {"dicom-series": series_reference, "dicom": dicom_reference, "nifti": nifti_reference,
                   "vtk": vtk_reference, "metaimage": metaimage_reference, "nrrd": nrrd_reference}
        for suite, path, kind in cases:
            name = os.path.relpath(path, {"pydicom": pyd, "nibabel": nib_dir, "written": written}.get(suite, SHARED or "/"))
            try:
                ref = readers[kind](path)
            except Exception as e:  # the reference cannot read it
                text = str(e).splitlines()[0] if str(e) else ""
                ref = ("error", f"{type(e).__name__}: {text}".replace(path, os.path.basename(path)).replace(os.path.dirname(path) + os.sep, "")[:200])
            if ref is None:
                continue  # no pixel data: not an image (reports, plans, structure sets)
            got = volterra_convert(path, work)
            if isinstance(ref[0], str) and ref[0] == "other format":
                # nibabel reads it as an image of a format volterra does not read.
                if got[0] == "refused":
                    rows.append((suite, name, "refused", got[1], justify(got[1])))
                else:
                    rows.append((suite, name, "wrong" if got[0] == "crash" else "no reference", got[1] if got[0] == "crash" else f"nibabel reads it as {ref[1]}", ""))
                continue
            if isinstance(ref[0], str):
                if got[0] in ("refused", "crash"):
                    verdict = ("wrong", got[1]) if got[0] == "crash" else ("refused", got[1])
                    why = f"the reference cannot read it either ({ref[1]})"
                    rows.append((suite, name, verdict[0], verdict[1], why if verdict[0] == "refused" else ""))
                else:
                    rows.append((suite, name, "no reference", f"the reference cannot read it ({ref[1]}); volterra reads it", ""))
                continue
            if got[0] == "crash":
                rows.append((suite, name, "wrong", got[1], ""))
            elif got[0] == "refused":
                rows.append((suite, name, "refused", got[1], justify(got[1])))
            else:
                verdict, detail = compare((ref[0], ref[1]), got[1], ref[2])
                rows.append((suite, name, verdict, detail, ""))
    write_table(rows)
    wrong = [r for r in rows if r[2] == "wrong"]
    unjustified = [r for r in rows if r[2] == "refused" and r[4].startswith("UNJUSTIFIED")]
    for r in wrong + unjustified:
        print(f"{r[2]}: {r[0]} {r[1]}: {r[3]} {r[4]}")
    counts = {}
    for r in rows:
        counts.setdefault(r[0], {}).setdefault(r[2], 0)
        counts[r[0]][r[2]] += 1
    print("differential:", "; ".join(f"{s}: " + ", ".join(f"{v} {k}" for k, v in sorted(c.items())) for s, c in counts.items()))
    sys.exit(1 if wrong or unjustified else 0)


def series_uids(root, files):
    import pydicom

    return {str(pydicom.dcmread(os.path.join(root, f), stop_before_pixels=True, force=True).get("SeriesInstanceUID")) for f in files}


def series_reference(path):
    """A directory of single-frame files: each read by pydicom, stacked along the normal."""
    vals, positions, aff = [], [], None
    files = sorted(os.listdir(path))
    refs = [dicom_reference(os.path.join(path, f)) for f in files]
    refs = [r for r in refs if r is not None]
    for v, a, ts in refs:
        vals.append(v[:, :, 0])
        positions.append(a[:3, 3] if a is not None else None)
        aff = a
    if aff is None or any(p is None for p in positions):
        raise ValueError("slices without positions")
    n = np.cross(aff[:3, 0], aff[:3, 1])
    n /= np.linalg.norm(n)
    order = np.argsort(np.array(positions) @ n, kind="stable")
    stack = np.stack([vals[i] for i in order], axis=2)
    p = [positions[i] for i in order]
    affine = aff.copy()
    affine[:3, 3] = p[0]
    affine[:3, 2] = (p[-1] - p[0]) / max(len(p) - 1, 1)
    return stack, affine, refs[0][2]


def write_table(rows):
    counts = {}
    for r in rows:
        counts.setdefault(r[0], {"equal": 0, "refused": 0, "wrong": 0, "no reference": 0})[r[2]] += 1
    with open(OUT + ".tmp", "w", encoding="utf-8") as f:
        f.write("# Differential test: volterra against pydicom, nibabel, pyvista/VTK, SimpleITK and pynrrd\n\n")
        f.write("Regenerated by `tests/differential.rs` (tests/reference/differential.py): every image-bearing\n")
        f.write("file of pydicom's and nibabel's own test data (from the reference venv), every DICOM, NIfTI,\n")
        f.write("VTK image, MetaImage and NRRD file in ../shared/data, and files SimpleITK, pynrrd and pyvista\n")
        f.write("write at test time (suite `written`: oblique directions, odd spacings, every encoding),\n")
        f.write("converted with `volterra convert FILE out.nii` and compared with\n")
        f.write("the reference library's reading of the original: values after rescale, dims, and the\n")
        f.write("voxel-to-world affine (RAS+ mm). Files without pixel data (reports, plans, structure sets) are\n")
        f.write("left out. Lossy transfer syntaxes allow 2 grey levels between decoders.\n\n")
        f.write("Particles (suites `shared particles` and `written particles`: every point file in\n")
        f.write("../shared/data, and files pyvista and VTK write at test time: legacy 5.1 and 4.2, binary\n")
        f.write("and ASCII, NaN and infinite values, XML .vtp/.vtu, a .vtp named .vtk) are converted with\n")
        f.write("`volterra convert FILE out.vtp`, read back by pyvista and compared with pyvista's reading\n")
        f.write("of the original: every point, every point array by name, NaN and infinities in place.\n\n")
        f.write("| suite | equal | refused | wrong | no reference |\n|---|---|---|---|---|\n")
        for s, c in counts.items():
            f.write(f"| {s} | {c['equal']} | {c['refused']} | {c['wrong']} | {c['no reference']} |\n")
        f.write("\n| suite | file | result | detail | why refused |\n|---|---|---|---|---|\n")
        for suite, name, verdict, detail, why in rows:
            cell = lambda t: t.replace("|", "\\|").replace("\n", " ")
            f.write(f"| {suite} | `{name}` | {verdict} | {cell(detail)} | {cell(why)} |\n")
    os.replace(OUT + ".tmp", OUT)


if __name__ == "__main__":
    main()
