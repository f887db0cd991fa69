#!/usr/bin/env python3
"""Writes the clinical comparison scenes (tests/reference/scenes/clinical_*.toml): three real
volumes from ../shared/data — a CT angiography, an MR T1 and a PET — each shaded, from three
views (along the anterior axis, oblique, exactly at the 45° switch of principal axis), in
parallel projection and in perspective (30°). vtk_volume.py renders them with VTK's
fixed-point mapper (tests/reference/data/vtk_clinical_*.exr) and tests/vtk_comparison.rs
with the reference ray caster and shear-warp.

The transfer functions and shading are the presets volterra gives these files (CT-AAA,
MR-Default, PET-Hot with the Slicer shift to the data's range), written out as points so
that VTK reads the same classification; PET-Hot has no shading in Slicer, so it gets VTK's
default lighting coefficients here. The focal point is the volume's centre (box of voxel
centres, world millimetres from the file's affine, as nibabel reads it).

Usage: make_clinical_scenes.py [SHARED_DATA]   (default ../shared/data beside the checkout)
"""
import math
import os
import sys

import nibabel as nib
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
SCENES = os.path.join(HERE, "scenes")

VOLUMES = {
    "ctavm": {
        "file": "volumes/angio/CT_AVM.nii.gz",
        "what": "head/neck CT angiography (CT_AVM), preset CT-AAA",
        "tf": """scalar_opacity = [[0.0, 0.0], [143.556, 0.0], [166.222, 0.686275], [214.389, 0.696078], [419.736, 0.833333], [563.2, 0.803922]]
color = [[0.0, 0.0, 0.0, 0.0], [143.556, 0.615686, 0.356863, 0.184314], [166.222, 0.882353, 0.603922, 0.290196], [214.389, 1.0, 1.0, 1.0], [419.736, 1.0, 0.937033, 0.954531], [563.2, 0.827451, 0.658824, 1.0]]
scalar_opacity_unit_distance = 0.719942569732666""",
        "shading": "shade = true\nambient = 0.1\ndiffuse = 0.9\nspecular = 0.2\nspecular_power = 10.0",
    },
    "mri": {
        "file": "volumes/mr/mni_icbm152_t1_tal_nlin_sym_09a_converted.nii.gz",
        "what": "MR T1 (the MNI152 2009a template), preset MR-Default",
        "tf": """scalar_opacity = [[0.0, 0.0], [0.498046875, 0.15], [101.435546875, 0.3], [227.607421875, 0.375], [255.0, 0.5]]
color = [[0.0, 0.0, 0.0, 0.0], [0.498046875, 0.403922, 0.145098, 0.0784314], [101.435546875, 0.780392, 0.607843, 0.380392], [227.607421875, 0.847059, 0.835294, 0.788235], [255.0, 1.0, 1.0, 1.0]]
scalar_opacity_unit_distance = 1.0""",
        "shading": "shade = true\nambient = 0.2\ndiffuse = 1.0\nspecular = 0.0\nspecular_power = 1.0",
    },
    "pet": {
        "file": "volumes/pet/FDOPA_fluorodopa_hc12_gomez.nii",
        "what": "[18F]FDOPA PET (group average, MNI space, 3 mm), preset PET-Hot, VTK's default lighting",
        "tf": """scalar_opacity = [[0.0, 0.0], [33.94251723718298, 0.0], [53.214963465075016, 0.15], [98.18400466348976, 0.8]]
color = [[0.0, 0.0, 0.0, 0.0], [33.94251723718298, 0.3, 0.0, 0.0], [56.427037836390355, 1.0, 0.2, 0.0], [78.91155843559773, 1.0, 0.85, 0.1], [98.18400466348976, 1.0, 1.0, 1.0]]
scalar_opacity_unit_distance = 3.0""",
        "shading": "shade = true\nambient = 0.1\ndiffuse = 0.7\nspecular = 0.2\nspecular_power = 10.0",
    },
}

# Directions from the focal point to the eye (RAS: +y anterior, +z superior).
VIEWS = {
    "axis": (0.0, 1.0, 0.0),
    "oblique": (math.sin(math.radians(30)) * math.cos(math.radians(25)), math.cos(math.radians(30)) * math.cos(math.radians(25)),
                math.sin(math.radians(25))),
    "switch45": (math.sqrt(0.5), math.sqrt(0.5), 0.0),
}


def main():
    shared = sys.argv[1] if len(sys.argv) > 1 else os.path.join(HERE, "..", "..", "..", "shared", "data")
    for name, v in VOLUMES.items():
        img = nib.load(os.path.join(shared, v["file"]))
        dims = np.array(img.shape[:3], dtype=float)
        centre = img.affine @ np.append((dims - 1) / 2, 1.0)
        rel = os.path.relpath(os.path.join(os.path.abspath(os.path.join(HERE, "..", "..", "..")), "shared", "data", v["file"]), SCENES)
        for view, d in VIEWS.items():
            for proj in ["parallel", "perspective"]:
                # 440 mm at 30°: a view 236 mm high at the focal point, as the parallel one.
                eye = centre[:3] + 440.0 * np.array(d)
                text = f"""# {v['what']}, shaded; view {view}, {proj}. Written by
# tests/reference/make_clinical_scenes.py; VTK's image by vtk_volume.py, compared in
# tests/vtk_comparison.rs.
[image]
width = 256
height = 256

[camera]
position = [{eye[0]:.6f}, {eye[1]:.6f}, {eye[2]:.6f}]
focal_point = [{centre[0]:.6f}, {centre[1]:.6f}, {centre[2]:.6f}]
view_up = [0.0, 0.0, 1.0]
view_angle = 30.0
parallel_projection = {'true' if proj == 'parallel' else 'false'}
parallel_scale = 118.0

[[node]]
name = "volume"
kind = "volume"
file = "{rel}"
renderer = "shear-warp"

[node.transfer_function]
{v['tf']}

[node.shading]
{v['shading']}
"""
                with open(os.path.join(SCENES, f"clinical_{name}_{view}_{proj}.toml"), "w") as f:
                    f.write(text)


if __name__ == "__main__":
    main()
