//! `volterra bench smoke`: the four configurations of the paper's Table 1 — photon map or
//! particle map, with or without the irradiance map — and two variants of the default
//! (shadow rays instead of the transmittance grid; the paper's biased local free path), on
//! the 110k-particle plume with 640k photons and 4 rays per pixel: photon tracing, store,
//! irradiance-map + ray-marching times and memory at the timing image size, and each one's
//! error against Mitsuba 3 on the comparison view
//! (tests/reference/smoke_scenes/plume110k.toml, 8192 spp, committed). Then Mitsuba's own
//! time to reach comparable errors at rising sample counts; `view s` is each one's time for
//! the comparison view itself, so time and error compare on one image.
//!
//! Then the race (alone with `--race-only`): the first view at the renderer's defaults —
//! particles loaded, photons traced, no cache — of the bench scene's plume and of the
//! built-in 400k-particle plume (tests/reference/bench_scenes/plume400k.toml, its
//! reference committed; `volterra::samples::write_large_plume` writes the particles) on
//! the comparison view and at 400², against Mitsuba at 64, 256 and 1024 spp in the same
//! run: Mitsuba's time for our error, interpolated between its rows. At 400² there is no
//! 8192 spp reference (half an hour of Mitsuba on 2 cores): two Mitsuba renders with
//! independent seeds stand in for it (`two_render_errors`): their difference measures
//! Mitsuba's noise, and our distance from their mean, less that noise, our error — checked
//! on the comparison view against the 8192 spp reference in the same run. Mitsuba's time
//! for our error there follows from its noise falling as 1/√spp.

use super::report::{Report, Table};
use anyhow::{bail, Context, Result};
use serde::Serialize;
use std::path::{Path, PathBuf};
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
    /// Only the first-view race against Mitsuba, not the paper's table.
    pub race_only: bool,
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
    f.stats.counter(name).unwrap_or(0.0)
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
    let table = if b.race_only { None } else { Some(table(b)?) };
    // The race: the bench scene's plume and the large built-in one, written where its
    // scene (tests/reference/bench_scenes/plume400k.toml) reads it.
    let large_scene = b.env.scripts.join("bench_scenes/plume400k.toml");
    let samples = b.env.scripts.join("../../target/builtin-samples");
    // Written afresh, and put in place only where it differs from the file there (an
    // older generator's), so Mitsuba's density grid cached for the file is kept otherwise.
    let fresh = samples.join("plume400k-fresh");
    std::fs::create_dir_all(&fresh)?;
    volterra::samples::write_large_plume(&fresh)?;
    let (new, old) = (fresh.join("smoke_plume_400k.vtp"), samples.join("smoke_plume_400k.vtp"));
    if std::fs::read(&old).ok() != Some(std::fs::read(&new)?) {
        std::fs::rename(&new, &old)?;
    }
    std::fs::remove_dir_all(&fresh)?;
    let mut races = Vec::new();
    for scene in [b.scene.clone(), large_scene] {
        races.push(race(b, &scene)?);
    }
    if b.json {
        let rows = table.as_ref().map(|t| t.0.clone()).unwrap_or_default();
        println!("{}", serde_json::to_string_pretty(&serde_json::json!({ "table": rows, "races": races }))?);
    }
    let mut report = Report::new("smoke", TABLES);
    if let Some((rows, view)) = &table {
        report_table(b, rows, *view, &mut report);
    }
    report_races(&races, &mut report);
    report.finish(b.json, b.env.markdown.as_deref())
}

/// The columns of the bench's table.
const COLUMNS: &[&str] = &["config", "total s", "trace s", "store s", "march s", "rel. RMSE %", "memory MB", "view s"];
pub const TABLES: &[&[&str]] = &[COLUMNS];

