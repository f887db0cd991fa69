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
use super::settings::Bounds;
use crate::render::{Frame, FrameStats};
use crate::scene::camera::RayGenerator;
use crate::scene::NodeKind;
use anyhow::{anyhow, bail, Result};
use glam::{DMat3, DMat4, DVec3};
use std::sync::OnceLock;
use std::time::Instant;
use volterra_formats::ParticleSet;

crate::declare_settings! {
    pub struct Settings {
        /// Sphere radius in the particles' length unit; 0: each particle's smoothing length h.
        pub radius: f64 = 0.0, range = Bounds::above(0.0), zero = "auto: each particle's h";
        /// The colour map for the node's `color_by` array.
        pub colormap: Colormap = Colormap::Viridis;
    }
}

pub const RENDERER: RendererDecl = RendererDecl {
    name: "points",
    kind: NodeKind::Particles,
    doc: "Every particle as a sphere on the GPU (wgpu), coloured by a point array (the node's \
          `color_by`, default density) through a colour map over `color_range` (default: the \
          data's range), shaded by a headlight; exact ray-sphere depth, composited with the \
          other nodes.",
    reference: false,
    settings: Settings::DECLS,
    parse: |t| Settings::from_table(t).map(NodeSettings::Points),
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
        let r = input.range.unwrap_or_else(|| {
            let (lo, hi) = v.iter().filter(|x| x.is_finite()).fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
            if lo <= hi {
                [lo, hi]
            } else {
                [0.0, 1.0]
            }
        });
        (name.clone(), r)
    });
    let mut out = Vec::with_capacity(p.len());
    for i in 0..p.len() {
        let radius = if s.radius > 0.0 { s.radius } else { h.unwrap()[i] as f64 } * scale;
        if !(radius.is_finite() && radius > 0.0) {
            bail!("particle {i} has radius {radius} (h must be positive and finite)");
        }
        let colour = match (&values, &range) {
            (Some((_, v)), Some((_, [lo, hi]))) => s.colormap.at(if hi > lo { (v[i] - lo) / (hi - lo) } else { 0.5 }),
            _ => [0.8; 3],
        };
        out.push(Sphere { centre: m.transform_point3(DVec3::from(p.positions[i])), radius, colour });
    }
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

struct Pipeline {
    layout: wgpu::BindGroupLayout,
    pipeline: wgpu::RenderPipeline,
}

static PIPELINE: OnceLock<Pipeline> = OnceLock::new();

fn pipeline(dev: &wgpu::Device) -> &'static Pipeline {
    PIPELINE.get_or_init(|| {
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
        // The fragment's depth is never nearer than the quad's (the sphere's nearest
        // point): with the adapter's early depth test, hidden fragments are never shaded.
        let source = include_str!("../../../shaders/points.wgsl");
        let source = if dev.features().contains(wgpu::Features::SHADER_EARLY_DEPTH_TEST) {
            source.replace("@fragment\nfn fs", "@fragment @early_depth_test(greater_equal)\nfn fs")
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
        let target = |format| Some(wgpu::ColorTargetState { format, blend: None, write_mask: wgpu::ColorWrites::ALL });
        let pipeline = dev.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("points"),
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
                targets: &[target(wgpu::TextureFormat::Rgba32Float), target(wgpu::TextureFormat::R32Float)],
            }),
            multiview_mask: None,
            cache: None,
        });
        Pipeline { layout, pipeline }
    })
}

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
    pad: f32,
}

pub fn render(input: &PointsInput, rays: &RayGenerator, s: &Settings) -> Result<Frame> {
    let start = Instant::now();
    let (spheres, range) = spheres(input, s)?;
    let dev = crate::render::gpu::device()?;
    let (w, h) = rays.size();
    let (eye, right, up) = rays.basis();
    let forward = rays.forward();
    let (half_w, half_h) = rays.half_extent();
    // Near and far from the spheres' extent along the view (a little room either side).
    let (mut near, mut far) = (f64::INFINITY, 0.0f64);
    for sp in &spheres {
        let z = (sp.centre - eye).dot(forward);
        near = near.min(z - sp.radius);
        far = far.max(z + sp.radius);
    }
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
        pad: 0.0,
    };
    let centres: Vec<[f32; 4]> = spheres
        .iter()
        .map(|sp| {
            let c = sp.centre - eye;
            [c.x as f32, c.y as f32, c.z as f32, sp.radius as f32]
        })
        .collect();
    let colours: Vec<[f32; 4]> = spheres.iter().map(|sp| [sp.colour[0], sp.colour[1], sp.colour[2], 1.0]).collect();
    let (colour, dist, seconds) = dev.guarded("drawing the particles on the GPU", || draw(dev, &view, &centres, &colours, w, h))?;
    let mut frame = Frame::empty(w, h);
    for i in 0..w * h {
        if colour[i][3] > 0.0 {
            frame.rgba[i] = colour[i];
            frame.depth[i] = dist[i];
        }
    }
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

