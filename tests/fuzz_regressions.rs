//! Replays every input that once crashed a reader under the fuzzer (fuzz/regressions/<target>/)
//! through the same harness the fuzz targets use (fuzz/src/harness.rs), on stable Rust and
//! without libFuzzer: each must now give an error or valid data, never a panic.

#[path = "../fuzz/src/harness.rs"]
mod harness;

use std::path::Path;

#[test]
fn every_fuzz_regression_input_is_handled() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/regressions");
    let mut replayed = 0;
    for target in harness::TARGETS {
        let dir = root.join(target);
        let Ok(entries) = std::fs::read_dir(&dir) else { continue };
        for entry in entries {
            let path = entry.unwrap().path();
            let data = std::fs::read(&path).unwrap();
            let outcome = std::panic::catch_unwind(|| harness::run(target, &data));
            assert!(outcome.is_ok(), "{target}: {} still fails", path.display());
            replayed += 1;
        }
    }
    assert!(replayed >= 6, "only {replayed} regression inputs found under {}", root.display());
}
