//! Synthetic files written by the reference libraries (tests/reference/make_fixtures.py)
//! covering every format variant, read by volterra and compared value by value with what
//! the same libraries read back (tests/fixtures/expected.json).

mod common;

use common::repo_path;
use serde_json::Value;
use volterra_formats::{dicom, load, Dataset, ErrorKind, LoadOptions};

fn expected() -> serde_json::Map<String, Value> {
    let text = std::fs::read_to_string(repo_path("tests/fixtures/expected.json")).unwrap();
    serde_json::from_str::<Value>(&text).unwrap().as_object().unwrap().clone()
}

fn floats(v: &Value) -> Vec<f64> {
    v.as_array().unwrap().iter().map(|x| x.as_f64().unwrap_or(f64::NAN)).collect()
}

fn same(a: f64, b: f64) -> bool {
    a == b || (a.is_nan() && b.is_nan())
}

#[test]
fn every_fixture_matches_its_reference_library() {
    let mut errors = Vec::new();
    let mut checked = 0;
    for (name, r) in expected() {
        let (file, volume_index) = match name.split_once('#') {
            Some((f, i)) => (f.to_string(), i.parse().unwrap()),
            None => (name.clone(), 0),
        };
        let path = repo_path("tests/fixtures").join(&file);
        let mut opts = LoadOptions::default();
        opts.nifti.volume_index = volume_index;
        match r["kind"].as_str().unwrap() {
            "volume" => {
                let v = match load(&path, &opts) {
                    Ok(Dataset::Volume(v)) => v,
                    other => {
                        errors.push(format!("{name}: {:?}", other.err()));
                        continue;
                    }
                };
                let dims: Vec<usize> = r["dims"].as_array().unwrap().iter().map(|x| x.as_u64().unwrap() as usize).collect();
                assert_eq!(v.dims.to_vec(), dims, "{name}");
                assert_eq!(v.data.scalar_type().name(), r["dtype"].as_str().unwrap(), "{name}");
                for i in 0..4 {
                    for j in 0..4 {
                        let want = r["affine"][i][j].as_f64().unwrap();
                        assert!((v.affine[i][j] - want).abs() < 1e-5, "{name}: affine[{i}][{j}] {} vs {want}", v.affine[i][j]);
                    }
                }
                let rs = floats(&r["rescale"]);
                assert!(
                    (v.rescale.slope - rs[0]).abs() < 1e-12 && (v.rescale.intercept - rs[1]).abs() < 1e-12,
                    "{name}: rescale {:?}",
                    v.rescale
                );
                let want = floats(&r["values"]);
                let bad = (0..want.len()).filter(|&i| !same(v.data.stored(i), want[i])).count();
                if bad > 0 {
                    errors.push(format!("{name}: {bad} voxels differ"));
                }
                if let Some(c) = r.get("volume_count") {
                    assert_eq!(v.volume_count as u64, c.as_u64().unwrap(), "{name}");
                }
            }
            "heightfield" => {
                let Ok(Dataset::Heightfield(h)) = load(&path, &opts) else {
                    errors.push(format!("{name}: not read as a heightfield: {:?}", load(&path, &opts).err()));
                    continue;
                };
                assert_eq!([h.width as u64, h.height as u64], [r["dims"][0].as_u64().unwrap(), r["dims"][1].as_u64().unwrap()], "{name}");
                assert_eq!(h.cell_size_native.to_vec(), floats(&r["cell_size"]), "{name}");
                assert_eq!(h.origin.to_vec(), floats(&r["origin"]), "{name}");
                assert_eq!(h.crs.epsg.map(u64::from), r["epsg"].as_u64(), "{name}");
                assert_eq!(h.crs.geographic, r["geographic"].as_bool().unwrap(), "{name}");
                assert_eq!(h.nodata_count() as u64, r["nodata_count"].as_u64().unwrap(), "{name}");
                let want = floats(&r["values"]);
                let bad = (0..want.len()).filter(|&i| !same(h.elevations[i] as f64, want[i] as f32 as f64)).count();
                if bad > 0 {
                    errors.push(format!("{name}: {bad} elevations differ"));
                }
            }
            "particles" => {
                let p = match load(&path, &opts) {
                    Ok(Dataset::Particles(p)) => p,
                    other => {
                        errors.push(format!("{name}: {:?}", other.err()));
                        continue;
                    }
                };
                assert_eq!(p.len() as u64, r["count"].as_u64().unwrap(), "{name}");
                let pos: Vec<f64> = p.positions.iter().flat_map(|q| q.iter().copied()).collect();
                assert_eq!(pos, floats(&r["positions"]), "{name}: positions");
                for (array, values) in r["arrays"].as_object().unwrap() {
                    let got: Vec<f64> = match array.as_str() {
                        "mass" => p.mass.clone().unwrap().iter().map(|&x| x as f64).collect(),
                        "density" => p.density.clone().unwrap().iter().map(|&x| x as f64).collect(),
                        "h" => p.smoothing_length.clone().unwrap().iter().map(|&x| x as f64).collect(),
                        _ => {
                            p.arrays.iter().find(|a| &a.name == array).unwrap_or_else(|| panic!("{name}: no array {array}")).values.clone()
                        }
                    };
                    assert_eq!(got, floats(values), "{name}: array {array}");
                }
            }
            "error" => {
                let err = load(&path, &opts).expect_err(&name);
                assert_eq!(err.kind, ErrorKind::Invalid, "{name}: {err}");
                let msg = err.to_string();
                let expect =
                    if name.contains("missing") { "1 slice(s) missing between 2.000 and 4.000 mm" } else { "non-uniform slice spacing" };
                assert!(msg.contains(expect) && msg.contains("--resample"), "{name}: {msg}");
                // With resampling the volume loads on a uniform grid.
                opts.dicom.resample = true;
                let Ok(Dataset::Volume(v)) = load(&path, &opts) else { panic!("{name}: resample failed") };
                let pos = floats(&r["positions"]);
                let span = pos[pos.len() - 1] - pos[0];
                assert!((v.affine[2][2] * (v.dims[2] - 1) as f64 - span).abs() <= v.affine[2][2] + 1e-9, "{name}: {:?}", v.affine);
                // Slice values are 10·k at position pos[k]: check linear interpolation.
                for k in 0..v.dims[2] {
                    let z = k as f64 * v.affine[2][2];
                    let seg = pos.windows(2).position(|w| z <= w[1] + 1e-9).unwrap();
                    let t = (z - pos[seg]) / (pos[seg + 1] - pos[seg]);
                    let want = 10.0 * (seg as f64 + t) - 1024.0;
                    assert!((v.value(v.index(0, 0, k)) - want).abs() < 1e-3, "{name}: slice {k}");
                }
            }
            "series_list" => {
                let list = dicom::list_series(&path, &Default::default()).unwrap();
                let uids: Vec<&str> = list.iter().map(|s| s.uid.as_str()).collect();
                assert_eq!(uids, r["uids"].as_array().unwrap().iter().map(|u| u.as_str().unwrap()).collect::<Vec<_>>());
                let err = load(&path, &opts).expect_err("two series need a choice");
                assert_eq!(err.kind, ErrorKind::Ambiguous);
                assert!(err.to_string().contains("--series"), "{err}");
                opts.dicom.series = Some("1.2.3.4.302".into());
                let Ok(Dataset::Volume(v)) = load(&path, &opts) else { panic!() };
                assert_eq!(v.value(v.index(0, 0, 2)), 102.0 - 1024.0);
                opts.dicom.series = Some("1".into());
                let Ok(Dataset::Volume(v)) = load(&path, &opts) else { panic!() };
                assert_eq!(v.value(v.index(0, 0, 1)), 1.0 - 1024.0);
            }
            k => panic!("unknown kind {k}"),
        }
        checked += 1;
    }
    assert!(errors.is_empty(), "{}", errors.join("\n"));
    assert!(checked >= 51, "only {checked} fixtures");
}

