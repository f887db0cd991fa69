"""Writes src/render/colormap/tables.rs: matplotlib's viridis, magma, coolwarm, hot and rainbow sampled
at 33 evenly spaced values, converted from sRGB to linear RGB (volterra's frames are linear;
the PNG preview encodes them back to sRGB). Re-run with the test venv's Python:
    tests/reference/.venv/bin/python tests/reference/make_colormaps.py
"""
import os
import matplotlib

N = 33


def linear(c):
    return c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4


out = ["//! matplotlib's viridis, magma, coolwarm, hot and rainbow at 33 evenly spaced values, in linear RGB.",
       "//! Written by tests/reference/make_colormaps.py; do not edit.", ""]
for name in ["viridis", "magma", "coolwarm", "hot", "rainbow"]:
    cmap = matplotlib.colormaps[name]
    out.append(f"pub const {name.upper()}: [[f32; 3]; {N}] = [")
    for i in range(N):
        r, g, b, _ = cmap(i / (N - 1))
        out.append(f"    [{linear(r):.6}, {linear(g):.6}, {linear(b):.6}],")
    out.append("];")
    out.append("")
path = os.path.join(os.path.dirname(__file__), "..", "..", "src", "render", "colormap", "tables.rs")
with open(path, "w") as f:
    f.write("\n".join(out))
print(f"wrote {os.path.normpath(path)}")
