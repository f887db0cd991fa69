//! Overlapping volumes fused along each ray (issue 19): in the reference ray caster every
//! volume covering a sample is classified by its own transfer function, extinctions add and
//! colours are extinction-weighted. Checked against the closed-form emission–absorption
//! integral through two translucent boxes on different grids (one turned, other spacing),
//! where per-pixel layers are visibly wrong; a translucent sphere inside a translucent box
//! shows no seam, and moving the sphere's volume by half a voxel changes the picture only
//! smoothly; scenes group overlapping volume nodes into one fused layer by themselves.

mod common;

use glam::{DMat4, DVec3};
use volterra::render::reference_volume::{self, render_fused, VolumeInput};
use volterra::render::Frame;
use volterra::scene::camera::Camera;
use volterra::scene::{BlendMode, TransferFunction};
use volterra_formats::{Volume, VoxelData};

/// A volume of `dims` whose index (i, j, k) lies at `origin` + R_z(turn)·(i·s, j·s, k·s).
fn placed(dims: [usize; 3], spacing: f64, turn_deg: f64, origin: [f64; 3], value: impl Fn(DVec3) -> f32) -> Volume {
    let (s, c) = turn_deg.to_radians().sin_cos();
    let affine = [
        [c * spacing, -s * spacing, 0.0, origin[0]],
        [s * spacing, c * spacing, 0.0, origin[1]],
        [0.0, 0.0, spacing, origin[2]],
        [0.0, 0.0, 0.0, 1.0],
    ];
    let mut data = Vec::with_capacity(dims[0] * dims[1] * dims[2]);
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                let p = DVec3::new(
                    affine[0][0] * i as f64 + affine[0][1] * j as f64 + origin[0],
                    affine[1][0] * i as f64 + affine[1][1] * j as f64 + origin[1],
                    spacing * k as f64 + origin[2],
                );
                data.push(value(p));
            }
        }
    }
    Volume::new(dims, affine, VoxelData::F32(data))
}

/// Constant opacity `alpha` per mm and one colour for values ≥ 0.5; clear below.
fn tf(alpha: f64, rgb: [f64; 3]) -> TransferFunction {
    TransferFunction {
        scalar_opacity: vec![[0.0, 0.0], [0.5, 0.0], [0.5000001, alpha], [2.0, alpha]],
        color: vec![[0.0, rgb[0], rgb[1], rgb[2]]],
        scalar_opacity_unit_distance: 1.0,
        gradient_opacity: vec![],
    }
}

fn input<'a>(v: &'a Volume, tf: &'a TransferFunction) -> VolumeInput<'a> {
    VolumeInput { volume: v, node_to_world: DMat4::IDENTITY, tf, blend: BlendMode::Composite, shading: None, lights: &[], crop: &[] }
}

fn camera() -> Camera {
    Camera {
        position: [-40.0, -70.0, 35.0],
        focal_point: [12.0, 10.0, 9.0],
        view_up: [0.0, 0.0, 1.0],
        view_angle: 30.0,
        parallel_projection: false,
        parallel_scale: 1.0,
    }
}

/// The ray's interval inside the box of voxel centres of `v` (slab method, f64; written
/// here apart from the renderer's clipping).
fn interval(v: &Volume, o: DVec3, d: DVec3) -> Option<(f64, f64)> {
    let a = &v.affine;
    let m = DMat4::from_cols_array_2d(&[
        [a[0][0], a[1][0], a[2][0], 0.0],
        [a[0][1], a[1][1], a[2][1], 0.0],
        [a[0][2], a[1][2], a[2][2], 0.0],
        [a[0][3], a[1][3], a[2][3], 1.0],
    ])
    .inverse();
    let (o, d) = (m.transform_point3(o), m.transform_vector3(d));
    let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
    for c in 0..3 {
        let hi = (v.dims[c] - 1) as f64;
        if d[c].abs() < 1e-300 {
            if o[c] < 0.0 || o[c] > hi {
                return None;
            }
            continue;
        }
        let (a, b) = ((0.0 - o[c]) / d[c], (hi - o[c]) / d[c]);
        t0 = t0.max(a.min(b));
        t1 = t1.min(a.max(b));
    }
    (t0 < t1).then_some((t0, t1))
}

/// Front-to-back emission–absorption through media constant on intervals: extinction σ
/// and colour per medium; the closed form over each piece where the set inside is fixed.
/// A medium: the ray's interval inside it, its extinction and its colour.
type Medium = (Option<(f64, f64)>, f64, [f64; 3]);

