//! The brute-force reference volume ray caster: the truth other volume renderers (and
//! VTK) are measured against. Trilinear interpolation of the scalar field at every sample,
//! a step of at most 0.05 voxel by default, f64 accumulation, opacity corrected for the
//! step exactly as vtkVolumeProperty defines it, no pre-integration, no empty-space
//! skipping; gradient shading and gradient opacity at every sample; each ray cut to the exact interval it
//! spends inside the node's crop region.
//!
//! Volumes that overlap are fused along each ray ([`render_fused`]): the ray is cut at
//! every volume's entry and exit, and at each sample every volume covering it is classified
//! by its own transfer function (and shaded by its own gradient); extinctions add —
//! α = 1 − Π (1 − αᵢ) — and the colour is the extinction-weighted mean of the volumes'
//! colours (weights σᵢ = −ln(1 − αᵢ)), the emission–absorption integral of two media
//! present at once (as VTK's multi-volume mapper adds its volumes' samples).

use super::frame::{Frame, FrameStats};
pub use crate::catalog::reference_volume::{Settings, RENDERER};
use crate::scene::{BlendMode, HalfSpace, Light, RayGenerator, TransferFunction, VolumeShading};
use anyhow::{anyhow, Result};
use glam::{DMat4, DVec3};
use rayon::prelude::*;
use volterra_formats::Volume;

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
        crate::geometry::trilinear(self.dims, p, |i| self.values[i] as f64)
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
    render_fused(std::slice::from_ref(input), rays, settings)
}

/// One volume placed for ray casting: index space, its crop, step and field.
struct Placed<'a> {
    input: &'a VolumeInput<'a>,
    world_to_index: DMat4,
    crop: Vec<HalfSpace>,
    dt: f64,
    field: Field,
    shader: Option<super::volume_shading::Shader>,
    g_to_world: glam::DMat3,
    gradient_opacity: bool,
    lo: DVec3,
    hi: DVec3,
}

impl<'a> Placed<'a> {
    fn new(input: &'a VolumeInput<'a>, settings: &Settings) -> Result<Placed<'a>> {
        let VolumeInput { volume, node_to_world, tf, shading, lights, crop, .. } = *input;
        let index_to_world = crate::geometry::index_to_world(node_to_world, crate::geometry::affine_matrix(&volume.affine))?;
        let index_to_node = crate::geometry::affine_matrix(&volume.affine);
        let min_spacing = (0..3).map(|c| index_to_world.col(c).truncate().length()).fold(f64::INFINITY, f64::min);
        let hi = DVec3::new((volume.dims[0] - 1) as f64, (volume.dims[1] - 1) as f64, (volume.dims[2] - 1) as f64);
        // A single-slice axis has zero thickness: give it half a voxel either side.
        let pad = DVec3::new(
            if volume.dims[0] == 1 { 0.5 } else { 0.0 },
            if volume.dims[1] == 1 { 0.5 } else { 0.0 },
            if volume.dims[2] == 1 { 0.5 } else { 0.0 },
        );
        Ok(Placed {
            input,
            world_to_index: index_to_world.inverse(),
            crop: crop.iter().map(|h| h.pulled_back(index_to_node)).collect(),
            dt: settings.step * min_spacing,
            field: Field::new(volume),
            shader: super::volume_shading::Shader::new(shading, lights, index_to_world)?,
            g_to_world: super::volume_shading::gradient_to_world(index_to_world),
            gradient_opacity: !tf.gradient_opacity.is_empty(),
            lo: -pad,
            hi: hi + pad,
        })
    }

    /// A world ray in this volume's index space (world and index space share the ray's
    /// parameter: the map between them is affine), once per ray, not per sample.
    fn index_ray(&self, origin: DVec3, dir: DVec3) -> (DVec3, DVec3) {
        (self.world_to_index.transform_point3(origin), self.world_to_index.transform_vector3(dir))
    }

    /// The index-space ray's parameter interval inside this volume's drawn region.
    fn interval(&self, (o, d): (DVec3, DVec3)) -> Option<(f64, f64)> {
        crate::geometry::clip_box(o, d, self.lo, self.hi)
            .and_then(|t| crate::scene::crop::clip_interval(o, d, t, &self.crop))
            .filter(|(a, b)| a < b)
    }

    /// Value, opacity for a segment of length `len` and colour at parameter t of the world
    /// ray (origin, dir), whose index-space form is `(o, d)`.
    fn classify(&self, (o, d): (DVec3, DVec3), origin: DVec3, dir: DVec3, t: f64, len: f64) -> (f64, f64, [f64; 3]) {
        use super::volume_shading::gradient;
        let tf = self.input.tf;
        let p = o + d * t;
        let v = self.field.sample(p);
        // The gradient, where the gradient opacity or shading reads it.
        let mut g = None;
        let mut grad = || *g.get_or_insert_with(|| gradient(self.input.volume.dims, p, &self.g_to_world, |q| self.field.sample(q)));
        let alpha = if self.gradient_opacity && tf.opacity(v) > 0.0 {
            tf.scaled_opacity_for_step(v, len, tf.gradient_factor(grad().length()))
        } else {
            tf.opacity_for_step(v, len)
        };
        let mut col = [0.0; 3];
        if alpha > 0.0 {
            col = tf.color(v);
            if let Some(sh) = &self.shader {
                col = sh.shade(col, grad(), origin + dir * t, dir);
            }
        }
        (v, alpha, col)
    }
}

