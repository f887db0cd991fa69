"""DEM products as `volterra dem` (and gdaldem, gdal_contour) computes them, in memory.

Each function takes the DEM as a path (a GeoTIFF or PNG heightmap, read whole), a
`Heightfield` from `volterra.read`, or an array of elevations (rows from the north, NaN for
NoData) with GDAL's geotransform in metres (``transform``; ``epsg`` its projected CRS).

    >>> import volterra.dem
    >>> shade = volterra.dem.hillshade("dem.tif", azimuth=300)       # uint8, 0 = NoData
    >>> slope = volterra.dem.slope(z, (x0, 30, 0, y0, 0, -30))       # float32 degrees, NaN = NoData
    >>> rgb = volterra.dem.color_relief(dem, "0 0 0 255\\n1000 255 255 255")
    >>> for level, xy in volterra.dem.contours(dem, interval=50): ...

The values equal those of the files `volterra dem` writes (read back with `volterra.read`,
which gives their NoData cells as NaN); gdaldem's options keep gdaldem's names and defaults.
"""

from os import PathLike
from pathlib import Path
from typing import List, Optional, Sequence, Tuple, Union

import numpy as np

from . import _volterra

__all__ = ["hillshade", "slope", "aspect", "tri", "tpi", "roughness", "color_relief", "contours"]

_Dem = Union[str, PathLike, np.ndarray, "_volterra.Heightfield"]


def _product(product, dem, transform, **options):
    return _volterra.dem_product(dem, product, transform, **options)


def hillshade(
    dem: _Dem,
    transform: Optional[Sequence[float]] = None,
    *,
    epsg: Optional[int] = None,
    z: float = 1.0,
    scale: float = 1.0,
    azimuth: float = 315.0,
    altitude: float = 45.0,
    alg: Optional[str] = None,
    multidirectional: bool = False,
    combined: bool = False,
    compute_edges: bool = False,
    max_memory=None,
) -> np.ndarray:
    """Shaded relief, uint8 (1–255; 0 where NoData), as ``gdaldem hillshade``: light from
    ``azimuth`` degrees clockwise from north, ``altitude`` degrees above the horizon;
    ``z`` vertical exaggeration, ``scale`` horizontal units per elevation unit; ``alg``
    "Horn" (default) or "ZevenbergenThorne"; ``multidirectional`` or ``combined`` shading."""
    return _product(
        "hillshade", dem, transform, epsg=epsg, z=z, scale=scale, azimuth=azimuth, altitude=altitude, alg=alg,
        multidirectional=multidirectional, combined=combined, compute_edges=compute_edges, max_memory=max_memory,
    )


def slope(
    dem: _Dem,
    transform: Optional[Sequence[float]] = None,
    *,
    epsg: Optional[int] = None,
    percent: bool = False,
    z: float = 1.0,
    scale: float = 1.0,
    alg: Optional[str] = None,
    compute_edges: bool = False,
    max_memory=None,
) -> np.ndarray:
    """Slope in degrees (or ``percent``), float32, NaN where NoData, as ``gdaldem slope``."""
    return _product(
        "slope", dem, transform, epsg=epsg, percent=percent, z=z, scale=scale, alg=alg,
        compute_edges=compute_edges, max_memory=max_memory,
    )


def aspect(
    dem: _Dem,
    transform: Optional[Sequence[float]] = None,
    *,
    epsg: Optional[int] = None,
    zero_for_flat: bool = False,
    alg: Optional[str] = None,
    compute_edges: bool = False,
    max_memory=None,
) -> np.ndarray:
    """Aspect in degrees clockwise from north, float32, NaN where NoData or flat (0 for flat
    with ``zero_for_flat``), as ``gdaldem aspect``."""
    return _product(
        "aspect", dem, transform, epsg=epsg, zero_for_flat=zero_for_flat, alg=alg,
        compute_edges=compute_edges, max_memory=max_memory,
    )


def tri(dem: _Dem, transform=None, *, epsg=None, alg: Optional[str] = None, compute_edges=False, max_memory=None) -> np.ndarray:
    """Terrain Ruggedness Index (``alg`` "Riley", the default, or "Wilson"), as ``gdaldem TRI``."""
    return _product("tri", dem, transform, epsg=epsg, alg=alg, compute_edges=compute_edges, max_memory=max_memory)


def tpi(dem: _Dem, transform=None, *, epsg=None, compute_edges=False, max_memory=None) -> np.ndarray:
    """Topographic Position Index: each cell less the mean of its 8 neighbours (``gdaldem TPI``)."""
    return _product("tpi", dem, transform, epsg=epsg, compute_edges=compute_edges, max_memory=max_memory)


def roughness(dem: _Dem, transform=None, *, epsg=None, compute_edges=False, max_memory=None) -> np.ndarray:
    """The largest difference between two cells of each 3 × 3 window (``gdaldem roughness``)."""
    return _product("roughness", dem, transform, epsg=epsg, compute_edges=compute_edges, max_memory=max_memory)


def color_relief(
    dem: _Dem,
    palette,
    transform: Optional[Sequence[float]] = None,
    *,
    epsg: Optional[int] = None,
    alpha: bool = False,
    mode: str = "interpolate",
    max_memory=None,
) -> np.ndarray:
    """Each cell's colour, uint8 (rows, columns, 3; 4 with ``alpha``), as ``gdaldem
    color-relief``. ``palette``: a gdaldem colour file (a path), its text ("value R G B [A]"
    lines; values may be "nv" or percentages), or a list of (value, r, g, b[, a]) rows.
    ``mode``: "interpolate" (default), "nearest" or "exact" (gdaldem's -nearest_color_entry,
    -exact_color_entry)."""
    if isinstance(palette, PathLike) or (isinstance(palette, str) and "\n" not in palette and Path(palette).is_file()):
        palette = Path(palette).read_text()
    elif not isinstance(palette, str):
        palette = "\n".join(" ".join(str(v) for v in row) for row in palette)
    return _volterra.dem_color_relief(dem, palette, transform, epsg=epsg, alpha=alpha, mode=mode, max_memory=max_memory)


def contours(
    dem: _Dem,
    transform: Optional[Sequence[float]] = None,
    *,
    epsg: Optional[int] = None,
    interval: Optional[float] = None,
    offset: float = 0.0,
    levels: Optional[Sequence[float]] = None,
    max_memory=None,
) -> List[Tuple[float, np.ndarray]]:
    """Contour lines, as ``gdal_contour``: every ``interval`` from ``offset`` (-i, -off) or
    at ``levels`` (-fl); a list of (level, (n, 2) map coordinates), a closed line repeating
    its first vertex."""
    return _volterra.dem_contours(
        dem, transform, epsg=epsg, interval=interval, offset=offset,
        levels=None if levels is None else [float(v) for v in levels], max_memory=max_memory,
    )
