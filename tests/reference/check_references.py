#!/usr/bin/env python3
"""Regenerates the committed reference files into a scratch directory and checks they
match what is committed (floats to 1e-9 relative: numpy's summation order may differ
between CPUs). Proves the references are reproducible from the scripts beside this file.

Usage: check_references.py SHARED_DATA_DIR SCRATCH_DIR
       check_references.py --builtin VOLTERRA_BINARY SCRATCH_DIR   (after a build)
"""
import json
import math
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(os.path.dirname(HERE))


def same(a, b, path, errors):
    if isinstance(a, dict) and isinstance(b, dict):
        if set(a) != set(b):
            errors.append(f"{path}: keys differ: {sorted(set(a) ^ set(b))}")
        for k in set(a) & set(b):
            same(a[k], b[k], f"{path}.{k}", errors)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            errors.append(f"{path}: lengths {len(a)} vs {len(b)}")
        for i, (x, y) in enumerate(zip(a, b)):
            same(x, y, f"{path}[{i}]", errors)
    elif isinstance(a, float) or isinstance(b, float):
        if a is None or b is None or not math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-12):
            errors.append(f"{path}: {a} vs {b}")
    elif a != b:
        errors.append(f"{path}: {a!r} vs {b!r}")


def check_mitsuba(folder, scratch, errors):
    """Renders the smoke scenes in tests/reference/FOLDER with Mitsuba (8192 spp, fixed
    seed) and compares them with the committed images."""
    import glob
    import numpy as np
    import OpenEXR
    scenes = sorted(glob.glob(os.path.join(HERE, folder, "*.toml")))
    subprocess.run([sys.executable, os.path.join(HERE, "mitsuba_smoke.py"), os.path.join(scratch, "mitsuba"), "8192"] + scenes,
                   check=True, stderr=subprocess.DEVNULL)
    for scene in scenes:
        name = "mitsuba_" + os.path.splitext(os.path.basename(scene))[0] + ".exr"
        a = OpenEXR.File(os.path.join(REPO, "tests/reference/data", name)).channels()["RGB"].pixels.astype(np.float64)
        b = OpenEXR.File(os.path.join(scratch, "mitsuba", name)).channels()["RGB"].pixels.astype(np.float64)
        rel = float(np.sqrt(((a - b) ** 2).mean() / max((b ** 2).mean(), 1e-30)))
        if rel > 1e-3:
            errors.append(f"{name}: Mitsuba render differs from the committed one by {rel} (relative RMSE)")


def report(errors):
    if errors:
        print("\n".join(errors[:50]), file=sys.stderr)
        print(f"references differ from the committed ones in {len(errors)} places", file=sys.stderr)
        sys.exit(1)
    print("references regenerate identically")


def main():
    if sys.argv[1] == "--builtin":
        # The references of our own built-in samples: VOLTERRA (a built binary) writes
        # them where the scenes in tests/reference/builtin_scenes read them.
        volterra, scratch = sys.argv[2], sys.argv[3]
        subprocess.run([volterra, "samples", os.path.join(REPO, "target/builtin-samples")], check=True, stdout=subprocess.DEVNULL)
        errors = []
        check_mitsuba("builtin_scenes", scratch, errors)
        report(errors)
        return
    shared, scratch = sys.argv[1], sys.argv[2]
    os.makedirs(scratch, exist_ok=True)
    py = sys.executable
    errors = []
    subprocess.run([py, os.path.join(HERE, "make_fixtures.py"), os.path.join(scratch, "fixtures")], check=True)
    with open(os.path.join(REPO, "tests/fixtures/expected.json")) as f:
        committed = json.load(f)
    with open(os.path.join(scratch, "fixtures/expected.json")) as f:
        same(committed, json.load(f), "fixtures", errors)
    if os.path.exists(os.path.join(shared, "SOURCES.md")):
        subprocess.run([py, os.path.join(HERE, "make_references.py"), shared, os.path.join(scratch, "data")], check=True,
                       stderr=subprocess.DEVNULL)
        with open(os.path.join(REPO, "tests/reference/data/shared_data.json")) as f:
            committed = json.load(f)
        with open(os.path.join(scratch, "data/shared_data.json")) as f:
            same(committed, json.load(f), "shared_data", errors)
        # VTK's renders of the comparison scenes.
        import glob
        import numpy as np
        import OpenEXR
        scenes = sorted(glob.glob(os.path.join(HERE, "scenes", "*.toml")))
        subprocess.run([py, os.path.join(HERE, "vtk_volume.py"), os.path.join(scratch, "vtk")] + scenes, check=True,
                       stderr=subprocess.DEVNULL)
        for scene in scenes:
            name = "vtk_" + os.path.splitext(os.path.basename(scene))[0] + ".exr"
            a = OpenEXR.File(os.path.join(REPO, "tests/reference/data", name)).channels()["RGBA"].pixels
            b = OpenEXR.File(os.path.join(scratch, "vtk", name)).channels()["RGBA"].pixels
            diff = float(np.abs(a.astype(np.float64) - b).max())
            if diff > 2e-3:
                errors.append(f"{name}: VTK render differs from the committed one by {diff}")
        # VTK's triangle-mesh depth of the terrain comparison scenes.
        scenes = sorted(glob.glob(os.path.join(HERE, "terrain_scenes", "*.toml")))
        subprocess.run([py, os.path.join(HERE, "vtk_terrain.py"), os.path.join(scratch, "vtk")] + scenes, check=True,
                       stderr=subprocess.DEVNULL)
        for scene in scenes:
            name = "vtk_terrain_" + os.path.splitext(os.path.basename(scene))[0] + ".exr"
            a = OpenEXR.File(os.path.join(REPO, "tests/reference/data", name)).channels()["Z"].pixels.astype(np.float64)
            b = OpenEXR.File(os.path.join(scratch, "vtk", name)).channels()["Z"].pixels.astype(np.float64)
            fa, fb = np.isfinite(a), np.isfinite(b)
            if (fa != fb).sum() > 0.001 * a.size:
                errors.append(f"{name}: VTK depth covers {(fa != fb).sum()} pixels differently from the committed one")
            both = fa & fb
            rel = float(np.median(np.abs(a[both] - b[both]) / b[both])) if both.any() else 0.0
            if rel > 1e-4:
                errors.append(f"{name}: VTK depth differs from the committed one by {rel} (median relative)")
        # Mitsuba's render of the smoke comparison scene (8192 spp, deterministic seed).
        check_mitsuba("smoke_scenes", scratch, errors)
    elif os.environ.get("CI") == "true":
        print(f"shared data not found at {shared} (CI=true: must not skip)", file=sys.stderr)
        sys.exit(1)
    else:
        print(f"SKIPPED shared-data references: {shared} not found", file=sys.stderr)
    report(errors)


if __name__ == "__main__":
    main()
