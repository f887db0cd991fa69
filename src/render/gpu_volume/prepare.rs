//! What the GPU ray-caster keeps of a volume across frames: its bricks as 3-D textures of
//! the stored type or as storage buffers of the stored values packed into words, and the
//! min-max grid of its blocks (real values) that the empty-space test reads. Neither
//! depends on the camera or the transfer function.

use super::gpu::{Gpu, SampleKind, Store};
use crate::catalog::gpu_volume::Voxels;
use anyhow::{anyhow, bail, Result};
use rayon::prelude::*;
use volterra_formats::{Limits, Volume, VoxelData};

/// Voxels per block edge of the min-max grid.
pub const BLOCK: usize = 8;

/// A brick's voxels on the GPU.
pub enum Held {
    Texture(wgpu::TextureView),
    /// Row after row, slice after slice (x fastest), packed little-endian into words.
    Buffer(wgpu::Buffer),
}

impl Held {
    pub fn binding(&self) -> wgpu::BindingResource<'_> {
        match self {
            Held::Texture(view) => wgpu::BindingResource::TextureView(view),
            Held::Buffer(buf) => buf.as_entire_binding(),
        }
    }
}

/// One brick: a texture or buffer holding voxels `origin ..` and the box of index space
/// whose segments it draws.
pub struct Brick {
    pub held: Held,
    pub origin: [i32; 3],
    /// Its voxel counts.
    pub size: [usize; 3],
    /// Segments starting in [owned_lo, owned_hi) are drawn from this brick (±1e30 on the
    /// volume's outer faces).
    pub owned_lo: [f32; 3],
    pub owned_hi: [f32; 3],
    /// Its place in the grid of bricks.
    pub cell: [usize; 3],
}

/// A volume on the GPU.
pub struct Prepared {
    pub dims: [usize; 3],
    /// Voxel index → the node's coordinates (the volume's affine).
    pub index_to_node: glam::DMat4,
    pub kind: SampleKind,
    /// Texture or buffer (what `Voxels::Auto` chose).
    pub store: Store,
    pub bricks: Vec<Brick>,
    /// Bricks per axis.
    pub brick_grid: [usize; 3],
    /// The voxels a segment reads beyond its start's voxel (see `ghost_for`).
    pub reach: usize,
    /// Blocks per axis, and each block's lowest and highest real value over the voxels its
    /// segments read.
    pub blocks: [usize; 3],
    pub block_range: Vec<[f32; 2]>,
    /// The highest value of each block, on the GPU (MIP's skipping).
    pub block_max: wgpu::Buffer,
    /// The volume's real value range (the pre-integrated table's).
    pub lo: f64,
    pub hi: f64,
    pub slope: f64,
    pub intercept: f64,
    /// Bytes held on the GPU.
    pub bytes: u64,
    /// Seconds the upload took.
    pub seconds: f64,
    /// The transfer function's classification, kept while it and the step stay.
    pub classified: std::sync::Mutex<Option<std::sync::Arc<super::Classified>>>,
}

/// Voxels a brick's texture holds around its box for segments that reach `reach` voxels
/// from their start along any axis: the segment's end (`reach`), the trilinear cell beyond
/// it (1) and the gradient's central difference around the segment's middle (1).
pub fn ghost_for(reach: usize) -> usize {
    reach + 2
}

/// How one axis of `n` voxels is cut into bricks of at most `edge` voxels of texture:
/// (owned start, owned end) per brick. One brick where the axis fits.
fn cuts(n: usize, edge: usize, ghost: usize) -> Result<Vec<(usize, usize)>> {
    if n <= edge {
        return Ok(vec![(0, n)]);
    }
    // Owned runs a multiple of the block edge, so blocks do not straddle bricks.
    let owned = (edge.saturating_sub(2 * ghost + 1) / BLOCK) * BLOCK;
    if owned == 0 {
        bail!("a brick of {edge} voxels leaves no room inside its {ghost} overlapping voxels either side");
    }
    Ok((0..n.div_ceil(owned)).map(|b| (b * owned, ((b + 1) * owned).min(n))).collect())
}

/// How a volume of `dims` is cut: the bricks' owned runs per axis, and each brick's span of
/// voxels (its owned run and the `ghost` voxels beyond it where the axis is cut).
struct Cutting {
    axes: [Vec<(usize, usize)>; 3],
    dims: [usize; 3],
    ghost: usize,
}

impl Cutting {
    fn new(dims: [usize; 3], edges: [usize; 3], ghost: usize) -> Result<Cutting> {
        let cut = |a: usize| cuts(dims[a], edges[a], ghost).map_err(|e| anyhow!("axis {a} of {} voxels: {e}", dims[a]));
        Ok(Cutting { axes: [cut(0)?, cut(1)?, cut(2)?], dims, ghost })
    }

