#!/usr/bin/env bash
# Fuzzes every reader for a bounded time: bash tests/fuzz.sh [SECONDS_PER_TARGET] [TARGET...]
#
# cargo-fuzz (libFuzzer) on the stable toolchain, so without AddressSanitizer (`-s none`):
# Rust's own checks catch out-of-bounds access, overflow (debug assertions are on), and
# panics; libFuzzer adds hangs (-timeout) and memory blow-ups (-rss_limit_mb). Every input
# that crashes is kept under fuzz/artifacts/<target>/; fix the reader, then copy the input
# to fuzz/regressions/<target>/, where tests/fuzz_regressions.rs replays it on every test run.
set -euo pipefail
cd "$(dirname "$0")/.."
SECONDS_PER_TARGET="${1:-60}"
shift || true
TARGETS=("$@")
if [ ${#TARGETS[@]} -eq 0 ]; then
    TARGETS=(dicom_file dicom_series nifti nifti_gz geotiff geotiff_sidecars png_height vtk_legacy vtk_xml vtk_image metaimage nrrd)
fi
SHARED="${VOLTERRA_SHARED_DATA:-$(cd .. && pwd)/shared/data}"
if [ ! -d "$SHARED" ]; then
    if [ "${CI:-}" = "true" ]; then
        echo "fuzz: $SHARED is missing; the seed corpus needs ../shared/data under CI" >&2
        exit 1
    fi
    echo "fuzz: $SHARED is missing; seeding from the fixtures only"
fi

CARGO_FUZZ_VERSION=0.13.2
if ! cargo fuzz --version 2>/dev/null | grep -q "$CARGO_FUZZ_VERSION"; then
    cargo install cargo-fuzz --version "$CARGO_FUZZ_VERSION" --locked
fi

python3 fuzz/make_seeds.py fuzz/seeds "$SHARED"
cargo fuzz build -O -s none
mkdir -p target/fuzz-logs

run_target() {
    local t="$1" secs="$2"
    rm -rf "fuzz/artifacts/$t"
    mkdir -p "fuzz/corpus/$t" "fuzz/artifacts/$t"
    # One thread per fuzzer: two fuzzers share the two cores.
    RAYON_NUM_THREADS=1 cargo fuzz run -O -s none "$t" "fuzz/corpus/$t" "fuzz/seeds/$t" -- \
        -max_total_time="$secs" -max_len=1048576 -timeout=10 -rss_limit_mb=2048 \
        -print_final_stats=1 -artifact_prefix="fuzz/artifacts/$t/" \
        > "target/fuzz-logs/$t.log" 2>&1
}
export -f run_target

set +e
printf '%s\n' "${TARGETS[@]}" | xargs -P 2 -I{} bash -c 'run_target "$1" "$2"' _ {} "$SECONDS_PER_TARGET"
set -e

failed=0
printf '%-14s %12s %10s %8s\n' target executions exec/s crashes
for t in "${TARGETS[@]}"; do
    log="target/fuzz-logs/$t.log"
    execs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$log" | grep -o '[0-9]*$' | tail -1)
    rate=$(grep -o 'stat::average_exec_per_sec: *[0-9]*' "$log" | grep -o '[0-9]*$' | tail -1)
    crashes=$(find "fuzz/artifacts/$t" -type f | wc -l)
    printf '%-14s %12s %10s %8s\n' "$t" "${execs:-?}" "${rate:-?}" "$crashes"
    if [ "$crashes" -gt 0 ] || [ -z "$execs" ]; then
        failed=1
        echo "fuzz: $t failed; its log: $log" >&2
        grep -m 5 -E 'panicked|ERROR: libFuzzer|SUMMARY|Test unit written' "$log" >&2 || tail -20 "$log" >&2
    fi
done
if [ "$failed" -ne 0 ]; then
    echo "fuzz: crashes found (inputs under fuzz/artifacts/); fix them and add the inputs to fuzz/regressions/" >&2
    exit 1
fi
echo "fuzz: ${#TARGETS[@]} targets, ${SECONDS_PER_TARGET} s each, no crashes"
