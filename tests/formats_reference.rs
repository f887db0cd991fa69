//! Every file in ../shared/data read by volterra and compared with what the independent
//! reference readers (nibabel, pydicom, tifffile, imagecodecs, pyvista) recorded in
//! tests/reference/data/shared_data.json (made by tests/reference/make_references.py).

mod common;

use common::*;
use serde_json::Value;
use volterra_formats::{load, png_height::PngHeightOptions, Dataset, LoadOptions};

/// Lossy-compressed inputs: decoders may differ by an IDCT rounding step (see
/// `twelve_bit_jpeg_is_read_as_libjpeg_turbo_decodes_it` for the 12-bit one).
const LOSSY: &[&str] = &["volumes/dicom_real/pydicom/SC_rgb_jpeg_dcmtk.dcm", "volumes/dicom_real/pydicom/JPGExtended.dcm"];
/// Inputs the reference reads but volterra refuses, with the error text expected (none: the
/// 12-bit lossy JPEG once here is read by libjpeg-turbo 3, value-equal to pydicom's decode).
const KNOWN_UNSUPPORTED: &[(&str, &str)] = &[];

fn references() -> Value {
    let text = std::fs::read_to_string(repo_path("tests/reference/data/shared_data.json")).expect("reference file");
    serde_json::from_str(&text).unwrap()
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or(f64::NAN)
}

fn check_fingerprint(what: &str, values: &[f64], r: &Value, tol: f64, errors: &mut Vec<String>) {
    let fp = fingerprint(values.iter().copied());
    if fp.count != r["count"].as_u64().unwrap() as usize {
        errors.push(format!("{what}: {} values, reference {}", fp.count, r["count"]));
        return;
    }
    let sum_tol = if tol == 0.0 { 1e-9 } else { 1e-3 };
    if !close(fp.sum, f(&r["sum"]), sum_tol) {
        errors.push(format!("{what}: sum {} vs reference {}", fp.sum, r["sum"]));
    }
    if !close(fp.wsum, f(&r["wsum"]), sum_tol) {
        errors.push(format!("{what}: weighted sum {} vs reference {} (order differs?)", fp.wsum, r["wsum"]));
    }
    for s in r["samples"].as_array().unwrap() {
        let i = s[0].as_u64().unwrap() as usize;
        let want = f(&s[1]);
        let got = values[i];
        let ok = if want.is_nan() { got.is_nan() } else { (got - want).abs() <= tol };
        if !ok {
            errors.push(format!("{what}: value[{i}] = {got}, reference {want}"));
        }
    }
}

fn options_for(rel: &str) -> LoadOptions {
    let mut o = LoadOptions::default();
    if rel.ends_with("ps_height_1k.png") {
        o.png = PngHeightOptions { vertical_scale: Some(0.1), cell_size: Some(160.0), ..Default::default() };
    }
    o
}

#[test]
fn every_shared_file_matches_the_reference_readers() {
    let Some(data) = shared_data() else { return };
    let refs = references();
    let mut errors = Vec::new();
    let mut checked = 0;
    for (rel, r) in refs.as_object().unwrap() {
        if r["kind"] == "texture" {
            let img = volterra_formats::image::read_rgb_png(&data.join(rel), &Default::default()).unwrap();
            let v: Vec<f64> = img.data.iter().map(|&b| b as f64).collect();
            check_fingerprint(rel, &v, &r["rgb"], 0.0, &mut errors);
            checked += 1;
            continue;
        }
        let path = data.join(rel);
        let loaded = load(&path, &options_for(rel));
        if let Some((_, msg)) = KNOWN_UNSUPPORTED.iter().find(|(p, _)| p == rel) {
            match loaded {
                Err(e) if e.to_string().contains(msg) => checked += 1,
                other => errors.push(format!("{rel}: expected error containing '{msg}', got {:?}", other.map(|_| "a dataset"))),
            }
            continue;
        }
        let d = match loaded {
            Ok(d) => d,
            Err(e) => {
                errors.push(format!("{rel}: volterra failed: {e}"));
                continue;
            }
        };
        let before = errors.len();
        match (&d, r["kind"].as_str().unwrap()) {
            (Dataset::Volume(v), "volume") => check_volume(rel, v, r, &mut errors),
            (Dataset::Heightfield(h), "heightfield") => check_heightfield(rel, h, r, &mut errors),
            (Dataset::Particles(p), "particles") => check_particles(rel, p, r, &mut errors),
            (_, k) => errors.push(format!("{rel}: volterra read a different kind than the reference ({k})")),
        }
        if errors.len() == before {
            checked += 1;
        }
    }
    assert!(errors.is_empty(), "{} mismatches:\n{}", errors.len(), errors.join("\n"));
    assert_eq!(checked, refs.as_object().unwrap().len());
    eprintln!("{checked} files agree with the reference readers");
}

