"""volterra: read clinical volumes, DEMs and particle files into numpy.

    >>> import volterra
    >>> ct = volterra.read("ct.nii.gz")
    >>> ct.array.shape, ct.affine          # as nibabel's get_fdata() and affine
    >>> dem = volterra.read("dem.tif")
    >>> dem.array, dem.transform, dem.crs  # as GDAL's ReadAsArray and geotransform

Every reader of the `volterra` command line, with its checks: a malformed file raises
FormatError (a ValueError), an unreadable one ReadError (an OSError), one larger than
`max_memory` MemoryLimitError (a MemoryError), each with the command's one-line message.
"""

from ._volterra import (  # noqa: F401
    AmbiguousError,
    FormatError,
    Heightfield,
    MemoryLimitError,
    Particles,
    ReadError,
    UnsupportedError,
    Volume,
    list_series,
    read,
)

__all__ = [
    "read",
    "list_series",
    "Volume",
    "Heightfield",
    "Particles",
    "FormatError",
    "UnsupportedError",
    "AmbiguousError",
    "ReadError",
    "MemoryLimitError",
    "to_nibabel",
    "to_pyvista",
]


def to_nibabel(volume):
    """The volume as a nibabel Nifti1Image: its real values and affine (RAS+ mm)."""
    import nibabel

    return nibabel.Nifti1Image(volume.array, volume.affine)


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
