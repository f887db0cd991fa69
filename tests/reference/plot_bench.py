#!/usr/bin/env python3
"""Plots `volterra bench shear-warp` rows (JSON on stdin or a file): median ms per frame
against relative RMSE from the reference ray caster, one labelled point per config.

Usage: plot_bench.py ROWS.json OUT.png
"""
import json
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

rows = json.load(open(sys.argv[1]))
fig, ax = plt.subplots(figsize=(9, 6), dpi=110)
for r in rows:
    vtk = r["config"].startswith("vtk")
    mip = "mip" in r["config"]
    colour = "tab:red" if vtk else ("tab:purple" if mip else "tab:blue")
    ax.scatter(r["median_ms"], 100 * r["rel_rmse"], c=colour, marker="s" if vtk else "o", s=40)
    ax.annotate(r["config"], (r["median_ms"], 100 * r["rel_rmse"]), fontsize=7, xytext=(4, 3), textcoords="offset points")
ax.set_xscale("log")
ax.set_xlabel("median time per frame (ms, log scale)")
ax.set_ylabel("relative RMSE from the reference ray caster (%)")
ax.set_title("shear-warp vs VTK fixed-point: speed against error")
ax.grid(True, which="both", alpha=0.3)
fig.tight_layout()
fig.savefig(sys.argv[2])
