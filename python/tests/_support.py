"""What the package's tests share: where the shared data and the `volterra` command are,
and the two ways a test reaches them."""

import os
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SHARED = Path(os.environ.get("VOLTERRA_SHARED_DATA", ROOT / ".." / "shared" / "data")).resolve()
# tests/python.sh sets VOLTERRA_BIN where CARGO_TARGET_DIR or a config moves target/.
VOLTERRA = Path(os.environ.get("VOLTERRA_BIN", ROOT / "target" / "debug" / "volterra"))


def shared(rel=""):
    """A path of ../shared/data: under CI=true its absence fails the test, locally it skips."""
    path = SHARED / rel
    if not path.exists():
        if os.environ.get("CI") == "true":
            pytest.fail(f"{path} is missing: the shared data must sit beside the checkout (../shared/data)")
        pytest.skip(f"{path} not here")
    return path


def cli(*args):
    """Runs the volterra command quietly and returns its stdout; its failure fails the
    test with its stderr."""
    if not VOLTERRA.exists():
        pytest.fail(f"{VOLTERRA} is missing: build it first (cargo build --workspace --bins)")
    r = subprocess.run([str(VOLTERRA), "-q", *map(str, args)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return r.stdout
