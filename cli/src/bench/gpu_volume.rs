//! `volterra bench gpu-volume`: the GPU volume ray-caster (`gpu-raycast`) against
//! shear-warp, VTK's GPU ray caster (vtkGPUVolumeRayCastMapper, 3D Slicer's default, on
//! the same machine's OpenGL: Mesa's llvmpipe where there is no GPU) and VTK's fixed-point
//! mapper, on the clinical-size CT phantom (512 × 512 × N int16, CT-AAA with Slicer's
//! shading) and the aneurism (MR-Angio, shaded), perspective 30°, at each image size. The
//! first frame counts from the file (read, upload or prepare, render); further frames orbit
//! the camera. Each first view against the reference ray caster (rendered once per volume
//! and size, cached in the work directory).

use super::median;
use super::report::{Report, Table};
use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};
use std::time::Instant;
use volterra::compare::{rgba_pixels, rgba_rel_rmse};
use volterra::render::{render_node_with, RenderCache};
use volterra::scene::presets::{Preset, ValueStats};
use volterra::scene::{Camera, Scene};

pub struct GpuVolumeBench {
    pub env: super::BenchEnv,
    /// N of the 512 × 512 × N CT phantom.
    pub slices: usize,
    /// Frames after the first (each from another direction).
    pub frames: usize,
    /// Image sizes (width, height).
    pub sizes: Vec<(usize, usize)>,
    /// The aneurism (aneurism.nii.gz of the shared data) where found.
    pub aneurism: Option<PathBuf>,
    /// Measure each first view against the reference ray caster.
    pub error: bool,
    pub json: bool,
    /// Overrides of the scene for our GPU side (`node.v.settings.step=1`).
    pub sets: Vec<String>,
    /// Leave VTK out (to compare our own configurations quickly).
    pub no_vtk: bool,
}

/// One volume the bench draws: its scene file (node "v") and camera distance.
struct Subject {
    name: String,
    scene: PathBuf,
    centre: glam::DVec3,
    dist: f64,
}

/// The camera of frame k: round the volume's centre, slightly from above.
fn view(s: &Subject, k: usize) -> Camera {
    let a = (35.0 + 47.0 * k as f64).to_radians();
    let d = glam::DVec3::new(a.cos(), a.sin(), 0.35 + 0.1 * (k % 3) as f64).normalize() * s.dist;
    Camera {
        position: (s.centre + d).to_array(),
        focal_point: s.centre.to_array(),
        view_up: [0.0, 0.0, 1.0],
        view_angle: 30.0,
        parallel_projection: false,
        parallel_scale: 1.0,
    }
}

/// Writes the scene of `volume` (read from `file`) classified by `preset` with its shading.
fn subject(env: &super::BenchEnv, name: &str, file: &Path, volume: &volterra_formats::Volume, preset: &str) -> Result<Subject> {
    let preset = Preset::from_name(preset).map_err(anyhow::Error::msg)?;
    let tf = preset.transfer_function(&ValueStats::of(volume), 0.7);
    let shading = preset.shading().context("the preset has shading")?;
    let corners: Vec<glam::DVec3> = (0..8)
        .map(|c| {
            let ijk = std::array::from_fn(|a| if c >> a & 1 == 0 { 0.0 } else { (volume.dims[a] - 1) as f64 });
            glam::DVec3::from(volume.index_to_world(ijk))
        })
        .collect();
    let centre = corners.iter().copied().sum::<glam::DVec3>() / 8.0;
    let radius = corners.iter().map(|c| c.distance(centre)).fold(0.0, f64::max);
    let s = Subject {
        name: name.into(),
        scene: env.work_dir.join(format!("gpu_volume_{name}.toml")),
        centre,
        dist: 1.15 * radius / 15f64.to_radians().tan(),
    };
    let text = format!(
        "[image]\nwidth = 512\nheight = 512\n\n[camera]\n{}\n[[node]]\nname = \"v\"\nkind = \"volume\"\nfile = \"{}\"\nrenderer = \"gpu-raycast\"\n\n[node.transfer_function]\n{}\n[node.shading]\n{}",
        toml::to_string(&view(&s, 0))?,
        std::fs::canonicalize(file)?.display(),
        toml::to_string(&tf)?,
        toml::to_string(&shading)?
    );
    std::fs::write(&s.scene, text)?;
    Ok(s)
}

/// One side's timings: the first frame from the file and the further frames' median, and
/// its first view.
struct Timed {
    first_ms: f64,
    further_ms: Vec<f64>,
    first: Option<Vec<[f32; 4]>>,
}