fn closed_form(media: &[Medium]) -> [f64; 4] {
    let mut cuts: Vec<f64> = media.iter().filter_map(|m| m.0).flat_map(|(a, b)| [a, b]).collect();
    cuts.sort_by(f64::total_cmp);
    let (mut c, mut transmit) = ([0.0; 3], 1.0);
    for w in cuts.windows(2) {
        let mid = 0.5 * (w[0] + w[1]);
        let inside: Vec<_> = media.iter().filter(|m| m.0.is_some_and(|(a, b)| a <= mid && mid < b)).collect();
        let sigma: f64 = inside.iter().map(|m| m.1).sum();
        if sigma == 0.0 {
            continue;
        }
        let absorbed = 1.0 - (-sigma * (w[1] - w[0])).exp();
        for (k, ck) in c.iter_mut().enumerate() {
            let mix = inside.iter().map(|m| m.1 * m.2[k]).sum::<f64>() / sigma;
            *ck += transmit * absorbed * mix;
        }
        transmit *= 1.0 - absorbed;
    }
    [c[0], c[1], c[2], 1.0 - transmit]
}

#[test]
fn two_translucent_boxes_on_different_grids_match_the_closed_form() {
    let a = placed([21, 17, 13], 1.5, 0.0, [0.0, 0.0, 0.0], |_| 1.0);
    let b = placed([25, 25, 25], 0.8, 30.0, [12.0, 4.0, 5.0], |_| 1.0);
    let (ta, tb) = (tf(0.08, [1.0, 0.25, 0.2]), tf(0.15, [0.2, 0.45, 1.0]));
    let sigma = |t: &TransferFunction| -(1.0 - t.opacity_for_step(1.0, 1.0)).ln();
    let rays = camera().rays(80, 60);
    let fused = render_fused(&[input(&a, &ta), input(&b, &tb)], &rays, &reference_volume::Settings::default()).unwrap();
    let (mut worst, mut both) = (0.0f64, 0);
    for y in 0..60 {
        for x in 0..80 {
            let ray = rays.ray(x as f64 + 0.5, y as f64 + 0.5);
            let (ia, ib) = (interval(&a, ray.origin, ray.dir), interval(&b, ray.origin, ray.dir));
            both += (ia.is_some() && ib.is_some()) as usize;
            let want = closed_form(&[(ia, sigma(&ta), [1.0, 0.25, 0.2]), (ib, sigma(&tb), [0.2, 0.45, 1.0])]);
            let got = fused.rgba[y * 80 + x];
            worst = worst.max((0..4).map(|k| (got[k] as f64 - want[k]).abs()).fold(0.0, f64::max));
        }
    }
    eprintln!("fused vs closed form: worst {worst:e} over 4800 pixels, {both} through both boxes");
    assert!(both > 400, "the boxes overlap in much of the view: {both}");
    assert!(worst < 1e-5, "fused differs from the closed form by {worst:e}");
    // Layers sorted per pixel by depth (what the scene did before) are far off.
    let s = reference_volume::Settings::default();
    let layers =
        [reference_volume::render(&input(&a, &ta), &rays, &s).unwrap(), reference_volume::render(&input(&b, &tb), &rays, &s).unwrap()];
    let layered = Frame::composite(80, 60, &layers);
    let off =
        layered.rgba.iter().zip(&fused.rgba).map(|(p, q)| (0..4).map(|k| (p[k] - q[k]).abs()).fold(0.0f32, f32::max)).fold(0.0, f32::max);
    assert!(off > 0.05, "layers would have passed this test: {off}");
}

/// The largest jump between neighbouring pixels (any channel) inside `mask`, relative to
/// the brightest pixel.
fn largest_jump(f: &Frame, mask: &[bool]) -> f32 {
    let (w, h) = (f.width, f.height);
    let top = f.rgba.iter().map(|p| p[0].max(p[1]).max(p[2])).fold(0.0f32, f32::max);
    let mut jump = 0.0f32;
    for y in 0..h {
        for x in 0..w {
            if !mask[y * w + x] {
                continue;
            }
            let p = f.rgba[y * w + x];
            for q in [(x + 1 < w).then(|| f.rgba[y * w + x + 1]), (y + 1 < h).then(|| f.rgba[(y + 1) * w + x])].into_iter().flatten() {
                jump = jump.max((0..3).map(|k| (p[k] - q[k]).abs()).fold(0.0, f32::max));
            }
        }
    }
    jump / top
}

