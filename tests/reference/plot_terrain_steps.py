#!/usr/bin/env python3
"""Plots the per-ray step counts of `volterra bench terrain` (the paper's Fig. 12): for the
largest heightfield, the fraction of rays finished within n steps, fly-through and
walk-through.

Usage: plot_terrain_steps.py STEPS.json OUT.png
"""
import json
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

runs = json.load(open(sys.argv[1]))
fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.5), dpi=110)
for r in runs:
    steps = np.asarray(r["steps"])
    label = f'{r["camera"]} ({r["size"]}²)'
    top = int(steps.max()) + 1
    ax1.hist(steps, bins=np.arange(0, min(top, 200) + 2) - 0.5, histtype="step", density=True, label=label)
    xs = np.arange(0, top + 1)
    ax2.plot(xs, [np.mean(steps <= x) for x in xs], label=label)
for ax in (ax1, ax2):
    ax.set_xlabel("steps per ray")
    ax.grid(True, alpha=0.3)
    ax.legend()
ax1.set_ylabel("fraction of rays")
ax1.set_title("steps per ray (quadtree traversal)")
ax2.axvline(16, color="grey", ls=":")
ax2.axvline(80, color="grey", ls=":")
ax2.set_ylabel("fraction of rays finished within n steps")
ax2.set_xscale("log")
ax2.set_title("cumulative (dotted: 16 and 80 steps)")
fig.tight_layout()
fig.savefig(sys.argv[2])
