//! `volterra bench clinical`: a clinical-size CT (512 × 512 × N int16, the CT phantom of
//! `samples::ct_phantom`, written once as NIfTI) drawn as a radiologist opens it —
//! CT-AAA with Slicer's shading, perspective 30°, 512² — by shear-warp and by VTK's
//! fixed-point mapper in the same run. The first frame counts everything from the file:
//! ours reading the NIfTI, preparing and rendering; VTK's nibabel + numpy into a
//! vtkImageData and its first render (which builds its gradient tables). Further frames
//! orbit the camera (each a new view), and the viewer's previews while it moves (128²,
//! preview settings: a 4³-averaged copy of the volume, made by the first). Peak memory of each side after the phantom is written (ours: the
//! process's resident peak from there; VTK's: its process's peak). With `--error`, the
//! first view of each side against the reference ray caster's (rendered once, cached).
//! With `--curve`, speed against error: our configurations and VTK's (sample distances and
//! ImageSampleDistance), each its further frames' median against its first view's error,
//! in a table and a plot with the Pareto front marked (issue 45: bench honesty).

use super::median;
use super::report::{Report, Table};
use super::shear_warp::{dominance, mark_pareto, vtk_config_image, Row, VTK_CONFIGS};
use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};
use std::time::Instant;
use volterra::compare::{rgba_pixels, rgba_psnr, rgba_rel_rmse};
use volterra::render::{render_node_with, RenderCache};
use volterra::scene::presets::{Preset, ValueStats};
use volterra::scene::{Camera, Scene};

pub struct ClinicalBench {
    pub env: super::BenchEnv,
    /// Slices (N of 512 × 512 × N).
    pub slices: usize,
    /// Frames after the first (each from another direction).
    pub frames: usize,
    pub json: bool,
    /// Scene overrides for our side (`--set node.ct.settings.supersampling=1`), to see
    /// speed against quality at this size.
    pub sets: Vec<String>,
    /// Measure the first view of each side against the reference ray caster.
    pub error: bool,
    /// Draw speed against error (`--curve`, which implies `error`) into this PNG.
    pub curve: Option<PathBuf>,
}

/// The family every row of the curve belongs to (`Row::family`).
const FAMILY: &str = "perspective composite shaded";

/// Our configurations on the speed/error curve: the defaults, fixed ratios (intermediate
/// pixels per voxel of the base plane), one sample per slab and the nearest warp.
const OUR_CURVE: [(&str, &[&str]); 7] = [
    ("defaults", &[]),
    ("×1", &["node.ct.settings.supersampling=1"]),
    ("×1 1/slab", &["node.ct.settings.supersampling=1", "node.ct.settings.slab_samples=1"]),
    ("×1.5", &["node.ct.settings.supersampling=1.5"]),
    ("×2", &["node.ct.settings.supersampling=2"]),
    ("nearest warp", &["node.ct.settings.warp=nearest"]),
    ("×2 nearest warp", &["node.ct.settings.supersampling=2", "node.ct.settings.warp=nearest"]),
];

/// The camera directions of the frames: the first from the front (anterior, +y) and
/// right, then round; the table lies behind the patient.
fn view(k: usize, dist: f64) -> Camera {
    let a = (35.0 + 47.0 * k as f64).to_radians();
    let d = glam::DVec3::new(a.cos(), a.sin(), 0.35 + 0.1 * (k % 3) as f64).normalize() * dist;
    Camera {
        position: d.to_array(),
        focal_point: [0.0; 3],
        view_up: [0.0, 0.0, 1.0],
        view_angle: 30.0,
        parallel_projection: false,
        parallel_scale: 1.0,
    }
}

/// This process's peak resident memory since the last reset, bytes (Linux).
fn peak_rss() -> Option<u64> {
    super::proc_status_bytes("VmHWM:")
}

