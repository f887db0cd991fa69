#!/usr/bin/env bash
# Regenerates docs/benchmarks.md: every benchmark, one after another (about an hour on 2
# cores), each writing its section and its plot. Run from the checkout's root after
# `cargo build --workspace --bins` and `python3 tests/setup_venv.py`; ../shared/data beside
# the checkout. Nothing else should run meanwhile: the figures are timings.
set -euo pipefail
volterra=${VOLTERRA:-target/debug/volterra}
page=docs/benchmarks.md
"$volterra" bench formats --markdown "$page"
"$volterra" bench shear-warp --plot docs/images/bench_shear_warp.png --markdown "$page"
"$volterra" bench clinical --curve --plot docs/images/bench_clinical.png --markdown "$page"
"$volterra" bench gpu-volume --error --markdown "$page"
"$volterra" bench terrain --plot docs/images/bench_terrain.png --markdown "$page"
"$volterra" bench points --markdown "$page"
"$volterra" bench frames --markdown "$page"
"$volterra" bench smoke --markdown "$page"