/// Draws the spheres into a colour and a distance target and reads both back; also the
/// seconds the draw took on the GPU side (submit to done).
fn draw(
    dev: &crate::render::gpu::Device,
    view: &ViewUniform,
    centres: &[[f32; 4]],
    colours: &[[f32; 4]],
    w: usize,
    h: usize,
) -> Result<(Vec<[f32; 4]>, Vec<f32>, f64)> {
    use wgpu::util::DeviceExt;
    let d = &dev.device;
    let p = pipeline(d);
    let buffer = |label: &str, bytes: &[u8], usage| {
        d.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some(label), contents: bytes, usage })
    };
    let uniform = buffer("points view", bytemuck::bytes_of(view), wgpu::BufferUsages::UNIFORM);
    let spheres = buffer("spheres", bytemuck::cast_slice(centres), wgpu::BufferUsages::STORAGE);
    let colour_buf = buffer("colours", bytemuck::cast_slice(colours), wgpu::BufferUsages::STORAGE);
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
    let texture = |label: &str, format| {
        d.create_texture(&wgpu::TextureDescriptor {
            label: Some(label),
            size,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
            view_formats: &[],
        })
    };
    let colour_tex = texture("points colour", wgpu::TextureFormat::Rgba32Float);
    let dist_tex = texture("points distance", wgpu::TextureFormat::R32Float);
    let depth_tex = texture("points depth", wgpu::TextureFormat::Depth32Float);
    let (cv, dv, zv) = (
        colour_tex.create_view(&Default::default()),
        dist_tex.create_view(&Default::default()),
        depth_tex.create_view(&Default::default()),
    );
    let attachment = |view| {
        Some(wgpu::RenderPassColorAttachment {
            view,
            depth_slice: None,
            resolve_target: None,
            ops: wgpu::Operations { load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT), store: wgpu::StoreOp::Store },
        })
    };
    let mut enc = d.create_command_encoder(&Default::default());
    {
        let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("points"),
            color_attachments: &[attachment(&cv), attachment(&dv)],
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &zv,
                depth_ops: Some(wgpu::Operations { load: wgpu::LoadOp::Clear(1.0), store: wgpu::StoreOp::Discard }),
                stencil_ops: None,
            }),
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        pass.set_pipeline(&p.pipeline);
        pass.set_bind_group(0, &bind, &[]);
        pass.draw(0..6, 0..centres.len() as u32);
    }
    // Rows padded to 256 bytes for the copies.
    let padded = |bytes_per_pixel: usize| (w * bytes_per_pixel).div_ceil(256) * 256;
    let readback = |tex: &wgpu::Texture, bpp: usize, enc: &mut wgpu::CommandEncoder| {
        let buf = d.create_buffer(&wgpu::BufferDescriptor {
            label: Some("points read-back"),
            size: (padded(bpp) * h) as u64,
            usage: wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
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
    };
    let colour_rows = readback(&colour_tex, 16, &mut enc);
    let dist_rows = readback(&dist_tex, 4, &mut enc);
    let t = Instant::now();
    dev.queue.submit([enc.finish()]);
    d.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| anyhow!("drawing the particles on the GPU failed: {e}"))?;
    let seconds = t.elapsed().as_secs_f64();
    let unpad = |bytes: Vec<u8>, bpp: usize| -> Vec<u8> { bytes.chunks(padded(bpp)).flat_map(|row| row[..w * bpp].to_vec()).collect() };
    let colour: Vec<[f32; 4]> = bytemuck::pod_collect_to_vec(&unpad(dev.read_buffer::<u8>(&colour_rows)?, 16));
    let dist: Vec<f32> = bytemuck::pod_collect_to_vec(&unpad(dev.read_buffer::<u8>(&dist_rows)?, 4));
    Ok((colour, dist, seconds))
}