#[test]
fn a_sphere_inside_a_box_has_no_seam_and_moves_smoothly() {
    // A translucent box of 24³ mm and a smooth ball (radius 6 mm) inside it on a finer,
    // turned grid.
    let boxed = placed([17, 17, 17], 1.5, 0.0, [0.0, 0.0, 0.0], |_| 1.0);
    let ball = |shift: f64| {
        placed([33, 33, 33], 0.7, 20.0, [9.0 + shift, 3.0, 1.0], move |p| {
            let r = (p - DVec3::new(12.0, 12.0, 12.0)).length();
            (1.5 - (r - 6.0) / 2.0).clamp(0.0, 2.0) as f32
        })
    };
    // The ball's opacity rises with its value: a soft, translucent ball.
    let ts = TransferFunction { scalar_opacity: vec![[0.0, 0.0], [2.0, 0.25]], ..tf(0.0, [1.0, 0.5, 0.1]) };
    let tb = tf(0.04, [0.9, 0.9, 0.9]);
    let cam = Camera {
        position: [12.0, -40.0, 30.0],
        focal_point: [12.0, 12.0, 12.0],
        view_up: [0.0, 0.0, 1.0],
        view_angle: 35.0,
        parallel_projection: false,
        parallel_scale: 1.0,
    };
    let rays = cam.rays(96, 96);
    let s = reference_volume::Settings { step: 0.1, ..Default::default() };
    let sphere = ball(0.0);
    let fused = render_fused(&[input(&boxed, &tb), input(&sphere, &ts)], &rays, &s).unwrap();
    let layered = Frame::composite(
        96,
        96,
        &[
            reference_volume::render(&input(&boxed, &tb), &rays, &s).unwrap(),
            reference_volume::render(&input(&sphere, &ts), &rays, &s).unwrap(),
        ],
    );
    // Inside the box's silhouette, 2 pixels from its edge (the edge itself is a jump in
    // any picture); the ball's edge is soft, so the fused picture is smooth there.
    let alone = reference_volume::render(&input(&boxed, &tb), &rays, &s).unwrap();
    let mask: Vec<bool> = (0..96 * 96)
        .map(|i| {
            let (x, y) = ((i % 96) as i64, (i / 96) as i64);
            (-2..=2).all(|dy| {
                (-2..=2).all(|dx| {
                    let (u, v) = (x + dx, y + dy);
                    (0..96).contains(&u) && (0..96).contains(&v) && alone.rgba[(v * 96 + u) as usize][3] > 0.0
                })
            })
        })
        .collect();
    assert!(mask.iter().filter(|m| **m).count() > 2000);
    let (jf, jl) = (largest_jump(&fused, &mask), largest_jump(&layered, &mask));
    eprintln!("largest neighbour jump: fused {jf:.3}, layered {jl:.3}");
    assert!(jl > 2.0 * jf, "the layered picture has a seam the fused one lacks: {jl} vs {jf}");
    assert!(jf < 0.15, "{jf}");
    // Half a voxel of the sphere's grid along x: a small, smooth change.
    let moved = ball(0.35);
    let shifted = render_fused(&[input(&boxed, &tb), input(&moved, &ts)], &rays, &s).unwrap();
    let change = volterra::compare::rgba_rel_rmse(&fused.rgba, &shifted.rgba);
    let js = largest_jump(&shifted, &mask);
    eprintln!("moved half a voxel: relative RMSE {change:.4}, largest jump {js:.3}");
    assert!(change > 1e-4 && change < 0.05, "{change}");
    assert!((js - jf).abs() < 0.05, "{jf} → {js}");
}