pub fn run(b: &ClinicalBench) -> Result<()> {
    if b.slices < 2 || b.slices > 2000 {
        bail!("--slices {} must lie in 2..=2000", b.slices);
    }
    std::fs::create_dir_all(&b.env.work_dir)?;
    let dims = [512usize, 512, b.slices];
    let nii = b.env.work_dir.join(format!("ct_phantom_512x512x{}.nii", b.slices));
    let stored_mib = (dims[0] * dims[1] * dims[2] * 2) as f64 / (1u64 << 20) as f64;
    let (tf, shading) = {
        let ct = volterra::samples::ct_phantom(dims[0], dims[1], dims[2]);
        if !nii.exists() {
            eprintln!("writing the {}×{}×{} CT phantom to {}", dims[0], dims[1], dims[2], nii.display());
            volterra_formats::nifti::write_nifti(&nii, &ct)?;
        }
        let preset = Preset::from_name("CT-AAA").map_err(anyhow::Error::msg)?;
        (preset.transfer_function(&ValueStats::of(&ct), 0.7), preset.shading().context("CT-AAA has shading")?)
    };
    // The scene both sides draw: the preset's points and shading written out.
    let dist = 1.15 * 260.0 / (15f64.to_radians().tan());
    let cam = view(0, dist);
    let scene_text = format!(
        "[image]\nwidth = 512\nheight = 512\n\n[camera]\n{}\n[[node]]\nname = \"ct\"\nkind = \"volume\"\nfile = \"{}\"\nrenderer = \"shear-warp\"\n\n[node.transfer_function]\n{}\n[node.shading]\n{}",
        toml::to_string(&cam)?,
        nii.file_name().unwrap().to_string_lossy(),
        toml::to_string(&tf)?,
        toml::to_string(&shading)?
    );
    let scene_path = b.env.work_dir.join(format!("ct_phantom_{}.toml", b.slices));
    std::fs::write(&scene_path, scene_text)?;

    // Ours: from the file to the first frame, then the further frames, in this process.
    // The resident peak is reset first (Linux: clear_refs 5), so it counts from here.
    let _ = std::fs::write("/proc/self/clear_refs", "5");
    let t = Instant::now();
    let scene = Scene::load(&scene_path, &b.sets)?.with_limits(b.env.limits);
    let cache = RenderCache::default();
    let mut first = render_node_with(&scene, 0, &cam, (512, 512), &cache)?.context("the node draws nothing")?;
    let first_ms = 1000.0 * t.elapsed().as_secs_f64();
    // Each frame's principal axis (shear-warp's `principal_axis` counter): a further frame
    // whose axis differs from the frame before turns to a new principal axis (where that
    // axis's copy may first be prepared): its time is said apart from the frames that
    // keep theirs (issue 45: bench honesty).
    let axis_of = |f: &volterra::render::Frame| f.stats.counter("principal_axis").map(|a| a as u8);
    let mut axes = vec![axis_of(&first)];
    let mut further = Vec::new();
    for k in 1..=b.frames {
        let t = Instant::now();
        let f = render_node_with(&scene, 0, &view(k, dist), (512, 512), &cache)?;
        further.push(1000.0 * t.elapsed().as_secs_f64());
        axes.push(f.as_ref().and_then(axis_of));
    }
    let turns: Vec<bool> = axes.windows(2).map(|w| w[0] != w[1]).collect();
    // The viewer's previews while the camera moves: a quarter of the size per side, each
    // renderer's preview settings (shear-warp: no supersampling, one sample per slab).
    let mut file = scene.file.clone();
    for (i, n) in file.nodes.iter_mut().enumerate() {
        if let Some(r) = scene.renderer(i) {
            volterra::settings::apply_preview(r.settings, &mut n.settings);
        }
    }
    let preview_scene = scene.edited(file)?;
    let mut previews = Vec::new();
    for k in 0..=b.frames {
        for step in 0..3 {
            // Small steps round each view, as a drag makes them.
            let mut c = view(k, dist);
            let p = glam::DMat3::from_rotation_z((2.0 * step as f64).to_radians()) * glam::DVec3::from(c.position);
            c.position = p.to_array();
            let t = Instant::now();
            render_node_with(&preview_scene, 0, &c, (128, 128), &cache)?;
            previews.push(1000.0 * t.elapsed().as_secs_f64());
        }
    }
    let ours_peak = peak_rss();
    let covered = first.rgba.iter().filter(|p| p[3] > 0.5).count();
    let first_rgba = std::mem::take(&mut first.rgba);
    drop((scene, preview_scene, cache, first));

    // VTK in its own process.
    // With --curve, VTK's further configurations follow in the same process (after its
    // peak is taken), each reading the file again.
    let configs: &[[f64; 2]] = if b.curve.is_some() { &VTK_CONFIGS } else { &[] };
    let spec = serde_json::json!({
        "scene": std::fs::canonicalize(&scene_path)?,
        "views": (0..=b.frames).map(|k| serde_json::json!({"position": view(k, dist).position,
            "image": b.env.work_dir.join(format!("vtk_clinical_{k}.exr"))})).collect::<Vec<_>>(),
        "configs": configs,
    });
    let spec_path = b.env.work_dir.join("vtk_clinical.json");
    std::fs::write(&spec_path, spec.to_string())?;
    let vtk = super::run_vtk_volume(&b.env, "--clinical", &spec_path);

    // The first view against the truth (after both sides' peaks were taken).
    let reference = if b.error { Some(reference_image(b, &scene_path, &cam)?) } else { None };
    let errors = if let Some(reference) = &reference {
        let vtk_first = b.env.work_dir.join("vtk_clinical_0.exr");
        let vtk_error = vtk
            .as_ref()
            .ok()
            .and_then(|_| volterra_formats::exr_io::read_exr(&vtk_first, &b.env.limits).ok())
            .map(|img| rgba_rel_rmse(&rgba_pixels(&img), reference));
        Some((rgba_rel_rmse(&first_rgba, reference), vtk_error))
    } else {
        None
    };
    // Speed against error: our configurations, then VTK's.
    let curve = match (&b.curve, &reference) {
        (Some(plot), Some(reference)) => {
            let mut rows = our_curve(b, &scene_path, dist, reference)?;
            match &vtk {
                Ok(v) => rows.extend(vtk_curve(b, v, reference)?),
                Err(e) => eprintln!("VTK's curve skipped: {e:#}"),
            }
            mark_pareto(&mut rows);
            let rows_path = b.env.work_dir.join("clinical_rows.json");
            std::fs::write(&rows_path, serde_json::to_string_pretty(&rows)?)?;
            super::plot(&b.env.python, &b.env.scripts, "plot_bench.py", &rows_path, plot, "plot");
            Some(rows)
        }
        _ => None,
    };

    let mut further_sorted = further.clone();
    let ours_further = median(&mut further_sorted);
    let mib = |b: Option<u64>| b.map(|v| format!("{:.0} MiB", v as f64 / (1u64 << 20) as f64)).unwrap_or_else(|| "-".into());
    let report = serde_json::json!({
        "volume": format!("{}×{}×{} int16, {:.0} MiB stored", dims[0], dims[1], dims[2], stored_mib),
        "ours": {"first_ms": first_ms, "further_ms": further, "further_median_ms": ours_further, "peak_bytes": ours_peak,
                 "principal_axes": axes, "further_turns_axis": turns,
                 "preview_128_ms": previews,
                 "pixels_opaque": covered},
        "rel_rmse_first_view": errors.map(|(ours, vtk)| serde_json::json!({"ours": ours, "vtk": vtk})),
        "vtk": vtk.as_ref().map_err(|e| format!("{e:#}")).ok(),
        "vtk_error": vtk.as_ref().err().map(|e| format!("{e:#}")),
        "curve": curve,
    });
    if b.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    }
    let mut report = Report::new("clinical", TABLES);
    report.line(format!(
        "{}×{}×{} int16 CT phantom ({stored_mib:.0} MiB), CT-AAA shaded, perspective 30°, 512², {} threads; \
         the first frame from the file (read, prepare, render), further frames each from another direction.",
        dims[0],
        dims[1],
        dims[2],
        rayon::current_num_threads()
    ));
    let mut table = Table::new(COLUMNS);
    table.row(vec![
        "volterra shear-warp (read + prepare + render)".into(),
        format!("{first_ms:.0}"),
        format!("{ours_further:.0}"),
        mib(ours_peak),
    ]);
    let vtk_line = match &vtk {
        Ok(v) => {
            let (vf, mut vfur) = (v["first_ms"].as_f64().unwrap_or(f64::NAN), v["further_ms"].as_array().cloned().unwrap_or_default());
            let mut vfur: Vec<f64> = vfur.drain(..).filter_map(|x| x.as_f64()).collect();
            let vmed = median(&mut vfur);
            table.row(vec![
                format!("VTK {} fixed-point (nibabel + render)", v["vtk"].as_str().unwrap_or("")),
                format!("{vf:.0}"),
                format!("{vmed:.0}"),
                mib(v["peak_bytes"].as_u64()),
            ]);
            format!(
                "VTK's time over ours (above 1: volterra faster): first frame {:.2}, further frames {:.2}.",
                vf / first_ms,
                vmed / ours_further
            )
        }
        Err(e) => format!("VTK skipped: {e:#}"),
    };
    report.table(table);
    report.line(vtk_line);
    let frames_where = |turning: bool| -> Vec<f64> { further.iter().zip(&turns).filter(|x| *x.1 == turning).map(|x| *x.0).collect() };
    let (mut turned_ms, mut kept_ms) = (frames_where(true), frames_where(false));
    report.line(format!(
        "Further frames turning to a new principal axis: {} of {} (median {:.0} ms); keeping theirs: median {:.0} ms.",
        turned_ms.len(),
        further.len(),
        if turned_ms.is_empty() { f64::NAN } else { median(&mut turned_ms) },
        if kept_ms.is_empty() { f64::NAN } else { median(&mut kept_ms) }
    ));
    // The first preview makes the coarse copy previews draw (`coarsening`); the slowest
    // of the rest is a turn to a new principal axis.
    let mut sorted = previews.clone();
    report.line(format!(
        "Previews at 128² while moving (the viewer's): median {:.0} ms, first {:.0} ms, slowest of the rest {:.0} ms.",
        median(&mut sorted),
        previews[0],
        previews[1..].iter().cloned().fold(0.0, f64::max)
    ));
    if let Some((ours, vtk)) = errors {
        let vtk = vtk.map(|e| format!("{:.2} %", 100.0 * e)).unwrap_or_else(|| "-".into());
        report.line(format!("First view against the reference ray caster (relative RMSE): volterra {:.2} %, VTK {vtk}.", 100.0 * ours));
    }
    if let Some(rows) = &curve {
        report.line("Speed against error: further frames' median, the first view's error (* on the Pareto front).");
        let mut table = Table::new(CURVE_COLUMNS);
        for r in rows {
            table.row(vec![
                format!("{}{}", if r.pareto { "* " } else { "" }, r.config),
                format!("{:.0}", r.median_ms),
                format!("{:.2}", 100.0 * r.rel_rmse),
                format!("{:.2}", r.psnr_db),
            ]);
        }
        report.table(table);
        for line in dominance(rows, 0) {
            report.line(line);
        }
    }
    if let Some(plot) = &b.curve {
        report.image(plot);
    }
    report.finish(b.json, b.env.markdown.as_deref())
}

