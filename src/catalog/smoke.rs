//! The settings of `smoke`, particle-map smoke (`render::smoke`).

use super::{NodeKind, NodeSettings, RendererDecl};
use crate::settings::{Bounds, Control, Preview, Widget};

crate::setting_choice! {
    /// The SPH smoothing kernel. Both have support 2h and integrate to 1 over space.
    pub enum Kernel {
        /// The normalised cubic spline (M4, "spline Gaussian").
        CubicSpline = "cubic-spline",
        /// Müller et al.'s poly6, 315/(64π H⁹)·(H² − r²)³ with H = 2h.
        Poly6 = "poly6",
    }
}

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
    heights_held: None,
    parse: |t| Settings::from_table(t).map(NodeSettings::Smoke),
};
