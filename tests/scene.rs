//! Scene files, overrides, lazy loading, and the reference volume ray caster against
//! closed-form answers.

mod common;

use common::repo_path;
use std::path::Path;
use volterra::catalog;
use volterra::render::{self, reference_volume};
use volterra::scene::{BlendMode, Camera, NodeData, Scene, TransferFunction};
use volterra_formats::{Volume, VoxelData};

fn write(dir: &Path, name: &str, text: &str) -> std::path::PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

#[test]
fn committed_sample_scenes_are_what_samples_writes_and_all_load() {
    for (name, text) in volterra::samples::SCENES {
        let committed = std::fs::read_to_string(repo_path("samples").join(name)).unwrap();
        assert_eq!(&committed, text, "{name}");
    }
    let dir = tempfile::tempdir().unwrap();
    volterra::samples::write_samples(dir.path()).unwrap();
    for (name, _) in volterra::samples::SCENES {
        let scene = Scene::load(&dir.path().join(name), &[]).unwrap_or_else(|e| panic!("{name}: {e:#}"));
        for i in 0..scene.nodes().len() {
            assert!(!scene.is_loaded(i), "{name}: data must not be read before it is needed");
            scene.data(i).unwrap_or_else(|e| panic!("{name}: {e:#}"));
        }
    }
}

#[test]
fn samples_are_deterministic() {
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    volterra::samples::write_samples(a.path()).unwrap();
    volterra::samples::write_samples(b.path()).unwrap();
    let files = |d: &Path| -> Vec<std::path::PathBuf> {
        let mut out = vec![];
        for e in std::fs::read_dir(d).unwrap() {
            let p = e.unwrap().path();
            let sub: Vec<_> = if p.is_dir() { std::fs::read_dir(&p).unwrap().map(|e| e.unwrap().path()).collect() } else { vec![p] };
            out.extend(sub.into_iter().map(|p| p.strip_prefix(d).unwrap().to_path_buf()));
        }
        out
    };
    let names = files(a.path());
    assert!(names.iter().any(|n| n.ends_with("plume_series/plume.pvd")), "{names:?}");
    for name in names {
        assert_eq!(std::fs::read(a.path().join(&name)).unwrap(), std::fs::read(b.path().join(&name)).unwrap(), "{name:?}");
    }
}

const CUBE_SCENE: &str = r#"
[image]
width = 8
height = 6

[camera]
position = [0.0, 0.0, 100.0]
focal_point = [0.0, 0.0, 0.0]
view_up = [0.0, 1.0, 0.0]
parallel_projection = true
parallel_scale = 10.0

[[node]]
name = "vol"
kind = "volume"
file = "v.nii"
renderer = "reference"
settings = { step = 0.05 }

[node.transfer_function]
scalar_opacity = [[0.0, 0.2]]
"#;

#[test]
fn unknown_keys_and_missing_files_are_one_line_errors_with_place() {
    let dir = tempfile::tempdir().unwrap();
    let vol = volterra::samples::angio_phantom(8);
    volterra_formats::nifti::write_nifti(&dir.path().join("v.nii"), &vol).unwrap();
    let bad = write(dir.path(), "bad.toml", &CUBE_SCENE.replace("parallel_scale = 10.0", "parallel_scale = 10.0\nzoom = 2"));
    let e = format!("{:#}", Scene::load(&bad, &[]).err().unwrap());
    assert!(
        e.contains("bad.toml")
            && e.contains("line 12")
            && e.contains("unknown key `zoom`")
            && e.contains("known keys: position, focal_point"),
        "{e}"
    );
    assert_eq!(e.lines().count(), 1, "{e}");
    let missing = write(dir.path(), "missing.toml", &CUBE_SCENE.replace("v.nii", "nothere.nii"));
    let e = format!("{:#}", Scene::load(&missing, &[]).err().unwrap());
    assert!(e.contains(&dir.path().join("nothere.nii").display().to_string()) && e.contains("not found"), "{e}");
}

/// The memory limits are a value each scene hands its readers and preparations (not a
/// setting of the whole process): two scenes in one process, each held to its own.
#[test]
fn each_scene_reads_and_renders_within_its_own_limits() {
    use volterra_formats::Limits;
    let dir = tempfile::tempdir().unwrap();
    let vol = volterra::samples::angio_phantom(8); // 8³ one-byte voxels
    volterra_formats::nifti::write_nifti(&dir.path().join("v.nii"), &vol).unwrap();
    let p = write(dir.path(), "s.toml", CUBE_SCENE);
    // Too little for the volume: the reader refuses it, naming the file and both sizes.
    let tight = Scene::load(&p, &[]).unwrap().with_limits(Limits::max(100));
    let Err(e) = tight.data(0) else { panic!("a 512-byte volume read within 100 bytes") };
    let e = format!("{e:#}");
    assert!(e.contains("v.nii") && e.contains("volume needs 512 B but the memory limit is 100 B"), "{e}");
    // Enough for the volume (and its preparation), not for the frames of a 512² image.
    let big = ["image.width=512".to_string(), "image.height=512".to_string()];
    let mid = Scene::load(&p, &big).unwrap().with_limits(Limits::max(100_000));
    mid.data(0).expect("the volume fits");
    let Err(e) = render::render_scene(&mid, None) else { panic!("512² frames within 100 kB") };
    let e = format!("{e:#}");
    assert!(e.contains("the frames needs 10.0 MiB but the memory limit is 97.7 KiB"), "{e}");
    // An edited scene keeps its limits; a scene without limits, in the same process, renders.
    let edited = mid.edited(mid.file.clone()).unwrap();
    assert_eq!(edited.limits(), &Limits::max(100_000));
    render::render_scene(&Scene::load(&p, &big).unwrap(), None).expect("no limit set: the machine's memory");
}

