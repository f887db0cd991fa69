//! The viewer driven through its UI (egui_kittest, AccessKit): open a sample, edit the
//! transfer function, switch renderers, save the view as a scene and as EXR, re-render the
//! scene with the CLI and get the same image. Then a real window under Xvfb on the software
//! adapter, screenshot checked.

mod common;

use egui_kittest::kittest::Queryable;
use egui_kittest::Harness;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;
use volterra::formats::{exr_io, LoadOptions};
use volterra::scene::presets::{Preset, ValueStats};
use volterra_view::worker::Quality;
use volterra_view::Viewer;

fn samples() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    volterra::samples::write_samples(dir.path()).unwrap();
    dir
}

/// Steps the UI until the full-quality frame of the current state is there.
fn settle(h: &mut Harness<'_, Viewer>) {
    for _ in 0..200 {
        h.run_steps(2);
        if h.state().current_full_frame().is_some() && !h.state().rendering() {
            h.run_steps(1);
            return;
        }
        if let Some(e) = h.state().last_error() {
            panic!("viewer error: {e}");
        }
        // Past the settle time of a change, and until the worker has delivered.
        std::thread::sleep(volterra_view::app::SETTLE / 4);
        h.state().wait_for_renders(Duration::from_secs(120));
    }
    panic!("no full-quality frame after 200 rounds");
}

fn harness(viewer: Viewer) -> Harness<'static, Viewer> {
    Harness::builder().with_size([1100.0, 640.0]).build_ui_state(|ui, v: &mut Viewer| v.ui(ui), viewer)
}

fn mean_rgba(f: &volterra::render::Frame) -> [f64; 4] {
    let mut m = [0.0; 4];
    for p in &f.rgba {
        for k in 0..4 {
            m[k] += p[k] as f64 / f.rgba.len() as f64;
        }
    }
    m
}

/// The viewer on the scene or data file at `path`, its first full frame drawn.
fn settled_on(path: &std::path::Path) -> Harness<'static, Viewer> {
    let mut viewer = Viewer::new(LoadOptions::default());
    viewer.open(path).unwrap();
    let mut h = harness(viewer);
    settle(&mut h);
    h
}

/// Clicks the panel's control labelled `label` (scrolled into view first) and waits for
/// the full frame that follows.
fn click_in_panel(h: &mut Harness<'_, Viewer>, label: &str) {
    h.get_by_label(label).scroll_to_me();
    h.run_steps(3);
    h.get_by_label(label).click();
    h.run_steps(3);
    settle(h);
}

/// Sets the panel's slider or drag value (`role`, `label`) to `value` through AccessKit,
/// scrolled into view first.
fn set_in_panel(h: &mut Harness<'_, Viewer>, role: egui::accesskit::Role, label: &str, value: f64) {
    h.get_by_role_and_label(role, label).scroll_to_me();
    h.run_steps(3);
    h.get_by_role_and_label(role, label).set_value_accesskit(value);
    h.run_steps(3);
}

/// Saves through the toolbar's "Save as" field and "Save" button (the extension picks a
/// scene, EXR or PNG).
fn save_through_toolbar(h: &mut Harness<'_, Viewer>, path: &std::path::Path) {
    h.get_by_label("Save as").focus();
    h.run_steps(1);
    h.get_by_label("Save as").set_text_value_accesskit(&path.display().to_string());
    h.run_steps(1);
    h.get_by_label("Save").click();
    h.run_steps(2);
}

/// `volterra render SCENE -o DIR/cli.exr`, read back.
fn render_with_cli(scene: &std::path::Path, dir: &std::path::Path) -> exr_io::FloatImage {
    let cli = dir.join("cli.exr");
    let st = Command::new(common::volterra_bin()).arg("render").arg(scene).arg("-o").arg(&cli).status().unwrap();
    assert!(st.success());
    exr_io::read_exr(&cli, &Default::default()).unwrap()
}

#[test]
fn open_edit_switch_save_and_rerender_gives_the_same_image() {
    let dir = samples();
    let mut h = settled_on(&dir.path().join("angio_shear_warp.toml"));
    let first = h.state().current_full_frame().unwrap().clone();
    let m0 = mean_rgba(&first);
    assert!(m0[3] > 0.02, "the phantom covers part of the view: mean alpha {}", m0[3]);
    assert!(m0[0] > m0[2], "the angiography transfer function is red over blue: {m0:?}");
    assert_eq!(first.stats.renderer, "shear-warp");

    // Transfer function: choose the CT-Bone preset from the editor's combo box; the node
    // keeps it by name (what a saved scene says), drawn by the preset's points.
    h.get_by_label("Preset").scroll_to_me();
    h.run_steps(3);
    h.get_by_label("Preset").click();
    h.run_steps(3);
    h.get_by_label("CT-Bone").click();
    h.run_steps(3);
    settle(&mut h);
    let scene = h.state().scene().unwrap();
    let vol = scene.volume(0).unwrap();
    assert_eq!(scene.nodes()[0].preset.as_deref(), Some("CT-Bone"));
    assert!(scene.nodes()[0].transfer_function.is_none());
    let expected = Preset::CtBone.transfer_function(&ValueStats::of(&vol), 0.6);
    assert_eq!(scene.transfer_function(0).unwrap().scalar_opacity, expected.scalar_opacity);
    assert!(scene.shading(0).is_some_and(|s| s.shade), "with Slicer's shading");
    let m1 = mean_rgba(h.state().current_full_frame().unwrap());
    assert!((m1[3] - m0[3]).abs() > 1e-3, "a new transfer function changes the picture: {m0:?} → {m1:?}");

    // Renderer: shear-warp → reference (coarser step to keep the test short) → shear-warp.
    h.get_by_label("Renderer").click();
    h.run_steps(3);
    h.get_by_label("reference").click();
    h.run_steps(3);
    assert_eq!(h.state().scene().unwrap().nodes()[0].renderer.as_deref(), Some("reference"));
    settle(&mut h);
    assert_eq!(h.state().current_full_frame().unwrap().stats.renderer, "reference");
    let reference = h.state().current_full_frame().unwrap().clone();
    h.get_by_label("Renderer").click();
    h.run_steps(3);
    h.get_by_label("shear-warp").click();
    h.run_steps(3);
    settle(&mut h);
    let sw = h.state().current_full_frame().unwrap().clone();
    assert_eq!(sw.stats.renderer, "shear-warp");
    let err = volterra::compare::rgba_rel_rmse(&reference.rgba, &sw.rgba);
    assert!(err < 0.12, "shear-warp within 12 % of the reference at the viewer's view: {err}");

    // A camera move through the mouse: drag in the 3-D view orbits.
    let before = h.state().camera().position;
    let centre = egui::Pos2::new(640.0, 300.0);
    h.drag_at(centre);
    h.run_steps(1);
    h.hover_at(centre + egui::Vec2::new(60.0, 0.0));
    h.run_steps(1);
    h.drop_at(centre + egui::Vec2::new(60.0, 0.0));
    h.run_steps(1);
    assert_ne!(h.state().camera().position, before, "dragging the view orbits the camera");
    let previews = h.state().frames_shown(Quality::Preview);
    let fulls = h.state().frames_shown(Quality::Full);
    settle(&mut h);
    // Progressive: the move showed a quarter-resolution preview, then one full frame.
    assert!(h.state().frames_shown(Quality::Preview) > previews, "a preview was shown while moving");
    assert_eq!(h.state().frames_shown(Quality::Full), fulls + 1);

    // Save the view as a scene and the frame as EXR, through the toolbar.
    let out = tempfile::tempdir().unwrap();
    let scene_path = out.path().join("saved view.toml");
    let exr_path = out.path().join("viewer.exr");
    for path in [&scene_path, &exr_path] {
        save_through_toolbar(&mut h, path);
        assert_eq!(h.state().last_error(), None);
        assert!(path.exists(), "{} written; status: {:?}", path.display(), h.state().message());
    }
    // The saved scene names the sample data relative to itself.
    let text = std::fs::read_to_string(&scene_path).unwrap();
    assert!(text.contains("renderer = \"shear-warp\""), "{text}");
    assert!(!text.contains(&dir.path().display().to_string()), "data path written relative: {text}");

    let (a, b) = (exr_io::read_exr(&exr_path, &Default::default()).unwrap(), render_with_cli(&scene_path, out.path()));
    assert_eq!((a.width, a.height), (b.width, b.height));
    for ch in ["R", "G", "B", "A", "Z"] {
        let (x, y) = (a.channel(ch).unwrap(), b.channel(ch).unwrap());
        let diff = x.iter().zip(y).map(|(p, q)| if p == q { 0.0 } else { (p - q).abs() }).fold(0.0f32, f32::max);
        assert_eq!(diff, 0.0, "channel {ch}: the CLI render of the saved scene equals the viewer's frame");
    }
}