/// Several volumes cast together (see the module's comment for the fusion rule); one
/// volume is the plain ray caster. Each volume's step is `settings.step` of its own
/// smallest spacing; a ray steps at the finest step of the volumes it is inside. MIP
/// draws one volume only.
pub fn render_fused(inputs: &[VolumeInput], rays: &RayGenerator, settings: &Settings) -> Result<Frame> {
    let (width, height) = rays.size();
    settings.validate().map_err(|e| anyhow!("{}: {e}", RENDERER.name))?;
    if inputs.len() != 1 && inputs.iter().any(|i| i.blend == BlendMode::Mip) {
        return Err(anyhow!("MIP volumes are not fused with others: draw them as separate layers"));
    }
    let start = std::time::Instant::now();
    let placed: Vec<Placed> = inputs.iter().map(|i| Placed::new(i, settings)).collect::<Result<_>>()?;
    let mip = inputs.len() == 1 && inputs[0].blend == BlendMode::Mip;

    let mut frame = Frame::empty(width, height);
    let samples: u64 =
        super::driver::render_bands("reference ray casting", width, 1, &mut frame.rgba, &mut frame.depth, &mut [], |band| {
            let (y, row, depth) = (band.y0, band.rgba, band.depth);
            let mut n = 0u64;
            let mut cuts: Vec<f64> = Vec::with_capacity(2 * placed.len());
            let mut spans: Vec<Option<(f64, f64)>> = vec![None; placed.len()];
            let mut index_rays: Vec<(DVec3, DVec3)> = vec![(DVec3::ZERO, DVec3::ZERO); placed.len()];
            let mut active: Vec<usize> = Vec::with_capacity(placed.len());
            for x in 0..width {
                let ray = rays.ray(x as f64 + 0.5, y as f64 + 0.5);
                cuts.clear();
                for (k, p) in placed.iter().enumerate() {
                    index_rays[k] = p.index_ray(ray.origin, ray.dir);
                    spans[k] = p.interval(index_rays[k]);
                    if let Some((a, b)) = spans[k] {
                        cuts.extend([a, b]);
                    }
                }
                if cuts.is_empty() {
                    continue;
                }
                cuts.sort_by(f64::total_cmp);
                cuts.dedup();
                let (mut c, mut a) = ([0.0f64; 3], 0.0f64);
                let mut z = f32::INFINITY;
                let (mut max_v, mut max_t) = (f64::NEG_INFINITY, 0.0);
                'ray: for piece in cuts.windows(2) {
                    let (t0, t1) = (piece[0], piece[1]);
                    // The volumes inside for the whole piece (cut at every entry and exit).
                    let mid = 0.5 * (t0 + t1);
                    active.clear();
                    active.extend((0..placed.len()).filter(|&k| spans[k].is_some_and(|(a, b)| a <= mid && mid < b)));
                    let Some(dt) = active.iter().map(|&k| placed[k].dt).reduce(f64::min) else { continue };
                    let steps = ((t1 - t0) / dt).ceil() as usize;
                    for s in 0..steps {
                        // Each sample stands for its segment; the last one may be shorter.
                        let ta = t0 + s as f64 * dt;
                        let len = dt.min(t1 - ta);
                        let t = ta + 0.5 * len;
                        n += 1;
                        if mip {
                            let (o, d) = index_rays[0];
                            let v = placed[0].field.sample(o + d * t);
                            if v > max_v {
                                max_v = v;
                                max_t = t;
                            }
                            continue;
                        }
                        let (alpha, col) = if let [k] = active[..] {
                            let (_, alpha, col) = placed[k].classify(index_rays[k], ray.origin, ray.dir, t, len);
                            (alpha, col)
                        } else {
                            fuse(active.iter().map(|&k| placed[k].classify(index_rays[k], ray.origin, ray.dir, t, len)))
                        };
                        if alpha > 0.0 {
                            let w = (1.0 - a) * alpha;
                            for k in 0..3 {
                                c[k] += w * col[k];
                            }
                            a += w;
                            if a >= 0.5 && z.is_infinite() {
                                z = t as f32;
                            }
                            if a >= settings.termination {
                                break 'ray;
                            }
                        }
                    }
                }
                if mip && max_v.is_finite() {
                    let tf = inputs[0].tf;
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
    let dt = placed.iter().map(|p| p.dt).fold(f64::INFINITY, f64::min);
    frame.stats = FrameStats {
        renderer: RENDERER.name.into(),
        seconds: start.elapsed().as_secs_f64(),
        counters: vec![("samples".into(), samples as f64), ("step_mm".into(), dt)],
        notes: if inputs.len() > 1 { vec![format!("{} volumes fused along each ray", inputs.len())] } else { vec![] },
        nodes: vec![],
    };
    Ok(frame)
}

/// Several media at one sample (value, opacity over the segment, colour each): extinctions
/// add, the colour is the extinction-weighted mean. An opaque one (α = 1, infinite
/// extinction) outweighs every translucent one.
pub fn fuse(samples: impl Iterator<Item = (f64, f64, [f64; 3])>) -> (f64, [f64; 3]) {
    let (mut clear, mut sum, mut col) = (1.0f64, 0.0f64, [0.0f64; 3]);
    let (mut opaque, mut opaque_col) = (0usize, [0.0f64; 3]);
    for (_, alpha, c) in samples {
        clear *= 1.0 - alpha;
        if alpha >= 1.0 {
            opaque += 1;
            for k in 0..3 {
                opaque_col[k] += c[k];
            }
        } else if alpha > 0.0 {
            let sigma = -(1.0 - alpha).ln();
            sum += sigma;
            for k in 0..3 {
                col[k] += sigma * c[k];
            }
        }
    }
    if opaque > 0 {
        return (1.0, opaque_col.map(|c| c / opaque as f64));
    }
    if sum <= 0.0 {
        return (0.0, [0.0; 3]);
    }
    (1.0 - clear, col.map(|c| c / sum))
}
