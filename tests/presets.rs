//! Volume node keys beyond the data: transfer-function presets named in scene files (3D
//! Slicer's names and points), the `modality` key for files that do not say it, and the
//! preset's shading: a preset renders exactly as its points written out would; an MR
//! angiogram's preset shows the vessels and leaves the noise clear. And cropping: the
//! `crop` box and `[[node.clip]]` planes, checked at load and honoured by both renderers.

mod common;

use std::path::Path;
use volterra::render;
use volterra::scene::presets::{Preset, ValueStats};
use volterra::scene::Scene;
use volterra_formats::{Volume, VoxelData};

/// A CT-like i16 volume in HU: air −1000, soft tissue 40, a contrast-filled vessel 300
/// and a bone 1200, 1 × 1 × 2 mm voxels.
fn ct() -> Volume {
    let dims = [24, 22, 14];
    let mut data = Vec::new();
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                let (x, y) = (i as f64 - 11.5, j as f64 - 10.5);
                let r = x.hypot(y);
                let v = if r > 9.0 {
                    -1000.0
                } else if (x - 3.0).hypot(y) < 2.5 {
                    300.0
                } else if (x + 4.0).hypot(y + 2.0) < 2.0 {
                    1200.0
                } else {
                    40.0 + (k as f64 - 7.0)
                };
                data.push(v as i16);
            }
        }
    }
    Volume::centred(dims, [1.0, 1.0, 2.0], VoxelData::I16(data))
}

fn scene_text(node: &str) -> String {
    format!(
        "[image]\nwidth = 40\nheight = 40\n\n[camera]\nposition = [0.0, -80.0, 20.0]\nfocal_point = [0.0, 0.0, 0.0]\nview_up = [0.0, 0.0, 1.0]\n\n[[node]]\nname = \"v\"\nkind = \"volume\"\nfile = \"v.nii\"\n{node}\n"
    )
}

fn load(dir: &Path, node: &str) -> Result<Scene, String> {
    load_scene(dir, node)
}

/// The error a scene with `node` gives at load.
fn load_error(dir: &Path, node: &str) -> String {
    match load_scene(dir, node) {
        Ok(_) => panic!("{node}: loads"),
        Err(e) => e,
    }
}

fn load_scene(dir: &Path, node: &str) -> Result<Scene, String> {
    let p = dir.join("s.toml");
    std::fs::write(&p, scene_text(node)).unwrap();
    Scene::load(&p, &[]).map_err(|e| format!("{e:#}"))
}

/// `preset = "CT-AAA"` renders exactly as the same scene with Slicer's points and shading
/// written out; `preset_shift` moves every point along the value axis.
#[test]
fn a_named_preset_renders_as_its_points_and_shading() {
    let dir = tempfile::tempdir().unwrap();
    let v = ct();
    volterra_formats::nifti::write_nifti(&dir.path().join("v.nii"), &v).unwrap();
    let stats = ValueStats::of(&v);
    for name in ["CT-AAA", "ct-bone", "CT-Chest-Contrast-Enhanced"] {
        let preset = Preset::from_name(name).unwrap();
        let named = load(dir.path(), &format!("preset = \"{name}\"")).unwrap();
        let tf = preset.transfer_function(&stats, 1.0);
        assert_eq!(named.transfer_function(0).unwrap(), tf);
        let s = preset.shading().unwrap();
        assert!(s.shade && (s.ambient, s.diffuse, s.specular, s.specular_power) == (0.1, 0.9, 0.2, 10.0), "Slicer's CT shading");
        let tf_toml = toml::to_string(&tf).unwrap();
        let sh_toml = toml::to_string(&s).unwrap();
        let spelled = load(dir.path(), &format!("[node.transfer_function]\n{tf_toml}\n[node.shading]\n{sh_toml}")).unwrap();
        let (a, b) = (render::render_scene(&named, None).unwrap(), render::render_scene(&spelled, None).unwrap());
        assert_eq!(a.rgba, b.rgba, "{name}");
        assert!(a.rgba.iter().any(|p| p[3] > 0.1), "{name} shows something");
    }
    // Slicer's CT-AAA: soft tissue clear, contrast and bone opaque.
    let tf = Preset::CtAaa.transfer_function(&stats, 1.0);
    assert_eq!(tf.opacity(40.0), 0.0);
    assert!(tf.opacity(300.0) > 0.69 && tf.opacity(1200.0) > 0.8);
    // A shift of +100 HU moves every point by 100 (the last, at 3071 HU, is clamped to the
    // data's maximum either way).
    let shifted = load(dir.path(), "preset = \"CT-AAA\"\npreset_shift = 100.0").unwrap().transfer_function(0).unwrap();
    for v in [150.0, 200.0, 260.0, 400.0] {
        assert!((shifted.opacity(v + 100.0) - tf.opacity(v)).abs() < 1e-9, "{v}");
    }
    // Its own shading wins over the preset's.
    let own = load(dir.path(), "preset = \"CT-AAA\"\nshading = { shade = false }").unwrap();
    assert!(!own.shading(0).unwrap().shade);
}