#[test]
fn renderer_settings_are_checked_at_load_with_their_line_before_any_data_is_read() {
    let dir = tempfile::tempdir().unwrap();
    // 200 MB of bytes that are no NIfTI: reading it would fail (and take time), so an
    // error about settings proves the file was never opened.
    let data = dir.path().join("v.nii");
    std::fs::File::create(&data).unwrap().set_len(200 << 20).unwrap();
    let cases: &[(&str, &str, &str)] = &[
        (
            "settings = { step = 0.05 }",
            "settings = { stp = 0.05 }",
            "line 18: node 'vol': reference setting 'stp': unknown (known: step, termination)",
        ),
        (
            "settings = { step = 0.05 }",
            "settings = { step = \"fine\" }",
            "line 18: node 'vol': reference setting 'step': expected number, found string",
        ),
        (
            "settings = { step = 0.05 }",
            "settings = { step = 2.0 }",
            "line 18: node 'vol': reference setting 'step': 2 is out of range: must be (0, 1]",
        ),
        (
            "renderer = \"reference\"\nsettings = { step = 0.05 }",
            "renderer = \"shear-warp\"\nsettings = { leaping = \"fast\" }",
            "line 18: node 'vol': shear-warp setting 'leaping': \"fast\" is not one of \"overlapped\" | \"multi-scanline\" | \"none\"",
        ),
        (
            "renderer = \"reference\"\nsettings = { step = 0.05 }",
            "renderer = \"shear-warp\"\nsettings = { block = -1 }",
            "block': -1 is out of range: must be [1, 256]",
        ),
        (
            "renderer = \"reference\"\nsettings = { step = 0.05 }",
            "renderer = \"sheer-warp\"",
            "line 17: node 'vol': unknown renderer 'sheer-warp' (known: shear-warp, reference,",
        ),
        (
            "renderer = \"reference\"\nsettings = { step = 0.05 }",
            "renderer = \"terrain\"",
            "line 17: node 'vol': renderer 'terrain' draws Heightfield nodes, not Volume",
        ),
    ];
    for (from, to, expected) in cases {
        let p = write(dir.path(), "bad.toml", &CUBE_SCENE.replace(from, to));
        let t = std::time::Instant::now();
        let e = format!("{:#}", Scene::load(&p, &[]).err().unwrap_or_else(|| panic!("{to}: loads")));
        assert!(t.elapsed().as_secs_f64() < 1.0, "{to}: {:?}", t.elapsed());
        assert!(e.contains("bad.toml") && e.contains(expected), "{to}:\n{e}\nexpected: {expected}");
        assert_eq!(e.lines().count(), 1, "{e}");
    }
    // A setting given by --set is named as such; a valid one gives typed settings.
    let p = write(dir.path(), "ok.toml", CUBE_SCENE);
    let e = format!("{:#}", Scene::load(&p, &["node.vol.settings.termination=0".into()]).err().unwrap());
    assert!(e.contains("(from --set): node 'vol': reference setting 'termination': 0 is out of range"), "{e}");
    let scene = Scene::load(&p, &["node.vol.settings.termination=0.5".into()]).unwrap();
    let expected = reference_volume::Settings { step: 0.05, termination: 0.5 };
    assert_eq!(scene.node_settings(0), Some(&catalog::NodeSettings::Reference(expected)));
    assert!(!scene.is_loaded(0));
}

#[test]
fn the_settings_tables_in_the_docs_are_the_declarations() {
    let doc = std::fs::read_to_string(repo_path("docs/scene-format.md")).unwrap();
    let begin = "<!-- BEGIN generated by `volterra renderers` -->\n";
    let end = "<!-- END generated by `volterra renderers` -->";
    let (a, b) = (doc.find(begin).expect("begin marker") + begin.len(), doc.find(end).expect("end marker"));
    let generated = catalog::markdown();
    assert!(
        doc[a..b] == generated,
        "docs/scene-format.md's renderer tables differ from the declarations; replace them with `volterra renderers`:\n{generated}"
    );
}

#[test]
fn overrides_change_values_by_path_and_by_node_name() {
    let dir = tempfile::tempdir().unwrap();
    let vol = volterra::samples::angio_phantom(8);
    volterra_formats::nifti::write_nifti(&dir.path().join("v.nii"), &vol).unwrap();
    let p = write(dir.path(), "s.toml", CUBE_SCENE);
    let s = Scene::load(
        &p,
        &[
            "image.width=32".into(),
            "node.vol.blend=mip".into(),
            "node.vol.settings.step=0.5".into(),
            "camera.view_up=[1.0, 0.0, 0.0]".into(),
        ],
    )
    .unwrap();
    assert_eq!(s.file.image.width, 32);
    assert_eq!(s.file.nodes[0].blend, BlendMode::Mip);
    assert_eq!(s.file.nodes[0].settings["step"].as_float(), Some(0.5));
    assert_eq!(s.file.camera.view_up, [1.0, 0.0, 0.0]);
    assert!(Scene::load(&p, &["node.nobody.blend=mip".into()]).is_err());
    // Renderer settings are checked at load (they were checked only at the first frame).
    let e = format!("{:#}", Scene::load(&p, &["node.vol.settings.stepp=0.5".into()]).err().unwrap());
    assert!(e.contains("stepp"), "{e}");
}

