//! Volume ray casting on the GPU (wgpu compute, `shaders/volume_raycast.wgsl`), with the
//! classification of shear-warp and the reference: the rays are the reference's (cut to
//! the exact interval inside the box of voxel centres and the crop region, sampled at a
//! step stated in voxels, the eye inside the volume allowed), each step one segment
//! classified by the pre-integrated table (`render::preint`) at its two trilinear end
//! values, its opacity scaled to its length, shaded with the gradient at its middle by the
//! rule of `volume_shading` (gradient opacity as shear-warp applies it); MIP takes the
//! highest value at the segments' middles, as the reference. Blocks of 8³ voxels whose
//! every segment the table makes transparent are leapt over (a test rebuilt when the
//! transfer function or the step changes, not per frame); rays stop at `termination`.
//!
//! The volume stays a texture of its stored type (16-bit where the data is), or on a CPU
//! adapter a storage buffer of its stored values (`Voxels`), cut into bricks where it
//! passes the adapter's largest 3-D texture or storage binding (`prepare`); bricks are
//! drawn one after another, nearest the eye first, each continuing every pixel's running
//! colour, opacity and depth.

pub mod gpu;
pub mod prepare;

use super::frame::{Frame, FrameStats};
use super::preint::{level_count, PreintTable};
pub use crate::catalog::gpu_volume::{Settings, Voxels, RENDERER};
use crate::scene::{BlendMode, HalfSpace, Light, RayGenerator, TransferFunction, VolumeShading};
use anyhow::{anyhow, bail, Result};
use glam::{DMat4, DVec3};
use gpu::Gpu;
pub use prepare::Prepared;
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// Lights the shader takes.
pub const MAX_LIGHTS: usize = 8;
/// Crop and clipping half-spaces the shader takes.
pub const MAX_HALF_SPACES: usize = 16;

/// What to draw.
pub struct Input<'a> {
    pub prepared: &'a Prepared,
    pub node_to_world: DMat4,
    pub tf: &'a TransferFunction,
    pub blend: BlendMode,
    /// Gradient shading (None or `shade = false`: none; MIP is never shaded).
    pub shading: Option<&'a VolumeShading>,
    /// The scene's lights for shading (none: a headlight).
    pub lights: &'a [Light],
    /// The region drawn (`Scene::crop_region`: half-spaces in node coordinates).
    pub crop: &'a [HalfSpace],
}

/// One volume's part of the uniform block (`Vol` in volume_raycast.wgsl), field for field.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Vol {
    eye: [f32; 4],
    fwd: [f32; 4],
    right: [f32; 4],
    up: [f32; 4],
    box_lo: [f32; 4],
    box_hi: [f32; 4],
    dims: [u32; 4],
    blocks: [u32; 4],
    march: [f32; 4],
    values: [f32; 4],
    shading: [f32; 4],
    gradient: [f32; 4],
    g_x: [f32; 4],
    g_y: [f32; 4],
    g_z: [f32; 4],
    crop: [[f32; 4]; MAX_HALF_SPACES],
}

/// The uniform block of volume_raycast.wgsl (`Params` there), field for field.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    eye: [f32; 4],
    fwd: [f32; 4],
    right: [f32; 4],
    up: [f32; 4],
    owned_lo: [f32; 4],
    owned_hi: [f32; 4],
    origin: [i32; 4],
    extent: [u32; 4],
    counts: [u32; 4],
    control: [f32; 4],
    light: [[f32; 4]; MAX_LIGHTS],
    light_color: [[f32; 4]; MAX_LIGHTS],
    vol: [Vol; 2],
}

// Params.counts[3]
const COMPOSITE: u32 = 1;
const FIRST: u32 = 2;
// Vol.blocks[3]
const SHADE: u32 = 1;
const GRADIENT_OPACITY: u32 = 2;
const SKIP: u32 = 4;
const POINT_LIGHTS: u32 = 8;

fn v4(v: DVec3, w: f64) -> [f32; 4] {
    [v.x as f32, v.y as f32, v.z as f32, w as f32]
}

