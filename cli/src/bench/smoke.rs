//! `volterra bench smoke`: the four configurations of the paper's Table 1 — photon map or
//! particle map, with or without the irradiance map — and two variants of the default
//! (shadow rays instead of the transmittance grid; the paper's biased local free path), on
//! the 110k-particle plume with 640k photons and 4 rays per pixel: photon tracing, store,
//! irradiance-map + ray-marching times and memory at the timing image size, and each one's
//! error against Mitsuba 3 on the comparison view
//! (tests/reference/smoke_scenes/plume110k.toml, 8192 spp, committed). Then Mitsuba's own
//! time to reach comparable errors at rising sample counts; `view s` is each one's time for
//! the comparison view itself, so time and error compare on one image.

use anyhow::{bail, Context, Result};
use serde::Serialize;
use std::path::PathBuf;
use volterra::compare::{rgba_pixels, rgba_rel_rmse};
use volterra::render::smoke::{self, FreeFlight, Settings, ShadowMode, SmokeInput, Store};
use volterra::render::Frame;
use volterra::scene::{NodeKind, Scene};

pub struct SmokeBench {
    pub scene: PathBuf,
    pub width: usize,
    pub height: usize,
    pub photons: usize,
    pub env: super::BenchEnv,
    pub json: bool,
}

#[derive(Debug, Clone, Serialize)]
pub struct Row {
    pub config: String,
    pub total_s: f64,
    pub trace_s: f64,
    pub store_s: f64,
    pub march_s: f64,
    pub rel_rmse: f64,
    pub memory_mb: f64,
    /// Seconds for the comparison view itself (the error's image, at Mitsuba's size and
    /// sample count for Mitsuba's rows): time against error on equal terms.
    pub view_s: f64,
}

fn counter(f: &Frame, name: &str) -> f64 {
    f.stats.counters.iter().find(|c| c.0 == name).map(|c| c.1).unwrap_or(0.0)
}

fn render(scene: &Scene, node: usize, sets: &Settings, size: (usize, usize)) -> Result<Frame> {
    let desc = &scene.nodes()[node];
    let particles = scene.particles(node)?;
    let medium = desc.medium.as_ref().context("the particle node needs a medium")?;
    let input = SmokeInput {
        particles: &particles,
        node_to_world: scene.world_transform(node),
        medium,
        lights: &scene.file.lights,
        limits: *scene.limits(),
    };
    smoke::render(&input, &scene.file.camera.rays(size.0, size.1), sets)
}

