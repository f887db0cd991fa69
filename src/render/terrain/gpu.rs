//! The terrain ray-caster on the GPU (wgpu): the heightfield as an R32Float texture, the
//! max-quadtree above the lid map built from it by compute passes (the lid map itself is
//! read from the heights: `shaders/terrain_pyramid.wgsl`),
//! one compute invocation per pixel for the rays (`shaders/terrain_raycast.wgsl`).

use super::grid::{TerrainGrid, HOLE};
use super::shading::{Shading, MAX_LIGHTS, RAMP_ENTRIES};
use super::Traversal;
use crate::render::{Frame, FrameStats};
use crate::scene::camera::RayGenerator;
use crate::scene::drape::Drape;
use crate::shared_error::SharedError;
use anyhow::{anyhow, bail, Result};
use std::sync::OnceLock;
use std::time::Instant;

/// The shared device (`gpu`; its fields and methods through `Deref`) with the
/// terrain's pipelines.
pub struct Gpu {
    shared: &'static crate::gpu::Device,
    pipelines: Pipelines,
}

impl std::ops::Deref for Gpu {
    type Target = crate::gpu::Device;
    fn deref(&self) -> &Self::Target {
        self.shared
    }
}

struct Pipelines {
    lid_layout: wgpu::BindGroupLayout,
    reduce_layout: wgpu::BindGroupLayout,
    ray_layout: wgpu::BindGroupLayout,
    level1: wgpu::ComputePipeline,
    reduce: wgpu::ComputePipeline,
    ray: wgpu::ComputePipeline,
    ray_split: OnceLock<wgpu::ComputePipeline>,
    raycast: wgpu::ShaderModule,
}

static GPU: OnceLock<Result<Gpu, SharedError>> = OnceLock::new();

/// The shared GPU, or why there is none (asked once per process).
pub fn gpu() -> Result<&'static Gpu> {
    GPU.get_or_init(|| open().map_err(SharedError::new)).as_ref().map_err(|e| anyhow::Error::new(e.clone()))
}

fn open() -> Result<Gpu> {
    let shared = crate::gpu::device()?;
    Ok(Gpu { shared, pipelines: Pipelines::new(&shared.device) })
}

fn texture_entry(binding: u32, filterable: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Float { filterable },
            view_dimension: wgpu::TextureViewDimension::D2,
            multisampled: false,
        },
        count: None,
    }
}

/// A texture array of f32 (heights) or, `packed`, of u32 (the pyramids' half-float pairs).
fn texture_array_entry(binding: u32, packed: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Texture {
            sample_type: if packed { wgpu::TextureSampleType::Uint } else { wgpu::TextureSampleType::Float { filterable: false } },
            view_dimension: wgpu::TextureViewDimension::D2Array,
            multisampled: false,
        },
        count: None,
    }
}

/// A level of a pyramid being written (half-float pairs in u32 texels).
fn storage_texture_entry(binding: u32) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::StorageTexture {
            access: wgpu::StorageTextureAccess::WriteOnly,
            format: wgpu::TextureFormat::R32Uint,
            view_dimension: wgpu::TextureViewDimension::D2,
        },
        count: None,
    }
}

fn buffer_entry(binding: u32, ty: wgpu::BufferBindingType) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer { ty, has_dynamic_offset: false, min_binding_size: None },
        count: None,
    }
}

impl Pipelines {
    fn new(device: &wgpu::Device) -> Pipelines {
        let storage = wgpu::BufferBindingType::Storage { read_only: false };
        let layout = |label: &str, entries: &[wgpu::BindGroupLayoutEntry]| {
            device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor { label: Some(label), entries })
        };
        let lid_layout =
            layout("lid", &[texture_entry(0, false), storage_texture_entry(1), buffer_entry(2, wgpu::BufferBindingType::Uniform)]);
        let uint_texture = wgpu::BindGroupLayoutEntry {
            binding: 3,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Uint,
                view_dimension: wgpu::TextureViewDimension::D2,
                multisampled: false,
            },
            count: None,
        };
        let reduce_layout = layout("reduce", &[storage_texture_entry(1), buffer_entry(2, wgpu::BufferBindingType::Uniform), uint_texture]);
        let ray_layout = layout(
            "raycast",
            &[
                buffer_entry(0, wgpu::BufferBindingType::Uniform),
                texture_array_entry(1, false),
                texture_array_entry(2, true),
                texture_entry(3, true),
                wgpu::BindGroupLayoutEntry {
                    binding: 4,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
                buffer_entry(5, storage),
                buffer_entry(6, storage),
                buffer_entry(7, storage),
                buffer_entry(8, storage),
                texture_entry(9, false),
                // The heights' and the pyramids' further arrays (MAX_ARRAYS − 1 each).
                texture_array_entry(10, false),
                texture_array_entry(11, false),
                texture_array_entry(12, false),
                texture_array_entry(13, true),
                texture_array_entry(14, true),
                texture_array_entry(15, true),
            ],
        );
        let pyramid = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("terrain_pyramid.wgsl"),
            source: wgpu::ShaderSource::Wgsl(include_str!("../../../shaders/terrain_pyramid.wgsl").into()),
        });
        let raycast = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("terrain_raycast.wgsl"),
            source: wgpu::ShaderSource::Wgsl(include_str!("../../../shaders/terrain_raycast.wgsl").into()),
        });
        let pipeline = |layout: &wgpu::BindGroupLayout, module: &wgpu::ShaderModule, entry: &str| {
            compute_pipeline(device, layout, module, entry, false)
        };
        Pipelines {
            level1: pipeline(&lid_layout, &pyramid, "build_level1"),
            reduce: pipeline(&reduce_layout, &pyramid, "reduce"),
            ray: pipeline(&ray_layout, &raycast, "main"),
            ray_split: OnceLock::new(),
            raycast,
            lid_layout,
            reduce_layout,
            ray_layout,
        }
    }

    /// The ray-caster for tiles split over several texture arrays (made on first use: most
    /// heightfields fit one array, and a branch over the arrays on every height read
    /// would cost software rasterisers every path).
    fn ray_split(&self, device: &wgpu::Device) -> &wgpu::ComputePipeline {
        self.ray_split.get_or_init(|| compute_pipeline(device, &self.ray_layout, &self.raycast, "main", true))
    }
}