/// Shading switched on in the viewer: the node's `[shading]` says so, the picture darkens
/// away from the headlight, a specular change re-renders, and the saved scene renders to
/// the same image from the CLI.
#[test]
fn shading_switched_on_in_the_viewer_is_rendered_and_saved() {
    let dir = samples();
    let mut h = settled_on(&dir.path().join("angio_shear_warp.toml"));
    let plain = mean_rgba(h.state().current_full_frame().unwrap());
    // Below the transfer function editor: scrolled into view, then clicked.
    click_in_panel(&mut h, "Shading");
    let shading = h.state().scene().unwrap().nodes()[0].shading.expect("the node has [shading]");
    assert!(shading.shade);
    assert_eq!(shading, volterra::scene::VolumeShading { shade: true, ..Default::default() }, "VTK's coefficients");
    let shaded = mean_rgba(h.state().current_full_frame().unwrap());
    assert!((shaded[3] - plain[3]).abs() < 1e-6, "shading leaves opacity alone: {plain:?} → {shaded:?}");
    assert!(shaded[0] < 0.95 * plain[0], "diffuse 0.7 + ambient 0.1 darken the picture: {plain:?} → {shaded:?}");
    // The specular slider, set through AccessKit.
    set_in_panel(&mut h, egui::accesskit::Role::Slider, "Specular", 0.8);
    settle(&mut h);
    assert_eq!(h.state().scene().unwrap().nodes()[0].shading.unwrap().specular, 0.8);
    let glossy = h.state().current_full_frame().unwrap().clone();
    assert!(mean_rgba(&glossy)[0] > shaded[0], "more specular, brighter");

    let out = tempfile::tempdir().unwrap();
    let scene_path = out.path().join("shaded.toml");
    save_through_toolbar(&mut h, &scene_path);
    let text = std::fs::read_to_string(&scene_path).unwrap();
    assert!(text.contains("shade = true") && text.contains("specular = 0.8"), "{text}");
    let b = render_with_cli(&scene_path, out.path());
    let r = b.channel("R").unwrap();
    let diff = glossy.rgba.iter().zip(r).map(|(p, q)| (p[0] - q).abs()).fold(0.0f32, f32::max);
    assert_eq!(diff, 0.0, "the CLI render of the saved scene equals the viewer's frame");
}

/// "Opacity scale" fades a volume: less opacity drawn, `opacity_scale` saved, and the CLI
/// render of the saved scene equals the viewer's frame.
#[test]
fn the_opacity_scale_fades_a_volume_and_is_saved() {
    let dir = samples();
    let mut h = settled_on(&dir.path().join("angio_shear_warp.toml"));
    let plain = mean_rgba(h.state().current_full_frame().unwrap());
    set_in_panel(&mut h, egui::accesskit::Role::Slider, "Opacity scale", 0.25);
    settle(&mut h);
    assert_eq!(h.state().scene().unwrap().nodes()[0].opacity_scale, 0.25);
    let faded = h.state().current_full_frame().unwrap().clone();
    assert!(mean_rgba(&faded)[3] < 0.9 * plain[3], "less opaque: {plain:?} → {:?}", mean_rgba(&faded));
    let out = tempfile::tempdir().unwrap();
    let scene_path = out.path().join("faded.toml");
    save_through_toolbar(&mut h, &scene_path);
    let text = std::fs::read_to_string(&scene_path).unwrap();
    assert!(text.contains("opacity_scale = 0.25"), "{text}");
    let b = render_with_cli(&scene_path, out.path());
    let a = b.channel("A").unwrap();
    let diff = faded.rgba.iter().zip(a).map(|(p, q)| (p[3] - q).abs()).fold(0.0f32, f32::max);
    assert_eq!(diff, 0.0, "the CLI render of the saved scene equals the viewer's frame");
}

/// Gradient opacity in the viewer: switched on it changes nothing (factor 1 at every
/// gradient); the factor at zero gradient lowered to 0 fades the vessels' homogeneous
/// insides, so less is opaque; the saved scene carries the points and renders as the
/// viewer drew it.
#[test]
fn gradient_opacity_edited_in_the_viewer_is_rendered_and_saved() {
    let dir = samples();
    let mut h = settled_on(&dir.path().join("angio_shear_warp.toml"));
    let plain = h.state().current_full_frame().unwrap().clone();
    click_in_panel(&mut h, "Gradient opacity");
    let points =
        |h: &Harness<'_, Viewer>| h.state().scene().unwrap().nodes()[0].transfer_function.as_ref().unwrap().gradient_opacity.clone();
    let seeded = points(&h);
    assert_eq!(seeded.len(), 2, "{seeded:?}");
    assert!(seeded.iter().all(|p| p[1] == 1.0) && seeded[1][0] > 0.0, "{seeded:?}");
    let same = h.state().current_full_frame().unwrap();
    let worst = plain.rgba.iter().zip(&same.rgba).flat_map(|(p, q)| (0..4).map(move |c| (p[c] - q[c]).abs())).fold(0.0f32, f32::max);
    assert_eq!((plain.width, plain.height), (same.width, same.height), "the view keeps its size");
    assert!(worst < 1e-6, "gradient opacity at factor 1 changed a pixel by {worst}");

    // The second point further out (the phantom's vessel walls are steep), then the
    // factor at zero gradient down to 0.
    set_in_panel(&mut h, egui::accesskit::Role::SpinButton, "gradient 2", 400.0);
    set_in_panel(&mut h, egui::accesskit::Role::Slider, "factor 1", 0.0);
    settle(&mut h);
    assert_eq!(points(&h), vec![[0.0, 0.0], [400.0, 1.0]]);
    let faded = h.state().current_full_frame().unwrap().clone();
    let (a0, a1) = (mean_rgba(&plain)[3], mean_rgba(&faded)[3]);
    assert!(a1 < 0.95 * a0, "homogeneous regions fade: mean alpha {a0} → {a1}");
    assert!(a1 > 0.05 * a0, "edges stay: mean alpha {a0} → {a1}");

    let out = tempfile::tempdir().unwrap();
    let scene_path = out.path().join("gradient.toml");
    save_through_toolbar(&mut h, &scene_path);
    let text = std::fs::read_to_string(&scene_path).unwrap();
    assert!(text.contains("gradient_opacity"), "{text}");
    let b = render_with_cli(&scene_path, out.path());
    let a = b.channel("A").unwrap();
    let diff = faded.rgba.iter().zip(a).map(|(p, q)| (p[3] - q).abs()).fold(0.0f32, f32::max);
    assert_eq!(diff, 0.0, "the CLI render of the saved scene equals the viewer's frame");
}

