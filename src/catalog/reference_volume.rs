//! The settings of `reference`, the brute-force volume ray caster (`render::reference_volume`).

use super::{NodeKind, NodeSettings, RendererDecl};
use crate::settings::{Bounds, Control, Preview, Widget};

crate::declare_settings! {
    pub struct Settings {
        /// Sample step as a fraction of the smallest voxel spacing.
        pub step: f64 = 0.05, unit = "voxel", range = Bounds::open_closed(0.0, 1.0), quality = true,
            viewer = Control { label: "Step (voxels)", widget: Widget::Drag { lo: 0.01, hi: 1.0, speed: 0.005 } },
            preview = Preview::AtLeast(0.25);
        /// Stop a ray once its accumulated opacity exceeds this (1 = never stop early).
        pub termination: f64 = 1.0 - 1e-9, range = Bounds::open_closed(0.0, 1.0), quality = true;
    }
}

pub const RENDERER: RendererDecl = RendererDecl {
    name: "reference",
    kind: NodeKind::Volume,
    doc: "The brute-force ray caster, on the CPU in f64: trilinear samples at a fine step, \
          no pre-integration, no empty-space skipping. Slow; the truth `shear-warp` and VTK \
          are measured against. Draws parallel and perspective cameras.",
    reference: true,
    settings: Settings::DECLS,
    heights_held: None,
    parse: |t| Settings::from_table(t).map(NodeSettings::Reference),
};