/// A compute pipeline of one bind group; `split`: the shader's SPLIT override (its tiles
/// over several texture arrays).
fn compute_pipeline(
    device: &wgpu::Device,
    layout: &wgpu::BindGroupLayout,
    module: &wgpu::ShaderModule,
    entry: &str,
    split: bool,
) -> wgpu::ComputePipeline {
    let pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some(entry),
        bind_group_layouts: &[Some(layout)],
        immediate_size: 0,
    });
    let constants: &[(&str, f64)] = if split { &[("SPLIT", 1.0)] } else { &[] };
    device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some(entry),
        layout: Some(&pl),
        module,
        entry_point: Some(entry),
        compilation_options: wgpu::PipelineCompilationOptions { constants, ..Default::default() },
        cache: None,
    })
}

/// The uniform block of terrain_raycast.wgsl, field for field (see `Params` there).
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    eye: [f32; 4],
    fwd: [f32; 4],
    right: [f32; 4],
    up: [f32; 4],
    normal_x: [f32; 4],
    normal_y: [f32; 4],
    normal_z: [f32; 4],
    extent: [f32; 4],
    size: [u32; 4],
    control: [u32; 4],
    misc: [u32; 4],
    eye_hi: [f32; 4],
    eye_lo: [f32; 4],
    drape: [f32; 4],
    tiles: [u32; 4],
    light_world: [[f32; 4]; MAX_LIGHTS],
    light_grid: [[f32; 4]; MAX_LIGHTS],
    light_color: [[f32; 4]; MAX_LIGHTS],
    ramp: [[f32; 4]; RAMP_ENTRIES],
}

fn v4(v: glam::DVec3, w: f64) -> [f32; 4] {
    [v.x as f32, v.y as f32, v.z as f32, w as f32]
}

/// One view of a terrain: camera rays, lights, traversal and its step cap.
#[derive(Clone, Copy)]
pub struct View<'a> {
    pub grid: &'a TerrainGrid,
    pub rays: &'a RayGenerator,
    pub shading: &'a Shading,
    pub traversal: Traversal,
    pub max_steps: u32,
}

/// How the grid is cut into GPU textures (layers of 2-D array textures). One tile when the
/// grid fits: its samples, and a pyramid of pw × ph (the patches rounded up to powers of
/// two). Otherwise square tiles of S = 2^k patches (S + 1 samples a side: neighbours share
/// their border row and column, so every patch lies in one tile), each with its own
/// pyramid of k + 1 levels, and above them a max-quadtree over the tiles (Dick, Krüger and
/// Westermann's arrangement for very large terrains): quadtree level k + m is level m of a
/// texture holding one texel per tile.
#[derive(Debug, Clone, Copy)]
pub struct Tiling {
    /// Patches per tile (east, north); 0 when not tiled.
    pub tile_patches: usize,
    /// Tiles east and north.
    pub tiles: [usize; 2],
    /// Samples per tile texture layer, and its pyramid's level-0 size (patches, padded;
    /// level 0 itself is not stored: see `pyramid_texture`).
    pub heights_size: [u32; 2],
    pub pyramid_size: [u32; 2],
    /// Levels of each tile's pyramid, and of the texture over the tiles (0 when not tiled).
    pub tile_levels: u32,
    pub top_levels: u32,
    /// Tiles per texture array: the heights and the pyramids are each split over up to
    /// `MAX_ARRAYS` arrays of this many layers, so that no texture is larger than the
    /// GPU allocates at once (lavapipe: 2 GiB, so a 40000² DEM's 25 tiles of 8192²
    /// patches, 6.7 GB of heights, take four arrays).
    pub layers_per_array: usize,
}

/// The most texture arrays the heights (and the pyramids) are split over: the ray-caster
/// binds this many of each (WebGPU guarantees 16 sampled textures per stage; with the
/// colour map and the texture over the tiles, 10 are bound).
pub const MAX_ARRAYS: usize = 4;

impl Tiling {
    /// Tiles of at most `limit` texels a side, at most `max_layers` a texture array, each
    /// texture at most `array_bytes`.
    fn new(grid: &TerrainGrid, limit: usize, max_layers: usize, array_bytes: u64) -> Result<Tiling> {
        let tiling = Tiling::tiles(grid, limit, max_layers)?;
        // A layer's bytes: its heights, or its pyramid with every mip, whichever is more.
        let (_, mips) = tiling.pyramid_texture();
        let (_, packed) = tiling.pyramid_packing();
        let layer_bytes = (4 * tiling.heights_size[0] as u64 * tiling.heights_size[1] as u64).max(mip_bytes(packed, mips));
        let per_array = ((array_bytes / layer_bytes) as usize).clamp(1, max_layers);
        let arrays = tiling.layers().div_ceil(per_array);
        if arrays > MAX_ARRAYS {
            bail!(
                "the heightfield's {}×{} samples need {} tiles of {} MiB, {arrays} textures of at most {} MiB (the most the GPU allocates at once), more than the {MAX_ARRAYS} the ray-caster binds",
                grid.nx,
                grid.ny,
                tiling.layers(),
                layer_bytes >> 20,
                array_bytes >> 20
            );
        }
        Ok(Tiling { layers_per_array: per_array, ..tiling })
    }