/// Cropping in the viewer: the crop box switched on starts round the whole volume (the
/// image stays as it was), a face handle dragged in the 3-D view moves that face (and not
/// the camera), a clipping plane is added from the panel; the saved scene carries both and
/// renders as the viewer drew it.
#[test]
fn a_crop_box_dragged_in_the_viewer_is_rendered_and_saved() {
    let dir = samples();
    let mut h = settled_on(&dir.path().join("angio_shear_warp.toml"));
    let whole = h.state().current_full_frame().unwrap().clone();
    click_in_panel(&mut h, "Crop box");
    let full_box = h.state().scene().unwrap().nodes()[0].crop.expect("the node has a crop box");
    assert!((full_box.max[0] - full_box.min[0] - 127.0 * 0.6).abs() < 1e-4, "the box of voxel centres: {full_box:?}");
    let same = h.state().current_full_frame().unwrap();
    let worst = whole.rgba.iter().zip(&same.rgba).flat_map(|(p, q)| (0..4).map(move |c| (p[c] - q[c]).abs())).fold(0.0f32, f32::max);
    assert!(worst < 1e-6, "a crop box round the volume changed a pixel by {worst}");

    // Drag the +z face's handle down, toward the -z face's.
    let camera = h.state().camera().clone();
    let (top, bottom) = (h.state().crop_handle(5).unwrap(), h.state().crop_handle(4).unwrap());
    let to = top + (bottom - top) * 0.4;
    h.drag_at(top);
    h.run_steps(1);
    for k in 1..=4 {
        h.hover_at(top + (to - top) * (k as f32 / 4.0));
        h.run_steps(1);
    }
    h.drop_at(to);
    h.run_steps(1);
    settle(&mut h);
    assert_eq!(h.state().camera().position, camera.position, "dragging a handle does not move the camera");
    let cropped = h.state().scene().unwrap().nodes()[0].crop.unwrap();
    let moved = full_box.max[2] - cropped.max[2];
    assert!(moved > 0.2 * (full_box.max[2] - full_box.min[2]) && cropped.min == full_box.min, "{full_box:?} → {cropped:?}");
    let after = mean_rgba(h.state().current_full_frame().unwrap());
    assert!(after[3] < 0.9 * mean_rgba(&whole)[3], "less is drawn: {:?} → {after:?}", mean_rgba(&whole));

    click_in_panel(&mut h, "Add a clipping plane");
    assert_eq!(h.state().scene().unwrap().nodes()[0].clip.len(), 1);
    let frame = h.state().current_full_frame().unwrap().clone();
    let out = tempfile::tempdir().unwrap();
    let scene_path = out.path().join("cropped.toml");
    save_through_toolbar(&mut h, &scene_path);
    let text = std::fs::read_to_string(&scene_path).unwrap();
    assert!(text.contains("[node.crop]") && text.contains("[[node.clip]]"), "{text}");
    let b = render_with_cli(&scene_path, out.path());
    let a = b.channel("A").unwrap();
    let diff = frame.rgba.iter().zip(a).map(|(p, q)| (p[3] - q).abs()).fold(0.0f32, f32::max);
    assert_eq!(diff, 0.0, "the CLI render of the saved scene equals the viewer's frame");
}

/// A camera inside the volume (as zooming in puts it): shear-warp refuses the view, and
/// the viewer draws it with the reference ray caster instead of showing the refusal, and
/// says so; the scene keeps shear-warp.
#[test]
fn a_camera_inside_the_volume_is_drawn_by_the_reference() {
    let dir = samples();
    let text = std::fs::read_to_string(dir.path().join("angio_preset.toml")).unwrap();
    // In the trunk of the vessel tree, looking up it.
    let inside = text
        .replace("position = [110.0, 122.0, 36.5]", "position = [0.0, 0.0, -25.0]")
        .replace("focal_point = [0.0, 0.0, 0.0]", "focal_point = [0.0, 0.0, 10.0]")
        .replace("view_up = [0.0, 0.0, 1.0]", "view_up = [0.0, 1.0, 0.0]");
    assert_ne!(inside, text);
    std::fs::write(dir.path().join("inside.toml"), inside).unwrap();
    let mut viewer = Viewer::new(LoadOptions::default());
    viewer.open(&dir.path().join("inside.toml")).unwrap();
    let mut h = Harness::builder().with_size([900.0, 420.0]).build_ui_state(|ui, v: &mut Viewer| v.ui(ui), viewer);
    settle(&mut h);
    let frame = h.state().current_full_frame().unwrap();
    assert_eq!(frame.stats.renderer, "reference");
    let most = frame.rgba.iter().map(|p| p[3]).fold(0.0f32, f32::max);
    assert!(most > 0.05, "the vessels around the eye are drawn: {most}, {:?} {}x{}", frame.stats, frame.width, frame.height);
    assert_eq!(h.state().message(), Some(volterra_view::worker::EYE_INSIDE_NOTE));
    assert!(h.state().last_error().is_none());
    assert_eq!(h.state().scene().unwrap().nodes()[0].renderer, None, "the scene keeps its renderer");
}

/// A volume node that names the GPU ray-caster is drawn by it in the viewer, still and
/// while the camera moves (its preview: a one-voxel step), and with the eye inside the
/// volume by itself, not switched to the reference as shear-warp is.
#[test]
fn the_gpu_ray_caster_draws_volumes_in_the_viewer_even_from_inside() {
    if common::gpu().is_none() {
        return;
    }
    let dir = samples();
    let text = std::fs::read_to_string(dir.path().join("angio_preset.toml")).unwrap();
    let inside = text
        .replace("position = [110.0, 122.0, 36.5]", "position = [0.0, 0.0, -25.0]")
        .replace("focal_point = [0.0, 0.0, 0.0]", "focal_point = [0.0, 0.0, 10.0]")
        .replace("view_up = [0.0, 0.0, 1.0]", "view_up = [0.0, 1.0, 0.0]")
        .replace("kind = \"volume\"\n", "kind = \"volume\"\nrenderer = \"gpu-raycast\"\n");
    assert_eq!(inside.matches("gpu-raycast").count(), 1);
    std::fs::write(dir.path().join("inside_gpu.toml"), inside).unwrap();
    let mut viewer = Viewer::new(LoadOptions::default());
    viewer.open(&dir.path().join("inside_gpu.toml")).unwrap();
    let mut h = Harness::builder().with_size([900.0, 420.0]).build_ui_state(|ui, v: &mut Viewer| v.ui(ui), viewer);
    settle(&mut h);
    let frame = h.state().current_full_frame().unwrap();
    assert_eq!(frame.stats.renderer, "gpu-raycast");
    let most = frame.rgba.iter().map(|p| p[3]).fold(0.0f32, f32::max);
    assert!(most > 0.05, "the vessels around the eye are drawn: {most}");
    assert_ne!(h.state().message(), Some(volterra_view::worker::EYE_INSIDE_NOTE));
    assert!(h.state().last_error().is_none());
}

#[test]
fn opening_a_data_file_frames_it_and_measures_the_error() {
    let dir = samples();
    let mut viewer = Viewer::new(LoadOptions::default());
    viewer.open(&dir.path().join("angio_phantom.nii.gz")).unwrap();
    // No DICOM modality and no negative values: the percentile-based preset.
    let scene = viewer.scene().unwrap();
    // The GPU ray-caster on a hardware GPU, shear-warp on a CPU adapter (lavapipe), said.
    let hardware = volterra::gpu::device().is_ok_and(|d| !d.is_software());
    let expected = if hardware { "gpu-raycast" } else { "shear-warp" };
    assert_eq!(scene.nodes()[0].renderer.as_deref(), Some(expected));
    let message = viewer.message().unwrap();
    assert!(message.contains(&format!("volumes drawn by {expected}")), "{message}");
    // Volumes open in perspective, as in 3D Slicer (parallel is a toggle).
    assert!(!viewer.camera().parallel_projection);
    let mut h = harness(viewer);
    // Node metadata is listed as `volterra info` gives it.
    h.get_by_label("dims");
    h.get_by_label("128 × 128 × 128").hover();
    settle(&mut h);
    let m = mean_rgba(h.state().current_full_frame().unwrap());
    assert!(m[3] > 0.01, "the framed volume is visible: {m:?}");
    // Ctrl+click on the volume: the slice cross-hair jumps to the surface there.
    let frame = h.state().current_full_frame().unwrap().clone();
    let rect = h.state().viewport_rect().unwrap();
    let (px, depth) = (0..frame.depth.len())
        .map(|i| (i, frame.depth[i]))
        .filter(|(_, d)| d.is_finite())
        .nth(frame.depth.iter().filter(|d| d.is_finite()).count() / 2)
        .unwrap();
    let (x, y) = (px % frame.width, px / frame.width);
    let ray = h.state().camera().rays(frame.width, frame.height).ray(x as f64 + 0.5, y as f64 + 0.5);
    let expected = ray.origin + ray.dir * depth as f64;
    let pos = egui::Pos2::new(
        rect.left() + (x as f32 + 0.5) * rect.width() / frame.width as f32,
        rect.top() + (y as f32 + 0.5) * rect.height() / frame.height as f32,
    );
    let before = h.state().slice_cross().unwrap();
    h.hover_at(pos);
    h.run_steps(1);
    for pressed in [true, false] {
        h.event_modifiers(
            egui::Event::PointerButton { pos, button: egui::PointerButton::Primary, pressed, modifiers: egui::Modifiers::COMMAND },
            egui::Modifiers::COMMAND,
        );
        h.run_steps(1);
    }
    let cross = h.state().slice_cross().unwrap();
    assert!(cross.distance(expected) < 1e-6, "cross-hair {cross} should jump to {expected} (was {before})");
    // Error against the reference renderer, at the viewer's view.
    h.get_by_label("Measure error").click();
    h.run_steps(1);
    for _ in 0..100 {
        h.state().wait_for_renders(Duration::from_secs(300));
        h.run_steps(1);
        if h.state().error_vs_reference().is_some() {
            break;
        }
    }
    let e = h.state().error_vs_reference().cloned().expect("an error figure").unwrap();
    assert!(e > 0.0 && e < 0.15, "shear-warp vs reference: {e}");
}

