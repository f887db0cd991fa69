//! What the GPU ray-caster keeps of a volume across frames: its bricks as 3-D textures of
//! the stored type, and the min-max grid of its blocks (real values) that the empty-space
//! test reads. Neither depends on the camera or the transfer function.

use super::gpu::{Gpu, SampleKind};
use anyhow::{anyhow, bail, Result};
use rayon::prelude::*;
use volterra_formats::{Limits, Volume, VoxelData};

/// Voxels per block edge of the min-max grid.
pub const BLOCK: usize = 8;

/// One brick: a texture holding voxels `origin ..` and the box of index space whose
/// segments it draws.
pub struct Brick {
    pub view: wgpu::TextureView,
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

impl Prepared {
    /// Uploads `volume` in bricks of at most `edge` voxels per axis (0: the adapter's
    /// largest 3-D texture), each holding `ghost_for(reach)` voxels beyond its box; the
    /// textures and buffers checked against `limits` first.
    pub fn new(gpu: &Gpu, volume: &Volume, edge: usize, reach: usize, limits: &Limits, source: &std::path::Path) -> Result<Prepared> {
        let start = std::time::Instant::now();
        let device = &gpu.device;
        let max_edge = device.limits().max_texture_dimension_3d as usize;
        let edge = if edge == 0 { max_edge } else { edge.min(max_edge) };
        let dims = volume.dims;
        let kind = SampleKind::of(&volume.data);
        let ghost = ghost_for(reach);
        let axes: Vec<Vec<(usize, usize)>> = (0..3)
            .map(|a| cuts(dims[a], edge, ghost).map_err(|e| anyhow!("axis {a} of {} voxels: {e}", dims[a])))
            .collect::<Result<_>>()?;
        let brick_grid = [axes[0].len(), axes[1].len(), axes[2].len()];
        let span = |a: usize, (lo, hi): (usize, usize)| -> (usize, usize) {
            if brick_grid[a] == 1 {
                (0, dims[a])
            } else {
                (lo.saturating_sub(ghost), (hi + ghost + 1).min(dims[a]))
            }
        };
        let blocks = dims.map(|n| n.div_ceil(BLOCK));
        let n_blocks = blocks.iter().product::<usize>();
        let mut texture_bytes = 0u64;
        for &x in &axes[0] {
            for &y in &axes[1] {
                for &z in &axes[2] {
                    let (sx, sy, sz) = (span(0, x), span(1, y), span(2, z));
                    texture_bytes += ((sx.1 - sx.0) * (sy.1 - sy.0) * (sz.1 - sz.0) * kind.bytes()) as u64;
                }
            }
        }
        let bytes = texture_bytes + n_blocks as u64 * 4;
        limits.check(source, "the volume's GPU textures", &[bytes + n_blocks as u64 * 8 + crate::gpu::driver_working_memory()])?;
        let max_buffer = device.limits().max_storage_buffer_binding_size;
        if n_blocks as u64 * 4 > max_buffer {
            bail!("the volume's {n_blocks} blocks of {BLOCK}³ voxels pass the GPU's largest storage buffer ({} MiB)", max_buffer >> 20);
        }
        let block_range = block_ranges(volume, blocks, reach);
        let (lo, hi) = volume.value_range().unwrap_or((0.0, 1.0));
        let hi = if hi > lo { hi } else { lo + 1.0 };
        let mut bricks = Vec::new();
        gpu.guarded("uploading the volume to the GPU", || {
            for (cz, &z) in axes[2].iter().enumerate() {
                for (cy, &y) in axes[1].iter().enumerate() {
                    for (cx, &x) in axes[0].iter().enumerate() {
                        let cell = [cx, cy, cz];
                        let lo = [span(0, x).0, span(1, y).0, span(2, z).0];
                        let hi = [span(0, x).1, span(1, y).1, span(2, z).1];
                        let owned = [x, y, z];
                        let size = [hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]];
                        let view = upload_brick(gpu, volume, kind, lo, size)?;
                        let open = |a: usize, first: bool| -> f32 {
                            match first {
                                true if cell[a] == 0 => -1e30,
                                false if cell[a] + 1 == brick_grid[a] => 1e30,
                                true => owned[a].0 as f32,
                                false => owned[a].1 as f32,
                            }
                        };
                        bricks.push(Brick {
                            view,
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

/// Writes the voxels of the box at `lo` of `size` into a new 3-D texture of `kind`, in
/// bands of about 16 MiB each finished before the next (a staging copy of the whole
/// volume would double the peak memory where the GPU's memory is the host's).
fn upload_brick(gpu: &Gpu, volume: &Volume, kind: SampleKind, lo: [usize; 3], size: [usize; 3]) -> Result<wgpu::TextureView> {
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
    let band = ((16usize << 20) / slice_bytes.max(1)).clamp(1, size[2]);
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
