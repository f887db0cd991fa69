//! `volterra bench shear-warp`: speed against error, in one process. Our renderer with
//! each leaping mode and supersampling ratio, MIP, gradient shading, perspective, and
//! VTK's fixed-point ray caster (through Python in the same command, unshaded and with
//! `ShadeOn`, parallel and perspective), each as the median ms per frame over several
//! views and the relative RMSE from the reference ray caster (cached per view, projection,
//! blend mode and shading).

use super::{fxhash, median};
use anyhow::{bail, Context, Result};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;
use volterra::compare::{rgba_pixels as rgba_of, rgba_psnr, rgba_rel_rmse as rel_rmse};
use volterra::render::{reference_volume, shear_warp, Frame};
use volterra::scene::{BlendMode, Camera, Scene, TransferFunction, VolumeShading};

pub struct ShearWarpBench {
    /// A scene with one volume node; its view is the first of five, drawn in parallel
    /// projection, and again in perspective (30°, framing the same height at the focal
    /// point).
    pub scene: PathBuf,
    pub env: super::BenchEnv,
    pub runs: usize,
    pub json: bool,
    pub plot: PathBuf,
    /// Time only the configurations whose name contains this (None: all).
    pub only: Option<String>,
}

#[derive(Debug, Clone, Serialize)]
pub struct Row {
    pub config: String,
    /// What the row draws, so that only like rows are compared: projection, blend mode
    /// and shading ("parallel composite shaded", "perspective mip", …).
    pub family: String,
    /// On its family's speed/error Pareto front: no row of the family is both as fast and
    /// as close to the reference, and better in one.
    pub pareto: bool,
    /// For a VTK row: the fastest volterra row of its family that is both faster and
    /// closer to the reference, if any.
    pub dominated_by: Option<String>,
    pub median_ms: f64,
    pub rel_rmse: f64,
    /// Relative RMSE at each view, in the order of `views`.
    pub rel_rmse_views: Vec<f64>,
    /// Mean PSNR over the views, dB (peak 1).
    pub psnr_db: f64,
    /// Median ms per million intermediate pixels (shear-warp only).
    pub ms_per_mpixel: Option<f64>,
}

impl Row {
    /// A row of the median of `ms`, the mean of the views' errors and PSNRs; not yet
    /// compared with the others (`mark_pareto`).
    pub(super) fn new(config: String, family: String, ms: &mut [f64], err: Vec<f64>, psnr: &[f64], ms_per_mpixel: Option<f64>) -> Row {
        Row {
            config,
            family,
            pareto: false,
            dominated_by: None,
            median_ms: median(ms),
            rel_rmse: err.iter().sum::<f64>() / err.len() as f64,
            rel_rmse_views: err,
            psnr_db: psnr.iter().sum::<f64>() / psnr.len() as f64,
            ms_per_mpixel,
        }
    }
}

/// The scene's view and four more: oblique, exactly 45° between two axes (where the
/// principal axis switches), a second oblique from below, and exactly axis-aligned.
fn views(cam: &Camera) -> Vec<Camera> {
    let fp = glam::DVec3::from(cam.focal_point);
    let dist = (glam::DVec3::from(cam.position) - fp).length();
    let mut out = vec![cam.clone()];
    for dir in [[0.55, 0.75, 0.3], [1.0, 1.0, 0.0], [-0.6, 0.3, -0.7], [0.0, -1.0, 0.0]] {
        let d = glam::DVec3::from(dir).normalize() * dist;
        let mut c = cam.clone();
        c.position = (fp + d).to_array();
        c.view_up = [0.0, 0.0, 1.0];
        out.push(c);
    }
    out
}

/// The perspective view angle of the perspective rows (3D Slicer's default).
const PERSPECTIVE_ANGLE: f64 = 30.0;

