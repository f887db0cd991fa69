//! `smoke`: particle-map smoke (Song & Ihm) for particle nodes — the SPH density of the
//! particles as the medium, photons traced once and deposited on the particles (or stored
//! in a classic volume photon map), an irradiance map of the multiply-scattered source,
//! and ray marching with exact single scattering.
//!
//! - `medium`: SPH density (cubic spline or poly6), majorant grid, homogeneous test media;
//!   `point_grid`: the uniform grid its neighbour and ray-band searches run on;
//! - `tracking`: delta tracking, the paper's local free path, ratio tracking, marched
//!   transmittance;
//! - `phase`, `lights`: Henyey–Greenstein, photon emission (random numbers:
//!   `volterra_formats::rng`);
//! - `photons`: photon tracing; `store`: particle map and photon map;
//! - `grid`: lazily filled grids (irradiance map, transmittance grid); `march`: the camera.

pub mod cache;
pub mod density_grid;
pub mod extinction;
pub mod grid;
pub mod lights;
pub mod march;
pub mod medium;
pub mod phase;
pub mod photons;
pub mod point_grid;
pub mod store;
pub mod tracking;

use super::registry::{NodeSettings, RendererDecl};
use super::settings::{Bounds, Control, Preview, Widget};
use crate::render::Frame;
use crate::scene::camera::RayGenerator;
use crate::scene::NodeKind;
use crate::scene::{Light, Medium as MediumParams};
use anyhow::{bail, Result};
use glam::{DMat3, DMat4, DVec3};
use medium::{Kernel, SphMedium};
use std::time::Instant;
use volterra_formats::{Limits, ParticleSet};

crate::setting_choice! {
    /// Where multiply-scattered light comes from.
    pub enum Store {
        /// The paper's particle map: photon power split over the particles by kernel weight.
        ParticleMap = "particle-map",
        /// The classic volume photon map (kd-tree, k nearest photons).
        PhotonMap = "photon-map",
        /// None: single scattering only.
        None = "none",
    }
}

crate::setting_choice! {
    /// How photons find their next collision.
    pub enum FreeFlight {
        /// Delta tracking against majorants: unbiased in a heterogeneous medium.
        Delta = "delta",
        /// The paper's −ln ξ / σ_t(x) with σ_t where the photon is: biased; for comparison.
        Local = "local",
    }
}

crate::setting_choice! {
    /// Which density a part of the renderer meets: the resampled grid or the particles.
    pub enum Density {
        /// The grid where it resolves the particles — its spacing no larger than the h of
        /// the smallest tenth of them (the plumes': 0.6 and 0.9 of it) — else the exact
        /// sum, with a note: smoothing lengths spread over a decade or more leave the
        /// smallest kernels a sample or less of the grid, which blurs them.
        Auto = "auto",
        /// The SPH density resampled every half median h and interpolated trilinearly
        /// (`smoke::density_grid`): a density query is eight loads instead of a sum over
        /// the particles near the point. The 110k and 400k plumes' images move by 0.1–0.2 %
        /// (relative RMSE) from the exact sum's; smoke with a hard surface (optical depth ≫ 1
        /// within a kernel's width) comes out up to 12 % darker, as the kernel's convex
        /// tail interpolated linearly thickens the surface: use `particles` there.
        Grid = "grid",
        /// The exact SPH sum.
        Particles = "particles",
    }
}

crate::setting_choice! {
    /// How the light reaching a sample from a light source is attenuated.
    pub enum ShadowMode {
        /// A transmittance grid per light (the irradiance map's resolution), filled lazily.
        Grid = "grid",
        /// A shadow ray marched per sample.
        Marched = "marched",
    }
}

