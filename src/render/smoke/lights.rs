//! The scene's lights as the smoke renderer uses them, in the scene's units: a directional
//! light's `intensity` is irradiance E (W/m²) on a surface facing it, a point or spot
//! light's is radiant intensity I (W/sr). Emitted power: directional E·πR² over the disc of
//! radius R that covers the smoke's bounding sphere; point 4π·I; spot 2π(1 − cos θc)·I.

use crate::scene::{Light, LightKind};
use anyhow::{bail, Result};
use glam::DVec3;
use std::f64::consts::PI;
use volterra_formats::rng::Rng;

#[derive(Debug, Clone)]
pub enum Emitter {
    /// Photons start on a disc covering the smoke's bounding sphere, or — after
    /// [`Emitter::fit_to`] — only over the shadow of the cells that hold smoke.
    Directional {
        dir: DVec3,
        irradiance: [f64; 3],
        centre: DVec3,
        radius: f64,
        footprint: Option<Footprint>,
    },
    Point {
        position: DVec3,
        intensity: [f64; 3],
    },
    Spot {
        position: DVec3,
        dir: DVec3,
        cos_cone: f64,
        intensity: [f64; 3],
    },
}

impl Emitter {
    /// The scene's lights around a medium with bounds (lo, hi).
    pub fn from_scene(lights: &[Light], lo: DVec3, hi: DVec3) -> Result<Vec<Emitter>> {
        if lights.is_empty() {
            bail!("the smoke renderer needs at least one light in the scene");
        }
        let centre = 0.5 * (lo + hi);
        let radius = 0.5 * (hi - lo).length();
        lights
            .iter()
            .map(|l| {
                let rgb = l.color.map(|c| c * l.intensity);
                if rgb.iter().any(|v| !(v.is_finite() && *v >= 0.0)) {
                    bail!("light colour × intensity must be non-negative numbers, not {rgb:?}");
                }
                Ok(match l.kind {
                    LightKind::Directional => {
                        Emitter::Directional { dir: l.travel_direction()?, irradiance: rgb, centre, radius, footprint: None }
                    }
                    LightKind::Point => Emitter::Point { position: l.location()?, intensity: rgb },
                    LightKind::Spot => {
                        let angle = l.cone_angle.unwrap_or(30.0);
                        if !(angle > 0.0 && angle <= 180.0) {
                            bail!("spot cone_angle {angle} must be in (0, 180] degrees");
                        }
                        Emitter::Spot {
                            position: l.location()?,
                            dir: l.travel_direction()?,
                            cos_cone: angle.to_radians().cos(),
                            intensity: rgb,
                        }
                    }
                })
            })
            .collect()
    }

    /// Emitted power (W, RGB).
    pub fn power(&self) -> [f64; 3] {
        match *self {
            Emitter::Directional { irradiance, radius, ref footprint, .. } => {
                let area = footprint.as_ref().map(|f| f.area()).unwrap_or(PI * radius * radius);
                irradiance.map(|e| e * area)
            }
            Emitter::Point { intensity, .. } => intensity.map(|i| 4.0 * PI * i),
            Emitter::Spot { intensity, cos_cone, .. } => intensity.map(|i| 2.0 * PI * (1.0 - cos_cone) * i),
        }
    }

    /// The share of photons this light gets is proportional to this.
    pub fn power_weight(&self) -> f64 {
        self.power().iter().sum::<f64>() / 3.0
    }

    /// A photon: start, unit direction, power = this light's power × `share`.
    pub fn emit(&self, rng: &mut Rng, share: f64) -> (DVec3, DVec3, [f64; 3]) {
        let power = self.power().map(|p| p * share);
        match *self {
            Emitter::Directional { dir, centre, radius, ref footprint, .. } => {
                let (u, v) = super::phase::orthonormal(dir);
                let (a, b) = match footprint {
                    Some(f) => f.sample(rng),
                    None => {
                        let r = radius * rng.uniform().sqrt();
                        let phi = 2.0 * PI * rng.uniform();
                        (r * phi.cos(), r * phi.sin())
                    }
                };
                (centre - dir * (1.01 * radius) + u * a + v * b, dir, power)
            }
            Emitter::Point { position, .. } => (position, uniform_sphere(rng), power),
            Emitter::Spot { position, dir, cos_cone, .. } => {
                let cos = 1.0 - rng.uniform() * (1.0 - cos_cone);
                let sin = (1.0 - cos * cos).max(0.0).sqrt();
                let phi = 2.0 * PI * rng.uniform();
                let (u, v) = super::phase::orthonormal(dir);
                (position, (u * (sin * phi.cos()) + v * (sin * phi.sin()) + dir * cos).normalize(), power)
            }
        }
    }

