//! `volterra bench frames`: an animation's throughput. The built-in plume series (24
//! steps by default, written by `samples::write_plume_series`) with an orbiting camera at
//! 500×500 is rendered by this executable as users run it — `render --frames` in one
//! process on every core, then two `--shard K/2` processes side by side with one render
//! thread each — for each renderer asked for; frames per minute for both, and whether the
//! shards' frames equal the serial ones bit for bit. For smoke, also the first frame of one
//! step (photons traced, the photon cache empty) against a second view of the same
//! particles (photons from the cache).

use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

pub struct FramesBench {
    pub env: super::BenchEnv,
    pub steps: usize,
    pub particles: usize,
    pub width: usize,
    pub height: usize,
    /// "points", "smoke", or both.
    pub renderers: Vec<String>,
    pub json: bool,
}

/// The scene: the series, orbiting once over the animation, drawn by `renderer`.
fn scene_text(renderer: &str, w: usize, h: usize) -> String {
    let node = match renderer {
        "smoke" => "renderer = \"smoke\"\nmedium = { c_ext = 10.0, albedo = 0.9, g = 0.3 }\nsettings = { photons = 50000, samples = 2 }\n",
        _ => "renderer = \"points\"\ncolor_by = \"temperature\"\nsettings = { colormap = \"coolwarm\" }\n",
    };
    format!(
        "[image]\nwidth = {w}\nheight = {h}\nbackground = [0.02, 0.02, 0.03]\n\
         [camera]\nposition = [0.5, -1.6, 0.5]\nfocal_point = [0.5, 0.5, 0.48]\nview_up = [0.0, 0.0, 1.0]\nview_angle = 35.0\n\
         [orbit]\naxis = [0.0, 0.0, 1.0]\ndegrees = 360.0\n\
         [[light]]\nkind = \"directional\"\ndirection = [-1.0, 0.6, -0.5]\nintensity = 3.0\n\
         [[node]]\nname = \"plume\"\nkind = \"particles\"\nfile = \"series/plume.pvd\"\n{node}"
    )
}

/// The frame files a render wrote into `dir`, sorted.
fn frame_files(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut v: Vec<PathBuf> =
        std::fs::read_dir(dir)?.flatten().map(|e| e.path()).filter(|p| p.extension().is_some_and(|e| e == "exr")).collect();
    v.sort();
    Ok(v)
}

/// Runs `render SCENE -o OUT --frames [--shard K/M]` with `threads` render threads (None:
/// every core); returns the child to wait for.
fn spawn_render(
    scene: &Path,
    out: &Path,
    shard: Option<(usize, usize)>,
    threads: Option<usize>,
    cache: &Path,
) -> Result<std::process::Child> {
    let exe = std::env::current_exe().context("cannot find this executable")?;
    let mut cmd = Command::new(exe);
    cmd.arg("render").arg(scene).arg("-o").arg(out.join("f.exr")).arg("--frames");
    if let Some((k, m)) = shard {
        cmd.arg("--shard").arg(format!("{k}/{m}"));
    }
    if let Some(t) = threads {
        cmd.env("RAYON_NUM_THREADS", t.to_string());
    }
    cmd.env("VOLTERRA_CACHE_DIR", cache).stdout(std::process::Stdio::null()).stderr(std::process::Stdio::piped());
    cmd.spawn().context("cannot start the render")
}

fn wait(child: std::process::Child, what: &str) -> Result<()> {
    let out = child.wait_with_output()?;
    if !out.status.success() {
        bail!("{what} failed: {}", crate::child::last_line(&out.stderr));
    }
    Ok(())
}

#[derive(serde::Serialize)]
struct Row {
    renderer: String,
    frames: usize,
    serial_s: f64,
    serial_frames_per_minute: f64,
    shards_s: f64,
    shards_frames_per_minute: f64,
    shards_identical: bool,
    /// Smoke: one step's first view (photons traced) and a second view (cached), seconds.
    first_view_s: Option<f64>,
    second_view_s: Option<f64>,
    /// Smoke: the second view in the process that drew the first (its preparation kept).
    kept_view_s: Option<f64>,
}