crate::declare_settings! {
    pub struct Settings {
        /// Photons traced (over all lights). 640k, the paper's count: with photons flying
        /// through the density grid they cost ~0.5 s on 2 cores for the 110k and 400k plumes,
        /// and the first view's error against Mitsuba fell from 6.9 % (200k) to 4.3 % (110k)
        /// and from 8.0 % to 5.2 % (400k).
        pub photons: usize = 640_000, quality = true,
            viewer = Control { label: "Photons", widget: Widget::Drag { lo: 1000.0, hi: 100_000_000.0, speed: 1000.0 } };
        /// Where multiply-scattered light comes from.
        pub store: Store = Store::ParticleMap;
        /// Photon map: photons gathered per estimate (k).
        pub gather: usize = 100, range = Bounds::at_least(1.0), quality = true;
        /// Photon map: largest gather radius.
        pub gather_radius: f64 = 0.0, unit = "m", range = Bounds::above(0.0), zero = "auto: 4 × the median h", quality = true;
        /// Precompute the multiply-scattered source on a grid and interpolate it.
        pub irradiance_map: bool = true, quality = true;
        /// Irradiance-map spacing; the transmittance grid's is twice it.
        pub irradiance_cell: f64 = 0.0, unit = "m", range = Bounds::above(0.0), zero = "auto: the median h", quality = true;
        /// March step (camera rays and the transmittance grid's shadow rays) as a multiple
        /// of the median h. Two h by default: a particle's support spans 4h and each ray's
        /// steps start at a random offset, so coarser steps add noise that the pixel's rays
        /// average, not bias. Against Mitsuba (8192 spp) at 32 rays per pixel and 1M
        /// photons, steps of h, 2h and 3h: the 110k plume 3.17, 3.18, 3.19 %, the 400k
        /// plume 3.91, 3.89, 3.87 % (4h: 3.97 %); at the defaults (4 rays per pixel) 4.27,
        /// 4.31, 4.46 % and 5.20, 5.20, 5.48 %. Half the samples per kernel's chord and
        /// half the light and irradiance look-ups: the 400k plume's march through the
        /// particles at 400² took 13 % less time (3.4 → 3.0 s, 2 cores).
        pub step: f64 = 2.0, unit = "h", range = Bounds::above(0.0), quality = true;
        /// Camera rays per pixel, stratified over the pixel.
        pub samples: usize = 4, range = Bounds::at_least(1.0), quality = true, preview = Preview::AtMost(1.0);
        /// Seed of the photon and camera random numbers.
        pub seed: u64 = 1, quality = true;
        /// How photons find their next collision.
        pub free_flight: FreeFlight = FreeFlight::Delta;
        /// The density light from the sources meets (photon flights, the transmittance
        /// grid's shadow rays): the SPH density on a grid of half the median h (trilinear),
        /// or the particles' exact sum.
        pub light_density: Density = Density::Grid, quality = true;
        /// The density the camera's rays march through. The grid where it resolves the
        /// particles (`auto`, the default; the 110k and 400k plumes'): with the same
        /// photons and rays (32 per pixel) the 110k and 400k plumes' images differ from the
        /// exact sum's by 0.12 % and 0.18 % (relative RMSE; alpha 0.23 % and 0.30 %); against
        /// Mitsuba (8192 spp, its density gridded at the same spacing) at 32 rays per pixel
        /// the 110k and 400k plumes come within 3.19 % and 3.90 % on the grid, 3.18 % and
        /// 3.89 % with the exact sum (at the defaults 4.31 / 5.19 % and 4.31 / 5.20 %),
        /// and the 400k plume's march at 400² takes 0.9 s instead of 2.5 s (2 cores): the
        /// sum gathers ~140 particles per ray. `particles` for smoke with a hard surface.
        pub camera_density: Density = Density::Auto, quality = true;
        /// How light from a source is attenuated on its way to a sample.
        pub shadows: ShadowMode = ShadowMode::Grid, quality = true;
        /// The SPH smoothing kernel.
        pub kernel: Kernel = Kernel::CubicSpline;
        /// Photon paths stop after this many scatterings (counted in the statistics).
        pub max_bounces: usize = 1000, quality = true;
        /// Keep traced photons on disk and reuse them for other views (see `smoke::cache`).
        pub cache: bool = true, quality = true;
    }
}

pub const RENDERER: RendererDecl = RendererDecl {
    name: "smoke",
    kind: NodeKind::Particles,
    doc: "Particle-map smoke (Song & Ihm): the particles' SPH density as the medium, photons \
          traced once and deposited on the particles (or a classic photon map), an irradiance \
          map, ray marching with exact single scattering. Needs `medium` and at least one light.",
    reference: false,
    settings: Settings::DECLS,
    parse: |t| Settings::from_table(t).map(NodeSettings::Smoke),
};

/// What the smoke renderer draws: one particle node.
pub struct SmokeInput<'a> {
    pub particles: &'a ParticleSet,
    pub node_to_world: DMat4,
    pub medium: &'a MediumParams,
    pub lights: &'a [Light],
    /// The memory limits the photon map is checked against.
    pub limits: Limits,
}