/// The columns of the bench's tables: the main one, and the speed/error curve's.
const COLUMNS: &[&str] = &["renderer", "first frame ms", "further frames ms (median)", "peak memory"];
const CURVE_COLUMNS: &[&str] = &["config", "median ms", "rel. RMSE %", "PSNR dB"];
pub const TABLES: &[&[&str]] = &[COLUMNS, CURVE_COLUMNS];

/// Our rows of the curve: each configuration of `OUR_CURVE` (after the bench's own
/// `--set`s) loaded afresh, its first view against the reference, its further frames timed
/// (the same orbit as the main row's).
fn our_curve(b: &ClinicalBench, scene_path: &Path, dist: f64, reference: &[[f32; 4]]) -> Result<Vec<Row>> {
    let mut rows = Vec::new();
    for (name, sets) in OUR_CURVE {
        eprintln!("curve: volterra {name}");
        let sets: Vec<String> = b.sets.iter().cloned().chain(sets.iter().map(|s| s.to_string())).collect();
        let scene = Scene::load(scene_path, &sets)?.with_limits(b.env.limits);
        let cache = RenderCache::default();
        let first = render_node_with(&scene, 0, &view(0, dist), (512, 512), &cache)?.context("the node draws nothing")?;
        let mut ms = Vec::new();
        for k in 1..=b.frames {
            let t = Instant::now();
            render_node_with(&scene, 0, &view(k, dist), (512, 512), &cache)?;
            ms.push(1000.0 * t.elapsed().as_secs_f64());
        }
        let (err, psnr) = (rgba_rel_rmse(&first.rgba, reference), rgba_psnr(&first.rgba, reference));
        rows.push(Row::new(format!("volterra {name}"), FAMILY.into(), &mut ms, vec![err], &[psnr], None));
    }
    Ok(rows)
}

