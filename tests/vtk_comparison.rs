//! Our renderers and VTK's vtkFixedPointVolumeRayCastMapper (images made by
//! tests/reference/vtk_volume.py from the same scene files) against the reference ray
//! caster, on the real aneurism scan: axis-aligned, oblique, and exactly at the 45° switch
//! of principal axis; and shaded, in parallel and in perspective, on a CT angiography, an
//! MR T1 and a PET (tests/reference/make_clinical_scenes.py writes those scenes).

mod common;

use common::repo_path;
use volterra::compare::{rgba_pixels as rgba, rgba_psnr as psnr, rgba_rel_rmse as rel_rmse};
use volterra::render::{self, Frame};
use volterra::scene::Scene;

/// The reference venv's Python (tests/setup_venv.py); None, with a printed reason, where
/// it is missing outside CI (under CI=true its absence fails the test).
fn reference_python() -> Option<std::path::PathBuf> {
    let python = repo_path("tests/reference/.venv/bin/python");
    if !python.exists() {
        assert!(!common::under_ci(), "{} missing (CI=true)", python.display());
        eprintln!("SKIPPED: no reference venv");
        return None;
    }
    Some(python)
}

fn render_with(scene: &Scene, renderer: &str) -> Frame {
    let path = scene.source.clone();
    let s = Scene::load(&path, &[format!("node.aneurism.renderer={renderer}")]).unwrap();
    render::render_scene(&s, None).unwrap()
}

#[test]
fn shear_warp_and_the_gpu_are_closer_to_the_reference_than_vtk_at_every_view() {
    if common::shared_data().is_none() || common::gpu().is_none() {
        return;
    }
    for view in ["axis", "oblique", "switch45"] {
        let scene = Scene::load(&repo_path(&format!("tests/reference/scenes/aneurism_{view}.toml")), &[]).unwrap();
        let vtk = rgba(
            &volterra_formats::exr_io::read_exr(&repo_path(&format!("tests/reference/data/vtk_aneurism_{view}.exr")), &Default::default())
                .unwrap(),
        );
        let reference = render_with(&scene, "reference");
        let ours = render_with(&scene, "shear-warp");
        let gpu = render_with(&scene, "gpu-raycast");
        let e_vtk = rel_rmse(&vtk, &reference.rgba);
        let e_ours = rel_rmse(&ours.rgba, &reference.rgba);
        let e_gpu = rel_rmse(&gpu.rgba, &reference.rgba);
        eprintln!(
            "{view}: VTK fixed-point {:.2} %, shear-warp {:.2} %, gpu-raycast {:.2} % from the reference",
            100.0 * e_vtk,
            100.0 * e_ours,
            100.0 * e_gpu
        );
        assert!(e_gpu < 0.5 * e_vtk, "{view}: gpu-raycast {e_gpu} vs VTK {e_vtk}");
        // VTK agrees with the reference to about its known sample-distance-1 error (the
        // issue's ~12 %): camera, transfer function and compositing conventions match. A
        // flipped axis or a wrong opacity correction gives several times that.
        assert!(e_vtk < 0.15, "{view}: VTK is {e_vtk} from the reference — conventions differ?");
        assert!(e_ours < 0.5 * e_vtk, "{view}: shear-warp {e_ours} vs VTK {e_vtk}");
    }
}