/// `cam` in parallel projection, showing at its focal point the height it shows there now.
fn as_parallel(cam: &Camera) -> Camera {
    let dist = (glam::DVec3::from(cam.position) - glam::DVec3::from(cam.focal_point)).length();
    let scale = if cam.parallel_projection { cam.parallel_scale } else { dist * (0.5 * cam.view_angle.to_radians()).tan() };
    Camera { parallel_projection: true, parallel_scale: scale, ..cam.clone() }
}

/// `cam` (parallel) in perspective at `PERSPECTIVE_ANGLE`, moved along its view direction
/// so the focal point's plane shows the same height.
fn as_perspective(cam: &Camera) -> Camera {
    let (eye, fp) = (glam::DVec3::from(cam.position), glam::DVec3::from(cam.focal_point));
    let dist = cam.parallel_scale / (0.5 * PERSPECTIVE_ANGLE.to_radians()).tan();
    let position = (fp + (eye - fp).normalize() * dist).to_array();
    Camera { position, parallel_projection: false, view_angle: PERSPECTIVE_ANGLE, ..cam.clone() }
}

/// A set of views and their reference images (MIP only for the parallel set).
struct ViewSet {
    /// "" or "perspective ", before each row's name.
    prefix: &'static str,
    cams: Vec<Camera>,
    refs: Vec<Vec<[f32; 4]>>,
    refs_mip: Vec<Vec<[f32; 4]>>,
    refs_shaded: Vec<Vec<[f32; 4]>>,
}

