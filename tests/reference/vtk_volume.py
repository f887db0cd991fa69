#!/usr/bin/env python3
"""Renders volume scenes (tests/reference/scenes/*.toml) with VTK's
vtkFixedPointVolumeRayCastMapper — the scene's camera (parallel or perspective), transfer
function and unit distance (mm), linear interpolation, shading as the scene's [node.shading] says (off by default), one sample per voxel — and
writes each image as a float RGBA OpenEXR (colour over black, alpha = accumulated opacity).

Usage: vtk_volume.py OUT_DIR SCENE.toml...
       vtk_volume.py --bench SPEC.json   (for `volterra bench shear-warp`: renders each view
       of one scene `runs` times after a warm-up, for each of the spec's `configs` (sample
       distance in voxels of the finest axis, ImageSampleDistance; default [[1, 1]]),
       prints {"configs": [{"sample_distance", "image_sample_distance", "ms": [[per-run
       ms]...]}...], "vtk"} and writes each config's images to the spec's paths, each
       path's stem followed by "_sd{sd}_isd{isd}")
       vtk_volume.py --clinical SPEC.json   (for `volterra bench clinical` and `bench
       gpu-volume`; the spec's "mapper" is "fixed-point" (default) or "gpu"
       (vtkGPUVolumeRayCastMapper), its "size" [w, h] overrides the scene's: the first view's
       frame timed from reading the file — nibabel + numpy into vtkImageData — to the end of
       its first render, then each further view rendered once, timed; prints
       {"first_ms", "further_ms", "peak_bytes", "vtk", "curve"}; for each of the spec's
       `configs` (as --bench's, default none) the same again after the peak is taken, its
       images at config_path: curve = [{"sample_distance", "image_sample_distance",
       "first_ms", "further_ms"}...])
"""
import json
import time
import os
import sys
import tomllib

import nibabel as nib
import numpy as np
import OpenEXR
import vtk
from vtk.util.numpy_support import numpy_to_vtk, vtk_to_numpy