/// The transfer function made ready for the GPU: the pre-integrated table for segments of
/// one step, and which blocks it leaves transparent. Kept beside the volume while the
/// transfer function and the step stay.
pub struct Classified {
    key: u64,
    levels: usize,
    clear_below: f32,
    table: wgpu::TextureView,
    clear_blocks: wgpu::Buffer,
    /// Blocks the table makes transparent (of all).
    pub clear_fraction: f64,
    pub seconds: f64,
}

/// A hash of what the classification depends on.
fn classification_key(tf: &TransferFunction, dt: f64, lo: f64, hi: f64) -> u64 {
    use std::hash::{Hash, Hasher};
    let mut h = std::collections::hash_map::DefaultHasher::new();
    for p in tf.scalar_opacity.iter().flatten().chain(tf.color.iter().flatten()) {
        p.to_bits().hash(&mut h);
    }
    (tf.scalar_opacity.len(), tf.color.len()).hash(&mut h);
    [tf.scalar_opacity_unit_distance, dt, lo, hi].map(f64::to_bits).hash(&mut h);
    h.finish()
}

/// The classification of `prepared` under `tf` for segments of `dt`, from `cache` where
/// it was made for the same transfer function and step.
fn classify(
    gpu: &Gpu,
    prepared: &Prepared,
    tf: &TransferFunction,
    dt: f64,
    cache: &Mutex<Option<Arc<Classified>>>,
) -> Result<Arc<Classified>> {
    let key = classification_key(tf, dt, prepared.lo, prepared.hi);
    if let Some(c) = cache.lock().unwrap().as_ref().filter(|c| c.key == key) {
        return Ok(c.clone());
    }
    let start = Instant::now();
    let levels = level_count(tf, prepared.lo, prepared.hi);
    let table = PreintTable::new(tf, prepared.lo, prepared.hi, levels, dt);
    let mut texels = Vec::with_capacity(levels * levels);
    for f in 0..levels {
        for b in 0..levels {
            let e = table.entry(f, b);
            texels.push([e.c[0], e.c[1], e.c[2], e.a]);
        }
    }
    let texture = gpu.device.create_texture(&wgpu::TextureDescriptor {
        label: Some("pre-integrated table"),
        size: wgpu::Extent3d { width: levels as u32, height: levels as u32, depth_or_array_layers: 1 },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: wgpu::TextureFormat::Rgba32Float,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    });
    gpu.queue.write_texture(
        wgpu::TexelCopyTextureInfo { texture: &texture, mip_level: 0, origin: wgpu::Origin3d::ZERO, aspect: wgpu::TextureAspect::All },
        bytemuck::cast_slice(&texels),
        wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(16 * levels as u32), rows_per_image: None },
        wgpu::Extent3d { width: levels as u32, height: levels as u32, depth_or_array_layers: 1 },
    );
    // A block is clear where every value its segments read lies in levels the table makes
    // transparent; a hundredth of a level of slack either side for the shader's f32 levels.
    let mut bits = vec![0u32; prepared.block_range.len().div_ceil(32)];
    let mut clear = 0usize;
    for (b, r) in prepared.block_range.iter().enumerate() {
        let (lo, hi) = (table.level(r[0] as f64) - 0.01, table.level(r[1] as f64) + 0.01);
        if r[0] <= r[1] && table.transparent(lo.max(0.0), hi) {
            bits[b / 32] |= 1 << (b % 32);
            clear += 1;
        }
    }
    let clear_blocks = gpu::storage_buffer(gpu, "clear blocks", bytemuck::cast_slice(&bits));
    let c = Arc::new(Classified {
        key,
        levels,
        clear_below: table.clear_below,
        table: texture.create_view(&Default::default()),
        clear_blocks,
        clear_fraction: clear as f64 / prepared.block_range.len().max(1) as f64,
        seconds: start.elapsed().as_secs_f64(),
    });
    *cache.lock().unwrap() = Some(c.clone());
    Ok(c)
}

