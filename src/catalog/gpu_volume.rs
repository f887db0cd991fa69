//! The settings of `gpu-raycast`, the volume ray-caster on the GPU (`render::gpu_volume`).

use super::{NodeKind, NodeSettings, RendererDecl};
use crate::settings::{Bounds, Control, Preview, Widget};

crate::setting_choice! {
    /// Where the volume's voxels live on the GPU.
    pub enum Voxels {
        /// A storage buffer on a CPU adapter (lavapipe), where one binding holds the whole
        /// volume; a 3-D texture otherwise. On lavapipe each texel load is a call that
        /// works out the texture's size and bounds, a buffer load is inline: faster frames
        /// (measured in docs/renderers.md). A volume cut into bricks to fit the binding
        /// is slower than one texture, so it stays a texture.
        Auto = "auto",
        /// A 3-D texture of the stored type (8, 16-bit integers or f32), bricked where the
        /// volume passes `max_texture_dimension_3d` (or `brick`) or its bytes the largest
        /// allocation (`max_buffer_size` stands in: wgpu tells no other).
        Texture = "texture",
        /// A storage buffer of the stored values packed into 32-bit words (four 8-bit or two
        /// 16-bit values a word), bricked where the volume passes the adapter's largest
        /// storage binding (`max_storage_buffer_binding_size`, 128 MiB on lavapipe).
        Buffer = "buffer",
    }
}

crate::declare_settings! {
    pub struct Settings {
        /// Sample step as a fraction of the smallest voxel spacing. Each step is one
        /// pre-integrated segment (the scalar taken as linear between its two samples), so
        /// a step of a voxel shows no wood-grain; a finer one follows the trilinear field's
        /// kinks between voxels more closely.
        pub step: f64 = 0.5, unit = "voxel", range = Bounds::open_closed(0.0, 1.0), quality = true,
            viewer = Control { label: "Step (voxels)", widget: Widget::Drag { lo: 0.05, hi: 1.0, speed: 0.01 } },
            preview = Preview::AtLeast(1.0);
        /// Stop a ray once its accumulated opacity reaches this.
        pub termination: f64 = 0.995, range = Bounds::open_closed(0.0, 1.0), quality = true;
        /// Leap over blocks of 8³ voxels whose every segment the transfer function makes
        /// transparent (MIP: whose highest value does not pass the ray's). The picture is
        /// the same either way, bit for bit; off only to measure what it saves.
        pub skipping: bool = true, quality = true;
        /// The most voxels along each edge of one brick (3-D texture or buffer): a volume
        /// larger along any axis is cut into bricks that overlap by the voxels its samples and gradients
        /// read, drawn one after another front to back into the same image.
        pub brick: usize = 0, unit = "voxels", range = Bounds::closed(8.0, 16384.0),
            zero = "auto: as large as the adapter allows (a texture: `max_texture_dimension_3d` and `max_buffer_size`; a buffer: its largest storage binding)", quality = true;
        /// Where the voxels live on the GPU: the same picture bit for bit either way.
        pub voxels: Voxels = Voxels::Auto, quality = true;
    }
}

pub const RENDERER: RendererDecl = RendererDecl {
    name: "gpu-raycast",
    kind: NodeKind::Volume,
    doc: "Ray casting on the GPU (wgpu compute, `shaders/volume_raycast.wgsl`): the volume as a \
          3-D texture of its stored type (16-bit where the data is; a storage buffer on a CPU \
          adapter), trilinear samples, the \
          pre-integrated table shear-warp uses, gradient shading and gradient opacity, MIP, \
          crop box and clipping planes cut at exact crossings, empty-space skipping over a \
          min-max grid of 8³-voxel blocks tested against the transfer function, early \
          termination. Parallel and perspective cameras, the eye inside the volume included. \
          Bricked where the volume passes what one texture or storage binding of the adapter holds.",
    reference: false,
    settings: Settings::DECLS,
    heights_held: None,
    parse: |t| Settings::from_table(t).map(NodeSettings::GpuRaycast),
};
