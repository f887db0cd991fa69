#!/usr/bin/env python3
"""Plots `volterra bench shear-warp` rows (JSON on stdin or a file): median ms per frame
against relative RMSE from the reference ray caster, one labelled point per config, a
panel per family (projection, blend mode, shading: only like rows are compared), VTK's
configurations as squares, each family's speed/error Pareto front drawn as a line through
its points (ringed).

Usage: plot_bench.py ROWS.json OUT.png
"""
import json
import math
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

rows = json.load(open(sys.argv[1]))
families = sorted({r.get("family", "all") for r in rows})
cols = min(3, len(families))
nrows = math.ceil(len(families) / cols)
fig, axes = plt.subplots(nrows, cols, figsize=(6.5 * cols, 5 * nrows), dpi=100, squeeze=False)
for ax, family in zip(axes.flat, families):
    fam = [r for r in rows if r.get("family", "all") == family]
    for r in fam:
        vtk = "vtk" in r["config"]
        x, y = r["median_ms"], 100 * r["rel_rmse"]
        ax.scatter(x, y, c="tab:red" if vtk else "tab:blue", marker="s" if vtk else "o", s=36, zorder=3,
                   edgecolors="black" if r.get("pareto") else "none", linewidths=1.2)
        ax.annotate(r["config"].replace("perspective ", "").replace("shaded ", ""), (x, y), fontsize=6,
                    xytext=(4, 3), textcoords="offset points")
    front = sorted((r["median_ms"], 100 * r["rel_rmse"]) for r in fam if r.get("pareto"))
    if len(front) > 1:
        ax.step([p[0] for p in front], [p[1] for p in front], where="post", color="black", lw=0.8, ls="--", zorder=2,
                label="Pareto front")
        ax.legend(fontsize=7, loc="upper right")
    ax.set_xscale("log")
    ax.set_xlabel("median ms per frame (log)")
    ax.set_ylabel("relative RMSE from the reference (%)")
    ax.set_title(family, fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
for ax in list(axes.flat)[len(families):]:
    ax.axis("off")
fig.suptitle("shear-warp (circles) vs VTK fixed-point (squares): speed against error", fontsize=11)
fig.tight_layout()
fig.savefig(sys.argv[2])