#[test]
fn a_terrain_walk_keeps_the_eye_above_the_ground() {
    if !gpu_available() {
        return;
    }
    let dir = samples();
    let mut viewer = Viewer::new(LoadOptions::default());
    // The scene's [walk] puts the viewer in walk mode.
    viewer.open(&dir.path().join("terrain_walk.toml")).unwrap();
    let mut h = harness(viewer);
    settle(&mut h);
    let frame = h.state().current_full_frame().unwrap();
    assert_eq!(frame.stats.renderer, "terrain");
    // The step counts behind the heat-map overlay come with every terrain frame.
    let steps = &frame.extra.iter().find(|(n, _)| n == "steps").expect("a steps channel").1;
    assert!(steps.iter().any(|&s| s > 0.0));
    h.get_by_label("Step-count heat map").click();
    h.run_steps(1);
    let start = h.state().camera().position;
    // W walks forward while the pointer is over the 3-D view.
    h.hover_at(egui::Pos2::new(640.0, 300.0));
    h.key_down(egui::Key::W);
    h.run_steps(10);
    h.key_up(egui::Key::W);
    h.run_steps(1);
    let eye = h.state().camera().position;
    assert!((eye[0] - start[0]).hypot(eye[1] - start[1]) > 1.0, "walked: {start:?} → {eye:?}");
    let scene = h.state().scene().unwrap();
    // The viewer read the DEM's GeoTIFF by rows, for the GPU and the eye's ground alike.
    assert!(!scene.is_loaded(0), "the DEM was read whole");
    let ground = scene.heightfield(0).unwrap().surface_height(eye[0], eye[1]).unwrap();
    assert!((eye[2] - ground - 1.7).abs() < 1e-6, "eye {eye:?}, ground {ground}");
    settle(&mut h);
}

/// A GeoTIFF DEM opened in the viewer is read as the terrain ray-caster reads it — by rows
/// into the GPU's textures — never held: framed as the raster held would be, described in
/// the metadata panel as `volterra info` describes it, drawn.
#[test]
fn a_geotiff_dem_opens_by_rows_framed_and_described_as_the_raster_held() {
    if !gpu_available() {
        return;
    }
    let dir = samples();
    let dem = dir.path().join("fractal_dem.tif");
    let held = volterra::formats::geotiff::read_geotiff(&dem, &Default::default()).unwrap();
    let mut viewer = Viewer::new(LoadOptions::default());
    viewer.open(&dem).unwrap();
    let scene = viewer.scene().unwrap();
    assert!(matches!(scene.terrain_data(0).unwrap(), volterra::scene::TerrainData::Rows(_)));
    let bounds = volterra::scene::auto::data_bounds(
        &volterra::scene::NodeData::Heightfield(std::sync::Arc::new(held.clone())),
        glam::DMat4::IDENTITY,
    );
    let framed = volterra::scene::auto::fit_camera(volterra::scene::NodeKind::Heightfield, bounds.unwrap());
    assert_eq!(viewer.camera().position, framed.position, "framed as the raster held");
    assert_eq!(viewer.camera().focal_point, framed.focal_point);
    let mut h = harness(viewer);
    h.get_by_label("dims");
    h.get_by_label(&format!("{} × {}", held.width, held.height)).hover();
    let (lo, hi) = held.range().unwrap();
    h.get_by_label(&serde_json::json!(lo as f64).to_string());
    h.get_by_label(&serde_json::json!(hi as f64).to_string());
    settle(&mut h);
    let frame = h.state().current_full_frame().unwrap();
    assert_eq!(frame.stats.renderer, "terrain");
    assert!(mean_rgba(frame)[3] > 0.3, "the terrain is drawn: {:?}", mean_rgba(frame));
    assert!(!h.state().scene().unwrap().is_loaded(0), "the DEM was read whole");
}

fn gpu_available() -> bool {
    match volterra::render::terrain::gpu::gpu() {
        Ok(_) => true,
        Err(e) => {
            if std::env::var("CI").is_ok_and(|v| v == "true") {
                panic!("no wgpu adapter under CI: {e}");
            }
            eprintln!("skipped: no wgpu adapter ({e})");
            false
        }
    }
}

/// xvfb-run, which tests/setup-system.sh installs: None (skip, with a reason) where it is
/// missing locally; a failure under CI.
fn xvfb_run() -> Option<&'static Path> {
    let xvfb = Path::new("/usr/bin/xvfb-run");
    if xvfb.exists() {
        return Some(xvfb);
    }
    if std::env::var("CI").is_ok_and(|v| v == "true") {
        panic!("xvfb-run missing under CI (tests/setup-system.sh installs xvfb)");
    }
    eprintln!("skipped: xvfb-run not installed");
    None
}

/// A real window: `volterra view --screenshot` under Xvfb, on lavapipe.
/// `volterra view SCENE --screenshot` in a 1280 × 800 X server: the PNG written (beside
/// the scene).
fn screenshot_under_xvfb(xvfb: &Path, scene: &Path) -> PathBuf {
    let shot = scene.with_extension("window.png");
    let runtime = tempfile::tempdir().unwrap();
    let out = Command::new(xvfb)
        .args(["-a", "-s", "-screen 0 1280x800x24"])
        .arg(common::volterra_bin())
        .arg("view")
        .arg(scene)
        .arg("--screenshot")
        .arg(&shot)
        // Mesa's window-system code wants a runtime directory; CI shells have none.
        .env("XDG_RUNTIME_DIR", runtime.path())
        .output()
        .unwrap();
    assert!(out.status.success(), "viewer failed: {}", String::from_utf8_lossy(&out.stderr));
    shot
}

#[test]
fn a_real_window_under_xvfb_shows_the_render() {
    let Some(xvfb) = xvfb_run() else { return };
    let dir = samples();
    let shot = screenshot_under_xvfb(xvfb, &dir.path().join("angio_shear_warp.toml"));
    let img = volterra::formats::image::decode_png(&shot, &Default::default(), 0).unwrap();
    assert!(img.width >= 1000 && img.height >= 600, "window size {}×{}", img.width, img.height);
    assert_eq!((img.channels, img.bit_depth), (4, 8));
    let px: Vec<[u8; 4]> = img.samples.chunks_exact(4).map(|p| [p[0] as u8, p[1] as u8, p[2] as u8, p[3] as u8]).collect();
    // Not blank: many distinct colours (panels, text, the render, the slices).
    let distinct: std::collections::HashSet<[u8; 4]> = px.iter().copied().collect();
    assert!(distinct.len() > 500, "only {} distinct colours", distinct.len());
    // The expected colours: the phantom's vessels through the angiography transfer
    // function (red-orange: r well above b) covering a real area of the window …
    let vessel = px.iter().filter(|p| p[0] > 150 && (p[0] as i32 - p[2] as i32) > 40 && p[1] > 60).count();
    assert!(vessel > 5000, "vessel-coloured pixels: {vessel}");
    // … on the scene's black background in the 3-D view.
    let black = px.iter().filter(|p| p[0] < 3 && p[1] < 3 && p[2] < 3).count();
    assert!(black > 50_000, "background pixels: {black}");
}