/// The paper's Table 1 and its two variants, then Mitsuba's rows, on the bench scene.
fn table(b: &SmokeBench) -> Result<(Vec<Row>, (usize, usize))> {
    let scene = Scene::load(&b.scene, &[])?.with_limits(b.env.limits);
    let node = scene.nodes().iter().position(|n| n.kind == NodeKind::Particles).context("the bench scene needs a particle node")?;
    let reference = reference_of(b, &b.scene)?;
    let ref_size = (scene.file.image.width, scene.file.image.height);
    let err_of = |f: &Frame| rgba_rel_rmse(&rgb_only(&f.rgba), &reference);

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
    Ok((rows, ref_size))
}

fn report_table(b: &SmokeBench, rows: &[Row], ref_size: (usize, usize), report: &mut Report) {
    report.line(format!(
        "{}: {}×{} timing image, 4 rays/pixel, {} photons; error on the {}×{} view against Mitsuba 8192 spp; {} threads.",
        b.scene.display(),
        b.width,
        b.height,
        b.photons,
        ref_size.0,
        ref_size.1,
        rayon::current_num_threads()
    ));
    let mut table = Table::new(COLUMNS);
    for r in rows {
        table.row(vec![
            r.config.clone(),
            format!("{:.2}", r.total_s),
            format!("{:.2}", r.trace_s),
            format!("{:.2}", r.store_s),
            format!("{:.2}", r.march_s),
            format!("{:.2}", 100.0 * r.rel_rmse),
            format!("{:.1}", r.memory_mb),
            format!("{:.2}", r.view_s),
        ]);
    }
    report.table(table);
}

/// One plume's first view at the renderer's defaults (photons traced, no cache) against
/// Mitsuba: the error on the comparison view, and the time at that view and at 400².
#[derive(Debug, Clone, Serialize)]
pub struct Race {
    pub plume: String,
    pub particles: usize,
    pub view: (usize, usize),
    /// Loading the particles and rendering, every phase included.
    pub ours_s: f64,
    pub ours_rel_rmse: f64,
    /// Mitsuba's rows on the view: sample count, seconds, relative RMSE.
    pub mitsuba: Vec<(usize, f64, f64)>,
    /// Mitsuba's seconds for our error (see [`seconds_at_error`]), and whether extrapolated.
    pub mitsuba_s_at_our_error: Option<(f64, bool)>,
    pub ours_large_s: f64,
    pub large: (usize, usize),
    /// Mitsuba's seconds per sample per pixel at the large size.
    pub mitsuba_large_s_per_spp: f64,
    /// On the view: our error and Mitsuba's at its largest row as two renders with
    /// independent seeds estimate them, without the reference (checks the estimator).
    pub view_two_render: (f64, f64),
    /// At the large size, from two Mitsuba renders of `LARGE_SPP` (independent seeds): our
    /// error, Mitsuba's error at that count, and its sample count and seconds for our error.
    pub large_ours_rel_rmse: f64,
    pub large_mitsuba_rel_rmse: f64,
    pub large_mitsuba_spp_at_our_error: f64,
    pub large_mitsuba_s_at_our_error: f64,
}

const LARGE: (usize, usize) = (400, 400);
const RACE_COUNTS: [usize; 3] = [64, 256, 1024];
/// Samples per pixel of the two Mitsuba renders at the large size: their noise near our
/// error (the 110k plume's needs ≈ 600), so that removing it leaves ours precise.
const LARGE_SPP: usize = 256;

