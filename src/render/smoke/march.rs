//! Ray marching the camera rays through the smoke (the paper's eq. in 2.1.2):
//! per step of length Δ with σ_t and the source J taken at the step's middle,
//! L += T·J·(1 − e^{−σ_t Δ})/σ_t and T ·= e^{−σ_t Δ} — the exact integral for a step of
//! constant medium, which stays finite and accurate however dense the smoke (no NaN,
//! no black speckles at optical depths of 50 and more). J = σ_s·Σ_lights p·E·T_light
//! (single scattering) + S(x, ω) (multiple scattering, from a photon store).

use super::lights::Emitter;
use super::medium::Medium;
use super::phase::hg;
use super::rng::Rng;
use super::tracking::marched_transmittance;
use crate::render::{Frame, FrameStats};
use crate::scene::camera::RayGenerator;
use glam::DVec3;
use rayon::prelude::*;

/// How light reaching a point from a light is attenuated.
pub enum LightTransmittance<'a> {
    /// A shadow ray marched at the given step for every sample.
    Marched { step: f64 },
    /// Looked up in a lazily filled grid per light (trilinear).
    Grid(&'a [super::grid::LazyGrid]),
}

pub struct MarchView<'a> {
    pub medium: &'a dyn Medium,
    pub emitters: &'a [Emitter],
    pub c_ext: f64,
    pub albedo: f64,
    pub g: f64,
    /// S(x, ω_out), W/m³/sr, or None for single scattering only.
    pub multiple: Option<&'a (dyn Fn(DVec3, DVec3) -> [f64; 3] + Sync)>,
    pub transmittance: LightTransmittance<'a>,
    pub step: f64,
    pub samples: usize,
    pub seed: u64,
}

impl MarchView<'_> {
    /// Transmittance from x toward light k.
    pub fn light_transmittance(&self, k: usize, x: DVec3) -> f64 {
        let Some((dir, dist, _)) = self.emitters[k].incident(x) else { return 0.0 };
        match &self.transmittance {
            LightTransmittance::Marched { step } => marched_transmittance(self.medium, self.c_ext, x, -dir, dist, *step),
            // The grid holds optical depth, not transmittance: τ changes nearly linearly
            // across a cell where e^−τ, in dense smoke, is far from linear (interpolating
            // T overestimated single scattering twofold in a dense cloud).
            LightTransmittance::Grid(grids) => {
                let tau = grids[k].sample(x, &|p| {
                    let t = match self.emitters[k].incident(p) {
                        Some((d, r, _)) => marched_transmittance(self.medium, self.c_ext, p, -d, r, self.step),
                        None => 0.0,
                    };
                    [-t.max(1e-30).ln(), 0.0, 0.0]
                })[0];
                (-tau).exp()
            }
        }
    }

    /// Single-scattered radiance source per unit σ_s at x toward `out`: Σ p·E·T.
    fn single(&self, x: DVec3, out: DVec3) -> [f64; 3] {
        let mut s = [0.0; 3];
        for (k, e) in self.emitters.iter().enumerate() {
            let Some((dir, _, irradiance)) = e.incident(x) else { continue };
            let t = self.light_transmittance(k, x);
            if t <= 0.0 {
                continue;
            }
            let p = hg(dir.dot(out), self.g);
            for c in 0..3 {
                s[c] += p * irradiance[c] * t;
            }
        }
        s
    }

    /// Radiance and transmittance along one ray (d unit), the march starting `jitter`·Δ in.
    pub fn trace(&self, o: DVec3, d: DVec3, jitter: f64) -> ([f64; 3], f64) {
        let (lo, hi) = self.medium.bounds();
        let Some((t0, t1)) = crate::render::geometry::clip_box(o, d, lo, hi) else { return ([0.0; 3], 1.0) };
        let mut radiance = [0.0; 3];
        let mut tr = 1.0;
        let out = -d;
        // Steps of Δ on a lattice t0 + (jitter + k)·Δ, so that the samples of neighbouring
        // pixels do not line up (no banding); cells of the majorant grid with no particle
        // are skipped without a step.
        let phase = jitter * self.step;
        self.medium.majorants().walk(o, d, t0, t1, |ca, cb, maj| {
            if maj <= 0.0 {
                return true;
            }
            let k0 = ((ca - t0 - phase) / self.step).floor();
            let mut ta = ca;
            let mut k = k0 + 1.0;
            while ta < cb {
                let tb = (t0 + phase + k * self.step).min(cb);
                if tb > ta {
                    let dt = tb - ta;
                    let x = o + 0.5 * (ta + tb) * d;
                    let sigma_t = self.c_ext * self.medium.density(x);
                    if sigma_t > 0.0 {
                        let ss = self.single(x, out);
                        let ms = self.multiple.map(|f| f(x, out)).unwrap_or([0.0; 3]);
                        let sigma_s = self.albedo * sigma_t;
                        // ∫ over the step of T e^{−σ_t s} ds = T (1 − e^{−σ_t Δ}) / σ_t.
                        let weight = tr * -(-sigma_t * dt).exp_m1() / sigma_t;
                        for c in 0..3 {
                            radiance[c] += weight * (sigma_s * ss[c] + ms[c]);
                        }
                        tr *= (-sigma_t * dt).exp();
                        if tr < 1e-5 {
                            return false;
                        }
                    }
                }
                ta = tb;
                k += 1.0;
            }
            true
        });
        (radiance, tr)
    }
}

/// Renders the smoke: premultiplied RGBA (colour = in-scattered radiance, alpha = 1 − T),
/// `Z` where transmittance passes 0.5 is left at +∞ (smoke has no surface; the
/// compositing depth is the entry into the medium's box).
pub fn render(view: &MarchView, rays: &RayGenerator) -> Frame {
    let (w, h) = rays.size();
    let mut frame = Frame::empty(w, h);
    let spp = view.samples.max(1);
    let (lo, hi) = view.medium.bounds();
    frame.rgba.par_chunks_mut(w).zip(frame.depth.par_chunks_mut(w)).enumerate().for_each(|(y, (row, depth))| {
        for x in 0..w {
            let mut rng = Rng::stream(view.seed ^ 0x005E_EDCA_3E7A, (y * w + x) as u64);
            let mut acc = [0.0; 4];
            for s in 0..spp {
                // One sample at the pixel centre; the rest jittered inside the pixel.
                let (jx, jy) = if s == 0 { (0.5, 0.5) } else { (rng.uniform(), rng.uniform()) };
                let ray = rays.ray(x as f64 + jx, y as f64 + jy);
                let (l, t) = view.trace(ray.origin, ray.dir, rng.uniform());
                for c in 0..3 {
                    acc[c] += l[c];
                }
                acc[3] += 1.0 - t;
            }
            row[x] = acc.map(|v| (v / spp as f64) as f32);
            let centre = rays.ray(x as f64 + 0.5, y as f64 + 0.5);
            if let Some((t0, _)) = crate::render::geometry::clip_box(centre.origin, centre.dir, lo, hi) {
                if row[x][3] > 0.0 {
                    depth[x] = t0 as f32;
                }
            }
        }
    });
    frame.stats = FrameStats { renderer: "smoke".into(), ..Default::default() };
    frame
}