#[test]
fn scenes_fuse_overlapping_volume_nodes_by_themselves() {
    let dir = tempfile::tempdir().unwrap();
    let a = placed([12, 12, 12], 2.0, 0.0, [0.0, 0.0, 0.0], |_| 1.0);
    let b = placed([12, 12, 12], 1.5, 25.0, [8.0, 4.0, 6.0], |_| 1.0);
    let far = placed([6, 6, 6], 1.0, 0.0, [60.0, 0.0, 0.0], |_| 1.0);
    for (v, name) in [(&a, "a.nii"), (&b, "b.nii"), (&far, "far.nii")] {
        volterra_formats::nifti::write_nifti(&dir.path().join(name), v).unwrap();
    }
    let node_with = |name: &str, renderer: &str, extra: &str| {
        format!(
            "[[node]]\nname = \"{name}\"\nkind = \"volume\"\nfile = \"{name}.nii\"\nrenderer = \"{renderer}\"\n{extra}\
             [node.transfer_function]\nscalar_opacity = [[0.0, 0.0], [0.5, 0.0], [0.5000001, 0.1], [2.0, 0.1]]\n"
        )
    };
    let node = |name: &str, renderer: &str| node_with(name, renderer, "");
    let head =
        "[image]\nwidth = 48\nheight = 40\n[camera]\nposition = [-30.0, -60.0, 40.0]\nfocal_point = [20.0, 8.0, 10.0]\nview_angle = 40.0\n";
    let load = |text: String| {
        std::fs::write(dir.path().join("s.toml"), text).unwrap();
        volterra::scene::Scene::load(&dir.path().join("s.toml"), &[]).unwrap()
    };
    let scene = load(format!("{head}{}{}{}", node("a", "reference"), node("b", "reference"), node("far", "reference")));
    assert_eq!(volterra::render::fusion_groups(&scene).unwrap(), vec![vec![0, 1]], "a and b overlap; far stands apart");
    let frame = volterra::render::render_scene(&scene, None).unwrap();
    assert!(frame.stats.notes.iter().any(|n| n.contains("2 volumes fused")), "{:?}", frame.stats.notes);
    // The scene's picture: the fused pair over the lone volume, as rendered by hand.
    let s = reference_volume::Settings::default();
    let (ta, tb) = (scene.transfer_function(0).unwrap(), scene.transfer_function(1).unwrap());
    let rays = scene.camera(None).unwrap().rays(48, 40);
    let pair = render_fused(&[input(&scene.volume(0).unwrap(), &ta), input(&scene.volume(1).unwrap(), &tb)], &rays, &s).unwrap();
    let tf_far = scene.transfer_function(2).unwrap();
    let lone = reference_volume::render(&input(&scene.volume(2).unwrap(), &tf_far), &rays, &s).unwrap();
    let by_hand = Frame::composite(48, 40, &[lone, pair.clone()]);
    assert_eq!(frame.rgba, by_hand.rgba);
    // Shear-warp nodes that overlap but that shear-warp cannot fuse (neither inside the
    // other) are fused by the reference at its preview step, which the frame says.
    let scene = load(format!("{head}{}{}", node("a", "shear-warp"), node("b", "shear-warp")));
    let frame = volterra::render::render_scene(&scene, None).unwrap();
    assert!(
        frame.stats.notes.iter().any(|n| n.contains("not by shear-warp: neither volume lies inside the other")),
        "{:?}",
        frame.stats.notes
    );
    // A volume inside another, both shear-warp: fused by shear-warp on the outer one's grid
    // (whichever is listed first), refined ×2 to the inner one's 1.5 mm (the outer's 2 mm
    // would lose its detail).
    let inner = placed([8, 8, 8], 1.5, 10.0, [6.0, 4.0, 4.0], |p| ((p - DVec3::new(10.0, 9.5, 9.0)).length() < 4.0) as u8 as f32);
    volterra_formats::nifti::write_nifti(&dir.path().join("inner.nii"), &inner).unwrap();
    let scene = load(format!("{head}{}{}", node("inner", "shear-warp"), node("a", "shear-warp")));
    assert_eq!(volterra::render::shear_warp_pair(&scene, &[0, 1]), Ok((1, 0)));
    let frame = volterra::render::render_scene(&scene, None).unwrap();
    assert!(
        frame
            .stats
            .notes
            .iter()
            .any(|n| n.contains("by shear-warp on the grid of 'a' refined 2×2×2 (23×23×23 voxels) to the voxel size of 'inner'")),
        "{:?}",
        frame.stats.notes
    );
    assert!(frame.rgba.iter().any(|p| p[3] > 0.05));
    // One that is not transparent at its lowest value (what it takes outside its box) is not.
    let opaque_low = node("inner", "shear-warp").replace("[[0.0, 0.0], [0.5, 0.0]", "[[0.0, 0.2], [0.5, 0.2]");
    let scene = load(format!("{head}{opaque_low}{}", node("a", "shear-warp")));
    assert_eq!(volterra::render::shear_warp_pair(&scene, &[0, 1]), Err("'inner' is not transparent at its lowest value".to_string()));
    // MIP volumes stay layers.
    let scene = load(format!("{head}{}{}", node_with("a", "reference", "blend = \"mip\"\n"), node("b", "reference")));
    assert!(volterra::render::fusion_groups(&scene).unwrap().is_empty());

    // opacity_scale fades one volume of the pair: s = 0.5 draws as if its opacity 0.1 per
    // unit distance were 1 − 0.9^0.5 (points written out here, not the unit distance the
    // scene divides), s = 0 as if it were not there.
    let faded = |scale: f64| {
        let scene = load(format!("{head}{}{}", node_with("a", "reference", &format!("opacity_scale = {scale}\n")), node("b", "reference")));
        volterra::render::render_scene(&scene, None).unwrap()
    };
    let a_alpha = 1.0 - 0.9f64.sqrt();
    let ta_half = TransferFunction {
        scalar_opacity: vec![[0.0, 0.0], [0.5, 0.0], [0.5000001, a_alpha], [2.0, a_alpha]],
        ..scene.transfer_function(0).unwrap()
    };
    let (va, vb) = (scene.volume(0).unwrap(), scene.volume(1).unwrap());
    let want = render_fused(&[input(&va, &ta_half), input(&vb, &tb)], &rays, &s).unwrap();
    let got = faded(0.5);
    let diff = got.rgba.iter().zip(&want.rgba).map(|(p, q)| (0..4).map(|k| (p[k] - q[k]).abs()).fold(0.0f32, f32::max)).fold(0.0, f32::max);
    let unfaded = pair.rgba.iter().zip(&want.rgba).map(|(p, q)| (p[3] - q[3]).abs()).fold(0.0f32, f32::max);
    eprintln!("opacity_scale 0.5 vs faded points: {diff:e} (the unfaded pair differs by {unfaded})");
    assert!(diff < 1e-5, "opacity_scale 0.5 differs from the faded transfer function by {diff}");
    assert!(unfaded > 0.02, "the fading is visible: {unfaded}");
    let b_alone = reference_volume::render(&input(&vb, &tb), &rays, &s).unwrap();
    let gone = faded(0.0);
    let diff =
        gone.rgba.iter().zip(&b_alone.rgba).map(|(p, q)| (0..4).map(|k| (p[k] - q[k]).abs()).fold(0.0f32, f32::max)).fold(0.0, f32::max);
    assert!(diff < 1e-5, "opacity_scale 0 leaves b alone: {diff}");
    // A scale on a node that is not a volume, or out of range, is refused at load.
    std::fs::write(dir.path().join("s.toml"), format!("{head}{}", node_with("a", "reference", "opacity_scale = -1.0\n"))).unwrap();
    let err = volterra::scene::Scene::load(&dir.path().join("s.toml"), &[]).err().unwrap().to_string();
    assert!(err.contains("opacity_scale -1 must be between 0 and 1000"), "{err}");
}