fn input<'a>(
    volume: &'a Volume,
    node_to_world: glam::DMat4,
    tf: &'a TransferFunction,
    blend: BlendMode,
) -> reference_volume::VolumeInput<'a> {
    reference_volume::VolumeInput { volume, node_to_world, tf, blend, shading: None, lights: &[], crop: &[] }
}

fn constant_volume(n: usize, spacing: f64, value: u8) -> Volume {
    Volume::centred([n, n, n], [spacing; 3], VoxelData::U8(vec![value; n * n * n]))
}

/// A homogeneous cube seen face-on: opacity 1 − (1 − α)^(L / unit), colour = TF colour ·
/// opacity, depth where opacity passes 0.5 — all in closed form.
#[test]
fn reference_caster_matches_closed_form_through_a_homogeneous_cube() {
    let n = 11;
    let spacing = 2.0; // the cube spans 20 mm between first and last voxel centres
    let vol = constant_volume(n, spacing, 100);
    let alpha = 0.1;
    let unit = 1.5;
    let tf = TransferFunction {
        scalar_opacity: vec![[0.0, alpha]],
        color: vec![[0.0, 0.2, 0.6, 1.0]],
        scalar_opacity_unit_distance: unit,
        gradient_opacity: Vec::new(),
    };
    let cam = Camera {
        position: [0.0, 0.0, 100.0],
        focal_point: [0.0; 3],
        view_up: [0.0, 1.0, 0.0],
        view_angle: 30.0,
        parallel_projection: true,
        parallel_scale: 15.0,
    };
    let (w, h) = (9, 9);
    let rays = cam.rays(w, h);
    let f = reference_volume::render(&input(&vol, glam::DMat4::IDENTITY, &tf, BlendMode::Composite), &rays, &Default::default()).unwrap();
    let length = 20.0;
    let want_a = 1.0 - (1.0 - alpha).powf(length / unit);
    let centre = f.rgba[4 * w + 4];
    assert!((centre[3] as f64 - want_a).abs() < 1e-5, "alpha {} vs {want_a}", centre[3]);
    assert!((centre[2] as f64 - want_a).abs() < 1e-5 && (centre[0] as f64 - 0.2 * want_a).abs() < 1e-5);
    // Depth: the entry face is at z = +10, 90 from the eye; opacity 0.5 after d with
    // 1 − (1 − α)^(d/unit) = 0.5.
    let d = unit * 0.5f64.ln() / (1.0 - alpha).ln();
    assert!((f.depth[4 * w + 4] as f64 - (90.0 + d)).abs() < 0.05 * spacing, "depth {} vs {}", f.depth[4 * w + 4], 90.0 + d);
    // Corners miss the cube (it spans ±10 of ±15).
    assert_eq!(f.rgba[0], [0.0; 4]);
    assert!(f.depth[0].is_infinite());
    // MIP of a constant volume: the TF at that value.
    let f = reference_volume::render(&input(&vol, glam::DMat4::IDENTITY, &tf, BlendMode::Mip), &rays, &Default::default()).unwrap();
    assert!((f.rgba[4 * w + 4][3] as f64 - alpha).abs() < 1e-6);
}

/// A node transform moves the volume: translate the cube sideways out of view.
#[test]
fn node_transform_moves_the_volume() {
    let vol = constant_volume(5, 1.0, 10);
    let tf = TransferFunction {
        scalar_opacity: vec![[0.0, 0.5]],
        color: vec![[0.0, 1.0, 1.0, 1.0]],
        scalar_opacity_unit_distance: 1.0,
        gradient_opacity: Vec::new(),
    };
    let cam = Camera {
        position: [0.0, 0.0, 50.0],
        focal_point: [0.0; 3],
        view_up: [0.0, 1.0, 0.0],
        view_angle: 30.0,
        parallel_projection: true,
        parallel_scale: 4.0,
    };
    let rays = cam.rays(8, 8);
    let s = reference_volume::Settings::default();
    let hit = reference_volume::render(&input(&vol, glam::DMat4::IDENTITY, &tf, BlendMode::Composite), &rays, &s).unwrap();
    assert!(hit.rgba.iter().any(|p| p[3] > 0.0));
    let moved = glam::DMat4::from_translation(glam::DVec3::new(100.0, 0.0, 0.0));
    let miss = reference_volume::render(&input(&vol, moved, &tf, BlendMode::Composite), &rays, &s).unwrap();
    assert!(miss.rgba.iter().all(|p| p[3] == 0.0));
}

