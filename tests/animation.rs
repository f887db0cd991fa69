//! Time series and animations as a simulation user runs them: a ParaView collection, a
//! numbered pattern and a 4-D NIfTI as a node's file; one frame per timestep; frames
//! split over tasks (`--shard`) and finished later (`--resume`), every frame bit for bit
//! the same whichever task, order or thread count renders it.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use volterra::scene::animation;
use volterra::scene::Scene;
use volterra_formats::VoxelData;

/// `volterra ARGS` with `threads` rayon threads and the photon cache off (so every run
/// traces its own photons: a cached run could hide a frame that depends on its history).
fn volterra(args: &[&str], threads: usize) -> Output {
    Command::new(common::volterra_bin())
        .args(args)
        .env("RAYON_NUM_THREADS", threads.to_string())
        .env("VOLTERRA_CACHE_MAX", "0")
        .output()
        .unwrap()
}

fn ok(out: &Output) -> String {
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{err}");
    err
}

/// The built-in plume series (4 steps) and a small smoke scene over `file`, turned by an
/// orbit, in a fresh directory.
fn plume_scene(file: &str) -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    volterra::samples::write_plume_series(&dir.path().join("series"), 4, 3000).unwrap();
    let scene = dir.path().join("scene.toml");
    std::fs::write(
        &scene,
        format!(
            r#"[image]
width = 48
height = 40
[camera]
position = [0.5, -1.6, 0.5]
focal_point = [0.5, 0.5, 0.45]
[orbit]
degrees = 90.0
[[light]]
kind = "directional"
direction = [-1.0, 0.6, -0.5]
intensity = 3.0
[[node]]
name = "plume"
kind = "particles"
file = "{file}"
renderer = "smoke"
medium = {{ c_ext = 10.0, albedo = 0.9, g = 0.3 }}
settings = {{ photons = 4000, samples = 2 }}
"#
        ),
    )
    .unwrap();
    (dir, scene)
}

fn frame_files(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().path()).collect();
    v.sort();
    v
}

#[test]
fn every_frame_is_the_same_whichever_shard_order_or_thread_count_renders_it() {
    let (dir, scene) = plume_scene("series/plume.pvd");
    let (serial, sharded) = (dir.path().join("serial"), dir.path().join("sharded"));
    std::fs::create_dir_all(&serial).unwrap();
    std::fs::create_dir_all(&sharded).unwrap();
    let s = scene.to_str().unwrap();
    let err = ok(&volterra(&["render", s, "-o", serial.join("f.exr").to_str().unwrap(), "--frames"], 2));
    assert!(err.contains("4 of the animation's 4 frames"), "{err}");
    // The shards in reverse order, one thread each.
    for k in [2, 1, 0] {
        let err = ok(&volterra(&["render", s, "-o", sharded.join("f.exr").to_str().unwrap(), "--frames", "--shard", &format!("{k}/3")], 1));
        let want = if k == 0 { 2 } else { 1 };
        assert!(err.contains(&format!("task {k} of 3: {want} of the animation's 4 frames")), "{err}");
    }
    let (a, b) = (frame_files(&serial), frame_files(&sharded));
    assert_eq!(a.iter().map(|p| p.file_name().unwrap()).collect::<Vec<_>>(), b.iter().map(|p| p.file_name().unwrap()).collect::<Vec<_>>());
    assert_eq!(a.len(), 4);
    for (x, y) in a.iter().zip(&b) {
        assert_eq!(std::fs::read(x).unwrap(), std::fs::read(y).unwrap(), "{}", x.display());
    }
    // The frames differ: the plume rises (more particles, higher) and the camera turns.
    let bytes: Vec<Vec<u8>> = a.iter().map(|p| std::fs::read(p).unwrap()).collect();
    assert!(bytes.windows(2).all(|w| w[0] != w[1]));
}

