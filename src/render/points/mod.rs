//! `points`: particles as spheres on the GPU (wgpu; WGSL in `shaders/points.wgsl`) — the
//! fast look at simulation output before (or instead of) smoke. Each particle is a sphere
//! of its smoothing length h (or a fixed radius), coloured by a point array through a
//! colour map and shaded by a headlight; each pixel's ray is intersected exactly with the
//! sphere, so `Z` is the distance along the same rays every renderer uses and the node
//! depth-composites with the others. Or each a Gaussian splat, blended order-independently
//! by a compute pass over 8×4-pixel tiles (the host bins each splat's exact ellipse into
//! the tiles, in particle order). [`render_reference`] and [`render_splats_reference`] are
//! the brute-force CPU versions the tests hold it to.

pub use crate::colormap::Colormap;
use crate::colormap::ColourScale;

pub use crate::catalog::points::{PointStyle, RadiusOf, Settings, RENDERER};
use crate::render::{Frame, FrameStats};
use crate::scene::camera::RayGenerator;
use anyhow::{anyhow, bail, Result};
use glam::{DMat3, DMat4, DVec3};
use rayon::prelude::*;
use std::sync::{Mutex, OnceLock};
use std::time::Instant;
use volterra_formats::ParticleSet;

/// What the points renderer draws: the particles, placed, and what colours them.
pub struct PointsInput<'a> {
    pub particles: &'a ParticleSet,
    pub node_to_world: DMat4,
    /// The point array coloured by (`density`, `mass`, `h` or any array; a vector's
    /// magnitude). None: density where the particles have it, else one colour.
    pub color_by: Option<&'a str>,
    /// Values mapped to the colour map's ends (None: the data's range).
    pub range: Option<[f64; 2]>,
    /// Half the distance from each particle to its nearest neighbour, at most its h
    /// (`spacing_radii`), where a caller keeps it between frames; None: found when needed.
    pub spacing: Option<&'a [f32]>,
}

/// Half the distance from each particle to its nearest other particle (node units), at
/// most its smoothing length h where it has one: spheres of these radii never overlap.
/// Particles sharing a position take the median of the others (duplicates draw as one);
/// a lone particle its h.
pub fn spacing_radii(p: &ParticleSet) -> Vec<f32> {
    // A lone particle has no neighbour: its h (else 1).
    if p.len() < 2 {
        return p.smoothing_length.clone().unwrap_or_else(|| vec![1.0; p.len()]);
    }
    let mut r: Vec<f64> = volterra_formats::sph::kth_neighbour_distance(&p.positions, 1).into_iter().map(|d| 0.5 * d).collect();
    if let Some(h) = &p.smoothing_length {
        for (r, &h) in r.iter_mut().zip(h) {
            if h > 0.0 && (h as f64) < *r {
                *r = h as f64;
            }
        }
    }
    let mut positive: Vec<f64> = r.iter().copied().filter(|v| *v > 0.0).collect();
    positive.sort_by(f64::total_cmp);
    let fallback = positive.get(positive.len() / 2).copied().unwrap_or(1.0);
    // Rounded down to f32, so that two spheres touching at most stay apart.
    let down = |v: f64| {
        let f = v as f32;
        if f as f64 > v {
            f32::from_bits(f.to_bits() - 1)
        } else {
            f
        }
    };
    r.into_iter().map(|v| down(if v > 0.0 { v } else { fallback })).collect()
}

/// A particle as drawn: world centre, radius and colour (linear RGB).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sphere {
    pub centre: DVec3,
    pub radius: f64,
    pub colour: [f32; 3],
}