pub fn run(b: &FramesBench) -> Result<()> {
    if b.steps < 2 || b.particles == 0 {
        bail!("--steps must be at least 2 and --particles at least 1");
    }
    let root = b.env.work_dir.join(format!("frames_{}x{}", b.steps, b.particles));
    let series = root.join("series");
    if !series.join("plume.pvd").exists() {
        volterra::samples::write_plume_series(&series, b.steps, b.particles)?;
    }
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut rows = Vec::new();
    for renderer in &b.renderers {
        if renderer != "points" && renderer != "smoke" {
            bail!("--renderer {renderer}: points or smoke");
        }
        let scene = root.join(format!("{renderer}.toml"));
        std::fs::write(&scene, scene_text(renderer, b.width, b.height))?;
        let dirs =
            ["serial", "shard0", "shard1", "cache-serial", "cache-shards", "cache-views"].map(|d| root.join(format!("{renderer}-{d}")));
        for d in &dirs {
            let _ = std::fs::remove_dir_all(d);
            std::fs::create_dir_all(d)?;
        }
        // A small frame first, so neither side pays for starting the GPU driver cold (Mesa
        // keeps compiled shaders on disk) or for reading the series' collection.
        let exe = std::env::current_exe()?;
        let warm = Command::new(&exe)
            .arg("render")
            .arg(&scene)
            .arg("-o")
            .arg(root.join("warm.exr"))
            .args(["--set", "image.width=16", "--set", "image.height=16"])
            .env("VOLTERRA_CACHE_DIR", &dirs[5])
            .stderr(std::process::Stdio::piped())
            .spawn()?;
        wait(warm, "the warm-up render")?;
        let _ = std::fs::remove_dir_all(&dirs[5]);
        eprintln!("{renderer}: {} frames serially on {cores} cores…", b.steps);
        let t = Instant::now();
        wait(spawn_render(&scene, &dirs[0], None, None, &dirs[3])?, "the serial render")?;
        let serial_s = t.elapsed().as_secs_f64();
        eprintln!("{renderer}: the same frames as 2 shards side by side, one thread each…");
        let t = Instant::now();
        let a = spawn_render(&scene, &dirs[1], Some((0, 2)), Some(1), &dirs[4])?;
        let c = spawn_render(&scene, &dirs[2], Some((1, 2)), Some(1), &dirs[4])?;
        wait(a, "shard 0/2")?;
        wait(c, "shard 1/2")?;
        let shards_s = t.elapsed().as_secs_f64();
        let serial = frame_files(&dirs[0])?;
        let mut sharded = frame_files(&dirs[1])?;
        sharded.extend(frame_files(&dirs[2])?);
        sharded.sort_by_key(|p| p.file_name().map(|n| n.to_os_string()));
        let names = |v: &[PathBuf]| v.iter().map(|p| p.file_name().map(|n| n.to_os_string())).collect::<Vec<_>>();
        let mut identical = names(&serial) == names(&sharded);
        for (s, h) in serial.iter().zip(&sharded) {
            identical &= std::fs::read(s)? == std::fs::read(h)?;
        }
        let (first_view_s, second_view_s, kept_view_s) = if renderer == "smoke" { views(&scene, &dirs[5])? } else { (None, None, None) };
        let n = serial.len();
        rows.push(Row {
            renderer: renderer.clone(),
            frames: n,
            serial_s,
            serial_frames_per_minute: 60.0 * n as f64 / serial_s,
            shards_s,
            shards_frames_per_minute: 60.0 * n as f64 / shards_s,
            shards_identical: identical,
            first_view_s,
            second_view_s,
            kept_view_s,
        });
    }
    if b.json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
    }
    let mut report = super::report::Report::new("frames", TABLES);
    report.line(format!(
        "The built-in plume series, {} steps of up to {} particles, orbiting camera, {}×{}, {cores} cores; \
         the same frames serially (all cores) and as 2 shards side by side (one thread each), compared bit for bit.",
        b.steps, b.particles, b.width, b.height
    ));
    let mut table = super::report::Table::new(COLUMNS);
    let mut views = Vec::new();
    for r in &rows {
        table.row(vec![
            r.renderer.to_string(),
            r.frames.to_string(),
            format!("{:.1}", r.serial_s),
            format!("{:.1}", r.serial_frames_per_minute),
            format!("{:.1}", r.shards_s),
            format!("{:.1}", r.shards_frames_per_minute),
            r.shards_identical.to_string(),
        ]);
        if let (Some(a), Some(c), Some(k)) = (r.first_view_s, r.second_view_s, r.kept_view_s) {
            views.push(format!(
                "{}, one step: first view {a:.2} s (photons traced); a second view {c:.2} s in a new process (photons \
                 cached on disk: {:.1}× faster), {k:.2} s in the same one (medium, photons and grids kept: {:.1}× faster).",
                r.renderer,
                a / c,
                a / k
            ));
        }
    }
    report.table(table);
    for v in views {
        report.line(v);
    }
    report.finish(b.json, b.env.markdown.as_deref())
}

/// The columns of the bench's table.
const COLUMNS: &[&str] = &["renderer", "frames", "serial s", "serial frames/min", "2 shards s", "2 shards frames/min", "identical"];
pub const TABLES: &[&[&str]] = &[COLUMNS];

/// Smoke: the middle step drawn from two camera angles, the photon cache empty before the
/// first: the seconds of the first view, of the second in a fresh process's state (a new
/// render cache: photons from the disk cache) and of the second in the first's (its
/// preparation kept).
fn views(scene_path: &Path, cache: &Path) -> Result<(Option<f64>, Option<f64>, Option<f64>)> {
    // The cache directory is read from the environment when photons are stored and loaded.
    std::env::set_var("VOLTERRA_CACHE_DIR", cache);
    let scene = volterra::scene::Scene::load(scene_path, &[])?;
    let times = scene.timeline();
    let scene = scene.at_time(times[times.len() / 2]);
    let (w, h) = (scene.file.image.width, scene.file.image.height);
    let cache_mem = volterra::render::RenderCache::default();
    let mut cam = scene.file.camera.clone();
    let t = Instant::now();
    let first = volterra::render::render_view(&scene, &cam, (w, h), &cache_mem)?;
    let first_s = t.elapsed().as_secs_f64();
    cam.position = [0.5 + 2.1 * 0.3f64.sin(), 0.5 - 2.1 * 0.3f64.cos(), 0.5];
    let t = Instant::now();
    let second = volterra::render::render_view(&scene, &cam, (w, h), &volterra::render::RenderCache::default())?;
    let second_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let kept = volterra::render::render_view(&scene, &cam, (w, h), &cache_mem)?;
    let kept_s = t.elapsed().as_secs_f64();
    let hit = |f: &volterra::render::Frame| f.stats.counter("photon cache hit") == Some(1.0);
    if hit(&first) || !hit(&second) {
        bail!("the photon cache did not behave: first view hit {}, second view hit {}", hit(&first), hit(&second));
    }
    if kept.stats.counter("earlier views of this preparation") != Some(1.0) {
        bail!("the render cache did not keep the smoke preparation for the second view");
    }
    if kept.rgba != second.rgba {
        bail!("the second view differs with the preparation kept");
    }
    Ok((Some(first_s), Some(second_s), Some(kept_s)))
}