/// The world step of `settings` for a volume placed by `index_to_world`, and how many
/// voxels along any axis a step may reach (at least 1).
pub fn step_and_reach(index_to_world: DMat4, settings: &Settings) -> (f64, usize) {
    let min_spacing = (0..3).map(|c| index_to_world.col(c).truncate().length()).fold(f64::INFINITY, f64::min);
    let dt = settings.step * min_spacing;
    // A world step of dt moves index coordinate a by at most |row a of the inverse| · dt.
    let inv = glam::DMat3::from_mat4(index_to_world).inverse();
    let reach = (0..3).map(|a| inv.row(a).length() * dt).fold(0.0, f64::max);
    (dt, (reach - 1e-9).ceil().max(1.0) as usize)
}

/// The order to draw bricks in, nearest the eye first: along any ray the brick indices move
/// away from the eye's brick on every axis (monotonically: the ray is straight in index
/// space), so the sum of those distances only grows. A parallel view's "eye brick" lies
/// beyond the volume on the side the rays come from.
fn brick_order(prepared: &Prepared, eye_index: DVec3, dir_index: DVec3, parallel: bool) -> Vec<usize> {
    let g = prepared.brick_grid;
    // The brick holding the eye along axis a (the outer bricks' boxes are open outward).
    let eye_cell = |a: usize| -> i64 {
        let e = eye_index[a] as f32;
        prepared
            .bricks
            .iter()
            .filter(|b| (0..3).all(|k| k == a || b.cell[k] == 0))
            .find(|b| e < b.owned_hi[a])
            .map_or(g[a] as i64 - 1, |b| b.cell[a] as i64)
    };
    let key = |b: &prepare::Brick| -> i64 {
        (0..3)
            .map(|a| {
                let c = b.cell[a] as i64;
                match (parallel, dir_index[a]) {
                    (true, d) if d > 0.0 => c,
                    (true, d) if d < 0.0 => g[a] as i64 - 1 - c,
                    (true, _) => 0,
                    (false, _) => (c - eye_cell(a)).abs(),
                }
            })
            .sum()
    };
    let mut order: Vec<usize> = (0..prepared.bricks.len()).collect();
    order.sort_by_key(|&i| key(&prepared.bricks[i]));
    order
}

/// One volume made ready for the shader: its part of the uniform block, its
/// classification (None for MIP), its gradient opacity points, its lights.
struct Placed {
    vol: Vol,
    classified: Option<Arc<Classified>>,
    points: wgpu::Buffer,
    /// The scene's lights as this volume shades with them (None: not shaded).
    lights: Option<Vec<(super::volume_shading::Source, [f64; 3])>>,
    dt: f64,
    world_to_index: DMat4,
}

