//! The settings of `shear-warp` (`render::shear_warp`).

use super::{NodeKind, NodeSettings, RendererDecl};
use crate::settings::{Bounds, Control, Preview, Widget};

/// The most samples per slab (`slab_samples`).
pub const MAX_SLAB_SAMPLES: usize = 4;

crate::setting_choice! {
    /// Empty-space leaping.
    pub enum Leaping {
        /// One lookup in the overlapped min-max map per run (paper Fig. 6b).
        Overlapped = "overlapped",
        /// Test every non-overlapping n×1×1 scanline block a run touches (paper Fig. 6a).
        MultiScanline = "multi-scanline",
        /// Sample every slab.
        None = "none",
    }
}

crate::setting_choice! {
    /// How the warp samples the intermediate image.
    pub enum WarpFilter {
        /// Each final pixel the bilinear mean of its four intermediate neighbours.
        Bilinear = "bilinear",
        /// Each final pixel its nearest intermediate pixel: a quarter of the rays where the
        /// intermediate image is finer than the final one (the automatic ratio's), each at
        /// most half an intermediate pixel from the final pixel's centre.
        Nearest = "nearest",
    }
}

crate::declare_settings! {
    pub struct Settings {
        /// Intermediate pixels per voxel: any real ratio, such as 1.13 or 2.26.
        pub supersampling: f64 = 0.0, unit = "pixels per voxel", range = Bounds::open_closed(0.0, 16.0),
            zero = "auto: intermediate pixels a quarter of an output pixel apart (only those the warp reads are composited), clamped to 2..8", quality = true,
            viewer = Control { label: "Supersampling", widget: Widget::Slider { lo: 0.0, hi: 4.0, step: 0.01 } },
            preview = Preview::AtMost(1.0);
        /// Empty-space leaping over runs of voxels the transfer function makes transparent.
        pub leaping: Leaping = Leaping::Overlapped, quality = true,
            viewer = Control { label: "Empty-space leaping", widget: Widget::ByType };
        /// Run length n of the min-max blocks.
        pub block: usize = 8, unit = "voxels", range = Bounds::closed(1.0, 256.0), quality = true;
        /// Stop compositing a pixel once its opacity reaches this.
        pub termination: f64 = 0.995, range = Bounds::open_closed(0.0, 1.0), quality = true;
        /// Pre-integration table levels.
        pub table_levels: usize = 0, range = Bounds::closed(2.0, 4096.0),
            zero = "auto: chosen from the transfer function, 256..1024", quality = true;
        /// Samples per slab along the ray: 1 is the paper's shear-warp (one sample per
        /// slice, the scalar taken as linear in between); k > 1 adds trilinear samples at
        /// k − 1 evenly spaced points between the slices and pre-integrates k shorter
        /// segments, which thin oblique structures need, in composite and MIP alike.
        /// Between slices the trilinear field along an oblique ray has kinks at every
        /// voxel boundary it crosses, and the straight line through the slice samples cuts
        /// below thin bright structures: on the aneurism at 512² (view 0) the image is
        /// 1–3 % too faint with k = 1, and the relative RMSE from the reference stops at
        /// 3.9 % however high the ratio; k = 2 gives 2.4 % at ratio 2 and 1.3 % at ratio 4,
        /// k = 4 0.7 % at ratio 4. MIP takes its maximum over these samples too
        /// (aneurism, ratio 2.26: 6.2 % → 4.3 %, at twice the time).
        pub slab_samples: usize = 2, range = Bounds::closed(1.0, MAX_SLAB_SAMPLES as f64), quality = true,
            viewer = Control { label: "Samples per slab", widget: Widget::Slider { lo: 1.0, hi: 4.0, step: 1.0 } },
            preview = Preview::AtMost(1.0);
        /// The warp's filter. Where intermediate pixels lie closer than the final ones (the
        /// automatic ratio puts them a quarter of an output pixel apart) the bilinear warp
        /// reads four intermediate rays per final pixel, the nearest one: 2.3–2.8× faster
        /// for a larger error. Aneurism 512², shaded, 5 views, 2 cores, same run: parallel,
        /// bilinear 2.29 % from the reference in 385 ms, nearest 3.98 % in 140 ms (ratio 2,
        /// bilinear: 3.61 % in 140 ms; VTK's fixed-point mapper 10.80 % in 166 ms);
        /// perspective 2.39 % in 549 ms, nearest 4.27 % in 241 ms (VTK 11.95 % in 202 ms).
        /// The 512×512×400 CT phantom in perspective (`volterra bench clinical`), further
        /// frames: bilinear 4.07 % in 831–893 ms, nearest 5.39 % in 548–558 ms (ratio 1,
        /// bilinear: 8.39 % in 534 ms; VTK 12.69 % in 108–113 ms).
        pub warp: WarpFilter = WarpFilter::Bilinear, quality = true,
            viewer = Control { label: "Warp filter", widget: Widget::ByType };
        /// Voxels averaged into one along each axis before drawing: 1 draws the volume
        /// itself; 2 or 4 a coarser copy (real values averaged over 2³ or 4³ voxels, made
        /// on first use and kept beside the volume's slices), as the viewer's previews do
        /// while the camera moves: it needs no new slices when the view turns across 45°,
        /// and a 4³ copy has 1/64 of the voxels. Thin structures fade in the average.
        pub coarsening: usize = 1, unit = "voxels per axis", range = Bounds::closed(1.0, 4.0),
            zero = "auto: 4 or 2 where an output pixel spans at least that many voxels at the volume's centre, else 1", quality = true,
            preview = Preview::AtMost(0.0);
    }
}

pub const RENDERER: RendererDecl = RendererDecl {
    name: "shear-warp",
    kind: NodeKind::Volume,
    doc: "Shear-warp on the CPU (Kye & Kim, after Lacroute & Levoy): intermediate-image \
          supersampling at any real ratio, pre-integrated classification, early ray \
          termination, empty-space leaping with the overlapped min-max map, MIP, a bilinear \
          warp, gradient shading. Parallel and perspective cameras (the perspective \
          factorisation: slices scaled about the eye's foot, a projective warp); a camera \
          inside the volume is refused with an error (use `reference`).",
    reference: false,
    settings: Settings::DECLS,
    heights_held: None,
    parse: |t| Settings::from_table(t).map(NodeSettings::ShearWarp),
};
