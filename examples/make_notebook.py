"""Writes python_tour.ipynb (the notebook is generated so that its cells stay reviewable as
Python; run `python examples/make_notebook.py` after editing, then commit both)."""
from pathlib import Path

import nbformat as nbf
nb = nbf.v4.new_notebook()
md, code = nbf.v4.new_markdown_cell, nbf.v4.new_code_cell
nb.cells = [
md("""# volterra from Python

Read a CT, a DEM and a particle simulation into numpy, build scenes from them and render
them here; compute DEM products; compare two renders. The data is the project's shared
set (`../shared/data` beside the checkout, or `VOLTERRA_SHARED_DATA`)."""),
code("""import os, time
from pathlib import Path
import numpy as np
import volterra, volterra.dem

DATA = Path(os.environ.get("VOLTERRA_SHARED_DATA", Path.cwd().parent.parent / "shared" / "data"))
assert DATA.is_dir(), f"the shared data is not at {DATA}: set VOLTERRA_SHARED_DATA\""""),
md("""## A volume

`read` gives the values in nibabel's layout (`array[i, j, k]`) and its affine (RAS+ mm)."""),
code("""ct = volterra.read(DATA / "volumes/aneurism/aneurism.nii.gz")
print(ct)
print(ct.array.shape, ct.array.dtype, ct.spacing)
print(ct.affine)"""),
code("""import nibabel
img = nibabel.load(DATA / "volumes/aneurism/aneurism.nii.gz")
assert np.array_equal(img.get_fdata(), ct.array) and np.array_equal(img.affine, ct.affine)
print("equal to nibabel's get_fdata() and affine")"""),
md("""A scene from it: a transfer-function preset, shading, a turn of the camera. The frame
shows itself below (its PNG preview)."""),
code("""scene = volterra.Scene(width=384, height=384, background=(0.08, 0.08, 0.12))
scene.add_volume(ct, preset="MR-Angio", shading=True)
scene.camera.azimuth(30)
scene.camera.elevation(15)
frame = scene.render()
print(frame, frame.rgba.shape)
frame"""),
md("""The same volume as a maximum intensity projection, from the side, in parallel
projection; `stats` holds what the command line prints."""),
code("""scene.update("volume", blend="mip", preset=None, shading=None)
scene.camera.azimuth(60)
scene.camera.parallel_projection = True
mip = scene.render()
print(mip.stats["renderer"], {k: round(v, 3) for k, v in mip.stats["nodes"][0].items() if k in ("load", "prepare", "render")})
mip"""),
md("""Written as a scene file, with the volume beside it, `volterra render` draws the same
image."""),
code("""import tempfile
out = Path(tempfile.mkdtemp())
scene.to_toml(out / "mip.toml")
print(sorted(p.name for p in out.iterdir()))"""),
md("""## A volume from an array

Any 3-D array with its affine: here an analytic blob on an oblique, anisotropic grid."""),
code("""i, j, k = np.meshgrid(np.arange(64), np.arange(64), np.arange(48), indexing="ij")
blob = (1000 * np.exp(-((i - 32) ** 2 + 0.5 * (j - 30) ** 2 + 2 * (k - 24) ** 2) / 120)).astype(np.int16)
affine = np.array([[0.0, -0.8, 0.2, 10], [0.6, 0.0, 0.0, -20], [0.0, 0.1, 1.2, 5], [0, 0, 0, 1]])
s = volterra.Scene(width=256, height=256)
s.add_volume(blob, affine, preset="CT-AAA", shading=True)
s.render()"""),
md("""## A DEM

GDAL's geotransform and gdaldem's products, computed in memory."""),
code("""dem = volterra.read(DATA / "terrain/pysheds_dem.tif")
print(dem, dem.transform, dem.crs)
shade = volterra.dem.hillshade(dem, scale=111120, z=2)
slope = volterra.dem.slope(dem, scale=111120)
print(shade.dtype, shade.shape, "slope %.1f–%.1f°" % (np.nanmin(slope), np.nanmax(slope)))
lines = volterra.dem.contours(dem, interval=50)
print(len(lines), "contour lines")"""),
code("""import matplotlib.pyplot as plt
fig, ax = plt.subplots(1, 2, figsize=(10, 4))
ax[0].imshow(shade, cmap="gray"); ax[0].set_title("hillshade")
im = ax[1].imshow(slope, cmap="magma"); ax[1].set_title("slope (°)"); fig.colorbar(im, ax=ax[1])
for level, xy in lines[:200]:
    col = (xy[:, 0] - dem.transform[0]) / dem.transform[1]
    row = (xy[:, 1] - dem.transform[3]) / dem.transform[5]
    ax[0].plot(col, row, lw=0.5, color="orange")
plt.show()"""),
md("""The terrain itself, ray-cast on the GPU (lavapipe where there is no graphics card)."""),
code("""t = volterra.Scene(width=480, height=300, background=(0.55, 0.7, 0.9))
t.add_heightfield(dem)
t.add_light("directional", direction=(1, 1, -1))
t.camera.dolly(1.3)
t.render()"""),
md("""## Particles

A smoke plume of 110,000 SPH particles, as points coloured by an array and as
particle-map smoke."""),
code("""plume = volterra.read(DATA / "particles/smoke_plume_110k.vtp")
print(plume, plume.positions.shape)
p = volterra.Scene(width=320, height=320, background=(0.02, 0.02, 0.03))
p.add_particles(plume, renderer="points", color_by="density")
p.render()"""),
code("""p.update("particles", renderer="smoke", color_by=None, medium={"albedo": 0.9, "g": 0.3})
p.add_light(direction=(-1, 0.6, -0.5), intensity=3.0)
smoke = p.render()
print(smoke.stats["notes"][:2])
smoke"""),
md("""## Comparing renders

The metrics `volterra compare` prints: shear-warp against the reference ray caster."""),
code("""fast = volterra.Scene(width=256, height=256)
fast.add_volume(ct, preset="MR-Angio", renderer="shear-warp")
ref = volterra.Scene(width=256, height=256)
ref.add_volume(ct, preset="MR-Angio", renderer="reference")
a, b = fast.render(), ref.render()
print("relative RMSE %.2f %%" % (100 * volterra.compare(a, b)["overall"]["relative_rmse"]))
print("shear-warp %.3f s, reference %.3f s" % (a.stats["seconds"], b.stats["seconds"]))"""),
]
nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
nbf.write(nb, Path(__file__).with_name("python_tour.ipynb"))