/// The values `color_by` names, one per particle, and the name used (None: no array).
pub fn values<'a>(p: &'a ParticleSet, color_by: Option<&'a str>) -> Result<Option<(String, Vec<f64>)>> {
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
    // Each particle's own radius (node units), where `radius` gives none.
    let by_spacing = s.radius_by_spacing();
    if s.radius == 0.0 && !by_spacing && h.is_none() {
        bail!("the particles have no smoothing length h: give settings.radius, or radius_of = \"spacing\"");
    }
    let found;
    let spacing: Option<&[f32]> = match (by_spacing, input.spacing) {
        (false, _) => None,
        (true, Some(r)) => Some(r),
        (true, None) => {
            found = spacing_radii(p);
            Some(&found)
        }
    };
    let values = values(p, input.color_by)?;
    let range = values.as_ref().map(|(name, v)| {
        let r = input.range.unwrap_or_else(|| volterra_formats::finite_range(v.iter().copied()).map_or([0.0, 1.0], |(lo, hi)| [lo, hi]));
        (name.clone(), r)
    });
    let radius = |i: usize| {
        scale
            * match (s.radius > 0.0, spacing) {
                (true, _) => s.radius,
                (false, Some(r)) => r[i] as f64,
                (false, None) => h.unwrap()[i] as f64,
            }
    };
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
    splat_layout: wgpu::BindGroupLayout,
    splats: wgpu::ComputePipeline,
    /// The splats' buffers of the last frame, where the host maps storage buffers in place.
    kept: Mutex<Option<KeptSplatBuffers>>,
}

/// The splats' records and sums kept from frame to frame where the host maps storage
/// buffers in place (`Device::host_mapped_storage`): refilled rather than made afresh, so
/// their ~200 MB (1M particles at 1920×1080) are not zeroed and faulted in every frame.
/// Unmapped while kept; a frame takes them (another frame drawn meanwhile makes its own).
struct KeptSplatBuffers {
    /// MAP_WRITE | STORAGE, room for this many records.
    records: wgpu::Buffer,
    capacity: usize,
    /// MAP_READ | STORAGE, for this many pixels.
    sums: wgpu::Buffer,
    weight_dist: wgpu::Buffer,
    pixels: usize,
}

static PIPELINES: OnceLock<Pipelines> = OnceLock::new();

fn pipelines(dev: &wgpu::Device) -> &'static Pipelines {
    PIPELINES.get_or_init(|| {
        let entry = |binding: u32, visibility, ty: wgpu::BufferBindingType| wgpu::BindGroupLayoutEntry {
            binding,
            visibility,
            ty: wgpu::BindingType::Buffer { ty, has_dynamic_offset: false, min_binding_size: None },
            count: None,
        };
        let (draw, compute) = (wgpu::ShaderStages::VERTEX_FRAGMENT, wgpu::ShaderStages::COMPUTE);
        let (uniform, read) = (wgpu::BufferBindingType::Uniform, wgpu::BufferBindingType::Storage { read_only: true });
        let write = wgpu::BufferBindingType::Storage { read_only: false };
        let layout = dev.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("points"),
            entries: &[entry(0, draw, uniform), entry(1, draw, read), entry(2, draw, read)],
        });
        let splat_layout = dev.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("splats"),
            entries: &[
                entry(0, compute, uniform),
                entry(3, compute, read),
                entry(4, compute, read),
                entry(6, compute, write),
                entry(7, compute, write),
                entry(8, compute, read),
            ],
        });
        // The fragment's depth is never nearer than the triangle's (the sphere's nearest
        // point): with the adapter's early depth test, hidden fragments are never shaded.
        let source = format!(
            "const TILE_W: u32 = {SPLAT_TILE_W}u;\nconst TILE_H: u32 = {SPLAT_TILE_H}u;\n{}",
            include_str!("../../../shaders/points.wgsl")
        );
        let source = if dev.features().contains(wgpu::Features::SHADER_EARLY_DEPTH_TEST) {
            source.replace("@fragment\nfn fs(", "@fragment @early_depth_test(greater_equal)\nfn fs(")
        } else {
            source
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
        let target = |format| Some(wgpu::ColorTargetState { format, blend: None, write_mask: wgpu::ColorWrites::ALL });
        let spheres = dev.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("spheres"),
            layout: Some(&pl),
            vertex: wgpu::VertexState { module: &module, entry_point: Some("vs"), compilation_options: Default::default(), buffers: &[] },
            primitive: wgpu::PrimitiveState { cull_mode: None, ..Default::default() },
            depth_stencil: Some(wgpu::DepthStencilState {
                format: wgpu::TextureFormat::Depth32Float,
                depth_write_enabled: Some(true),
                depth_compare: Some(wgpu::CompareFunction::Less),
                stencil: Default::default(),
                bias: Default::default(),
            }),
            multisample: Default::default(),
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some("fs"),
                compilation_options: Default::default(),
                targets: &[target(SPHERE_TARGETS[0].0), target(SPHERE_TARGETS[1].0)],
            }),
            multiview_mask: None,
            cache: None,
        });
        let splats = dev.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("cs_splat"),
            layout: Some(&dev.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("splats"),
                bind_group_layouts: &[Some(&splat_layout)],
                immediate_size: 0,
            })),
            module: &module,
            entry_point: Some("cs_splat"),
            compilation_options: Default::default(),
            cache: None,
        });
        Pipelines { layout, spheres, splat_layout, splats, kept: Mutex::new(None) }
    })
}