#[test]
fn presets_and_modalities_are_checked_at_load() {
    let dir = tempfile::tempdir().unwrap();
    volterra_formats::nifti::write_nifti(&dir.path().join("v.nii"), &ct()).unwrap();
    let e = load_error(dir.path(), "preset = \"CT-AA\"");
    assert!(e.contains("unknown preset 'CT-AA'") && e.contains("CT-AAA, CT-Bone") && e.contains("PET-Hot"), "{e}");
    let e = load_error(dir.path(), "preset = \"CT-AAA\"\n[node.transfer_function]\nscalar_opacity = [[0.0, 0.2]]");
    assert!(e.contains("not both"), "{e}");
    let e = load_error(dir.path(), "modality = \"XR\"");
    assert!(e.contains("unknown modality 'XR'") && e.contains("CT, MR (MRI), PT (PET), NM (SPECT)"), "{e}");
    assert!(e.lines().count() == 1);
    // The names people use beside DICOM's codes (issue 44): PET is PT, SPECT is NM.
    for (name, code) in [("PET", "PT"), ("spect", "NM"), ("MRI", "MR")] {
        let scene = load(dir.path(), &format!("modality = \"{name}\"")).unwrap();
        let want = load(dir.path(), &format!("modality = \"{code}\"")).unwrap();
        assert_eq!(scene.preset(0).unwrap(), want.preset(0).unwrap(), "{name}");
    }
}

/// A NIfTI says no modality: a PET without a `modality` gets the MR preset (an opaque grey
/// blob over the whole brain); with `modality = "PT"` it gets PET-Hot, clear below the
/// 90th percentile.
#[test]
fn the_modality_key_picks_the_preset_of_a_nifti() {
    let dir = tempfile::tempdir().unwrap();
    let dims = [20, 20, 20];
    // Uptake: a smooth background of 1 with two hot spots of 8 and 5.
    let mut data = Vec::new();
    for k in 0..20 {
        for j in 0..20 {
            for i in 0..20 {
                let d = |c: [f64; 3]| ((i as f64 - c[0]).powi(2) + (j as f64 - c[1]).powi(2) + (k as f64 - c[2]).powi(2)).sqrt();
                data.push(
                    (1.0 + 7.0 * (-d([6.0, 7.0, 9.0]).powi(2) / 4.0).exp() + 4.0 * (-d([13.0, 12.0, 10.0]).powi(2) / 6.0).exp()) as f32,
                );
            }
        }
    }
    let pet = Volume::centred(dims, [3.0; 3], VoxelData::F32(data));
    volterra_formats::nifti::write_nifti(&dir.path().join("v.nii"), &pet).unwrap();
    let plain = load(dir.path(), "").unwrap();
    assert_eq!(plain.preset(0).unwrap(), Preset::MrDefault);
    let tagged = load(dir.path(), "modality = \"PT\"").unwrap();
    assert_eq!(tagged.preset(0).unwrap(), Preset::PetHot);
    let tf = tagged.transfer_function(0).unwrap();
    assert_eq!(tf.opacity(1.0), 0.0, "background uptake is clear");
    assert!(tf.opacity(7.5) > 0.5, "the hot spot is seen");
    assert!(tagged.shading(0).is_none(), "PET presets do not shade");
    // Rendered, PET-Hot covers far less of the image than the MR preset's blob.
    let cover = |s: &Scene| render::render_scene(s, None).unwrap().rgba.iter().filter(|p| p[3] > 0.2).count();
    let (c_pet, c_mr) = (cover(&tagged), cover(&plain));
    assert!(c_pet > 0 && 3 * c_pet < c_mr, "PET-Hot {c_pet} pixels, MR-Default {c_mr}");
}