fn ours(b: &GpuVolumeBench, s: &Subject, renderer: &str, (w, h): (usize, usize)) -> Result<Timed> {
    let mut sets = vec![format!("node.v.renderer={renderer}")];
    if renderer == "gpu-raycast" {
        sets.extend(b.sets.iter().cloned());
    }
    let t = Instant::now();
    let scene = Scene::load(&s.scene, &sets)?.with_limits(b.env.limits);
    let cache = RenderCache::default();
    let first = render_node_with(&scene, 0, &view(s, 0), (w, h), &cache)?.context("the node draws nothing")?;
    let first_ms = 1000.0 * t.elapsed().as_secs_f64();
    let mut further_ms = Vec::new();
    for k in 1..=b.frames {
        let t = Instant::now();
        render_node_with(&scene, 0, &view(s, k), (w, h), &cache)?;
        further_ms.push(1000.0 * t.elapsed().as_secs_f64());
    }
    Ok(Timed { first_ms, further_ms, first: Some(first.rgba) })
}

/// VTK's `mapper` ("gpu" or "fixed-point") in its own process (tests/reference/vtk_volume.py).
fn vtk(b: &GpuVolumeBench, s: &Subject, mapper: &str, (w, h): (usize, usize)) -> Result<(Timed, serde_json::Value)> {
    let image = |k: usize| b.env.work_dir.join(format!("vtk_{mapper}_{}_{w}x{h}_{k}.exr", s.name));
    let spec = serde_json::json!({
        "scene": std::fs::canonicalize(&s.scene)?,
        "views": (0..=b.frames).map(|k| serde_json::json!({"position": view(s, k).position, "image": image(k)})).collect::<Vec<_>>(),
        "mapper": mapper,
        "size": [w, h],
    });
    let spec_path = b.env.work_dir.join(format!("vtk_gpu_volume_{mapper}.json"));
    std::fs::write(&spec_path, spec.to_string())?;
    let v = super::run_vtk_volume(&b.env, "--clinical", &spec_path)?;
    let first = volterra_formats::exr_io::read_exr(&image(0), &b.env.limits).ok().map(|img| rgba_pixels(&img));
    let further_ms = v["further_ms"].as_array().map(|a| a.iter().filter_map(|x| x.as_f64()).collect()).unwrap_or_default();
    Ok((Timed { first_ms: v["first_ms"].as_f64().unwrap_or(f64::NAN), further_ms, first }, v))
}

/// The reference ray caster's first view at `size`, cached by the scene's text.
fn reference(b: &GpuVolumeBench, s: &Subject, (w, h): (usize, usize)) -> Result<Vec<[f32; 4]>> {
    let key = super::fxhash(&std::fs::read_to_string(&s.scene)?);
    let path = b.env.work_dir.join(format!("ref_gpu_volume_{}_{w}x{h}_{key:x}.exr", s.name));
    if let Ok(img) = volterra_formats::exr_io::read_exr(&path, &b.env.limits) {
        return Ok(rgba_pixels(&img));
    }
    say!("rendering the reference of {} at {w}×{h}, cached in {}", s.name, path.display());
    let scene = Scene::load(&s.scene, &["node.v.renderer=reference".to_string()])?.with_limits(b.env.limits);
    let frame = render_node_with(&scene, 0, &view(s, 0), (w, h), &RenderCache::default())?.context("the node draws nothing")?;
    volterra_formats::exr_io::write_exr(&path, &frame.to_image([0.0; 3]))?;
    Ok(frame.rgba)
}

const COLUMNS: &[&str] = &["volume", "image", "renderer", "first frame ms", "further frames ms (median)", "rel. RMSE % (first view)"];
pub const TABLES: &[&[&str]] = &[COLUMNS];

