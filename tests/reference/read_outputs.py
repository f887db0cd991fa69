#!/usr/bin/env python3
"""Reads files that volterra wrote with the reference libraries and prints what they see
as JSON, so a Rust test can check our writers against independent readers.

Usage: read_outputs.py KIND PATH   (KIND: nifti | nrrd | geotiff | vtp)
"""
import json
import sys

import numpy as np

kind, path = sys.argv[1], sys.argv[2]
if kind == "nifti":
    import nibabel as nib
    img = nib.load(path)
    data = np.asanyarray(img.dataobj.get_unscaled())
    slope, inter = img.dataobj.slope, img.dataobj.inter
    out = {
        "shape": list(data.shape),
        "dtype": str(data.dtype.newbyteorder("=")),
        "affine": img.affine.tolist(),
        "qform_code": int(img.header["qform_code"]),
        "sform_code": int(img.header["sform_code"]),
        "qform": img.header.get_qform().tolist(),
        "slope": None if slope is None else float(slope),
        "inter": None if inter is None else float(inter),
        "values": data.transpose(2, 1, 0).ravel().astype(np.float64).tolist(),
    }
elif kind == "nrrd":
    import nrrd
    data, h = nrrd.read(path, index_order="F")
    out = {
        "shape": list(data.shape),
        "dtype": str(data.dtype.newbyteorder("=")),
        "space": h.get("space"),
        "directions": np.asarray(h["space directions"], dtype=np.float64).tolist(),
        "origin": np.asarray(h["space origin"], dtype=np.float64).tolist(),
        "values": data.ravel(order="F").astype(np.float64).tolist(),
    }
elif kind == "geotiff":
    import tifffile
    with tifffile.TiffFile(path) as tif:
        page = tif.pages[0]
        geo = page.geotiff_tags or {}
        data = page.asarray()
        out = {
            "shape": list(data.shape),
            "dtype": str(data.dtype),
            "scale": list(page.tags["ModelPixelScaleTag"].value),
            "tiepoint": list(page.tags["ModelTiepointTag"].value),
            "epsg": int(geo.get("ProjectedCSTypeGeoKey", geo.get("GeographicTypeGeoKey", 0)) or 0),
            "nodata": page.tags["GDAL_NODATA"].value.strip("\x00 ") if "GDAL_NODATA" in page.tags else None,
            "values": [None if v != v else v for v in data.astype(np.float64).ravel().tolist()],
        }
elif kind == "vtp":
    import pyvista as pv
    m = pv.read(path)
    out = {
        "count": int(m.n_points),
        "n_verts": int(m.n_verts),
        "positions": np.asarray(m.points, dtype=np.float64).ravel().tolist(),
        "arrays": {k: np.asarray(m.point_data[k], dtype=np.float64).ravel().tolist() for k in m.point_data.keys()},
    }
else:
    sys.exit(f"unknown kind {kind}")
print(json.dumps(out, allow_nan=False))