/// `input` placed for `rays`: the camera in its index space, its box, crop region,
/// classification, shading and empty-space test.
fn place(gpu: &Gpu, input: &Input, rays: &RayGenerator, settings: &Settings) -> Result<Placed> {
    let prepared = input.prepared;
    let index_to_world = crate::geometry::index_to_world(input.node_to_world, prepared.index_to_node)?;
    let world_to_index = index_to_world.inverse();
    let (dt, reach) = step_and_reach(index_to_world, settings);
    if reach > prepared.reach {
        bail!("the volume was prepared for a reach of {} voxels per step, this step needs {reach}", prepared.reach);
    }
    let mip = input.blend == BlendMode::Mip;
    let classified = if mip { None } else { Some(classify(gpu, prepared, input.tf, dt, &prepared.classified)?) };
    let (eye, right, up) = rays.basis();
    let lin = |v: DVec3| world_to_index.transform_vector3(v);
    let mut p = <Vol as bytemuck::Zeroable>::zeroed();
    p.eye = v4(world_to_index.transform_point3(eye), 0.0);
    p.fwd = v4(lin(rays.forward()), 0.0);
    p.right = v4(lin(right), 0.0);
    p.up = v4(lin(up), 0.0);
    let dims = prepared.dims;
    // A single-slice axis has zero thickness: half a voxel either side (as the reference).
    let pad = |a: usize| if dims[a] == 1 { 0.5 } else { 0.0 };
    p.box_lo = [-pad(0) as f32, -pad(1) as f32, -pad(2) as f32, 0.0];
    p.box_hi = [(dims[0] - 1) as f32 + pad(0) as f32, (dims[1] - 1) as f32 + pad(1) as f32, (dims[2] - 1) as f32 + pad(2) as f32, 0.0];
    p.dims = [dims[0] as u32, dims[1] as u32, dims[2] as u32, prepare::BLOCK as u32];
    let index_crop: Vec<HalfSpace> = input.crop.iter().map(|h| h.pulled_back(prepared.index_to_node)).collect();
    if index_crop.len() > MAX_HALF_SPACES {
        bail!("{} crop and clipping half-spaces: the GPU ray-caster takes at most {MAX_HALF_SPACES}", index_crop.len());
    }
    for (slot, h) in p.crop.iter_mut().zip(&index_crop) {
        *slot = v4(h.normal, h.offset);
    }
    let mut flags = if settings.skipping { SKIP } else { 0 };
    if !mip && !input.tf.gradient_opacity.is_empty() {
        flags |= GRADIENT_OPACITY;
    }
    let shader = if mip { None } else { super::volume_shading::Shader::new(input.shading, input.lights, index_to_world)? };
    let mut lights = None;
    if let Some(sh) = &shader {
        flags |= SHADE;
        let c = sh.coefficients();
        p.shading = [c.ambient as f32, c.diffuse as f32, c.specular as f32, c.specular_power as f32];
        if sh.lights().len() > MAX_LIGHTS {
            bail!("{} lights: the GPU ray-caster shades with at most {MAX_LIGHTS}", sh.lights().len());
        }
        if sh.lights().iter().any(|(s, _)| matches!(s, super::volume_shading::Source::Point(_))) {
            flags |= POINT_LIGHTS;
        }
        lights = Some(sh.lights().to_vec());
    }
    // Index-space gradients of stored values to world gradients of real values.
    let g = super::volume_shading::gradient_to_world(index_to_world) * prepared.slope;
    p.g_x = v4(g.row(0), 0.0);
    p.g_y = v4(g.row(1), 0.0);
    p.g_z = v4(g.row(2), 0.0);
    let b = prepared.blocks;
    p.blocks = [b[0] as u32, b[1] as u32, b[2] as u32, flags];
    let (levels, clear_below) = classified.as_ref().map_or((2, 0.0), |c| (c.levels, c.clear_below));
    let per_value = (levels - 1) as f64 / (prepared.hi - prepared.lo);
    p.march = [dt as f32, 0.0, per_value as f32, (-prepared.lo * per_value) as f32];
    p.values = [prepared.slope as f32, prepared.intercept as f32, levels as f32, clear_below];
    let points: Vec<[f32; 2]> = input.tf.gradient_opacity.iter().map(|q| [q[0] as f32, q[1] as f32]).collect();
    p.gradient = [(dt / input.tf.scalar_opacity_unit_distance) as f32, points.len() as f32, index_crop.len() as f32, 0.0];
    let points = gpu::storage_buffer(gpu, "gradient opacity", bytemuck::cast_slice(&points));
    Ok(Placed { vol: p, classified, points, lights, dt, world_to_index })
}

/// The uniform block's camera, lights and flags for `rays`, with the volumes `vol`.
fn params(rays: &RayGenerator, settings: &Settings, placed: &[&Placed], composite: bool) -> Params {
    let (eye, right, up) = rays.basis();
    let (half_w, half_h) = rays.half_extent();
    let (width, height) = rays.size();
    let mut p = <Params as bytemuck::Zeroable>::zeroed();
    p.eye = v4(eye, if rays.is_parallel() { 1.0 } else { 0.0 });
    p.fwd = v4(rays.forward(), half_w);
    p.right = v4(right, half_h);
    p.up = v4(up, 0.0);
    p.owned_lo = [-1e30, -1e30, -1e30, 0.0];
    p.owned_hi = [1e30, 1e30, 1e30, 0.0];
    // Every shaded volume shades with the same scene lights.
    let lights = placed.iter().find_map(|v| v.lights.as_ref());
    p.counts = [width as u32, height as u32, lights.map_or(0, |l| l.len()) as u32, if composite { COMPOSITE } else { 0 } | FIRST];
    p.control = [settings.termination as f32, 0.0, 0.0, 0.0];
    for (k, (source, colour)) in lights.into_iter().flatten().enumerate() {
        use super::volume_shading::Source;
        p.light[k] = match *source {
            Source::Head => [0.0; 4],
            Source::Directional(l) => v4(l, 1.0),
            Source::Point(q) => v4(q, 2.0),
        };
        p.light_color[k] = [colour[0] as f32, colour[1] as f32, colour[2] as f32, 0.0];
    }
    for (slot, v) in p.vol.iter_mut().zip(placed) {
        *slot = v.vol;
    }
    p
}