/// The stars file has no mass, h or density: a particle node gets the documented defaults.
#[test]
fn particle_nodes_get_documented_defaults_for_missing_sph_arrays() {
    let dir = tempfile::tempdir().unwrap();
    let mut set = volterra::samples::smoke_plume(500, 1);
    set.mass = None;
    set.density = None;
    set.smoothing_length = None;
    volterra_formats::vtk::write_vtp(&dir.path().join("p.vtp"), &set, &Default::default()).unwrap();
    let scene = r#"
[camera]
position = [0.5, -2.0, 0.5]
focal_point = [0.5, 0.5, 0.5]

[[node]]
name = "p"
kind = "particles"
file = "p.vtp"
"#;
    let s = Scene::load(&write(dir.path(), "s.toml", scene), &[]).unwrap();
    let p = s.particles(0).unwrap();
    let (m, h, rho) = (p.mass.as_ref().unwrap(), p.smoothing_length.as_ref().unwrap(), p.density.as_ref().unwrap());
    assert!(m.iter().all(|&x| x == 1.0 / 500.0));
    assert!(h.iter().all(|&x| x > 0.0 && x.is_finite()));
    assert!(rho.iter().all(|&x| x > 0.0 && x.is_finite()));
    assert_eq!(p.notes.iter().filter(|n| n.starts_with("no ")).count(), 3, "{:?}", p.notes);
}

/// samples/aneurysm.toml reads the real scan beside the repository.
#[test]
fn aneurysm_sample_scene_renders_the_shared_scan() {
    if common::shared_data().is_none() {
        return;
    }
    let s = Scene::load(&repo_path("samples/aneurysm.toml"), &["image.width=64".into(), "image.height=64".into()]).unwrap();
    let f = render::render_scene(&s, None).unwrap();
    assert!(f.rgba.iter().filter(|p| p[3] > 0.3).count() > 100, "the vessels are visible");
}

/// samples/smoke_plume110k.toml reads the real particle set beside the repository.
#[test]
fn smoke_sample_scene_renders_the_shared_plume() {
    if common::shared_data().is_none() {
        return;
    }
    let sets = [
        "image.width=48",
        "image.height=48",
        "node.plume.settings.photons=20000",
        "node.plume.settings.samples=1",
        "node.plume.settings.cache=false",
    ];
    let s = Scene::load(&repo_path("samples/smoke_plume110k.toml"), &sets.map(String::from)).unwrap();
    assert_eq!(s.particles(0).unwrap().len(), 110_401);
    let f = render::render_scene(&s, None).unwrap();
    assert!(f.rgba.iter().filter(|p| p[3] > 0.3).count() > 100, "the plume is visible");
    assert!(f.rgba.iter().all(|p| p.iter().all(|v| v.is_finite())));
}

/// [walk] puts the eye eye_height above the bilinear ground, and keyframed frames pass
/// through every key.
#[test]
fn walk_keeps_the_eye_above_the_ground_and_frames_pass_through_the_keyframes() {
    let dir = tempfile::tempdir().unwrap();
    volterra::samples::write_samples(dir.path()).unwrap();
    let scene = Scene::load(&dir.path().join("terrain_walk.toml"), &[]).unwrap();
    let dem = volterra::formats::geotiff::read_geotiff(&dir.path().join("fractal_dem.tif"), &Default::default()).unwrap();
    // The ground by hand: bilinear between the four samples around (x, y); rows run south.
    let ground = |x: f64, y: f64| {
        let (gx, gy) = (x / dem.cell_size[0], y / dem.cell_size[1]);
        let (i, j) = (gx.floor() as usize, gy.floor() as usize);
        let z = |c: usize, jj: usize| dem.elevations[(dem.height - 1 - jj) * dem.width + c] as f64;
        let (u, v) = (gx - i as f64, gy - j as f64);
        (1.0 - u) * (1.0 - v) * z(i, j) + u * (1.0 - v) * z(i + 1, j) + (1.0 - u) * v * z(i, j + 1) + u * v * z(i + 1, j + 1)
    };
    let cam = scene.camera(None).unwrap();
    let g = ground(cam.position[0], cam.position[1]);
    assert!((cam.position[2] - (g + 1.7)).abs() < 1e-6, "eye z {} vs ground {g} + 1.7", cam.position[2]);
    assert!((cam.focal_point[2] - (120.0 + g + 1.7)).abs() < 1e-6, "the focal point rises with the eye");
    let keys = &scene.file.keyframes;
    for (k, n) in [(0usize, 5usize), (2, 5), (4, 5)] {
        let c = scene.camera(Some((k, n))).unwrap();
        let key = &keys[k / 2];
        assert!((c.position[0] - key.position[0]).abs() < 1e-9 && (c.position[1] - key.position[1]).abs() < 1e-9, "frame {k}");
        assert!((c.position[2] - (ground(c.position[0], c.position[1]) + 1.7)).abs() < 1e-6);
    }
    // Walking off the terrain is an error naming the problem.
    let off = Scene::load(&dir.path().join("terrain_walk.toml"), &["camera.position=[-500.0, 100.0, 0.0]".into()]).unwrap();
    let e = format!("{:#}", off.camera(None).unwrap_err());
    assert!(e.contains("walk") && e.contains("not over the terrain"), "{e}");
}