def render(scene_path, out_path, views=None, runs=0, shading=None, first_frame=False, sample_distance=1.0, image_sample_distance=1.0,
           mapper_kind="fixed-point", size=None):
    start = time.perf_counter()
    with open(scene_path, "rb") as f:
        scene = tomllib.load(f)
    node = scene["node"][0]
    img = nib.load(os.path.join(os.path.dirname(scene_path), node["file"]))
    # Real-world values: get_fdata applies scl_slope/scl_inter once (np.asanyarray of the
    # proxy applies them too: scaling that again rendered a PET with slope 0.001 empty).
    data = img.get_fdata(dtype=np.float32)
    nx, ny, nz = data.shape[:3]
    # The voxel size as the image's spacing and only the rotation and translation in the
    # prop's matrix: VTK's sample distance and opacity unit distance are in the data's
    # coordinates, which are then millimetres, as the scene's are (with one-voxel spacing
    # and the whole affine as the matrix they were in voxels: a 0.52 mm MR angiography came
    # out about 20 % too opaque).
    affine = np.asarray(img.affine, dtype=np.float64)
    spacing = np.linalg.norm(affine[:3, :3], axis=0)
    image = vtk.vtkImageData()
    image.SetDimensions(nx, ny, nz)
    image.SetSpacing(*spacing)
    image.SetOrigin(0, 0, 0)
    arr = numpy_to_vtk(np.ascontiguousarray(data[..., 0] if data.ndim > 3 else data).transpose(2, 1, 0).ravel(), deep=True)  # x fastest
    image.GetPointData().SetScalars(arr)
    # Data coordinates (mm along the voxel axes) → world (RAS mm) as the prop's matrix, so the
    # camera is the scene's.
    rigid = affine.copy()
    rigid[:3, :3] = affine[:3, :3] / spacing
    m = vtk.vtkMatrix4x4()
    for r in range(4):
        for c in range(4):
            m.SetElement(r, c, float(rigid[r, c]))
    tf = node["transfer_function"]
    opacity = vtk.vtkPiecewiseFunction()
    for v, a in tf["scalar_opacity"]:
        opacity.AddPoint(v, a)
    color = vtk.vtkColorTransferFunction()
    for v, r, g, b in tf["color"]:
        color.AddRGBPoint(v, r, g, b)
    prop = vtk.vtkVolumeProperty()
    prop.SetScalarOpacity(opacity)
    prop.SetColor(color)
    prop.SetScalarOpacityUnitDistance(tf.get("scalar_opacity_unit_distance", 1.0))
    prop.SetInterpolationTypeToLinear()
    # Gradient shading as the scene's [node.shading] asks (VTK's defaults where it is
    # silent), under a headlight as ours without scene lights.
    # (`shading` given: these keys instead of the scene's, for the bench's shaded and
    # unshaded rows.)
    if shading is None:
        shading = node.get("shading", {})
    if shading.get("shade", False):
        prop.ShadeOn()
        prop.SetAmbient(shading.get("ambient", 0.1))
        prop.SetDiffuse(shading.get("diffuse", 0.7))
        prop.SetSpecular(shading.get("specular", 0.2))
        prop.SetSpecularPower(shading.get("specular_power", 10.0))
    else:
        prop.ShadeOff()
    # VTK's fixed-point CPU mapper, or its GPU ray caster (OpenGL: 3D Slicer's default; on a
    # machine without a GPU, Mesa's llvmpipe through EGL).
    if mapper_kind == "gpu":
        mapper = vtk.vtkGPUVolumeRayCastMapper()
    elif mapper_kind == "fixed-point":
        mapper = vtk.vtkFixedPointVolumeRayCastMapper()
    else:
        raise SystemExit(f"vtk_volume.py: unknown mapper {mapper_kind!r} (fixed-point or gpu)")
    mapper.SetInputData(image)
    mapper.SetAutoAdjustSampleDistances(0)
    # One sample per voxel along the finest axis (1 for the 1 mm comparison scenes), or
    # `sample_distance` voxels; one ray per pixel, or one per `image_sample_distance`
    # pixels (VTK interpolates between them).
    mapper.SetSampleDistance(float(sample_distance * spacing.min()))
    mapper.SetImageSampleDistance(float(image_sample_distance))
    volume = vtk.vtkVolume()
    volume.SetMapper(mapper)
    volume.SetProperty(prop)
    volume.SetUserMatrix(m)
    ren = vtk.vtkRenderer()
    ren.SetBackground(0, 0, 0)
    ren.SetBackgroundAlpha(0.0)
    ren.AddVolume(volume)
    if shading.get("shade", False):
        # VTK's own headlight has a black ambient colour, so its fixed-point mapper would drop
        # the ambient term (its GPU mapper, as Slicer's, keeps it): a white-ambient headlight
        # makes the model ours, C·(ambient + diffuse·max(n·l, 0)) + specular·(n·h)^power.
        # The scene's directional lights instead, where it has any (one: VTK adds the
        # ambient term once per light).
        scene_lights = [l for l in scene.get("light", []) if l.get("kind", "directional") == "directional"]
        if len(scene_lights) > 1:
            raise SystemExit("vtk_volume.py: one directional light at most (VTK adds the ambient term per light)")
        light = vtk.vtkLight()
        light.SetAmbientColor(1.0, 1.0, 1.0)
        if scene_lights:
            l = scene_lights[0]
            d = l["direction"]  # the way the light travels
            light.SetLightTypeToSceneLight()
            light.SetPositional(False)
            light.SetFocalPoint(0.0, 0.0, 0.0)
            light.SetPosition(-d[0], -d[1], -d[2])
            c = l.get("color", [1.0, 1.0, 1.0])
            light.SetColor(*c)
            light.SetIntensity(l.get("intensity", 1.0))
        else:
            light.SetLightTypeToHeadlight()
        ren.AddLight(light)
    cam = ren.GetActiveCamera()
    c = scene["camera"]
    cam.SetPosition(*c["position"])
    cam.SetFocalPoint(*c["focal_point"])
    cam.SetViewUp(*c.get("view_up", [0, 0, 1]))
    # As our Camera: perspective unless parallel_projection is set, view angle 30° by default.
    cam.SetParallelProjection(1 if c.get("parallel_projection", False) else 0)
    cam.SetParallelScale(c.get("parallel_scale", 1.0))
    cam.SetViewAngle(c.get("view_angle", 30.0))
    ren.ResetCameraClippingRange()
    w, h = size if size else (scene["image"]["width"], scene["image"]["height"])
    win = vtk.vtkRenderWindow()
    win.SetOffScreenRendering(1)
    win.SetAlphaBitPlanes(1)
    win.SetMultiSamples(0)
    win.AddRenderer(ren)
    win.SetSize(w, h)
    if views is None:
        views = [{"position": c["position"], "image": out_path}]
    timings = []
    if first_frame:
        # As a user opens a volume and turns it: no warm-up, one render per view.
        for k, view in enumerate(views):
            cam.SetPosition(*view["position"])
            ren.ResetCameraClippingRange()
            t = time.perf_counter()
            win.Render()
            timings.append(1000 * (time.perf_counter() - (start if k == 0 else t)))
            write_image(win, w, h, view["image"])
        return timings
    for view in views:
        path = view["image"]
        cam.SetPosition(*view["position"])
        # A bench view may change the projection (its perspective rows).
        if "parallel" in view:
            cam.SetParallelProjection(1 if view["parallel"] else 0)
        if "view_angle" in view:
            cam.SetViewAngle(view["view_angle"])
        if "parallel_scale" in view:
            cam.SetParallelScale(view["parallel_scale"])
        ren.ResetCameraClippingRange()
        win.Render()  # warm-up: the first render also builds VTK's tables
        ms = []
        for _ in range(runs):
            t = time.perf_counter()
            cam.Modified()
            win.Render()
            ms.append(1000 * (time.perf_counter() - t))
        timings.append(ms)
        write_image(win, w, h, path)
    return timings


