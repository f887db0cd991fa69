//! Files volterra writes, read back by the independent reference libraries (nibabel,
//! tifffile, pyvista) through tests/reference/read_outputs.py.

mod common;

use common::repo_path;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;
use volterra_formats::{load, Dataset, LoadOptions};

/// The reference venv's Python; under CI a missing venv is a failure.
fn python() -> Option<PathBuf> {
    let py = repo_path("tests/reference/.venv/bin/python");
    if py.exists() {
        return Some(py);
    }
    if std::env::var("CI").is_ok_and(|v| v == "true" || v == "1") {
        panic!("{} not found (CI=true: run tests/run.sh, which creates it)", py.display());
    }
    eprintln!("SKIPPED: {} not found (run python3 tests/setup_venv.py)", py.display());
    None
}

fn read_with_reference(py: &Path, kind: &str, path: &Path) -> Value {
    let out = Command::new(py).arg(repo_path("tests/reference/read_outputs.py")).arg(kind).arg(path).output().unwrap();
    assert!(out.status.success(), "{kind} {}: {}", path.display(), String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).unwrap()
}

fn floats(v: &Value) -> Vec<f64> {
    v.as_array().unwrap().iter().map(|x| x.as_f64().unwrap_or(f64::NAN)).collect()
}

#[test]
fn nibabel_reads_our_nifti_exactly() {
    let Some(py) = python() else { return };
    let dir = tempfile::tempdir().unwrap();
    // (source, output, whether its affine is a rotation times a scale, so a qform exists)
    for (src, out, rigid) in [
        ("dicom/oblique", "oblique.nii.gz", true),
        ("nifti/qform_only.nii", "qform.nii", true),
        ("nifti/scaled.nii", "scaled.nii", false),
        ("nifti/f32_nifti2_be.nii.gz", "f32.nii", false),
    ] {
        let Dataset::Volume(v) = load(&repo_path("tests/fixtures").join(src), &LoadOptions::default()).unwrap() else { panic!() };
        let p = dir.path().join(out);
        volterra_formats::nifti::write_nifti(&p, &v).unwrap();
        let r = read_with_reference(&py, "nifti", &p);
        assert_eq!(r["shape"], serde_json::json!(v.dims), "{src}");
        let values = floats(&r["values"]);
        assert!((0..v.voxel_count()).all(|i| v.data.stored(i) == values[i]), "{src}: voxel values");
        let mut checks = vec![&r["affine"]];
        if rigid {
            checks.push(&r["qform"]);
        }
        for a in checks {
            let want = &v.affine;
            for i in 0..4 {
                for j in 0..4 {
                    let got = a[i][j].as_f64().unwrap();
                    assert!((got - want[i][j]).abs() < 1e-4, "{src}: affine[{i}][{j}] {got} vs {}", want[i][j]);
                }
            }
        }
        // A sheared affine has no qform: it must be left out (code 0), not written wrong.
        assert_eq!((r["sform_code"].as_i64(), r["qform_code"].as_i64()), (Some(1), Some(rigid as i64)), "{src}");
        if !v.rescale.is_identity() {
            assert_eq!(r["slope"].as_f64().unwrap() as f32, v.rescale.slope as f32);
            assert_eq!(r["inter"].as_f64().unwrap() as f32, v.rescale.intercept as f32);
        }
    }
}