fn race(b: &SmokeBench, scene_path: &Path) -> Result<Race> {
    let t = std::time::Instant::now();
    let scene = Scene::load(scene_path, &[])?.with_limits(b.env.limits);
    let node = scene.nodes().iter().position(|n| n.kind == NodeKind::Particles).context("the race scene needs a particle node")?;
    let particles = scene.particles(node)?.len();
    let view = (scene.file.image.width, scene.file.image.height);
    let defaults = Settings { cache: false, ..Default::default() };
    let ours = render(&scene, node, &defaults, view)?;
    let ours_s = t.elapsed().as_secs_f64();
    let reference = reference_of(b, scene_path)?;
    let error = |rgb: &[[f32; 4]]| rgba_rel_rmse(rgb, &reference);
    let ours_rel_rmse = error(&rgb_only(&ours.rgba));
    // Loaded again: the large view is a first view too, its load included.
    let t = std::time::Instant::now();
    let scene = Scene::load(scene_path, &[])?.with_limits(b.env.limits);
    let ours_large = render(&scene, node, &defaults, LARGE)?;
    let ours_large_s = t.elapsed().as_secs_f64();
    let runs = mitsuba_runs(b, scene_path, &RACE_COUNTS, view, None, 1)?;
    let mitsuba: Vec<(usize, f64, f64)> = runs.iter().map(|r| (r.spp, r.seconds, error(&r.rgb))).collect();
    let rows: Vec<(f64, f64)> = mitsuba.iter().map(|r| (r.1, r.2)).collect();
    // The estimator checked where the reference exists: the largest row again, another seed.
    let last = runs.last().context("no Mitsuba rows")?;
    let again = mitsuba_runs(b, scene_path, &[last.spp], view, None, 2)?;
    let view_two_render = two_render_errors(&rgb_only(&ours.rgba), &last.rgb, &again[0].rgb);
    let large: Vec<MitsubaRun> = [1, 2]
        .into_iter()
        .map(|seed| mitsuba_runs(b, scene_path, &[LARGE_SPP], LARGE, Some(LARGE), seed))
        .collect::<Result<Vec<_>>>()?
        .into_iter()
        .flatten()
        .collect();
    let (large_ours, large_mitsuba) = two_render_errors(&rgb_only(&ours_large.rgba), &large[0].rgb, &large[1].rgb);
    let large_s_per_spp = 0.5 * (large[0].seconds + large[1].seconds) / LARGE_SPP as f64;
    // Monte-Carlo noise falls as 1/√spp: the count whose noise is our error.
    let large_spp = LARGE_SPP as f64 * (large_mitsuba / large_ours).powi(2);
    Ok(Race {
        plume: scene_path.file_stem().unwrap_or_default().to_string_lossy().to_string(),
        particles,
        view,
        ours_s,
        ours_rel_rmse,
        mitsuba_s_at_our_error: seconds_at_error(&rows, ours_rel_rmse),
        mitsuba,
        ours_large_s,
        large: LARGE,
        mitsuba_large_s_per_spp: large_s_per_spp,
        view_two_render,
        large_ours_rel_rmse: large_ours,
        large_mitsuba_rel_rmse: large_mitsuba,
        large_mitsuba_spp_at_our_error: large_spp,
        large_mitsuba_s_at_our_error: large_spp * large_s_per_spp,
    })
}

/// Colour without alpha: Mitsuba's images have none, and the errors compare colour only.
fn rgb_only(rgba: &[[f32; 4]]) -> Vec<[f32; 4]> {
    rgba.iter().map(|p| [p[0], p[1], p[2], 0.0]).collect()
}

/// The committed Mitsuba reference (8192 spp) of a bench scene: ../data/mitsuba_NAME.exr
/// beside its folder, as RGB.
fn reference_of(b: &SmokeBench, scene: &Path) -> Result<Vec<[f32; 4]>> {
    let path = scene
        .parent()
        .and_then(|d| d.parent())
        .map(|d| d.join("data").join(format!("mitsuba_{}.exr", scene.file_stem().unwrap_or_default().to_string_lossy())));
    let Some(p) = path.filter(|p| p.exists()) else {
        bail!("no Mitsuba reference beside {} (expected ../data/mitsuba_NAME.exr)", scene.display())
    };
    let img = volterra_formats::exr_io::read_exr(&p, &b.env.limits)?;
    Ok(rgb_only(&rgba_pixels(&img)))
}