fn check_volume(rel: &str, v: &volterra_formats::Volume, r: &Value, errors: &mut Vec<String>) {
    let dims: Vec<usize> = r["dims"].as_array().unwrap().iter().map(|x| x.as_u64().unwrap() as usize).collect();
    if v.dims.to_vec() != dims {
        errors.push(format!("{rel}: dims {:?} vs reference {dims:?}", v.dims));
        return;
    }
    if v.data.scalar_type().name() != r["dtype"].as_str().unwrap() {
        errors.push(format!("{rel}: dtype {} vs reference {}", v.data.scalar_type().name(), r["dtype"]));
    }
    for i in 0..4 {
        for j in 0..4 {
            let want = f(&r["affine"][i][j]);
            if (v.affine[i][j] - want).abs() > 1e-5 {
                errors.push(format!("{rel}: affine[{i}][{j}] = {} vs reference {want}", v.affine[i][j]));
            }
        }
    }
    if !close(v.rescale.slope, f(&r["rescale"]["slope"]), 1e-12) || !close(v.rescale.intercept, f(&r["rescale"]["intercept"]), 1e-12) {
        errors.push(format!("{rel}: rescale {:?} vs reference {}", v.rescale, r["rescale"]));
    }
    if let Some(c) = r.get("volume_count") {
        if v.volume_count as u64 != c.as_u64().unwrap() {
            errors.push(format!("{rel}: {} volumes vs reference {c}", v.volume_count));
        }
    }
    let lossy = LOSSY.contains(&rel);
    let stored: Vec<f64> = (0..v.voxel_count()).map(|i| v.data.stored(i)).collect();
    check_fingerprint(rel, &stored, &r["stored"], if lossy { 2.0 } else { 0.0 }, errors);
    let (min, max) = v.value_range().unwrap();
    let tol = if lossy { 1e-2 } else { 1e-9 };
    if !close(min, f(&r["min"]), tol) || !close(max, f(&r["max"]), tol) {
        errors.push(format!("{rel}: range {min}..{max} vs reference {}..{}", r["min"], r["max"]));
    }
}

fn check_heightfield(rel: &str, h: &volterra_formats::Heightfield, r: &Value, errors: &mut Vec<String>) {
    if [h.width as u64, h.height as u64] != [r["dims"][0].as_u64().unwrap(), r["dims"][1].as_u64().unwrap()] {
        errors.push(format!("{rel}: dims {}x{} vs reference {}", h.width, h.height, r["dims"]));
        return;
    }
    if let Some(cs) = r.get("cell_size_native") {
        for a in 0..2 {
            if !close(h.cell_size_native[a], f(&cs[a]), 1e-12) || !close(h.origin[a], f(&r["origin"][a]), 1e-12) {
                errors.push(format!("{rel}: cell {:?} origin {:?} vs reference {cs} {}", h.cell_size_native, h.origin, r["origin"]));
            }
        }
        if h.crs.epsg.map(u64::from) != r["epsg"].as_u64() || h.crs.geographic != r["geographic"].as_bool().unwrap() {
            errors.push(format!("{rel}: crs {:?} vs reference EPSG {} geographic {}", h.crs, r["epsg"], r["geographic"]));
        }
        if h.nodata_value != r["nodata_value"].as_f64() || h.nodata_count() as u64 != r["nodata_count"].as_u64().unwrap() {
            errors.push(format!(
                "{rel}: nodata {:?} ×{} vs reference {} ×{}",
                h.nodata_value,
                h.nodata_count(),
                r["nodata_value"],
                r["nodata_count"]
            ));
        }
    }
    let elev: Vec<f64> = h.elevations.iter().map(|&z| z as f64).collect();
    check_fingerprint(rel, &elev, &r["elevation"], 0.0, errors);
}

fn check_particles(rel: &str, p: &volterra_formats::ParticleSet, r: &Value, errors: &mut Vec<String>) {
    if p.len() as u64 != r["count"].as_u64().unwrap() {
        errors.push(format!("{rel}: {} particles vs reference {}", p.len(), r["count"]));
        return;
    }
    let pos: Vec<f64> = p.positions.iter().flat_map(|q| q.iter().copied()).collect();
    check_fingerprint(&format!("{rel} positions"), &pos, &r["positions"], 0.0, errors);
    let names = volterra_formats::ParticleArrayNames::default();
    let mut ours = p.array_names(&names);
    ours.sort();
    let mut theirs: Vec<String> = r["arrays"].as_object().unwrap().keys().cloned().collect();
    theirs.sort();
    if ours != theirs {
        errors.push(format!("{rel}: arrays {ours:?} vs reference {theirs:?}"));
        return;
    }
    for (name, a) in r["arrays"].as_object().unwrap() {
        let sph = [(&names.mass, &p.mass), (&names.density, &p.density), (&names.smoothing_length, &p.smoothing_length)];
        let values: Vec<f64> = match sph.iter().find(|(n, _)| *n == name) {
            Some((_, v)) => v.as_ref().unwrap().iter().map(|&x| x as f64).collect(),
            None => p.arrays.iter().find(|x| &x.name == name).unwrap().values.clone(),
        };
        check_fingerprint(&format!("{rel} {name}"), &values, &a["values"], 0.0, errors);
    }
}