/// A file dropped on the window, as the windowing integration hands it to egui.
#[derive(Debug)]
struct Dropped(PathBuf);

impl egui::DroppedFile for Dropped {
    fn path(&self) -> &Path {
        &self.0
    }
    fn bytes(&self) -> Result<Vec<u8>, String> {
        std::fs::read(&self.0).map_err(|e| e.to_string())
    }
}

fn wait_loaded(h: &mut Harness<'_, Viewer>) {
    for _ in 0..400 {
        h.run_steps(1);
        if !h.state().loading() {
            return;
        }
        std::thread::sleep(Duration::from_millis(25));
    }
    panic!("the file did not finish loading");
}

#[test]
fn files_open_from_the_dialog_and_by_drag_and_drop_without_blocking() {
    let dir = samples();
    let mut h = harness(Viewer::new(LoadOptions::default()));
    h.run_steps(2);
    assert!(h.state().scene().is_none());
    // The dialog: type a path, press Open; the file is read off the UI thread.
    h.get_by_label("Open…").click();
    h.run_steps(4);
    h.get_by_label("Path").focus();
    h.get_by_label("Path").set_text_value_accesskit(&dir.path().join("smoke_plume.vtp").display().to_string());
    h.run_steps(1);
    h.get_by_role_and_label(egui::accesskit::Role::Button, "Open").click();
    h.run_steps(1);
    wait_loaded(&mut h);
    let scene = h.state().scene().expect("opened from the dialog");
    assert_eq!(scene.nodes()[0].renderer.as_deref(), Some("points"), "particles open as points, smoke a click away");
    assert_eq!(scene.particles(0).unwrap().positions.len(), 20_000);
    // Drag and drop a DEM: it replaces the particles.
    h.input_mut().dropped_files.push(std::sync::Arc::new(Dropped(dir.path().join("fractal_dem.tif"))));
    h.run_steps(1);
    wait_loaded(&mut h);
    let scene = h.state().scene().unwrap();
    assert_eq!(scene.nodes()[0].renderer.as_deref(), Some("terrain"));
    // A file that cannot be read: one line naming it, in the status bar; the old scene stays.
    let bad = dir.path().join("broken.nii");
    std::fs::write(&bad, b"not a nifti file").unwrap();
    h.input_mut().dropped_files.push(std::sync::Arc::new(Dropped(bad.clone())));
    h.run_steps(1);
    wait_loaded(&mut h);
    let e = h.state().last_error().expect("an error for the broken file").to_string();
    assert!(e.contains("broken.nii") && !e.contains('\n'), "{e}");
    assert_eq!(h.state().scene().unwrap().nodes()[0].renderer.as_deref(), Some("terrain"));
    // The old scene's frames still arrive (on a loaded machine after the error, which a
    // frame used to wipe): the error stays until the next action.
    for _ in 0..400 {
        if h.state().frames_shown(Quality::Full) > 0 {
            break;
        }
        h.run_steps(1);
        std::thread::sleep(Duration::from_millis(25));
    }
    assert!(h.state().frames_shown(Quality::Full) > 0, "the terrain's frame never came");
    assert_eq!(h.state().last_error(), Some(e.as_str()), "a frame of the old scene cleared the error");
}

