#!/usr/bin/env python3
"""`volterra bench points`'s peer: the same particles drawn by VTK as spheres of their
smoothing length, the way pyvista draws `style="points_gaussian"` with
`render_points_as_spheres=True` (vtkPointGaussianMapper, scale array h, the sphere
splat shader), coloured by temperature through coolwarm, offscreen at the same size on the
same machine (Mesa's software OpenGL where there is no GPU; ours runs on Mesa's software
Vulkan). Prints {"first_ms", "ms": [...], "vtk", "renderer"} and writes the image.

With spec style "splats": VTK's own Gaussian splats (default shader, emissive), footprint h.

Usage: vtk_points.py SPEC.json   (spec: vtp, width, height, camera {position,
focal_point, view_up, view_angle}, runs, image, style)
"""
import json
import sys
import time

import numpy as np
import OpenEXR
import vtk
from vtk.util.numpy_support import vtk_to_numpy


def spheres(mapper):
    """pyvista's sphere look for points_gaussian + render_points_as_spheres."""
    mapper.SetScaleFactor(1.0)
    mapper.EmissiveOff()
    mapper.SetSplatShaderCode(
        "//VTK::Color::Impl\n"
        "float dist = dot(offsetVCVSOutput.xy, offsetVCVSOutput.xy);\n"
        "if (dist > 1.0) { discard; } else {\n"
        "  float scale = (1.0 - dist);\n"
        "  ambientColor *= scale;\n"
        "  diffuseColor *= scale;\n"
        "}\n"
    )


def main():
    with open(sys.argv[1]) as f:
        spec = json.load(f)
    start = time.perf_counter()
    reader = vtk.vtkXMLPolyDataReader()
    reader.SetFileName(spec["vtp"])
    reader.Update()
    poly = reader.GetOutput()
    poly.GetPointData().SetActiveScalars("temperature")
    mapper = vtk.vtkPointGaussianMapper()
    mapper.SetInputData(poly)
    mapper.SetScaleArray("h")
    if spec.get("style") == "splats":
        # VTK's own Gaussian splats (its default shader, emissive): σ is the scale, drawn
        # out to 3σ; a third of h puts the footprint at h, as volterra's splats.
        mapper.SetScaleFactor(1.0 / 3.0)
    else:
        spheres(mapper)

    lut = vtk.vtkColorTransferFunction()
    t = vtk_to_numpy(poly.GetPointData().GetArray("temperature"))
    lo, hi = float(t.min()), float(t.max())
    # Moreland's cool-warm ends and middle (matplotlib's coolwarm).
    lut.SetColorSpaceToDiverging()
    lut.AddRGBPoint(lo, 0.2298057, 0.298717966, 0.753683153)
    lut.AddRGBPoint(hi, 0.705673158, 0.01555616, 0.150232812)
    mapper.SetLookupTable(lut)
    mapper.SetScalarRange(lo, hi)
    mapper.SetScalarModeToUsePointData()
    actor = vtk.vtkActor()
    actor.SetMapper(mapper)
    ren = vtk.vtkRenderer()
    ren.SetBackground(0, 0, 0)
    ren.AddActor(actor)
    cam = ren.GetActiveCamera()
    c = spec["camera"]
    cam.SetPosition(*c["position"])
    cam.SetFocalPoint(*c["focal_point"])
    cam.SetViewUp(*c["view_up"])
    cam.SetViewAngle(c["view_angle"])
    ren.ResetCameraClippingRange()
    win = vtk.vtkRenderWindow()
    win.SetOffScreenRendering(1)
    win.SetMultiSamples(0)
    win.AddRenderer(ren)
    w, h = spec["width"], spec["height"]
    win.SetSize(w, h)
    buf = vtk.vtkFloatArray()

    def frame():
        win.Render()
        # Read the frame back, as ours does.
        win.GetRGBAPixelData(0, 0, w - 1, h - 1, 1, buf)

    frame()
    first_ms = 1000 * (time.perf_counter() - start)
    ms = []
    for _ in range(spec["runs"]):
        t0 = time.perf_counter()
        cam.Azimuth(0.5)  # a new view each frame
        frame()
        ms.append(1000 * (time.perf_counter() - t0))
    rgba = vtk_to_numpy(buf).reshape(h, w, 4)[::-1].astype(np.float32)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, {"RGBA": np.ascontiguousarray(rgba)}).write(spec["image"])
    print(json.dumps({"first_ms": first_ms, "ms": ms, "vtk": vtk.vtkVersion.GetVTKVersion(),
                      "renderer": win.ReportCapabilities().splitlines()[1] if win.ReportCapabilities() else ""}))


if __name__ == "__main__":
    main()