pub fn run(b: &SmokeBench) -> Result<()> {
    let scene = Scene::load(&b.scene, &[])?.with_limits(b.env.limits);
    let node = scene.nodes().iter().position(|n| n.kind == NodeKind::Particles).context("the bench scene needs a particle node")?;
    let reference_path = b
        .scene
        .parent()
        .and_then(|d| d.parent())
        .map(|d| d.join("data").join(format!("mitsuba_{}.exr", b.scene.file_stem().unwrap_or_default().to_string_lossy())));
    let reference = match reference_path.as_ref().filter(|p| p.exists()) {
        Some(p) => volterra_formats::exr_io::read_exr(p, &b.env.limits)?,
        None => bail!("no Mitsuba reference beside {} (expected ../data/mitsuba_NAME.exr)", b.scene.display()),
    };
    let reference = rgba_pixels(&reference).iter().map(|p| [p[0], p[1], p[2], 0.0]).collect::<Vec<_>>();
    let ref_size = (scene.file.image.width, scene.file.image.height);
    let err_of = |f: &Frame| rgba_rel_rmse(&f.rgba.iter().map(|p| [p[0], p[1], p[2], 0.0]).collect::<Vec<_>>(), &reference);

    let mut rows = Vec::new();
    // The four combinations of the paper's Table 1, then the default's two alternatives:
    // a shadow ray per sample instead of the transmittance grid, and the paper's local
    // free path −ln ξ / σ_t(x) instead of delta tracking (its bias shows as error).
    let configs = [
        (Store::PhotonMap, false, ShadowMode::Grid, FreeFlight::Delta, ""),
        (Store::PhotonMap, true, ShadowMode::Grid, FreeFlight::Delta, ""),
        (Store::ParticleMap, false, ShadowMode::Grid, FreeFlight::Delta, ""),
        (Store::ParticleMap, true, ShadowMode::Grid, FreeFlight::Delta, ""),
        (Store::ParticleMap, true, ShadowMode::Marched, FreeFlight::Delta, ", shadow rays"),
        (Store::ParticleMap, true, ShadowMode::Grid, FreeFlight::Local, ", local free path"),
    ];
    let bar = crate::progress::bar(configs.len() as u64, "smoke bench");
    for (store, irradiance, shadows, free_flight, variant) in configs {
        let name = format!(
            "{} {}{variant}",
            if store == Store::PhotonMap { "photon map" } else { "particle map" },
            if irradiance { "+ irradiance map" } else { "direct" }
        );
        // The paper gathers up to 500 photons; 100 keeps the direct photon-map row in minutes.
        let s = Settings {
            store,
            irradiance_map: irradiance,
            shadows,
            free_flight,
            photons: b.photons,
            samples: 4,
            gather: 100,
            cache: false,
            ..Default::default()
        };
        let timed = render(&scene, node, &s, (b.width, b.height))?;
        let check = render(&scene, node, &s, ref_size)?;
        let memory = ["particle map MB", "photon map MB", "irradiance map MB"].iter().map(|k| counter(&timed, k)).sum::<f64>();
        rows.push(Row {
            config: name,
            total_s: timed.stats.seconds,
            trace_s: counter(&timed, "photon tracing s"),
            store_s: counter(&timed, "photon store s"),
            march_s: counter(&timed, "ray marching s"),
            rel_rmse: err_of(&check),
            memory_mb: memory,
            view_s: check.stats.seconds,
        });
        bar.inc(1);
    }
    bar.finish_and_clear();
    match mitsuba_rows(b, ref_size, &reference) {
        Ok(r) => rows.extend(r),
        Err(e) => eprintln!("Mitsuba rows skipped: {e:#}"),
    }
    if b.json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
        return Ok(());
    }
    println!(
        "{}: {}×{} timing image, 4 rays/pixel, {} photons; error on the {}×{} view against Mitsuba 8192 spp; {} threads",
        b.scene.display(),
        b.width,
        b.height,
        b.photons,
        ref_size.0,
        ref_size.1,
        rayon::current_num_threads()
    );
    println!(
        "{:<50} {:>9} {:>9} {:>9} {:>9} {:>10} {:>10} {:>8}",
        "config", "total s", "trace s", "store s", "march s", "rel. RMSE", "memory MB", "view s"
    );
    for r in &rows {
        println!(
            "{:<50} {:>9.2} {:>9.2} {:>9.2} {:>9.2} {:>9.2}% {:>10.1} {:>8.2}",
            r.config,
            r.total_s,
            r.trace_s,
            r.store_s,
            r.march_s,
            100.0 * r.rel_rmse,
            r.memory_mb,
            r.view_s
        );
    }
    Ok(())
}

/// Mitsuba at rising sample counts on the comparison view: render time against error.
fn mitsuba_rows(b: &SmokeBench, size: (usize, usize), reference: &[[f32; 4]]) -> Result<Vec<Row>> {
    let mut rows = Vec::new();
    for spp in [16, 64, 256, 1024] {
        let out_dir = b.env.work_dir.join(format!("mitsuba_{spp}"));
        let out = std::process::Command::new(&b.env.python)
            .arg(b.env.scripts.join("mitsuba_smoke.py"))
            .arg(&out_dir)
            .arg(spp.to_string())
            .arg(&b.scene)
            .output()
            .with_context(|| format!("cannot run {}", b.env.python.display()))?;
        if !out.status.success() {
            bail!("mitsuba_smoke.py failed: {}", crate::child::last_line(&out.stderr));
        }
        // "mitsuba WxH at N spp in T s" on stderr: the render alone, without the resampling.
        let stderr = String::from_utf8_lossy(&out.stderr);
        let seconds = stderr
            .lines()
            .find_map(|l| {
                l.strip_prefix("mitsuba ")
                    .and_then(|r| r.rsplit_once(" in "))
                    .and_then(|(_, t)| t.trim_end_matches(" s").parse::<f64>().ok())
            })
            .context("no timing from mitsuba_smoke.py")?;
        let stem = b.scene.file_stem().unwrap_or_default().to_string_lossy().to_string();
        let img = volterra_formats::exr_io::read_exr(&out_dir.join(format!("mitsuba_{stem}.exr")), &b.env.limits)?;
        let rgb: Vec<[f32; 4]> = rgba_pixels(&img).iter().map(|p| [p[0], p[1], p[2], 0.0]).collect();
        if rgb.len() != size.0 * size.1 {
            bail!("Mitsuba image size differs");
        }
        rows.push(Row {
            config: format!("mitsuba volpath {spp} spp ({}×{})", size.0, size.1),
            total_s: seconds,
            trace_s: 0.0,
            store_s: 0.0,
            march_s: seconds,
            rel_rmse: rgba_rel_rmse(&rgb, reference),
            memory_mb: 0.0,
            view_s: seconds,
        });
    }
    Ok(rows)
}