#[test]
fn resume_renders_only_the_frames_whose_outputs_are_missing() {
    let (dir, scene) = plume_scene("series/plume_####.vtp");
    let out = dir.path().join("out");
    std::fs::create_dir_all(&out).unwrap();
    let (s, o) = (scene.to_str().unwrap(), out.join("f.exr"));
    let png = out.join("p.png");
    let args = ["render", s, "-o", o.to_str().unwrap(), "--png", png.to_str().unwrap(), "--frames"];
    ok(&volterra(&args, 2));
    let before: Vec<(PathBuf, Vec<u8>)> = frame_files(&out).into_iter().map(|p| (p.clone(), std::fs::read(&p).unwrap())).collect();
    assert_eq!(before.len(), 8, "4 EXRs and 4 PNGs");
    // A frame lost (its EXR), another half there (its PNG gone): both are rendered again,
    // the other two are left as they are (their files are not rewritten).
    std::fs::remove_file(out.join("f_0002.exr")).unwrap();
    std::fs::remove_file(out.join("p_0000.png")).unwrap();
    let stamp = |p: &Path| std::fs::metadata(p).unwrap().modified().unwrap();
    let kept = [out.join("f_0001.exr"), out.join("f_0003.exr")];
    let stamps: Vec<_> = kept.iter().map(|p| stamp(p)).collect();
    std::thread::sleep(std::time::Duration::from_millis(20));
    let mut resumed = args.to_vec();
    resumed.push("--resume");
    let err = ok(&volterra(&resumed, 1));
    assert!(err.contains("2 of the animation's 4 frames to render (2 already written)"), "{err}");
    assert_eq!(kept.iter().map(|p| stamp(p)).collect::<Vec<_>>(), stamps, "finished frames are not rendered again");
    for (p, b) in &before {
        assert_eq!(&std::fs::read(p).unwrap(), b, "{}", p.display());
    }
    // No temporary file is left beside the outputs.
    assert_eq!(frame_files(&out).len(), 8);
}

#[test]
fn frames_over_time_draw_each_series_step_at_or_before_their_time_and_load_lazily() {
    let (dir, scene_path) = plume_scene("series/plume.pvd");
    let scene = Scene::load(&scene_path, &[]).unwrap();
    let series = scene.series(0).expect("a .pvd is a series");
    assert_eq!(series.times(), vec![0.0, 0.5, 1.0, 1.5]);
    assert_eq!(scene.timeline(), vec![0.0, 0.5, 1.0, 1.5]);
    // 7 frames over 0..1.5 s: times 0, 0.25, …; each node draws its last step at or before.
    let frames = animation::frames(&scene, Some(7)).unwrap();
    let times: Vec<f64> = frames.iter().map(|f| f.time.unwrap()).collect();
    assert_eq!(times, vec![0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5]);
    let steps: Vec<usize> = times.iter().map(|&t| scene.at_time(t).step(0).unwrap()).collect();
    assert_eq!(steps, vec![0, 0, 1, 1, 2, 2, 3]);
    // Per timestep: 4 frames, the path fraction their share of the time.
    let per_step = animation::frames(&scene, None).unwrap();
    assert_eq!(per_step.iter().map(|f| f.path).collect::<Vec<_>>(), vec![0.0, 1.0 / 3.0, 2.0 / 3.0, 1.0]);
    // Only the step drawn is read; moving on keeps a step still drawn, reads the next one.
    let t0 = scene.at_time(0.0);
    assert!(!t0.is_loaded(0));
    let p0 = t0.particles(0).unwrap();
    let same = t0.at_time(0.25);
    assert!(same.is_loaded(0) && std::sync::Arc::ptr_eq(&p0, &same.particles(0).unwrap()));
    let next = same.at_time(0.5);
    assert!(!next.is_loaded(0));
    assert!(next.particles(0).unwrap().len() > p0.len(), "the plume grows");
    // The orbit turns 90° over the frames, ending on it (not a whole turn).
    let cams: Vec<_> = per_step.iter().map(|f| scene.camera_at(Some(*f)).unwrap()).collect();
    let (c0, c3) = (glam::DVec3::from(cams[0].position), glam::DVec3::from(cams[3].position));
    let f = glam::DVec3::from(cams[0].focal_point);
    let turn = ((c0 - f).truncate().angle_to((c3 - f).truncate())).to_degrees();
    assert!((turn - 90.0).abs() < 1e-9, "{turn}");
    drop(dir);
}

