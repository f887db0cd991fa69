//! `points`: particles as spheres on the GPU (wgpu; WGSL in `shaders/points.wgsl`) — the
//! fast look at simulation output before (or instead of) smoke. Each particle is a sphere
//! of its smoothing length h (or a fixed radius), coloured by a point array through a
//! colour map and shaded by a headlight; each pixel's ray is intersected exactly with the
//! sphere, so `Z` is the distance along the same rays every renderer uses and the node
//! depth-composites with the others. [`render_reference`] is the brute-force CPU version
//! the tests hold it to.

pub use crate::render::colormap::Colormap;
use crate::render::colormap::ColourScale;

use super::registry::{NodeSettings, RendererDecl};
use super::settings::{Bounds, Control, SettingError, Widget};
use crate::render::{Frame, FrameStats};
use crate::scene::camera::RayGenerator;
use crate::scene::NodeKind;
use anyhow::{anyhow, bail, Result};
use glam::{DMat3, DMat4, DVec3};
use rayon::prelude::*;
use std::sync::OnceLock;
use std::time::Instant;
use volterra_formats::ParticleSet;

crate::setting_choice! {
    /// How each particle is drawn.
    pub enum PointStyle {
        /// An opaque sphere of the particle's radius, shaded by a headlight; exact
        /// ray-sphere depth.
        Spheres = "spheres",
        /// A translucent Gaussian blob (σ = radius / 3, cut at the radius), unshaded, blended
        /// order-independently: the look of a density field rather than of balls.
        Splats = "splats",
    }
}

crate::declare_settings! {
    pub struct Settings {
        /// How each particle is drawn.
        pub style: PointStyle = PointStyle::Spheres, viewer = Control { label: "Style", widget: Widget::ByType };
        /// Sphere radius in the particles' length unit; 0: each particle's smoothing length h.
        pub radius: f64 = 0.0, range = Bounds::above(0.0), zero = "auto: each particle's h",
            viewer = Control { label: "Radius (0: h)", widget: Widget::Drag { lo: 0.0, hi: 1e30, speed: 0.001 } };
        /// The colour map for the node's `color_by` array.
        pub colormap: Colormap = Colormap::Viridis, viewer = Control { label: "Colour map", widget: Widget::ByType };
        /// Splats only: each splat's opacity at its centre (falling off as its Gaussian).
        pub opacity: f64 = 0.3, range = Bounds::open_closed(0.0, 1.0),
            viewer = Control { label: "Opacity", widget: Widget::Slider { lo: 0.01, hi: 1.0, step: 0.01 } };
    }
}

/// The settings a node's table gives; `opacity` is refused unless the style is splats
/// (spheres are opaque), before anything is drawn.
fn parse(t: &toml::Table) -> Result<NodeSettings, SettingError> {
    let s = Settings::from_table(t)?;
    if s.style != PointStyle::Splats && t.contains_key("opacity") {
        return Err(SettingError { key: "opacity".into(), message: "applies to style = \"splats\" only (spheres are opaque)".into() });
    }
    Ok(NodeSettings::Points(s))
}

pub const RENDERER: RendererDecl = RendererDecl {
    name: "points",
    kind: NodeKind::Particles,
    doc: "Every particle as a sphere or a Gaussian splat on the GPU (wgpu), coloured by a point \
          array (the node's `color_by`, default density) through a colour map over \
          `color_range` (default: the data's range). Spheres: shaded by a headlight, exact \
          ray-sphere depth. Splats: blended order-independently, depth where a ray passes \
          within σ of a centre. Composited with the other nodes by depth.",
    reference: false,
    settings: Settings::DECLS,
    parse,
};

/// What the points renderer draws: the particles, placed, and what colours them.
pub struct PointsInput<'a> {
    pub particles: &'a ParticleSet,
    pub node_to_world: DMat4,
    /// The point array coloured by (`density`, `mass`, `h` or any array; a vector's
    /// magnitude). None: density where the particles have it, else one colour.
    pub color_by: Option<&'a str>,
    /// Values mapped to the colour map's ends (None: the data's range).
    pub range: Option<[f64; 2]>,
}

