"""volterra: read clinical volumes, DEMs and particle files into numpy, build scenes
from them and render them.

    >>> import volterra
    >>> ct = volterra.read("ct.nii.gz")
    >>> ct.array.shape, ct.affine          # as nibabel's get_fdata() and affine
    >>> dem = volterra.read("dem.tif")
    >>> dem.array, dem.transform, dem.crs  # as GDAL's ReadAsArray and geotransform
    >>> scene = volterra.Scene(width=512, height=512)
    >>> scene.add_volume(ct, preset="CT-AAA", shading=True)
    >>> scene.camera.azimuth(30)
    >>> frame = scene.render()             # shows inline in Jupyter
    >>> frame.save("ct.exr"); scene.to_toml("ct.toml")  # `volterra render ct.toml` draws the same

Every reader of the `volterra` command line, with its checks: a malformed file raises
FormatError (a ValueError), an unreadable one ReadError (an OSError), one larger than
`max_memory` MemoryLimitError (a MemoryError), a scene that does not check SceneError (a
ValueError), each with the command's one-line message.
"""

from ._volterra import (  # noqa: F401
    AmbiguousError,
    Camera,
    FormatError,
    Frame,
    Frames,
    Heightfield,
    MemoryLimitError,
    Particles,
    ReadError,
    Scene,
    SceneError,
    UnsupportedError,
    Volume,
    compare,
    list_series,
    read,
)
from . import dem  # noqa: F401,E402

__all__ = [
    "read",
    "list_series",
    "Volume",
    "Heightfield",
    "Particles",
    "Scene",
    "Camera",
    "Frame",
    "Frames",
    "FormatError",
    "UnsupportedError",
    "AmbiguousError",
    "ReadError",
    "MemoryLimitError",
    "SceneError",
    "to_nibabel",
    "from_nibabel",
    "compare",
    "dem",
    "to_pyvista",
]


def to_nibabel(volume):
    """The volume as a nibabel Nifti1Image: its real values and affine (RAS+ mm)."""
    import nibabel

    return nibabel.Nifti1Image(volume.array, volume.affine)


def from_nibabel(img):
    """A Volume from a nibabel image: its stored values (not scaled, in their own type)
    with the header's slope and intercept, and its affine."""
    import nibabel
    import numpy as np

    dataobj = img.dataobj
    if nibabel.is_proxy(dataobj):
        raw = dataobj.get_unscaled()
        slope, inter = dataobj.slope, dataobj.inter
    else:
        raw, slope, inter = np.asanyarray(dataobj), 1.0, 0.0
    # nibabel reads a slope of 0 or NaN as none (NIfTI's rule).
    if slope is None or not np.isfinite(slope) or slope == 0:
        slope, inter = 1.0, 0.0
    if inter is None or not np.isfinite(inter):
        inter = 0.0
    if raw.ndim != 3:
        raise ValueError(f"from_nibabel: a {raw.ndim}-D image; a Volume is 3-D (choose one with img.slicer[..., k])")
    return Volume(raw, img.affine, slope=float(slope), intercept=float(inter))


def to_pyvista(data):
    """A Volume as pyvista.ImageData (origin, spacing and direction from its affine, the
    values as point data "values"); Particles as pyvista.PolyData with their arrays."""
    import numpy as np
    import pyvista

    if isinstance(data, Volume):
        affine = np.asarray(data.affine)
        spacing = np.asarray(data.spacing)
        grid = pyvista.ImageData(dimensions=data.array.shape, spacing=spacing, origin=affine[:3, 3])
        grid.direction_matrix = affine[:3, :3] / spacing
        grid.point_data["values"] = np.ravel(data.array, order="F")
        return grid
    if isinstance(data, Particles):
        cloud = pyvista.PolyData(np.asarray(data.positions))
        for name, values in data.arrays.items():
            cloud.point_data[name] = values
        return cloud
    raise TypeError(f"to_pyvista takes a Volume or Particles, not {type(data).__name__}")
