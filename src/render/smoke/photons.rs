//! Photon tracing through the smoke (view-independent): photons leave the lights with
//! power split by each light's emitted power, fly to real collisions (delta tracking, or
//! the paper's local −ln ξ / σ_t), scatter by Henyey–Greenstein and survive by Russian
//! roulette with the albedo. Every collision after the first is stored: the first one is
//! single scattering of direct light, which the ray marcher computes exactly; later ones
//! carry the multiply-scattered light the stores estimate.
//!
//! Deterministic for a seed: photon k draws from its own stream `Rng::stream(seed, k)`,
//! whatever the number of threads.

use super::lights::Emitter;
use super::medium::Medium;
use super::phase::sample_hg;
use super::tracking::{delta_track, local_free_path};
use super::FreeFlight;
use glam::DVec3;
use rayon::prelude::*;
use volterra_formats::rng::Rng;

/// A stored photon: where it collided, the direction it was travelling, and the power it
/// scatters there (watts, RGB) — its power times the albedo.
#[derive(Debug, Clone, Copy)]
pub struct Photon {
    pub position: DVec3,
    pub direction: DVec3,
    pub power: [f64; 3],
}

/// What a tracing run produced, with the bookkeeping the energy checks use.
pub struct Traced {
    pub photons: Vec<Photon>,
    /// Total power emitted (W, RGB).
    pub emitted: [f64; 3],
    /// Power carried out of the medium by escaping photons.
    pub escaped: [f64; 3],
    /// Photons whose path reached the bounce cap (counted, not hidden).
    pub capped: usize,
}

/// Traces `count` photons.
pub struct TraceSettings {
    pub count: usize,
    pub seed: u64,
    pub c_ext: f64,
    pub albedo: f64,
    pub g: f64,
    pub free_flight: FreeFlight,
    /// Step for the local free-path rule when it meets empty space.
    pub step: f64,
    /// A guard against endless paths at albedo 1 in dense smoke.
    pub max_bounces: usize,
}

/// Traces the photons in parallel chunks; [`Cancelled`](crate::render::driver::Cancelled)
/// when the caller cancels between chunks.
pub fn trace(medium: &dyn Medium, emitters: &[Emitter], s: &TraceSettings) -> Result<Traced, crate::render::driver::Cancelled> {
    let total: f64 = emitters.iter().map(|e| e.power_weight()).sum();
    let mut out = Traced { photons: Vec::new(), emitted: [0.0; 3], escaped: [0.0; 3], capped: 0 };
    if s.count == 0 || total <= 0.0 {
        return Ok(out);
    }
    const CHUNK: usize = 4096;
    // Per chunk: stored photons, power emitted, power escaped, paths capped.
    type Chunk = (Vec<Photon>, [f64; 3], [f64; 3], usize);
    let progress = crate::render::driver::Task::begin("photons", s.count as u64);
    let chunks: Option<Vec<Chunk>> = (0..s.count.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            if progress.cancelled() {
                return None;
            }
            let mut stored = Vec::new();
            let (mut emitted, mut escaped, mut capped) = ([0.0; 3], [0.0; 3], 0usize);
            for k in c * CHUNK..((c + 1) * CHUNK).min(s.count) {
                let mut rng = Rng::stream(s.seed, k as u64);
                // Choose a light in proportion to its power; the photon carries
                // (light's power) / (photons it gets on average).
                let mut pick = rng.uniform() * total;
                let mut light = &emitters[emitters.len() - 1];
                for e in emitters {
                    if pick < e.power_weight() {
                        light = e;
                        break;
                    }
                    pick -= e.power_weight();
                }
                let (mut pos, mut dir, power) = light.emit(&mut rng, total / (light.power_weight() * s.count as f64));
                for ch in 0..3 {
                    emitted[ch] += power[ch];
                }
                let mut bounce = 0;
                loop {
                    let far = 1e30;
                    let t = match s.free_flight {
                        FreeFlight::Delta => delta_track(medium, s.c_ext, pos, dir, far, &mut rng),
                        FreeFlight::Local => local_free_path(medium, s.c_ext, pos, dir, far, s.step, &mut rng),
                    };
                    let Some(t) = t else {
                        for ch in 0..3 {
                            escaped[ch] += power[ch];
                        }
                        break;
                    };
                    pos += t * dir;
                    if bounce > 0 {
                        stored.push(Photon { position: pos, direction: dir, power: power.map(|p| p * s.albedo) });
                    }
                    // Russian roulette: survive with probability albedo, power unchanged.
                    if rng.uniform() >= s.albedo {
                        break;
                    }
                    bounce += 1;
                    if bounce >= s.max_bounces {
                        capped += 1;
                        break;
                    }
                    dir = sample_hg(dir, s.g, rng.uniform(), rng.uniform());
                }
            }
            progress.advance((((c + 1) * CHUNK).min(s.count) - c * CHUNK) as u64);
            Some((stored, emitted, escaped, capped))
        })
        .collect();
    drop(progress);
    for (stored, emitted, escaped, capped) in chunks.ok_or(crate::render::driver::Cancelled)? {
        out.photons.extend(stored);
        for ch in 0..3 {
            out.emitted[ch] += emitted[ch];
            out.escaped[ch] += escaped[ch];
        }
        out.capped += capped;
    }
    Ok(out)
}