    fn tiles(grid: &TerrainGrid, limit: usize, max_layers: usize) -> Result<Tiling> {
        let [cx, cy] = grid.cells();
        let (pw, ph) = (cx.next_power_of_two(), cy.next_power_of_two());
        let log2 = |n: usize| n.trailing_zeros();
        if grid.nx <= limit && grid.ny <= limit && pw <= limit && ph <= limit {
            return Ok(Tiling {
                tile_patches: 0,
                tiles: [1, 1],
                heights_size: [grid.nx as u32, grid.ny as u32],
                pyramid_size: [pw as u32, ph as u32],
                tile_levels: log2(pw.max(ph)) + 1,
                top_levels: 0,
                layers_per_array: 1,
            });
        }
        if limit < 3 {
            bail!("textures of {limit} texels a side cannot hold a tile");
        }
        // The tile size: the largest power of two that fits, unless smaller tiles waste
        // much less on the partly filled last row and column of tiles (a 20000 × 3000 DEM
        // in tiles of 8192² would hold 2.7 times its samples): the largest size within 10 %
        // of the fewest texels, and no more tiles than the GPU has layers.
        let largest = 1usize << (usize::BITS - 1 - (limit - 1).leading_zeros());
        let texels = |s: usize| cx.div_ceil(s) * cy.div_ceil(s) * s * s;
        let sizes: Vec<usize> = (0..).map(|k| largest >> k).take_while(|&s| s >= 2 && s >= largest.min(256)).collect();
        let fewest = sizes.iter().filter(|&&s| cx.div_ceil(s) * cy.div_ceil(s) <= max_layers).map(|&s| texels(s)).min();
        let s = match fewest {
            Some(fewest) => *sizes
                .iter()
                .find(|&&s| cx.div_ceil(s) * cy.div_ceil(s) <= max_layers && texels(s) * 10 <= fewest * 11)
                .expect("one is the fewest"),
            None => largest,
        };
        let tiles = [cx.div_ceil(s), cy.div_ceil(s)];
        if tiles[0] * tiles[1] > MAX_ARRAYS * max_layers {
            bail!(
                "the heightfield's {}×{} samples need {} tiles of {s}² patches, more than {MAX_ARRAYS} × the GPU's {max_layers} texture layers",
                grid.nx,
                grid.ny,
                tiles[0] * tiles[1]
            );
        }
        let top = tiles[0].max(tiles[1]).next_power_of_two();
        Ok(Tiling {
            tile_patches: s,
            tiles,
            heights_size: [s as u32 + 1; 2],
            pyramid_size: [s as u32; 2],
            tile_levels: log2(s) + 1,
            top_levels: log2(top) + 1,
            layers_per_array: 1,
        })
    }

    pub fn tiled(&self) -> bool {
        self.tile_patches > 0
    }

    /// Size and mip levels of each tile's pyramid texture: quadtree levels 1 and up (mip m
    /// is level m + 1). Level 0, the lid map, is the highest of each patch's four heights,
    /// which the ray-caster reads anyway to intersect the patch; not storing it keeps the
    /// pyramid at a third of the heights' texels instead of four thirds. A grid of one
    /// patch has no level 1: a 1×1 texture stands in.
    fn pyramid_texture(&self) -> ([u32; 2], u32) {
        (self.pyramid_size.map(|s| (s / 2).max(1)), (self.tile_levels - 1).max(1))
    }

    /// Whether the pyramid's half-float pairs are neighbours east-west (else north-south),
    /// and the size of the texture holding them. Pairs lie along the shorter side (north-
    /// south when square): halving the longer one would leave the texture a mip short of
    /// the quadtree's levels.
    fn pyramid_packing(&self) -> (bool, [u32; 2]) {
        let ([w, h], _) = self.pyramid_texture();
        let east = w < h;
        (east, if east { [(w / 2).max(1), h] } else { [w, (h / 2).max(1)] })
    }

    fn layers(&self) -> usize {
        self.tiles[0] * self.tiles[1]
    }

    /// The texture arrays the tiles are split over.
    pub fn arrays(&self) -> usize {
        self.layers().div_ceil(self.layers_per_array)
    }

    /// Layers in array a.
    fn layers_in(&self, a: usize) -> usize {
        self.layers_per_array.min(self.layers() - a * self.layers_per_array)
    }

    /// The array and layer of tile `tile`.
    fn place(&self, tile: usize) -> (usize, u32) {
        (tile / self.layers_per_array, (tile % self.layers_per_array) as u32)
    }

    /// Levels of the whole quadtree: the tiles' below, the texture over them above.
    fn levels(&self) -> u32 {
        if self.tiled() {
            self.tile_levels + self.top_levels - 1
        } else {
            self.tile_levels
        }
    }

    /// The first sample (east, north) and the samples (east, north) of tile `layer`.
    fn samples_of(&self, layer: usize, grid: &TerrainGrid) -> ([usize; 2], [usize; 2]) {
        if !self.tiled() {
            return ([0, 0], [grid.nx, grid.ny]);
        }
        let s = self.tile_patches;
        let (i0, j0) = (layer % self.tiles[0] * s, layer / self.tiles[0] * s);
        ([i0, j0], [(s + 1).min(grid.nx - i0), (s + 1).min(grid.ny - j0)])
    }

    /// The shader's `tiles` parameter: patches per tile, tiles east, log2 of the patches per
    /// tile, tiles north. Not tiled: one tile of 2^31 (every sample and node in tile 0).
    fn params(&self) -> [u32; 4] {
        if !self.tiled() {
            return [0, 1, 31, 1];
        }
        [self.tile_patches as u32, self.tiles[0] as u32, self.tile_levels - 1, self.tiles[1] as u32]
    }
}

/// The highest lid of the patches between two neighbouring rows of samples (HOLE where
/// every patch touches NoData, stored as HOLE).
fn highest_lid(below: &[f32], above: &[f32]) -> f32 {
    // As the shaders: below -1e37 is NoData (uploaded as HOLE).
    let valid = |z: f32| z > -1.0e37;
    let mut highest = HOLE;
    for i in 0..below.len() - 1 {
        let z = [below[i], below[i + 1], above[i], above[i + 1]];
        if z.iter().all(|&v| valid(v)) {
            highest = highest.max(z[0].max(z[1]).max(z[2].max(z[3])));
        }
    }
    highest
}

