#!/usr/bin/env python3
"""Times the reference readers on the files `volterra bench formats` prepared, doing the
same work volterra does: a DICOM series read file by file with pydicom, sorted by
ImagePositionPatient along the slice normal and stacked with numpy; a gzipped NIfTI read
with nibabel into its stored type.

Usage: bench_readers.py SERIES_DIR NIFTI_PATH RUNS   → one JSON object on stdout
"""
import json
import os
import statistics
import sys
import time

import nibabel as nib
import numpy as np
import pydicom


def load_series(d):
    dss = [pydicom.dcmread(os.path.join(d, f)) for f in os.listdir(d)]
    iop = np.array([float(x) for x in dss[0].ImageOrientationPatient])
    n = np.cross(iop[:3], iop[3:])
    dss.sort(key=lambda ds: float(np.dot(n, [float(x) for x in ds.ImagePositionPatient])))
    return np.stack([ds.pixel_array for ds in dss])


def load_nifti(p):
    return np.asanyarray(nib.load(p).dataobj)


def timed(f, arg, runs):
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        out = f(arg)
        times.append(time.perf_counter() - t)
        del out
    return times


series, nifti, runs = sys.argv[1], sys.argv[2], int(sys.argv[3])
print(json.dumps({
    "pydicom": timed(load_series, series, runs),
    "nibabel": timed(load_nifti, nifti, runs),
    "versions": {"pydicom": pydicom.__version__, "nibabel": nib.__version__, "numpy": np.__version__},
}))
