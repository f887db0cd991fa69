//! The settings of `terrain`, the GPU ray-caster, and of `terrain-reference`
//! (`render::terrain`), and what the GPU ray-caster holds for a heightfield's samples.

use super::{NodeKind, NodeSettings, RendererDecl};
use crate::colormap::Colormap;
use crate::settings::{Bounds, Control, Preview, Widget};

crate::setting_choice! {
    /// How the GPU walks the pyramid. The last two are the baselines the benchmark
    /// measures the paper's choice against. The discriminants are the shader's codes.
    #[repr(u32)]
    pub enum Traversal {
        /// Descend on a possible hit; after a miss, leave the node and go up one level.
        Quadtree = "quadtree",
        /// As above but stay on the same level after a miss (plain pyramidal displacement mapping).
        NoRaise = "no-raise",
        /// Every cell the ray crosses, in order (the lid map only).
        Linear = "linear",
    }
}

crate::setting_choice! {
    /// The normals terrain is shaded with; either way rays meet the exact bilinear patches.
    pub enum Normals {
        /// Per-sample gradients (central differences) interpolated bilinearly across each
        /// patch: continuous across patch borders, no facets.
        Smooth = "smooth",
        /// Each bilinear patch's own normal: exact, but it jumps at patch borders.
        Faceted = "faceted",
    }
}

crate::declare_settings! {
    pub struct Settings {
        /// How the GPU walks the max-quadtree.
        pub traversal: Traversal = Traversal::Quadtree, quality = true;
        /// Hard shadows from a second ray toward each light.
        pub shadows: bool = false, viewer = Control { label: "Shadows", widget: Widget::ByType };
        /// Light reaching every point regardless of orientation, as a fraction of the base colour.
        pub ambient: f64 = 0.25, range = Bounds::at_least(0.0);
        /// The shading normals.
        pub normals: Normals = Normals::Smooth, viewer = Control { label: "Normals", widget: Widget::ByType };
        /// The colour map elevations are shown through where no texture covers the terrain
        /// (its lowest valid sample at the low end, the highest at the high end; the PNG
        /// preview gets its scalar bar).
        pub colormap: Colormap = Colormap::Hypsometric, viewer = Control { label: "Elevation colours", widget: Widget::ByType };
        /// Rays per pixel, on a stratified k × k grid (1, 4, 9, 16, …): their colours are
        /// averaged (anti-aliasing); depth and steps stay those of the pixel's centre ray.
        /// 4 by measurement (`volterra bench terrain`, 1920 × 1080, lavapipe on 2 cores): the
        /// colour error from 256 rays falls 7.5 → 2.6 % (fly) and 3.4 → 1.4 % (walk) for
        /// 3.3 × the time; 9 and 16 rays halve it again for 1.8 × and 3 × more. Previews
        /// while the camera moves use 1.
        pub rays_per_pixel: u32 = 4, range = Bounds::closed(1.0, 256.0), quality = true, preview = Preview::AtMost(1.0);
        /// Per-ray cap on traversal steps. Rays stopped by the cap are counted in the
        /// frame's statistics.
        pub max_steps: u32 = 0, zero = "auto: 4 × (cells east + cells north) + 64, more than any ray needs", quality = true;
    }
}

crate::declare_settings! {
    /// The settings of `terrain-reference`: what the picture shows (it walks every cell,
    /// so traversal and step caps do not apply).
    pub struct ReferenceSettings {
        /// Hard shadows from a second ray toward each light.
        pub shadows: bool = false;
        /// Light reaching every point regardless of orientation, as a fraction of the base colour.
        pub ambient: f64 = 0.25, range = Bounds::at_least(0.0);
        /// The shading normals.
        pub normals: Normals = Normals::Smooth;
        /// The colour map elevations are shown through where no texture covers the terrain.
        pub colormap: Colormap = Colormap::Hypsometric;
        /// Rays per pixel, on a stratified k × k grid (1, 4, 9, 16, …): their colours are
        /// averaged (anti-aliasing); depth stays that of the pixel's centre ray.
        pub rays_per_pixel: u32 = 4, range = Bounds::closed(1.0, 256.0);
    }
}

impl From<&ReferenceSettings> for Settings {
    fn from(r: &ReferenceSettings) -> Settings {
        Settings {
            shadows: r.shadows,
            ambient: r.ambient,
            normals: r.normals,
            colormap: r.colormap,
            rays_per_pixel: r.rays_per_pixel,
            ..Default::default()
        }
    }
}

pub const RENDERER: RendererDecl = RendererDecl {
    name: "terrain",
    kind: NodeKind::Heightfield,
    doc: "The GPU ray-caster (Park, Oh & Cho; wgpu, any Vulkan/Metal/DX12 adapter, lavapipe \
          without a GPU): a max-quadtree with a lid map, exact bilinear patches.",
    reference: false,
    settings: Settings::DECLS,
    heights_held: Some(gpu_held_bytes_opened),
    parse: |t| Settings::from_table(t).map(NodeSettings::Terrain),
};

pub const REFERENCE_RENDERER: RendererDecl = RendererDecl {
    name: "terrain-reference",
    kind: NodeKind::Heightfield,
    doc: "The CPU reference in f64: every cell a ray crosses, the exact patch intersection. \
          Slow; the truth `terrain` is measured against.",
    reference: true,
    settings: ReferenceSettings::DECLS,
    heights_held: None,
    parse: |t| ReferenceSettings::from_table(t).map(NodeSettings::TerrainReference),
};

/// Bytes the GPU ray-caster holds per sample: the heights (4, up to 5 % more in tiles) and
/// the pyramid of half floats (a sixth of that).
pub const GPU_BYTES_PER_SAMPLE: u64 = 5;

/// All the GPU ray-caster takes for a heightfield of `samples` samples: its textures
/// (`GPU_BYTES_PER_SAMPLE`), the staging of two bands of rows as they are uploaded (16 MiB
/// each at most), and the driver's working memory where the GPU's memory is the host's.
/// What a GeoTIFF's level is chosen by, and what is checked before the textures are made.
pub fn gpu_held_bytes(samples: u64) -> u64 {
    let staging = samples.saturating_mul(8).min(32 << 20);
    samples.saturating_mul(GPU_BYTES_PER_SAMPLE).saturating_add(staging).saturating_add(crate::gpu::driver_working_memory())
}

/// `gpu_held_bytes` with the GPU opened first: where its memory is the host's, what its
/// driver holds from then on (its compiled pipelines) is in use when a level is chosen.
/// Without a GPU the renderer says so when it draws.
fn gpu_held_bytes_opened(samples: u64) -> u64 {
    let _ = crate::gpu::device();
    gpu_held_bytes(samples)
}