#[test]
fn a_4d_nifti_is_a_series_of_its_volumes_and_each_frame_is_that_volume_rendered() {
    let dir = tempfile::tempdir().unwrap();
    let vols: Vec<_> = (0..3)
        .map(|t| {
            // The vessels brighten over time (values scaled by 0.4, 0.7, 1.0).
            let v = volterra::samples::angio_phantom(24);
            let VoxelData::U8(d) = &v.data else { panic!("the phantom is u8") };
            let d = d.iter().map(|&x| (x as f64 * (0.4 + 0.3 * t as f64)).round() as u8).collect();
            volterra_formats::Volume { data: VoxelData::U8(d), ..v }
        })
        .collect();
    let nii = dir.path().join("fmri.nii");
    // 2.5 s between volumes (xyzt_units 8: seconds).
    volterra_formats::nifti::write_nifti_volumes(&nii, &vols, &[3], 2.5, 8).unwrap();
    let scene = |extra: &str| {
        format!(
            "[image]\nwidth = 32\nheight = 32\n[camera]\nposition = [0.0, -200.0, 0.0]\nfocal_point = [0.0, 0.0, 0.0]\nparallel_projection = true\nparallel_scale = 20.0\n[orbit]\ndegrees = 0.0\n[[node]]\nname = \"v\"\nkind = \"volume\"\nfile = \"fmri.nii\"\nrenderer = \"shear-warp\"\n{extra}[node.transfer_function]\nscalar_opacity = [[0.0, 0.0], [255.0, 0.8]]\ncolor = [[0.0, 1.0, 1.0, 1.0], [255.0, 1.0, 1.0, 1.0]]\n"
        )
    };
    std::fs::write(dir.path().join("series.toml"), scene("")).unwrap();
    let out = dir.path().join("out");
    std::fs::create_dir_all(&out).unwrap();
    ok(&volterra(&["render", dir.path().join("series.toml").to_str().unwrap(), "-o", out.join("f.exr").to_str().unwrap(), "--frames"], 2));
    let info = volterra(&["info", "--json", nii.to_str().unwrap()], 2);
    let v: serde_json::Value = serde_json::from_slice(&info.stdout).unwrap();
    assert_eq!(v["kind"], "4-D NIfTI");
    assert_eq!(v["time_unit"], "s");
    let times: Vec<f64> = v["timesteps"].as_array().unwrap().iter().map(|s| s["time"].as_f64().unwrap()).collect();
    assert_eq!(times, vec![0.0, 2.5, 5.0]);
    // Each frame is the still of that volume (volume_index = k), bit for bit.
    for k in 0..3 {
        let still = dir.path().join(format!("still_{k}.toml"));
        std::fs::write(&still, scene(&format!("volume_index = {k}\n"))).unwrap();
        let o = dir.path().join(format!("still_{k}.exr"));
        ok(&volterra(&["render", still.to_str().unwrap(), "-o", o.to_str().unwrap()], 2));
        assert_eq!(std::fs::read(&o).unwrap(), std::fs::read(out.join(format!("f_{k:04}.exr"))).unwrap(), "volume {k}");
    }
    assert_ne!(std::fs::read(out.join("f_0000.exr")).unwrap(), std::fs::read(out.join("f_0002.exr")).unwrap());
}

#[test]
fn info_lists_a_series_steps_with_their_counts_and_ranges() {
    let (dir, _) = plume_scene("series/plume.pvd");
    let pattern = dir.path().join("series/plume_####.vtp");
    let out = volterra(&["info", "--json", pattern.to_str().unwrap()], 2);
    ok(&out);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let steps = v["timesteps"].as_array().unwrap();
    assert_eq!(steps.len(), 4);
    // Counts as the reader gives them, one file at a time.
    for s in steps {
        let file = PathBuf::from(s["file"].as_str().unwrap());
        let p = volterra_formats::load(&file, &Default::default()).unwrap();
        let volterra_formats::Dataset::Particles(p) = p else { panic!() };
        assert_eq!(s["particles"].as_u64().unwrap() as usize, p.len());
        let d = p.density.unwrap();
        let lo = d.iter().cloned().fold(f32::INFINITY, f32::min) as f64;
        assert_eq!(s["ranges"]["density"][0].as_f64().unwrap(), lo);
    }
    let counts: Vec<u64> = steps.iter().map(|s| s["particles"].as_u64().unwrap()).collect();
    assert!(counts.windows(2).all(|w| w[0] < w[1]), "{counts:?}");
    let text = volterra(&["info", pattern.to_str().unwrap()], 2);
    ok(&text);
    assert!(
        String::from_utf8_lossy(&text.stdout).contains("(numbered files): 4 timesteps, time 0 .. 3"),
        "{}",
        String::from_utf8_lossy(&text.stdout)
    );
}

#[test]
fn animation_mistakes_are_one_line_errors() {
    let (dir, scene) = plume_scene("series/plume.pvd");
    let s = scene.to_str().unwrap();
    let o = dir.path().join("f.exr");
    let o = o.to_str().unwrap();
    for (args, want) in [
        (vec!["render", s, "-o", o, "--frames", "--shard", "3/3"], "K must lie in 0..M"),
        (vec!["render", s, "-o", o, "--frames", "--shard", "auto"], "SLURM_ARRAY_TASK_ID is not set"),
        (vec!["render", s, "-o", o, "--frames", "0"], "at least 1"),
    ] {
        let out = volterra(&args, 1);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {err}");
        assert_eq!(err.trim_end().lines().count(), 1, "{err}");
        assert!(err.contains(want), "{args:?}: {err}");
    }
    let (dir2, missing) = plume_scene("series/none_####.vtp");
    let out = volterra(&["render", missing.to_str().unwrap(), "-o", o], 1);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("none_####.vtp") && err.contains("matches"), "{err}");
    assert!(!Path::new(o).exists());
    drop(dir2);
}