/// Checks the medium's parameters.
pub fn check_medium(m: &MediumParams) -> Result<()> {
    if let Some(c) = m.c_ext.filter(|c| !(c.is_finite() && *c >= 0.0)) {
        bail!("medium c_ext = {c} must be a non-negative number");
    }
    if !(0.0..=1.0).contains(&m.albedo) {
        bail!("medium albedo = {} must be between 0 and 1", m.albedo);
    }
    if !(m.g > -1.0 && m.g < 1.0) {
        bail!("medium g = {} must be strictly between -1 and 1", m.g);
    }
    Ok(())
}

/// The particles in world space as an SPH medium. A node transform moves the positions;
/// smoothing lengths scale by the cube root of its volume change.
pub fn build_medium(input: &SmokeInput, kernel: Kernel) -> Result<SphMedium> {
    let p = input.particles;
    if p.is_empty() {
        bail!("the particle set is empty: there is no smoke to render");
    }
    let (Some(mass), Some(h)) = (&p.mass, &p.smoothing_length) else {
        bail!("the particle set has no mass or smoothing length (the scene fills defaults; this is a bug)");
    };
    let m = input.node_to_world;
    let scale = DMat3::from_mat4(m).determinant().abs().cbrt();
    let positions = p.positions.iter().map(|x| m.transform_point3(DVec3::from(*x)).to_array()).collect();
    SphMedium::new(positions, mass.iter().map(|&v| v as f64).collect(), h.iter().map(|&v| v as f64 * scale).collect(), kernel)
}

/// The smoothing length below which a fraction `q` of the particles' lie.
fn h_quantile(medium: &SphMedium, q: f64) -> f64 {
    let mut h: Vec<f64> = (0..medium.len()).map(|i| medium.smoothing_length(i)).collect();
    if h.is_empty() {
        return 0.0;
    }
    let k = ((h.len() as f64 * q) as usize).min(h.len() - 1);
    *h.select_nth_unstable_by(k, f64::total_cmp).1
}