fn report_races(races: &[Race], report: &mut Report) {
    report.line("First view at the defaults (photons traced, no cache; load included) against Mitsuba volpath (its render alone):");
    for r in races {
        report.line(format!(
            "{} ({} particles), {}×{}: ours {:.2} s at {:.2}%; Mitsuba {}",
            r.plume,
            r.particles,
            r.view.0,
            r.view.1,
            r.ours_s,
            100.0 * r.ours_rel_rmse,
            r.mitsuba.iter().map(|m| format!("{} spp {:.2} s {:.2}%", m.0, m.1, 100.0 * m.2)).collect::<Vec<_>>().join(", ")
        ));
        match r.mitsuba_s_at_our_error {
            Some((s, extrapolated)) => report.line(format!(
                "  Mitsuba at our error: {:.2} s ({}) — ours {:.1}× faster",
                s,
                if extrapolated { "extrapolated past its last row" } else { "interpolated between its rows" },
                s / r.ours_s
            )),
            None => report.line("  Mitsuba at our error: not found from its rows"),
        }
        let (e, m) = r.view_two_render;
        report.line(format!(
            "  the two-render estimate on this view (Mitsuba {} spp, seeds 1 and 2, no reference): ours {:.2}% (against the reference {:.2}%), Mitsuba {:.2}% (against the reference {:.2}%)",
            r.mitsuba.last().map_or(0, |m| m.0),
            100.0 * e,
            100.0 * r.ours_rel_rmse,
            100.0 * m,
            100.0 * r.mitsuba.last().map_or(f64::NAN, |m| m.2)
        ));
        report.line(format!(
            "  {}×{}: ours {:.2} s at {:.2}% (two Mitsuba renders of {LARGE_SPP} spp: {:.2}% each, {:.3} s per spp); Mitsuba at our error: {:.0} spp, {:.0} s — ours {:.1}× faster",
            r.large.0,
            r.large.1,
            r.ours_large_s,
            100.0 * r.large_ours_rel_rmse,
            100.0 * r.large_mitsuba_rel_rmse,
            r.mitsuba_large_s_per_spp,
            r.large_mitsuba_spp_at_our_error,
            r.large_mitsuba_s_at_our_error,
            r.large_mitsuba_s_at_our_error / r.ours_large_s
        ));
    }
}

/// Relative RMSE of `ours` and of one Mitsuba render against the truth, estimated from two
/// Mitsuba renders `a` and `b` with independent seeds and no reference: Mitsuba is
/// unbiased, so |a − b|² is twice its noise, and our squared distance from their mean is
/// our squared error plus half that noise (the cross terms vanish in expectation). Both
/// relative to the mean image.
pub fn two_render_errors(ours: &[[f32; 4]], a: &[[f32; 4]], b: &[[f32; 4]]) -> (f64, f64) {
    let (mut diff, mut from_mean, mut norm) = (0.0f64, 0.0f64, 0.0f64);
    for ((o, p), q) in ours.iter().zip(a).zip(b) {
        for k in 0..4 {
            let (p, q, o) = (p[k] as f64, q[k] as f64, o[k] as f64);
            let m = 0.5 * (p + q);
            diff += (p - q).powi(2);
            from_mean += (o - m).powi(2);
            norm += m * m;
        }
    }
    let noise = diff / 2.0;
    (((from_mean - noise / 2.0).max(0.0) / norm).sqrt(), (noise / norm).sqrt())
}

/// One Mitsuba render of a bench scene: sample count, seconds (the render alone, without
/// resampling the density), and RGB.
struct MitsubaRun {
    spp: usize,
    seconds: f64,
    rgb: Vec<[f32; 4]>,
}