/// Issue 17's goal on real clinical volumes: shaded, parallel and perspective, along an
/// axis, oblique and at the 45° switch, shear-warp at its default settings is at most half
/// VTK's error (its fixed-point mapper with ShadeOn, the same lights, property values and
/// unit distance, one sample per voxel) from the shaded reference ray caster.
#[test]
fn shaded_shear_warp_and_the_gpu_have_half_vtks_error_on_clinical_volumes() {
    if common::shared_data().is_none() || common::gpu().is_none() {
        return;
    }
    let (mut worst, mut worst_gpu, mut failures): (f64, f64, Vec<String>) = (0.0, 0.0, Vec::new());
    for volume in ["ctavm", "mri", "pet"] {
        for view in ["axis", "oblique", "switch45"] {
            for projection in ["parallel", "perspective"] {
                let name = format!("clinical_{volume}_{view}_{projection}");
                let scene = Scene::load(&repo_path(&format!("tests/reference/scenes/{name}.toml")), &[]).unwrap();
                let path = repo_path(&format!("tests/reference/data/vtk_{name}.exr"));
                let vtk = rgba(&volterra_formats::exr_io::read_exr(&path, &Default::default()).unwrap());
                let load = |r: &str| {
                    let s = Scene::load(&scene.source, &[format!("node.volume.renderer={r}")]).unwrap();
                    render::render_scene(&s, None).unwrap()
                };
                let (reference, ours, gpu) = (load("reference"), load("shear-warp"), load("gpu-raycast"));
                let covered = reference.rgba.iter().filter(|p| p[3] > 0.1).count();
                assert!(covered > 2000, "{name}: the view shows the volume ({covered} pixels)");
                let (e_vtk, e_ours) = (rel_rmse(&vtk, &reference.rgba), rel_rmse(&ours.rgba, &reference.rgba));
                let e_gpu = rel_rmse(&gpu.rgba, &reference.rgba);
                eprintln!(
                    "{name}: shear-warp {:.2} % ({:.1} dB), gpu-raycast {:.2} % ({:.1} dB), VTK fixed-point {:.2} % ({:.1} dB) from the reference",
                    100.0 * e_ours,
                    psnr(&ours.rgba, &reference.rgba),
                    100.0 * e_gpu,
                    psnr(&gpu.rgba, &reference.rgba),
                    100.0 * e_vtk,
                    psnr(&vtk, &reference.rgba)
                );
                // VTK within its usual one-sample-per-voxel error: the conventions (world
                // millimetres, orientation, lighting) match.
                assert!(e_vtk < 0.25, "{name}: VTK is {e_vtk} from the reference — conventions differ?");
                worst = worst.max(e_ours / e_vtk);
                worst_gpu = worst_gpu.max(e_gpu / e_vtk);
                if e_ours >= 0.5 * e_vtk {
                    failures.push(format!("{name}: shear-warp {e_ours:.4} vs VTK {e_vtk:.4}"));
                }
                if e_gpu >= 0.5 * e_vtk {
                    failures.push(format!("{name}: gpu-raycast {e_gpu:.4} vs VTK {e_vtk:.4}"));
                }
            }
        }
    }
    eprintln!("largest ratio of shear-warp's error to VTK's: {worst:.2}; of gpu-raycast's: {worst_gpu:.2}");
    assert!(failures.is_empty(), "over half VTK's error: {failures:#?}");
}

/// The VTK reference script is code under test too: on a volume with non-unit, anisotropic
/// spacing, an oblique affine and scl_slope ≠ 1 (as clinical files are), VTK's image must
/// agree with our reference ray caster to its usual sample error. The script used to apply
/// the scale twice (a PET with slope 0.001 rendered empty) and give VTK one-voxel spacing,
/// so its sample and opacity unit distances were voxels, not millimetres (about 20 % too
/// opaque on a 0.52 mm angiography).
#[test]
fn the_vtk_reference_reads_scaled_anisotropic_oblique_volumes_in_millimetres() {
    let Some(python) = reference_python() else { return };
    let dir = tempfile::tempdir().unwrap();
    let (nx, ny, nz) = (48usize, 40, 36);
    let spacing = [0.5, 0.6, 0.9];
    // Stored integers × 0.01: a blob of real values 0..200 with a brighter core.
    let mut data = vec![0i16; nx * ny * nz];
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                let p = [(x as f64 - 24.0) * spacing[0], (y as f64 - 20.0) * spacing[1], (z as f64 - 18.0) * spacing[2]];
                let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                let v = (200.0 * (1.0 - r / 11.0)).max(0.0) + if r < 4.0 { 100.0 } else { 0.0 };
                data[(z * ny + y) * nx + x] = (v * 100.0) as i16;
            }
        }
    }
    let (c, s) = (0.4f64.cos(), 0.4f64.sin());
    let affine = [
        [c * spacing[0], -s * spacing[1], 0.0, -10.0],
        [s * spacing[0], c * spacing[1], 0.0, 5.0],
        [0.0, 0.0, spacing[2], -16.0],
        [0.0, 0.0, 0.0, 1.0],
    ];
    let rescale = volterra_formats::Rescale { slope: 0.01, intercept: 0.0 };
    let vol = common::volume([nx, ny, nz], affine, volterra_formats::VoxelData::I16(data), rescale);
    volterra_formats::nifti::write_nifti(&dir.path().join("blob.nii"), &vol).unwrap();
    let scene = dir.path().join("blob.toml");
    std::fs::write(
        &scene,
        r#"[image]
width = 96
height = 96

[camera]
position = [60.0, -70.0, 40.0]
focal_point = [-9.0, 8.0, 0.0]
view_up = [0.0, 0.0, 1.0]
parallel_projection = true
parallel_scale = 18.0

[[node]]
name = "blob"
kind = "volume"
file = "blob.nii"
renderer = "reference"

[node.transfer_function]
scalar_opacity = [[0.0, 0.0], [40.0, 0.0], [150.0, 0.3], [300.0, 0.8]]
color = [[0.0, 0.2, 0.2, 0.8], [150.0, 0.9, 0.5, 0.2], [300.0, 1.0, 1.0, 1.0]]
scalar_opacity_unit_distance = 2.0
"#,
    )
    .unwrap();
    let out =
        std::process::Command::new(&python).arg(repo_path("tests/reference/vtk_volume.py")).arg(dir.path()).arg(&scene).output().unwrap();
    assert!(out.status.success(), "vtk_volume.py: {}", String::from_utf8_lossy(&out.stderr));
    let vtk = rgba(&volterra_formats::exr_io::read_exr(&dir.path().join("vtk_blob.exr"), &Default::default()).unwrap());
    let reference = render::render_scene(&Scene::load(&scene, &[]).unwrap(), None).unwrap();
    let e = rel_rmse(&vtk, &reference.rgba);
    let alpha = |px: &[[f32; 4]]| px.iter().map(|p| p[3] as f64).sum::<f64>();
    let (a_vtk, a_ref) = (alpha(&vtk), alpha(&reference.rgba));
    eprintln!(
        "VTK on a scaled oblique 0.5×0.6×0.9 mm volume: {:.2} % from the reference, total alpha {:.1} vs {:.1}",
        100.0 * e,
        a_vtk,
        a_ref
    );
    assert!(a_ref > 100.0, "the scene shows the blob");
    assert!((a_vtk / a_ref - 1.0).abs() < 0.05, "VTK's total opacity {a_vtk} vs the reference's {a_ref}");
    assert!(e < 0.15, "VTK is {:.1} % from the reference", 100.0 * e);
}