    fn grid(&self) -> [usize; 3] {
        self.axes.each_ref().map(Vec::len)
    }

    fn span(&self, a: usize, (lo, hi): (usize, usize)) -> (usize, usize) {
        if self.axes[a].len() == 1 {
            (0, self.dims[a])
        } else {
            (lo.saturating_sub(self.ghost), (hi + self.ghost + 1).min(self.dims[a]))
        }
    }

    /// Each brick's voxel count, in the order the bricks are made (x fastest).
    fn brick_voxels(&self) -> impl Iterator<Item = usize> + '_ {
        let len = |a: usize, r: (usize, usize)| {
            let (lo, hi) = self.span(a, r);
            hi - lo
        };
        self.axes[2].iter().flat_map(move |&z| {
            self.axes[1].iter().flat_map(move |&y| self.axes[0].iter().map(move |&x| len(0, x) * len(1, y) * len(2, z)))
        })
    }
}

/// Bytes of a brick of `voxels` voxels held as `store`.
fn held_bytes(store: Store, kind: SampleKind, voxels: usize) -> u64 {
    match store {
        Store::Texture => (voxels * kind.bytes()) as u64,
        Store::Buffer => (voxels * kind.bytes()).next_multiple_of(4) as u64,
    }
}

/// Brick edges per axis for bricks held as `store` of at most `max_bytes` each (`bound`
/// names that limit): `edge` on every axis (0: none), then cut down along z, then y, then
/// x (slabs keep rows and slices whole where they can) until the largest brick fits.
fn fitted_edges(
    dims: [usize; 3],
    edge: usize,
    ghost: usize,
    (store, kind): (Store, SampleKind),
    max_bytes: u64,
    bound: &str,
) -> Result<[usize; 3]> {
    let mut edges = dims.map(|n| if edge == 0 { n } else { edge.min(n) });
    let fits = |edges: [usize; 3]| -> Result<bool> {
        let c = Cutting::new(dims, edges, ghost)?;
        let all_fit = c.brick_voxels().all(|v| held_bytes(store, kind, v) <= max_bytes);
        Ok(all_fit)
    };
    // The smallest edge that leaves a block owned inside the overlap.
    let least = 2 * ghost + 1 + BLOCK;
    for a in [2, 1, 0] {
        while !fits(edges)? {
            if edges[a] <= least {
                break;
            }
            edges[a] = edges[a].saturating_sub(BLOCK).max(least);
        }
    }
    if !fits(edges)? {
        bail!("bricks of the smallest size still pass {bound} ({} MiB)", max_bytes >> 20);
    }
    Ok(edges)
}