/// The per-pixel buffers the shader writes, checked against what the GPU binds.
struct Target {
    state: wgpu::Buffer,
    depth: wgpu::Buffer,
    samples: wgpu::Buffer,
}

impl Target {
    fn new(gpu: &Gpu, (width, height): (usize, usize)) -> Result<Target> {
        let pixels = (width * height) as u64;
        let limit = gpu.device.limits().max_storage_buffer_binding_size;
        if 16 * pixels > limit {
            bail!(
                "a {width}×{height} image needs {} MiB of colour buffer, more than the GPU binds ({} MiB)",
                (16 * pixels) >> 20,
                limit >> 20
            );
        }
        let usage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC;
        let buffer = |label: &str, size: u64| {
            gpu.device.create_buffer(&wgpu::BufferDescriptor { label: Some(label), size: size.max(16), usage, mapped_at_creation: false })
        };
        Ok(Target { state: buffer("state", 16 * pixels), depth: buffer("depth", 4 * pixels), samples: buffer("samples", 4 * pixels) })
    }
}

/// The bind group of one dispatch: the first volume's brick `brick` (and its blocks'
/// maxima), the second volume where fused, and the target.
fn bind_group(
    gpu: &Gpu,
    pipeline: &gpu::Pipeline,
    uniform: &wgpu::Buffer,
    (first, brick, block_max): (&Placed, &prepare::Held, &wgpu::Buffer),
    second: Option<(&Placed, &prepare::Held)>,
    target: &Target,
    unused: &(wgpu::TextureView, wgpu::Buffer),
) -> wgpu::BindGroup {
    fn table<'a>(p: &'a Placed, unused: &'a (wgpu::TextureView, wgpu::Buffer)) -> (&'a wgpu::TextureView, &'a wgpu::Buffer) {
        p.classified.as_ref().map_or((&unused.0, &unused.1), |c| (&c.table, &c.clear_blocks))
    }
    let (table0, clear0) = table(first, unused);
    let (other, other_brick) = second.unwrap_or((first, brick));
    let (table1, clear1) = table(other, unused);
    let view = wgpu::BindingResource::TextureView;
    gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("volume ray casting"),
        layout: &pipeline.layout,
        entries: &[
            wgpu::BindGroupEntry { binding: 0, resource: uniform.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 1, resource: brick.binding() },
            wgpu::BindGroupEntry { binding: 2, resource: view(table0) },
            wgpu::BindGroupEntry { binding: 3, resource: clear0.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 4, resource: block_max.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 5, resource: first.points.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 6, resource: target.state.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 7, resource: target.depth.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 8, resource: target.samples.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 9, resource: other_brick.binding() },
            wgpu::BindGroupEntry { binding: 10, resource: view(table1) },
            wgpu::BindGroupEntry { binding: 11, resource: clear1.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 12, resource: other.points.as_entire_binding() },
        ],
    })
}

/// Runs the dispatches (one pass each: each reads what the one before wrote) and reads the
/// target back: (colour or MIP state, depth, samples, GPU seconds).
fn dispatch(gpu: &Gpu, pipeline: &gpu::Pipeline, groups: &[wgpu::BindGroup], target: &Target, (w, h): (usize, usize)) -> Result<Readback> {
    let start = Instant::now();
    let mut enc = gpu.device.create_command_encoder(&Default::default());
    for bind in groups {
        let mut pass = enc.begin_compute_pass(&Default::default());
        pass.set_pipeline(&pipeline.pipeline);
        pass.set_bind_group(0, bind, &[]);
        pass.dispatch_workgroups((w as u32).div_ceil(8), (h as u32).div_ceil(8), 1);
    }
    gpu.queue.submit([enc.finish()]);
    gpu.device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| anyhow!("GPU volume ray casting failed: {e}"))?;
    let seconds = start.elapsed().as_secs_f64();
    Ok(Readback {
        state: gpu.read_buffer(&target.state)?,
        depth: gpu.read_buffer(&target.depth)?,
        samples: gpu.read_buffer(&target.samples)?,
        seconds,
    })
}

