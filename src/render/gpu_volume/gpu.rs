//! The volume ray-caster's pipelines on the shared device (`crate::gpu`): one per way the
//! volumes are held (texture of a texel family, or buffer of a stored type) and entry,
//! compiled on first use.

use crate::shared_error::SharedError;
use anyhow::Result;
use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock};
use volterra_formats::VoxelData;

/// The volume's texels on the GPU: its stored type where a texture format holds it
/// exactly (8 and 16 bits, f32), else f32 (32-bit integers beyond 2²⁴ and f64 lose
/// precision, as they do in the reference's f32 field).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SampleKind {
    U8,
    I8,
    U16,
    I16,
    F32,
}

impl SampleKind {
    pub fn of(data: &VoxelData) -> SampleKind {
        match data {
            VoxelData::U8(_) => SampleKind::U8,
            VoxelData::I8(_) => SampleKind::I8,
            VoxelData::U16(_) => SampleKind::U16,
            VoxelData::I16(_) => SampleKind::I16,
            _ => SampleKind::F32,
        }
    }

    pub fn bytes(self) -> usize {
        match self {
            SampleKind::U8 | SampleKind::I8 => 1,
            SampleKind::U16 | SampleKind::I16 => 2,
            SampleKind::F32 => 4,
        }
    }

    pub fn format(self) -> wgpu::TextureFormat {
        match self {
            SampleKind::U8 => wgpu::TextureFormat::R8Uint,
            SampleKind::I8 => wgpu::TextureFormat::R8Sint,
            SampleKind::U16 => wgpu::TextureFormat::R16Uint,
            SampleKind::I16 => wgpu::TextureFormat::R16Sint,
            SampleKind::F32 => wgpu::TextureFormat::R32Float,
        }
    }

    /// The texture's sample type and its WGSL name.
    fn texel(self) -> (wgpu::TextureSampleType, &'static str) {
        match self {
            SampleKind::U8 | SampleKind::U16 => (wgpu::TextureSampleType::Uint, "u32"),
            SampleKind::I8 | SampleKind::I16 => (wgpu::TextureSampleType::Sint, "i32"),
            SampleKind::F32 => (wgpu::TextureSampleType::Float { filterable: false }, "f32"),
        }
    }

    /// WGSL that reads voxel `i` (a u32 index) of words `w` as f32, little-endian.
    fn unpack(self, w: &str) -> String {
        match self {
            SampleKind::U8 => format!("f32(({w}[i >> 2u] >> ((i & 3u) << 3u)) & 0xffu)"),
            SampleKind::I8 => format!("f32(i32({w}[i >> 2u] << ((3u - (i & 3u)) << 3u)) >> 24u)"),
            SampleKind::U16 => format!("f32(({w}[i >> 1u] >> ((i & 1u) << 4u)) & 0xffffu)"),
            SampleKind::I16 => format!("f32(i32({w}[i >> 1u] << ((1u - (i & 1u)) << 4u)) >> 16u)"),
            SampleKind::F32 => format!("bitcast<f32>({w}[i])"),
        }
    }
}

/// How a volume's voxels are held on the GPU (`prepare`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Store {
    Texture,
    Buffer,
}

/// What a pipeline's shader is compiled for about one volume.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
struct VoxelLayout {
    store: Store,
    /// For a texture only its family (unsigned, signed, float) matters.
    kind: SampleKind,
}

impl VoxelLayout {
    fn new(store: Store, kind: SampleKind) -> VoxelLayout {
        let kind = match (store, kind) {
            (Store::Texture, SampleKind::U16) => SampleKind::U8,
            (Store::Texture, SampleKind::I16) => SampleKind::I8,
            _ => kind,
        };
        VoxelLayout { store, kind }
    }

    /// The binding's layout entry.
    fn binding(self) -> wgpu::BindingType {
        match self.store {
            Store::Texture => wgpu::BindingType::Texture {
                sample_type: self.kind.texel().0,
                view_dimension: wgpu::TextureViewDimension::D3,
                multisampled: false,
            },
            Store::Buffer => wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only: true },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
        }
    }

    /// WGSL declaring volume `slot` at `binding` and `fn voxel{slot}(j)`, the stored value
    /// at j in its brick's voxel indices; a buffer's rows are `row` voxels long and its
    /// slices `slice` rows.
    fn wgsl(self, slot: usize, binding: u32, (row, slice): (&str, &str)) -> String {
        match self.store {
            Store::Texture => format!(
                "@group(0) @binding({binding}) var volume{slot}: texture_3d<{t}>;\n\
                 fn voxel{slot}(j: vec3<i32>) -> f32 {{\n    return f32(textureLoad(volume{slot}, j, 0).x);\n}}\n",
                t = self.kind.texel().1
            ),
            Store::Buffer => format!(
                "@group(0) @binding({binding}) var<storage, read> volume{slot}: array<u32>;\n\
                 fn voxel{slot}(j: vec3<i32>) -> f32 {{\n    let i = u32(j.x) + {row} * (u32(j.y) + {slice} * u32(j.z));\n    return {};\n}}\n",
                self.kind.unpack(&format!("volume{slot}"))
            ),
        }
    }
}