impl Prepared {
    /// Uploads `volume` held as `voxels` says, in bricks of at most `edge` voxels per axis
    /// (0: as large as the adapter allows), each holding `ghost_for(reach)` voxels beyond
    /// its box; the textures and buffers checked against `limits` first.
    pub fn new(
        gpu: &Gpu,
        volume: &Volume,
        voxels: Voxels,
        edge: usize,
        reach: usize,
        limits: &Limits,
        source: &std::path::Path,
    ) -> Result<Prepared> {
        let start = std::time::Instant::now();
        let device = &gpu.device;
        let dims = volume.dims;
        let kind = SampleKind::of(&volume.data);
        let ghost = ghost_for(reach);
        let max_binding = device.limits().max_storage_buffer_binding_size;
        let store = match voxels {
            Voxels::Texture => Store::Texture,
            Voxels::Buffer => Store::Buffer,
            Voxels::Auto => {
                let whole = held_bytes(Store::Buffer, kind, dims.iter().product());
                if gpu.is_software() && whole <= max_binding && edge == 0 {
                    Store::Buffer
                } else {
                    Store::Texture
                }
            }
        };
        let edges = match store {
            // wgpu tells no largest allocation; its largest buffer stands in (on Vulkan it
            // is at most maxMemoryAllocationSize, which bounds one texture too).
            Store::Texture => {
                let max_edge = device.limits().max_texture_dimension_3d as usize;
                let edge = if edge == 0 { max_edge } else { edge.min(max_edge) };
                let bound = "the GPU's largest allocation (`max_buffer_size`)";
                fitted_edges(dims, edge, ghost, (store, kind), device.limits().max_buffer_size, bound)?
            }
            Store::Buffer => {
                let bound = "the GPU's largest storage binding";
                fitted_edges(dims, edge, ghost, (store, kind), max_binding, bound)?
            }
        };
        let cutting = Cutting::new(dims, edges, ghost)?;
        let brick_grid = cutting.grid();
        let blocks = dims.map(|n| n.div_ceil(BLOCK));
        let n_blocks = blocks.iter().product::<usize>();
        let held: u64 = cutting.brick_voxels().map(|v| held_bytes(store, kind, v)).sum();
        let bytes = held + n_blocks as u64 * 4;
        limits.check(source, "the volume's GPU copy", &[bytes + n_blocks as u64 * 8 + crate::gpu::driver_working_memory()])?;
        let max_buffer = device.limits().max_storage_buffer_binding_size;
        if n_blocks as u64 * 4 > max_buffer {
            bail!("the volume's {n_blocks} blocks of {BLOCK}³ voxels pass the GPU's largest storage buffer ({} MiB)", max_buffer >> 20);
        }
        let block_range = block_ranges(volume, blocks, reach);
        let (lo, hi) = volume.value_range().unwrap_or((0.0, 1.0));
        let hi = if hi > lo { hi } else { lo + 1.0 };
        let mut bricks = Vec::new();
        let axes = &cutting.axes;
        gpu.guarded("uploading the volume to the GPU", || {
            for (cz, &z) in axes[2].iter().enumerate() {
                for (cy, &y) in axes[1].iter().enumerate() {
                    for (cx, &x) in axes[0].iter().enumerate() {
                        let cell = [cx, cy, cz];
                        let owned = [x, y, z];
                        let spans = [cutting.span(0, x), cutting.span(1, y), cutting.span(2, z)];
                        let lo = spans.map(|s| s.0);
                        let size = spans.map(|s| s.1 - s.0);
                        let held = match store {
                            Store::Texture => Held::Texture(upload_texture(gpu, volume, kind, lo, size)?),
                            Store::Buffer => Held::Buffer(upload_buffer(gpu, volume, kind, lo, size)?),
                        };
                        let open = |a: usize, first: bool| -> f32 {
                            match first {
                                true if cell[a] == 0 => -1e30,
                                false if cell[a] + 1 == brick_grid[a] => 1e30,
                                true => owned[a].0 as f32,
                                false => owned[a].1 as f32,
                            }
                        };
                        bricks.push(Brick {
                            held,
                            origin: lo.map(|v| v as i32),
                            size,
                            owned_lo: [open(0, true), open(1, true), open(2, true)],
                            owned_hi: [open(0, false), open(1, false), open(2, false)],
                            cell,
                        });
                    }
                }
            }
            Ok(())
        })?;
        let maxima: Vec<f32> = block_range.iter().map(|r| r[1]).collect();
        let block_max = super::gpu::storage_buffer(gpu, "block maxima", bytemuck::cast_slice(&maxima));
        Ok(Prepared {
            dims,
            index_to_node: crate::geometry::affine_matrix(&volume.affine),
            kind,
            store,
            bricks,
            brick_grid,
            reach,
            blocks,
            block_range,
            block_max,
            lo,
            hi,
            slope: volume.rescale.slope,
            intercept: volume.rescale.intercept,
            bytes,
            seconds: start.elapsed().as_secs_f64(),
            classified: Default::default(),
        })
    }
}

/// Bytes of upload finished before the next band is made (a staging copy of the whole
/// volume would double the peak memory where the GPU's memory is the host's).
const BAND_BYTES: usize = 16 << 20;

/// Writes the voxels of the box at `lo` of `size` into a new 3-D texture of `kind`, in
/// bands of about `BAND_BYTES` each finished before the next.
fn upload_texture(gpu: &Gpu, volume: &Volume, kind: SampleKind, lo: [usize; 3], size: [usize; 3]) -> Result<wgpu::TextureView> {
    let texture = gpu.device.create_texture(&wgpu::TextureDescriptor {
        label: Some("volume brick"),
        size: wgpu::Extent3d { width: size[0] as u32, height: size[1] as u32, depth_or_array_layers: size[2] as u32 },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D3,
        format: kind.format(),
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    });
    let slice_bytes = size[0] * size[1] * kind.bytes();
    let band = (BAND_BYTES / slice_bytes.max(1)).clamp(1, size[2]);
    let [nx, ny, _] = volume.dims;
    for z0 in (0..size[2]).step_by(band) {
        let depth = band.min(size[2] - z0);
        let mut bytes = Vec::with_capacity(slice_bytes * depth);
        for z in z0..z0 + depth {
            for y in 0..size[1] {
                let first = lo[0] + nx * (lo[1] + y + ny * (lo[2] + z));
                kind.push_row(&volume.data, first..first + size[0], &mut bytes);
            }
        }
        gpu.queue.write_texture(
            wgpu::TexelCopyTextureInfo {
                texture: &texture,
                mip_level: 0,
                origin: wgpu::Origin3d { x: 0, y: 0, z: z0 as u32 },
                aspect: wgpu::TextureAspect::All,
            },
            &bytes,
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some((size[0] * kind.bytes()) as u32),
                rows_per_image: Some(size[1] as u32),
            },
            wgpu::Extent3d { width: size[0] as u32, height: size[1] as u32, depth_or_array_layers: depth as u32 },
        );
        gpu.queue.submit(std::iter::empty());
        gpu.device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| anyhow!("uploading the volume: {e}"))?;
    }
    Ok(texture.create_view(&Default::default()))
}