pub fn run(b: &ShearWarpBench) -> Result<()> {
    if b.runs == 0 {
        bail!("--runs must be at least 1");
    }
    let scene = Scene::load(&b.scene, &[])?.with_limits(b.env.limits);
    let node =
        scene.nodes().iter().position(|n| n.kind == volterra::scene::NodeKind::Volume).context("the bench scene needs a volume node")?;
    let desc = &scene.nodes()[node];
    let tf: &TransferFunction = desc.transfer_function.as_ref().context("the volume node needs a transfer_function")?;
    let volume = scene.volume(node)?;
    let to_world = scene.world_transform(node);
    let (w, h) = (scene.file.image.width, scene.file.image.height);
    let cams = views(&as_parallel(&scene.file.camera));
    std::fs::create_dir_all(&b.env.work_dir)?;
    let prepared = shear_warp::Prepared::new(&volume, &b.env.limits)?;

    // The shaded rows use the node's shading coefficients, or VTK's defaults, with shading on.
    let shading = VolumeShading { shade: true, ..desc.shading.unwrap_or_default() };
    let lights = &scene.file.lights;
    if !lights.is_empty() {
        bail!("{}: the bench compares with VTK under its headlight; remove the scene's lights", b.scene.display());
    }

    // Reference images, cached by scene, view, projection, blend mode and shading.
    let key = format!("{:x}", fxhash(&(std::fs::read_to_string(&b.scene)?, w, h)));
    let mut sets = Vec::new();
    for (prefix, cams) in [("", cams.clone()), ("perspective ", cams.iter().map(as_perspective).collect())] {
        let mut set = ViewSet { prefix, cams, refs: Vec::new(), refs_mip: Vec::new(), refs_shaded: Vec::new() };
        let tag0 = if prefix.is_empty() { "" } else { "_perspective" };
        for (v, cam) in set.cams.iter().enumerate() {
            for (blend, shade, list) in [
                (BlendMode::Composite, false, &mut set.refs),
                (BlendMode::Mip, false, &mut set.refs_mip),
                (BlendMode::Composite, true, &mut set.refs_shaded),
            ] {
                if blend == BlendMode::Mip && !prefix.is_empty() {
                    continue;
                }
                let tag = format!("{tag0}{}", if shade { "_shaded" } else { "" });
                let path = b.env.work_dir.join(format!("ref_{key}_{v}_{blend:?}{tag}.exr"));
                let img = match volterra_formats::exr_io::read_exr(&path, &b.env.limits) {
                    Ok(img) => img,
                    Err(_) => {
                        eprintln!("rendering the reference for view {v} ({blend:?}{tag}), cached in {}", path.display());
                        let shading = shade.then_some(&shading);
                        let input = reference_volume::VolumeInput {
                            volume: &volume,
                            node_to_world: to_world,
                            tf,
                            blend,
                            shading,
                            lights,
                            crop: &[],
                        };
                        let f = reference_volume::render(&input, &cam.rays(w, h), &Default::default())?;
                        let img = f.to_image([0.0; 3]);
                        volterra_formats::exr_io::write_exr(&path, &img)?;
                        img
                    }
                };
                list.push(rgba_of(&img));
            }
        }
        sets.push(set);
    }
    let (parallel, perspective) = (&sets[0], &sets[1]);

    let mut rows = Vec::new();
    let wanted = |name: &str| b.only.as_deref().is_none_or(|o| name.contains(o));
    let time_in = |set: &ViewSet, name: String, blend: BlendMode, s: shear_warp::Settings, shade: bool| -> Result<Option<Row>> {
        let name = format!("{}{name}", set.prefix);
        if !wanted(&name) {
            return Ok(None);
        }
        let ViewSet { cams, refs, refs_mip, refs_shaded, .. } = set;
        let shading = shade.then_some(&shading);
        let input = shear_warp::Input { prepared: &prepared, node_to_world: to_world, tf, blend, shading, lights, crop: &[], second: None };
        let (mut ms, mut err, mut psnr, mut mpix) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for (v, cam) in cams.iter().enumerate() {
            let rays = cam.rays(w, h);
            let warm: Frame = shear_warp::render(&input, &rays, &s)?; // builds the axis copy and maps once
            let reference = match (blend, shade) {
                (BlendMode::Mip, _) => &refs_mip[v],
                (_, true) => &refs_shaded[v],
                _ => &refs[v],
            };
            err.push(rel_rmse(&warm.rgba, reference));
            psnr.push(rgba_psnr(&warm.rgba, reference));
            let fac_pixels = intermediate_pixels(&warm);
            for _ in 0..b.runs {
                let t = Instant::now();
                let f = shear_warp::render(&input, &rays, &s)?;
                let dt = 1000.0 * t.elapsed().as_secs_f64();
                ms.push(dt);
                mpix.push(dt / (fac_pixels / 1e6));
                drop(f);
            }
        }
        let row = Row::new(name, family(set, blend, shade), &mut ms, err, &psnr, Some(median(&mut mpix)));
        if !b.json {
            eprintln!("{:<38} {:>9.1} ms {:>8.2} %", row.config, row.median_ms, 100.0 * row.rel_rmse);
        }
        Ok(Some(row))
    };
    let time_shaded = |name: String, blend: BlendMode, s: shear_warp::Settings, shade: bool| time_in(parallel, name, blend, s, shade);
    let time_config = |name: String, blend: BlendMode, s: shear_warp::Settings| time_shaded(name, blend, s, false);
    // The paper's renderer (one sample per slab) with each leaping mode at its ratios.
    for leaping in [shear_warp::Leaping::None, shear_warp::Leaping::MultiScanline, shear_warp::Leaping::Overlapped] {
        for ratio in [1.0, 1.13, 2.26] {
            let name = format!("shear-warp {} ×{ratio} 1/slab", leaping.name());
            rows.extend(time_config(
                name,
                BlendMode::Composite,
                shear_warp::Settings { leaping, supersampling: ratio, slab_samples: 1, ..Default::default() },
            )?);
        }
    }
    // More ratios (below 1: fewer rays than voxels, as VTK's ImageSampleDistance 2 casts
    // fewer than pixels), and two samples per slab (the default), so the speed-against-error
    // curves are visible.
    for (per_slab, ratios) in [(1, &[0.5, 0.75, 1.5, 1.75, 2.0, 3.0][..]), (2, &[1.0, 1.5, 2.0, 2.26, 3.0][..])] {
        for &ratio in ratios {
            rows.extend(time_config(
                format!("shear-warp {} ×{ratio} {per_slab}/slab", shear_warp::Leaping::Overlapped.name()),
                BlendMode::Composite,
                shear_warp::Settings { supersampling: ratio, slab_samples: per_slab, ..Default::default() },
            )?);
        }
    }
    rows.extend(time_config("shear-warp overlapped auto (default)".into(), BlendMode::Composite, Default::default())?);
    for per_slab in [1, 2] {
        rows.extend(time_config(
            format!("shear-warp mip overlapped ×2.26 {per_slab}/slab"),
            BlendMode::Mip,
            shear_warp::Settings { supersampling: 2.26, slab_samples: per_slab, ..Default::default() },
        )?);
    }
    rows.extend(time_config(
        "shear-warp mip none ×2.26 2/slab".into(),
        BlendMode::Mip,
        shear_warp::Settings { supersampling: 2.26, leaping: shear_warp::Leaping::None, ..Default::default() },
    )?);

    // Gradient shading (the node's coefficients, or VTK's defaults), against the shaded
    // reference.
    for (per_slab, ratio) in [(1, 0.75), (1, 1.0), (2, 1.5), (2, 2.0), (2, 3.0)] {
        rows.extend(time_shaded(
            format!("shaded shear-warp ×{ratio} {per_slab}/slab"),
            BlendMode::Composite,
            shear_warp::Settings { supersampling: ratio, slab_samples: per_slab, ..Default::default() },
            true,
        )?);
    }
    rows.extend(time_shaded("shaded shear-warp auto (default)".into(), BlendMode::Composite, Default::default(), true)?);
    // The nearest-pixel warp: one intermediate ray per final pixel instead of about four.
    let nearest = shear_warp::Settings { warp: shear_warp::WarpFilter::Nearest, ..Default::default() };
    rows.extend(time_config("shear-warp overlapped auto, nearest warp".into(), BlendMode::Composite, nearest.clone())?);
    rows.extend(time_shaded("shaded shear-warp auto, nearest warp".into(), BlendMode::Composite, nearest.clone(), true)?);

    // Perspective (the same views at 30°), unshaded and shaded, against the perspective
    // references.
    rows.extend(time_in(perspective, "shear-warp overlapped auto (default)".into(), BlendMode::Composite, Default::default(), false)?);
    rows.extend(time_in(perspective, "shaded shear-warp auto (default)".into(), BlendMode::Composite, Default::default(), true)?);
    rows.extend(time_in(perspective, "shaded shear-warp auto, nearest warp".into(), BlendMode::Composite, nearest, true)?);
    // Cheaper perspective configurations, so VTK's perspective rows (sample distances and
    // ImageSampleDistance) meet ours along the whole speed/error curve.
    for (per_slab, ratio) in [(1, 0.75), (1, 1.0), (1, 1.5), (2, 2.0)] {
        let s = shear_warp::Settings { supersampling: ratio, slab_samples: per_slab, ..Default::default() };
        rows.extend(time_in(perspective, format!("shear-warp overlapped ×{ratio} {per_slab}/slab"), BlendMode::Composite, s, false)?);
    }
    for (per_slab, ratio) in [(1, 0.75), (1, 1.0), (2, 1.5), (2, 2.0)] {
        let s = shear_warp::Settings { supersampling: ratio, slab_samples: per_slab, ..Default::default() };
        rows.extend(time_in(perspective, format!("shaded shear-warp ×{ratio} {per_slab}/slab"), BlendMode::Composite, s, true)?);
    }

    // VTK's fixed-point mapper through Python, same views, same references.
    for set in &sets {
        for (shade, name, refs) in [(false, "vtk fixed-point", &set.refs), (true, "shaded vtk fixed-point", &set.refs_shaded)] {
            let name = format!("{}{name}", set.prefix);
            if wanted(&name) {
                match vtk_rows(b, set, refs, shade.then_some(&shading)) {
                    Ok(r) => rows.extend(r),
                    Err(e) => eprintln!("VTK rows ({name}) skipped: {e:#}"),
                }
            }
        }
    }

    mark_pareto(&mut rows);
    let rows_path = b.env.work_dir.join("shear_warp_rows.json");
    std::fs::write(&rows_path, serde_json::to_string_pretty(&rows)?)?;
    if b.only.is_none() {
        super::plot(&b.env.python, &b.env.scripts, "plot_bench.py", &rows_path, &b.plot, "plot");
    }
    if b.json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
    }
    let mut report = super::report::Report::new("shear-warp", TABLES);
    report.line(format!(
        "{w}×{h}, {} views, median of {} runs per view, {} threads; * on its family's speed/error Pareto front \
         (projection, blend mode and shading alike).",
        cams.len(),
        b.runs,
        rayon::current_num_threads()
    ));
    let mut table = super::report::Table::new(COLUMNS);
    for r in &rows {
        let mp = r.ms_per_mpixel.map(|v| format!("{v:.1}")).unwrap_or_else(|| "-".into());
        let views: Vec<String> = r.rel_rmse_views.iter().map(|e| format!("{:.2}", 100.0 * e)).collect();
        table.row(vec![
            format!("{}{}", if r.pareto { "* " } else { "" }, r.config),
            format!("{:.1}", r.median_ms),
            format!("{:.2}", 100.0 * r.rel_rmse),
            format!("{:.2}", r.psnr_db),
            mp,
            views.join(" "),
        ]);
    }
    report.table(table);
    // Each VTK configuration against ours: is some volterra configuration of its family
    // both faster and closer to the reference?
    for line in dominance(&rows, 1) {
        report.line(line);
    }
    if b.only.is_none() {
        report.image(&b.plot);
    }
    report.finish(b.json, b.env.markdown.as_deref())
}