/// A render target: its format and what it is cleared to.
type Target = (wgpu::TextureFormat, wgpu::Color);

/// Spheres: shaded colour, distance along the ray.
const SPHERE_TARGETS: [Target; 2] =
    [(wgpu::TextureFormat::Rgba32Float, wgpu::Color::TRANSPARENT), (wgpu::TextureFormat::R32Float, wgpu::Color::TRANSPARENT)];
/// The view the shader needs (std140-compatible: three vec4 and nine 4-byte values, padded).
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
    tiles_x: u32,
    first_batch: u32,
    _pad: [u32; 2],
}

pub fn render(input: &PointsInput, rays: &RayGenerator, s: &Settings) -> Result<Frame> {
    render_in_batches(input, rays, s, SPLAT_BATCH)
}

/// [`render`], with splats drawn in passes of at most `batch` tile records (render: 4M, 128 MB);
/// the tests force several passes on a small scene.
pub fn render_in_batches(input: &PointsInput, rays: &RayGenerator, s: &Settings, batch: usize) -> Result<Frame> {
    let start = Instant::now();
    let (spheres, range) = spheres(input, s)?;
    let dev = crate::gpu::device()?;
    let p = pipelines(&dev.device);
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
        tiles_x: w.div_ceil(SPLAT_TILE_W) as u32,
        first_batch: 1,
        _pad: [0; 2],
    };
    let mut frame = Frame::empty(w, h);
    let seconds = match s.style {
        PointStyle::Spheres => draw_spheres(dev, p, &spheres, eye, &view, &mut frame)?,
        PointStyle::Splats => draw_splats(dev, p, &spheres, (eye, right, up, forward), &view, batch, &mut frame)?,
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

/// Draws the spheres into `frame` (colour and distance where one is hit); returns the
/// seconds the GPU took.
fn draw_spheres(
    dev: &crate::gpu::Device,
    p: &Pipelines,
    spheres: &[Sphere],
    eye: DVec3,
    view: &ViewUniform,
    frame: &mut Frame,
) -> Result<f64> {
    let (w, h) = (frame.width, frame.height);
    let centres: Vec<[f32; 4]> = spheres
        .par_iter()
        .map(|sp| {
            let c = sp.centre - eye;
            [c.x as f32, c.y as f32, c.z as f32, sp.radius as f32]
        })
        .collect();
    let colours: Vec<[f32; 4]> = spheres.par_iter().map(|sp| [sp.colour[0], sp.colour[1], sp.colour[2], 1.0]).collect();
    let buffers = Buffers { view, centres: &centres, colours: &colours, w, h };
    let (targets, seconds) = dev.guarded("drawing the particles on the GPU", || draw(dev, &p.spheres, &SPHERE_TARGETS, &buffers))?;
    let (colour, dist) = (&targets[0], &targets[1]);
    frame.rgba.par_iter_mut().zip(frame.depth.par_iter_mut()).enumerate().for_each(|(i, (rgba, depth))| {
        if colour[4 * i + 3] > 0.0 {
            *rgba = [colour[4 * i], colour[4 * i + 1], colour[4 * i + 2], colour[4 * i + 3]];
            *depth = dist[i];
        }
    });
    Ok(seconds)
}

/// The tiles the splats are binned into, in pixels: one compute workgroup of 4×2
/// invocations, 2×2 pixels each — one step of lavapipe's 8 SIMD lanes. Each pixel of a tile
/// tests each of its splats, so the tiles are small: the 1M-particle plume's splats, about 7
/// pixels across, make 4.7 records each at 1920×1080, 149 M pixel tests a frame for 58 M
/// pixels inside their boxes; with 8×8 tiles (two SIMD steps) 3.2 records and 205 M tests,
/// and a frame 3–9 % slower, the fewer records notwithstanding.
const SPLAT_TILE_W: usize = 8;
const SPLAT_TILE_H: usize = 4;

/// The most tile records (32 bytes each) one pass of the splats draws: 128 MB.
const SPLAT_BATCH: usize = 1 << 22;

/// A splat as the shader reads it: the centre in the camera's frame and the falloff
/// −4.5 log2(e) / radius²; the colour (linear RGB) and 1 / c_z (see `splat_record`).
type SplatRecord = [[f32; 4]; 2];

/// A splat's record from its centre `c` in the camera's frame (f64, so each value is
/// rounded once), radius and colour: what the shader's pixel test multiplies by instead of
/// dividing (1 / c_z is never read in parallel views, nor for a splat behind the eye).
fn splat_record(c: [f64; 3], radius: f64, colour: [f32; 3]) -> SplatRecord {
    let falloff = -4.5 * std::f64::consts::LOG2_E / (radius * radius);
    [[c[0] as f32, c[1] as f32, c[2] as f32, falloff as f32], [colour[0], colour[1], colour[2], (1.0 / c[2]) as f32]]
}

/// The pixels (x0, y0, x1, y1, inclusive) whose centres may lie within a splat's cut, the
/// box round its exact ellipse on the image plane (as the spheres' triangle is; a 20th of a
/// pixel more each side, for the shader's f32 rounding at the cut) — or None where it
/// reaches no pixel, is behind the eye or reaches the eye plane (perspective: its
/// projection is unbounded; as for the spheres, it is not drawn). `c`: the centre in the
/// camera's frame and the radius, as the shader reads them.
fn splat_pixels(c: [f32; 4], view: &ViewUniform) -> Option<[u32; 4]> {
    let [cx, cy, cz, r] = c.map(f64::from);
    let (w, h) = (view.width as f64, view.height as f64);
    let (half_w, half_h) = (view.half_w as f64, view.half_h as f64);
    // Centre, semi-axis a along u (radially) and b across it, as the vertex shader's.
    let (p0, u, a, b) = if view.parallel != 0 {
        if cz <= 0.0 {
            return None;
        }
        ([cx, cy], [1.0, 0.0], r, r)
    } else {
        let e = (cz - r) * (cz + r);
        if cz - r <= 0.0 || e <= 0.0 {
            return None;
        }
        let rho = (cx * cx + cy * cy).sqrt();
        let u = if rho > 0.0 { [cx / rho, cy / rho] } else { [1.0, 0.0] };
        ([cx * cz / e, cy * cz / e], u, r * (e + rho * rho).sqrt() / e, r / e.sqrt())
    };
    let hx = ((a * u[0]).powi(2) + (b * u[1]).powi(2)).sqrt();
    let hy = ((a * u[1]).powi(2) + (b * u[0]).powi(2)).sqrt();
    // Image plane to pixel coordinates (pixel i's centre at i + 0.5; row 0 at the top).
    let margin = 0.05;
    let x_lo = (p0[0] - hx + half_w) * w / (2.0 * half_w) - margin;
    let x_hi = (p0[0] + hx + half_w) * w / (2.0 * half_w) + margin;
    let y_lo = (half_h - p0[1] - hy) * h / (2.0 * half_h) - margin;
    let y_hi = (half_h - p0[1] + hy) * h / (2.0 * half_h) + margin;
    let first = |lo: f64| (lo - 0.5).ceil().max(0.0);
    let last = |hi: f64, n: f64| (hi - 0.5).floor().min(n - 1.0);
    let (x0, x1, y0, y1) = (first(x_lo), last(x_hi, w), first(y_lo), last(y_hi, h));
    // NaN (an overflowing ellipse) fails these as well.
    (x0 <= x1 && y0 <= y1).then_some([x0 as u32, y0 as u32, x1 as u32, y1 as u32])
}

/// The columns and rows of tiles a splat's pixel box touches.
fn splat_tiles(b: &[u32; 4]) -> (std::ops::RangeInclusive<u32>, std::ops::RangeInclusive<u32>) {
    let (tw, th) = (SPLAT_TILE_W as u32, SPLAT_TILE_H as u32);
    (b[0] / tw..=b[2] / tw, b[1] / th..=b[3] / th)
}

/// The splats of each tile, in particle order: tile t's are `splats[start[t]..start[t + 1]]`
/// (row-major tiles of [`SPLAT_TILE_W`] × [`SPLAT_TILE_H`] pixels).
struct SplatBins {
    start: Vec<u32>,
    splats: Vec<u32>,
}

/// Bins each splat into the tiles its pixel box touches. In chunks of particles on rayon's
/// threads (each chunk counts, places and keeps its own list), then the chunks' lists
/// joined tile row by tile row: the same bins, in particle order, whatever the threads.
fn bin_splats(boxes: &[Option<[u32; 4]>], tiles_x: usize, tiles_y: usize) -> Result<SplatBins> {
    let tiles = tiles_x * tiles_y;
    let chunk = boxes.len().div_ceil(4 * rayon::current_num_threads()).max(1 << 14);
    // Per chunk: where each tile's entries start in its list, and the list.
    let chunks: Vec<(Vec<u32>, Vec<u32>)> = boxes
        .par_chunks(chunk)
        .enumerate()
        .map(|(ci, boxes)| {
            let mut start = vec![0u32; tiles + 1];
            for b in boxes.iter().flatten() {
                let (xs, ys) = splat_tiles(b);
                for ty in ys {
                    for tx in xs.clone() {
                        start[ty as usize * tiles_x + tx as usize + 1] += 1;
                    }
                }
            }
            for t in 0..tiles {
                start[t + 1] += start[t];
            }
            let mut next = start.clone();
            let mut list = vec![0u32; start[tiles] as usize];
            for (j, b) in boxes.iter().enumerate() {
                if let Some(b) = b {
                    let (xs, ys) = splat_tiles(b);
                    for ty in ys {
                        for tx in xs.clone() {
                            let t = ty as usize * tiles_x + tx as usize;
                            list[next[t] as usize] = (ci * chunk + j) as u32;
                            next[t] += 1;
                        }
                    }
                }
            }
            (start, list)
        })
        .collect();
    let mut start = vec![0u64; tiles + 1];
    for t in 0..tiles {
        start[t + 1] = start[t] + chunks.iter().map(|(s, _)| (s[t + 1] - s[t]) as u64).sum::<u64>();
    }
    let total = start[tiles];
    if total > u32::MAX as u64 {
        bail!("the splats cover {total} tiles of {SPLAT_TILE_W}×{SPLAT_TILE_H} pixels between them, more than the GPU buffer can index; draw them as spheres, smaller or from further away");
    }
    let mut splats = vec![0u32; total as usize];
    // Each tile row's part of the list, filled on its own thread.
    let mut rows = Vec::with_capacity(tiles_y);
    let mut rest = splats.as_mut_slice();
    for ty in 0..tiles_y {
        let len = (start[(ty + 1) * tiles_x] - start[ty * tiles_x]) as usize;
        let (row, tail) = rest.split_at_mut(len);
        rows.push((ty, row));
        rest = tail;
    }
    rows.into_par_iter().for_each(|(ty, row)| {
        let mut k = 0;
        for t in ty * tiles_x..(ty + 1) * tiles_x {
            for (s, list) in &chunks {
                let part = &list[s[t] as usize..s[t + 1] as usize];
                row[k..k + part.len()].copy_from_slice(part);
                k += part.len();
            }
        }
    });
    Ok(SplatBins { start: start.into_iter().map(|s| s as u32).collect(), splats })
}

/// A run of a write-only mapping, handed to one thread. wgpu's `WriteOnly` is `Send` only
/// for sized contents (its impl's implicit `Sized` bound); a run of bytes is exclusive
/// memory like any `&mut [u8]`, so sending it is sound.
struct WriteRun<'a>(wgpu::WriteOnly<'a, [[u8; 32]]>);
// SAFETY: see above: the run is the only handle to its bytes, which are plain memory.
unsafe impl Send for WriteRun<'_> {}