/// Writes the voxels of the box at `lo` of `size` into a new storage buffer, `kind`'s
/// values packed little-endian into 32-bit words (the shader unpacks them), in bands of
/// about `BAND_BYTES`.
fn upload_buffer(gpu: &Gpu, volume: &Volume, kind: SampleKind, lo: [usize; 3], size: [usize; 3]) -> Result<wgpu::Buffer> {
    let total = (size.iter().product::<usize>() * kind.bytes()).next_multiple_of(4);
    let buffer = gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("volume brick"),
        size: total.max(4) as u64,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let [nx, ny, _] = volume.dims;
    let mut band = Vec::with_capacity(BAND_BYTES + size[0] * kind.bytes());
    let mut offset = 0usize;
    let flush = |band: &mut Vec<u8>, offset: &mut usize, last: bool| -> Result<()> {
        // Writes start and end on whole words: the tail of a band waits for the next.
        let n = if last { band.len().next_multiple_of(4) } else { band.len() / 4 * 4 };
        band.resize(band.len().max(n), 0);
        gpu.queue.write_buffer(&buffer, *offset as u64, &band[..n]);
        gpu.queue.submit(std::iter::empty());
        gpu.device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| anyhow!("uploading the volume: {e}"))?;
        band.drain(..n);
        *offset += n;
        Ok(())
    };
    for z in 0..size[2] {
        for y in 0..size[1] {
            let first = lo[0] + nx * (lo[1] + y + ny * (lo[2] + z));
            kind.push_row(&volume.data, first..first + size[0], &mut band);
        }
        if band.len() >= BAND_BYTES {
            flush(&mut band, &mut offset, false)?;
        }
    }
    if !band.is_empty() {
        flush(&mut band, &mut offset, true)?;
    }
    Ok(buffer)
}

/// Each block's lowest and highest real value over the voxels any segment starting in it
/// reads: its own voxels, one beyond (the trilinear cell) and `reach` more either side
/// (where the segment may end). NaN voxels are left out.
fn block_ranges(volume: &Volume, blocks: [usize; 3], reach: usize) -> Vec<[f32; 2]> {
    let dims = volume.dims;
    let span = |a: usize, b: usize| ((b * BLOCK).saturating_sub(reach), ((b + 1) * BLOCK + 1 + reach).min(dims[a]));
    let stored = |i: usize| volume.data.stored(i);
    let [bx, by, bz] = blocks;
    (0..bx * by * bz)
        .into_par_iter()
        .map(|b| {
            let (x, y, z) = (b % bx, (b / bx) % by, b / (bx * by));
            let ((x0, x1), (y0, y1), (z0, z1)) = (span(0, x), span(1, y), span(2, z));
            let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
            for k in z0..z1 {
                for j in y0..y1 {
                    let row = dims[0] * (j + dims[1] * k);
                    for i in x0..x1 {
                        let v = stored(row + i);
                        lo = lo.min(v);
                        hi = hi.max(v);
                    }
                }
            }
            // The rescale may reverse the order.
            let (a, b) = (volume.rescale.apply(lo), volume.rescale.apply(hi));
            // Rounded outward to f32, so the test stays conservative.
            [next_down(a.min(b) as f32), next_up(a.max(b) as f32)]
        })
        .collect()
}

fn next_up(x: f32) -> f32 {
    if x.is_finite() {
        x + x.abs() * 1e-6 + f32::MIN_POSITIVE
    } else {
        x
    }
}

fn next_down(x: f32) -> f32 {
    -next_up(-x)
}