/// `convert … out.nrrd`: pynrrd reads our NRRD's values, space and geometry (the axis
/// vectors are the affine's columns, in RAS); a rescaled volume is written as its real
/// values in float; our own reader reads it back to the same volume.
#[test]
fn pynrrd_reads_our_nrrd() {
    let Some(py) = python() else { return };
    let dir = tempfile::tempdir().unwrap();
    for (src, out) in [("dicom/oblique", "oblique.nrrd"), ("nifti/scaled.nii", "scaled.nrrd"), ("nifti/f32_nifti2_be.nii.gz", "f32.nrrd")] {
        let Dataset::Volume(v) = load(&repo_path("tests/fixtures").join(src), &LoadOptions::default()).unwrap() else { panic!() };
        let p = dir.path().join(out);
        volterra_formats::nrrd::write_nrrd(&p, &v).unwrap();
        let r = read_with_reference(&py, "nrrd", &p);
        assert_eq!(r["shape"], serde_json::json!(v.dims), "{src}");
        assert_eq!(r["space"], "right-anterior-superior");
        let values = floats(&r["values"]);
        assert_eq!(values.len(), v.voxel_count());
        for (i, got) in values.iter().enumerate() {
            let want = if v.rescale.is_identity() { v.data.stored(i) } else { v.value(i) as f32 as f64 };
            assert_eq!(*got, want, "{src}: voxel {i}");
        }
        for c in 0..3 {
            for row in 0..3 {
                assert!((r["directions"][c][row].as_f64().unwrap() - v.affine[row][c]).abs() < 1e-9, "{src}: axis {c}");
            }
            assert!((r["origin"][c].as_f64().unwrap() - v.affine[c][3]).abs() < 1e-9, "{src}: origin");
        }
        let Dataset::Volume(back) = load(&p, &LoadOptions::default()).unwrap() else { panic!() };
        assert_eq!((back.dims, back.affine), (v.dims, v.affine), "{src}");
        assert!((0..v.voxel_count()).all(|i| back.value(i) == values[i]), "{src}: read back");
    }
}

#[test]
fn tifffile_reads_our_geotiff_with_its_georeferencing() {
    let Some(py) = python() else { return };
    let dir = tempfile::tempdir().unwrap();
    let Dataset::Heightfield(h) = load(&repo_path("tests/fixtures/geotiff/i16_none_strips.tif"), &LoadOptions::default()).unwrap() else {
        panic!()
    };
    let p = dir.path().join("out.tif");
    volterra_formats::geotiff::write_geotiff(&p, &h).unwrap();
    let r = read_with_reference(&py, "geotiff", &p);
    assert_eq!(r["shape"], serde_json::json!([h.height, h.width]));
    assert_eq!(r["dtype"], "float32");
    assert_eq!(floats(&r["scale"])[..2], h.cell_size_native);
    let tie = floats(&r["tiepoint"]);
    assert_eq!([tie[3] + 0.5 * h.cell_size_native[0], tie[4] - 0.5 * h.cell_size_native[1]], h.origin);
    assert_eq!(r["epsg"].as_u64(), h.crs.epsg.map(u64::from));
    let nodata: f64 = r["nodata"].as_str().unwrap().parse().unwrap();
    let values = floats(&r["values"]);
    for (i, &z) in h.elevations.iter().enumerate() {
        if h.nodata.get(i) {
            assert_eq!(values[i], nodata);
        } else {
            assert_eq!(values[i], z as f64);
        }
    }
}

#[test]
fn pyvista_reads_our_vtp() {
    let Some(py) = python() else { return };
    let dir = tempfile::tempdir().unwrap();
    let Dataset::Particles(p) = load(&repo_path("tests/fixtures/vtk/legacy_binary_51.vtk"), &LoadOptions::default()).unwrap() else {
        panic!()
    };
    let out = dir.path().join("out.vtp");
    volterra_formats::vtk::write_vtp(&out, &p, &Default::default()).unwrap();
    let r = read_with_reference(&py, "vtp", &out);
    assert_eq!(r["count"].as_u64(), Some(p.len() as u64));
    assert_eq!(r["n_verts"].as_u64(), Some(p.len() as u64));
    let pos: Vec<f64> = p.positions.iter().flat_map(|q| q.iter().copied()).collect();
    assert_eq!(floats(&r["positions"]), pos);
    assert_eq!(floats(&r["arrays"]["h"]), p.smoothing_length.as_ref().unwrap().iter().map(|&x| x as f64).collect::<Vec<_>>());
    assert_eq!(floats(&r["arrays"]["velocity"]), p.arrays.iter().find(|a| a.name == "velocity").unwrap().values);
}
