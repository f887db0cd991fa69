//! What a smoke render keeps across views of the same particles: the SPH medium, the
//! density grid, the traced photons and their store, the transmittance grids of the
//! lights, and the irradiance map where it does not depend on the view (g = 0). A view
//! then costs its march alone, with the grid points earlier views computed already there.
//!
//! Every value a view reads is a function of the point alone (each grid point is
//! computed once, by whichever view first needs it, from the same photons), so a view
//! rendered after others is the same bit for bit as the view rendered alone — which an
//! animation's shards rely on.

use super::medium::{Medium, SphMedium};
use super::{build_medium, check_medium, Density, ShadowMode, SmokeInput, Store, RENDERER};
use super::{cache, density_grid, extinction, grid, lights, march, photons, store};
use crate::render::Frame;
use crate::scene::camera::RayGenerator;
use anyhow::Result;
use glam::DVec3;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::OnceLock;
use std::time::Instant;
use volterra_formats::Limits;

use super::Settings;

/// The view-independent part of a smoke render.
pub struct Prepared {
    /// The settings it was prepared with (a view's own: `samples`, `camera_density`).
    settings: Settings,
    medium: SphMedium,
    emitters: Vec<lights::Emitter>,
    limits: Limits,
    /// The median h, the march step and the irradiance map's cell (m).
    h: f64,
    step: f64,
    c_ext: f64,
    albedo: f64,
    g: f64,
    /// The density grid's spacing, and the h of the smallest tenth of the particles that
    /// `Density::Auto` compares it with.
    grid_spacing: f64,
    small_h: f64,
    /// The density resampled on a grid, built the first time photons, the transmittance
    /// grids or a camera need it, with its notes.
    density_grid: OnceLock<Result<(density_grid::DensityGrid, Vec<String>), String>>,
    /// Photons stored and photon paths cut at the bounce cap (None: none traced). The
    /// photons themselves live on in their store only.
    traced: Option<TracedCounts>,
    photon_cache_hit: bool,
    particle_map: Option<store::ParticleMap>,
    photon_map: Option<store::PhotonMap>,
    /// Optical depth toward each light (`shadows = "grid"`), filled lazily.
    shadow_grids: Vec<grid::LazyGrid>,
    /// The irradiance map when it holds the same for every view (g = 0: S does not
    /// depend on the direction light leaves in); None otherwise, and each view makes its
    /// own (S toward that view's eye).
    irradiance: Option<grid::LazyGrid>,
    cell: f64,
    /// Seconds spent preparing: setup (the medium), photon tracing, storing photons.
    seconds: [f64; 3],
    notes: Vec<String>,
    /// Views rendered from this preparation.
    views: AtomicUsize,
}