/// The shared device with the ray-caster's pipelines.
pub struct Gpu {
    shared: &'static crate::gpu::Device,
    /// Keyed by how the two volumes are held and whether the entry is `fused`.
    pipelines: Mutex<HashMap<(VoxelLayout, VoxelLayout, bool), Arc<Pipeline>>>,
}

pub struct Pipeline {
    pub layout: wgpu::BindGroupLayout,
    pub pipeline: wgpu::ComputePipeline,
}

impl std::ops::Deref for Gpu {
    type Target = crate::gpu::Device;
    fn deref(&self) -> &Self::Target {
        self.shared
    }
}

static GPU: OnceLock<Result<Gpu, SharedError>> = OnceLock::new();

/// The shared GPU, or why there is none (asked once per process).
pub fn gpu() -> Result<&'static Gpu> {
    GPU.get_or_init(|| crate::gpu::device().map(|shared| Gpu { shared, pipelines: Default::default() }).map_err(SharedError::new))
        .as_ref()
        .map_err(|e| anyhow::Error::new(e.clone()))
}

impl Gpu {
    /// The pipeline of entry `main` (one volume; `second` None) or `fused` (two), for
    /// volumes held as `(store, kind)`.
    pub fn pipeline(&self, first: (Store, SampleKind), second: Option<(Store, SampleKind)>) -> Arc<Pipeline> {
        let held0 = VoxelLayout::new(first.0, first.1);
        let held1 = second.map_or(held0, |(s, k)| VoxelLayout::new(s, k));
        let key = (held0, held1, second.is_some());
        if let Some(p) = self.pipelines.lock().unwrap().get(&key) {
            return p.clone();
        }
        let device = &self.device;
        let entry = |binding: u32, ty| wgpu::BindGroupLayoutEntry { binding, visibility: wgpu::ShaderStages::COMPUTE, ty, count: None };
        let texture = |binding: u32, sample_type, view_dimension| {
            entry(binding, wgpu::BindingType::Texture { sample_type, view_dimension, multisampled: false })
        };
        let buffer = |binding: u32, ty| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer { ty, has_dynamic_offset: false, min_binding_size: None },
            count: None,
        };
        let read = wgpu::BufferBindingType::Storage { read_only: true };
        let write = wgpu::BufferBindingType::Storage { read_only: false };
        let table = wgpu::TextureSampleType::Float { filterable: false };
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("volume ray casting"),
            entries: &[
                buffer(0, wgpu::BufferBindingType::Uniform),
                entry(1, held0.binding()),
                texture(2, table, wgpu::TextureViewDimension::D2),
                buffer(3, read),
                buffer(4, read),
                buffer(5, read),
                buffer(6, write),
                buffer(7, write),
                buffer(8, write),
                entry(9, held1.binding()),
                texture(10, table, wgpu::TextureViewDimension::D2),
                buffer(11, read),
                buffer(12, read),
            ],
        });
        // The first volume's rows are its brick's (`P.extent`), the second's its own.
        let volumes = held0.wgsl(0, 1, ("P.extent.x", "P.extent.y")) + &held1.wgsl(1, 9, ("P.vol[1].dims.x", "P.vol[1].dims.y"));
        let source = include_str!("../../../shaders/volume_raycast.wgsl").replace("// VOLUMES\n", &volumes);
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("volume_raycast.wgsl"),
            source: wgpu::ShaderSource::Wgsl(source.into()),
        });
        let pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("volume ray casting"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("volume ray casting"),
            layout: Some(&pl),
            module: &module,
            entry_point: Some(if key.2 { "fused" } else { "main" }),
            compilation_options: Default::default(),
            cache: None,
        });
        let p = Arc::new(Pipeline { layout, pipeline });
        self.pipelines.lock().unwrap().insert(key, p.clone());
        p
    }
}

/// A read-only storage buffer holding `bytes` (at least 16 bytes: an empty array binds).
pub fn storage_buffer(gpu: &Gpu, label: &str, bytes: &[u8]) -> wgpu::Buffer {
    let buf = gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: (bytes.len() as u64).max(16).next_multiple_of(4),
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    if !bytes.is_empty() {
        gpu.queue.write_buffer(&buf, 0, bytes);
    }
    buf
}

/// A uniform buffer holding `bytes`.
pub fn uniform_buffer(gpu: &Gpu, bytes: &[u8]) -> wgpu::Buffer {
    let buf = gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("volume uniform"),
        size: bytes.len() as u64,
        usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    gpu.queue.write_buffer(&buf, 0, bytes);
    buf
}
