//! `volterra bench points`: N particles (the built-in plume, 1M by default) drawn as spheres
//! of their smoothing length, coloured by temperature, at 1920×1080 — by our points
//! renderer (wgpu; lavapipe where there is no GPU) and by VTK's vtkPointGaussianMapper
//! with pyvista's sphere look (OpenGL; Mesa's llvmpipe where there is no GPU), in the same
//! run. With `--style splats`: our Gaussian splats against VTK's own (its default shader,
//! emissive, scaled so its 3σ footprint is h as ours is). Each side's first frame counts from the particles in memory (ours) or the file (VTK:
//! reading the .vtp) to the frame read back; further frames turn the camera by half a degree
//! each and read the frame back.

use super::median;
use anyhow::{bail, Context, Result};
use std::path::Path;
use std::time::Instant;
use volterra::render::points::{self, Colormap, PointStyle, PointsInput, Settings};
use volterra::scene::Camera;

pub struct PointsBench {
    pub env: super::BenchEnv,
    pub count: usize,
    pub style: PointStyle,
    pub width: usize,
    pub height: usize,
    pub runs: usize,
    pub json: bool,
}

fn camera(step: usize) -> Camera {
    // 2.1 m in front of the plume (−y), turned about z by half a degree a step.
    let a = (0.5 * step as f64).to_radians();
    Camera {
        position: [0.5 + 2.1 * a.sin(), 0.5 - 2.1 * a.cos(), 0.5],
        focal_point: [0.5, 0.5, 0.48],
        view_up: [0.0, 0.0, 1.0],
        view_angle: 35.0,
        parallel_projection: false,
        parallel_scale: 1.0,
    }
}

pub fn run(b: &PointsBench) -> Result<()> {
    if b.count == 0 || b.runs == 0 {
        bail!("--count and --runs must be at least 1");
    }
    std::fs::create_dir_all(&b.env.work_dir)?;
    let t = Instant::now();
    let set = volterra::samples::smoke_plume(b.count, 3);
    let vtp = b.env.work_dir.join(format!("plume_points_{}.vtp", b.count));
    if !vtp.exists() {
        volterra_formats::vtk::write_vtp(&vtp, &set, &Default::default())?;
    }
    eprintln!("{} particles made and written in {:.1} s", b.count, t.elapsed().as_secs_f64());

    // Ours.
    let input =
        PointsInput { particles: &set, node_to_world: glam::DMat4::IDENTITY, color_by: Some("temperature"), range: None, spacing: None };
    // Spheres of h, as VTK's scale array h draws them (the default would be the spacing).
    let s =
        Settings { colormap: Colormap::Coolwarm, style: b.style, radius_of: volterra::render::points::RadiusOf::H, ..Default::default() };
    let t = Instant::now();
    let first = points::render(&input, &camera(0).rays(b.width, b.height), &s)?;
    let ours_first = 1000.0 * t.elapsed().as_secs_f64();
    let (mut ours, mut draw) = (Vec::with_capacity(b.runs), Vec::with_capacity(b.runs));
    for k in 1..=b.runs {
        let t = Instant::now();
        let f = points::render(&input, &camera(k).rays(b.width, b.height), &s)?;
        ours.push(1000.0 * t.elapsed().as_secs_f64());
        draw.push(f.stats.counter("GPU ms").unwrap_or(f64::NAN));
    }
    let draw_med = median(&mut draw.clone());
    let gpu_note = first.stats.notes.first().cloned().unwrap_or_default();
    volterra_formats::exr_io::write_exr(&b.env.work_dir.join("points_ours.exr"), &first.to_image([0.0; 3]))?;

    // VTK in its own process.
    let c = camera(0);
    let spec = serde_json::json!({
        "vtp": std::fs::canonicalize(&vtp)?, "width": b.width, "height": b.height, "runs": b.runs, "style": b.style.name(),
        "camera": {"position": c.position, "focal_point": c.focal_point, "view_up": c.view_up, "view_angle": c.view_angle},
        "image": b.env.work_dir.join("points_vtk.exr"),
    });
    let spec_path = b.env.work_dir.join("vtk_points.json");
    std::fs::write(&spec_path, spec.to_string())?;
    let vtk = run_vtk(&b.env.python, &b.env.scripts, &spec_path);

    let mut sorted = ours.clone();
    let ours_med = median(&mut sorted);
    let report = serde_json::json!({
        "particles": b.count, "style": b.style.name(), "image": [b.width, b.height],
        "ours": {"first_ms": ours_first, "ms": ours, "median_ms": ours_med, "draw_ms": draw, "gpu": gpu_note},
        "vtk": vtk.as_ref().ok(), "vtk_error": vtk.as_ref().err().map(|e| format!("{e:#}")),
    });
    if b.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    }
    let mut report = super::report::Report::new("points", TABLES);
    report.line(format!("{} particles as {} of their h, coloured by temperature, {}×{}.", b.count, b.style.name(), b.width, b.height));
    let mut table = super::report::Table::new(COLUMNS);
    table.row(vec![format!("volterra points ({gpu_note})"), format!("{ours_first:.0}"), format!("{ours_med:.1}")]);
    let vtk_line = match &vtk {
        Ok(v) => {
            let mut ms: Vec<f64> = v["ms"].as_array().cloned().unwrap_or_default().iter().filter_map(|x| x.as_f64()).collect();
            let vmed = median(&mut ms);
            table.row(vec![
                format!("VTK {} vtkPointGaussianMapper ({})", v["vtk"].as_str().unwrap_or(""), v["renderer"].as_str().unwrap_or("")),
                format!("{:.0}", v["first_ms"].as_f64().unwrap_or(f64::NAN)),
                format!("{vmed:.1}"),
            ]);
            format!("VTK's frame time over ours (above 1: volterra faster): {:.2}.", vmed / ours_med)
        }
        Err(e) => format!("VTK skipped: {e:#}"),
    };
    report.table(table);
    report.line(format!("Of volterra's frame, the GPU's draw (submit to done): {draw_med:.1} ms (median)."));
    report.line(vtk_line);
    report.finish(b.json, b.env.markdown.as_deref())
}

/// The columns of the bench's table.
const COLUMNS: &[&str] = &["renderer", "first frame ms", "frame ms (median)"];
pub const TABLES: &[&[&str]] = &[COLUMNS];

fn run_vtk(python: &Path, scripts: &Path, spec: &Path) -> Result<serde_json::Value> {
    let out = std::process::Command::new(python)
        .arg(scripts.join("vtk_points.py"))
        .arg(spec)
        .output()
        .with_context(|| format!("cannot run {}", python.display()))?;
    if !out.status.success() {
        bail!("vtk_points.py failed: {}", crate::child::last_line(&out.stderr));
    }
    let text = String::from_utf8_lossy(&out.stdout);
    let line = text.lines().rev().find(|l| l.starts_with('{')).context("vtk_points.py printed no result")?;
    Ok(serde_json::from_str(line)?)
}
