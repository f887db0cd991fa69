#!/usr/bin/env bash
# The test command: installs what the tests need, checks that the committed reference
# files regenerate from their scripts, then runs every Rust test.
set -euo pipefail
cd "$(dirname "$0")/.."
bash tests/setup-system.sh
python3 tests/setup_venv.py
VENV_PY=tests/reference/.venv/bin/python
SHARED="${VOLTERRA_SHARED_DATA:-$(cd .. && pwd)/shared/data}"
"$VENV_PY" tests/reference/check_references.py "$SHARED" target/reference-regen
cargo test --workspace --no-fail-fast