/// A particle as drawn: world centre, radius and colour (linear RGB).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sphere {
    pub centre: DVec3,
    pub radius: f64,
    pub colour: [f32; 3],
}

/// The values `color_by` names, one per particle, and the name used (None: no array).
fn values<'a>(p: &'a ParticleSet, color_by: Option<&'a str>) -> Result<Option<(String, Vec<f64>)>> {
    let f32s = |v: &Vec<f32>| v.iter().map(|&x| x as f64).collect::<Vec<f64>>();
    let name = match color_by {
        Some(n) => n,
        None if p.density.is_some() => "density",
        None => return Ok(None),
    };
    let special = match name {
        "density" => p.density.as_ref().map(f32s),
        "mass" => p.mass.as_ref().map(f32s),
        "h" => p.smoothing_length.as_ref().map(f32s),
        _ => None,
    };
    if let Some(v) = special {
        return Ok(Some((name.into(), v)));
    }
    let a = p.arrays.iter().find(|a| a.name == name).ok_or_else(|| {
        let mut names: Vec<&str> = p.arrays.iter().map(|a| a.name.as_str()).collect();
        for (n, present) in [("density", p.density.is_some()), ("mass", p.mass.is_some()), ("h", p.smoothing_length.is_some())] {
            if present {
                names.push(n);
            }
        }
        anyhow!("color_by: no point array '{name}' (the particles have: {})", names.join(", "))
    })?;
    let c = a.components.max(1);
    let v = if c == 1 { a.values.clone() } else { a.values.chunks(c).map(|v| v.iter().map(|x| x * x).sum::<f64>().sqrt()).collect() };
    Ok(Some((name.into(), v)))
}

/// The array coloured by and the values at the colour map's ends.
pub type ColourRange = (String, [f64; 2]);

/// The particles as spheres in world space, each coloured, with the value range used.
pub fn spheres(input: &PointsInput, s: &Settings) -> Result<(Vec<Sphere>, Option<ColourRange>)> {
    let p = input.particles;
    if p.is_empty() {
        bail!("the particle set is empty: there is nothing to draw");
    }
    let m = input.node_to_world;
    let scale = DMat3::from_mat4(m).determinant().abs().cbrt();
    let h = p.smoothing_length.as_ref();
    if s.radius == 0.0 && h.is_none() {
        bail!("the particles have no smoothing length h: give settings.radius");
    }
    let values = values(p, input.color_by)?;
    let range = values.as_ref().map(|(name, v)| {
        let r = input.range.unwrap_or_else(|| volterra_formats::finite_range(v.iter().copied()).map_or([0.0, 1.0], |(lo, hi)| [lo, hi]));
        (name.clone(), r)
    });
    let radius = |i: usize| if s.radius > 0.0 { s.radius } else { h.unwrap()[i] as f64 } * scale;
    // The first bad radius (the lowest index, whatever the threads).
    if let Some(i) = (0..p.len()).into_par_iter().find_first(|&i| !(radius(i).is_finite() && radius(i) > 0.0)) {
        bail!("particle {i} has radius {} (h must be positive and finite)", radius(i));
    }
    let out = (0..p.len())
        .into_par_iter()
        .map(|i| {
            let colour = match (&values, &range) {
                (Some((_, v)), Some((_, [lo, hi]))) => s.colormap.at(if hi > lo { (v[i] - lo) / (hi - lo) } else { 0.5 }),
                _ => [0.8; 3],
            };
            Sphere { centre: m.transform_point3(DVec3::from(p.positions[i])), radius: radius(i), colour }
        })
        .collect();
    Ok((out, range))
}