/// An MR angiogram: noisy tissue (values 0–120) with thin flow-bright vessels (about 1 %
/// of the voxels, 300–500). MR-Angio leaves the noise clear and shows the vessels;
/// MR-Default shows the noise too.
#[test]
fn mr_angio_shows_vessels_not_noise() {
    let n = 48;
    let mut rng = volterra_formats::rng::Rng::new(7);
    let mut data = Vec::with_capacity(n * n * n);
    let mut vessel = Vec::with_capacity(n * n * n);
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                let (x, y, z) = (i as f64, j as f64, k as f64);
                // Two vessels: one along z, one diagonal in the x-y plane.
                let d1 = (x - 20.0).hypot(y - 30.0);
                let d2 = ((x - y) / 2f64.sqrt()).hypot(z - 24.0);
                let r = d1.min(d2);
                let inside = r < 1.3;
                let v = if inside { 300.0 + 200.0 * (1.0 - r / 1.3) } else { 120.0 * rng.uniform() };
                data.push(v as f32);
                vessel.push(inside);
            }
        }
    }
    let frac = vessel.iter().filter(|&&v| v).count() as f64 / vessel.len() as f64;
    eprintln!("vessels: {:.2} % of the voxels", 100.0 * frac);
    assert!((0.003..0.03).contains(&frac), "vessel fraction {frac}");
    let v = Volume::centred([n; 3], [0.5; 3], VoxelData::F32(data.clone()));
    let stats = ValueStats::of(&v);
    let angio = Preset::MrAngio.transfer_function(&stats, 0.5);
    let default = Preset::MrDefault.transfer_function(&stats, 0.5);
    let visible = |tf: &volterra::scene::TransferFunction, want: bool| {
        data.iter().zip(&vessel).filter(|(_, &inside)| inside == want).filter(|(&x, _)| tf.opacity(x as f64) > 0.0).count() as f64
            / vessel.iter().filter(|&&inside| inside == want).count() as f64
    };
    let (noise_angio, vessels_angio) = (visible(&angio, false), visible(&angio, true));
    eprintln!(
        "MR-Angio: noise visible {noise_angio:.4}, vessels visible {vessels_angio:.3}; MR-Default noise {:.3}",
        visible(&default, false)
    );
    assert!(noise_angio < 0.005, "MR-Angio shows noise: {noise_angio}");
    assert!(vessels_angio > 0.8, "MR-Angio hides vessels: {vessels_angio}");
    assert!(visible(&default, false) > 0.2, "MR-Default is the one that shows tissue");
    // Slicer's shading for its MR presets.
    assert_eq!(Preset::MrAngio.shading().unwrap().ambient, 0.2);
}