/// The columns of the bench's table.
const COLUMNS: &[&str] = &["config", "median ms", "rel. RMSE %", "PSNR dB", "ms/Mpixel", "rel. RMSE % per view"];
pub const TABLES: &[&[&str]] = &[COLUMNS];

/// For each VTK row, the volterra row of its family both faster and closer to the
/// reference (`Row::dominated_by`), or that there is none; times to `decimals` places.
pub(super) fn dominance(rows: &[Row], decimals: usize) -> Vec<String> {
    let mut lines = Vec::new();
    for r in rows.iter().filter(|r| r.config.contains("vtk")) {
        let figures = |o: &Row| format!("{} ({:.*} ms, {:.2} %)", o.config, decimals, o.median_ms, 100.0 * o.rel_rmse);
        lines.push(match r.dominated_by.as_ref().and_then(|by| rows.iter().find(|o| &o.config == by)) {
            Some(o) => format!("{}: faster and closer: {}", figures(r), figures(o)),
            None => format!("{}: no volterra configuration is both faster and closer", figures(r)),
        });
    }
    lines
}

/// Intermediate image pixels of a frame, from its statistics.
fn intermediate_pixels(f: &Frame) -> f64 {
    f.stats.counter("intermediate_pixels").unwrap_or(1.0)
}