/// `volterra view SCENE --screenshot W.png` hung for ever when the first frame failed: it
/// prints the error and exits 1, no PNG. (The frame here fails because the particle node
/// gives no medium; a camera inside a volume, the case that found it, is now drawn by the
/// reference ray caster.)
#[test]
fn a_screenshot_of_a_scene_that_cannot_render_ends_with_the_error() {
    let Some(xvfb) = xvfb_run() else { return };
    let dir = samples();
    let text = std::fs::read_to_string(dir.path().join("smoke.toml")).unwrap();
    let scene = dir.path().join("no_medium.toml");
    let broken: String = text.lines().filter(|l| !l.starts_with("medium =")).map(|l| format!("{l}\n")).collect();
    assert_ne!(broken, text);
    std::fs::write(&scene, broken).unwrap();
    let shot = dir.path().join("never.png");
    let runtime = tempfile::tempdir().unwrap();
    let mut child = Command::new(xvfb)
        .args(["-a", "-s", "-screen 0 1280x800x24"])
        .arg(common::volterra_bin())
        .arg("view")
        .arg(&scene)
        .arg("--screenshot")
        .arg(&shot)
        .env("XDG_RUNTIME_DIR", runtime.path())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let start = std::time::Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if start.elapsed() > Duration::from_secs(120) {
            let _ = child.kill();
            panic!("the viewer still runs after 120 s: it waits for a frame that cannot come");
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    let mut err = String::new();
    std::io::Read::read_to_string(child.stderr.as_mut().unwrap(), &mut err).unwrap();
    assert_eq!(status.code(), Some(1), "{err}");
    assert!(err.contains("needs medium"), "the error names the cause: {err}");
    assert!(!shot.exists());
}

/// The points node's controls: colour by another array, switch to splats (the opacity
/// slider appears only then), save; the saved scene renders as the viewer drew it; back to
/// spheres, the opacity goes (spheres refuse it).
#[test]
fn points_coloured_by_another_array_as_splats_are_rendered_and_saved() {
    if !gpu_available() {
        return;
    }
    let dir = samples();
    let mut h = settled_on(&dir.path().join("plume_points.toml"));
    assert!(h.query_by_label("Opacity").is_none(), "no opacity for spheres");
    h.get_by_label("Colour by").click();
    h.run_steps(2);
    click_in_panel(&mut h, "density");
    let n = &h.state().scene().unwrap().nodes()[0];
    assert_eq!(n.color_by.as_deref(), Some("density"));
    assert_eq!(h.state().current_full_frame().unwrap().scales[0].title, "density", "the scalar bar follows");
    h.get_by_label("Style").click();
    h.run_steps(2);
    click_in_panel(&mut h, "splats");
    set_in_panel(&mut h, egui::accesskit::Role::Slider, "Opacity", 0.6);
    settle(&mut h);
    let splats = h.state().current_full_frame().unwrap().clone();
    assert!(splats.rgba.iter().any(|p| p[3] > 0.0 && p[3] < 0.5), "translucent edges");
    let out = tempfile::tempdir().unwrap();
    let scene_path = out.path().join("splats.toml");
    save_through_toolbar(&mut h, &scene_path);
    let text = std::fs::read_to_string(&scene_path).unwrap();
    assert!(text.contains("style = \"splats\"") && text.contains("opacity = 0.6") && text.contains("color_by = \"density\""), "{text}");
    let b = render_with_cli(&scene_path, out.path());
    let a = b.channel("A").unwrap();
    assert_eq!(a.len(), splats.rgba.len());
    let diff = splats.rgba.iter().zip(a).map(|(p, q)| (p[3] - q).abs()).fold(0.0f32, f32::max);
    assert_eq!(diff, 0.0, "the CLI render of the saved scene equals the viewer's frame");
    h.get_by_label("Style").click();
    h.run_steps(2);
    click_in_panel(&mut h, "spheres");
    assert!(!h.state().scene().unwrap().nodes()[0].settings.contains_key("opacity"));
}

/// A time series opened as a file (a ParaView collection): framed by its first step; the
/// toolbar's time slider draws another step (its particles, read when drawn), ">" steps
/// on, and Play runs through the steps by itself, from the last back to the first.
#[test]
fn a_time_series_steps_and_plays_in_the_viewer() {
    if !gpu_available() {
        return;
    }
    let dir = samples();
    let pvd = dir.path().join("plume_series").join("plume.pvd");
    let mut h = settled_on(&pvd);
    let scene = h.state().scene().unwrap();
    let times = scene.timeline();
    assert_eq!(times.len(), 8);
    assert_eq!(scene.nodes()[0].renderer.as_deref(), Some("points"));
    let first = scene.particles(0).unwrap().len();
    let covered = |h: &Harness<'_, Viewer>| h.state().current_full_frame().unwrap().rgba.iter().filter(|p| p[3] > 0.0).count();
    let covered_first = covered(&h);
    set_in_panel(&mut h, egui::accesskit::Role::Slider, "Time", 5.0);
    settle(&mut h);
    let scene = h.state().scene().unwrap();
    assert_eq!(scene.time(), Some(times[5]));
    let later = scene.particles(0).unwrap().len();
    assert!(later > first, "the plume grows over time: {first} → {later} particles");
    assert!(covered(&h) > covered_first, "and covers more of the view");
    h.get_by_label(">").click();
    h.run_steps(2);
    settle(&mut h);
    assert_eq!(h.state().scene().unwrap().time(), Some(times[6]));
    // Play: each full frame brings the next step, past the last back to the first.
    h.get_by_label("Play").click();
    let mut seen = std::collections::BTreeSet::new();
    for _ in 0..400 {
        h.run_steps(1);
        h.state().wait_for_renders(Duration::from_secs(30));
        std::thread::sleep(Duration::from_millis(20));
        seen.insert(h.state().scene().unwrap().time().map(|t| t.to_bits()));
        if seen.len() >= 4 && seen.contains(&Some(times[0].to_bits())) {
            break;
        }
    }
    assert!(
        seen.contains(&Some(times[7].to_bits())) && seen.contains(&Some(times[0].to_bits())),
        "played through the end and round: {seen:?}"
    );
    h.get_by_label("Pause").click();
    h.run_steps(2);
    settle(&mut h);
}

/// CT window/level presets in the slice views, named and valued as PACS viewers set them;
/// they change the slice pictures; a volume that is not CT gets them disabled.
#[test]
fn ct_window_presets_set_the_slice_views() {
    let dir = tempfile::tempdir().unwrap();
    volterra_formats::nifti::write_nifti(&dir.path().join("ct.nii"), &volterra::samples::ct_phantom(48, 48, 24)).unwrap();
    let scene = |modality: &str| {
        format!(
            "[image]\nwidth = 64\nheight = 64\n[camera]\nposition = [0.0, -200.0, 0.0]\nfocal_point = [0.0, 0.0, 0.0]\n\
             [[node]]\nname = \"ct\"\nkind = \"volume\"\nfile = \"ct.nii\"\nrenderer = \"shear-warp\"\n{modality}"
        )
    };
    std::fs::write(dir.path().join("ct.toml"), scene("modality = \"CT\"\npreset = \"CT-Bone\"\n")).unwrap();
    let mut h = settled_on(&dir.path().join("ct.toml"));
    h.get_by_label("W/L preset").click();
    h.run_steps(2);
    h.get_by_label("Lung (W 1500 / L -600)").click();
    h.run_steps(3);
    assert_eq!(h.state().window_level(), Some((1500.0, -600.0)));
    h.get_by_label("W/L preset").click();
    h.run_steps(2);
    h.get_by_label("Brain (W 80 / L 40)").click();
    h.run_steps(3);
    assert_eq!(h.state().window_level(), Some((80.0, 40.0)));
    // Without a CT modality (the NIfTI does not say), the presets are disabled.
    std::fs::write(dir.path().join("plain.toml"), scene("preset = \"CT-Bone\"\n")).unwrap();
    let h = settled_on(&dir.path().join("plain.toml"));
    use egui_kittest::kittest::NodeT;
    assert!(h.get_by_label("W/L preset").accesskit_node().is_disabled());
}

/// A DICOM folder with two series opens the series browser (patient, study, series,
/// modality, size, images) instead of an error; a row chosen opens that series (a
/// double-click does the same).
#[test]
fn a_folder_of_several_series_opens_the_series_browser() {
    let mut h = harness(Viewer::new(LoadOptions::default()));
    h.run_steps(1);
    h.state_mut().open_in_background(common::repo_path("tests/fixtures/dicom/two_series"));
    wait_loaded(&mut h);
    h.run_steps(2);
    assert!(h.state().scene().is_none(), "nothing opened yet");
    let listed: Vec<String> =
        h.state().series_to_choose().expect("the browser lists the series").iter().map(|s| s.description.clone()).collect();
    assert_eq!(listed, ["fixture .301", "fixture .302"]);
    // The table shows what each series is; a click selects the second, "Open series" opens it.
    assert_eq!(h.get_all_by_label("3").count(), 2, "three images in each row");
    assert_eq!(h.get_all_by_label("CT").count(), 2);
    h.get_by_label("fixture .302").click();
    h.run_steps(1);
    h.get_by_label("Open series").click();
    h.run_steps(1);
    wait_loaded(&mut h);
    h.run_steps(1);
    assert!(h.state().series_to_choose().is_none(), "the browser closes");
    let scene = h.state().scene().expect("the series opened");
    let v = scene.volume(0).unwrap();
    assert!(v.attributes.iter().any(|(k, val)| k == "series" && val == "fixture .302"), "{:?}", v.attributes);
    assert_eq!(v.dims[2], 3);
}

/// A CT (`ct.nii`) and a hot ball (value 10 inside radius
/// 8 mm, 0 outside; 16³ voxels of 3 mm about the CT's centre: `pet.nii`), and the scene
/// `fused.toml` showing both (CT-Bone and PET-Hot presets) with `extra` appended. The CT.
fn write_pet_ct_pair(dir: &Path, ct: volterra_formats::Volume, extra: &str) -> volterra_formats::Volume {
    volterra_formats::nifti::write_nifti(&dir.join("ct.nii"), &ct).unwrap();
    let [nx, ny, nz] = ct.dims;
    let centre = ct.index_to_world([0.5 * (nx - 1) as f64, 0.5 * (ny - 1) as f64, 0.5 * (nz - 1) as f64]);
    let n = 16;
    let spacing = 3.0;
    let mut data = Vec::new();
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                let p = [i, j, k].map(|x| (x as f64 - 7.5) * spacing);
                let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                data.push(if r < 8.0 { 10.0f32 } else { 0.0 });
            }
        }
    }
    let affine = [
        [spacing, 0.0, 0.0, centre[0] - 7.5 * spacing],
        [0.0, spacing, 0.0, centre[1] - 7.5 * spacing],
        [0.0, 0.0, spacing, centre[2] - 7.5 * spacing],
        [0.0, 0.0, 0.0, 1.0],
    ];
    let pet = volterra_formats::Volume::new([n, n, n], affine, volterra_formats::VoxelData::F32(data));
    volterra_formats::nifti::write_nifti(&dir.join("pet.nii"), &pet).unwrap();
    std::fs::write(
        dir.join("fused.toml"),
        format!(
            "[image]\nwidth = 48\nheight = 48\n[camera]\nposition = [0.0, -300.0, 0.0]\nfocal_point = [0.0, 0.0, 0.0]\n\
             [[node]]\nname = \"ct\"\nkind = \"volume\"\nfile = \"ct.nii\"\nmodality = \"CT\"\npreset = \"CT-Bone\"\n\
             [[node]]\nname = \"pet\"\nkind = \"volume\"\nfile = \"pet.nii\"\npreset = \"PET-Hot\"\n{extra}"
        ),
    )
    .unwrap();
    ct
}

/// PET over CT in the slice views: a second volume chosen as the overlay is drawn through
/// the hot colour map over the CT's grey where its values are above the overlay window's
/// bottom; elsewhere the slices stay grey; opacity 0 shows the grey alone.
#[test]
fn a_pet_overlay_is_fused_over_the_ct_slices() {
    let dir = tempfile::tempdir().unwrap();
    let ct = write_pet_ct_pair(dir.path(), volterra::samples::ct_phantom(48, 48, 24), "");
    let mut h = settled_on(&dir.path().join("fused.toml"));
    let coloured = |h: &Harness<'_, Viewer>| {
        let (_, _, px) = h.state().slice_colours(0).unwrap();
        px.iter().filter(|p| p[0] as i32 - p[2] as i32 > 40).count()
    };
    assert_eq!(coloured(&h), 0, "grey slices before the overlay");
    h.get_by_label("Overlay").click();
    h.run_steps(2);
    h.get_by_label("pet").click();
    h.run_steps(3);
    let (w, hh, px) = h.state().slice_colours(0).unwrap();
    let hot = coloured(&h);
    // The ball's axial cross-section through its centre: π 8² mm² over the slice's pixels.
    let pixel_mm = (ct.spacing[0] * 47.0) / (w as f64 - 1.0);
    let expected = std::f64::consts::PI * 64.0 / (pixel_mm * pixel_mm);
    assert!((hot as f64) > 0.4 * expected && (hot as f64) < 1.6 * expected, "{hot} hot pixels, about {expected:.0} expected ({w}×{hh})");
    let greys = px.iter().filter(|p| p[0] == p[1] && p[1] == p[2]).count();
    assert!(greys > px.len() / 2, "the rest stays grey: {greys} of {}", px.len());
    // Saved with the scene ([slices]) and reopened as it was: the same fused slices.
    let saved = dir.path().join("fused_saved.toml");
    h.state().save_scene(&saved).unwrap();
    let text = std::fs::read_to_string(&saved).unwrap();
    assert!(text.contains("[slices.overlay]") && text.contains("colormap = \"hot\""), "{text}");
    let reopened = settled_on(&saved);
    assert_eq!(reopened.state().window_level(), h.state().window_level());
    assert_eq!(reopened.state().slice_colours(0).unwrap().2, px, "the reopened slices are the saved ones");
    set_in_panel(&mut h, egui::accesskit::Role::Slider, "Overlay opacity", 0.0);
    h.run_steps(3);
    assert_eq!(coloured(&h), 0, "opacity 0: the grey alone");
}