def opengl_renderer():
    """The OpenGL renderer VTK's windows draw with (llvmpipe where there is no GPU)."""
    win = vtk.vtkRenderWindow()
    win.SetOffScreenRendering(1)
    win.Render()
    for line in win.ReportCapabilities().splitlines():
        if line.startswith("OpenGL renderer string:"):
            return line.split(":", 1)[1].strip()
    return None


def write_image(win, w, h, path):
    buf = vtk.vtkFloatArray()
    win.GetRGBAPixelData(0, 0, w - 1, h - 1, 1, buf)
    rgba = vtk_to_numpy(buf).reshape(h, w, 4)[::-1].astype(np.float32)  # row 0 at the top
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, {"RGBA": np.ascontiguousarray(rgba)}).write(path)


def config_path(path, sd, isd):
    """A bench image's path for one configuration: its stem followed by _sd{sd}_isd{isd}."""
    stem, ext = os.path.splitext(path)
    return f"{stem}_sd{sd:g}_isd{isd:g}{ext}"


def main():
    if sys.argv[1] == "--clinical":
        import resource

        with open(sys.argv[2]) as f:
            spec = json.load(f)
        mapper_kind = spec.get("mapper", "fixed-point")
        size = spec.get("size")
        ms = render(spec["scene"], None, spec["views"], first_frame=True, mapper_kind=mapper_kind, size=size)
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
        curve = []
        for sd, isd in spec.get("configs", []):
            views = [dict(v, image=config_path(v["image"], sd, isd)) for v in spec["views"]]
            t = render(spec["scene"], None, views, first_frame=True, sample_distance=sd, image_sample_distance=isd, mapper_kind=mapper_kind,
                       size=size)
            curve.append({"sample_distance": sd, "image_sample_distance": isd, "first_ms": t[0], "further_ms": t[1:]})
        print(json.dumps({"first_ms": ms[0], "further_ms": ms[1:], "peak_bytes": peak, "vtk": vtk.vtkVersion.GetVTKVersion(),
                          "curve": curve, "opengl": opengl_renderer()}))
        return
    if sys.argv[1] == "--bench":
        with open(sys.argv[2]) as f:
            spec = json.load(f)
        configs = []
        for sd, isd in spec.get("configs", [[1.0, 1.0]]):
            views = [dict(v, image=config_path(v["image"], sd, isd)) for v in spec["views"]]
            ms = render(spec["scene"], None, views, spec["runs"], spec.get("shading"), sample_distance=sd, image_sample_distance=isd)
            configs.append({"sample_distance": sd, "image_sample_distance": isd, "ms": ms})
        print(json.dumps({"configs": configs, "vtk": vtk.vtkVersion.GetVTKVersion()}))
        return
    out = sys.argv[1]
    os.makedirs(out, exist_ok=True)
    for scene in sys.argv[2:]:
        name = os.path.splitext(os.path.basename(scene))[0]
        render(scene, os.path.join(out, f"vtk_{name}.exr"))
        print(f"rendered {name}", file=sys.stderr)


if __name__ == "__main__":
    main()