/// Shading under a light from the side, against VTK's fixed-point mapper (issue 44): VTK
/// turns each normal toward the viewer, not toward the light, so the side of a surface
/// facing away from the light is dark; ours does the same. A shaded ball lit from +x and
/// seen from +z: the reference as close to VTK as under the headlight (with the normal
/// turned toward the light instead, |n·l|, 36.8 % from it here).
#[test]
fn a_side_lit_shaded_ball_is_lit_as_vtk_lights_it() {
    let Some(python) = reference_python() else { return };
    let dir = tempfile::tempdir().unwrap();
    let n = 48usize;
    // The signed distance to a ball of radius 9 mm (positive inside), 0.5 mm voxels.
    let data: Vec<f32> = (0..n * n * n)
        .map(|i| {
            let p = [(i % n) as f64, ((i / n) % n) as f64, (i / (n * n)) as f64].map(|c| (c - 23.5) * 0.5);
            (9.0 - (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt()) as f32
        })
        .collect();
    let affine = [[0.5, 0.0, 0.0, -11.75], [0.0, 0.5, 0.0, -11.75], [0.0, 0.0, 0.5, -11.75], [0.0, 0.0, 0.0, 1.0]];
    let vol = volterra_formats::Volume::new([n, n, n], affine, volterra_formats::VoxelData::F32(data));
    volterra_formats::nifti::write_nifti(&dir.path().join("ball.nii"), &vol).unwrap();
    let scene_text = |light: &str| {
        format!(
            "[image]\nwidth = 96\nheight = 96\n[camera]\nposition = [0.0, 0.0, 100.0]\nfocal_point = [0.0, 0.0, 0.0]\nview_up = [0.0, 1.0, 0.0]\n\
             parallel_projection = true\nparallel_scale = 12.0\n{light}\
             [[node]]\nname = \"ball\"\nkind = \"volume\"\nfile = \"ball.nii\"\nrenderer = \"reference\"\n\
             [node.shading]\nshade = true\nambient = 0.1\ndiffuse = 0.9\nspecular = 0.0\n\
             [node.transfer_function]\nscalar_opacity = [[-3.0, 0.0], [0.0, 0.05], [3.0, 0.3], [10.0, 0.3]]\ncolor = [[0.0, 1.0, 1.0, 1.0]]\nscalar_opacity_unit_distance = 0.5\n"
        )
    };
    let mut errors = Vec::new();
    for (name, light) in [("headlight", ""), ("side", "[[light]]\nkind = \"directional\"\ndirection = [-1.0, 0.0, 0.0]\n")] {
        let scene = dir.path().join(format!("{name}.toml"));
        std::fs::write(&scene, scene_text(light)).unwrap();
        let out = std::process::Command::new(&python)
            .arg(repo_path("tests/reference/vtk_volume.py"))
            .arg(dir.path())
            .arg(&scene)
            .output()
            .unwrap();
        assert!(out.status.success(), "vtk_volume.py: {}", String::from_utf8_lossy(&out.stderr));
        let vtk = rgba(&volterra_formats::exr_io::read_exr(&dir.path().join(format!("vtk_{name}.exr")), &Default::default()).unwrap());
        let ours = render::render_scene(&Scene::load(&scene, &[]).unwrap(), None).unwrap();
        let e = rel_rmse(&vtk, &ours.rgba);
        eprintln!("shaded ball, {name}: the reference {:.2} % from VTK's fixed-point mapper", 100.0 * e);
        errors.push(e);
    }
    // Under the side light the ball's western half is dark in both: as close to VTK as
    // under the headlight (2.6 % and 2.1 % when written; the normal turned toward the light
    // instead gives 36.8 %).
    assert!(errors[0] < 0.04, "headlight {:.2} %", 100.0 * errors[0]);
    assert!(errors[1] < 1.5 * errors[0].max(0.01), "side-lit {:.2} %, headlight {:.2} %", 100.0 * errors[1], 100.0 * errors[0]);
}

/// `volterra bench clinical --curve` (issue 45, bench honesty): our configurations and
/// VTK's six (sample distance 0.5/1/2 voxels × ImageSampleDistance 1/2) on one
/// speed/error table against the same reference, the Pareto front and each VTK row's
/// dominating volterra row consistent with the figures, and the plot written. A thin
/// 512 × 512 × 8 phantom keeps it short.
#[test]
fn bench_clinical_curve_puts_ours_and_vtks_configurations_on_one_table() {
    let Some(python) = reference_python() else { return };
    let dir = tempfile::tempdir().unwrap();
    let plot = dir.path().join("curve.png");
    let out = std::process::Command::new(common::volterra_bin())
        .args(["bench", "clinical", "--slices", "8", "--frames", "2", "--curve", "--json"])
        .arg("--work-dir")
        .arg(dir.path())
        .arg("--plot")
        .arg(&plot)
        .arg("--python")
        .arg(&python)
        .arg("--scripts")
        .arg(repo_path("tests/reference"))
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let rows = report["curve"].as_array().expect("curve rows");
    let (ours, vtk): (Vec<_>, Vec<_>) = rows.iter().partition(|r| r["config"].as_str().unwrap().starts_with("volterra"));
    assert_eq!(ours.len(), 7);
    assert_eq!(vtk.len(), 6);
    let (ms, err) = (|r: &serde_json::Value| r["median_ms"].as_f64().unwrap(), |r: &serde_json::Value| r["rel_rmse"].as_f64().unwrap());
    for r in rows {
        assert!(ms(r) > 0.0 && err(r) > 0.0 && err(r) < 1.0, "{r}");
    }
    // The curve's default row is the main row's first view, drawn again.
    assert_eq!(err(ours[0]), report["rel_rmse_first_view"]["ours"].as_f64().unwrap());
    // Finer sampling is closer on both sides.
    let named = |name: &str| rows.iter().find(|r| r["config"].as_str().unwrap().ends_with(name)).unwrap();
    assert!(err(named("sd 0.5 isd 1")) < err(named("sd 2 isd 2")));
    assert!(err(named("volterra defaults")) < err(named("volterra ×1 1/slab")));
    // The front and the dominating rows as the figures say.
    let better = |a: &serde_json::Value, b: &serde_json::Value| ms(a) <= ms(b) && err(a) <= err(b) && (ms(a) < ms(b) || err(a) < err(b));
    for r in rows {
        assert_eq!(r["pareto"].as_bool().unwrap(), !rows.iter().any(|o| better(o, r)), "{r}");
    }
    for r in &vtk {
        let faster_closer = ours.iter().filter(|o| ms(o) < ms(r) && err(o) < err(r));
        let fastest = faster_closer.min_by(|a, b| ms(a).total_cmp(&ms(b))).map(|o| o["config"].as_str().unwrap());
        assert_eq!(r["dominated_by"].as_str(), fastest, "{r}");
    }
    assert!(plot.is_file(), "the plot is written");
}