/// The tiles 0..n shuffled (w ↦ w·P mod n, P coprime to n near 0.618 n): any run of
/// consecutive workgroups draws tiles from all over the image.
fn tile_order(n: usize) -> Vec<u32> {
    let gcd = |mut a: usize, mut b: usize| {
        while b != 0 {
            (a, b) = (b, a % b);
        }
        a
    };
    let p = (((n as f64) * 0.618) as usize..).find(|&p| gcd(p, n) == 1).unwrap_or(1);
    (0..n).map(|w| ((w as u64 * p as u64) % n as u64) as u32).collect()
}

/// Splats `spheres` into `frame` by the compute pass (see `cs_splat` in shaders/points.wgsl)
/// and resolves each pixel; returns the seconds the GPU took. `basis`: the eye and the
/// camera's right, up and forward axes.
fn draw_splats(
    dev: &crate::gpu::Device,
    p: &Pipelines,
    spheres: &[Sphere],
    basis: (DVec3, DVec3, DVec3, DVec3),
    view: &ViewUniform,
    batch: usize,
    frame: &mut Frame,
) -> Result<f64> {
    use wgpu::util::DeviceExt;
    let (eye, right, up, forward) = basis;
    let (w, h) = (frame.width, frame.height);
    let (tiles_x, tiles_y) = (w.div_ceil(SPLAT_TILE_W), h.div_ceil(SPLAT_TILE_H));
    // Per particle: the centre in the camera's frame (from f64, so only one rounding) and
    // the radius, then the colour; and the pixels it may cover.
    let (data, boxes): (Vec<SplatRecord>, Vec<Option<[u32; 4]>>) = spheres
        .par_iter()
        .map(|sp| {
            let c = sp.centre - eye;
            let cam = [c.dot(right), c.dot(up), c.dot(forward)];
            let record = splat_record(cam, sp.radius, [sp.colour[0], sp.colour[1], sp.colour[2]]);
            (record, splat_pixels([cam[0], cam[1], cam[2], sp.radius].map(|v| v as f32), view))
        })
        .unzip();
    // Batches of consecutive particles with at most `batch` tile records each (however
    // large the splats, the records stay within 128 MB by default; a single splat's records
    // are never split); each batch's pass carries on the sums the one before left, so the
    // sums keep particle order.
    // Each pass's records in one storage binding (lavapipe's limit: 128 MiB, 4M records).
    let batch = batch.min((dev.device.limits().max_storage_buffer_binding_size / 32) as usize).max(1);
    let mut batches = vec![0usize];
    let (mut records, mut most_records) = (0u64, 0u64);
    for (i, b) in boxes.iter().enumerate() {
        let n = b.map_or(0, |b| {
            let (xs, ys) = splat_tiles(&b);
            xs.count() as u64 * ys.count() as u64
        });
        if records + n > batch as u64 && records > 0 {
            batches.push(i);
            records = 0;
        }
        records += n;
        most_records = most_records.max(records);
    }
    batches.push(boxes.len());
    let d = &dev.device;
    let limit = d.limits().max_storage_buffer_binding_size;
    if (w * h * 16) as u64 > limit {
        bail!(
            "the splats' sums for {w}×{h} pixels need a {} MB GPU buffer, more than the GPU '{}' binds ({} MB)",
            (w * h * 16) >> 20,
            dev.info.name,
            limit >> 20
        );
    }
    let (seconds, sums, weight_dist, kept) = dev.guarded("drawing the splats on the GPU", || {
        let buffer = |label: &str, bytes: &[u8], usage| {
            d.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some(label), contents: bytes, usage })
        };
        let storage = wgpu::BufferUsages::STORAGE;
        let order_buf = buffer("tile order", bytemuck::cast_slice(&tile_order(tiles_x * tiles_y)), storage);
        let output = |label, bytes: usize, usage| {
            d.create_buffer(&wgpu::BufferDescriptor { label: Some(label), size: bytes as u64, usage, mapped_at_creation: false })
        };
        // Where storage buffers map, the records are written and the sums read where the
        // pass reads and sums them, in buffers kept from frame to frame; otherwise through
        // a fresh mapped-at-creation buffer (a staging copy) and read-back copies.
        let in_place = dev.host_mapped_storage;
        let out_usage = storage | if in_place { wgpu::BufferUsages::MAP_READ } else { wgpu::BufferUsages::COPY_SRC };
        let read_usage = wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST;
        let before = if in_place { p.kept.lock().unwrap().take() } else { None };
        let (sums, weight_dist) = match before.as_ref().filter(|k| k.pixels == w * h) {
            Some(k) => (k.sums.clone(), k.weight_dist.clone()),
            None => (output("splat sums", w * h * 16, out_usage), output("splat weights", w * h * 8, out_usage)),
        };
        let kept = in_place.then(|| {
            let (records, capacity) = match before.as_ref().filter(|k| k.capacity as u64 >= most_records) {
                Some(k) => (k.records.clone(), k.capacity),
                // Room for an eighth more (a moving view's records vary), within the binding.
                None => {
                    let capacity = (most_records + most_records / 8).clamp(1, batch as u64) as usize;
                    (output("tiles' splats", capacity * 32, storage | wgpu::BufferUsages::MAP_WRITE), capacity)
                }
            };
            KeptSplatBuffers { records, capacity, sums: sums.clone(), weight_dist: weight_dist.clone(), pixels: w * h }
        });
        let (sums_read, weight_dist_read) = if in_place {
            (sums.clone(), weight_dist.clone())
        } else {
            (output("splat sums read-back", w * h * 16, read_usage), output("splat weights read-back", w * h * 8, read_usage))
        };
        let mut seconds = 0.0;
        for (k, run) in batches.windows(2).enumerate() {
            let bins = bin_splats(&boxes[run[0]..run[1]], tiles_x, tiles_y)?;
            let data = &data[run[0]..run[1]];
            let uniform = buffer(
                "splats view",
                bytemuck::bytes_of(&ViewUniform { first_batch: (k == 0) as u32, ..*view }),
                wgpu::BufferUsages::UNIFORM,
            );
            // Each tile's splats one after another, as the shader reads them (read through
            // the tiles' lists of indices, the draw took a sixth longer): written straight
            // into the buffer's mapping, in runs on rayon's threads (through a Vec and a
            // copy, 95 ms a frame for 1M particles instead of 60).
            let data_buf = match &kept {
                Some(k) => {
                    dev.map(&[&k.records], wgpu::MapMode::Write)?;
                    k.records.clone()
                }
                None => d.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("tiles' splats"),
                    size: (bins.splats.len().max(1) * 32) as u64,
                    usage: storage,
                    mapped_at_creation: true,
                }),
            };
            {
                let mut mapped = data_buf.slice(..).get_mapped_range_mut().map_err(|e| anyhow!("GPU upload failed: {e:?}"))?;
                let (mut rest, _) = mapped.slice(..bins.splats.len() * 32).into_chunks::<32>();
                let per = bins.splats.len().div_ceil(4 * rayon::current_num_threads()).max(1);
                let mut runs = Vec::new();
                for indices in bins.splats.chunks(per) {
                    let (run, tail) = rest.split_at(indices.len());
                    runs.push((WriteRun(run), indices));
                    rest = tail;
                }
                runs.into_par_iter().for_each(|(run, indices)| {
                    run.0.write_iter(indices.iter().map(|&i| bytemuck::cast::<SplatRecord, [u8; 32]>(data[i as usize])))
                });
            }
            data_buf.unmap();
            let start_buf = buffer("tile starts", bytemuck::cast_slice(&bins.start), storage);
            let bind = d.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("splats"),
                layout: &p.splat_layout,
                entries: &[
                    wgpu::BindGroupEntry { binding: 0, resource: uniform.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 3, resource: data_buf.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 4, resource: start_buf.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 6, resource: sums.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 7, resource: weight_dist.as_entire_binding() },
                    wgpu::BindGroupEntry { binding: 8, resource: order_buf.as_entire_binding() },
                ],
            });
            let mut enc = d.create_command_encoder(&Default::default());
            {
                let mut pass = enc.begin_compute_pass(&Default::default());
                pass.set_pipeline(&p.splats);
                pass.set_bind_group(0, &bind, &[]);
                pass.dispatch_workgroups(tiles_x as u32, tiles_y as u32, 1);
            }
            if k + 2 == batches.len() && !in_place {
                enc.copy_buffer_to_buffer(&sums, 0, &sums_read, 0, None);
                enc.copy_buffer_to_buffer(&weight_dist, 0, &weight_dist_read, 0, None);
            }
            let t = Instant::now();
            dev.queue.submit([enc.finish()]);
            d.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| anyhow!("drawing the splats on the GPU failed: {e}"))?;
            seconds += t.elapsed().as_secs_f64();
        }
        Ok((seconds, sums_read, weight_dist_read, kept))
    })?;
    dev.map_for_reading(&[&sums, &weight_dist])?;
    let mapped = |b: &wgpu::Buffer| b.slice(..).get_mapped_range().map_err(|e| anyhow!("GPU read-back failed: {e:?}"));
    {
        let (sums, weight_dist) = (mapped(&sums)?, mapped(&weight_dist)?);
        let (sums, weight_dist): (&[[f32; 4]], &[[f32; 2]]) = (bytemuck::cast_slice(&sums), bytemuck::cast_slice(&weight_dist));
        frame.rgba.par_iter_mut().zip(frame.depth.par_iter_mut()).enumerate().for_each(|(i, (rgba, depth))| {
            let [r, g, b, clear] = sums[i];
            let [weight, dist] = weight_dist[i];
            let acc = SplatSums { colour: [r, g, b].map(f64::from), clear: clear as f64, weight: weight as f64, dist: dist as f64 };
            (*rgba, *depth) = acc.resolve();
        });
    }
    if let Some(k) = kept {
        k.sums.unmap();
        k.weight_dist.unmap();
        *p.kept.lock().unwrap() = Some(k);
    }
    Ok(seconds)
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

/// Draws every sphere once through `pipeline` into `targets` (with a depth buffer) and reads
/// each target back as f32 values (all are 32-bit float formats); also the seconds the draw
/// took on the GPU side (submit to done).
fn draw(dev: &crate::gpu::Device, pipeline: &wgpu::RenderPipeline, targets: &[Target], b: &Buffers) -> Result<(Vec<Vec<f32>>, f64)> {
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
    let depth_tex = texture(wgpu::TextureFormat::Depth32Float);
    let depth_view = depth_tex.create_view(&Default::default());
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
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &depth_view,
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