/// The real pair in `../shared/data`: group-average FDOPA PET (3 mm) over the MNI152 T1
/// template (1 mm), both in MNI space, two shear-warp nodes — what the scene draws (the PET
/// resampled onto the T1's grid, fused by shear-warp) against the reference's fused picture
/// at its own step (0.05 voxel) at three views; beside it the reference fused at its preview
/// step (0.25, what such scenes got before shear-warp fused) and each node drawn by
/// shear-warp as its own layer. The MR is faded (`opacity_scale`) so that the PET inside
/// shows.
#[test]
fn fdopa_pet_over_the_mni_t1_is_fused_close_to_the_reference() {
    let Some(shared) = common::shared_data() else { return };
    let (mr, pet) = (
        shared.join("volumes/mr/mni_icbm152_t1_tal_nlin_sym_09a_converted.nii.gz"),
        shared.join("volumes/pet/FDOPA_fluorodopa_hc12_gomez.nii"),
    );
    let dir = tempfile::tempdir().unwrap();
    let views = [
        ("front", [0.0, 420.0, 18.0], [0.0, 0.0, 1.0]),
        ("oblique", [300.0, 260.0, 220.0], [0.0, 0.0, 1.0]),
        ("top", [0.0, -18.0, 430.0], [0.0, 1.0, 0.0]),
    ];
    let size = 96;
    for (name, position, up) in views {
        let text = format!(
            "[image]\nwidth = {size}\nheight = {size}\n[camera]\nposition = {position:?}\nfocal_point = [0.0, -18.0, 18.0]\n\
             view_up = {up:?}\nview_angle = 35.0\n\
             [[node]]\nname = \"mr\"\nkind = \"volume\"\nfile = {mr:?}\npreset = \"MR-Default\"\nopacity_scale = 0.3\n\
             [[node]]\nname = \"pet\"\nkind = \"volume\"\nfile = {pet:?}\npreset = \"PET-Hot\"\n"
        );
        std::fs::write(dir.path().join("pair.toml"), text).unwrap();
        let scene = volterra::scene::Scene::load(&dir.path().join("pair.toml"), &[]).unwrap();
        assert_eq!(volterra::render::fusion_groups(&scene).unwrap(), vec![vec![0, 1]]);
        assert_eq!(volterra::render::shear_warp_pair(&scene, &[0, 1]), Ok((0, 1)), "the PET lies inside the T1's box");
        let cache = volterra::render::RenderCache::default();
        let camera = scene.camera(None).unwrap();
        // Once to prepare (resampling the PET onto the T1's grid), once as a further frame.
        let t = std::time::Instant::now();
        volterra::render::render_view(&scene, &camera, (size, size), &cache).unwrap();
        let first_s = t.elapsed().as_secs_f64();
        let t = std::time::Instant::now();
        let drawn = volterra::render::render_view(&scene, &camera, (size, size), &cache).unwrap();
        let drawn_s = t.elapsed().as_secs_f64();
        assert!(drawn.stats.notes.iter().any(|n| n.contains("fused along each ray by shear-warp")), "{:?}", drawn.stats.notes);
        let owned: Vec<_> = (0..2)
            .map(|i| (scene.volume(i).unwrap(), scene.classification(i).unwrap(), scene.shading(i), scene.world_transform(i)))
            .collect();
        let inputs: Vec<VolumeInput> = owned
            .iter()
            .map(|(v, tf, shading, m)| VolumeInput {
                volume: v,
                node_to_world: *m,
                tf,
                blend: BlendMode::Composite,
                shading: shading.as_ref(),
                lights: &[],
                crop: &[],
            })
            .collect();
        let rays = camera.rays(size, size);
        let t = std::time::Instant::now();
        let truth = render_fused(&inputs, &rays, &reference_volume::Settings::default()).unwrap();
        let truth_s = t.elapsed().as_secs_f64();
        let t = std::time::Instant::now();
        let preview = render_fused(&inputs, &rays, &reference_volume::Settings { step: 0.25, ..Default::default() }).unwrap();
        let preview_s = t.elapsed().as_secs_f64();
        let layers: Vec<Frame> =
            (0..2).map(|i| volterra::render::render_node_with(&scene, i, &camera, (size, size), &cache).unwrap().unwrap()).collect();
        let layered = Frame::composite(size, size, &layers);
        let (e_drawn, e_preview, e_layered) =
            (relative_rmse(&drawn, &truth), relative_rmse(&preview, &truth), relative_rmse(&layered, &truth));
        let pet_share = truth.rgba.iter().filter(|p| p[0] > 1.5 * p[2] + 0.02).count();
        eprintln!(
            "{name}: shear-warp fused {:.2} % in {drawn_s:.2} s (first frame {first_s:.2} s); reference at 0.25 {:.2} % in {preview_s:.2} s; \
             shear-warp layers {:.2} %; truth (reference 0.05) {truth_s:.1} s; {pet_share} PET-red pixels",
            100.0 * e_drawn,
            100.0 * e_preview,
            100.0 * e_layered
        );
        assert!(pet_share > size * size / 50, "{name}: the PET shows through the faded MR ({pet_share} pixels)");
        assert!(e_drawn < 0.02, "{name}: the scene's fused picture is {:.2} % from the reference", 100.0 * e_drawn);
        // Both nodes on the GPU: fused there, each on its own grid, as close to the truth.
        if common::gpu().is_some() {
            let sets = ["node.mr.renderer=gpu-raycast".to_string(), "node.pet.renderer=gpu-raycast".to_string()];
            let on_gpu = volterra::scene::Scene::load(&dir.path().join("pair.toml"), &sets).unwrap();
            let gpu = volterra::render::render_view(&on_gpu, &camera, (size, size), &volterra::render::RenderCache::default()).unwrap();
            assert!(gpu.stats.notes.iter().any(|n| n.contains("fused along each ray on the GPU")), "{:?}", gpu.stats.notes);
            let e_gpu = relative_rmse(&gpu, &truth);
            eprintln!("{name}: gpu-raycast fused {:.2} %", 100.0 * e_gpu);
            assert!(e_gpu < 0.02, "{name}: the GPU's fused picture is {:.2} % from the reference", 100.0 * e_gpu);
        }
    }
}