    /// Light arriving at `x` unoccluded: unit direction of propagation (from the light to
    /// x), distance to the light (∞ for directional) and irradiance on a surface facing it.
    pub fn incident(&self, x: DVec3) -> Option<(DVec3, f64, [f64; 3])> {
        match *self {
            Emitter::Directional { dir, irradiance, .. } => Some((dir, f64::INFINITY, irradiance)),
            Emitter::Point { position, intensity } => {
                let v = x - position;
                let r2 = v.length_squared();
                (r2 > 0.0).then(|| (v / r2.sqrt(), r2.sqrt(), intensity.map(|i| i / r2)))
            }
            Emitter::Spot { position, dir, cos_cone, intensity } => {
                let v = x - position;
                let r2 = v.length_squared();
                let d = v / r2.sqrt();
                (r2 > 0.0 && d.dot(dir) >= cos_cone).then(|| (d, r2.sqrt(), intensity.map(|i| i / r2)))
            }
        }
    }
}

impl Emitter {
    /// Narrows a directional light's photons to the shadow of the majorant cells that hold
    /// smoke (a 256² raster across the light, each cell's projected box marked): photons
    /// that could only miss are never traced. The emitted power shrinks with the area, so
    /// what arrives at the smoke is unchanged.
    pub fn fit_to(&mut self, grid: &super::medium::MajorantGrid) {
        let Emitter::Directional { dir, centre, radius, footprint, .. } = self else { return };
        const RES: usize = 256;
        let (u, v) = super::phase::orthonormal(*dir);
        let cell = 2.0 * *radius / RES as f64;
        let mut mark = vec![false; RES * RES];
        let size = (grid.hi - grid.lo) / DVec3::new(grid.dims[0] as f64, grid.dims[1] as f64, grid.dims[2] as f64);
        for z in 0..grid.dims[2] {
            for y in 0..grid.dims[1] {
                for x in 0..grid.dims[0] {
                    if grid.max[x + grid.dims[0] * (y + grid.dims[1] * z)] <= 0.0 {
                        continue;
                    }
                    let lo = grid.lo + DVec3::new(x as f64, y as f64, z as f64) * size;
                    let (mut a0, mut a1, mut b0, mut b1) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
                    for k in 0..8 {
                        let p = lo + size * DVec3::new((k & 1) as f64, ((k >> 1) & 1) as f64, ((k >> 2) & 1) as f64) - *centre;
                        let (a, b) = (p.dot(u), p.dot(v));
                        (a0, a1, b0, b1) = (a0.min(a), a1.max(a), b0.min(b), b1.max(b));
                    }
                    let px = |t: f64| (((t + *radius) / cell).floor().max(0.0) as usize).min(RES - 1);
                    for j in px(b0)..=px(b1) {
                        for i in px(a0)..=px(a1) {
                            mark[j * RES + i] = true;
                        }
                    }
                }
            }
        }
        let pixels: Vec<(u32, u32)> = (0..RES * RES).filter(|&k| mark[k]).map(|k| ((k % RES) as u32, (k / RES) as u32)).collect();
        if !pixels.is_empty() {
            *footprint = Some(Footprint { origin: -*radius, cell, pixels });
        }
    }
}

/// The raster cells across a directional light that photons start from.
#[derive(Debug, Clone)]
pub struct Footprint {
    origin: f64,
    cell: f64,
    pixels: Vec<(u32, u32)>,
}

impl Footprint {
    pub fn area(&self) -> f64 {
        self.pixels.len() as f64 * self.cell * self.cell
    }
    /// A uniform point (u, v) over the marked cells.
    fn sample(&self, rng: &mut Rng) -> (f64, f64) {
        let k = ((rng.uniform() * self.pixels.len() as f64) as usize).min(self.pixels.len() - 1);
        let (i, j) = self.pixels[k];
        (self.origin + (i as f64 + rng.uniform()) * self.cell, self.origin + (j as f64 + rng.uniform()) * self.cell)
    }
}

fn uniform_sphere(rng: &mut Rng) -> DVec3 {
    let z = 1.0 - 2.0 * rng.uniform();
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * PI * rng.uniform();
    DVec3::new(r * phi.cos(), r * phi.sin(), z)
}
