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
//! - `grid`: lazily filled grids (irradiance map, transmittance grid); `march`: the camera;
//! - `prepare`: what a render keeps across views of the same particles (`RenderCache`).

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
pub mod prepare;
pub mod store;
pub mod tracking;

pub use crate::catalog::smoke::{Density, FreeFlight, Settings, ShadowMode, Store, RENDERER};
use crate::render::Frame;
use crate::scene::camera::RayGenerator;
use crate::scene::{Light, Medium as MediumParams};
use anyhow::{bail, Result};
use glam::{DMat3, DMat4, DVec3};
use medium::{Kernel, SphMedium};
use volterra_formats::{Limits, ParticleSet};

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

/// One view: the view-independent part prepared (`prepare::Prepared`), then the march.
/// Views of the same particles keep the preparation through `render::RenderCache`.
pub fn render(input: &SmokeInput, rays: &RayGenerator, s: &Settings) -> Result<Frame> {
    prepare::Prepared::new(input, s)?.render(rays, s)
}