/// VTK's rows of the curve, from its script's `curve` (one entry per `VTK_CONFIGS`) and the
/// first view's image of each configuration.
fn vtk_curve(b: &ClinicalBench, v: &serde_json::Value, reference: &[[f32; 4]]) -> Result<Vec<Row>> {
    let mut rows = Vec::new();
    for (c, &config @ [sd, isd]) in v["curve"].as_array().context("VTK's script gave no curve")?.iter().zip(&VTK_CONFIGS) {
        let mut ms: Vec<f64> = c["further_ms"].as_array().context("no timings")?.iter().filter_map(|x| x.as_f64()).collect();
        let image = vtk_config_image(&b.env.work_dir.join("vtk_clinical_0.exr"), config);
        let img = rgba_pixels(&volterra_formats::exr_io::read_exr(&image, &b.env.limits)?);
        let config = format!("vtk fixed-point {} sd {sd} isd {isd}", v["vtk"].as_str().unwrap_or(""));
        rows.push(Row::new(config, FAMILY.into(), &mut ms, vec![rgba_rel_rmse(&img, reference)], &[rgba_psnr(&img, reference)], None));
    }
    Ok(rows)
}

/// The reference ray caster's image of the bench scene's first view (RGBA), cached in the
/// work directory by the scene's text.
fn reference_image(b: &ClinicalBench, scene_path: &Path, cam: &Camera) -> Result<Vec<[f32; 4]>> {
    let key = super::fxhash(&std::fs::read_to_string(scene_path)?);
    let path = b.env.work_dir.join(format!("ref_clinical_{}_{key:x}.exr", b.slices));
    if let Ok(img) = volterra_formats::exr_io::read_exr(&path, &b.env.limits) {
        return Ok(rgba_pixels(&img));
    }
    eprintln!("rendering the reference for the first view, cached in {}", path.display());
    let scene = Scene::load(scene_path, &["node.ct.renderer=reference".to_string()])?.with_limits(b.env.limits);
    let frame = render_node_with(&scene, 0, cam, (512, 512), &RenderCache::default())?.context("the node draws nothing")?;
    let img = frame.to_image([0.0; 3]);
    volterra_formats::exr_io::write_exr(&path, &img)?;
    Ok(frame.rgba)
}