/// The highest lid of the patches a band of rows (`w` samples each) closes: those between
/// its rows, and those between its first row and `below`, the last row of the band before
/// (empty for a tile's first band). `below` becomes this band's last row.
fn band_lid(below: &mut Vec<f32>, band: &[f32], w: usize) -> f32 {
    let rows = band.len() / w;
    let mut highest = if below.is_empty() { HOLE } else { highest_lid(below, &band[..w]) };
    for r in 1..rows {
        highest = highest.max(highest_lid(&band[(r - 1) * w..r * w], &band[r * w..(r + 1) * w]));
    }
    below.clear();
    below.extend_from_slice(&band[(rows - 1) * w..]);
    highest
}

/// The smallest half float ≥ v, as an f32: the value terrain_pyramid.wgsl's `half_up`
/// stores (−∞ for NoData, +∞ above the half floats, no subnormals). The texture over the
/// tiles holds f32 texels, but the same values as the tiles' pyramids would hold there,
/// so a tiled heightfield's quadtree is the one of the same heights in one texture.
fn half_up(v: f32) -> f32 {
    use half::f16;
    let smallest_normal = f16::MIN_POSITIVE.to_f32();
    if v <= -1.0e37 {
        return f32::NEG_INFINITY;
    }
    if v > 65504.0 {
        return f32::INFINITY;
    }
    if v < -65504.0 {
        return -65504.0;
    }
    if v.abs() < smallest_normal {
        return if v > 0.0 { smallest_normal } else { 0.0 };
    }
    let mut h = f16::from_f32(v).to_bits();
    if f16::from_bits(h).to_f32() < v {
        h = if h & 0x8000 != 0 { h - 1 } else { h + 1 };
    }
    f16::from_bits(h).to_f32()
}

/// The levels of the texture over the tiles (`levels` of them from `size`, powers of two):
/// level 0 each tile's highest lid rounded up to a half float (tiles east × north of them,
/// −∞ — the pyramids' HOLE — past them), each further texel the highest of the 2 × 2
/// below it (a side already 1 texel stays 1).
fn top_levels(tile_lids: &[f32], tiles: [usize; 2], size: [u32; 2], levels: u32) -> Vec<Vec<f32>> {
    let [w, h] = size.map(|s| s as usize);
    let mut level0 = vec![f32::NEG_INFINITY; w * h];
    for (t, &lid) in tile_lids.iter().enumerate() {
        level0[t / tiles[0] * w + t % tiles[0]] = half_up(lid);
    }
    let mut out = vec![level0];
    for l in 1..levels.max(1) as usize {
        let (sw, sh) = ((w >> (l - 1)).max(1), (h >> (l - 1)).max(1));
        let (dw, dh) = ((w >> l).max(1), (h >> l).max(1));
        let src = &out[l - 1];
        let at = |x: usize, y: usize| src[y.min(sh - 1) * sw + x.min(sw - 1)];
        let level = (0..dw * dh)
            .map(|k| {
                let (x, y) = (2 * (k % dw), 2 * (k / dw));
                at(x, y).max(at(x + 1, y)).max(at(x, y + 1)).max(at(x + 1, y + 1))
            })
            .collect();
        out.push(level);
    }
    out
}

/// Bytes of a texture of 4-byte texels of `size` with `levels` mips.
fn mip_bytes(size: [u32; 2], levels: u32) -> u64 {
    (0..levels).map(|l| 4 * ((size[0] >> l).max(1) as u64) * ((size[1] >> l).max(1) as u64)).sum()
}

/// A heightfield resident on the GPU with its pyramid, ready to render any camera.
pub struct GpuTerrain {
    /// The heights' and the pyramids' texture arrays (`Tiling::arrays` of each).
    heights_views: Vec<wgpu::TextureView>,
    pyramid_views: Vec<wgpu::TextureView>,
    top_view: wgpu::TextureView,
    tiling: Tiling,
    colour_view: wgpu::TextureView,
    sampler: wgpu::Sampler,
    has_texture: bool,
    /// [s0, s1, t0, t1]: where the drape lies over the grid.
    placement: [f32; 4],
    levels: u32,
    cells: [u32; 2],
    /// Seconds to build the quadtree on the GPU (upload excluded).
    pub build_seconds: f64,
    /// Bytes of GPU memory held: heights, pyramid, colour texture.
    pub gpu_bytes: u64,
}

/// Output buffers and the bind group for one image size.
struct Target {
    width: u32,
    height: u32,
    colour: wgpu::Buffer,
    depth: wgpu::Buffer,
    steps: wgpu::Buffer,
    counters: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
}

impl GpuTerrain {
    /// Uploads the heightfield (and texture) and builds the pyramid. GPU errors — out of
    /// memory above all — come back as errors, not the panic wgpu's default handler gives.
    /// `texture`: the drape and its placement (see `shading::LinearTexture::placement`).
    pub fn new(gpu: &Gpu, grid: &TerrainGrid, texture: Option<(&Drape, [f64; 4])>) -> Result<GpuTerrain> {
        let max_dim = gpu.device.limits().max_texture_dimension_2d as usize;
        GpuTerrain::with_texture_limit(gpu, grid, texture, max_dim)
    }

    /// As [`GpuTerrain::new`], with textures no larger than `limit` texels a side (at most
    /// the adapter's): a grid larger than that is tiled. Tests lower it to tile small grids.
    pub fn with_texture_limit(gpu: &Gpu, grid: &TerrainGrid, texture: Option<(&Drape, [f64; 4])>, limit: usize) -> Result<GpuTerrain> {
        GpuTerrain::with_limits(gpu, grid, texture, limit, u64::MAX)
    }

