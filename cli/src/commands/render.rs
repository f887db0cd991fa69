//! `render`: one frame, or an animation's frames (a shard of them, resumed), written
//! atomically as EXR and PNG.

use crate::verbosity;
use anyhow::{bail, Result};
use std::path::{Path, PathBuf};
use volterra::scene::animation::{self, Shard};
use volterra::scene::{Camera, Scene};
use volterra::{info, render};
use volterra_formats::{self as formats, Limits};

pub(crate) fn cmd_render(scene_path: &Path, output: &Path, png: Option<&Path>, sets: &[String], limits: Limits) -> Result<()> {
    check_render_outputs(output, png)?;
    let scene = Scene::load(scene_path, sets)?.with_limits(limits);
    let camera = scene.camera(None)?;
    // A DEM larger than memory allows is read only where the camera sees it.
    let scene = scene.with_views(std::slice::from_ref(&camera))?;
    write_frame(&scene, &camera, true, output, png, &render::RenderCache::default())
}

/// Renders one frame seen by `camera` with what `cache` kept from earlier frames, and
/// writes it; `report` prints its statistics and each node's times.
pub(crate) fn write_frame(
    scene: &Scene,
    camera: &Camera,
    report: bool,
    output: &Path,
    png: Option<&Path>,
    cache: &render::RenderCache,
) -> Result<()> {
    let image = render::render_view(scene, camera, (scene.file.image.width, scene.file.image.height), cache)?;
    if report {
        let counters: Vec<String> = image.stats.counters.iter().map(|(k, v)| format!("{k} {}", short(*v))).collect();
        say!("{}: {}", image.stats.renderer, counters.join(", "));
        for n in &image.stats.notes {
            say!("  {n}");
        }
        for t in &image.stats.nodes {
            say!("node '{}' ({}): load {:.3} s, preparation {:.3} s, render {:.3} s", t.node, t.renderer, t.load, t.prepare, t.render);
        }
    }
    let (bg, exposure) = (scene.file.image.background, scene.file.image.exposure);
    match output_format(output)? {
        OutputFormat::Exr => formats::exr_io::write_exr(output, &image.to_image(bg))?,
        OutputFormat::Png => formats::image::write_png_preview(output, image.width, image.height, &image.preview_rgba(bg, exposure))?,
    }
    if let Some(p) = png {
        formats::image::write_png_preview(p, image.width, image.height, &image.preview_rgba(bg, exposure))?;
    }
    Ok(())
}

/// What a rendered image is written as: decided by the output's extension, never assumed.
#[derive(Clone, Copy, PartialEq)]
pub(crate) enum OutputFormat {
    Exr,
    Png,
}

pub(crate) fn output_format(path: &Path) -> Result<OutputFormat> {
    match path.extension().map(|e| e.to_string_lossy().to_ascii_lowercase()).as_deref() {
        Some("exr") => Ok(OutputFormat::Exr),
        Some("png") => Ok(OutputFormat::Png),
        _ => bail!("{}: unsupported output format (render writes .exr or .png)", path.display()),
    }
}

/// A render's outputs, checked before any work: a format the extension names, directories
/// that exist.
pub(crate) fn check_render_outputs(output: &Path, png: Option<&Path>) -> Result<()> {
    output_format(output)?;
    check_output_dir(output)?;
    png.map_or(Ok(()), check_output_dir)
}

/// Refuses an output whose directory does not exist before any work is done (the atomic
/// writer would otherwise fail at the end with a bare "No such file or directory").
pub(crate) fn check_output_dir(path: &Path) -> Result<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        if !dir.is_dir() {
            bail!("{}: the output directory {} does not exist", path.display(), dir.display());
        }
    }
    Ok(())
}

/// `out.exr` → `out_0007.exr`.
pub(crate) fn numbered(path: &Path, k: usize) -> PathBuf {
    let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let name = match path.extension() {
        Some(ext) => format!("{stem}_{k:04}.{}", ext.to_string_lossy()),
        None => format!("{stem}_{k:04}"),
    };
    path.with_file_name(name)
}