/// The aneurism as a DICOM series (LPS, HU = 8·v − 1024) and as NIfTI (RAS, raw v): the
/// same anatomy must land at the same world coordinates with the same values.
#[test]
fn dicom_and_nifti_of_the_same_anatomy_agree_in_world_space() {
    let Some(data) = shared_data() else { return };
    let opts = LoadOptions::default();
    let Dataset::Volume(d) = load(&data.join("volumes/aneurism/dicom_ct"), &opts).unwrap() else { panic!() };
    let Dataset::Volume(n) = load(&data.join("volumes/aneurism/aneurism.nii.gz"), &opts).unwrap() else { panic!() };
    let inv = invert_affine(&n.affine);
    let mut compared = 0;
    for k in (0..d.dims[2]).step_by(7) {
        for j in (0..d.dims[1]).step_by(5) {
            for i in (0..d.dims[0]).step_by(3) {
                let w = d.index_to_world([i as f64, j as f64, k as f64]);
                let ijk: Vec<f64> = (0..3).map(|r| inv[r][0] * w[0] + inv[r][1] * w[1] + inv[r][2] * w[2] + inv[r][3]).collect();
                let idx: Vec<usize> = ijk.iter().map(|x| x.round() as usize).collect();
                for a in 0..3 {
                    assert!((ijk[a] - idx[a] as f64).abs() < 1e-6, "world point {w:?} is not on the NIfTI grid: {ijk:?}");
                }
                let hu = d.value(d.index(i, j, k));
                let raw = n.value(n.index(idx[0], idx[1], idx[2]));
                assert_eq!(hu, 8.0 * raw - 1024.0, "voxel ({i},{j},{k}) vs NIfTI {idx:?}");
                compared += 1;
            }
        }
    }
    assert!(compared > 100_000);
}

fn invert_affine(m: &volterra_formats::Affine) -> [[f64; 4]; 3] {
    let inv = glam::DMat4::from_cols_array_2d(m).transpose().inverse().transpose().to_cols_array_2d();
    [inv[0], inv[1], inv[2]]
}

/// 12-bit lossy JPEG (JPEG Extended, refused before: jpeg-decoder has no 12-bit DCT) is
/// read by libjpeg-turbo 3: every sample equal to imagecodecs' decode (a libjpeg-turbo 3
/// built apart from ours), and within one grey level of pydicom's (pylibjpeg's libjpeg,
/// whose IDCT rounds otherwise: 3612 of 262 144 samples differ by 1 on JPGExtended.dcm).
#[test]
fn twelve_bit_jpeg_is_read_as_libjpeg_turbo_decodes_it() {
    let Some(data) = shared_data() else { return };
    let python = repo_path("tests/reference/.venv/bin/python");
    if !python.exists() {
        assert!(!under_ci(), "{} is missing (CI=true: tests/setup_venv.py makes it)", python.display());
        eprintln!("SKIPPED: no reference venv at {}", python.display());
        return;
    }
    let dcm = data.join("volumes/dicom_real/pydicom/JPGExtended.dcm");
    let dir = tempfile::tempdir().unwrap();
    let nii = dir.path().join("jpeg12.nii");
    let vol = match load(&dcm, &LoadOptions::default()).unwrap() {
        Dataset::Volume(v) => v,
        _ => panic!("a volume"),
    };
    assert_eq!((vol.dims, vol.data.scalar_type().name()), ([256, 1024, 1], "u16"));
    volterra_formats::nifti::write_nifti(&nii, &vol).unwrap();
    let out =
        std::process::Command::new(&python).arg(repo_path("tests/reference/jpeg12_decoders.py")).arg(&dcm).arg(&nii).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let r: Value = serde_json::from_slice(&out.stdout).unwrap();
    eprintln!("{r}");
    assert_eq!(r["libjpeg_turbo"]["differing"], 0, "{r}");
    assert!(r["pydicom"]["max_abs"].as_u64().unwrap() <= 1, "{r}");
    let differing = r["pydicom"]["differing"].as_f64().unwrap() / r["pydicom"]["samples"].as_f64().unwrap();
    assert!(differing < 0.02, "{r}");
}