    /// As [`GpuTerrain::with_texture_limit`], with no texture larger than `array_bytes`
    /// (at most what the GPU allocates at once, its largest buffer): more tiles are split
    /// over several texture arrays. Tests lower it to split small grids.
    pub fn with_limits(
        gpu: &Gpu,
        grid: &TerrainGrid,
        texture: Option<(&Drape, [f64; 4])>,
        limit: usize,
        array_bytes: u64,
    ) -> Result<GpuTerrain> {
        gpu.guarded("uploading the terrain to the GPU", || GpuTerrain::build(gpu, grid, texture, limit, array_bytes))
    }

    fn build(gpu: &Gpu, grid: &TerrainGrid, texture: Option<(&Drape, [f64; 4])>, limit: usize, array_bytes: u64) -> Result<GpuTerrain> {
        let device = &gpu.device;
        let max_dim = device.limits().max_texture_dimension_2d as usize;
        let array_bytes = array_bytes.min(device.limits().max_buffer_size);
        let tiling = Tiling::new(grid, limit.min(max_dim), device.limits().max_texture_array_layers as usize, array_bytes)?;
        let [cx, cy] = grid.cells();
        let layers = tiling.layers();
        let levels = tiling.levels();
        let texture_2d_array =
            |label: &str, size: [u32; 2], mips: u32, format: wgpu::TextureFormat, usage: wgpu::TextureUsages, layers: usize| {
                device.create_texture(&wgpu::TextureDescriptor {
                    label: Some(label),
                    size: wgpu::Extent3d { width: size[0], height: size[1], depth_or_array_layers: layers as u32 },
                    mip_level_count: mips,
                    sample_count: 1,
                    dimension: wgpu::TextureDimension::D2,
                    format,
                    usage,
                    view_formats: &[],
                })
            };
        let heights: Vec<wgpu::Texture> = (0..tiling.arrays())
            .map(|a| {
                let usage = wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST;
                texture_2d_array("heights", tiling.heights_size, 1, wgpu::TextureFormat::R32Float, usage, tiling.layers_in(a))
            })
            .collect();
        // Each tile's samples uploaded in bands of rows of about 16 MiB, each submitted and
        // finished before the next: a copy of the whole grid (and wgpu's staging of it)
        // would add twice the heights to the peak memory. On the way, each tile's highest
        // lid: the texture over the tiles, built here (`top_levels`) rather than from the
        // tiles' pyramids, whose half-float pairs a texture copy cannot unpack.
        let mut tile_lids = vec![HOLE; layers];
        for tile in 0..layers {
            let ([i0, j0], [w, h]) = tiling.samples_of(tile, grid);
            let (array, layer) = tiling.place(tile);
            let band_rows = ((16usize << 20) / (4 * w)).clamp(1, h);
            let mut below = Vec::new();
            for r0 in (0..h).step_by(band_rows) {
                let rows = band_rows.min(h - r0);
                let mut band = vec![0f32; rows * w];
                for (r, row) in band.chunks_exact_mut(w).enumerate() {
                    grid.heights_of_row(i0, j0 + r0 + r, row);
                    row.iter_mut().filter(|z| !z.is_finite()).for_each(|z| *z = HOLE);
                }
                if tiling.tiled() {
                    tile_lids[tile] = tile_lids[tile].max(band_lid(&mut below, &band, w));
                }
                gpu.queue.write_texture(
                    wgpu::TexelCopyTextureInfo {
                        texture: &heights[array],
                        mip_level: 0,
                        origin: wgpu::Origin3d { x: 0, y: r0 as u32, z: layer },
                        aspect: wgpu::TextureAspect::All,
                    },
                    bytemuck::cast_slice(&band),
                    wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(4 * w as u32), rows_per_image: None },
                    wgpu::Extent3d { width: w as u32, height: rows as u32, depth_or_array_layers: 1 },
                );
                gpu.queue.submit(std::iter::empty());
                device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| anyhow!("uploading the heights: {e}"))?;
            }
        }
        // A source read from a file says here whether every row was read.
        if let Some(why) = grid.read_failure() {
            bail!("{why}");
        }
        let storage = wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::STORAGE_BINDING;
        let (pyramid_size, pyramid_mips) = tiling.pyramid_texture();
        let (pairs_east, packed_size) = tiling.pyramid_packing();
        let pyramid: Vec<wgpu::Texture> = (0..tiling.arrays())
            .map(|a| texture_2d_array("lid pyramid", packed_size, pyramid_mips, wgpu::TextureFormat::R32Uint, storage, tiling.layers_in(a)))
            .collect();
        // Above the tiles: one texel per tile (the tile's top level), then its own levels.
        let top_size = [tiling.tiles[0].next_power_of_two() as u32, tiling.tiles[1].next_power_of_two() as u32];
        let top = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("lid pyramid over tiles"),
            size: wgpu::Extent3d { width: top_size[0], height: top_size[1], depth_or_array_layers: 1 },
            mip_level_count: tiling.top_levels.max(1),
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::R32Float,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        if tiling.tiled() {
            for (level, texels) in top_levels(&tile_lids, tiling.tiles, top_size, tiling.top_levels).iter().enumerate() {
                let size = top_size.map(|s| (s >> level).max(1));
                gpu.queue.write_texture(
                    wgpu::TexelCopyTextureInfo {
                        texture: &top,
                        mip_level: level as u32,
                        origin: wgpu::Origin3d::ZERO,
                        aspect: wgpu::TextureAspect::All,
                    },
                    bytemuck::cast_slice(texels),
                    wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(4 * size[0]), rows_per_image: None },
                    wgpu::Extent3d { width: size[0], height: size[1], depth_or_array_layers: 1 },
                );
            }
        }
        let (colour, has_texture, placement) = match texture {
            Some((drape, placement)) => (colour_texture(gpu, drape, max_dim)?, true, placement),
            None => {
                let blank = Drape { width: 1, height: 1, rgba: vec![0; 4], georef: None, scale: None };
                (colour_texture(gpu, &blank, max_dim)?, false, [0.0; 4])
            }
        };
        // Uploads first, so that the build time below is the compute passes alone.
        gpu.queue.submit([]);
        device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| anyhow!("GPU upload failed: {e}"))?;

        let start = Instant::now();
        let layer_view = |t: &wgpu::Texture, layer: u32, level: u32| {
            t.create_view(&wgpu::TextureViewDescriptor {
                dimension: Some(wgpu::TextureViewDimension::D2),
                base_mip_level: level,
                mip_level_count: Some(1),
                base_array_layer: layer,
                array_layer_count: Some(1),
                ..Default::default()
            })
        };
        let mut enc = device.create_command_encoder(&Default::default());
        // The packed texels written by a pass over a level of `logical` texels.
        let packed =
            |logical: [u32; 2]| if pairs_east { [logical[0].div_ceil(2), logical[1]] } else { [logical[0], logical[1].div_ceil(2)] };
        let groups = |size: [u32; 2]| (size[0].div_ceil(8), size[1].div_ceil(8));
        let packing_buffer = |src: [u32; 2], dst: [u32; 2]| {
            uniform_buffer(gpu, bytemuck::cast_slice(&[src[0], src[1], dst[0], dst[1], pairs_east as u32, 0, 0, 0]))
        };
        let mut uniforms = Vec::new();
        for tile in 0..layers {
            let (_, [w, h]) = tiling.samples_of(tile, grid);
            let (array, layer) = tiling.place(tile);
            let (heights, pyramid) = (&heights[array], &pyramid[array]);
            if tiling.tile_levels > 1 {
                let uniform = packing_buffer([w as u32 - 1, h as u32 - 1], pyramid_size);
                let (src, dst) = (layer_view(heights, layer, 0), layer_view(pyramid, layer, 0));
                let bg = device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("lid"),
                    layout: &gpu.pipelines.lid_layout,
                    entries: &[
                        wgpu::BindGroupEntry { binding: 0, resource: wgpu::BindingResource::TextureView(&src) },
                        wgpu::BindGroupEntry { binding: 1, resource: wgpu::BindingResource::TextureView(&dst) },
                        wgpu::BindGroupEntry { binding: 2, resource: uniform.as_entire_binding() },
                    ],
                });
                uniforms.push(uniform);
                let mut pass = enc.begin_compute_pass(&Default::default());
                pass.set_pipeline(&gpu.pipelines.level1);
                pass.set_bind_group(0, &bg, &[]);
                let (gx, gy) = groups(packed(pyramid_size));
                pass.dispatch_workgroups(gx, gy, 1);
            }
            // Quadtree level L is the pyramid texture's mip L − 1.
            for level in 2..tiling.tile_levels {
                let logical = |l: u32| tiling.pyramid_size.map(|s| (s >> l).max(1));
                let uniform = packing_buffer(logical(level - 1), logical(level));
                let (src, dst) = (layer_view(pyramid, layer, level - 2), layer_view(pyramid, layer, level - 1));
                let bg = device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("reduce"),
                    layout: &gpu.pipelines.reduce_layout,
                    entries: &[
                        wgpu::BindGroupEntry { binding: 1, resource: wgpu::BindingResource::TextureView(&dst) },
                        wgpu::BindGroupEntry { binding: 2, resource: uniform.as_entire_binding() },
                        wgpu::BindGroupEntry { binding: 3, resource: wgpu::BindingResource::TextureView(&src) },
                    ],
                });
                uniforms.push(uniform);
                let mut pass = enc.begin_compute_pass(&Default::default());
                pass.set_pipeline(&gpu.pipelines.reduce);
                pass.set_bind_group(0, &bg, &[]);
                let (gx, gy) = groups(packed(logical(level)));
                pass.dispatch_workgroups(gx, gy, 1);
            }
        }
        gpu.queue.submit([enc.finish()]);
        device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| anyhow!("GPU pyramid build failed: {e}"))?;
        let build_seconds = start.elapsed().as_secs_f64();

        let gpu_bytes = 4 * (tiling.heights_size[0] as u64 * tiling.heights_size[1] as u64) * layers as u64
            + mip_bytes(packed_size, pyramid_mips) * layers as u64
            + mip_bytes(top_size, tiling.top_levels.max(1))
            + 4 * colour.width() as u64 * colour.height() as u64;
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("colour"),
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            ..Default::default()
        });
        let array_view = |t: &wgpu::Texture| {
            t.create_view(&wgpu::TextureViewDescriptor { dimension: Some(wgpu::TextureViewDimension::D2Array), ..Default::default() })
        };
        Ok(GpuTerrain {
            heights_views: heights.iter().map(array_view).collect(),
            pyramid_views: pyramid.iter().map(array_view).collect(),
            top_view: top.create_view(&Default::default()),
            tiling,
            colour_view: colour.create_view(&Default::default()),
            sampler,
            has_texture,
            placement: placement.map(|v| v as f32),
            levels,
            cells: [cx as u32, cy as u32],
            build_seconds,
            gpu_bytes,
        })
    }

    /// Whether the heightfield is cut into tiles (larger than one GPU texture).
    pub fn tiled(&self) -> bool {
        self.tiling.tiled()
    }

    /// The texture arrays its tiles are split over (1 unless they exceed what the GPU
    /// allocates at once).
    pub fn texture_arrays(&self) -> usize {
        self.tiling.arrays()
    }

    /// Quadtree levels, the lid map (level 0, read from the heights) included.
    pub fn levels(&self) -> u32 {
        self.levels
    }

    fn params(&self, view: &View) -> Params {
        let View { grid, rays, shading, traversal, max_steps } = *view;
        let (w, h) = rays.size();
        let (eye, right, up) = rays.basis();
        let (half_w, half_h) = rays.half_extent();
        let m = grid.world_to_grid;
        let n = grid.normal_to_world;
        let mut p = <Params as bytemuck::Zeroable>::zeroed();
        // The shader works relative to the eye, which it gets as an unevaluated sum of
        // two floats per axis (see eye_hi in terrain_raycast.wgsl).
        let eye_grid = m.transform_point3(eye);
        let hi = eye_grid.as_vec3().as_dvec3();
        p.eye_hi = v4(hi, 0.0);
        p.eye_lo = v4(eye_grid - hi, 0.0);
        p.eye = [0.0, 0.0, 0.0, if rays.is_parallel() { 1.0 } else { 0.0 }];
        p.fwd = v4(m.transform_vector3(rays.forward()), half_w);
        p.right = v4(m.transform_vector3(right), half_h);
        p.up = v4(m.transform_vector3(up), shading.ambient);
        p.normal_x = v4(n.row(0), 0.0);
        p.normal_y = v4(n.row(1), 0.0);
        p.normal_z = v4(n.row(2), 0.0);
        p.extent = [(grid.z_lo - eye_grid.z) as f32, (grid.z_hi - eye_grid.z) as f32, grid.cell[0] as f32, grid.cell[1] as f32];
        p.size = [w as u32, h as u32, self.cells[0], self.cells[1]];
        let flags = shading.shadows as u32
            | (self.has_texture as u32) << 1
            | (shading.smooth as u32) << 2
            | (self.tiling.pyramid_packing().0 as u32) << 3;
        p.control = [self.levels - 1, max_steps, traversal as u32, flags];
        p.drape = self.placement;
        p.tiles = self.tiling.params();
        for (entry, c) in p.ramp.iter_mut().zip(super::shading::elevation_ramp(shading.colormap, grid.elevations(), shading.colour_range)) {
            *entry = [c[0], c[1], c[2], 0.0];
        }
        p.misc = [
            shading.lights.len() as u32,
            (super::reference::shadow_lift(grid) as f32).to_bits(),
            shading.rays_per_side.max(1),
            self.tiling.layers_per_array as u32,
        ];
        for (k, l) in shading.lights.iter().enumerate() {
            p.light_world[k] = v4(l.to_light, 0.0);
            p.light_grid[k] = v4(m.transform_vector3(l.to_light), 0.0);
            p.light_color[k] = [l.radiance[0] as f32, l.radiance[1] as f32, l.radiance[2] as f32, 0.0];
        }
        p
    }

    fn target<'a>(&'a self, gpu: &Gpu, params: &Params) -> Result<Target> {
        let device = &gpu.device;
        let (width, height) = (params.size[0], params.size[1]);
        let pixels = width as u64 * height as u64;
        let limit = device.limits().max_storage_buffer_binding_size;
        if 16 * pixels > limit {
            bail!(
                "a {width}×{height} image needs {} MiB of colour buffer, more than the GPU binds ({} MiB)",
                (16 * pixels) >> 20,
                limit >> 20
            );
        }
        let usage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST;
        let buffer = |label: &str, size: u64| {
            device.create_buffer(&wgpu::BufferDescriptor { label: Some(label), size: size.max(16), usage, mapped_at_creation: false })
        };
        let colour = buffer("colour", 16 * pixels);
        let depth = buffer("depth", 4 * pixels);
        let steps = buffer("steps", 4 * pixels);
        let counters = buffer("counters", 16);
        let uniform = uniform_buffer(gpu, bytemuck::bytes_of(params));
        // Array a of the split textures, or (past the last) the first: bound, never read.
        let further = |binding: u32, views: &'a [wgpu::TextureView], a: usize| wgpu::BindGroupEntry {
            binding,
            resource: wgpu::BindingResource::TextureView(views.get(a).unwrap_or(&views[0])),
        };
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("raycast"),
            layout: &gpu.pipelines.ray_layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: uniform.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 1, resource: wgpu::BindingResource::TextureView(&self.heights_views[0]) },
                wgpu::BindGroupEntry { binding: 2, resource: wgpu::BindingResource::TextureView(&self.pyramid_views[0]) },
                wgpu::BindGroupEntry { binding: 3, resource: wgpu::BindingResource::TextureView(&self.colour_view) },
                wgpu::BindGroupEntry { binding: 4, resource: wgpu::BindingResource::Sampler(&self.sampler) },
                wgpu::BindGroupEntry { binding: 5, resource: colour.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 6, resource: depth.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 7, resource: steps.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 8, resource: counters.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 9, resource: wgpu::BindingResource::TextureView(&self.top_view) },
                further(10, &self.heights_views, 1),
                further(11, &self.heights_views, 2),
                further(12, &self.heights_views, 3),
                further(13, &self.pyramid_views, 1),
                further(14, &self.pyramid_views, 2),
                further(15, &self.pyramid_views, 3),
            ],
        });
        Ok(Target { width, height, colour, depth, steps, counters, bind_group })
    }

    fn dispatch(&self, gpu: &Gpu, target: &Target) -> Result<f64> {
        let start = Instant::now();
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        enc.clear_buffer(&target.counters, 0, None);
        {
            let mut pass = enc.begin_compute_pass(&Default::default());
            pass.set_pipeline(if self.tiling.arrays() > 1 { gpu.pipelines.ray_split(&gpu.device) } else { &gpu.pipelines.ray });
            pass.set_bind_group(0, &target.bind_group, &[]);
            pass.dispatch_workgroups(target.width.div_ceil(8), target.height.div_ceil(8), 1);
        }
        gpu.queue.submit([enc.finish()]);
        gpu.device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| anyhow!("GPU ray casting failed: {e}"))?;
        Ok(start.elapsed().as_secs_f64())
    }

    /// Renders one frame and reads it back: colour, `Z` (world distance), `steps`.
    pub fn render(&self, gpu: &Gpu, view: &View) -> Result<Frame> {
        let params = self.params(view);
        let (rays, max_steps) = (view.rays, view.max_steps);
        let (target, seconds) = gpu.guarded("ray casting the terrain on the GPU", || {
            let target = self.target(gpu, &params)?;
            let seconds = self.dispatch(gpu, &target)?;
            Ok((target, seconds))
        })?;
        let colour: Vec<[f32; 4]> = gpu.read_buffer(&target.colour)?;
        let depth: Vec<f32> = gpu.read_buffer(&target.depth)?;
        let steps: Vec<u32> = gpu.read_buffer(&target.steps)?;
        let counters: Vec<u32> = gpu.read_buffer(&target.counters)?;
        let (w, h) = rays.size();
        let mut frame = Frame::empty(w, h);
        frame.rgba = colour[..w * h].to_vec();
        frame.depth = depth[..w * h].iter().map(|&d| if d >= 0.0 { d } else { f32::INFINITY }).collect();
        let stats = StepStats::new(&steps[..w * h]);
        let hits = frame.depth.iter().filter(|d| d.is_finite()).count();
        frame.stats = FrameStats {
            renderer: super::RENDERER.name.into(),
            seconds,
            counters: vec![
                ("rays".into(), (w * h) as f64),
                ("hits".into(), hits as f64),
                ("rays at the step cap".into(), counters[0] as f64),
                ("mean steps".into(), stats.mean),
                ("p95 steps".into(), stats.p95 as f64),
                ("max steps".into(), stats.max as f64),
                ("pyramid build ms".into(), self.build_seconds * 1e3),
            ],
            notes: vec![format!("GPU: {} ({:?})", gpu.info.name, gpu.info.backend)],
            nodes: vec![],
        };
        if counters[0] > 0 {
            frame.stats.notes.push(format!("{} rays stopped at the step cap of {max_steps}; raise settings.max_steps", counters[0]));
        }
        frame.extra.push(("steps".into(), steps[..w * h].iter().map(|&s| s as f32).collect()));
        Ok(frame)
    }

    /// Seconds per frame for `runs` frames of the same view (dispatch and wait, no read-back).
    pub fn time_frames(&self, gpu: &Gpu, view: &View, runs: usize) -> Result<Vec<f64>> {
        let params = self.params(view);
        let target = gpu.guarded("allocating the frame on the GPU", || self.target(gpu, &params))?;
        self.dispatch(gpu, &target)?;
        (0..runs).map(|_| self.dispatch(gpu, &target)).collect()
    }
}