/// The shading of a hit: the colour times 0.3 + 0.7 |n · −d|, as the shader does.
fn shade(colour: [f32; 3], n: DVec3, d: DVec3) -> [f32; 4] {
    let k = (0.3 + 0.7 * n.dot(-d).max(0.0)) as f32;
    [colour[0] * k, colour[1] * k, colour[2] * k, 1.0]
}

/// The nearest hit of a ray with a sphere (t > 0), in the shader's form.
fn hit(o: DVec3, d: DVec3, s: &Sphere) -> Option<f64> {
    let oc = o - s.centre;
    let b = oc.dot(d);
    let q = oc - b * d;
    let disc = s.radius * s.radius - q.length_squared();
    let t = -b - disc.sqrt();
    (disc >= 0.0 && t > 0.0).then_some(t)
}

/// The brute-force CPU version: every pixel's ray against every sphere, in f64 (the tests'
/// reference; O(pixels × particles)).
pub fn render_reference(spheres: &[Sphere], rays: &RayGenerator) -> Frame {
    let (w, h) = rays.size();
    let mut frame = Frame::empty(w, h);
    for y in 0..h {
        for x in 0..w {
            let ray = rays.ray(x as f64 + 0.5, y as f64 + 0.5);
            let best = spheres.iter().filter_map(|s| hit(ray.origin, ray.dir, s).map(|t| (t, s))).min_by(|a, b| a.0.total_cmp(&b.0));
            if let Some((t, s)) = best {
                let n = (ray.origin + t * ray.dir - s.centre).normalize();
                frame.rgba[y * w + x] = shade(s.colour, n, ray.dir);
                frame.depth[y * w + x] = t as f32;
            }
        }
    }
    frame
}

/// The brute-force CPU version of the splats, in f64: every pixel's ray against every
/// splat, with the shader's formulas (see `fs_splat` in shaders/points.wgsl).
pub fn render_splats_reference(spheres: &[Sphere], rays: &RayGenerator, opacity: f64) -> Frame {
    let (w, h) = rays.size();
    let mut frame = Frame::empty(w, h);
    for y in 0..h {
        for x in 0..w {
            let ray = rays.ray(x as f64 + 0.5, y as f64 + 0.5);
            let mut acc = SplatSums::default();
            for s in spheres {
                let oc = ray.origin - s.centre;
                let b = oc.dot(ray.dir);
                let q2 = (oc - b * ray.dir).length_squared() / (s.radius * s.radius);
                if q2 < 1.0 && -b > 0.0 {
                    let a = opacity * (-4.5 * q2).exp();
                    for k in 0..3 {
                        acc.colour[k] += s.colour[k] as f64 * a;
                    }
                    acc.weight += a;
                    acc.clear *= 1.0 - a;
                    if q2 <= 1.0 / 9.0 {
                        acc.dist = acc.dist.min(-b);
                    }
                }
            }
            (frame.rgba[y * w + x], frame.depth[y * w + x]) = acc.resolve();
        }
    }
    frame
}

/// What the splats leave in a pixel: Σ colour·α, Σ α, Π (1 − α) and the least distance.
struct SplatSums {
    colour: [f64; 3],
    weight: f64,
    clear: f64,
    dist: f64,
}

impl Default for SplatSums {
    fn default() -> Self {
        SplatSums { colour: [0.0; 3], weight: 0.0, clear: 1.0, dist: f64::INFINITY }
    }
}

impl SplatSums {
    /// Weighted blended order-independent transparency: the α-weighted mean colour, with
    /// coverage 1 − Π (1 − α) (premultiplied); the distance, +∞ where no splat is near.
    fn resolve(&self) -> ([f32; 4], f32) {
        if self.weight <= 0.0 {
            return ([0.0; 4], f32::INFINITY);
        }
        let a = 1.0 - self.clear;
        let c = self.colour.map(|c| (c / self.weight * a) as f32);
        ([c[0], c[1], c[2], a as f32], if self.dist < 1e38 { self.dist as f32 } else { f32::INFINITY })
    }
}

