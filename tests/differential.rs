//! Differential test against pydicom and nibabel: every image-bearing file of their own test
//! suites (read in place from the reference venv) and every DICOM and NIfTI file in
//! ../shared/data, converted by volterra and compared value by value, dims and affine, with
//! what the reference library reads (tests/reference/differential.py). Regenerates
//! docs/differential.md; fails on any file read wrong, crashed on, or refused without a
//! stated justification.

mod common;

use common::{repo_path, under_ci};
use std::process::Command;

#[test]
fn readers_agree_with_pydicom_and_nibabel_on_their_test_suites() {
    let python = repo_path("tests/reference/.venv/bin/python");
    if !python.exists() {
        if under_ci() {
            panic!("{} is missing (CI=true: tests/setup_venv.py makes it)", python.display());
        }
        eprintln!("SKIPPED: no reference venv at {} (run python3 tests/setup_venv.py)", python.display());
        return;
    }
    let mut cmd = Command::new(&python);
    cmd.arg(repo_path("tests/reference/differential.py")).arg(common::volterra_bin()).arg(repo_path("docs/differential.md"));
    if let Some(shared) = common::shared_data() {
        cmd.arg(shared);
    }
    let out = cmd.output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    println!("{stdout}");
    assert!(out.status.success(), "files read wrong or refused without reason:\n{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
}