struct Readback {
    state: Vec<[f32; 4]>,
    depth: Vec<f32>,
    samples: Vec<u32>,
    seconds: f64,
}

/// Renders `input` seen by `rays`.
pub fn render(input: &Input, rays: &RayGenerator, settings: &Settings) -> Result<Frame> {
    settings.validate().map_err(|e| anyhow!("{}: {e}", RENDERER.name))?;
    let gpu = gpu::gpu()?;
    let prepared = input.prepared;
    let placed = place(gpu, input, rays, settings)?;
    let mip = input.blend == BlendMode::Mip;
    let size = rays.size();
    let base = params(rays, settings, &[&placed], !mip);
    let eye_index = placed.world_to_index.transform_point3(rays.basis().0);
    let order = brick_order(prepared, eye_index, placed.world_to_index.transform_vector3(rays.forward()), rays.is_parallel());
    let unused = placeholder_table(gpu);
    let back = gpu.guarded("ray casting the volume on the GPU", || {
        let target = Target::new(gpu, size)?;
        let pipeline = gpu.pipeline((prepared.store, prepared.kind), None);
        let mut uniforms = Vec::new();
        let mut groups = Vec::new();
        for (i, &bi) in order.iter().enumerate() {
            let brick = &prepared.bricks[bi];
            let mut q = base;
            q.owned_lo = [brick.owned_lo[0], brick.owned_lo[1], brick.owned_lo[2], 0.0];
            q.owned_hi = [brick.owned_hi[0], brick.owned_hi[1], brick.owned_hi[2], 0.0];
            q.origin = [brick.origin[0], brick.origin[1], brick.origin[2], 0];
            q.extent = [brick.size[0] as u32, brick.size[1] as u32, brick.size[2] as u32, 0];
            if i > 0 {
                q.counts[3] &= !FIRST;
            }
            uniforms.push(gpu::uniform_buffer(gpu, bytemuck::bytes_of(&q)));
            let uniform = uniforms.last().unwrap();
            groups.push(bind_group(gpu, &pipeline, uniform, (&placed, &brick.held, &prepared.block_max), None, &target, &unused));
        }
        dispatch(gpu, &pipeline, &groups, &target, size)
    })?;
    let mut frame = frame_of(&back, size, mip.then_some(input.tf));
    frame.stats.counters.extend([
        ("step_mm".into(), placed.dt),
        ("bricks".into(), prepared.bricks.len() as f64),
        ("upload ms".into(), prepared.seconds * 1e3),
    ]);
    frame.stats.notes.push(match prepared.store {
        gpu::Store::Texture => "voxels in 3-D textures".into(),
        gpu::Store::Buffer => "voxels in storage buffers".into(),
    });
    if let Some(c) = &placed.classified {
        frame.stats.counters.push(("clear blocks".into(), c.clear_fraction));
        frame.stats.counters.push(("classification ms".into(), c.seconds * 1e3));
    }
    Ok(frame)
}

/// Whether two volumes can be fused in one pass: each in one brick, composite blending.
pub fn can_fuse(inputs: &[Input]) -> Result<(), String> {
    if inputs.len() != 2 {
        return Err(format!("{} volumes (the GPU fuses two)", inputs.len()));
    }
    if let Some(i) = inputs.iter().position(|i| i.prepared.bricks.len() > 1) {
        return Err(format!(
            "volume {} is cut into {} bricks (the GPU fuses volumes held in one texture each)",
            i + 1,
            inputs[i].prepared.bricks.len()
        ));
    }
    if inputs.iter().any(|i| i.blend == BlendMode::Mip) {
        return Err("MIP volumes are not fused with others".into());
    }
    Ok(())
}