/// Mitsuba at the given sample counts on `scene`'s view, in one run of mitsuba_smoke.py
/// (the density grid resampled once), with sampler seed `seed`: not the committed
/// reference's (0), so that each run's noise is independent of the reference's.
fn mitsuba_runs(
    b: &SmokeBench,
    scene: &Path,
    counts: &[usize],
    size: (usize, usize),
    image: Option<(usize, usize)>,
    seed: u64,
) -> Result<Vec<MitsubaRun>> {
    let stem = scene.file_stem().unwrap_or_default().to_string_lossy().to_string();
    let out_dir = b.env.work_dir.join(format!("mitsuba_{stem}_{}x{}_seed{seed}", size.0, size.1));
    let list = counts.iter().map(|c| c.to_string()).collect::<Vec<_>>().join(",");
    let out = std::process::Command::new(&b.env.python)
        .arg(b.env.scripts.join("mitsuba_smoke.py"))
        .arg(&out_dir)
        .arg(&list)
        .args(["--seed", &seed.to_string()])
        .args(image.map(|(w, h)| vec!["--image".to_string(), format!("{w}x{h}")]).unwrap_or_default())
        .arg(scene)
        .output()
        .with_context(|| format!("cannot run {}", b.env.python.display()))?;
    if !out.status.success() {
        bail!("mitsuba_smoke.py failed: {}", crate::child::last_line(&out.stderr));
    }
    // "mitsuba WxH at N spp in T s" on stderr, one line per sample count.
    let stderr = String::from_utf8_lossy(&out.stderr);
    let mut runs = Vec::new();
    for &spp in counts {
        let seconds = stderr
            .lines()
            .find_map(|l| {
                let rest = l.strip_prefix("mitsuba ")?;
                let (head, t) = rest.rsplit_once(" in ")?;
                head.ends_with(&format!(" at {spp} spp")).then(|| t.trim_end_matches(" s").parse::<f64>().ok()).flatten()
            })
            .with_context(|| format!("no timing for {spp} spp from mitsuba_smoke.py"))?;
        // One sample count keeps the script's plain name.
        let name = if counts.len() == 1 { format!("mitsuba_{stem}.exr") } else { format!("mitsuba_{stem}_{spp}.exr") };
        let img = volterra_formats::exr_io::read_exr(&out_dir.join(name), &b.env.limits)?;
        let rgb = rgb_only(&rgba_pixels(&img));
        if rgb.len() != size.0 * size.1 {
            bail!("Mitsuba image size differs");
        }
        runs.push(MitsubaRun { spp, seconds, rgb });
    }
    Ok(runs)
}

/// Mitsuba at rising sample counts on the comparison view: render time against error.
fn mitsuba_rows(b: &SmokeBench, size: (usize, usize), reference: &[[f32; 4]]) -> Result<Vec<Row>> {
    Ok(mitsuba_runs(b, &b.scene, &[16, 64, 256, 1024], size, None, 1)?
        .into_iter()
        .map(|r| Row {
            config: format!("mitsuba volpath {} spp ({}×{})", r.spp, size.0, size.1),
            total_s: r.seconds,
            trace_s: 0.0,
            store_s: 0.0,
            march_s: r.seconds,
            rel_rmse: rgba_rel_rmse(&r.rgb, reference),
            memory_mb: 0.0,
            view_s: r.seconds,
        })
        .collect())
}

/// Mitsuba's seconds to reach `error`, from (seconds, error) rows at rising sample counts:
/// interpolated linearly in log error against log time between the two rows around it, or
/// extrapolated from the nearest two when `error` lies outside the rows' (then the flag
/// is true).
pub fn seconds_at_error(rows: &[(f64, f64)], error: f64) -> Option<(f64, bool)> {
    if rows.len() < 2 || error <= 0.0 {
        return None;
    }
    let (i, extrapolated) = match rows.windows(2).position(|w| w[0].1 >= error && error >= w[1].1) {
        Some(i) => (i, false),
        None if error < rows[rows.len() - 1].1 => (rows.len() - 2, true),
        None => (0, true),
    };
    let ((t0, e0), (t1, e1)) = (rows[i], rows[i + 1]);
    if !(e0 > e1 && t1 > t0) {
        return None;
    }
    let s = (error.ln() - e0.ln()) / (e1.ln() - e0.ln());
    Some(((t0.ln() + s * (t1.ln() - t0.ln())).exp(), extrapolated))
}

