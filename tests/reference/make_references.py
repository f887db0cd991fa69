#!/usr/bin/env python3
"""Reads every file in ../shared/data with the reference readers (nibabel, pydicom,
tifffile, imagecodecs, pyvista) and records what they see into small JSON files that the
Rust tests compare against (tests/formats_reference.rs).

Usage: make_references.py SHARED_DATA_DIR OUT_DIR

Everything recorded is computed here, independently of volterra: shapes, affines in RAS+ mm
(DICOM's LPS converted here), stored-value checksums and sampled values, rescale, NoData,
CRS, particle counts, arrays and positions. The checksum weights and sample positions are
defined once below and mirrored in the Rust test.
"""
import json
import os
import sys

import numpy as np

N_SAMPLES = 64


def weights(n):
    """w(i) = (i * 7919) % 1009 — a deterministic weighting that catches permutations."""
    return ((np.arange(n, dtype=np.int64) * 7919) % 1009).astype(np.float64)


def sample_index(k, n):
    return (k * 104729 + 17) % n


def fingerprint(flat):
    """Sum, weighted sum, and sampled values of a flat array (as float64)."""
    v = np.asarray(flat).astype(np.float64).ravel()
    n = v.size
    finite = np.isfinite(v)
    vv = np.where(finite, v, 0.0)
    return {
        "count": int(n),
        "sum": float(vv.sum()),
        "wsum": float((vv * weights(n)).sum()),
        "samples": [[int(sample_index(k, n)), float(v[sample_index(k, n)])] for k in range(N_SAMPLES)] if n else [],
    }


def volume_record(stored_xyz, affine, slope, inter, dtype, extra=None):
    """stored_xyz is indexed [i, j, k] (i fastest in volterra's layout)."""
    flat = np.asarray(stored_xyz).transpose(2, 1, 0).ravel()  # k slowest, i fastest
    real = flat.astype(np.float64) * slope + inter
    rec = {
        "kind": "volume",
        "dims": [int(d) for d in stored_xyz.shape],
        "affine": [[float(x) for x in row] for row in np.asarray(affine)],
        "dtype": dtype,
        "rescale": {"slope": float(slope), "intercept": float(inter)},
        "min": float(np.nanmin(real)),
        "max": float(np.nanmax(real)),
        "stored": fingerprint(flat),
    }
    if extra:
        rec.update(extra)
    return rec


NP_TO_DTYPE = {
    np.dtype("uint8"): "u8", np.dtype("int8"): "i8", np.dtype("uint16"): "u16", np.dtype("int16"): "i16",
    np.dtype("uint32"): "u32", np.dtype("int32"): "i32", np.dtype("float32"): "f32", np.dtype("float64"): "f64",
}


def nifti_record(path):
    import nibabel as nib
    img = nib.load(path)
    hdr = img.header
    data = np.asanyarray(img.dataobj.get_unscaled())
    count = 1
    if data.ndim > 3:
        count = int(np.prod(data.shape[3:]))
        data = data.reshape(data.shape[:3] + (-1,), order="F")[..., 0]
    slope, inter = img.dataobj.slope, img.dataobj.inter
    if slope is None or not np.isfinite(slope) or slope == 0:
        slope, inter = 1.0, 0.0
    dt = NP_TO_DTYPE[np.dtype(hdr.get_data_dtype()).newbyteorder("=")]
    return volume_record(data, img.affine, slope, inter if np.isfinite(inter) else 0.0, dt, {"volume_count": count})


def lps_to_ras(m):
    m = np.array(m, dtype=np.float64)
    m[0, :] *= -1
    m[1, :] *= -1
    return m


def dicom_dtype(ds):
    signed = int(getattr(ds, "PixelRepresentation", 0)) == 1
    bits = int(ds.BitsAllocated)
    if int(getattr(ds, "SamplesPerPixel", 1)) == 3:
        return "u8"
    return {(8, False): "u8", (8, True): "i8", (16, False): "u16", (16, True): "i16", (32, False): "u32", (32, True): "i32"}[(bits, signed)]


def dicom_rescale(ds):
    slope = float(getattr(ds, "RescaleSlope", 1) or 1)
    inter = float(getattr(ds, "RescaleIntercept", 0) or 0)
    if getattr(ds, "Modality", "") == "RTDOSE" and "DoseGridScaling" in ds:
        slope = float(ds.DoseGridScaling)
    return slope, inter


def dicom_pixels(ds):
    arr = ds.pixel_array
    if int(getattr(ds, "SamplesPerPixel", 1)) == 3:
        # pydicom 3's pixel_array already converts YBR to RGB.
        arr = np.floor(0.299 * arr[..., 0] + 0.587 * arr[..., 1] + 0.114 * arr[..., 2] + 0.5).astype(np.uint8)
    frames = int(getattr(ds, "NumberOfFrames", 1) or 1)
    if frames == 1 and arr.ndim == 2:
        arr = arr[np.newaxis]
    return arr  # (frames, rows, cols)