/// Two overlapping volumes fused along every ray (see the shader's `fused`), each sampled on
/// its own grid with its own step, classification and shading (`can_fuse` says where).
pub fn render_fused(inputs: &[Input], rays: &RayGenerator, settings: &Settings) -> Result<Frame> {
    settings.validate().map_err(|e| anyhow!("{}: {e}", RENDERER.name))?;
    can_fuse(inputs).map_err(|e| anyhow!("cannot fuse on the GPU: {e}"))?;
    let gpu = gpu::gpu()?;
    let placed: Vec<Placed> = inputs.iter().map(|i| place(gpu, i, rays, settings)).collect::<Result<_>>()?;
    let size = rays.size();
    let q = params(rays, settings, &[&placed[0], &placed[1]], true);
    let unused = placeholder_table(gpu);
    let (p0, p1) = (inputs[0].prepared, inputs[1].prepared);
    let back = gpu.guarded("fusing volumes on the GPU", || {
        let target = Target::new(gpu, size)?;
        let pipeline = gpu.pipeline((p0.store, p0.kind), Some((p1.store, p1.kind)));
        let mut q = q;
        q.extent = [p0.dims[0] as u32, p0.dims[1] as u32, p0.dims[2] as u32, 0];
        let uniform = gpu::uniform_buffer(gpu, bytemuck::bytes_of(&q));
        let group = bind_group(
            gpu,
            &pipeline,
            &uniform,
            (&placed[0], &p0.bricks[0].held, &p0.block_max),
            Some((&placed[1], &p1.bricks[0].held)),
            &target,
            &unused,
        );
        dispatch(gpu, &pipeline, &[group], &target, size)
    })?;
    let mut frame = frame_of(&back, size, None);
    frame.stats.counters.push(("step_mm".into(), placed[0].dt.min(placed[1].dt)));
    frame.stats.notes.push("2 volumes fused along each ray, each on its own grid".into());
    Ok(frame)
}

/// The frame of what the shader left: colour and depth, or for MIP (`mip_tf`) the highest
/// value's colour and opacity, un-corrected for the step (the reference's).
fn frame_of(back: &Readback, (width, height): (usize, usize), mip_tf: Option<&TransferFunction>) -> Frame {
    let n = width * height;
    let mut frame = Frame::empty(width, height);
    match mip_tf {
        Some(tf) => {
            for i in 0..n {
                let [v, t, _, found] = back.state[i];
                if found == 1.0 {
                    let v = v as f64;
                    let alpha = tf.opacity(v).min(1.0);
                    let col = tf.color(v);
                    frame.rgba[i] = [(col[0] * alpha) as f32, (col[1] * alpha) as f32, (col[2] * alpha) as f32, alpha as f32];
                    if alpha > 0.0 {
                        frame.depth[i] = t;
                    }
                }
            }
        }
        None => {
            frame.rgba.copy_from_slice(&back.state[..n]);
            for i in 0..n {
                frame.depth[i] = if back.depth[i] >= 0.0 { back.depth[i] } else { f32::INFINITY };
            }
        }
    }
    let total: u64 = back.samples[..n].iter().map(|&s| s as u64).sum();
    let gpu = gpu::gpu().map(|g| format!("GPU: {} ({:?})", g.info.name, g.info.backend)).unwrap_or_default();
    frame.stats = FrameStats {
        renderer: RENDERER.name.into(),
        seconds: back.seconds,
        counters: vec![("samples".into(), total as f64)],
        notes: vec![gpu],
        nodes: vec![],
    };
    frame
}

/// A 2×2 table and an empty block mask, bound where nothing reads them (MIP).
fn placeholder_table(gpu: &Gpu) -> (wgpu::TextureView, wgpu::Buffer) {
    let texture = gpu.device.create_texture(&wgpu::TextureDescriptor {
        label: Some("unused table"),
        size: wgpu::Extent3d { width: 2, height: 2, depth_or_array_layers: 1 },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: wgpu::TextureFormat::Rgba32Float,
        usage: wgpu::TextureUsages::TEXTURE_BINDING,
        view_formats: &[],
    });
    (texture.create_view(&Default::default()), gpu::storage_buffer(gpu, "unused blocks", &[]))
}