/// A GeoTIFF terrain drawn by the GPU ray-caster is read row by row into its textures
/// (issue 20: a DEM held once, there, not also as a raster on the host): the scene never
/// reads the raster whole, and the frames — colour and depth, the walk's eye on the ground,
/// a drape, shadows, and a node `extent` — are those of the raster held, bit for bit. A
/// strip that fails to decode fails the render with the file's name.
#[test]
fn a_geotiff_terrain_is_read_row_by_row_into_the_gpu_and_renders_as_the_raster_held() {
    if common::gpu().is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    volterra::samples::write_samples(dir.path()).unwrap();
    let path = dir.path().join("terrain_walk.toml");
    let dem = dir.path().join("fractal_dem.tif");
    let held = volterra::formats::geotiff::read_geotiff(&dem, &Default::default()).unwrap();
    // Columns 20..=400 and rows 30..=380 of the DEM (map units are metres from its corner).
    let (ox, oy, cell) = (held.origin[0], held.origin[1], held.cell_size_native[0]);
    let extent = [ox + 20.0 * cell, oy - 380.0 * cell, ox + 400.0 * cell, oy - 30.0 * cell];
    let sizes = ["image.width=160".to_string(), "image.height=96".to_string()];
    let with_extent = format!("node.dem.extent=[{}, {}, {}, {}]", extent[0], extent[1], extent[2], extent[3]);
    for sets in [sizes.to_vec(), [sizes.to_vec(), vec![with_extent]].concat()] {
        let windowed = sets.len() > 2;
        let streamed = Scene::load(&path, &sets).unwrap();
        assert!(matches!(streamed.terrain_data(0).unwrap(), volterra::scene::TerrainData::Rows(_)), "the GPU's heights come by rows");
        let a = render::render_scene(&streamed, None).unwrap();
        assert!(!streamed.is_loaded(0), "the raster was not read whole");
        let b = {
            let scene = Scene::load(&path, &sets).unwrap();
            let opts = volterra::formats::geotiff::GeoTiffOptions { extent: windowed.then_some(extent), level: None };
            scene.provide_data(
                0,
                NodeData::Heightfield(std::sync::Arc::new(
                    volterra::formats::geotiff::read_geotiff_with(&dem, &opts, &Default::default()).unwrap(),
                )),
            );
            assert!(matches!(scene.terrain_data(0).unwrap(), volterra::scene::TerrainData::Held(_)));
            assert_eq!(scene.camera(None).unwrap(), streamed.camera(None).unwrap(), "the walk's eye stands on the same ground");
            render::render_scene(&scene, None).unwrap()
        };
        let hits = a.depth.iter().filter(|d| d.is_finite()).count();
        assert!(hits > a.depth.len() / 3, "the terrain fills much of the view ({hits} hits)");
        let bits = |f: &render::Frame| {
            (f.rgba.iter().flatten().map(|v| v.to_bits()).collect::<Vec<_>>(), f.depth.iter().map(|d| d.to_bits()).collect::<Vec<_>>())
        };
        assert!(bits(&a) == bits(&b), "extent {windowed}: the frames differ from those of the raster held");
    }

    // A broken strip: the render fails naming the file (its rows read as NoData until then).
    let broken = dir.path().join("broken.tif");
    let (offset, count) = {
        let mut d = tiff::decoder::Decoder::new(std::fs::File::open(&dem).unwrap()).unwrap();
        let offsets = d.get_tag_u64_vec(tiff::tags::Tag::StripOffsets).unwrap();
        let counts = d.get_tag_u64_vec(tiff::tags::Tag::StripByteCounts).unwrap();
        (offsets[offsets.len() / 2], counts[offsets.len() / 2])
    };
    let mut bytes = std::fs::read(&dem).unwrap();
    bytes[offset as usize..(offset + count) as usize].fill(0x5A);
    std::fs::write(&broken, &bytes).unwrap();
    let scene = Scene::load(&path, &[sizes.to_vec(), vec!["node.dem.file=broken.tif".into()]].concat()).unwrap();
    let Err(e) = render::render_scene(&scene, None) else { panic!("a broken strip fails the render") };
    let e = format!("{e:#}");
    assert!(e.contains("broken.tif"), "{e}");
}

/// An edited scene (the viewer's) keeps a node's data only while the keys that say what is
/// read stay: a heightfield's `extent` is one of them — a new extent reads the new window,
/// a moved camera reads nothing again.
#[test]
fn an_edited_extent_reads_the_new_window_and_a_moved_camera_reads_nothing() {
    let dir = tempfile::tempdir().unwrap();
    volterra::samples::write_samples(dir.path()).unwrap();
    let scene = Scene::load(&dir.path().join("terrain.toml"), &[]).unwrap();
    let whole = scene.heightfield(0).unwrap();
    let mut file = scene.file.clone();
    file.camera.position[2] += 100.0;
    let moved = scene.edited(file.clone()).unwrap();
    assert!(moved.is_loaded(0) && std::sync::Arc::ptr_eq(&moved.heightfield(0).unwrap(), &whole), "the camera's move reads nothing");
    let (ox, oy, cell) = (whole.origin[0], whole.origin[1], whole.cell_size_native[0]);
    file.nodes[0].extent = Some([ox, oy - 99.0 * cell, ox + 49.0 * cell, oy]);
    let windowed = scene.edited(file).unwrap();
    assert!(!windowed.is_loaded(0), "a new extent is read anew");
    let part = windowed.heightfield(0).unwrap();
    assert_eq!((part.width, part.height), (50, 100));
}