def dicom_file_record(path):
    import pydicom
    ds = pydicom.dcmread(path)
    arr = dicom_pixels(ds)
    frames = arr.shape[0]
    iop = [float(x) for x in getattr(ds, "ImageOrientationPatient", [1, 0, 0, 0, 1, 0])]
    row, col = np.array(iop[:3]), np.array(iop[3:])
    normal = np.cross(row, col)
    ps = [float(x) for x in getattr(ds, "PixelSpacing", [1, 1])]
    ipp = np.array([float(x) for x in getattr(ds, "ImagePositionPatient", [0, 0, 0])])
    step = float(getattr(ds, "SpacingBetweenSlices", 0) or getattr(ds, "SliceThickness", 0) or 1)
    order = np.arange(frames)
    slice_vec = normal * step
    if frames > 1 and "GridFrameOffsetVector" in ds:
        offs = np.array([float(x) for x in ds.GridFrameOffsetVector])
        order = np.argsort(offs, kind="stable")
        offs = offs[order]
        ipp = ipp + offs[0] * normal
        slice_vec = normal * (offs[-1] - offs[0]) / (frames - 1)
    m = np.eye(4)
    m[:3, 0] = row * ps[1]
    m[:3, 1] = col * ps[0]
    m[:3, 2] = slice_vec
    m[:3, 3] = ipp
    stored = arr[order].transpose(2, 1, 0)  # (cols, rows, frames) = (i, j, k)
    slope, inter = dicom_rescale(ds)
    return volume_record(stored, lps_to_ras(m), slope, inter, dicom_dtype(ds), {"modality": str(getattr(ds, "Modality", ""))})


def dicom_series_record(directory):
    import pydicom
    files = [os.path.join(directory, f) for f in sorted(os.listdir(directory))]
    dss = [pydicom.dcmread(f) for f in files]
    iop = [float(x) for x in dss[0].ImageOrientationPatient]
    row, col = np.array(iop[:3]), np.array(iop[3:])
    normal = np.cross(row, col)
    dss.sort(key=lambda d: float(np.dot(normal, [float(x) for x in d.ImagePositionPatient])))
    pos = np.array([[float(x) for x in d.ImagePositionPatient] for d in dss])
    n = len(dss)
    ps = [float(x) for x in dss[0].PixelSpacing]
    m = np.eye(4)
    m[:3, 0] = row * ps[1]
    m[:3, 1] = col * ps[0]
    m[:3, 2] = (pos[-1] - pos[0]) / (n - 1) if n > 1 else normal * float(dss[0].SliceThickness)
    m[:3, 3] = pos[0]
    stack = np.stack([d.pixel_array for d in dss])  # (k, rows, cols)
    slope, inter = dicom_rescale(dss[0])
    return volume_record(stack.transpose(2, 1, 0), lps_to_ras(m), slope, inter, dicom_dtype(dss[0]),
                         {"modality": str(getattr(dss[0], "Modality", "")), "files": n})


def geotiff_record(path):
    import tifffile
    with tifffile.TiffFile(path) as tif:
        page = tif.pages[0]
        data = page.asarray()
        geo = tif.pages[0].geotiff_tags or {}
        tags = page.tags
        scale = list(tags["ModelPixelScaleTag"].value)
        tie = list(tags["ModelTiepointTag"].value)
        nodata = tags["GDAL_NODATA"].value if "GDAL_NODATA" in tags else None
    nodata = float(nodata.strip("\x00 ")) if nodata is not None else None
    raster_point = int(geo.get("GTRasterTypeGeoKey", 1)) == 2
    x0, y0 = tie[3] - tie[0] * scale[0], tie[4] + tie[1] * scale[1]
    origin = [x0, y0] if raster_point else [x0 + 0.5 * scale[0], y0 - 0.5 * scale[1]]
    model = int(geo.get("GTModelTypeGeoKey", 0))
    epsg = geo.get("GeographicTypeGeoKey") if model == 2 else geo.get("ProjectedCSTypeGeoKey", geo.get("GeographicTypeGeoKey"))
    epsg = int(epsg) if epsg is not None else None
    vals = data.astype(np.float64)
    mask = np.isnan(vals) | ((vals == nodata) if nodata is not None else False)
    elev = np.where(mask, np.nan, vals).ravel()
    return {
        "kind": "heightfield",
        "dims": [int(data.shape[1]), int(data.shape[0])],
        "cell_size_native": [float(scale[0]), float(scale[1])],
        "origin": [float(o) for o in origin],
        "epsg": epsg,
        "geographic": model == 2,
        "nodata_value": nodata,
        "nodata_count": int(mask.sum()),
        "min": float(np.nanmin(elev)),
        "max": float(np.nanmax(elev)),
        "elevation": fingerprint(elev),
    }