/// Mean, 95th percentile and maximum of per-ray step counts.
#[derive(Debug, Clone, Copy)]
pub struct StepStats {
    pub mean: f64,
    pub p95: u32,
    pub max: u32,
}

impl StepStats {
    pub fn new(steps: &[u32]) -> StepStats {
        let mut sorted = steps.to_vec();
        sorted.sort_unstable();
        let n = sorted.len().max(1);
        StepStats {
            mean: steps.iter().map(|&s| s as f64).sum::<f64>() / n as f64,
            p95: sorted.get(((n as f64 * 0.95).ceil() as usize).saturating_sub(1)).copied().unwrap_or(0),
            max: sorted.last().copied().unwrap_or(0),
        }
    }
}

fn uniform_buffer(gpu: &Gpu, bytes: &[u8]) -> wgpu::Buffer {
    let buf = gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("uniform"),
        size: bytes.len() as u64,
        usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    gpu.queue.write_buffer(&buf, 0, bytes);
    buf
}

fn colour_texture(gpu: &Gpu, img: &Drape, max_dim: usize) -> Result<wgpu::Texture> {
    if img.width > max_dim || img.height > max_dim || img.width == 0 || img.height == 0 {
        bail!("colour texture {}×{} does not fit the GPU's textures ({max_dim}²)", img.width, img.height);
    }
    let rgba = &img.rgba;
    let tex = gpu.device.create_texture(&wgpu::TextureDescriptor {
        label: Some("colour"),
        size: wgpu::Extent3d { width: img.width as u32, height: img.height as u32, depth_or_array_layers: 1 },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: wgpu::TextureFormat::Rgba8UnormSrgb,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    });
    gpu.queue.write_texture(
        tex.as_image_copy(),
        rgba,
        wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(4 * img.width as u32), rows_per_image: None },
        tex.size(),
    );
    Ok(tex)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A tile's highest lid is the same whichever bands of rows its heights arrive in,
    /// the patches between two bands included: here the only patch clear of NoData, and
    /// the highest, straddles the bands' border.
    #[test]
    fn a_tile_s_highest_lid_does_not_depend_on_its_bands() {
        let w = 3;
        #[rustfmt::skip]
        let rows = [
            HOLE, HOLE, HOLE,
            1.0, 7.0, HOLE,
            2.0, 3.0, HOLE,
            HOLE, 9.0, HOLE,
        ];
        let whole = band_lid(&mut Vec::new(), &rows, w);
        assert_eq!(whole, 7.0);
        for split in 1..4 {
            let mut below = Vec::new();
            let (first, second) = rows.split_at(split * w);
            let highest = band_lid(&mut below, first, w).max(band_lid(&mut below, second, w));
            assert_eq!(highest, whole, "bands of {split} and {} rows", 4 - split);
        }
        // Every patch touching NoData: nothing to bound.
        assert_eq!(band_lid(&mut Vec::new(), &[HOLE, 1.0, 2.0, 3.0], 2), HOLE);
    }

    /// Rounding to half floats goes up, never down, and keeps NoData below everything.
    #[test]
    fn half_up_never_rounds_down() {
        for v in [1000.2f32, -999.8, 0.1, -0.1, 1e-6, -1e-6, 2048.5, 65504.0, 70000.0, -70000.0] {
            let h = half_up(v);
            assert!(h >= v, "{v} → {h}");
            assert_eq!(half::f16::from_f32(h).to_f32(), h, "{v} → {h} is a half float");
        }
        assert_eq!(half_up(HOLE), f32::NEG_INFINITY);
        assert_eq!(half_up(1000.2), 1000.5);
        assert_eq!(half_up(-999.8), -999.5);
    }
}