struct Pipelines {
    layout: wgpu::BindGroupLayout,
    spheres: wgpu::RenderPipeline,
    /// None where the adapter cannot blend 32-bit float targets.
    splats: Option<wgpu::RenderPipeline>,
}

static PIPELINES: OnceLock<Pipelines> = OnceLock::new();

fn pipelines(dev: &wgpu::Device) -> &'static Pipelines {
    PIPELINES.get_or_init(|| {
        let entry = |binding: u32, ty: wgpu::BufferBindingType| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
            ty: wgpu::BindingType::Buffer { ty, has_dynamic_offset: false, min_binding_size: None },
            count: None,
        };
        let storage = wgpu::BufferBindingType::Storage { read_only: true };
        let layout = dev.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("points"),
            entries: &[entry(0, wgpu::BufferBindingType::Uniform), entry(1, storage), entry(2, storage)],
        });
        // The fragment's depth is never nearer than the triangle's (the sphere's nearest
        // point): with the adapter's early depth test, hidden fragments are never shaded.
        let source = include_str!("../../../shaders/points.wgsl");
        let source = if dev.features().contains(wgpu::Features::SHADER_EARLY_DEPTH_TEST) {
            source.replace("@fragment\nfn fs(", "@fragment @early_depth_test(greater_equal)\nfn fs(")
        } else {
            source.to_string()
        };
        let module = dev.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("points.wgsl"),
            source: wgpu::ShaderSource::Wgsl(source.into()),
        });
        let pl = dev.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("points"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = |entry: &str, depth: bool, targets: &[Option<wgpu::ColorTargetState>]| {
            dev.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some(entry),
                layout: Some(&pl),
                vertex: wgpu::VertexState {
                    module: &module,
                    entry_point: Some("vs"),
                    compilation_options: Default::default(),
                    buffers: &[],
                },
                primitive: wgpu::PrimitiveState { cull_mode: None, ..Default::default() },
                depth_stencil: depth.then(|| wgpu::DepthStencilState {
                    format: wgpu::TextureFormat::Depth32Float,
                    depth_write_enabled: Some(true),
                    depth_compare: Some(wgpu::CompareFunction::Less),
                    stencil: Default::default(),
                    bias: Default::default(),
                }),
                multisample: Default::default(),
                fragment: Some(wgpu::FragmentState {
                    module: &module,
                    entry_point: Some(entry),
                    compilation_options: Default::default(),
                    targets,
                }),
                multiview_mask: None,
                cache: None,
            })
        };
        let target = |format, blend| Some(wgpu::ColorTargetState { format, blend, write_mask: wgpu::ColorWrites::ALL });
        let spheres = pipeline("fs", true, &[target(SPHERE_TARGETS[0].0, None), target(SPHERE_TARGETS[1].0, None)]);
        use wgpu::{BlendComponent as C, BlendFactor as F, BlendOperation as O};
        let add = C { src_factor: F::One, dst_factor: F::One, operation: O::Add };
        let splats = dev.features().contains(wgpu::Features::FLOAT32_BLENDABLE).then(|| {
            // Colour sums; coverage as the product of (1 − α); α sums; the least distance.
            let product = C { src_factor: F::Zero, dst_factor: F::OneMinusSrcAlpha, operation: O::Add };
            let least = C { src_factor: F::One, dst_factor: F::One, operation: O::Min };
            pipeline(
                "fs_splat",
                false,
                &[
                    target(SPLAT_TARGETS[0].0, Some(wgpu::BlendState { color: add, alpha: product })),
                    target(SPLAT_TARGETS[1].0, Some(wgpu::BlendState { color: add, alpha: add })),
                    target(SPLAT_TARGETS[2].0, Some(wgpu::BlendState { color: least, alpha: least })),
                ],
            )
        });
        Pipelines { layout, spheres, splats }
    })
}