def png_record(path, vertical_scale, cell_size):
    import imagecodecs
    with open(path, "rb") as f:
        img = imagecodecs.png_decode(f.read())
    if img.ndim == 3:
        img = img[..., 0]
    elev = img.astype(np.float64) * vertical_scale
    return {
        "kind": "heightfield",
        "dims": [int(img.shape[1]), int(img.shape[0])],
        "vertical_scale": vertical_scale,
        "cell_size": cell_size,
        "min": float(elev.min()),
        "max": float(elev.max()),
        "elevation": fingerprint(elev.astype(np.float32).ravel()),
    }


def texture_record(path):
    import imagecodecs
    with open(path, "rb") as f:
        img = imagecodecs.png_decode(f.read())
    return {"kind": "texture", "dims": [int(img.shape[1]), int(img.shape[0])], "rgb": fingerprint(img[..., :3].ravel())}


def particles_record(path):
    import pyvista as pv
    mesh = pv.read(path)
    pts = np.asarray(mesh.points, dtype=np.float64)
    arrays = {}
    for name in mesh.point_data.keys():
        a = np.asarray(mesh.point_data[name])
        comps = 1 if a.ndim == 1 else int(a.shape[1])
        arrays[name] = {"components": comps, "values": fingerprint(a.astype(np.float64).ravel())}
    return {
        "kind": "particles",
        "count": int(mesh.n_points),
        "arrays": arrays,
        "bounds": [[float(x) for x in pts.min(axis=0)], [float(x) for x in pts.max(axis=0)]] if len(pts) else None,
        "positions": fingerprint(pts.ravel()),
    }


# (relative path under shared/data, reference key, reader)
CASES = [
    ("volumes/aneurism/aneurism.nii.gz", nifti_record),
    ("volumes/angio/CT_AVM.nii.gz", nifti_record),
    ("volumes/mr/mni_icbm152_t1_tal_nlin_sym_09a_converted.nii.gz", nifti_record),
    ("volumes/mr/nibabel_anatomical.nii", nifti_record),
    ("volumes/mr/nibabel_example4d.nii.gz", nifti_record),
    ("volumes/pet/FDOPA_fluorodopa_hc12_gomez.nii", nifti_record),
    ("volumes/aneurism/dicom_ct", dicom_series_record),
    ("volumes/dicom_real/mr_scout_cptac_sar_3slices", dicom_series_record),
    ("volumes/dicom_real/mr_t1_vestibular_schwannoma_20slices", dicom_series_record),
    ("volumes/dicom_real/pydicom/693_UNCI.dcm", dicom_file_record),
    ("volumes/dicom_real/pydicom/CT_small.dcm", dicom_file_record),
    ("volumes/dicom_real/pydicom/JPEG-LL.dcm", dicom_file_record),
    ("volumes/dicom_real/pydicom/JPGExtended.dcm", dicom_file_record),
    ("volumes/dicom_real/pydicom/MR_small.dcm", dicom_file_record),
    ("volumes/dicom_real/pydicom/MR_small_RLE.dcm", dicom_file_record),
    ("volumes/dicom_real/pydicom/MR_small_bigendian.dcm", dicom_file_record),
    ("volumes/dicom_real/pydicom/MR_small_implicit.dcm", dicom_file_record),
    ("volumes/dicom_real/pydicom/MR_small_jp2klossless.dcm", dicom_file_record),
    ("volumes/dicom_real/pydicom/MR_small_jpeg_ls_lossless.dcm", dicom_file_record),
    ("volumes/dicom_real/pydicom/SC_rgb_jpeg_dcmtk.dcm", dicom_file_record),
    ("volumes/dicom_real/pydicom/emri_small.dcm", dicom_file_record),
    ("volumes/dicom_real/pydicom/image_dfl.dcm", dicom_file_record),
    ("volumes/dicom_real/pydicom/rtdose.dcm", dicom_file_record),
    ("terrain/pysheds_dem.tif", geotiff_record),
    ("terrain/ps_height_1k.png", lambda p: png_record(p, 0.1, 160.0)),
    ("terrain/ps_texture_1k.png", texture_record),
    ("particles/smoke_plume_110k.vtk", particles_record),
    ("particles/smoke_plume_110k.vtp", particles_record),
    ("particles/stars_hyg.vtp", particles_record),
]


def main():
    data_dir, out_dir = sys.argv[1], sys.argv[2]
    os.makedirs(out_dir, exist_ok=True)
    out = {}
    for rel, reader in CASES:
        try:
            out[rel] = reader(os.path.join(data_dir, rel))
        except Exception as e:  # recorded so the Rust test knows the reference could not read it
            out[rel] = {"kind": "error", "error": f"{type(e).__name__}: {e}"}
        print(f"{rel}: {out[rel]['kind']}", file=sys.stderr)
    with open(os.path.join(out_dir, "shared_data.json"), "w") as f:
        json.dump(out, f, indent=1, sort_keys=True)
        f.write("\n")


if __name__ == "__main__":
    main()