/// A PET slice in Bq/ml with what SUV needs: the body-weight SUV factor is read as the
/// standard rule gives it (worked out here by hand, apart from the reader), for images
/// decay-corrected to the scan's start, to the injection, and across midnight; without the
/// patient's weight, or with another correction, there is none.
#[test]
fn pet_in_bq_per_ml_gets_its_suv_factor() {
    use dicom_core::{value::DataSetSequence, DataElement, PrimitiveValue, VR};
    use dicom_dictionary_std::tags;
    use dicom_object::InMemDicomObject;
    let dir = tempfile::tempdir().unwrap();
    // F-18 (half-life 109.77 min), 370 MBq injected at `start`, the series at `series`,
    // a 72.5 kg patient.
    let write = |name: &str, start: &str, series: &str, correction: &str, weight: Option<&str>| {
        let mut obj = dicom_object::open_file(repo_path("tests/fixtures/dicom/oblique/z5.dcm")).unwrap();
        let put =
            |obj: &mut dicom_object::DefaultDicomObject, tag, vr, v: &str| obj.put(DataElement::new(tag, vr, PrimitiveValue::from(v)));
        put(&mut obj, tags::MODALITY, VR::CS, "PT");
        put(&mut obj, tags::UNITS, VR::CS, "BQML");
        put(&mut obj, tags::DECAY_CORRECTION, VR::CS, correction);
        put(&mut obj, tags::SERIES_TIME, VR::TM, series);
        if let Some(w) = weight {
            put(&mut obj, tags::PATIENT_WEIGHT, VR::DS, w);
        }
        let item = InMemDicomObject::from_element_iter([
            DataElement::new(tags::RADIOPHARMACEUTICAL_START_TIME, VR::TM, PrimitiveValue::from(start)),
            DataElement::new(tags::RADIONUCLIDE_TOTAL_DOSE, VR::DS, PrimitiveValue::from("370000000")),
            DataElement::new(tags::RADIONUCLIDE_HALF_LIFE, VR::DS, PrimitiveValue::from("6586.2")),
        ]);
        obj.put(DataElement::new(tags::RADIOPHARMACEUTICAL_INFORMATION_SEQUENCE, VR::SQ, DataSetSequence::from(vec![item])));
        let path = dir.path().join(name);
        obj.write_to_file(&path).unwrap();
        dicom::read_dicom(&path, &Default::default(), &Default::default()).unwrap()
    };
    // 62.5 min after injection: the dose left is 370 MBq · 2^(−3750 / 6586.2).
    let at_start = 72_500.0 / (370e6 * 2f64.powf(-3750.0 / 6586.2));
    let v = write("start.dcm", "101500", "111730", "START", Some("72.5"));
    assert_eq!(v.units.as_deref(), Some("Bq/ml"));
    let f = v.suv_bw.expect("a factor");
    assert!((f / at_start - 1.0).abs() < 1e-12, "{f} vs {at_start}");
    assert!(v.notes.iter().any(|n| n.contains("SUVbw") && n.contains("62.5 min")), "{:?}", v.notes);
    // Fractional seconds and an injection before midnight.
    let v = write("midnight.dcm", "235500.5", "005730.5", "START", Some("72.5"));
    assert!((v.suv_bw.unwrap() / at_start - 1.0).abs() < 1e-12);
    // Corrected to the injection: no decay.
    let v = write("admin.dcm", "101500", "111730", "ADMIN", Some("72.5"));
    assert!((v.suv_bw.unwrap() - 72_500.0 / 370e6).abs() < 1e-15);
    assert_eq!(write("noweight.dcm", "101500", "111730", "START", None).suv_bw, None);
    assert_eq!(write("none.dcm", "101500", "111730", "NONE", Some("72.5")).suv_bw, None);
}