/// The family of a row drawn in `set` (see `Row::family`).
fn family(set: &ViewSet, blend: BlendMode, shade: bool) -> String {
    let projection = if set.prefix.is_empty() { "parallel" } else { "perspective" };
    let blend = if blend == BlendMode::Mip { "mip" } else { "composite" };
    format!("{projection} {blend}{}", if shade { " shaded" } else { "" })
}

/// VTK's configurations on the table: sample distance (voxels of the finest axis) and
/// ImageSampleDistance (pixels between rays), so its whole speed/error curve is there.
pub(super) const VTK_CONFIGS: [[f64; 2]; 6] = [[0.5, 1.0], [1.0, 1.0], [2.0, 1.0], [0.5, 2.0], [1.0, 2.0], [2.0, 2.0]];

/// Where vtk_volume.py writes a configuration's image of the view whose image is `view`
/// (its `config_path`): the stem followed by `_sd{sd}_isd{isd}`.
pub(super) fn vtk_config_image(view: &Path, [sd, isd]: [f64; 2]) -> PathBuf {
    let stem = view.file_stem().unwrap_or_default().to_string_lossy();
    let ext = view.extension().map(|e| format!(".{}", e.to_string_lossy())).unwrap_or_default();
    view.with_file_name(format!("{stem}_sd{sd}_isd{isd}{ext}"))
}

