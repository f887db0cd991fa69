#!/usr/bin/env python3
"""Renders terrain scenes (tests/reference/terrain_scenes/*.toml) with VTK: the heightfield
triangulated — every cell split along its south-west/north-east diagonal — in the scene's
coordinates (x east, y north in metres from the south-west sample, z up), seen by the
scene's camera. Writes each image's depth as an OpenEXR channel Z: the distance along the
pixel's ray, recovered from VTK's z-buffer and clipping range (+inf where nothing).

Usage: vtk_terrain.py OUT_DIR SCENE.toml...
       vtk_terrain.py --bench SIZES W H RUNS DIR   (for `volterra bench terrain`: times VTK's
       mesh rendering of the DEMs DIR/dem_SIZE.npy (30 m cells) seen by the cameras in
       DIR/cams_SIZE.json; prints JSON rows with median ms and added resident memory)
"""
import json
import math
import os
import sys
import time
import tomllib

import numpy as np
import OpenEXR
import vtk
from PIL import Image
from vtk.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray, vtk_to_numpy


def load_heightfield(scene_path, node):
    """Elevations (rows north first, NaN = NoData) and the cell size in metres."""
    path = os.path.join(os.path.dirname(scene_path), node["file"])
    if not path.endswith(".png"):
        raise SystemExit(f"{path}: only PNG heightmaps are supported by this script")
    grey = np.asarray(Image.open(path)).astype(np.float64)
    png = node.get("png", {})
    z = png.get("vertical_offset", 0.0) + png.get("vertical_scale", 1.0) * grey
    if "nodata" in png:
        z[grey == png["nodata"]] = np.nan
    cell = png.get("cell_size", 1.0)
    return z, cell, cell


def mesh(z, cx, cy):
    h, w = z.shape
    cols, rows = np.meshgrid(np.arange(w), np.arange(h))
    pts = np.stack([cols * cx, (h - 1 - rows) * cy, np.nan_to_num(z)], axis=-1).reshape(-1, 3)
    idx = np.arange(w * h).reshape(h, w)
    # Cell (i, j) with j counted from the south: corners 00 = (i, row), 10 = (i+1, row),
    # 01 = (i, row-1), 11 = (i+1, row-1) where row = h-1-j.
    p00 = idx[1:, :-1]
    p10 = idx[1:, 1:]
    p01 = idx[:-1, :-1]
    p11 = idx[:-1, 1:]
    valid = ~(np.isnan(z[1:, :-1]) | np.isnan(z[1:, 1:]) | np.isnan(z[:-1, :-1]) | np.isnan(z[:-1, 1:]))
    tri = np.concatenate([np.stack([p00, p10, p11], -1)[valid], np.stack([p00, p11, p01], -1)[valid]])
    cells = np.hstack([np.full((len(tri), 1), 3), tri]).astype(np.int64).ravel()
    poly = vtk.vtkPolyData()
    points = vtk.vtkPoints()
    points.SetData(numpy_to_vtk(pts, deep=True))
    poly.SetPoints(points)
    ca = vtk.vtkCellArray()
    ca.SetCells(len(tri), numpy_to_vtkIdTypeArray(cells, deep=True))
    poly.SetPolys(ca)
    return poly


def window(poly, cam_spec, w, h):
    mapper = vtk.vtkPolyDataMapper()
    mapper.SetInputData(poly)
    actor = vtk.vtkActor()
    actor.SetMapper(mapper)
    ren = vtk.vtkRenderer()
    ren.AddActor(actor)
    cam = ren.GetActiveCamera()
    cam.SetPosition(*cam_spec["position"])
    cam.SetFocalPoint(*cam_spec["focal_point"])
    cam.SetViewUp(*cam_spec.get("view_up", [0, 0, 1]))
    cam.SetViewAngle(cam_spec.get("view_angle", 30.0))
    # VTK's default near plane (a fraction of the far one) cuts away the ground close to a
    # low eye; a smaller fraction keeps it, at 24-bit depth precision still ~1e-5.
    ren.SetNearClippingPlaneTolerance(2e-4)
    ren.ResetCameraClippingRange()
    win = vtk.vtkRenderWindow()
    win.SetOffScreenRendering(1)
    win.SetMultiSamples(0)
    win.AddRenderer(ren)
    win.SetSize(w, h)
    return win, ren, cam