/// Issue 20, "only what a view needs is read when the DEM is larger than memory allows": a
/// GeoTIFF DEM whose whole raster passes the memory limit (and which has no overviews to
/// fall back on) is refused — unless the render's cameras are known first
/// (`Scene::with_views`, as `volterra render` does): then only the window they see is read,
/// placed where it lies in the whole, and the frame's depth is the whole raster's.
#[test]
fn a_dem_beyond_the_memory_limit_is_read_only_where_the_camera_sees_it_and_draws_as_the_whole() {
    let dir = tempfile::tempdir().unwrap();
    let scene_path = write(dir.path(), "view.toml", &common::view_window_scene(96, 64));
    common::view_window_dem(&dir.path().join("dem.tif"));
    let size = (96, 64);
    let mut renderers = vec!["terrain-reference"];
    if common::gpu().is_some() {
        renderers.push("terrain");
    }
    // Also with the node turned, moved and its heights exaggerated: the frusta are clipped
    // in the node's frame.
    let placed = [
        "node.dem.transform.rotate=[0.0, 0.0, 12.0]",
        "node.dem.transform.scale=[1.0, 1.0, 2.5]",
        "node.dem.transform.translate=[2500.0, -400.0, -300.0]",
    ];
    let cases = renderers.iter().flat_map(|r| [(*r, false), (*r, true)]);
    for (renderer, moved) in cases {
        let mut sets = vec![format!("node.dem.renderer={renderer}")];
        if moved {
            sets.extend(placed.iter().map(|s| s.to_string()));
        }
        let renderer = format!("{renderer}{}", if moved { " (node turned, moved, exaggerated)" } else { "" });
        let whole = Scene::load(&scene_path, &sets).unwrap();
        let camera = whole.camera(None).unwrap();
        let whole = whole.with_views(std::slice::from_ref(&camera)).unwrap();
        assert_eq!(whole.view_window_note(0), None, "{renderer}: within the default limit the DEM is read whole");
        let a = render::render_view(&whole, &camera, size, &Default::default()).unwrap();

        // 1200 × 900 samples need 4.3 MB as float32 (5.4 MB on the GPU): over a 3 MB limit.
        let limits = volterra_formats::Limits::max(3_000_000);
        let refused = Scene::load(&scene_path, &sets).unwrap().with_limits(limits);
        let e = format!("{:#}", render::render_view(&refused, &camera, size, &Default::default()).unwrap_err());
        assert!(e.contains("dem.tif") && e.contains("memory limit"), "{renderer}: without the views the whole is refused: {e}");

        let windowed = Scene::load(&scene_path, &sets).unwrap().with_limits(limits).with_views(std::slice::from_ref(&camera)).unwrap();
        let note = windowed.view_window_note(0).expect("a view window").to_string();
        assert!(note.contains("of the full raster"), "{renderer}: {note}");
        let b = render::render_view(&windowed, &camera, size, &Default::default()).unwrap();
        assert!(b.stats.notes.iter().any(|n| n.contains("read only what the views see")), "{renderer}: {:?}", b.stats.notes);
        let read = windowed.terrain_data(0).unwrap().georef();
        assert!(
            read.width * read.height * 4 < 3_000_000 && read.width < 1200 && read.height < 900,
            "{renderer}: {}×{} samples read",
            read.width,
            read.height
        );

        // Views handed again once the window is read: what was read stays where it was.
        let (placed, note) = (windowed.world_transform(0), windowed.view_window_note(0).map(str::to_string));
        let mut far = camera.clone();
        far.position[0] -= 20000.0;
        let windowed = windowed.with_views(&[far]).unwrap();
        assert_eq!((windowed.world_transform(0), windowed.view_window_note(0).map(str::to_string)), (placed, note), "{renderer}");

        let hits = a.depth.iter().filter(|d| d.is_finite()).count();
        assert!(hits > a.depth.len() / 2, "{renderer}: the terrain fills the view ({hits} hits)");
        let agreement = render::terrain::depth_agreement(&b, &a);
        assert!(agreement.both_hit > 0, "{renderer}: no pixel hit in both");
        let (median, max, coverage) = (agreement.median_rel, agreement.max_rel, agreement.mismatched);
        eprintln!("{renderer}: window {}×{} of 1200×900; depth vs the whole: median {median:.1e}, max {max:.1e}, {coverage} pixels hit in one only", read.width, read.height);
        // The window's terrain spans the whole raster's elevations (found in one pass over
        // its rows: it has no overviews): the walls at the raster's edges reach as deep, the
        // heights are the same relative to the grid's middle, the elevation colours span
        // the same range. The f64 reference draws the same frame bit for bit; the GPU's
        // f32 within a few ulps.
        let colour = a.rgba.iter().zip(&b.rgba).flat_map(|(p, q)| (0..3).map(move |c| (p[c] - q[c]).abs())).fold(0f32, f32::max);
        eprintln!("{renderer}: largest colour difference {colour:.1e}");
        let bound = if renderer.starts_with("terrain-reference") { 0.0 } else { 1e-6 };
        assert!(
            coverage == 0 && max <= bound && f64::from(colour) <= 10.0 * bound,
            "{renderer}: depth median {median:e}, max {max:e}, coverage {coverage}, colour {colour:e}"
        );
        let range = |f: &render::Frame| f.scales.iter().find(|s| s.title.starts_with("elevation")).map(|s| s.range);
        assert_eq!(range(&b), range(&a), "{renderer}: the scalar bar's range");
    }
}