/// Marks each family's Pareto front, and for each VTK row the fastest volterra row of its
/// family that is both faster and closer to the reference.
pub(super) fn mark_pareto(rows: &mut [Row]) {
    let better =
        |a: &Row, b: &Row| a.median_ms <= b.median_ms && a.rel_rmse <= b.rel_rmse && (a.median_ms < b.median_ms || a.rel_rmse < b.rel_rmse);
    let is_vtk = |r: &Row| r.config.contains("vtk");
    for i in 0..rows.len() {
        let (r, family) = (&rows[i], &rows[i].family);
        let pareto = !rows.iter().any(|o| &o.family == family && better(o, r));
        let dominated_by = is_vtk(r)
            .then(|| {
                rows.iter()
                    .filter(|o| &o.family == family && !is_vtk(o) && o.median_ms < r.median_ms && o.rel_rmse < r.rel_rmse)
                    .min_by(|a, b| a.median_ms.total_cmp(&b.median_ms))
                    .map(|o| o.config.clone())
            })
            .flatten();
        (rows[i].pareto, rows[i].dominated_by) = (pareto, dominated_by);
    }
}

/// VTK's rows (one per `VTK_CONFIGS` entry), with `ShadeOn` and these coefficients when
/// `shading` is given (shading off otherwise, whatever the scene says).
fn vtk_rows(b: &ShearWarpBench, set: &ViewSet, refs: &[Vec<[f32; 4]>], shading: Option<&VolumeShading>) -> Result<Vec<Row>> {
    let tag = format!("{}{}", if set.prefix.is_empty() { "" } else { "_perspective" }, if shading.is_some() { "_shaded" } else { "" });
    let image = |v: usize| b.env.work_dir.join(format!("vtk_{v}{tag}.exr"));
    let family = family(set, BlendMode::Composite, shading.is_some());
    let spec_views: Vec<serde_json::Value> = set
        .cams
        .iter()
        .enumerate()
        .map(|(v, c)| {
            serde_json::json!({"position": c.position, "image": image(v), "parallel": c.parallel_projection,
                               "view_angle": c.view_angle, "parallel_scale": c.parallel_scale})
        })
        .collect();
    let shading = serde_json::to_value(shading.copied().unwrap_or_default())?;
    let spec = serde_json::json!({"scene": std::fs::canonicalize(&b.scene)?, "views": spec_views, "runs": b.runs, "shading": shading,
                                  "configs": VTK_CONFIGS});
    let spec_path = b.env.work_dir.join("vtk_spec.json");
    std::fs::write(&spec_path, spec.to_string())?;
    let v = super::run_vtk_volume(&b.env, "--bench", &spec_path)?;
    let mut rows = Vec::new();
    for (c, &config) in v["configs"].as_array().context("no configurations")?.iter().zip(&VTK_CONFIGS) {
        let mut ms: Vec<f64> = c["ms"]
            .as_array()
            .context("no timings")?
            .iter()
            .flat_map(|r| r.as_array().cloned().unwrap_or_default())
            .filter_map(|x| x.as_f64())
            .collect();
        let (mut err, mut psnr) = (Vec::new(), Vec::new());
        for (i, r) in refs.iter().enumerate() {
            let img = volterra_formats::exr_io::read_exr(&vtk_config_image(&image(i), config), &b.env.limits)?;
            err.push(rel_rmse(&rgba_of(&img), r));
            psnr.push(rgba_psnr(&rgba_of(&img), r));
        }
        let config = format!(
            "{}{}vtk fixed-point {} sd {} isd {}",
            set.prefix,
            if tag.ends_with("_shaded") { "shaded " } else { "" },
            v["vtk"].as_str().unwrap_or(""),
            config[0],
            config[1]
        );
        rows.push(Row::new(config, family.clone(), &mut ms, err, &psnr, None));
    }
    Ok(rows)
}