/// The peak memory of a whole animation over a 4-D NIfTI is that of one frame: each step is
/// read when its frame comes and dropped, with its preparation, when the next one does.
#[test]
fn an_animation_holds_one_step_at_a_time() {
    let dir = tempfile::tempdir().unwrap();
    let n = 96;
    let step_bytes = n * n * n * 4;
    let vols: Vec<_> = (0..8)
        .map(|t| {
            let data = (0..n * n * n).map(|i| ((i * 7 + t * 13) % 1000) as f32).collect();
            volterra_formats::Volume::centred([n, n, n], [1.0; 3], VoxelData::F32(data))
        })
        .collect();
    volterra_formats::nifti::write_nifti_volumes(&dir.path().join("v.nii"), &vols, &[8], 1.0, 8).unwrap();
    std::fs::write(
        dir.path().join("s.toml"),
        "[image]\nwidth = 32\nheight = 32\n[camera]\nposition = [0.0, -400.0, 50.0]\nfocal_point = [0.0, 0.0, 0.0]\n\
         [[node]]\nname = \"v\"\nkind = \"volume\"\nfile = \"v.nii\"\nrenderer = \"shear-warp\"\n\
         [node.transfer_function]\nscalar_opacity = [[0.0, 0.0], [1000.0, 0.02]]\ncolor = [[0.0, 1.0, 1.0, 1.0], [1000.0, 1.0, 1.0, 1.0]]\n",
    )
    .unwrap();
    let s = dir.path().join("s.toml");
    let peak = |extra: &[&str]| -> f64 {
        let mut args = vec!["--max-memory", "4G", "render", s.to_str().unwrap(), "-o"];
        let o = dir.path().join("f.exr");
        args.push(o.to_str().unwrap());
        args.extend(extra);
        let err = ok(&volterra(&args, 2));
        let line = err.lines().find(|l| l.starts_with("memory: peak")).unwrap_or_else(|| panic!("{err}"));
        let v: Vec<&str> = line.split_whitespace().collect();
        let unit = match v[3] {
            "KiB" => 1024.0,
            "MiB" => 1048576.0,
            "GiB" => 1073741824.0,
            _ => 1.0,
        };
        v[2].parse::<f64>().unwrap() * unit
    };
    let one = peak(&[]);
    let all = peak(&["--frames"]);
    // Each step: its f32 voxels and shear-warp's u16 copy (1.5 × the step); all 8 kept would
    // add 10 MB.
    assert!(all < one + 0.5 * step_bytes as f64, "8 frames peak at {all:.0} B, one frame at {one:.0} B (a step is {step_bytes} B)");
}

