//! `volterra convert` then read back: the same data, for every writer. Runs the real CLI
//! binary so the command-line path (exit codes, temporary files) is covered too.

mod common;

use common::repo_path;
use std::path::{Path, PathBuf};
use std::process::Command;
use volterra_formats::{exr_io, load, Dataset, LoadOptions};

fn volterra(args: &[&str]) -> std::process::Output {
    Command::new(common::volterra_bin()).args(args).output().unwrap()
}

fn convert(input: &Path, output: &Path) {
    let out = volterra(&["convert", input.to_str().unwrap(), output.to_str().unwrap()]);
    assert!(out.status.success(), "convert failed: {}", String::from_utf8_lossy(&out.stderr));
    // No temporary file may be left beside the output.
    let leftovers: Vec<PathBuf> = std::fs::read_dir(output.parent().unwrap())
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.to_string_lossy().ends_with(".tmp"))
        .collect();
    assert!(leftovers.is_empty(), "temporary files left: {leftovers:?}");
}

fn read(p: &Path) -> Dataset {
    load(p, &LoadOptions::default()).unwrap()
}

#[test]
fn volumes_round_trip_through_nifti_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let fx = repo_path("tests/fixtures");
    for (src, out) in [
        ("dicom/oblique", "oblique.nii.gz"),
        ("nifti/f64_nifti2_be.nii.gz", "f64.nii"),
        ("nifti/i8_pair.hdr", "i8.nii.gz"),
        ("nifti/u32_nifti1.nii", "u32.nii"),
        ("nifti/scaled.nii", "scaled.nii"),
        ("nifti/qform_only.nii", "qform.nii"),
    ] {
        let out = dir.path().join(out);
        convert(&fx.join(src), &out);
        let (Dataset::Volume(a), Dataset::Volume(b)) = (read(&fx.join(src)), read(&out)) else { panic!() };
        assert_eq!(a.dims, b.dims, "{src}");
        assert_eq!(a.data, b.data, "{src}: voxel values");
        assert_eq!(a.rescale.slope as f32, b.rescale.slope as f32, "{src}");
        assert_eq!(a.rescale.intercept as f32, b.rescale.intercept as f32, "{src}");
        for r in 0..4 {
            for c in 0..4 {
                // NIfTI-1 stores the affine as f32.
                assert!((a.affine[r][c] - b.affine[r][c]).abs() <= 1e-5 * a.affine[r][c].abs().max(1.0), "{src}: affine {r},{c}");
            }
        }
    }
}

#[test]
fn heightfields_round_trip_through_geotiff_and_exr() {
    let dir = tempfile::tempdir().unwrap();
    let fx = repo_path("tests/fixtures");
    let mut sources: Vec<String> = std::fs::read_dir(fx.join("geotiff"))
        .unwrap()
        .map(|e| format!("geotiff/{}", e.unwrap().file_name().to_string_lossy()))
        .filter(|n| n.ends_with(".tif") && load(&fx.join(n), &LoadOptions::default()).is_ok())
        .collect();
    sources.sort();
    assert!(sources.len() >= 8 && sources.iter().any(|s| s == "geotiff/f64_packbits.tif"), "{sources:?}");
    for src in &sources {
        let Dataset::Heightfield(a) = read(&fx.join(src)) else { panic!() };
        let tif = dir.path().join("out.tif");
        convert(&fx.join(src), &tif);
        let Dataset::Heightfield(b) = read(&tif) else { panic!() };
        assert_eq!((a.width, a.height), (b.width, b.height), "{src}");
        assert_eq!(a.origin, b.origin, "{src}");
        assert_eq!(a.cell_size_native, b.cell_size_native, "{src}");
        assert_eq!(a.crs.epsg, b.crs.epsg, "{src}");
        assert_eq!(a.crs.geographic, b.crs.geographic, "{src}");
        assert_eq!(a.nodata, b.nodata, "{src}");
        let same = a.elevations.iter().zip(&b.elevations).all(|(x, y)| x == y || (x.is_nan() && y.is_nan()));
        assert!(same, "{src}: elevations differ");

        // Converted by rows, strip by strip: the very file the raster held is written as.
        let held = dir.path().join("held.tif");
        volterra_formats::geotiff::write_geotiff(&held, &a).unwrap();
        assert!(std::fs::read(&held).unwrap() == std::fs::read(&tif).unwrap(), "{src}: not the file the raster held gives");

        let exr = dir.path().join("out.exr");
        convert(&fx.join(src), &exr);
        let img = exr_io::read_exr(&exr, &Default::default()).unwrap();
        let y = img.channel("Y").unwrap();
        assert!(a.elevations.iter().zip(y).all(|(x, y)| x == y || (x.is_nan() && y.is_nan())), "{src}: EXR elevations");
    }
}

#[test]
fn particles_round_trip_through_vtp() {
    let dir = tempfile::tempdir().unwrap();
    let fx = repo_path("tests/fixtures");
    for src in ["vtk/legacy_binary_42.vtk", "vtk/xml_appended_raw_zlib.vtu", "vtk/legacy_ascii_42.vtk"] {
        let out = dir.path().join("out.vtp");
        convert(&fx.join(src), &out);
        let (Dataset::Particles(a), Dataset::Particles(b)) = (read(&fx.join(src)), read(&out)) else { panic!() };
        assert_eq!(a.positions, b.positions, "{src}");
        assert_eq!(a.mass, b.mass, "{src}");
        assert_eq!(a.density, b.density, "{src}");
        assert_eq!(a.smoothing_length, b.smoothing_length, "{src}");
        assert_eq!(a.arrays, b.arrays, "{src}");
    }
}

#[test]
fn exr_keeps_every_named_channel() {
    let dir = tempfile::tempdir().unwrap();
    let mut img = volterra_formats::FloatImage::new(7, 5);
    for (k, name) in ["R", "G", "B", "A", "Z", "steps"].iter().enumerate() {
        img.add_channel(name, (0..35).map(|i| i as f32 * 0.5 + k as f32).collect());
    }
    let p = dir.path().join("c.exr");
    exr_io::write_exr(&p, &img).unwrap();
    let back = exr_io::read_exr(&p, &Default::default()).unwrap();
    for (name, v) in &img.channels {
        assert_eq!(back.channel(name).unwrap(), v.as_slice(), "channel {name}");
    }
}

#[test]
fn a_failed_conversion_leaves_no_output_and_exits_1() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.nii");
    let res = volterra(&["convert", repo_path("tests/fixtures/vtk/legacy_binary_42.vtk").to_str().unwrap(), out.to_str().unwrap()]);
    assert_eq!(res.status.code(), Some(1));
    let err = String::from_utf8_lossy(&res.stderr);
    assert_eq!(err.lines().count(), 1, "one-line error: {err}");
    assert!(err.contains("x.nii") && err.contains("particle set converts to .vtp"), "{err}");
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
}
