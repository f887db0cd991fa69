//! The volume ray-caster's pipelines on the shared device (`crate::gpu`): one per texel
//! type of the volume's texture (unsigned, signed, float), compiled on first use.

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

    /// Which pipeline (0 unsigned, 1 signed, 2 float).
    fn family(self) -> usize {
        match self {
            SampleKind::U8 | SampleKind::U16 => 0,
            SampleKind::I8 | SampleKind::I16 => 1,
            SampleKind::F32 => 2,
        }
    }
}

/// The shared device with the ray-caster's pipelines.
pub struct Gpu {
    shared: &'static crate::gpu::Device,
    /// Keyed by the two volumes' texel families and whether the entry is `fused`.
    pipelines: Mutex<HashMap<(usize, usize, bool), Arc<Pipeline>>>,
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

/// A texel family's sample type and its WGSL name.
fn sample_type(family: usize) -> (wgpu::TextureSampleType, &'static str) {
    match family {
        0 => (wgpu::TextureSampleType::Uint, "u32"),
        1 => (wgpu::TextureSampleType::Sint, "i32"),
        _ => (wgpu::TextureSampleType::Float { filterable: false }, "f32"),
    }
}

impl Gpu {
    /// The pipeline of entry `main` (one volume; `second` None) or `fused` (two).
    pub fn pipeline(&self, first: SampleKind, second: Option<SampleKind>) -> Arc<Pipeline> {
        let key = (first.family(), second.unwrap_or(first).family(), second.is_some());
        if let Some(p) = self.pipelines.lock().unwrap().get(&key) {
            return p.clone();
        }
        let device = &self.device;
        let ((type0, texel0), (type1, texel1)) = (sample_type(key.0), sample_type(key.1));
        let texture = |binding: u32, sample_type, view_dimension| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Texture { sample_type, view_dimension, multisampled: false },
            count: None,
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
                texture(1, type0, wgpu::TextureViewDimension::D3),
                texture(2, table, wgpu::TextureViewDimension::D2),
                buffer(3, read),
                buffer(4, read),
                buffer(5, read),
                buffer(6, write),
                buffer(7, write),
                buffer(8, write),
                texture(9, type1, wgpu::TextureViewDimension::D3),
                texture(10, table, wgpu::TextureViewDimension::D2),
                buffer(11, read),
                buffer(12, read),
            ],
        });
        let source = include_str!("../../../shaders/volume_raycast.wgsl").replace("VOXEL0", texel0).replace("VOXEL1", texel1);
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