/// RMSE over RGBA relative to the reference's RMS.
fn relative_rmse(f: &Frame, truth: &Frame) -> f64 {
    let (mut e, mut r) = (0.0, 0.0);
    for (p, q) in f.rgba.iter().zip(&truth.rgba) {
        for k in 0..4 {
            e += ((p[k] - q[k]) as f64).powi(2);
            r += (q[k] as f64).powi(2);
        }
    }
    (e / r.max(1e-30)).sqrt()
}

/// Shear-warp fuses a second volume resampled onto the first's grid: a soft translucent
/// ball on a finer, turned grid inside a translucent box, against the reference's fused
/// picture at several views (parallel and perspective, axis-aligned and oblique): the
/// relative RMSE stays within a few percent, where drawing each volume by shear-warp as
/// its own layer is far off; through a scene, two shear-warp nodes are fused by shear-warp.
#[test]
fn shear_warp_fuses_a_second_volume_resampled_onto_the_first_ones_grid() {
    use volterra::render::shear_warp::{self, fusion};
    use volterra::scene::VolumeShading;
    let boxed = placed([17, 17, 17], 1.5, 0.0, [0.0, 0.0, 0.0], |_| 1.0);
    let ball = placed([25, 25, 25], 0.6, 20.0, [6.0, 4.0, 4.0], |p| {
        let r = (p - DVec3::new(11.0, 12.0, 11.0)).length();
        (1.5 - (r - 5.0) / 2.0).clamp(0.0, 2.0) as f32
    });
    let ts = TransferFunction { scalar_opacity: vec![[0.0, 0.0], [2.0, 0.3]], ..tf(0.0, [1.0, 0.5, 0.1]) };
    let tb = tf(0.05, [0.3, 0.6, 0.9]);
    let limits = volterra_formats::Limits::default();
    let first = shear_warp::Prepared::new(&boxed, &limits).unwrap();
    let on_grid = fusion::resample_onto(&boxed, DMat4::IDENTITY, &ball, DMat4::IDENTITY, &limits).unwrap();
    let second = shear_warp::Prepared::new(&on_grid, &limits).unwrap();
    let ball_alone = shear_warp::Prepared::new(&ball, &limits).unwrap();
    let sw_input = |prepared, tf, shading, second| shear_warp::Input {
        prepared,
        node_to_world: DMat4::IDENTITY,
        tf,
        blend: BlendMode::Composite,
        shading,
        lights: &[],
        crop: &[],
        second,
    };
    let ref_input = |volume, tf, shading| VolumeInput {
        volume,
        node_to_world: DMat4::IDENTITY,
        tf,
        blend: BlendMode::Composite,
        shading,
        lights: &[],
        crop: &[],
    };
    let views = [
        ("perspective oblique", [-20.0, -30.0, 40.0], false),
        ("perspective along y", [12.0, -60.0, 12.0], false),
        ("parallel oblique", [50.0, -25.0, 30.0], true),
        ("parallel near 45°", [52.0, -28.0, 12.0], true),
    ];
    let s = reference_volume::Settings::default();
    // Unshaded, then both volumes shaded (VTK's coefficients, a headlight).
    let lit = VolumeShading { shade: true, ..Default::default() };
    for shading in [None, Some(&lit)] {
        for (name, position, parallel) in views {
            let name = format!("{name}{}", if shading.is_some() { ", shaded" } else { "" });
            let cam = Camera {
                position,
                focal_point: [12.0, 12.0, 12.0],
                view_up: [0.0, 0.0, 1.0],
                view_angle: 40.0,
                parallel_projection: parallel,
                parallel_scale: 18.0,
            };
            let rays = cam.rays(96, 96);
            let truth = render_fused(&[ref_input(&boxed, &tb, shading), ref_input(&ball, &ts, shading)], &rays, &s).unwrap();
            let t = std::time::Instant::now();
            let with_second = Some(fusion::Second { prepared: &second, tf: &ts, shading });
            let fused = shear_warp::render(&sw_input(&first, &tb, shading, with_second), &rays, &Default::default()).unwrap();
            let sw_s = t.elapsed().as_secs_f64();
            // Each volume by shear-warp as its own layer (the ball on its own grid).
            let ball_layer = shear_warp::render(&sw_input(&ball_alone, &ts, shading, None), &rays, &Default::default()).unwrap();
            let box_layer = shear_warp::render(&sw_input(&first, &tb, shading, None), &rays, &Default::default()).unwrap();
            let layered = Frame::composite(96, 96, &[box_layer, ball_layer]);
            let (e_fused, e_layered) = (relative_rmse(&fused, &truth), relative_rmse(&layered, &truth));
            // What the resampling adds: the reference on the resampled ball against the truth.
            let on_first_grid = render_fused(&[ref_input(&boxed, &tb, shading), ref_input(&on_grid, &ts, shading)], &rays, &s).unwrap();
            let (e_resampling, e_own) = (relative_rmse(&on_first_grid, &truth), relative_rmse(&fused, &on_first_grid));
            eprintln!(
                "{name}: shear-warp fused {:.2} % in {sw_s:.3} s (resampling alone {:.2} %, shear-warp on the resampled pair {:.2} %), shear-warp layers {:.2} %",
                100.0 * e_fused,
                100.0 * e_resampling,
                100.0 * e_own,
                100.0 * e_layered
            );
            assert!(e_fused < 0.03, "{name}: fused shear-warp is {:.2} % from the reference", 100.0 * e_fused);
            assert!(e_layered > 2.0 * e_fused, "{name}: layers {:.2} % vs fused {:.2} %", 100.0 * e_layered, 100.0 * e_fused);
        }
    }
}