/// A series' automatic scales are taken over all its steps (issue 44): with no
/// `color_range`, every frame of a points series is coloured over its array's range over
/// every step (each step's own ranges differ: 0–1, 0–2, 0–3), and frame k draws bit for bit
/// as step k alone with that range given; smoke without `c_ext` gets the c_ext of the
/// densest step in every frame, which each frame's note says. `scale_over = "step"` takes
/// each step's own, as before.
#[test]
fn a_series_is_coloured_and_its_smoke_extinguished_over_all_its_steps() {
    use volterra::render::{render_view, RenderCache};
    let dir = tempfile::tempdir().unwrap();
    let base = volterra::samples::smoke_plume(1500, 9);
    let mut pvd = String::from("<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\">\n<Collection>\n");
    for k in 0..3 {
        // Step k: heat over [0, k + 1]; the plume compressed sideways (denser) each step.
        let mut step = base.clone();
        let n = step.len();
        step.arrays.push(volterra_formats::PointArray {
            name: "heat".into(),
            components: 1,
            values: (0..n).map(|i| (k + 1) as f64 * i as f64 / (n - 1) as f64).collect(),
        });
        for p in &mut step.positions {
            p[0] = 0.5 + (p[0] - 0.5) / (1.0 + 0.5 * k as f64);
        }
        volterra_formats::vtk::write_vtp(&dir.path().join(format!("s_{k}.vtp")), &step, &Default::default()).unwrap();
        pvd += &format!("  <DataSet timestep=\"{k}\" file=\"s_{k}.vtp\"/>\n");
    }
    pvd += "</Collection>\n</VTKFile>\n";
    std::fs::write(dir.path().join("s.pvd"), pvd).unwrap();
    let scene_text = |file: &str, renderer: &str, extra: &str| {
        format!(
            "[image]\nwidth = 40\nheight = 32\n[camera]\nposition = [0.5, -1.6, 0.5]\nfocal_point = [0.5, 0.5, 0.45]\n\
             [[light]]\nkind = \"directional\"\ndirection = [-1.0, 0.6, -0.5]\nintensity = 3.0\n\
             [[node]]\nname = \"plume\"\nkind = \"particles\"\nfile = \"{file}\"\nrenderer = \"{renderer}\"\n{extra}"
        )
    };
    let load = |text: String| {
        std::fs::write(dir.path().join("scene.toml"), text).unwrap();
        Scene::load(&dir.path().join("scene.toml"), &[]).unwrap()
    };
    // Every frame of the series through one cache, as `render --frames` draws them.
    let frames = |scene: &Scene| -> Vec<volterra::render::Frame> {
        let cache = RenderCache::default();
        let camera = scene.camera(None).unwrap();
        animation::frames(scene, None)
            .unwrap()
            .iter()
            .map(|f| render_view(&scene.at_time(f.time.unwrap()), &camera, (40, 32), &cache).unwrap())
            .collect()
    };
    if common::gpu().is_some() {
        let series = frames(&load(scene_text("s.pvd", "points", "color_by = \"heat\"\n")));
        for (k, f) in series.iter().enumerate() {
            assert_eq!(f.scales[0].range, [0.0, 3.0], "frame {k}: coloured over the series' range");
            assert!(f.stats.notes.iter().any(|n| n.contains("across the series' 3 steps")), "{:?}", f.stats.notes);
            // Step k alone with that range: the same picture.
            let alone = load(scene_text(&format!("s_{k}.vtp"), "points", "color_by = \"heat\"\ncolor_range = [0.0, 3.0]\n"));
            let still = render_view(&alone, &alone.camera(None).unwrap(), (40, 32), &RenderCache::default()).unwrap();
            assert!(still.rgba == f.rgba, "frame {k} differs from step {k} drawn alone over the series' range");
        }
        let per_step = frames(&load(scene_text("s.pvd", "points", "color_by = \"heat\"\nscale_over = \"step\"\n")));
        let ranges: Vec<[f64; 2]> = per_step.iter().map(|f| f.scales[0].range).collect();
        assert_eq!(ranges, [[0.0, 1.0], [0.0, 2.0], [0.0, 3.0]], "each step over its own range");
    }
    // Smoke: one c_ext, the densest step's, in every frame.
    let smoke = "medium = { albedo = 0.9, g = 0.3 }\nsettings = { photons = 2000, samples = 1 }\n";
    let series = frames(&load(scene_text("s.pvd", "smoke", smoke)));
    let notes: Vec<String> =
        series.iter().map(|f| f.stats.notes.iter().find(|n| n.contains("c_ext")).cloned().unwrap_or_default()).collect();
    assert!(
        notes.iter().all(|n| n == &notes[0] && n.contains("for every step, chosen from the series' densest step (3 of 3")),
        "{notes:?}"
    );
    // Each step alone chooses its own, and the series' is the smallest of them.
    let own: Vec<f64> = (0..3)
        .map(|k| {
            let alone = load(scene_text(&format!("s_{k}.vtp"), "smoke", smoke));
            let f = render_view(&alone, &alone.camera(None).unwrap(), (40, 32), &RenderCache::default()).unwrap();
            let note = f.stats.notes.iter().find(|n| n.contains("c_ext chosen from the data")).unwrap().clone();
            note.split("data: ").nth(1).unwrap().split_whitespace().next().unwrap().parse().unwrap()
        })
        .collect();
    assert!(own[0] > 1.2 * own[2], "the steps' own c_ext differ: {own:?}");
    let series_c: f64 = notes[0].split("c_ext ").nth(1).unwrap().split_whitespace().next().unwrap().parse().unwrap();
    let smallest = own.iter().cloned().fold(f64::INFINITY, f64::min);
    assert!((series_c - smallest).abs() <= 1e-6 * smallest, "{series_c} vs the steps' {own:?}");
    let per_step = frames(&load(scene_text("s.pvd", "smoke", &format!("{smoke}scale_over = \"step\"\n"))));
    assert!(per_step.iter().all(|f| f.stats.notes.iter().any(|n| n.contains("c_ext chosen from the data"))));
}