pub fn run(b: &GpuVolumeBench) -> Result<()> {
    if b.slices < 2 || b.slices > 2000 {
        bail!("--slices {} must lie in 2..=2000", b.slices);
    }
    std::fs::create_dir_all(&b.env.work_dir)?;
    let mut subjects = Vec::new();
    let nii = b.env.work_dir.join(format!("ct_phantom_512x512x{}.nii", b.slices));
    let ct = volterra::samples::ct_phantom(512, 512, b.slices);
    if !nii.exists() {
        say!("writing the 512×512×{} CT phantom to {}", b.slices, nii.display());
        volterra_formats::nifti::write_nifti(&nii, &ct)?;
    }
    subjects.push(subject(&b.env, &format!("ct512x512x{}", b.slices), &nii, &ct, "CT-AAA")?);
    drop(ct);
    match &b.aneurism {
        Some(path) => {
            let v = volterra_formats::nifti::read_nifti(path, &Default::default(), &b.env.limits)?;
            subjects.push(subject(&b.env, "aneurism", path, &v, "MR-Angio")?);
        }
        None => say!("the aneurism skipped: no shared data (../shared/data or VOLTERRA_SHARED_DATA)"),
    }
    let gpu = volterra::gpu::device()?;
    let mut table = Table::new(COLUMNS);
    let mut json = Vec::new();
    let mut ratios = Vec::new();
    for s in &subjects {
        for &size in &b.sizes {
            let truth = if b.error { Some(reference(b, s, size)?) } else { None };
            let mut further = std::collections::HashMap::new();
            let sides: [(&str, &str); 4] = [
                ("volterra gpu-raycast", "gpu-raycast"),
                ("volterra shear-warp", "shear-warp"),
                ("VTK GPU ray caster", "vtk:gpu"),
                ("VTK fixed-point", "vtk:fixed-point"),
            ];
            for (label, side) in sides {
                say!("{} at {}×{}: {label}", s.name, size.0, size.1);
                if b.no_vtk && side.starts_with("vtk:") {
                    continue;
                }
                let run = match side.strip_prefix("vtk:") {
                    Some(mapper) => vtk(b, s, mapper, size).map(|(t, v)| {
                        let version = v["vtk"].as_str().unwrap_or("?");
                        let label = match mapper {
                            "gpu" => format!("{label} (VTK {version}, OpenGL: {})", v["opengl"].as_str().unwrap_or("?")),
                            _ => format!("{label} (VTK {version})"),
                        };
                        (t, label)
                    }),
                    None if side == "gpu-raycast" && !b.sets.is_empty() => {
                        ours(b, s, side, size).map(|t| (t, format!("{label} ({})", b.sets.join(", "))))
                    }
                    None => ours(b, s, side, size).map(|t| (t, label.to_string())),
                };
                let (t, label) = match run {
                    Ok(x) => x,
                    Err(e) => {
                        say!("{label} skipped: {e:#}");
                        continue;
                    }
                };
                let err = match (&truth, &t.first) {
                    (Some(r), Some(f)) if f.len() == r.len() => Some(rgba_rel_rmse(f, r)),
                    _ => None,
                };
                let med = median(&mut t.further_ms.clone());
                further.insert(side, med);
                table.row(vec![
                    s.name.clone(),
                    format!("{}×{}", size.0, size.1),
                    label.clone(),
                    format!("{:.0}", t.first_ms),
                    format!("{med:.0}"),
                    err.map_or("-".into(), |e| format!("{:.2}", 100.0 * e)),
                ]);
                json.push(serde_json::json!({"volume": s.name, "size": [size.0, size.1], "renderer": label, "first_ms": t.first_ms,
                    "further_ms": t.further_ms, "further_median_ms": med, "rel_rmse": err}));
            }
            if let (Some(g), Some(w), Some(v)) = (further.get("gpu-raycast"), further.get("shear-warp"), further.get("vtk:gpu")) {
                ratios.push(format!("{} at {}×{}: over gpu-raycast {:.2}, over shear-warp {:.2}", s.name, size.0, size.1, v / g, v / w));
            }
        }
    }
    if b.json {
        println!("{}", serde_json::to_string_pretty(&json)?);
    }
    let mut report = Report::new("gpu-volume", TABLES);
    report.line(format!(
        "Perspective 30°, shaded (CT-AAA, MR-Angio with 3D Slicer's shading), {} further frames orbiting the volume; our GPU: {} ({:?}), {} CPU threads. \
         The first frame from the file (read, upload or prepare, render); errors are each side's first view against the reference ray caster.",
        b.frames,
        gpu.info.name,
        gpu.info.backend,
        rayon::current_num_threads()
    ));
    report.table(table);
    if !ratios.is_empty() {
        report.line(format!("Further frames, VTK's GPU ray caster's time over ours (above 1: volterra faster): {}.", ratios.join("; ")));
        report.line(format!(
            "The viewer draws volumes with gpu-raycast on a hardware GPU and with shear-warp on a CPU adapter such as this one ({}).",
            if gpu.is_software() { "software" } else { "hardware" }
        ));
    }
    report.finish(b.json, b.env.markdown.as_deref())
}
