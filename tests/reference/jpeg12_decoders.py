"""12-bit lossy JPEG (DICOM JPEG Extended) decoded three ways, compared with volterra's.

usage: jpeg12_decoders.py FILE.dcm VOLTERRA_OUTPUT.nii

Prints JSON: for pydicom's own decode (pylibjpeg's libjpeg, Thomas Richter's) and for
imagecodecs' jpeg8_decode (libjpeg-turbo 3, built independently of volterra's), how many
samples differ from volterra's read of the same file (written to NIfTI by `volterra
convert`) and by how much at most. Lossy JPEG leaves each decoder its own IDCT rounding, so
two libjpeg-turbo builds agree exactly where libjpeg may differ by a grey level.
"""
import json
import sys

import imagecodecs
import nibabel as nib
import numpy as np
import pydicom
from pydicom.encaps import generate_frames

dcm, nii = sys.argv[1], sys.argv[2]
ds = pydicom.dcmread(dcm)
frames = int(getattr(ds, "NumberOfFrames", 1) or 1)
by_pydicom = ds.pixel_array.astype(np.int64).reshape(frames, ds.Rows, ds.Columns)
by_turbo = np.stack([imagecodecs.jpeg8_decode(f) for f in generate_frames(ds.PixelData, number_of_frames=frames)]).astype(np.int64)
# volterra's NIfTI holds voxel [i, j, k] = column, row, frame (nibabel's order).
ours = np.asanyarray(nib.load(nii).dataobj).astype(np.int64)
ours = ours.reshape(ds.Columns, ds.Rows, frames).transpose(2, 1, 0)


def against(ref):
    d = np.abs(ref - ours)
    return {"differing": int((d != 0).sum()), "max_abs": int(d.max()), "samples": int(d.size)}


print(json.dumps({"pydicom": against(by_pydicom), "libjpeg_turbo": against(by_turbo), "imagecodecs": imagecodecs.__version__}))