/// A fine volume inside a coarse one keeps its detail (issue 44): thin vessels on a 0.5 mm
/// grid inside a smooth 3 mm "SPECT" are drawn by shear-warp on the coarse grid refined to
/// 0.5 mm, close to the reference (each volume sampled on its own grid), where resampling
/// the vessels onto the 3 mm grid turned them into rows of blobs; a coarse volume inside a
/// fine one is drawn on the fine grid as before. Through scenes, parallel and perspective.
#[test]
fn fused_volumes_keep_the_finer_ones_resolution_both_ways() {
    use volterra::render::shear_warp::{self, fusion};
    let dir = tempfile::tempdir().unwrap();
    // Vessels: tubes of radius 0.6 mm (a helix and two straight ones) on a 0.5 mm grid.
    let vessel = |p: DVec3| -> f32 {
        let c = DVec3::new(24.0, 22.0, 20.0);
        let q = p - c;
        let helix = {
            let t = q.z / 4.0;
            (DVec3::new(q.x - 8.0 * t.cos(), q.y - 8.0 * t.sin(), 0.0)).length()
        };
        let straight = |a: DVec3, d: DVec3| (q - a - d * (q - a).dot(d)).length();
        let r = helix
            .min(straight(DVec3::new(-3.0, 2.0, 0.0), DVec3::new(0.6, 0.8, 0.0)))
            .min(straight(DVec3::ZERO, DVec3::new(0.0, 0.6, 0.8)));
        (1.0 - (r - 0.6) / 0.5).clamp(0.0, 2.0) as f32
    };
    let fine = placed([64, 64, 56], 0.5, 0.0, [8.0, 6.0, 6.0], vessel);
    let spect = placed([17, 17, 17], 3.0, 0.0, [0.0, 0.0, 0.0], |p| {
        (2.0 * (-(p - DVec3::new(24.0, 24.0, 24.0)).length_squared() / 300.0).exp()) as f32
    });
    // Coarse inside fine: a 3 mm blob inside a 1 mm volume with 1 mm-scale ripples.
    let rippled = placed([48, 48, 48], 1.0, 0.0, [0.0, 0.0, 0.0], |p| (1.0 + 0.8 * (p.x / 1.7).sin() * (p.y / 2.3).cos()) as f32);
    let blob = placed([9, 9, 9], 3.0, 15.0, [14.0, 10.0, 12.0], |p| {
        (2.0 * (-(p - DVec3::new(24.0, 24.0, 24.0)).length_squared() / 60.0).exp()) as f32
    });
    for (v, name) in [(&fine, "fine"), (&spect, "spect"), (&rippled, "rippled"), (&blob, "blob")] {
        volterra_formats::nifti::write_nifti(&dir.path().join(format!("{name}.nii")), v).unwrap();
    }
    let node = |name: &str, opacity: &str, colour: &str| {
        format!(
            "[[node]]\nname = \"{name}\"\nkind = \"volume\"\nfile = \"{name}.nii\"\nrenderer = \"shear-warp\"\n\
             [node.transfer_function]\nscalar_opacity = {opacity}\ncolor = {colour}\n"
        )
    };
    let vessels_tf = ("[[0.0, 0.0], [0.4, 0.0], [1.0, 0.8], [2.0, 0.8]]", "[[0.0, 1.0, 0.2, 0.1]]");
    let glow_tf = ("[[0.0, 0.0], [0.3, 0.0], [2.0, 0.03]]", "[[0.0, 0.2, 0.5, 1.0]]");
    let cases = [
        ("vessels 0.5 mm in a 3 mm SPECT", node("spect", glow_tf.0, glow_tf.1) + &node("fine", vessels_tf.0, vessels_tf.1), true),
        ("3 mm blob in a 1 mm volume", node("rippled", glow_tf.0, glow_tf.1) + &node("blob", vessels_tf.0, vessels_tf.1), false),
    ];
    for (case, nodes, refined) in cases {
        for (view, position, parallel) in [("perspective", [-30.0, -50.0, 60.0], false), ("parallel", [70.0, -20.0, 40.0], true)] {
            let text = format!(
                "[image]\nwidth = 128\nheight = 128\n[camera]\nposition = {position:?}\nfocal_point = [24.0, 24.0, 22.0]\n\
                 view_angle = 40.0\nparallel_projection = {parallel}\nparallel_scale = 26.0\n{nodes}"
            );
            std::fs::write(dir.path().join("pair.toml"), text).unwrap();
            let scene = volterra::scene::Scene::load(&dir.path().join("pair.toml"), &[]).unwrap();
            assert_eq!(volterra::render::shear_warp_pair(&scene, &[0, 1]), Ok((0, 1)), "{case}");
            let camera = scene.camera(None).unwrap();
            let t = std::time::Instant::now();
            let drawn = volterra::render::render_view(&scene, &camera, (128, 128), &Default::default()).unwrap();
            let drawn_s = t.elapsed().as_secs_f64();
            let note = drawn.stats.notes.iter().find(|n| n.contains("fused along each ray by shear-warp")).unwrap().clone();
            assert_eq!(note.contains("refined 6×6×6"), refined, "{case}: {note}");
            let owned: Vec<_> = (0..2).map(|i| (scene.volume(i).unwrap(), scene.classification(i).unwrap())).collect();
            let inputs: Vec<VolumeInput> = owned.iter().map(|(v, tf)| input(v, tf)).collect();
            let rays = camera.rays(128, 128);
            let truth = render_fused(&inputs, &rays, &reference_volume::Settings::default()).unwrap();
            // Before: the second resampled onto the first's own grid.
            let limits = volterra_formats::Limits::default();
            let first = shear_warp::Prepared::new(&owned[0].0, &limits).unwrap();
            let on_coarse = fusion::resample_onto(&owned[0].0, DMat4::IDENTITY, &owned[1].0, DMat4::IDENTITY, &limits).unwrap();
            let second = shear_warp::Prepared::new(&on_coarse, &limits).unwrap();
            let before_input = shear_warp::Input {
                prepared: &first,
                node_to_world: DMat4::IDENTITY,
                tf: &owned[0].1,
                blend: BlendMode::Composite,
                shading: None,
                lights: &[],
                crop: &[],
                second: Some(fusion::Second { prepared: &second, tf: &owned[1].1, shading: None }),
            };
            let before = shear_warp::render(&before_input, &rays, &Default::default()).unwrap();
            let (e_now, e_before) = (relative_rmse(&drawn, &truth), relative_rmse(&before, &truth));
            eprintln!(
                "{case}, {view}: shear-warp fused {:.2} % in {drawn_s:.2} s ({note}); on the first's own grid {:.2} %",
                100.0 * e_now,
                100.0 * e_before
            );
            assert!(e_now < 0.05, "{case}, {view}: {:.2} % from the reference", 100.0 * e_now);
            if refined {
                assert!(e_before > 3.0 * e_now, "{case}, {view}: the coarse grid's {:.2} % vs {:.2} %", 100.0 * e_before, 100.0 * e_now);
            } else {
                assert_eq!(drawn.rgba, before.rgba, "{case}, {view}: a coarse second on the fine grid, as before");
            }
        }
    }
}