/// A fused PET/CT with measurements in a real window under Xvfb: the two volumes drawn
/// fused in the 3-D view (the PET's hot colours), a distance between surface points over it
/// and an elliptical ROI on the axial slice, both from the scene's `[[measurement]]`s (the
/// orange of the measuring tools). The screenshot is kept as
/// `target/test-pictures/fused_pet_ct_window.png`.
#[test]
fn a_fused_pet_ct_with_measurements_in_a_real_window() {
    let Some(xvfb) = xvfb_run() else { return };
    let dir = tempfile::tempdir().unwrap();
    let measurements = "[[measurement]]\nkind = \"distance\"\nnode = \"ct\"\npoints = [[-30.0, 0.0, -10.0], [30.0, 0.0, 10.0]]\n\
                        [[measurement]]\nkind = \"ellipse\"\nnode = \"ct\"\nplane = \"axial\"\npoints = [[-12.0, -9.0, 0.0], [12.0, 9.0, 0.0]]\n";
    // The whole body at a PET/CT's CT resolution for speed: the phantom at 0.7 mm, every
    // fourth voxel across (2.8 mm), 1 mm slices.
    let fine = volterra::samples::ct_phantom(448, 384, 40);
    let (nx, ny, nz) = (112, 96, 40);
    let mut data = Vec::with_capacity(nx * ny * nz);
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                data.push(fine.data.stored(4 * i + 1 + 448 * (4 * j + 1 + 384 * k)) as i16);
            }
        }
    }
    let mut affine = fine.affine;
    (affine[0][0], affine[0][3]) = (2.8, -0.5 * (nx - 1) as f64 * 2.8);
    (affine[1][1], affine[1][3]) = (2.8, -0.5 * (ny - 1) as f64 * 2.8);
    let ct = volterra_formats::Volume {
        rescale: fine.rescale,
        modality: fine.modality.clone(),
        ..volterra_formats::Volume::new([nx, ny, nz], affine, volterra_formats::VoxelData::I16(data))
    };
    write_pet_ct_pair(dir.path(), ct, measurements);
    // From the front, right and above; the CT faded so that the PET inside shows.
    let text = std::fs::read_to_string(dir.path().join("fused.toml"))
        .unwrap()
        .replace("position = [0.0, -300.0, 0.0]", "position = [260.0, 420.0, 200.0]")
        .replace("preset = \"CT-Bone\"\n", "preset = \"CT-Bone\"\nopacity_scale = 0.1\n");
    std::fs::write(dir.path().join("fused.toml"), text).unwrap();
    let shot = screenshot_under_xvfb(xvfb, &dir.path().join("fused.toml"));
    let keep = common::repo_path("target/test-pictures");
    std::fs::create_dir_all(&keep).unwrap();
    std::fs::copy(&shot, keep.join("fused_pet_ct_window.png")).unwrap();
    let img = volterra::formats::image::decode_png(&shot, &Default::default(), 0).unwrap();
    let px: Vec<[u8; 4]> = img.samples.chunks_exact(4).map(|p| [p[0] as u8, p[1] as u8, p[2] as u8, p[3] as u8]).collect();
    // The measuring tools' orange (255, 120, 40): lines, end points and labels.
    let orange = px.iter().filter(|p| p[0] > 230 && (90..150).contains(&p[1]) && p[2] < 80).count();
    assert!(orange > 400, "measurement-orange pixels: {orange}");
    // The PET ball through PET-Hot: orange to yellow (the tools' orange has less green).
    let hot = px.iter().filter(|p| p[0] > 200 && p[1] > 150 && p[2] < 120).count();
    // Measured: about 950 orange and 1200 PET-hot pixels; with the CT not faded the ball
    // is hidden and there are none.
    eprintln!("orange {orange}, PET-hot {hot} pixels");
    assert!(hot > 600, "PET-hot pixels: {hot}");
}

/// Clicks at `p` (press and release, hovering first).
fn click_at(h: &mut Harness<'_, Viewer>, p: egui::Pos2) {
    h.hover_at(p);
    h.run_steps(1);
    for pressed in [true, false] {
        h.event(egui::Event::PointerButton { pos: p, button: egui::PointerButton::Primary, pressed, modifiers: egui::Modifiers::NONE });
        h.run_steps(1);
    }
}

/// Chooses `tool` in the toolbar's "Measuring tool" menu.
fn choose_slice_tool(h: &mut Harness<'_, Viewer>, tool: &str) {
    h.get_by_label("Measuring tool").click();
    h.run_steps(2);
    h.get_by_label(tool).click();
    h.run_steps(2);
}

