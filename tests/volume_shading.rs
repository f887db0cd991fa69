//! Gradient shading in the reference ray caster (the truth the other volume renderers are
//! measured against): a sphere against its analytic normals on an anisotropic grid, flat
//! regions, a single bright voxel, the scene's lights, and what a scene may ask for.

mod common;

use volterra::render::frame::Frame;
use volterra::render::reference_volume::{self, Settings, VolumeInput};
use volterra::scene::{BlendMode, Camera, Light, LightKind, Scene, TransferFunction, VolumeShading};
use volterra_formats::{Volume, VoxelData};

const R: f64 = 10.0;

/// The signed distance to a sphere of radius R (mm, positive inside), centred, on a grid
/// of unequal spacing: round in the world, not in voxels.
fn sphere() -> Volume {
    let spacing = [0.5, 0.75, 1.0];
    let dims = spacing.map(|s: f64| (2.0 * (R + 3.0) / s) as usize + 1);
    let v = Volume::centred(dims, spacing, VoxelData::F32(vec![0.0; dims[0] * dims[1] * dims[2]]));
    let mut data = Vec::with_capacity(v.voxel_count());
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                let p = v.index_to_world([i as f64, j as f64, k as f64]);
                data.push((R - (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt()) as f32);
            }
        }
    }
    Volume { data: VoxelData::F32(data), ..v }
}

fn camera() -> Camera {
    Camera {
        position: [0.0, 0.0, 100.0],
        focal_point: [0.0; 3],
        view_up: [0.0, 1.0, 0.0],
        view_angle: 30.0,
        parallel_projection: true,
        parallel_scale: 12.0,
    }
}

/// White, opaque within a quarter millimetre inside the surface.
fn surface_tf() -> TransferFunction {
    TransferFunction {
        scalar_opacity: vec![[-0.25, 0.0], [0.0, 1.0]],
        color: vec![[0.0, 1.0, 1.0, 1.0]],
        scalar_opacity_unit_distance: 0.05,
    }
}

fn render(v: &Volume, tf: &TransferFunction, shading: Option<&VolumeShading>, lights: &[Light], size: usize) -> Frame {
    let input = VolumeInput { volume: v, node_to_world: glam::DMat4::IDENTITY, tf, blend: BlendMode::Composite, shading, lights };
    reference_volume::render(&input, &camera().rays(size, size), &Settings::default()).unwrap()
}

fn diffuse_only() -> VolumeShading {
    VolumeShading { shade: true, ambient: 0.0, diffuse: 1.0, specular: 0.0, ..Default::default() }
}

/// Over the pixels whose ray meets the sphere within 0.85 R of its axis: the largest and
/// the mean |rendered − expected(x, y)|, with the expected brightness from the analytic
/// normal at the surface point (x, y, √(R² − x² − y²)).
fn errors(frame: &Frame, size: usize, expected: impl Fn(f64, f64, f64) -> f64) -> (f64, f64, usize) {
    let rays = camera().rays(size, size);
    let (mut max, mut sum, mut n) = (0.0f64, 0.0, 0);
    for y in 0..size {
        for x in 0..size {
            let o = rays.ray(x as f64 + 0.5, y as f64 + 0.5).origin;
            let r2 = o.x * o.x + o.y * o.y;
            if r2 > (0.85 * R).powi(2) {
                continue;
            }
            let nz = (1.0 - r2 / (R * R)).sqrt();
            let px = frame.rgba[y * size + x];
            assert!(px.iter().all(|c| c.is_finite()), "NaN at {x},{y}");
            let e = (px[0] as f64 - expected(o.x / R, o.y / R, nz)).abs();
            max = max.max(e);
            sum += e;
            n += 1;
        }
    }
    (max, sum / n as f64, n)
}

#[test]
fn a_shaded_sphere_on_an_anisotropic_grid_follows_its_analytic_normals() {
    let v = sphere();
    let tf = surface_tf();
    let size = 48;
    // Headlight (no scene lights), diffuse only: brightness = |n · view| = n_z.
    let shaded = render(&v, &tf, Some(&diffuse_only()), &[], size);
    let (max, mean, n) = errors(&shaded, size, |_, _, nz| nz);
    eprintln!("headlight: {n} pixels, max |error| {max:.4}, mean {mean:.5}");
    assert!(n > 800, "{n} pixels checked");
    assert!(max < 0.03 && mean < 0.01, "max {max}, mean {mean}");
    // Unshaded, the same pixels are white: the check above is not passed by accident.
    let flat = render(&v, &tf, None, &[], size);
    let (max_flat, _, _) = errors(&flat, size, |_, _, nz| nz);
    assert!(max_flat > 0.4, "{max_flat}");
    // A sun from +x (travelling along −x), two-sided as VTK lights volumes: |n_x|.
    let sun = Light {
        kind: LightKind::Directional,
        direction: Some([-1.0, 0.0, 0.0]),
        position: None,
        color: [1.0; 3],
        intensity: 1.0,
        cone_angle: None,
    };
    let lit = render(&v, &tf, Some(&diffuse_only()), std::slice::from_ref(&sun), size);
    let (max, mean, _) = errors(&lit, size, |nx, _, _| nx.abs());
    eprintln!("sun from +x: max |error| {max:.4}, mean {mean:.5}");
    assert!(max < 0.03 && mean < 0.01, "max {max}, mean {mean}");
    // Specular alone under the headlight: n·h = n_z, so (n_z)^power.
    let spec = VolumeShading { shade: true, ambient: 0.0, diffuse: 0.0, specular: 1.0, specular_power: 10.0 };
    let (max, _, _) = errors(&render(&v, &tf, Some(&spec), &[], size), size, |_, _, nz| nz.powf(10.0));
    assert!(max < 0.05, "specular max {max}");
}