impl Prepared {
    pub fn new(input: &SmokeInput, s: &Settings) -> Result<Prepared> {
        check_medium(input.medium)?;
        s.validate().map_err(|e| anyhow::anyhow!("{}: {e}", RENDERER.name))?;
        let start = Instant::now();
        // Each phase reported as it runs (photon tracing and ray marching count their own).
        let phase = crate::render::driver::Task::begin("smoke: the SPH medium", 1);
        let medium = build_medium(input, s.kernel)?;
        let (lo, hi) = Medium::bounds(&medium);
        let mut emitters = lights::Emitter::from_scene(input.lights, lo, hi)?;
        for e in &mut emitters {
            e.fit_to(Medium::majorants(&medium));
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
        let grid_spacing = density_grid::DensityGrid::spacing(&medium, 0.5 * h);
        let small_h = h_quantile(&medium, 0.1);
        let setup = start.elapsed().as_secs_f64();
        phase.advance(1);
        drop(phase);

        let shadow_grids = match s.shadows {
            // Optical depth varies more slowly than the scattered source — twice the cell —
            // but in dense smoke light dies within a mean free path, and the grid must
            // resolve that: no coarser than 1/σ_t at the median majorant.
            ShadowMode::Grid => {
                let maj = Medium::majorants(&medium);
                let mut nonzero: Vec<f64> = maj.max.iter().cloned().filter(|&m| m > 0.0).collect();
                nonzero.sort_by(f64::total_cmp);
                let sigma = c_ext * nonzero.get(nonzero.len() / 2).copied().unwrap_or(0.0);
                let tcell = if sigma > 0.0 { (2.0 * cell).min(1.0 / sigma) } else { 2.0 * cell };
                emitters.iter().map(|_| grid::LazyGrid::new(lo, hi, tcell)).collect()
            }
            ShadowMode::Marched => Vec::new(),
        };
        let irradiance = (g == 0.0 && s.irradiance_map).then(|| grid::LazyGrid::new(lo, hi, cell));
        let mut p = Prepared {
            settings: s.clone(),
            medium,
            emitters,
            limits: input.limits,
            h,
            step,
            c_ext,
            albedo,
            g,
            grid_spacing,
            small_h,
            density_grid: OnceLock::new(),
            traced: None,
            photon_cache_hit: false,
            particle_map: None,
            photon_map: None,
            shadow_grids,
            irradiance,
            cell,
            seconds: [setup, 0.0, 0.0],
            notes,
            views: AtomicUsize::new(0),
        };

        // Photons: traced once (and kept on disk for other processes: `smoke::cache`).
        let t = Instant::now();
        let mut traced_photons = None;
        if s.store != Store::None && albedo != 0.0 {
            let mut key = cache::Key::new();
            let m = &p.medium;
            for i in 0..m.len() {
                let x = m.position(i);
                key.f64(x.x).f64(x.y).f64(x.z).f64(m.mass(i)).f64(m.smoothing_length(i));
            }
            key.str(&format!("{:?} {:?} {:?} {:?}", s.kernel, p.emitters, s.free_flight, s.light_density));
            key.f64(c_ext).f64(albedo).f64(g).f64(step).u64(s.photons as u64).u64(s.seed).u64(s.max_bounces as u64);
            let key = key.finish();
            // At least one 72-byte record per traced photon (more where a photon collides often).
            input.limits.check(std::path::Path::new("smoke"), "the photon records", &[s.photons as u64, 72])?;
            let cached = if s.cache { cache::load(key) } else { None };
            let traced = if let Some(traced) = cached {
                p.photon_cache_hit = true;
                p.notes.push(format!("photons from the cache ({} stored)", traced.photons.len()));
                traced
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
                let mut notes = Vec::new();
                let traced = photons::trace(p.density_for(s.light_density, "photons and shadow rays", &mut notes)?, &p.emitters, &ts)?;
                p.notes.extend(notes);
                if s.cache {
                    if let Err(e) = cache::store(key, &traced) {
                        p.notes.push(format!("photon cache not written: {e}"));
                    }
                }
                traced
            };
            p.traced = Some(TracedCounts { stored: traced.photons.len(), capped: traced.capped });
            traced_photons = Some(traced.photons);
        }
        p.seconds[1] = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let phase = crate::render::driver::Task::begin("smoke: storing photons", 1);
        match (traced_photons, s.store) {
            (Some(photons), Store::ParticleMap) => p.particle_map = Some(store::ParticleMap::build(&p.medium, &photons)),
            (Some(photons), Store::PhotonMap) => {
                let radius = if s.gather_radius > 0.0 { s.gather_radius } else { 4.0 * h };
                p.photon_map = Some(store::PhotonMap::build(photons, s.gather, radius));
            }
            _ => {}
        }
        p.seconds[2] = t.elapsed().as_secs_f64();
        phase.advance(1);
        drop(phase);
        Ok(p)
    }

    /// The identity of what [`Prepared::new`] makes from `input` and `s`, for everything
    /// but the particles themselves (whose set the cache holds): the placement, the
    /// medium, the lights and every setting but a view's own (`samples`,
    /// `camera_density`).
    pub fn key(input: &SmokeInput, s: &Settings) -> u64 {
        let prep = Settings { samples: 1, camera_density: Density::Auto, ..s.clone() };
        let mut key = cache::Key::new();
        key.str(&format!("{:?} {:?} {:?} {prep:?} {:?}", input.node_to_world, input.medium, input.lights, input.limits));
        key.finish()
    }

    /// The medium a part of the renderer meets (`what`, for the note `auto` leaves when it
    /// keeps the particles): the particles' exact sum or the density grid.
    fn density_for(&self, density: Density, what: &str, notes: &mut Vec<String>) -> Result<&dyn Medium> {
        let density = match density {
            Density::Auto if self.grid_spacing <= self.small_h => Density::Grid,
            Density::Auto => {
                let note = format!(
                    "{what} through the particles: the density grid's spacing {:.3e} is larger than the h of the smallest \
                     tenth of them ({:.3e}), which it would blur",
                    self.grid_spacing, self.small_h
                );
                if !notes.contains(&note) {
                    notes.push(note);
                }
                Density::Particles
            }
            d => d,
        };
        if density == Density::Particles {
            return Ok(&self.medium);
        }
        let built = self.density_grid.get_or_init(|| {
            // Over a second for the 400k plume: shown as a phase of its own.
            let phase = crate::render::driver::Task::begin("smoke: the density grid", 1);
            let t = Instant::now();
            let spacing = self.grid_spacing;
            let dims = density_grid::DensityGrid::dims_for(&self.medium, spacing);
            self.limits
                .check(std::path::Path::new("smoke"), "the density grid", &[dims[0] as u64, dims[1] as u64, dims[2] as u64, 4])
                .map_err(|e| format!("{e:#}"))?;
            let grid = density_grid::DensityGrid::new(&self.medium, spacing);
            let mut notes = Vec::new();
            if spacing > 0.5 * self.h * 1.0001 {
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
            phase.advance(1);
            Ok((grid, notes))
        });
        match built {
            Ok((grid, grid_notes)) => {
                for n in grid_notes {
                    if !notes.contains(n) {
                        notes.push(n.clone());
                    }
                }
                Ok(grid as &dyn Medium)
            }
            Err(e) => Err(anyhow::anyhow!("{e}")),
        }
    }

    /// One view: the camera's march through what is prepared. `s` must be the settings
    /// it was prepared with but for a view's own (`samples`, `camera_density`).
    pub fn render(&self, rays: &RayGenerator, s: &Settings) -> Result<Frame> {
        let start = Instant::now();
        let earlier_views = self.views.fetch_add(1, Ordering::Relaxed);
        let mut notes = self.notes.clone();
        // What this view spent preparing: nothing when an earlier view prepared it.
        let [setup, trace_s, store_s] = if earlier_views == 0 { self.seconds } else { [0.0; 3] };
        if earlier_views > 0 {
            notes.push(format!(
                "the medium, photons and grids kept from {earlier_views} earlier view{} of these particles",
                if earlier_views == 1 { "" } else { "s" }
            ));
        }
        let source = |x: DVec3, out: DVec3| -> [f64; 3] {
            if let Some(pm) = &self.particle_map {
                pm.source(&self.medium, x, out, self.g)
            } else if let Some(pm) = &self.photon_map {
                pm.source(x, out, self.g)
            } else {
                [0.0; 3]
            }
        };
        // The irradiance map holds S toward the eye (perspective) or against the view
        // direction (parallel) at each grid point: the direction a camera ray leaves it
        // in. With g = 0 that is the same for every direction, and the prepared map serves
        // every view.
        let (eye, _, _) = rays.basis();
        let parallel = rays.is_parallel();
        let forward = rays.forward();
        let (lo, hi) = Medium::bounds(&self.medium);
        let own_map;
        let irradiance = match &self.irradiance {
            Some(map) => map,
            None => {
                own_map = grid::LazyGrid::new(lo, hi, self.cell);
                &own_map
            }
        };
        let points_before = irradiance.computed_points();
        let mapped = |x: DVec3, _out: DVec3| -> [f64; 3] {
            irradiance.sample(x, &|p| {
                let out = if parallel { -forward } else { (eye - p).normalize_or(-forward) };
                source(p, out)
            })
        };
        // No photon stored (thin smoke, or none reached it): multiple scattering is zero,
        // and neither the irradiance map nor the store is consulted.
        let has_ms = self.traced.as_ref().is_some_and(|t| t.stored > 0);
        if self.traced.as_ref().is_some_and(|t| t.stored == 0) {
            notes.push("no photon scattered twice in the smoke: single scattering only".into());
        }
        let prep = &self.settings;
        let shadow_medium = self.density_for(prep.light_density, "photons and shadow rays", &mut notes)?;
        let direct: &(dyn Fn(DVec3, DVec3) -> [f64; 3] + Sync) = &source;
        let gridded: &(dyn Fn(DVec3, DVec3) -> [f64; 3] + Sync) = &mapped;
        let camera_medium = self.density_for(s.camera_density, "the camera's march", &mut notes)?;
        let view = march::MarchView {
            medium: camera_medium,
            emitters: &self.emitters,
            c_ext: self.c_ext,
            albedo: self.albedo,
            g: self.g,
            multiple: has_ms.then_some(if prep.irradiance_map { gridded } else { direct }),
            transmittance: match prep.shadows {
                ShadowMode::Marched => march::LightTransmittance::Marched { step: self.step, medium: shadow_medium },
                ShadowMode::Grid => march::LightTransmittance::Grid { grids: &self.shadow_grids, medium: shadow_medium },
            },
            step: self.step,
            samples: s.samples,
            seed: prep.seed,
        };
        let t = Instant::now();
        let mut frame = march::render(&view, rays)?;
        let march_s = t.elapsed().as_secs_f64();

        let mut counters = vec![
            ("particles".to_string(), self.medium.len() as f64),
            ("median h".into(), self.h),
            ("c_ext".into(), self.c_ext),
            ("setup s".into(), setup),
            ("photon tracing s".into(), trace_s),
            ("photon store s".into(), store_s),
            ("ray marching s".into(), march_s),
        ];
        if let Some(tr) = &self.traced {
            counters.push(("photons stored".into(), tr.stored as f64));
            counters.push(("photon paths at the bounce cap".into(), tr.capped as f64));
        }
        if let Some(pm) = &self.particle_map {
            counters.push(("particle map MB".into(), pm.memory() as f64 / 1e6));
        }
        if let Some(pm) = &self.photon_map {
            counters.push(("photon map MB".into(), pm.memory() as f64 / 1e6));
        }
        if prep.irradiance_map && has_ms {
            // The points this view computed (an earlier view's are reused where g = 0).
            counters.push(("irradiance points computed".into(), (irradiance.computed_points() - points_before) as f64));
            counters.push(("irradiance map MB".into(), irradiance.memory() as f64 / 1e6));
        }
        counters.push(("photon cache hit".into(), self.photon_cache_hit as u8 as f64));
        counters.push(("earlier views of this preparation".into(), earlier_views as f64));
        frame.stats.counters = counters;
        frame.stats.notes.extend(notes);
        frame.stats.seconds = setup + trace_s + store_s + start.elapsed().as_secs_f64();
        frame.stats.notes.push(format!("{:?} + {}", prep.store, if prep.irradiance_map { "irradiance map" } else { "direct estimates" }));
        Ok(frame)
    }
}

struct TracedCounts {
    stored: usize,
    capped: usize,
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