/// Crop keys are checked at load with one-line errors naming the node.
#[test]
fn crop_keys_are_checked_at_load() {
    let dir = tempfile::tempdir().unwrap();
    volterra_formats::nifti::write_nifti(&dir.path().join("v.nii"), &ct()).unwrap();
    for (node, want) in [
        ("crop = { min = [0.0, 0.0, 5.0], max = [1.0, 1.0, 2.0] }", "crop.min[2] = 5 lies above crop.max[2] = 2"),
        ("crop = { min = [0.0, 0.0, 0.0], max = [1.0, 1.0, 1.0], size = 2 }", "unknown field `size`"),
        ("[[node.clip]]\norigin = [0.0, 0.0, 0.0]\nnormal = [0.0, 0.0, 0.0]", "non-zero normal"),
        ("[[node.clip]]\norigin = [0.0, 0.0, 0.0]", "missing field `normal`"),
    ] {
        let e = load_error(dir.path(), node);
        assert!(e.contains(want) && (e.contains("node 'v'") || e.contains("s.toml")), "{node}: {e}");
        assert_eq!(e.lines().count(), 1, "{e}");
    }
}

/// Through a scene, with either renderer: a crop box round the whole volume changes
/// nothing; a clipping plane x ≥ 0 (node coordinates) empties the half of the image left
/// of the eye (which sits on x = 0) and leaves the right half as it was; moving the node
/// moves the plane with it.
#[test]
fn crop_box_and_clipping_planes_through_a_scene() {
    let dir = tempfile::tempdir().unwrap();
    volterra_formats::nifti::write_nifti(&dir.path().join("v.nii"), &ct()).unwrap();
    let tf = "transfer_function = { scalar_opacity = [[-200.0, 0.0], [1200.0, 0.6]], color = [[-200.0, 1.0, 0.8, 0.7], [1200.0, 1.0, 1.0, 1.0]] }";
    for renderer in ["shear-warp", "reference"] {
        let draw = |extra: &str| {
            let s = load(dir.path(), &format!("renderer = \"{renderer}\"\n{tf}\n{extra}")).unwrap();
            render::render_scene(&s, None).unwrap()
        };
        let whole = draw("");
        let covered = whole.rgba.iter().filter(|p| p[3] > 0.05).count();
        assert!(covered > 300, "{renderer}: the volume covers {covered} pixels");
        let all = draw("crop = { min = [-100.0, -100.0, -100.0], max = [100.0, 100.0, 100.0] }");
        let worst = whole.rgba.iter().zip(&all.rgba).flat_map(|(p, q)| (0..4).map(move |c| (p[c] - q[c]).abs())).fold(0.0, f32::max);
        assert!(worst < 1e-6, "{renderer}: a crop box round everything changed a pixel by {worst}");
        let clip = "[[node.clip]]\norigin = [0.0, 0.0, 0.0]\nnormal = [1.0, 0.0, 0.0]";
        let half = draw(clip);
        let (w, h) = (40, 40);
        for y in 0..h {
            for x in 0..w {
                let (p, q) = (half.rgba[y * w + x], whole.rgba[y * w + x]);
                if x + 2 < w / 2 {
                    assert!(p[3] == 0.0, "{renderer}: pixel ({x}, {y}) left of the plane has opacity {}", p[3]);
                } else if x > w / 2 + 1 {
                    assert!((p[3] - q[3]).abs() < 0.02, "{renderer}: pixel ({x}, {y}) right of the plane: {} against {}", p[3], q[3]);
                }
            }
        }
        // The node moved 6 mm to +x takes the plane with it: columns between the eye's
        // plane and x = 6 mm are now empty as well.
        let moved = draw(&format!("transform = {{ translate = [6.0, 0.0, 0.0] }}\n{clip}"));
        let lit = |f: &render::Frame, x: usize| (0..h).filter(|&y| f.rgba[y * w + x][3] > 0.05).count();
        assert!(lit(&half, w / 2 + 3) > 5 && lit(&moved, w / 2 + 3) == 0, "{renderer}: the plane did not move with the node");
    }
}