/// Zero gradient has no normal: lit as a surface facing the light, never NaN or black.
#[test]
fn a_flat_region_is_lit_as_facing_the_light() {
    let v = Volume::centred([12, 12, 12], [1.0; 3], VoxelData::U8(vec![100; 12 * 12 * 12]));
    let tf = TransferFunction { scalar_opacity: vec![[0.0, 0.3]], color: vec![[0.0, 0.2, 0.6, 1.0]], scalar_opacity_unit_distance: 1.0 };
    let plain = render(&v, &tf, None, &[], 16);
    let shaded = render(&v, &tf, Some(&VolumeShading { shade: true, ..Default::default() }), &[], 16);
    let mut covered = 0;
    for (a, b) in plain.rgba.iter().zip(&shaded.rgba) {
        assert!(b.iter().all(|c| c.is_finite()));
        assert_eq!(a[3], b[3], "shading leaves opacity alone");
        for k in 0..3 {
            // ambient 0.1 + diffuse 0.7, no highlight.
            assert!((b[k] as f64 - 0.8 * a[k] as f64).abs() < 1e-6, "{a:?} {b:?}");
        }
        covered += (a[3] > 0.0) as usize;
    }
    assert!(covered > 50, "{covered}");
}

#[test]
fn a_single_bright_voxel_shades_without_nan() {
    let mut data = vec![0u8; 9 * 9 * 9];
    data[4 + 9 * (4 + 9 * 4)] = 255;
    let v = Volume::centred([9, 9, 9], [1.0; 3], VoxelData::U8(data));
    let tf = TransferFunction {
        scalar_opacity: vec![[0.0, 0.0], [255.0, 1.0]],
        color: vec![[0.0, 1.0, 1.0, 1.0]],
        scalar_opacity_unit_distance: 1.0,
    };
    let f = render(&v, &tf, Some(&VolumeShading { shade: true, ..Default::default() }), &[], 24);
    assert!(f.rgba.iter().flatten().all(|c| c.is_finite() && *c >= 0.0));
    assert!(f.rgba.iter().any(|p| p[3] > 0.0));
}

#[test]
fn scenes_refuse_shading_where_it_cannot_be_honoured() {
    let dir = tempfile::tempdir().unwrap();
    volterra_formats::nifti::write_nifti(&dir.path().join("v.nii"), &volterra::samples::angio_phantom(8)).unwrap();
    let scene = |node: &str| {
        let text = format!(
            "[camera]\nposition = [0.0, 0.0, 100.0]\nfocal_point = [0.0, 0.0, 0.0]\nview_up = [0.0, 1.0, 0.0]\n\n[[node]]\nname = \"vol\"\nkind = \"volume\"\nfile = \"v.nii\"\n{node}\n\n[node.transfer_function]\nscalar_opacity = [[0.0, 0.2]]\n"
        );
        let p = dir.path().join("s.toml");
        std::fs::write(&p, text).unwrap();
        Scene::load(&p, &[]).map(|_| ()).map_err(|e| format!("{e:#}"))
    };
    scene("renderer = \"reference\"\nshading = { shade = true, specular = 0.5 }").unwrap();
    // Coefficients without shade = true are VTK's: shading stays off, any renderer draws it.
    scene("renderer = \"shear-warp\"\nshading = { ambient = 0.3 }").unwrap();
    let e = scene("renderer = \"shear-warp\"\nshading = { shade = true }").unwrap_err();
    assert!(
        e.contains("line 10: node 'vol': renderer 'shear-warp' does not shade volumes yet (shade = true needs one of: reference)"),
        "{e}"
    );
    let e = scene("shading = { shade = true, diffuse = 1.5 }").unwrap_err();
    assert!(e.contains("shading.diffuse = 1.5 must lie in [0, 1]"), "{e}");
    let e = scene("shading = { shade = true, shininess = 3 }").unwrap_err();
    assert!(e.contains("shininess"), "{e}");
}