/// A render target: its format and what it is cleared to.
type Target = (wgpu::TextureFormat, wgpu::Color);

/// Spheres: shaded colour, distance along the ray.
const SPHERE_TARGETS: [Target; 2] =
    [(wgpu::TextureFormat::Rgba32Float, wgpu::Color::TRANSPARENT), (wgpu::TextureFormat::R32Float, wgpu::Color::TRANSPARENT)];
/// Splats: (Σ colour·α, Π (1 − α)), Σ α, the least distance.
const SPLAT_TARGETS: [Target; 3] = [
    (wgpu::TextureFormat::Rgba32Float, wgpu::Color { r: 0.0, g: 0.0, b: 0.0, a: 1.0 }),
    (wgpu::TextureFormat::R32Float, wgpu::Color::TRANSPARENT),
    (wgpu::TextureFormat::R32Float, wgpu::Color { r: 3.0e38, g: 3.0e38, b: 3.0e38, a: 3.0e38 }),
];

/// The view the shader needs (std140-compatible: three vec4 and eight 4-byte values).
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct ViewUniform {
    forward: [f32; 4],
    right: [f32; 4],
    up: [f32; 4],
    half_w: f32,
    half_h: f32,
    width: f32,
    height: f32,
    parallel: u32,
    near: f32,
    far: f32,
    opacity: f32,
}