#[cfg(test)]
mod tests {
    use super::{seconds_at_error, two_render_errors};

    /// A known truth, ours off it by a known error, two noisy renders of it: the estimate
    /// without the truth finds both errors, including when the renders' noise is larger
    /// than our error (heavy-tailed noise, as a path tracer's fireflies).
    #[test]
    fn two_renders_with_independent_seeds_estimate_both_errors() {
        let mut rng = volterra_formats::rng::Rng::new(7);
        let n = 200_000;
        let truth: Vec<[f32; 4]> =
            (0..n).map(|i| [0.2 + 0.6 * (i % 97) as f32 / 97.0, 0.3, 0.1 + 0.2 * (i % 13) as f32 / 13.0, 0.0]).collect();
        let norm = truth.iter().map(|p| p.iter().map(|&v| (v as f64).powi(2)).sum::<f64>()).sum::<f64>().sqrt();
        let rms = |img: &[[f32; 4]]| {
            img.iter().zip(&truth).map(|(p, q)| (0..4).map(|k| ((p[k] - q[k]) as f64).powi(2)).sum::<f64>()).sum::<f64>().sqrt() / norm
        };
        // Ours: a smooth bias of a few per cent.
        let ours: Vec<[f32; 4]> = truth.iter().enumerate().map(|(i, p)| p.map(|v| v * (1.0 + 0.05 * ((i as f32) * 0.001).sin()))).collect();
        for scale in [0.5f64, 1.0, 2.0] {
            let mut noisy = || -> Vec<[f32; 4]> {
                truth
                    .iter()
                    .map(|p| {
                        p.map(|v| {
                            // Zero-mean, heavy-tailed: mostly small, now and then ten times larger.
                            let big = if rng.uniform() < 0.01 { 10.0 } else { 1.0 };
                            v + (scale * 0.03 * big * (rng.uniform() - 0.5)) as f32 * v
                        })
                    })
                    .collect()
            };
            let (a, b) = (noisy(), noisy());
            let (e, m) = two_render_errors(&ours, &a, &b);
            let (e_true, m_true) = (rms(&ours), 0.5 * (rms(&a) + rms(&b)));
            assert!((e / e_true - 1.0).abs() < 0.05, "noise ×{scale}: ours {e} against {e_true}");
            assert!((m / m_true - 1.0).abs() < 0.05, "noise ×{scale}: the renders' {m} against {m_true}");
        }
    }

    /// Rows on error ∝ time^(−1/2), as Monte-Carlo noise: every error is found at the
    /// time that law gives, inside the rows, past the last and before the first.
    #[test]
    fn mitsubas_time_at_an_error_follows_its_rows() {
        let rows: Vec<(f64, f64)> = [1.0, 4.0, 16.0].iter().map(|&t| (t, 0.2 / f64::sqrt(t))).collect();
        for (error, extrapolated) in [(0.2 / 2.5, false), (0.2 / 3.0, false), (0.2 / 8.0, true), (0.2 / 0.5, true)] {
            let (t, flag) = seconds_at_error(&rows, error).unwrap();
            let expected = (0.2 / error) * (0.2 / error);
            assert!((t / expected - 1.0).abs() < 1e-12, "error {error}: {t} s, expected {expected}");
            assert_eq!(flag, extrapolated, "error {error}");
        }
        assert_eq!(seconds_at_error(&rows[..1], 0.1), None);
        assert_eq!(seconds_at_error(&[(1.0, 0.1), (2.0, 0.2)], 0.15), None, "rows whose error rises with time");
    }
}
