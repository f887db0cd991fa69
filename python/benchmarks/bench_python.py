#!/usr/bin/env python3
"""The Python package against what users run today, side by side in one run (medians of
interleaved runs; these machines are noisy):

- reading: volterra.read of a DICOM series against pydicom + numpy (read every file, sort
  by position along the slice normal, stack, rescale), and of a .nii.gz against nibabel's
  get_fdata();
- rendering: a scene loaded, rendered and saved as EXR from Python against `volterra
  render` of the same scene file (its whole run: start, read, render, write), and the
  render alone (the frame's own seconds) from both.

    python python/benchmarks/bench_python.py [--runs 7] [--shared ../shared/data] [--json]
"""

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import volterra

ROOT = Path(__file__).resolve().parents[2]


def timed(f):
    t = time.perf_counter()
    r = f()
    return time.perf_counter() - t, r


def pydicom_stack(directory):
    import pydicom

    slices = [pydicom.dcmread(p) for p in sorted(Path(directory).iterdir()) if p.is_file()]
    normal = np.cross(*np.reshape(np.array(slices[0].ImageOrientationPatient, float), (2, 3)))
    slices.sort(key=lambda s: float(np.dot(normal, np.array(s.ImagePositionPatient, float))))
    # pixel_array is [row, column]; volterra's (i, j, k) is (column, row, slice): a view.
    stack = np.stack([s.pixel_array for s in slices], axis=-1).transpose(1, 0, 2)
    slope, inter = float(getattr(slices[0], "RescaleSlope", 1)), float(getattr(slices[0], "RescaleIntercept", 0))
    return stack * slope + inter if (slope, inter) != (1.0, 0.0) else stack


def nibabel_fdata(path):
    import nibabel

    return nibabel.load(path).get_fdata()


def side_by_side(runs, a, b):
    """Medians of `runs` interleaved runs of a and b (after one warm-up each)."""
    a(), b()
    ta, tb = [], []
    for _ in range(runs):
        ta.append(timed(a)[0])
        tb.append(timed(b)[0])
    return statistics.median(ta), statistics.median(tb)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--shared", type=Path, default=ROOT.parent / "shared" / "data")
    ap.add_argument("--volterra", type=Path, default=ROOT / "target" / "debug" / "volterra")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    rows = []

    dicom = args.shared / "volumes/aneurism/dicom_ct"
    ours, theirs = side_by_side(args.runs, lambda: volterra.read(dicom).array, lambda: pydicom_stack(dicom))
    assert np.array_equal(volterra.read(dicom).array, pydicom_stack(dicom))
    rows.append(("read a DICOM series (256 files)", "pydicom + numpy", ours, theirs))
    for rel in ("volumes/aneurism/aneurism.nii.gz", "volumes/angio/CT_AVM.nii.gz"):
        path = args.shared / rel
        ours, theirs = side_by_side(args.runs, lambda: volterra.read(path).array, lambda: nibabel_fdata(path))
        rows.append((f"read {path.name}", "nibabel get_fdata()", ours, theirs))

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        scene = volterra.Scene(width=512, height=512)
        scene.add_volume(volterra.read(args.shared / "volumes/angio/CT_AVM.nii.gz"), preset="CT-AAA", shading=True)
        scene.camera.azimuth(30)
        toml = tmp / "scene.toml"
        scene.to_toml(toml)
        cli_render = []

        def python_run():
            frame = volterra.Scene.load(toml).render()
            frame.save(tmp / "py.exr")
            return frame

        def cli_run():
            r = subprocess.run([str(args.volterra), "render", str(toml), "-o", str(tmp / "cli.exr")], capture_output=True, text=True, check=True)
            line = next(ln for ln in r.stderr.splitlines() if ln.startswith("node '"))
            cli_render.append(float(line.split("render ")[-1].split(" s")[0]))

        py_render = []
        python_run(), cli_run()
        t_py, t_cli = [], []
        for _ in range(args.runs):
            t, frame = timed(python_run)
            t_py.append(t)
            py_render.append(frame.stats["nodes"][0]["render"])
            t_cli.append(timed(cli_run)[0])
        assert (tmp / "py.exr").read_bytes() == (tmp / "cli.exr").read_bytes()
        rows.append(("load, render 512² (CT_AVM, CT-AAA shaded), write EXR", "volterra render", statistics.median(t_py), statistics.median(t_cli)))
        rows.append(("the render alone (frame stats)", "volterra render", statistics.median(py_render), statistics.median(cli_render[-args.runs:])))

    machine = f"{platform.processor() or platform.machine()}, {os.cpu_count()} threads, Python {platform.python_version()}"
    if args.json:
        print(json.dumps({"machine": machine, "runs": args.runs,
                          "rows": [{"task": r[0], "peer": r[1], "volterra_s": r[2], "peer_s": r[3], "peer_over_volterra": r[3] / r[2]} for r in rows]}, indent=2))
        return
    print(f"{machine}; medians of {args.runs} interleaved runs")
    print(f"{'task':<58} {'volterra (Python)':>18} {'peer':>22} {'peer / volterra':>16}")
    for task, peer, ours, theirs in rows:
        print(f"{task:<58} {ours * 1000:>15.1f} ms {peer + ' ' + format(theirs * 1000, '.1f') + ' ms':>22} {theirs / ours:>15.2f}×")


if __name__ == "__main__":
    sys.exit(main())
