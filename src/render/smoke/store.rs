//! The two photon stores. Both answer one question: the in-scattered source
//! S(x, ω) (W/m³/sr) of multiply-scattered light at x toward direction ω.
//!
//! - [`ParticleMap`] (the paper's): each photon's scattered power is split over the
//!   particles whose support holds it, by normalised kernel weights, and each particle also
//!   sums the photons' directions. S(x, ω) = Σ_i Φ_i W(|x − x_i|, h_i) p_i(ω): the SPH
//!   interpolation of the power density Φ_i/V_i with V_i = m_i/ρ_i the particle's volume.
//!   Where the particle's photons come from many directions, its mean direction is short;
//!   p_i blends HG about the mean direction with isotropic by that length r:
//!   p_i = r·HG(ω̄_i·ω) + (1 − r)/4π (the paper normalises the mean and loses the spread).
//! - [`PhotonMap`] (the classic volume photon map): a kd-tree of the photons;
//!   S(x, ω) = Σ_k HG(ω_k·ω) ΔΦ_k / ((4/3)π r³) over the k nearest within r.

use super::medium::SphMedium;
use super::phase::hg;
use super::photons::Photon;
use glam::DVec3;
use rayon::prelude::*;
use std::f64::consts::PI;
use volterra_formats::kdtree::KdTree;

pub struct ParticleMap {
    /// Scattered power per particle (W, RGB).
    pub power: Vec<[f64; 3]>,
    /// Mean photon direction per particle (unit), and its length before normalising.
    pub direction: Vec<DVec3>,
    pub coherence: Vec<f64>,
    /// Photons no particle's support held (none, for photons that collided in the smoke).
    pub orphans: usize,
}

impl ParticleMap {
    pub fn build(medium: &SphMedium, photons: &[Photon]) -> ParticleMap {
        let n = medium.len();
        let fold = || (vec![[0.0f64; 3]; n], vec![DVec3::ZERO; n], vec![0.0f64; n], 0usize);
        let (power, dir_sum, weight_sum, orphans) = photons
            .par_chunks(8192)
            .map(|chunk| {
                let (mut power, mut dirs, mut wsum, mut orphans) = fold();
                let mut near: Vec<(usize, f64)> = Vec::new();
                for ph in chunk {
                    near.clear();
                    medium.for_each_neighbour(ph.position, |i, w| near.push((i, w)));
                    let total: f64 = near.iter().map(|e| e.1).sum();
                    if total <= 0.0 {
                        orphans += 1;
                        continue;
                    }
                    let mean = (ph.power[0] + ph.power[1] + ph.power[2]) / 3.0;
                    for &(i, w) in &near {
                        let share = w / total;
                        for c in 0..3 {
                            power[i][c] += share * ph.power[c];
                        }
                        dirs[i] += ph.direction * (share * mean);
                        wsum[i] += share * mean;
                    }
                }
                (power, dirs, wsum, orphans)
            })
            .reduce(fold, |mut a, b| {
                for i in 0..n {
                    for c in 0..3 {
                        a.0[i][c] += b.0[i][c];
                    }
                    a.1[i] += b.1[i];
                    a.2[i] += b.2[i];
                }
                (a.0, a.1, a.2, a.3 + b.3)
            });
        let mut direction = vec![DVec3::Z; n];
        let mut coherence = vec![0.0; n];
        for i in 0..n {
            let len = dir_sum[i].length();
            if len > 0.0 && weight_sum[i] > 0.0 {
                direction[i] = dir_sum[i] / len;
                coherence[i] = (len / weight_sum[i]).min(1.0);
            }
        }
        ParticleMap { power, direction, coherence, orphans }
    }

    /// S(x, ω_out) in W/m³/sr, ω_out the direction the light leaves x in.
    pub fn source(&self, medium: &SphMedium, x: DVec3, out: DVec3, g: f64) -> [f64; 3] {
        let mut s = [0.0; 3];
        medium.for_each_neighbour(x, |i, w| {
            let r = self.coherence[i];
            let p = r * hg(self.direction[i].dot(out), g) + (1.0 - r) / (4.0 * PI);
            for c in 0..3 {
                s[c] += self.power[i][c] * w * p;
            }
        });
        s
    }

    /// Bytes held.
    pub fn memory(&self) -> usize {
        self.power.len() * (24 + 24 + 8)
    }
}

/// The photons in the workspace's kd-tree (`volterra_formats::kdtree`).
pub struct PhotonMap {
    photons: Vec<Photon>,
    tree: KdTree,
    /// Neighbours gathered per estimate, and the largest radius searched.
    pub k: usize,
    pub max_radius: f64,
}

impl PhotonMap {
    pub fn build(photons: Vec<Photon>, k: usize, max_radius: f64) -> PhotonMap {
        let positions: Vec<[f64; 3]> = photons.iter().map(|p| p.position.to_array()).collect();
        PhotonMap { tree: KdTree::new(&positions), photons, k: k.max(1), max_radius }
    }

    /// The k nearest photons within max_radius of x: (squared distance, index), unordered.
    fn nearest(&self, x: DVec3) -> Vec<(f64, usize)> {
        self.tree.k_nearest(x.to_array(), self.k, self.max_radius * self.max_radius, None)
    }

    /// S(x, ω_out) in W/m³/sr.
    pub fn source(&self, x: DVec3, out: DVec3, g: f64) -> [f64; 3] {
        let near = self.nearest(x);
        if near.is_empty() {
            return [0.0; 3];
        }
        // The volume is the sphere through the farthest photon gathered; with fewer than k
        // found, the search radius.
        let r2 = if near.len() == self.k { near.iter().map(|e| e.0).fold(0.0, f64::max) } else { self.max_radius * self.max_radius };
        let volume = 4.0 / 3.0 * PI * r2 * r2.sqrt();
        let mut s = [0.0; 3];
        for &(_, i) in &near {
            let p = &self.photons[i];
            let f = hg(p.direction.dot(out), g) / volume;
            for c in 0..3 {
                s[c] += p.power[c] * f;
            }
        }
        s
    }

    pub fn len(&self) -> usize {
        self.photons.len()
    }

    pub fn is_empty(&self) -> bool {
        self.photons.is_empty()
    }

    pub fn memory(&self) -> usize {
        self.photons.len() * std::mem::size_of::<Photon>() + self.tree.memory()
    }
}