/// What `render --frames` renders: the animation's frames (`count` None: one per
/// timestep, or the orbit's), the shard's share of them, skipping finished ones.
pub(crate) struct FrameJob {
    pub(crate) count: Option<usize>,
    pub(crate) shard: Shard,
    pub(crate) resume: bool,
}

pub(crate) fn cmd_render_frames(
    scene_path: &Path,
    output: &Path,
    png: Option<&Path>,
    sets: &[String],
    job: FrameJob,
    limits: Limits,
) -> Result<()> {
    check_render_outputs(output, png)?;
    let scene = Scene::load(scene_path, sets)?.with_limits(limits);
    let frames = animation::frames(&scene, job.count)?;
    let outputs = |k: usize| (numbered(output, k), png.map(|p| numbered(p, k)));
    let mine: Vec<_> = frames.iter().filter(|f| job.shard.takes(f.index)).collect();
    // Outputs are renamed into place when complete, so one that exists is finished.
    let done = |k: usize| {
        let (o, p) = outputs(k);
        o.is_file() && p.is_none_or(|p| p.is_file())
    };
    let todo: Vec<animation::AnimationFrame> = mine.iter().filter(|f| !(job.resume && done(f.index))).map(|f| **f).collect();
    // A DEM larger than memory allows is read only where this task's frames see it (a
    // walk's cameras stand on the ground read: `with_views` leaves such a scene as it is).
    let scene = if scene.file.walk.is_none() {
        let cameras = todo.iter().map(|f| scene.camera_at(Some(*f))).collect::<Result<Vec<_>>>()?;
        scene.with_views(&cameras)?
    } else {
        scene
    };
    let shard = if job.shard == Shard::ALL { String::new() } else { format!("task {} of {}: ", job.shard.index, job.shard.of) };
    say!(
        "{shard}{} of the animation's {} frames to render{}",
        todo.len(),
        frames.len(),
        if todo.len() < mine.len() { format!(" ({} already written)", mine.len() - todo.len()) } else { String::new() }
    );
    let bar = crate::progress::bar(todo.len() as u64, "frames");
    // One cache for every frame: shear-warp's preparation and the terrain's pyramid are
    // built once, not per frame; a series' steps are read as frames reach them, and what
    // was read and prepared for a step is dropped once no frame draws it.
    let cache = render::RenderCache::default();
    let mut current = scene;
    let mut seconds = Vec::with_capacity(todo.len());
    for f in &todo {
        let t = std::time::Instant::now();
        if let Some(time) = f.time {
            current = current.at_time(time);
            cache.keep_only_for(&current);
        }
        let camera = current.camera_at(Some(*f))?;
        let (o, p) = outputs(f.index);
        write_frame(&current, &camera, verbosity::verbose(), &o, p.as_deref(), &cache)?;
        seconds.push(t.elapsed().as_secs_f64());
        bar.inc(1);
        if !crate::progress::on_terminal() || verbosity::verbose() {
            // A log (a Slurm task's): a line per frame.
            let time = f.time.map(|t| format!(" (time {})", info::num(t))).unwrap_or_default();
            say!("frame {}{time}: {} in {:.2} s", f.index, o.display(), seconds[seconds.len() - 1]);
        }
    }
    bar.finish_and_clear();
    if let (Some(first), Some(last)) = (todo.first(), todo.last()) {
        let first_s = seconds[0];
        seconds.sort_by(f64::total_cmp);
        say!(
            "wrote {} frame{}: {} … {} (first {:.3} s, median {:.3} s per frame)",
            todo.len(),
            if todo.len() == 1 { "" } else { "s" },
            outputs(first.index).0.display(),
            outputs(last.index).0.display(),
            first_s,
            seconds[seconds.len() / 2]
        );
    }
    Ok(())
}

/// A statistic for a one-line summary: integers as such, others to 4 significant digits
/// (a c_ext of 3.2e-6 in code units printed "0.0000" with 4 decimals).
pub(crate) fn short(v: f64) -> String {
    if !v.is_finite() || (v.fract() == 0.0 && v.abs() < 1e15) {
        return format!("{v:.0}");
    }
    let magnitude = v.abs().log10().floor() as i32;
    if !(-3..6).contains(&magnitude) {
        return format!("{v:.3e}");
    }
    format!("{v:.*}", (3 - magnitude).max(0) as usize)
}