pub fn render(input: &PointsInput, rays: &RayGenerator, s: &Settings) -> Result<Frame> {
    let start = Instant::now();
    let (spheres, range) = spheres(input, s)?;
    let dev = crate::render::gpu::device()?;
    let p = pipelines(&dev.device);
    let splats = match (s.style, &p.splats) {
        (PointStyle::Spheres, _) => None,
        (PointStyle::Splats, Some(pipeline)) => Some(pipeline),
        (PointStyle::Splats, None) => bail!(
            "splats sum into 32-bit float render targets, and the GPU '{}' cannot blend them (wgpu's FLOAT32_BLENDABLE); use style = \"spheres\"",
            dev.info.name
        ),
    };
    let (w, h) = rays.size();
    let (eye, right, up) = rays.basis();
    let forward = rays.forward();
    let (half_w, half_h) = rays.half_extent();
    // Near and far bound the depth the shader writes, the distance along each pixel's ray
    // (a little room either side): from the spheres' extent along the view, and in
    // perspective far from their distance from the eye — off the axis a ray reaches a
    // sphere further than its depth along the view, and a far bound by depth put the
    // spheres at a wide view's edges behind the far plane, undrawn.
    let (near, far) = spheres
        .par_iter()
        .map(|sp| {
            let z = (sp.centre - eye).dot(forward);
            let reach = if rays.is_parallel() { z } else { (sp.centre - eye).length() };
            (z - sp.radius, reach + sp.radius)
        })
        .reduce(|| (f64::INFINITY, 0.0f64), |a, b| (a.0.min(b.0), a.1.max(b.1)));
    // Room either side, so the nearest and farthest spheres are not clipped; a sphere that
    // reaches the eye plane (perspective) is not drawn (the shader culls it).
    let near = if rays.is_parallel() { 0.0 } else { (0.999 * near).max(1e-6 * far.max(1e-30)) };
    let far = far.max(near + 1e-30) * 1.001;
    let f4 = |v: DVec3| [v.x as f32, v.y as f32, v.z as f32, 0.0];
    let view = ViewUniform {
        forward: f4(forward),
        right: f4(right),
        up: f4(up),
        half_w: half_w as f32,
        half_h: half_h as f32,
        width: w as f32,
        height: h as f32,
        parallel: rays.is_parallel() as u32,
        near: near as f32,
        far: far as f32,
        opacity: s.opacity as f32,
    };
    let centres: Vec<[f32; 4]> = spheres
        .par_iter()
        .map(|sp| {
            let c = sp.centre - eye;
            [c.x as f32, c.y as f32, c.z as f32, sp.radius as f32]
        })
        .collect();
    let colours: Vec<[f32; 4]> = spheres.par_iter().map(|sp| [sp.colour[0], sp.colour[1], sp.colour[2], 1.0]).collect();
    let buffers = Buffers { view: &view, centres: &centres, colours: &colours, w, h };
    let mut frame = Frame::empty(w, h);
    let seconds = match splats {
        None => {
            let (targets, seconds) =
                dev.guarded("drawing the particles on the GPU", || draw(dev, &p.spheres, true, &SPHERE_TARGETS, &buffers))?;
            let (colour, dist) = (&targets[0], &targets[1]);
            frame.rgba.par_iter_mut().zip(frame.depth.par_iter_mut()).enumerate().for_each(|(i, (rgba, depth))| {
                if colour[4 * i + 3] > 0.0 {
                    *rgba = [colour[4 * i], colour[4 * i + 1], colour[4 * i + 2], colour[4 * i + 3]];
                    *depth = dist[i];
                }
            });
            seconds
        }
        Some(pipeline) => {
            let (targets, seconds) =
                dev.guarded("drawing the particles on the GPU", || draw(dev, pipeline, false, &SPLAT_TARGETS, &buffers))?;
            let (sums, weight, dist) = (&targets[0], &targets[1], &targets[2]);
            frame.rgba.par_iter_mut().zip(frame.depth.par_iter_mut()).enumerate().for_each(|(i, (rgba, depth))| {
                let c = &sums[4 * i..4 * i + 4];
                let acc = SplatSums {
                    colour: [c[0], c[1], c[2]].map(f64::from),
                    clear: c[3] as f64,
                    weight: weight[i] as f64,
                    dist: dist[i] as f64,
                };
                (*rgba, *depth) = acc.resolve();
            });
            seconds
        }
    };
    let drawn = frame.rgba.iter().filter(|p| p[3] > 0.0).count();
    let mut notes = vec![format!("GPU: {} ({:?})", dev.info.name, dev.info.backend)];
    if let Some((name, [lo, hi])) = &range {
        notes.push(format!("colour: {name} from {lo} to {hi} ({})", s.colormap.name()));
        frame.scales.push(ColourScale { title: name.clone(), colormap: s.colormap, range: [*lo, *hi] });
    }
    frame.stats = FrameStats {
        renderer: RENDERER.name.into(),
        seconds: start.elapsed().as_secs_f64(),
        counters: vec![
            ("particles".into(), spheres.len() as f64),
            ("pixels covered".into(), drawn as f64),
            ("GPU ms".into(), seconds * 1e3),
        ],
        notes,
        nodes: vec![],
    };
    Ok(frame)
}

/// What a draw reads: the view, each sphere's eye-relative centre and radius, its colour,
/// and the picture's size.
struct Buffers<'a> {
    view: &'a ViewUniform,
    centres: &'a [[f32; 4]],
    colours: &'a [[f32; 4]],
    w: usize,
    h: usize,
}

