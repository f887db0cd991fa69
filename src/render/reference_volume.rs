//! The brute-force reference volume ray caster: the truth other volume renderers (and
//! VTK) are measured against. Trilinear interpolation of the scalar field at every sample,
//! a step of at most 0.05 voxel by default, f64 accumulation, opacity corrected for the
//! step exactly as vtkVolumeProperty defines it, no pre-integration, no empty-space
//! skipping; gradient shading and gradient opacity at every sample; each ray cut to the exact interval it
//! spends inside the node's crop region.

use super::frame::{Frame, FrameStats};
use super::registry::{NodeSettings, RendererDecl};
use super::settings::{Bounds, Control, Preview, Widget};
use crate::scene::NodeKind;
use crate::scene::{BlendMode, HalfSpace, Light, RayGenerator, TransferFunction, VolumeShading};
use anyhow::{anyhow, Result};
use glam::{DMat4, DVec3};
use rayon::prelude::*;
use volterra_formats::Volume;

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
    parse: |t| Settings::from_table(t).map(NodeSettings::Reference),
};

/// The scalar field as real-world f32 values for fast trilinear lookups.
pub struct Field {
    dims: [usize; 3],
    values: Vec<f32>,
}

impl Field {
    pub fn new(v: &Volume) -> Field {
        let values = (0..v.voxel_count()).into_par_iter().map(|i| v.value(i) as f32).collect();
        Field { dims: v.dims, values }
    }

    /// Trilinear interpolation at continuous index coordinates inside [0, dims−1].
    #[inline]
    pub fn sample(&self, p: DVec3) -> f64 {
        super::geometry::trilinear(self.dims, p, |i| self.values[i] as f64)
    }
}

/// What to draw: a volume placed in the world, classified by a transfer function.
pub struct VolumeInput<'a> {
    pub volume: &'a Volume,
    pub node_to_world: DMat4,
    pub tf: &'a TransferFunction,
    pub blend: BlendMode,
    /// Gradient shading (None or `shade = false`: none; MIP is never shaded).
    pub shading: Option<&'a VolumeShading>,
    /// The scene's lights for shading (none: a headlight).
    pub lights: &'a [Light],
    /// The region drawn (`Scene::crop_region`: half-spaces in node coordinates; empty:
    /// the whole volume).
    pub crop: &'a [HalfSpace],
}

pub fn render(input: &VolumeInput, rays: &RayGenerator, settings: &Settings) -> Result<Frame> {
    let VolumeInput { volume, node_to_world, tf, blend, shading, lights, crop } = *input;
    let (width, height) = rays.size();
    settings.validate().map_err(|e| anyhow!("{}: {e}", RENDERER.name))?;
    let start = std::time::Instant::now();
    let index_to_world = super::geometry::index_to_world(node_to_world, super::geometry::affine_matrix(&volume.affine))?;
    let world_to_index = index_to_world.inverse();
    let index_to_node = super::geometry::affine_matrix(&volume.affine);
    let crop: Vec<HalfSpace> = crop.iter().map(|h| h.pulled_back(index_to_node)).collect();
    let min_spacing = (0..3).map(|c| index_to_world.col(c).truncate().length()).fold(f64::INFINITY, f64::min);
    let dt = settings.step * min_spacing;
    let field = Field::new(volume);
    let shader = super::volume_shading::Shader::new(shading, lights, index_to_world)?;
    let (g_to_world, gradient_opacity) = (super::volume_shading::gradient_to_world(index_to_world), !tf.gradient_opacity.is_empty());
    use super::volume_shading::gradient;
    let hi = DVec3::new((volume.dims[0] - 1) as f64, (volume.dims[1] - 1) as f64, (volume.dims[2] - 1) as f64);
    // A single-slice axis has zero thickness: give it half a voxel either side.
    let pad = DVec3::new(
        if volume.dims[0] == 1 { 0.5 } else { 0.0 },
        if volume.dims[1] == 1 { 0.5 } else { 0.0 },
        if volume.dims[2] == 1 { 0.5 } else { 0.0 },
    );
    let (lo, hi) = (-pad, hi + pad);

    let mut frame = Frame::empty(width, height);
    let samples: u64 =
        super::driver::render_bands("reference ray casting", width, 1, &mut frame.rgba, &mut frame.depth, &mut [], |band| {
            let (y, row, depth) = (band.y0, band.rgba, band.depth);
            let mut n = 0u64;
            for x in 0..width {
                let ray = rays.ray(x as f64 + 0.5, y as f64 + 0.5);
                let o = world_to_index.transform_point3(ray.origin);
                let d = world_to_index.transform_vector3(ray.dir);
                // A zero-length interval holds no sample.
                let Some((t0, t1)) = crate::render::geometry::clip_box(o, d, lo, hi)
                    .and_then(|t| crate::scene::crop::clip_interval(o, d, t, &crop))
                    .filter(|(a, b)| a < b)
                else {
                    continue;
                };
                let steps = ((t1 - t0) / dt).ceil() as usize;
                let (mut c, mut a) = ([0.0f64; 3], 0.0f64);
                let mut z = f32::INFINITY;
                let mut max_v = f64::NEG_INFINITY;
                let mut max_t = 0.0;
                for s in 0..steps {
                    // Each sample stands for its segment; the last one may be shorter.
                    let ta = t0 + s as f64 * dt;
                    let len = dt.min(t1 - ta);
                    let t = ta + 0.5 * len;
                    let v = field.sample(o + d * t);
                    n += 1;
                    match blend {
                        BlendMode::Mip => {
                            if v > max_v {
                                max_v = v;
                                max_t = t;
                            }
                        }
                        BlendMode::Composite => {
                            // The gradient, where the gradient opacity or shading reads it.
                            let mut g = None;
                            let mut grad = || *g.get_or_insert_with(|| gradient(volume.dims, o + d * t, &g_to_world, |q| field.sample(q)));
                            let alpha = if gradient_opacity && tf.opacity(v) > 0.0 {
                                tf.scaled_opacity_for_step(v, len, tf.gradient_factor(grad().length()))
                            } else {
                                tf.opacity_for_step(v, len)
                            };
                            if alpha > 0.0 {
                                let mut col = tf.color(v);
                                if let Some(sh) = &shader {
                                    col = sh.shade(col, grad(), ray.origin + ray.dir * t, ray.dir);
                                }
                                let w = (1.0 - a) * alpha;
                                for k in 0..3 {
                                    c[k] += w * col[k];
                                }
                                a += w;
                                if a >= 0.5 && z.is_infinite() {
                                    z = t as f32;
                                }
                                if a >= settings.termination {
                                    break;
                                }
                            }
                        }
                    }
                }
                if blend == BlendMode::Mip && max_v.is_finite() {
                    let alpha = tf.opacity(max_v).min(1.0);
                    let col = tf.color(max_v);
                    c = [col[0] * alpha, col[1] * alpha, col[2] * alpha];
                    a = alpha;
                    if alpha > 0.0 {
                        z = max_t as f32;
                    }
                }
                row[x] = [c[0] as f32, c[1] as f32, c[2] as f32, a as f32];
                depth[x] = z;
            }
            n
        })?
        .into_iter()
        .sum();
    frame.stats = FrameStats {
        renderer: RENDERER.name.into(),
        seconds: start.elapsed().as_secs_f64(),
        counters: vec![("samples".into(), samples as f64), ("step_mm".into(), dt)],
        notes: vec![],
        nodes: vec![],
    };
    Ok(frame)
}