pub fn render(input: &SmokeInput, rays: &RayGenerator, s: &Settings) -> Result<Frame> {
    check_medium(input.medium)?;
    s.validate().map_err(|e| anyhow::anyhow!("{}: {e}", RENDERER.name))?;
    let start = Instant::now();
    // Each phase reported as it runs (photon tracing and ray marching count their own).
    let phase = crate::render::driver::Task::begin("smoke: the SPH medium", 1);
    let medium = build_medium(input, s.kernel)?;
    let (lo, hi) = medium::Medium::bounds(&medium);
    let mut emitters = lights::Emitter::from_scene(input.lights, lo, hi)?;
    for e in &mut emitters {
        e.fit_to(medium::Medium::majorants(&medium));
    }
    let h = h_quantile(&medium, 0.5);
    let step = s.step * h;
    let cell = if s.irradiance_cell > 0.0 { s.irradiance_cell } else { h };
    let mut notes = Vec::new();
    // No c_ext given: the one that gives the densest column an optical depth of 2.
    let c_ext = match input.medium.c_ext {
        Some(c) => c,
        None => {
            let auto = extinction::auto_extinction(&medium)
                .ok_or_else(|| anyhow::anyhow!("the particles have no mass: there is no smoke to render"))?;
            notes.push(format!(
                "c_ext chosen from the data: {:.6e} (optical depth {} through the densest column, {:.6e} mass per area)",
                auto.c_ext,
                extinction::TARGET_DEPTH,
                auto.column
            ));
            auto.c_ext
        }
    };
    let (albedo, g) = (input.medium.albedo, input.medium.g);
    let setup = start.elapsed().as_secs_f64();
    phase.advance(1);
    drop(phase);

    // The density resampled on a grid the first time photons, the transmittance grid or
    // the camera need it (see `Density`).
    let density_grid = std::cell::OnceCell::new();
    let grid_spacing = density_grid::DensityGrid::spacing(&medium, 0.5 * h);
    // What `Density::Auto` compares the spacing with (once, not per part that asks).
    let small = h_quantile(&medium, 0.1);
    let medium_of = |density: Density, what: &str, notes: &mut Vec<String>| -> Result<&dyn medium::Medium> {
        let density = match density {
            Density::Auto => {
                if grid_spacing <= small {
                    Density::Grid
                } else {
                    let note = format!(
                        "{what} through the particles: the density grid's spacing {grid_spacing:.3e} is larger than the \
                         h of the smallest tenth of them ({small:.3e}), which it would blur"
                    );
                    if !notes.contains(&note) {
                        notes.push(note);
                    }
                    Density::Particles
                }
            }
            d => d,
        };
        if density == Density::Particles {
            return Ok(&medium);
        }
        if density_grid.get().is_none() {
            // Over a second for the 400k plume: shown as a phase of its own.
            let phase = crate::render::driver::Task::begin("smoke: the density grid", 1);
            let t = Instant::now();
            let spacing = grid_spacing;
            let dims = density_grid::DensityGrid::dims_for(&medium, spacing);
            input.limits.check(std::path::Path::new("smoke"), "the density grid", &[dims[0] as u64, dims[1] as u64, dims[2] as u64, 4])?;
            let grid = density_grid::DensityGrid::new(&medium, spacing);
            if spacing > 0.5 * h * 1.0001 {
                notes.push(format!(
                    "the density grid is coarser than half the median h ({spacing:.3e} m) to stay within its {} samples: \
                     light_density / camera_density = \"particles\" for the exact sum",
                    density_grid::MAX_SAMPLES
                ));
            }
            notes.push(format!(
                "a {}×{}×{} density grid ({:.1} MB, spacing {:.3e}, built in {:.2} s)",
                dims[0],
                dims[1],
                dims[2],
                grid.memory() as f64 / 1e6,
                grid.spacing_m(),
                t.elapsed().as_secs_f64()
            ));
            let _ = density_grid.set(grid);
            phase.advance(1);
        }
        Ok(density_grid.get().expect("built above") as &dyn medium::Medium)
    };
    // Photons: view-independent, traced once per render here (cached across views later).
    let t = Instant::now();
    let mut cache_hit = false;
    let traced = if s.store == Store::None || albedo == 0.0 {
        None
    } else {
        let mut key = cache::Key::new();
        for i in 0..medium.len() {
            let p = medium.position(i);
            key.f64(p.x).f64(p.y).f64(p.z).f64(medium.mass(i)).f64(medium.smoothing_length(i));
        }
        key.str(&format!("{:?} {emitters:?} {:?} {:?}", s.kernel, s.free_flight, s.light_density));
        key.f64(c_ext).f64(albedo).f64(g).f64(step).u64(s.photons as u64).u64(s.seed).u64(s.max_bounces as u64);
        let key = key.finish();
        // At least one 72-byte record per traced photon (more where a photon collides often).
        input.limits.check(std::path::Path::new("smoke"), "the photon records", &[s.photons as u64, 72])?;
        let cached = if s.cache { cache::load(key) } else { None };
        if let Some(traced) = cached {
            cache_hit = true;
            notes.push(format!("photons from the cache ({} stored)", traced.photons.len()));
            Some(traced)
        } else {
            let ts = photons::TraceSettings {
                count: s.photons,
                seed: s.seed,
                c_ext,
                albedo,
                g,
                free_flight: s.free_flight,
                step,
                max_bounces: s.max_bounces,
            };
            let traced = photons::trace(medium_of(s.light_density, "photons and shadow rays", &mut notes)?, &emitters, &ts)?;
            if s.cache {
                if let Err(e) = cache::store(key, &traced) {
                    notes.push(format!("photon cache not written: {e}"));
                }
            }
            Some(traced)
        }
    };
    let trace_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let phase = crate::render::driver::Task::begin("smoke: storing photons", 1);
    let particle_map = match (&traced, s.store) {
        (Some(tr), Store::ParticleMap) => Some(store::ParticleMap::build(&medium, &tr.photons)),
        _ => None,
    };
    let photon_map = match (&traced, s.store) {
        (Some(tr), Store::PhotonMap) => {
            let radius = if s.gather_radius > 0.0 { s.gather_radius } else { 4.0 * h };
            Some(store::PhotonMap::build(tr.photons.clone(), s.gather, radius))
        }
        _ => None,
    };
    let store_s = t.elapsed().as_secs_f64();
    phase.advance(1);
    drop(phase);

    let source = |x: DVec3, out: DVec3| -> [f64; 3] {
        if let Some(pm) = &particle_map {
            pm.source(&medium, x, out, g)
        } else if let Some(pm) = &photon_map {
            pm.source(x, out, g)
        } else {
            [0.0; 3]
        }
    };
    // The irradiance map holds S toward the eye (perspective) or against the view
    // direction (parallel) at each grid point: the direction a camera ray leaves it in.
    let (eye, _, _) = rays.basis();
    let parallel = rays.is_parallel();
    let forward = rays.forward();
    let irradiance = grid::LazyGrid::new(lo, hi, cell);
    let mapped = |x: DVec3, _out: DVec3| -> [f64; 3] {
        irradiance.sample(x, &|p| {
            let out = if parallel { -forward } else { (eye - p).normalize_or(-forward) };
            source(p, out)
        })
    };
    let shadow_grids: Vec<grid::LazyGrid> = match s.shadows {
        // Optical depth varies more slowly than the scattered source — twice the cell —
        // but in dense smoke light dies within a mean free path, and the grid must resolve
        // that: no coarser than 1/σ_t at the median majorant.
        ShadowMode::Grid => {
            let maj = medium::Medium::majorants(&medium);
            let mut nonzero: Vec<f64> = maj.max.iter().cloned().filter(|&m| m > 0.0).collect();
            nonzero.sort_by(f64::total_cmp);
            let sigma = c_ext * nonzero.get(nonzero.len() / 2).copied().unwrap_or(0.0);
            let tcell = if sigma > 0.0 { (2.0 * cell).min(1.0 / sigma) } else { 2.0 * cell };
            emitters.iter().map(|_| grid::LazyGrid::new(lo, hi, tcell)).collect()
        }
        ShadowMode::Marched => Vec::new(),
    };
    // No photon stored (thin smoke, or none reached it): multiple scattering is zero, and
    // neither the irradiance map nor the store is consulted.
    let has_ms = traced.as_ref().is_some_and(|t| !t.photons.is_empty());
    if traced.as_ref().is_some_and(|t| t.photons.is_empty()) {
        notes.push("no photon scattered twice in the smoke: single scattering only".into());
    }
    let shadow_medium = medium_of(s.light_density, "photons and shadow rays", &mut notes)?;
    let direct: &(dyn Fn(DVec3, DVec3) -> [f64; 3] + Sync) = &source;
    let gridded: &(dyn Fn(DVec3, DVec3) -> [f64; 3] + Sync) = &mapped;
    let camera_medium = medium_of(s.camera_density, "the camera's march", &mut notes)?;
    let view = march::MarchView {
        medium: camera_medium,
        emitters: &emitters,
        c_ext,
        albedo,
        g,
        multiple: has_ms.then_some(if s.irradiance_map { gridded } else { direct }),
        transmittance: match s.shadows {
            ShadowMode::Marched => march::LightTransmittance::Marched { step, medium: shadow_medium },
            ShadowMode::Grid => march::LightTransmittance::Grid { grids: &shadow_grids, medium: shadow_medium },
        },
        step,
        samples: s.samples,
        seed: s.seed,
    };
    let t = Instant::now();
    let mut frame = march::render(&view, rays)?;
    let march_s = t.elapsed().as_secs_f64();

    let mut counters = vec![
        ("particles".to_string(), medium.len() as f64),
        ("median h".into(), h),
        ("c_ext".into(), c_ext),
        ("setup s".into(), setup),
        ("photon tracing s".into(), trace_s),
        ("photon store s".into(), store_s),
        ("ray marching s".into(), march_s),
    ];
    if let Some(tr) = &traced {
        counters.push(("photons stored".into(), tr.photons.len() as f64));
        counters.push(("photon paths at the bounce cap".into(), tr.capped as f64));
    }
    if let Some(pm) = &particle_map {
        counters.push(("particle map MB".into(), pm.memory() as f64 / 1e6));
    }
    if let Some(pm) = &photon_map {
        counters.push(("photon map MB".into(), pm.memory() as f64 / 1e6));
    }
    if s.irradiance_map && has_ms {
        counters.push(("irradiance points computed".into(), irradiance.computed_points() as f64));
        counters.push(("irradiance map MB".into(), irradiance.memory() as f64 / 1e6));
    }
    counters.push(("photon cache hit".into(), cache_hit as u8 as f64));
    frame.stats.counters = counters;
    frame.stats.notes.extend(notes);
    frame.stats.seconds = start.elapsed().as_secs_f64();
    frame.stats.notes.push(format!("{:?} + {}", s.store, if s.irradiance_map { "irradiance map" } else { "direct estimates" }));
    Ok(frame)
}