/// Draws every sphere once through `pipeline` into `targets` (with a depth buffer when
/// `depth`) and reads each target back as f32 values (all are 32-bit float formats); also
/// the seconds the draw took on the GPU side (submit to done).
fn draw(
    dev: &crate::render::gpu::Device,
    pipeline: &wgpu::RenderPipeline,
    depth: bool,
    targets: &[Target],
    b: &Buffers,
) -> Result<(Vec<Vec<f32>>, f64)> {
    use wgpu::util::DeviceExt;
    let (d, w, h) = (&dev.device, b.w, b.h);
    let p = pipelines(d);
    let buffer = |label: &str, bytes: &[u8], usage| {
        d.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some(label), contents: bytes, usage })
    };
    let uniform = buffer("points view", bytemuck::bytes_of(b.view), wgpu::BufferUsages::UNIFORM);
    let spheres = buffer("spheres", bytemuck::cast_slice(b.centres), wgpu::BufferUsages::STORAGE);
    let colour_buf = buffer("colours", bytemuck::cast_slice(b.colours), wgpu::BufferUsages::STORAGE);
    let bind = d.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("points"),
        layout: &p.layout,
        entries: &[
            wgpu::BindGroupEntry { binding: 0, resource: uniform.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 1, resource: spheres.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 2, resource: colour_buf.as_entire_binding() },
        ],
    });
    let size = wgpu::Extent3d { width: w as u32, height: h as u32, depth_or_array_layers: 1 };
    let texture = |format| {
        d.create_texture(&wgpu::TextureDescriptor {
            label: Some("points target"),
            size,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
            view_formats: &[],
        })
    };
    let textures: Vec<wgpu::Texture> = targets.iter().map(|t| texture(t.0)).collect();
    let views: Vec<wgpu::TextureView> = textures.iter().map(|t| t.create_view(&Default::default())).collect();
    let depth_tex = depth.then(|| texture(wgpu::TextureFormat::Depth32Float));
    let depth_view = depth_tex.as_ref().map(|t| t.create_view(&Default::default()));
    let attachments: Vec<Option<wgpu::RenderPassColorAttachment>> = views
        .iter()
        .zip(targets)
        .map(|(view, t)| {
            Some(wgpu::RenderPassColorAttachment {
                view,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations { load: wgpu::LoadOp::Clear(t.1), store: wgpu::StoreOp::Store },
            })
        })
        .collect();
    let mut enc = d.create_command_encoder(&Default::default());
    {
        let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("points"),
            color_attachments: &attachments,
            depth_stencil_attachment: depth_view.as_ref().map(|view| wgpu::RenderPassDepthStencilAttachment {
                view,
                depth_ops: Some(wgpu::Operations { load: wgpu::LoadOp::Clear(1.0), store: wgpu::StoreOp::Discard }),
                stencil_ops: None,
            }),
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, &bind, &[]);
        pass.draw(0..3, 0..b.centres.len() as u32);
    }
    // Rows padded to 256 bytes for the copies.
    let padded = |bytes_per_pixel: usize| (w * bytes_per_pixel).div_ceil(256) * 256;
    let bpp = |format: wgpu::TextureFormat| format.block_copy_size(None).unwrap_or(4) as usize;
    // Copied straight into buffers the host maps (no second copy into a staging buffer).
    let rows: Vec<wgpu::Buffer> = textures
        .iter()
        .map(|tex| {
            let bpp = bpp(tex.format());
            let buf = d.create_buffer(&wgpu::BufferDescriptor {
                label: Some("points read-back"),
                size: (padded(bpp) * h) as u64,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            enc.copy_texture_to_buffer(
                tex.as_image_copy(),
                wgpu::TexelCopyBufferInfo {
                    buffer: &buf,
                    layout: wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(padded(bpp) as u32), rows_per_image: None },
                },
                size,
            );
            buf
        })
        .collect();
    let t = Instant::now();
    dev.queue.submit([enc.finish()]);
    d.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| anyhow!("drawing the particles on the GPU failed: {e}"))?;
    let seconds = t.elapsed().as_secs_f64();
    dev.map_for_reading(&rows.iter().collect::<Vec<_>>())?;
    let mut out = Vec::with_capacity(rows.len());
    for (buf, tex) in rows.iter().zip(&textures) {
        let row_values = w * bpp(tex.format()) / 4;
        let mapped = buf.slice(..).get_mapped_range().map_err(|e| anyhow!("GPU read-back failed: {e:?}"))?;
        let values: &[f32] = bytemuck::cast_slice(&mapped);
        let mut unpadded = Vec::with_capacity(row_values * h);
        for row in values.chunks(padded(bpp(tex.format())) / 4) {
            unpadded.extend_from_slice(&row[..row_values]);
        }
        out.push(unpadded);
    }
    Ok((out, seconds))
}