impl SampleKind {
    /// The voxels `range` of `data` as this kind's texels, appended to `out`.
    fn push_row(self, data: &VoxelData, range: std::ops::Range<usize>, out: &mut Vec<u8>) {
        match (self, data) {
            (SampleKind::U8, VoxelData::U8(v)) => out.extend_from_slice(&v[range]),
            (SampleKind::I8, VoxelData::I8(v)) => out.extend_from_slice(bytemuck::cast_slice(&v[range])),
            (SampleKind::U16, VoxelData::U16(v)) => out.extend_from_slice(bytemuck::cast_slice(&v[range])),
            (SampleKind::I16, VoxelData::I16(v)) => out.extend_from_slice(bytemuck::cast_slice(&v[range])),
            (SampleKind::F32, VoxelData::F32(v)) => out.extend_from_slice(bytemuck::cast_slice(&v[range])),
            (_, d) => range.for_each(|i| out.extend_from_slice(&(d.stored(i) as f32).to_le_bytes())),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cuts_partition_the_axis_in_whole_blocks() {
        assert_eq!(cuts(100, 128, 3).unwrap(), vec![(0, 100)]);
        let c = cuts(1000, 64, 3).unwrap();
        assert_eq!(c[0], (0, 56));
        assert!(c.windows(2).all(|w| w[0].1 == w[1].0));
        assert_eq!(c.last().unwrap().1, 1000);
        assert!(c.iter().all(|&(a, b)| a % BLOCK == 0 && b - a <= 56));
        assert!(cuts(1000, 10, 3).is_err());
    }

    #[test]
    fn bricks_fit_the_binding_or_allocation_cut_along_z_first() {
        // 512 × 512 × 400 int16 (200 MiB) into 128 MiB bindings: two slabs along z, rows
        // and slices whole.
        let (dims, ghost, mib) = ([512, 512, 400], 3, 1u64 << 20);
        let buffer = (Store::Buffer, SampleKind::I16);
        let edges = fitted_edges(dims, 0, ghost, buffer, 128 * mib, "the binding").unwrap();
        let c = Cutting::new(dims, edges, ghost).unwrap();
        assert_eq!(c.grid(), [1, 1, 2], "{edges:?}");
        assert!(c.brick_voxels().all(|v| held_bytes(Store::Buffer, SampleKind::I16, v) <= 128 * mib));
        // A binding too small for a slab of whole slices cuts y as well.
        let edges = fitted_edges(dims, 0, ghost, buffer, 4 * mib, "the binding").unwrap();
        let c = Cutting::new(dims, edges, ghost).unwrap();
        assert!(c.grid()[1] > 1 && c.brick_voxels().all(|v| held_bytes(Store::Buffer, SampleKind::I16, v) <= 4 * mib), "{edges:?}");
        // Voxels packed into whole words: 3 × 1 × 1 bytes take a word.
        assert_eq!(held_bytes(Store::Buffer, SampleKind::U8, 3), 4);
        assert_eq!(held_bytes(Store::Texture, SampleKind::U8, 3), 3);
        // No brick can fit: refused in one line.
        let err = fitted_edges(dims, 0, ghost, (Store::Buffer, SampleKind::F32), 1024, "the binding").unwrap_err().to_string();
        assert!(err.contains("the binding") && !err.contains('\n'), "{err}");
        // A texture larger than the largest allocation is bricked the same way: 512 × 512 ×
        // 1000 int16 (500 MiB) in 256 MiB.
        let dims = [512, 512, 1000];
        let edges = fitted_edges(dims, 0, ghost, (Store::Texture, SampleKind::I16), 256 * mib, "the allocation").unwrap();
        let c = Cutting::new(dims, edges, ghost).unwrap();
        assert_eq!(c.grid(), [1, 1, 2], "{edges:?}");
    }

    #[test]
    fn block_ranges_cover_what_segments_read() {
        let dims = [20, 9, 3];
        let data: Vec<i16> = (0..dims.iter().product::<usize>()).map(|i| (i as i16 * 7) % 50 - 20).collect();
        let mut v = Volume::centred(dims, [1.0; 3], VoxelData::I16(data));
        v.rescale = volterra_formats::Rescale { slope: -2.0, intercept: 5.0 };
        let r = block_ranges(&v, [3, 2, 1], 1);
        // Block (1, 0, 0) reads voxels x 7..17, y 0..9, z 0..3.
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for k in 0..3 {
            for j in 0..9 {
                for i in 7..17 {
                    let x = v.value(v.index(i, j, k));
                    lo = lo.min(x);
                    hi = hi.max(x);
                }
            }
        }
        assert!(r[1][0] as f64 <= lo && lo - r[1][0] as f64 <= 1e-3, "{:?} vs {lo}", r[1]);
        assert!(r[1][1] as f64 >= hi && r[1][1] as f64 - hi <= 1e-3, "{:?} vs {hi}", r[1]);
    }
}