def ray_depth(win, cam, w, h, view_angle):
    buf = vtk.vtkFloatArray()
    win.GetZbufferData(0, 0, w - 1, h - 1, buf)
    zb = vtk_to_numpy(buf).reshape(h, w)[::-1].astype(np.float64)  # row 0 at the top
    near, far = cam.GetClippingRange()
    ndc = 2.0 * zb - 1.0
    z_view = 2.0 * near * far / (far + near - ndc * (far - near))
    half_h = math.tan(math.radians(view_angle) / 2)
    half_w = half_h * w / h
    xs = (2.0 * (np.arange(w) + 0.5) / w - 1.0) * half_w
    ys = (1.0 - 2.0 * (np.arange(h) + 0.5) / h) * half_h
    sx, sy = np.meshgrid(xs, ys)
    dist = z_view * np.sqrt(1.0 + sx * sx + sy * sy)
    dist[zb >= 1.0] = np.inf
    return dist.astype(np.float32)


def render(scene_path, out_path):
    with open(scene_path, "rb") as f:
        scene = tomllib.load(f)
    node = scene["node"][0]
    z, cx, cy = load_heightfield(scene_path, node)
    w, h = scene["image"]["width"], scene["image"]["height"]
    win, ren, cam = window(mesh(z, cx, cy), scene["camera"], w, h)
    win.Render()
    depth = ray_depth(win, cam, w, h, scene["camera"].get("view_angle", 30.0))
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, {"Z": np.ascontiguousarray(depth)}).write(out_path)


def rss_mib():
    """Resident memory of this process now (MiB)."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def bench(sizes, w, h, runs, work_dir):
    """Median ms per frame and resident memory added, VTK mesh rendering of each DEM."""
    rows = []
    for size in sizes:
        z = np.load(os.path.join(work_dir, f"dem_{size}.npy")).astype(np.float64)
        with open(os.path.join(work_dir, f"cams_{size}.json")) as f:
            cams = json.load(f)
        before = rss_mib()
        t = time.perf_counter()
        poly = mesh(z, 30.0, 30.0)
        build_ms = 1000 * (time.perf_counter() - t)
        for name, cam_spec in cams.items():
            win, ren, cam = window(poly, cam_spec, w, h)
            t = time.perf_counter()
            win.Render()
            first_ms = 1000 * (time.perf_counter() - t)
            ms = []
            for _ in range(runs):
                t = time.perf_counter()
                cam.Modified()
                win.Render()
                ms.append(1000 * (time.perf_counter() - t))
            now = rss_mib()
            rows.append({"size": size, "camera": name, "median_ms": float(np.median(ms)), "first_frame_ms": first_ms,
                         "build_ms": build_ms, "rss_mib": now, "added_rss_mib": now - before,
                         "triangles": poly.GetNumberOfPolys()})
            win.Finalize()
            del win, ren
        del poly
    return rows


def main():
    if sys.argv[1] == "--bench":
        sizes = [int(s) for s in sys.argv[2].split(",")]
        out = bench(sizes, int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5]), sys.argv[6])
        print(json.dumps({"rows": out, "vtk": vtk.vtkVersion.GetVTKVersion()}))
        return
    out = sys.argv[1]
    os.makedirs(out, exist_ok=True)
    for scene in sys.argv[2:]:
        name = os.path.splitext(os.path.basename(scene))[0]
        render(scene, os.path.join(out, f"vtk_terrain_{name}.exr"))
        print(f"rendered {name}", file=sys.stderr)


if __name__ == "__main__":
    main()