/// Measurements in the slice views, in world millimetres: a distance (two clicks), an angle
/// (three) and an elliptical ROI (two corners) on the axial slice. Each is checked against
/// the world points under the clicks and, independently, against the click offsets times
/// the slice's millimetres per screen point; the ROI over a volume whose value is the world
/// x coordinate has that ramp's moments (mean at its centre, SD a/2). The cross-hair stays;
/// the measurements are saved with the scene, reopen with it, and the CLI still renders it.
#[test]
fn distances_angles_and_rois_are_measured_on_a_slice_and_saved() {
    let dir = tempfile::tempdir().unwrap();
    // 48×48×24 voxels of 0.8×0.8×2 mm, value = world x (mm).
    let (d, sp) = ([48usize, 48, 24], [0.8, 0.8, 2.0]);
    let origin = [-18.8, -18.8, -23.0];
    let data = (0..d[0] * d[1] * d[2]).map(|i| (origin[0] + sp[0] * (i % d[0]) as f64) as f32).collect();
    let affine = [[sp[0], 0.0, 0.0, origin[0]], [0.0, sp[1], 0.0, origin[1]], [0.0, 0.0, sp[2], origin[2]], [0.0, 0.0, 0.0, 1.0]];
    let ramp = volterra_formats::Volume::new(d, affine, volterra_formats::VoxelData::F32(data));
    volterra_formats::nifti::write_nifti(&dir.path().join("ramp.nii"), &ramp).unwrap();
    std::fs::write(
        dir.path().join("ramp.toml"),
        "[image]\nwidth = 48\nheight = 48\n[camera]\nposition = [0.0, -300.0, 0.0]\nfocal_point = [0.0, 0.0, 0.0]\n\
         [[node]]\nname = \"ramp\"\nkind = \"volume\"\nfile = \"ramp.nii\"\nmodality = \"CT\"\npreset = \"CT-Bone\"\n",
    )
    .unwrap();
    let mut h = settled_on(&dir.path().join("ramp.toml"));
    let cross = h.state().slice_cross().unwrap();
    // Where the axial view lies (the panel may scroll or narrow as controls appear), a point
    // at a fraction of it, and millimetres per screen point: an axial slice spans its voxel
    // centres (47 spacings) plus one slice pixel (the finest spacing) across the view, and
    // likewise in height.
    let view = |h: &Harness<'_, Viewer>| h.state().slice_point(0, egui::Pos2::ZERO).unwrap().0;
    let at = |r: egui::Rect, fx: f32, fy: f32| r.left_top() + egui::vec2(fx, fy) * r.size();
    let mm = |r: egui::Rect, a: egui::Pos2, b: egui::Pos2| {
        let (mx, my) = ((47.0 * sp[0] + 0.8) / r.width() as f64, (47.0 * sp[1] + 0.8) / r.height() as f64);
        glam::DVec2::new((b.x - a.x) as f64 * mx, (b.y - a.y) as f64 * my)
    };

    choose_slice_tool(&mut h, "Distance");
    let r = view(&h);
    let (pa, pb) = (at(r, 0.2, 0.3), at(r, 0.7, 0.6));
    let (a, b) = (h.state().slice_point(0, pa).unwrap().1, h.state().slice_point(0, pb).unwrap().1);
    click_at(&mut h, pa);
    click_at(&mut h, pb);
    let dist = h.state().measured_mm().expect("both ends placed");
    assert!((dist - (b - a).length()).abs() < 1e-6, "{dist} vs {}", (b - a).length());
    let expected = mm(r, pa, pb).length();
    assert!((dist - expected).abs() < 0.02 * expected, "{dist} mm, about {expected} mm from the pixel sizes");

    choose_slice_tool(&mut h, "Angle");
    let r = view(&h);
    let (p0, vertex, p2) = (at(r, 0.25, 0.25), at(r, 0.5, 0.6), at(r, 0.8, 0.35));
    for p in [p0, vertex, p2] {
        click_at(&mut h, p);
    }
    let (angle, _) = h.state().measurements().last().cloned().unwrap();
    assert_eq!(angle.kind, volterra::scene::MeasurementKind::Angle);
    let expected = mm(r, vertex, p0).angle_to(mm(r, vertex, p2)).abs().to_degrees();
    assert!((angle.value() - expected).abs() < 0.5, "{}° vs {expected}° from the pixel sizes", angle.value());

    choose_slice_tool(&mut h, "Ellipse ROI");
    let r = view(&h);
    let (c0, c1) = (at(r, 0.3, 0.35), at(r, 0.7, 0.55));
    click_at(&mut h, c0);
    click_at(&mut h, c1);
    let (roi, stats) = h.state().measurements().last().cloned().unwrap();
    let stats = stats.expect("the ellipse lies in the volume");
    let half = mm(r, c0, c1).abs() * 0.5;
    let area = std::f64::consts::PI * half.x * half.y;
    assert!((stats.area_mm2 - area).abs() < 0.04 * area, "area {} mm², about {area} from the pixel sizes", stats.area_mm2);
    // Values = x: the mean is x at the ellipse's centre, SD = a/2 of its x semi-axis.
    let centre_x = 0.5 * (roi.points[0][0] + roi.points[1][0]);
    let ax = 0.5 * (roi.points[1][0] - roi.points[0][0]).abs();
    assert!((stats.mean - centre_x).abs() < 0.05, "mean {} vs x at the centre {centre_x}", stats.mean);
    assert!((stats.sd - 0.5 * ax).abs() < 0.03 * ax, "SD {} vs a/2 = {}", stats.sd, 0.5 * ax);
    assert!((stats.min - (centre_x - ax)).abs() < 0.9 && (stats.max - (centre_x + ax)).abs() < 0.9, "{stats:?} for a = {ax}");
    assert_eq!(h.state().slice_cross().unwrap(), cross, "measuring leaves the cross-hair");

    // Saved with the scene and reopened with it; the CLI renders the saved scene.
    let saved = dir.path().join("measured.toml");
    h.state().save_scene(&saved).unwrap();
    let text = std::fs::read_to_string(&saved).unwrap();
    assert_eq!(text.matches("[[measurement]]").count(), 3, "{text}");
    let taken: Vec<_> = h.state().measurements().to_vec();
    let h2 = settled_on(&saved);
    assert_eq!(h2.state().measurements(), taken.as_slice());
    render_with_cli(&saved, dir.path());
}

/// On the 3-D view: with the distance tool, two clicks on an opaque cube's front face place
/// a measurement between surface points (from the full frame's depth): both lie on the face,
/// and their distance is the click offset times the parallel view's millimetres per point.
/// The orientation marker follows the camera (a view from the front: R to the screen's
/// right, S up, A into the screen) and the scale bar's length over its points is the view's
/// millimetres per point; "Axes and scale" hides both.
#[test]
fn distances_on_the_3d_surface_and_the_orientation_marker_and_scale_bar() {
    let dir = tempfile::tempdir().unwrap();
    // 32³ voxels of 1 mm centred on the origin; value 100 in the central 20³ block.
    let n = 32;
    let data = (0..n * n * n)
        .map(|i| {
            let (x, y, z) = (i % n, (i / n) % n, i / (n * n));
            if [x, y, z].iter().all(|&c| (6..26).contains(&c)) {
                100.0f32
            } else {
                0.0
            }
        })
        .collect();
    let affine = [[1.0, 0.0, 0.0, -15.5], [0.0, 1.0, 0.0, -15.5], [0.0, 0.0, 1.0, -15.5], [0.0, 0.0, 0.0, 1.0]];
    let cube = volterra_formats::Volume::new([n, n, n], affine, volterra_formats::VoxelData::F32(data));
    volterra_formats::nifti::write_nifti(&dir.path().join("cube.nii"), &cube).unwrap();
    std::fs::write(
        dir.path().join("cube.toml"),
        "[image]\nwidth = 64\nheight = 64\n[camera]\nposition = [0.0, -200.0, 0.0]\nfocal_point = [0.0, 0.0, 0.0]\n\
         parallel_projection = true\nparallel_scale = 30.0\n\
         [[node]]\nname = \"cube\"\nkind = \"volume\"\nfile = \"cube.nii\"\nrenderer = \"reference\"\n\
         [node.transfer_function]\nscalar_opacity = [[0.0, 0.0], [40.0, 0.0], [60.0, 1.0], [100.0, 1.0]]\n",
    )
    .unwrap();
    let mut h = settled_on(&dir.path().join("cube.toml"));
    let rect = h.state().viewport_rect().unwrap();
    let mpp = 60.0 / rect.height() as f64;

    // The marker and the bar.
    let (axes, (bar_mm, bar_points)) = h.state().view_marks().expect("shown by default");
    let close = |v: egui::Vec2, x: f32, y: f32| (v - egui::vec2(x, y)).length() < 1e-6;
    assert!(close(axes[0], 1.0, 0.0) && close(axes[1], 0.0, 0.0) && close(axes[2], 0.0, -1.0), "{axes:?}");
    assert!((bar_mm / bar_points as f64 - mpp).abs() < 1e-6 * mpp, "{bar_mm} mm over {bar_points} points, {mpp} mm a point");

    // Two surface points on the cube's front face (y = 6 − 15.5 − 0.5 = −10 at the voxels'
    // edge; the surface, where opacity passes 0.5, lies within a voxel of it).
    choose_slice_tool(&mut h, "Distance");
    let rect = h.state().viewport_rect().unwrap();
    let (pa, pb) = (rect.center() + egui::vec2(-0.12, -0.1) * rect.height(), rect.center() + egui::vec2(0.1, 0.12) * rect.height());
    click_at(&mut h, pa);
    click_at(&mut h, pb);
    let (m, _) = h.state().measurements().last().cloned().expect("a surface distance");
    assert_eq!(m.plane, None);
    for p in &m.points {
        assert!((p[1] + 10.0).abs() < 1.0, "{p:?} lies on the front face");
    }
    let mpp = 60.0 / rect.height() as f64;
    let expected = ((pb.x - pa.x) as f64 * mpp).hypot((pb.y - pa.y) as f64 * mpp);
    let across = glam::DVec3::from(m.points[1]) - glam::DVec3::from(m.points[0]);
    let in_face = across.x.hypot(across.z);
    assert!((in_face - expected).abs() < 0.02 * expected + 0.1, "{in_face} mm across the face, {expected} from the clicks");
    assert_eq!(m.value(), across.length());

    // (The toolbar gained "Clear measurements" with the measurement: let it settle first.)
    h.run_steps(3);
    h.get_by_label("Axes and scale").click();
    h.run_steps(3);
    assert!(h.state().view_marks().is_none());
}
