//! The command line as a user meets it: JSON info, errors, render and compare.

mod common;

use common::repo_path;
use std::process::Command;

fn volterra(args: &[&str]) -> std::process::Output {
    Command::new(common::volterra_bin()).args(args).output().unwrap()
}

#[test]
fn info_json_reports_volume_geometry() {
    let p = repo_path("tests/fixtures/nifti/scaled.nii");
    let out = volterra(&["info", "--json", p.to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["kind"], "volume");
    assert_eq!(v["dims"], serde_json::json!([5, 4, 3]));
    assert_eq!(v["dtype"], "i16");
    assert_eq!(v["rescale"]["slope"], 0.5);
    assert_eq!(v["affine"][0][0], -1.5);
    assert_eq!(v["affine"][3], serde_json::json!([0.0, 0.0, 0.0, 1.0]));
}

#[test]
fn info_lists_series_of_a_multi_series_directory() {
    let p = repo_path("tests/fixtures/dicom/two_series");
    let out = volterra(&["info", "--json", p.to_str().unwrap()]);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["series"].as_array().unwrap().len(), 2);
    assert_eq!(v["series"][1]["uid"], "1.2.3.4.302");
}

#[test]
fn bad_inputs_give_one_line_errors_and_exit_1() {
    let dir = tempfile::tempdir().unwrap();
    let garbage = dir.path().join("garbage.nii");
    std::fs::write(&garbage, b"this is not a nifti header at all").unwrap();
    let huge = dir.path().join("huge.nii");
    // A valid NIfTI-1 header declaring 30000^3 voxels of f64 and no data.
    let mut h = vec![0u8; 352];
    h[0..4].copy_from_slice(&348i32.to_le_bytes());
    for (i, d) in [3i16, 30000, 30000, 30000, 1, 1, 1, 1].iter().enumerate() {
        h[40 + 2 * i..42 + 2 * i].copy_from_slice(&d.to_le_bytes());
    }
    h[70..72].copy_from_slice(&64i16.to_le_bytes());
    h[72..74].copy_from_slice(&64i16.to_le_bytes());
    h[108..112].copy_from_slice(&352f32.to_le_bytes());
    h[344..348].copy_from_slice(b"n+1\0");
    std::fs::write(&huge, &h).unwrap();
    let cases: Vec<(String, &str)> = vec![
        (garbage.display().to_string(), "not a NIfTI file"),
        (huge.display().to_string(), "memory limit"),
        (dir.path().join("absent.nii").display().to_string(), "no such file"),
        (repo_path("tests/fixtures/dicom/missing_slice").display().to_string(), "missing"),
        (dir.path().join("x.xyz").display().to_string(), "no such file"),
    ];
    for (path, want) in cases {
        let out = volterra(&["info", &path]);
        assert_eq!(out.status.code(), Some(1), "{path}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(err.trim_end().lines().count(), 1, "{err}");
        assert!(err.contains(&path) || err.contains(path.rsplit('/').next().unwrap()), "{err}");
        assert!(err.contains(want), "{path}: {err}");
    }
    let out = volterra(&["--max-memory", "100", "info", repo_path("tests/fixtures/nifti/f64_nifti1.nii").to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("memory limit is 100 B"));
}

#[test]
fn render_then_compare_with_itself_and_with_a_coarser_render() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = volterra(&["samples", d.to_str().unwrap()]);
    assert!(out.status.success());
    let scene = d.join("angio.toml");
    let fine = d.join("fine.exr");
    let coarse = d.join("coarse.exr");
    let png = d.join("fine.png");
    let sets = ["--set", "image.width=48", "--set", "image.height=48"];
    let mut args = vec!["render", scene.to_str().unwrap(), "-o", fine.to_str().unwrap(), "--png", png.to_str().unwrap()];
    args.extend_from_slice(&sets);
    assert!(volterra(&args).status.success());
    let mut args = vec!["render", scene.to_str().unwrap(), "-o", coarse.to_str().unwrap(), "--set", "node.phantom.settings.step=1.0"];
    args.extend_from_slice(&sets);
    assert!(volterra(&args).status.success());
    assert!(png.exists());
    let same: serde_json::Value =
        serde_json::from_slice(&volterra(&["compare", fine.to_str().unwrap(), fine.to_str().unwrap(), "--json"]).stdout).unwrap();
    assert_eq!(same["overall"]["rmse"], 0.0);
    let diff: serde_json::Value =
        serde_json::from_slice(&volterra(&["compare", coarse.to_str().unwrap(), fine.to_str().unwrap(), "--json"]).stdout).unwrap();
    let rel = diff["overall"]["relative_rmse"].as_f64().unwrap();
    // A step of one voxel instead of 0.1 changes the image, but not beyond recognition.
    assert!(rel > 1e-4 && rel < 0.2, "relative RMSE {rel}");
    let img = volterra_formats::exr_io::read_exr(&fine, &Default::default()).unwrap();
    for c in ["R", "G", "B", "A", "Z"] {
        assert!(img.channel(c).is_some(), "channel {c}");
    }
    assert!(img.channel("A").unwrap().iter().any(|&a| a > 0.5), "the phantom is visible");
}

/// `render --frames N` writes N numbered EXR and PNG files along the keyframes (needs the
/// GPU for the terrain: lavapipe in CI).
#[test]
fn render_frames_writes_a_numbered_sequence() {
    if common::gpu().is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    assert!(volterra(&["samples", d.to_str().unwrap()]).status.success());
    let scene = d.join("terrain_walk.toml");
    let out = d.join("walk.exr");
    let png = d.join("walk.png");
    let o = volterra(&[
        "render",
        scene.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--png",
        png.to_str().unwrap(),
        "--frames",
        "3",
        "--set",
        "image.width=64",
        "--set",
        "image.height=36",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for k in 0..3 {
        assert!(d.join(format!("walk_{k:04}.exr")).exists() && d.join(format!("walk_{k:04}.png")).exists(), "frame {k}");
        let img = volterra_formats::exr_io::read_exr(&d.join(format!("walk_{k:04}.exr")), &Default::default()).unwrap();
        assert!(img.channel("steps").is_some());
        assert!(img.channel("A").unwrap().iter().any(|&a| a > 0.5), "frame {k} sees the ground");
    }
    assert!(!d.join("walk_0003.exr").exists());
    // A scene without keyframes: a clear error.
    let o = volterra(&["render", d.join("terrain.toml").to_str().unwrap(), "-o", out.to_str().unwrap(), "--frames", "2"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("keyframe"));
}

/// `[image] exposure` brightens the PNG preview by 2^exposure and leaves the EXR linear.
#[test]
fn exposure_scales_the_png_preview_and_not_the_exr() {
    let dir = tempfile::tempdir().unwrap();
    volterra::samples::write_samples(dir.path()).unwrap();
    let scene = dir.path().join("smoke_series.toml");
    let render = |exposure: &str, name: &str| {
        let (exr, png) = (dir.path().join(format!("{name}.exr")), dir.path().join(format!("{name}.png")));
        let out = volterra(&[
            "render",
            scene.to_str().unwrap(),
            "-o",
            exr.to_str().unwrap(),
            "--png",
            png.to_str().unwrap(),
            "--set",
            &format!("image.exposure={exposure}"),
            "--set",
            "image.width=40",
            "--set",
            "image.height=40",
        ]);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        (std::fs::read(&exr).unwrap(), volterra_formats::image::decode_png(&png, &Default::default(), 0).unwrap())
    };
    let (exr0, png0) = render("0.0", "plain");
    let (exr1, png1) = render("1.0", "bright");
    assert_eq!(exr0, exr1, "the EXR stays linear");
    let linear = |v: u16| {
        let c = v as f64 / 255.0;
        if c <= 0.04045 {
            c / 12.92
        } else {
            ((c + 0.055) / 1.055).powf(2.4)
        }
    };
    let mut compared = 0;
    for (a, b) in png0.samples.iter().zip(&png1.samples) {
        let (a, b) = (linear(*a), linear(*b));
        // Unclipped, away from the 8-bit steps near black: twice as bright.
        if a > 0.02 && 2.0 * a < 0.95 {
            assert!((b / a - 2.0).abs() < 0.12, "{a} → {b}");
            compared += 1;
        }
    }
    assert!(compared > 100, "{compared} samples compared");
    let bad =
        volterra(&["render", scene.to_str().unwrap(), "-o", dir.path().join("x.exr").to_str().unwrap(), "--set", "image.exposure=99"]);
    assert!(String::from_utf8_lossy(&bad.stderr).contains("exposure 99 must be a number of stops"));
}

/// `info` reads a GeoTIFF by rows (never held, so a DEM larger than memory is described at
/// full resolution): every GeoTIFF elevation fixture and the real DEMs describe themselves
/// exactly as the raster read whole does — dims, georeferencing, corners, range, NoData
/// count, attributes, notes — in JSON and in text.
#[test]
fn info_of_a_geotiff_read_by_rows_equals_the_raster_read_whole() {
    let mut files: Vec<std::path::PathBuf> = std::fs::read_dir(repo_path("tests/fixtures/geotiff"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "tif"))
        .collect();
    if let Some(shared) = common::shared_data() {
        files.extend(
            std::fs::read_dir(shared.join("terrain"))
                .unwrap()
                .map(|e| e.unwrap().path())
                .filter(|p| p.extension().is_some_and(|e| e == "tif")),
        );
    }
    files.sort();
    let limits = volterra_formats::Limits::default();
    let (mut compared, mut with_nodata) = (0, 0);
    for file in &files {
        let name = file.display().to_string();
        // Drapes (RGB) and the like are refused by both; only elevation rasters compare.
        let Ok(whole) = volterra_formats::geotiff::read_geotiff(file, &limits) else {
            let out = volterra(&["info", "--json", &name]);
            assert!(!out.status.success(), "{name}: refused whole, described by rows");
            continue;
        };
        let out = volterra(&["info", "--json", &name]);
        assert!(out.status.success(), "{name}: {}", String::from_utf8_lossy(&out.stderr));
        let by_rows: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        // Through JSON text on both sides, so NaN and float formatting match.
        let held: serde_json::Value = serde_json::from_str(&volterra::info::heightfield_json(&whole).to_string()).unwrap();
        assert_eq!(by_rows, held, "{name}: JSON");
        let text = volterra(&["info", &name]);
        let held_text = volterra::info::dataset_text(&volterra_formats::Dataset::Heightfield(whole.clone()), &Default::default(), false);
        assert_eq!(String::from_utf8_lossy(&text.stdout), held_text, "{name}: text");
        compared += 1;
        with_nodata += usize::from(whole.nodata_count() > 0);
    }
    assert!(compared >= 10 && with_nodata >= 2, "{compared} rasters compared, {with_nodata} with NoData");
}

/// `--max-memory` holds for every reader: `info` on every data file of the fixtures and of
/// ../shared/data, under limits from 1 MiB to 64 MiB, either reads it within the limit or
/// refuses it with the one-line reason — never passes the limit (the binary's counting
/// allocator reports "over the limit" when it does). Readers once counted only what they
/// returned, not the file, the decoder's buffers and the copies held beside it.
#[test]
fn info_never_passes_the_memory_limit_it_is_given() {
    let mut inputs: Vec<std::path::PathBuf> = Vec::new();
    let mut roots = vec![repo_path("tests/fixtures")];
    roots.extend(common::shared_data());
    let data_file = |p: &std::path::Path| {
        let name = p.file_name().unwrap().to_string_lossy().to_ascii_lowercase();
        [".nii", ".nii.gz", ".hdr", ".tif", ".png", ".vtp", ".vtu", ".vti", ".vtk", ".mha", ".mhd", ".nrrd", ".nhdr", ".dcm", ".pvd"]
            .iter()
            .any(|e| name.ends_with(e))
    };
    fn walk(dir: &std::path::Path, out: &mut Vec<std::path::PathBuf>, keep: &dyn Fn(&std::path::Path) -> bool) {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                // A DICOM series directory is read as one volume, too.
                if std::fs::read_dir(&p).unwrap().any(|f| f.unwrap().path().extension().is_some_and(|x| x == "dcm")) {
                    out.push(p.clone());
                }
                walk(&p, out, keep);
            } else if keep(&p) {
                out.push(p);
            }
        }
    }
    for root in &roots {
        walk(root, &mut inputs, &data_file);
    }
    inputs.sort();
    let mut over = Vec::new();
    let (mut read, mut refused) = (0, 0);
    for limit in ["1M", "2M", "4M", "8M", "16M", "32M", "64M"] {
        for p in &inputs {
            let out = volterra(&["info", "--max-memory", limit, p.to_str().unwrap()]);
            let stderr = String::from_utf8_lossy(&out.stderr);
            if stderr.contains("over the limit") {
                over.push(format!("{limit} {}: {}", p.display(), stderr.lines().last().unwrap_or_default()));
            }
            match out.status.success() {
                true => read += 1,
                false => refused += usize::from(stderr.contains("memory limit")),
            }
        }
    }
    assert!(over.is_empty(), "{} of {} runs passed the limit:\n{}", over.len(), inputs.len() * 7, over.join("\n"));
    assert!(inputs.len() > 60 && read > 300 && refused > 50, "{} inputs: {read} read, {refused} refused for memory", inputs.len());
}

/// `volterra render` hands its cameras to the scene before reading (issue 20): a DEM whose
/// whole raster passes `--max-memory` renders one frame, and an animation's frames, from
/// the window they see — refused before, as it still is where the view takes in the whole.
#[test]
fn render_reads_only_the_window_its_cameras_see_of_a_dem_beyond_the_memory_limit() {
    let dir = tempfile::tempdir().unwrap();
    // 1200 × 900 float32 samples: 4.3 MB.
    common::view_window_dem(&dir.path().join("dem.tif"));
    let scene = dir.path().join("view.toml");
    let keyframes = r#"
[[keyframe]]
position = [26000.0, 1500.0, 3000.0]
focal_point = [29000.0, 6000.0, 300.0]
[[keyframe]]
position = [27000.0, 2500.0, 3000.0]
focal_point = [30000.0, 7000.0, 300.0]
"#;
    let text = format!("{}{keyframes}", common::view_window_scene(48, 32));
    std::fs::write(&scene, text).unwrap();
    let (scene, out) = (scene.to_str().unwrap(), dir.path().join("f.exr"));
    let one = volterra(&["--max-memory", "4M", "render", scene, "-o", out.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&one.stderr);
    assert!(one.status.success() && err.contains("read only what the views see"), "{err}");
    let frames = volterra(&["--max-memory", "4M", "render", scene, "-o", out.to_str().unwrap(), "--frames", "3"]);
    assert!(frames.status.success(), "{}", String::from_utf8_lossy(&frames.stderr));
    assert!((0..3).all(|k| dir.path().join(format!("f_{k:04}.exr")).is_file()));
    // Looking down on the whole DEM from far above: the whole is seen, and refused.
    let wide = volterra(&[
        "--max-memory",
        "4M",
        "render",
        scene,
        "-o",
        out.to_str().unwrap(),
        "--set",
        "camera.position=[18000.0, 13500.0, 90000.0]",
        "--set",
        "camera.focal_point=[18000.0, 13500.0, 0.0]",
        "--set",
        "camera.view_up=[0.0, 1.0, 0.0]",
    ]);
    let err = String::from_utf8_lossy(&wide.stderr);
    assert!(!wide.status.success() && err.contains("dem.tif") && err.contains("memory limit"), "{err}");
}

/// `--version` names the commit the binary was built from, as `git rev-parse` does for this
/// checkout (or says it is unknown outside one).
#[test]
fn version_names_the_commit_it_was_built_from() {
    let out = volterra(&["--version"]);
    assert!(out.status.success());
    let line = String::from_utf8(out.stdout).unwrap();
    assert!(line.starts_with(&format!("volterra {} (", env!("CARGO_PKG_VERSION"))), "{line}");
    let head = Command::new("git").args(["rev-parse", "--short=12", "HEAD"]).current_dir(repo_path(".")).output().ok();
    match head.filter(|o| o.status.success()) {
        Some(o) => {
            let commit = String::from_utf8(o.stdout).unwrap();
            assert!(
                line.contains(&format!("commit {}", commit.trim())),
                "{line} should name HEAD {commit} (rebuild the binary after committing)"
            );
        }
        None => assert!(line.contains("unknown commit"), "{line}"),
    }
}

/// Shell completions and manual pages, generated from the same command definitions as
/// `--help`: every command is in them.
#[test]
fn completions_and_manual_pages_cover_every_command() {
    let commands = ["info", "convert", "render", "view", "slurm", "movie", "demo", "bench", "dem", "compare", "completions", "man"];
    let bash = volterra(&["completions", "bash"]);
    assert!(bash.status.success());
    let bash = String::from_utf8(bash.stdout).unwrap();
    assert!(bash.contains("_volterra()") && bash.contains("complete -F _volterra"), "not a bash completion script");
    for c in commands {
        assert!(bash.contains(&format!("volterra,{c})")), "bash completion lacks {c}");
    }
    let zsh = String::from_utf8(volterra(&["completions", "zsh"]).stdout).unwrap();
    assert!(zsh.starts_with("#compdef volterra"), "{}", &zsh[..zsh.len().min(80)]);
    let fish = String::from_utf8(volterra(&["completions", "fish"]).stdout).unwrap();
    assert!(fish.contains("complete -c volterra") && fish.contains("-l max-memory"));
    let bad = volterra(&["completions", "tcsh"]);
    assert_eq!(bad.status.code(), Some(2), "an unknown shell is a usage error");

    let dir = tempfile::tempdir().unwrap();
    let out = volterra(&["man", dir.path().to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let page = |name: &str| std::fs::read_to_string(dir.path().join(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
    let main = page("volterra.1");
    assert!(main.starts_with(".ie") || main.contains(".TH volterra 1"), "not a roff page");
    for c in commands {
        let sub = page(&format!("volterra-{c}.1"));
        assert!(sub.contains(&format!(".TH volterra-{c} 1")), "volterra-{c}.1 has no title");
        assert!(main.contains(&format!("volterra\\-{c}(1)")), "volterra.1 does not list {c}");
    }
    assert!(page("volterra-render.1").contains("\\-\\-output"), "the render page lacks its options");
    assert!(page("volterra-bench-clinical.1").contains("\\-\\-slices"), "nested commands get their own pages");
    let tmp: Vec<_> =
        std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).filter(|n| !n.to_string_lossy().ends_with(".1")).collect();
    assert!(tmp.is_empty(), "left behind: {tmp:?}");
}

/// -q leaves warnings and errors only on stderr, -v adds every frame's statistics and a
/// closing line; stdout (the command's output) is the same at every level; a usage error
/// exits 2.
#[test]
fn quiet_and_verbose_change_only_what_is_said_on_stderr() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let samples = d.join("samples");
    let quiet = volterra(&["-q", "samples", samples.to_str().unwrap()]);
    assert!(quiet.status.success());
    assert!(quiet.stderr.is_empty(), "-q samples said: {}", String::from_utf8_lossy(&quiet.stderr));
    let scene = samples.join("angio.toml");
    let render = |level: Option<&str>, out: &str| {
        let out = d.join(out);
        let mut args: Vec<&str> = level.into_iter().collect();
        args.extend([
            "render",
            scene.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--set",
            "image.width=48",
            "--set",
            "image.height=48",
        ]);
        let o = volterra(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        assert!(out.is_file());
        (String::from_utf8(o.stdout).unwrap(), String::from_utf8(o.stderr).unwrap(), std::fs::read(&out).unwrap())
    };
    let (out_n, err_n, exr_n) = render(None, "n.exr");
    let (out_q, err_q, exr_q) = render(Some("-q"), "q.exr");
    let (out_v, err_v, exr_v) = render(Some("--verbose"), "v.exr");
    assert!(err_n.contains("load") && err_n.contains("render"), "by default a render reports its node's times: {err_n}");
    assert_eq!(err_q, "", "-q render said something");
    // The same lines but for their timings, and the closing one.
    let words = |s: &str| s.lines().map(|l| l.chars().filter(|c| !c.is_ascii_digit()).collect::<String>()).collect::<Vec<_>>();
    let (said_n, said_v) = (words(&err_n), words(&err_v));
    assert!(
        said_v.len() == said_n.len() + 1 && said_v[..said_n.len()] == said_n[..],
        "-v says what the default says first:\n{err_v}\n---\n{err_n}"
    );
    let closing = err_v.lines().last().unwrap();
    assert!(closing.starts_with("volterra: done in ") && closing.contains("peak memory"), "{closing}");
    assert!(out_n == out_q && out_q == out_v, "stdout changed with the level");
    assert!(exr_n == exr_q && exr_q == exr_v, "the image changed with the level");

    let both = volterra(&["-q", "-v", "info", scene.to_str().unwrap()]);
    assert_eq!(both.status.code(), Some(2), "-q with -v is a usage error");
    let unknown = volterra(&["render", "--no-such-flag"]);
    assert_eq!(unknown.status.code(), Some(2));
    let missing = volterra(&["-q", "info", d.join("missing.nii").to_str().unwrap()]);
    assert_eq!(missing.status.code(), Some(1));
    let err = String::from_utf8(missing.stderr).unwrap();
    assert_eq!(err.lines().count(), 1, "errors are said under -q too, in one line: {err}");
}

/// The README's main job: `demo` renders every built-in scene into OUT and says so, as a
/// table or (`--json`) one object per scene whose files exist and have the scene's size.
#[test]
fn demo_renders_every_built_in_scene_and_reports_each() {
    let dir = tempfile::tempdir().unwrap();
    let out = volterra(&["-q", "demo", "--out", dir.path().to_str().unwrap(), "--json"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let rows: Vec<serde_json::Value> = serde_json::from_slice(&out.stdout).unwrap();
    let scenes: Vec<&str> = volterra::samples::SCENES.iter().map(|(name, _)| name.trim_end_matches(".toml")).collect();
    assert_eq!(rows.iter().map(|r| r["scene"].as_str().unwrap()).collect::<Vec<_>>(), scenes);
    for r in &rows {
        let (w, h) = (r["width"].as_u64().unwrap() as usize, r["height"].as_u64().unwrap() as usize);
        let png = volterra_formats::image::png_size(std::path::Path::new(r["png"].as_str().unwrap())).unwrap();
        assert_eq!(png, (w, h), "{}", r["scene"]);
        assert!(std::path::Path::new(r["exr"].as_str().unwrap()).is_file());
        assert!(r["seconds"].as_f64().unwrap() > 0.0 && !r["renderer"].as_str().unwrap().is_empty());
    }
}

#[test]
fn renderers_json_lists_what_the_markdown_tables_show() {
    let out = volterra(&["renderers", "--json"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let rows: Vec<serde_json::Value> = serde_json::from_slice(&out.stdout).unwrap();
    let markdown = String::from_utf8(volterra(&["renderers"]).stdout).unwrap();
    assert_eq!(rows.len(), volterra::catalog::RENDERERS.len());
    for (row, decl) in rows.iter().zip(volterra::catalog::RENDERERS) {
        assert_eq!(row["name"], decl.name);
        assert!(markdown.contains(&format!("### `{}`: draws `{}` nodes", decl.name, row["kind"].as_str().unwrap())));
        let settings = row["settings"].as_array().unwrap();
        assert_eq!(settings.len(), decl.settings.len(), "{}", decl.name);
        for (s, d) in settings.iter().zip(decl.settings) {
            assert_eq!(s["key"], d.key);
            // Every default is a value the declaration accepts for the key.
            let toml_value = match &s["default"] {
                serde_json::Value::Bool(b) => toml::Value::Boolean(*b),
                serde_json::Value::String(c) => toml::Value::String(c.clone()),
                serde_json::Value::Number(n) if n.is_i64() || n.is_u64() => toml::Value::Integer(n.as_i64().unwrap()),
                serde_json::Value::Number(n) => toml::Value::Float(n.as_f64().unwrap()),
                other => panic!("{}.{}: default {other}", decl.name, d.key),
            };
            assert_eq!(d.check(&toml_value), Ok((d.default)()), "{}.{} = {}", decl.name, d.key, s["default"]);
            assert!(markdown.contains(&format!("| `{}` |", d.key)));
        }
    }
    // One default renderer per node kind that is drawn.
    let defaults: Vec<&str> = rows.iter().filter(|r| r["default_for_kind"] == true).map(|r| r["kind"].as_str().unwrap()).collect();
    assert_eq!(defaults, ["volume", "heightfield", "particles"]);
}
