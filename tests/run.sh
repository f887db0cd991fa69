#!/usr/bin/env bash
# The test command: installs what the tests need, checks that the committed reference
# files regenerate from their scripts, runs every Rust test, fuzzes every reader for a
# bounded time, and prints one summary line ("N passed, M failed").
set -euo pipefail
cd "$(dirname "$0")/.."
bash tests/setup-system.sh
python3 tests/setup_venv.py
VENV_PY=tests/reference/.venv/bin/python
SHARED="${VOLTERRA_SHARED_DATA:-$(cd .. && pwd)/shared/data}"
"$VENV_PY" tests/reference/check_references.py "$SHARED" target/reference-regen
mkdir -p target
# Where cargo puts the binaries: CARGO_TARGET_DIR or a config may move them out of ./target.
TARGET_DIR=$(cargo metadata --format-version 1 --no-deps | "$VENV_PY" -c 'import json, sys; print(json.load(sys.stdin)["target_directory"])')
# A full build each run: cargo's incremental caches would only add GBs to a clean clone's disk.
export CARGO_INCREMENTAL=0
df -h . | awk 'NR == 2 { print "disk before the build: " $4 " free of " $2 }'
set +e
# The integration tests run the `volterra` binary, which lives in its own package
# (volterra-cli): `cargo test` builds only its test harness, so build the binary first.
cargo build --workspace --bins 2>&1 | tail -3
# The Python package's crate is a cdylib that only maturin links (tests/python.sh).
cargo test --workspace --all-targets --exclude volterra-python --no-fail-fast 2>&1 | tee target/test-output.log
status=${PIPESTATUS[0]}
# The Python package, built into the venv and tested by pytest; its counts join the summary.
bash tests/python.sh 2>&1 | tee target/python-output.log
[ "${PIPESTATUS[0]}" -eq 0 ] || status=1
grep '^test result:' target/python-output.log >> target/test-output.log || status=1
# The Mitsuba reference of the built-in plume, from the particles the built binary writes.
if [ -x "$TARGET_DIR/debug/volterra" ]; then
    "$VENV_PY" tests/reference/check_references.py --builtin "$TARGET_DIR/debug/volterra" target/reference-regen || status=1
else
    echo "no $TARGET_DIR/debug/volterra: built-in references not checked"; status=1
fi
set -e
echo "disk after the tests: $(df -h . | awk 'NR == 2 { print $4 }') free; $(du -sh "$TARGET_DIR" 2>/dev/null | cut -f1) in $TARGET_DIR"
# Every reader under libFuzzer for a bounded time (tests/fuzz.sh; 45 s per target, two at once).
set +e
bash tests/fuzz.sh "${VOLTERRA_FUZZ_SECONDS:-45}" 2>&1 | tee target/fuzz-output.log
fuzz_status=${PIPESTATUS[0]}
set -e
awk '/^test result:/ { for (i = 1; i <= NF; i++) { if ($(i+1) ~ /^passed/) p += $i; if ($(i+1) ~ /^failed/) f += $i } }
     END { printf "tests: %d passed, %d failed\n", p, f }' target/test-output.log
if [ "$fuzz_status" -ne 0 ]; then
    echo "fuzz: FAILED (see target/fuzz-output.log)"
    [ "$status" -ne 0 ] || status=$fuzz_status
fi
exit "$status"