/// A PNG drape is stretched over what is read, so a DEM draped with one gets no view
/// window (it would shrink the drape onto the window): it is read as before — refused here.
#[test]
fn a_dem_with_a_stretched_png_drape_gets_no_view_window() {
    let dir = tempfile::tempdir().unwrap();
    let scene_path = write(dir.path(), "view.toml", &common::view_window_scene(96, 64));
    common::view_window_dem(&dir.path().join("dem.tif"));
    let drape = volterra_formats::RgbImage { width: 8, height: 6, data: [200, 120, 40].repeat(48) };
    volterra_formats::image::write_png_rgb8(&dir.path().join("drape.png"), &drape).unwrap();
    let scene = Scene::load(&scene_path, &["node.dem.texture=\"drape.png\"".to_string()]).unwrap();
    let camera = scene.camera(None).unwrap();
    let scene = scene.with_limits(volterra_formats::Limits::max(3_000_000)).with_views(std::slice::from_ref(&camera)).unwrap();
    assert_eq!(scene.view_window_note(0), None);
    let e = format!("{:#}", render::render_view(&scene, &camera, (96, 64), &Default::default()).unwrap_err());
    assert!(e.contains("memory limit"), "{e}");
}

/// The same DEM tiled with `gdaladdo` overviews (2, 4, 8) under a limit that fits neither
/// the whole (it would be read from the 4× overview) nor the view's window at full
/// resolution: the window is read from the 2× overview, and every sample read lies in the
/// world at its map position (GDAL's placement of the overview) less the full raster's
/// south-west sample's — the node's frame does not move with the level read.
#[test]
fn a_view_window_read_from_an_overview_keeps_every_sample_where_its_map_coordinates_put_it() {
    let (Some(translate), Some(addo)) = (common::gdal_tool("gdal_translate"), common::gdal_tool("gdaladdo")) else { return };
    let dir = tempfile::tempdir().unwrap();
    let scene_path = write(dir.path(), "view.toml", &common::view_window_scene(96, 64));
    let plain = dir.path().join("plain.tif");
    common::view_window_dem(&plain);
    let tiled = dir.path().join("dem.tif");
    let run = |cmd: &mut std::process::Command| {
        let out = cmd.output().unwrap();
        assert!(out.status.success(), "{cmd:?}: {}", String::from_utf8_lossy(&out.stderr));
    };
    run(std::process::Command::new(translate)
        .args(["-q", "-co", "TILED=YES", "-co", "BLOCKXSIZE=128", "-co", "BLOCKYSIZE=128"])
        .arg(&plain)
        .arg(&tiled));
    run(std::process::Command::new(addo).args(["-q", "-r", "average"]).arg(&tiled).args(["2", "4", "8"]));
    let size = (96, 64);
    let whole = Scene::load(&scene_path, &[]).unwrap();
    let camera = whole.camera(None).unwrap();
    let a = render::render_view(&whole, &camera, size, &Default::default()).unwrap();

    let limits = volterra_formats::Limits::max(400_000);
    let windowed = Scene::load(&scene_path, &[]).unwrap().with_limits(limits).with_views(std::slice::from_ref(&camera)).unwrap();
    let b = render::render_view(&windowed, &camera, size, &Default::default()).unwrap();
    let note = windowed.view_window_note(0).unwrap();
    assert!(note.contains("of the 600×450 overview"), "{note}");
    let hf = windowed.heightfield(0).unwrap();
    assert!(
        hf.width < 600 && hf.height < 450 && hf.cell_size_native == [60.0, 60.0],
        "{}×{}, cells {:?}",
        hf.width,
        hf.height,
        hf.cell_size_native
    );
    let m = windowed.world_transform(0);
    let full_south_west = [500_015.0, 4_200_015.0 - 899.0 * 30.0];
    for (c, r) in [(0, 0), (hf.width - 1, 0), (0, hf.height - 1), (hf.width / 2, hf.height / 3)] {
        let local = glam::DVec3::new(c as f64 * hf.cell_size[0], (hf.height - 1 - r) as f64 * hf.cell_size[1], 0.0);
        let world = m.transform_point3(local);
        let map = [hf.origin[0] + c as f64 * hf.cell_size_native[0], hf.origin[1] - r as f64 * hf.cell_size_native[1]];
        let want = [map[0] - full_south_west[0], map[1] - full_south_west[1]];
        assert!(
            (world.x - want[0]).abs() < 1e-6 && (world.y - want[1]).abs() < 1e-6,
            "sample ({c}, {r}) at {world:?}, its map position puts it at {want:?}"
        );
    }
    // The 2× overview drawn where the full raster is: depths close to the full raster's.
    let agreement = render::terrain::depth_agreement(&b, &a);
    assert!(agreement.both_hit > 0, "no pixel hit in both");
    let (median, coverage) = (agreement.median_rel, agreement.mismatched);
    eprintln!(
        "2× overview window {}×{}: depth vs the full raster's median {median:.1e}, {coverage} pixels hit in one only",
        hf.width, hf.height
    );
    assert!(median < 2e-3 && coverage <= 3, "median {median:e}, coverage {coverage}");
}

