#!/usr/bin/env bash
# The Python package (python/): built by maturin into the reference venv (the dev profile,
# so it shares target/ with the Rust build) and tested by pytest against nibabel, pydicom,
# pyvista and tifffile. Prints pytest's results as a cargo-style "test result:" line too,
# which tests/run.sh adds to its summary.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=tests/reference/.venv
export VIRTUAL_ENV="$PWD/$VENV"
"$VENV/bin/maturin" develop --quiet --manifest-path python/Cargo.toml 2>&1 | tail -3
mkdir -p target
# The command the scene tests compare against (CARGO_TARGET_DIR or a config may move it).
TARGET_DIR=$(cargo metadata --format-version 1 --no-deps | "$VENV/bin/python" -c 'import json, sys; print(json.load(sys.stdin)["target_directory"])')
export VOLTERRA_BIN="${VOLTERRA_BIN:-$TARGET_DIR/debug/volterra}"
set +e
"$VENV/bin/python" -m pytest python/tests -q -p no:cacheprovider --disable-warnings --junitxml=target/pytest.xml
status=$?
set -e
"$VENV/bin/python" - <<'PY'
import xml.etree.ElementTree as ET
suite = ET.parse("target/pytest.xml").getroot()
suite = suite if suite.tag == "testsuite" else suite[0]
n, f, e, s = (int(suite.get(k, 0)) for k in ("tests", "failures", "errors", "skipped"))
print(f"test result: {'ok' if f + e == 0 else 'FAILED'}. {n - f - e - s} passed; {f + e} failed; {s} ignored (pytest, python/tests)")
PY
exit "$status"