/// A heightfield's `elevation_range` puts the elevation colours' ends where it says (the
/// scalar bar too), and is refused where it means nothing.
#[test]
fn an_elevation_range_sets_the_elevation_colours_ends() {
    let dir = tempfile::tempdir().unwrap();
    volterra::samples::write_samples(dir.path()).unwrap();
    // The sample terrain without its drape, which would cover the elevation colours.
    let text = std::fs::read_to_string(dir.path().join("terrain.toml")).unwrap().replace("texture = \"fractal_dem_texture.png\"\n", "");
    let path = write(dir.path(), "bare.toml", &text);
    let small = ["image.width=48".to_string(), "image.height=32".into(), "node.dem.renderer=terrain-reference".into()];
    let render = |extra: Option<String>| {
        let sets: Vec<String> = small.iter().cloned().chain(extra).collect();
        render::render_scene(&Scene::load(&path, &sets).unwrap(), None).unwrap()
    };
    let range = |f: &render::Frame| f.scales.iter().find(|s| s.title.starts_with("elevation")).map(|s| s.range);
    let plain = render(None);
    let own = range(&plain).expect("an elevation scale");
    let wide = render(Some("node.dem.elevation_range=[-2000.0, 6000.0]".into()));
    assert_eq!(range(&wide), Some([-2000.0, 6000.0]));
    let diff = |a: &render::Frame, b: &render::Frame| {
        a.rgba.iter().zip(&b.rgba).flat_map(|(p, q)| (0..3).map(move |c| (p[c] - q[c]).abs())).fold(0f32, f32::max)
    };
    assert!(diff(&plain, &wide) > 0.05, "a wider range changes the colours");
    // The data's own range: the same colours.
    let same = render(Some(format!("node.dem.elevation_range=[{}, {}]", own[0], own[1])));
    assert!(diff(&plain, &same) <= 1e-5, "the data's own range: colours differ by {}", diff(&plain, &same));
    for (set, why) in [("node.dem.elevation_range=[5.0, 5.0]", "low < high"), ("node.dem.elevation_range=[1.0, nan]", "finite")] {
        let e = format!("{:#}", Scene::load(&path, &[set.to_string()]).err().expect("refused"));
        assert!(e.contains("elevation_range") && e.contains(why), "{e}");
    }
}

#[test]
fn nodes_given_data_in_memory_render_keep_it_across_edits_and_are_checked() {
    use volterra::scene::{NodeDesc, NodeKind, SceneFile};
    let mut file: SceneFile = toml::from_str("[camera]\nposition = [0, -60, 0]\nfocal_point = [0, 0, 0]\n").unwrap();
    file.image.width = 24;
    file.image.height = 24;
    file.nodes.push(NodeDesc { preset: Some("CT-AAA".into()), ..NodeDesc::new("ct", NodeKind::Volume) });
    // Values rising along x, so the preset placed on their percentiles draws something.
    let ramp = Volume::centred([16; 3], [2.0; 3], VoxelData::U8((0..16 * 16 * 16).map(|i| (i % 16 * 17) as u8).collect()));
    let volume = || NodeData::Volume(std::sync::Arc::new(ramp.clone()));
    let src = std::path::PathBuf::from("<memory>");
    // Without data, a node without a file is refused as in a scene file.
    let e = Scene::from_memory(file.clone(), ".".into(), src.clone(), vec![]).err().unwrap().to_string();
    assert!(e.contains("node 'ct' (Volume) needs a file"), "{e}");
    // Data for a node the scene lacks, or of another kind, is refused.
    let e = Scene::from_memory(file.clone(), ".".into(), src.clone(), vec![("mr".into(), volume())]).err().unwrap().to_string();
    assert!(e.contains("a node the scene lacks"), "{e}");
    let hf = NodeData::Particles(std::sync::Arc::new(
        volterra_formats::ParticleSet::from_arrays(vec![[0.0; 3]], vec![], &Default::default(), vec![]).unwrap(),
    ));
    let e = Scene::from_memory(file.clone(), ".".into(), src.clone(), vec![("ct".into(), hf)]).err().unwrap().to_string();
    assert!(e.contains("is given Particles data"), "{e}");
    let scene = Scene::from_memory(file.clone(), ".".into(), src, vec![("ct".into(), volume())]).unwrap();
    assert!(scene.is_loaded(0));
    let before = render::render_scene(&scene, None).unwrap();
    assert!(before.rgba.iter().any(|p| p[3] > 0.5));
    // An edit (the background) keeps the data given; a second node is given its own.
    let mut edited = scene.file.clone();
    edited.image.background = [0.5; 3];
    edited.nodes.push(NodeDesc { visible: false, ..NodeDesc::new("copy", NodeKind::Volume) });
    let next = scene.edited_with_data(edited, vec![("copy".into(), volume())]).unwrap();
    assert!(next.is_loaded(0) && next.is_loaded(1));
    assert!(std::sync::Arc::ptr_eq(&scene.volume(0).unwrap(), &next.volume(0).unwrap()));
    // A drape in memory is for heightfields only.
    let drape = volterra::scene::drape::Drape::stretched(&volterra_formats::RgbImage { width: 1, height: 1, data: vec![0; 3] });
    let e = next.provide_texture(0, std::sync::Arc::new(drape)).unwrap_err().to_string();
    assert!(e.contains("for a heightfield node"), "{e}");
    // The same data drawn again (the hidden copy draws nothing).
    assert_eq!(render::render_scene(&next, None).unwrap().rgba, before.rgba);
}
