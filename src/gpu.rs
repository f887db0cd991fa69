//! The process's one GPU device (wgpu), opened on first use and shared by the GPU renderers
//! (terrain, points); each builds its own pipelines on it. Also what they share: running
//! work with wgpu's errors turned into ours, and reading a buffer back.

use crate::shared_error::SharedError;
use anyhow::{anyhow, bail, Result};
use std::sync::OnceLock;

pub struct Device {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub info: wgpu::AdapterInfo,
    /// Storage buffers may also be mapped for writing (MAPPABLE_PRIMARY_BUFFERS): asked for
    /// only where the adapter's memory is the host's (a CPU or integrated GPU), where
    /// filling such a buffer in place spares the staging copy and its pages that a
    /// `mapped_at_creation` buffer otherwise costs; a discrete GPU would read it over the bus.
    pub host_mapped_storage: bool,
}

static DEVICE: OnceLock<Result<Device, SharedError>> = OnceLock::new();

/// What a GPU whose memory is the host's holds while a renderer first draws, beyond the
/// textures and buffers the renderer asks for (the driver compiling its shaders at the first
/// dispatch, its threads' working memory): 18 MiB measured on lavapipe for a terrain frame,
/// so 24 MiB are allowed for it when the renderers check the memory limit.
pub fn driver_working_memory() -> u64 {
    if volterra_formats::memory::host_gpu().is_some() {
        24 << 20
    } else {
        0
    }
}

/// The shared device, or why there is none (asked once per process).
pub fn device() -> Result<&'static Device> {
    DEVICE.get_or_init(|| open().map_err(SharedError::new)).as_ref().map_err(|e| anyhow::Error::new(e.clone()))
}

fn open() -> Result<Device> {
    let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
    desc.backends = wgpu::Backends::from_env().unwrap_or(wgpu::Backends::PRIMARY);
    let instance = wgpu::Instance::new(desc);
    let ask = |fallback: bool| {
        pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: fallback,
            compatible_surface: None,
            ..Default::default()
        }))
    };
    let adapter = ask(false).or_else(|_| ask(true)).map_err(|e| {
        anyhow!(
            "no GPU adapter for the GPU renderers (terrain, points) ({e}); without a GPU, install a \
             software Vulkan driver (Debian/Ubuntu: apt install mesa-vulkan-drivers)"
        )
    })?;
    // Ask for everything the adapter offers: big heightfields need big textures.
    let limits = adapter.limits();
    // Early depth tests with a conservative frag_depth, where the adapter has them (Vulkan):
    // the points renderer then skips the fragments of hidden spheres.
    let info = adapter.get_info();
    let shared_memory = matches!(info.device_type, wgpu::DeviceType::Cpu | wgpu::DeviceType::IntegratedGpu);
    let mappable = if shared_memory { wgpu::Features::MAPPABLE_PRIMARY_BUFFERS } else { wgpu::Features::empty() };
    let features = adapter.features() & (wgpu::Features::SHADER_EARLY_DEPTH_TEST | mappable);
    let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
        label: Some("volterra"),
        required_features: features,
        required_limits: limits,
        ..Default::default()
    }))
    .map_err(|e| anyhow!("cannot open the GPU '{}': {e}", adapter.get_info().name))?;
    let host_mapped_storage = features.contains(wgpu::Features::MAPPABLE_PRIMARY_BUFFERS);
    // Its textures and buffers then live in the host's memory: counted against the limit.
    if shared_memory {
        volterra_formats::memory::gpu_memory_is_host(&info.name);
    }
    Ok(Device { device, queue, info, host_mapped_storage })
}

impl Device {
    /// Whether the adapter runs on the CPU (lavapipe, llvmpipe, WARP): what a renderer that
    /// has a CPU twin asks before taking the GPU path by default.
    pub fn is_software(&self) -> bool {
        self.info.device_type == wgpu::DeviceType::Cpu
    }

    /// Runs `f` inside GPU error scopes (they are per thread), turning the GPU's
    /// out-of-memory and validation errors into errors that say `what` failed.
    pub fn guarded<T>(&self, what: &str, f: impl FnOnce() -> Result<T>) -> Result<T> {
        let oom = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let invalid = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let result = f();
        let invalid = pollster::block_on(invalid.pop());
        let oom = pollster::block_on(oom.pop());
        if let Some(e) = oom {
            bail!("{what}: the GPU '{}' is out of memory ({e})", self.info.name);
        }
        if let Some(e) = invalid {
            bail!("{what}: {e}");
        }
        result
    }

    /// Copies `src` into a mappable buffer and reads it back.
    pub fn read_buffer<T: bytemuck::Pod>(&self, src: &wgpu::Buffer) -> Result<Vec<T>> {
        let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("read-back"),
            size: src.size(),
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut enc = self.device.create_command_encoder(&Default::default());
        enc.copy_buffer_to_buffer(src, 0, &staging, 0, src.size());
        self.queue.submit([enc.finish()]);
        self.map_for_reading(&[&staging])?;
        let view = staging.slice(..).get_mapped_range().map_err(|e| anyhow!("GPU read-back failed: {e:?}"))?;
        Ok(bytemuck::cast_slice::<u8, T>(&view).to_vec())
    }

    /// Maps `buffers` (MAP_READ, their copies submitted) for the host to read, waiting for
    /// the GPU once for all of them.
    pub fn map_for_reading(&self, buffers: &[&wgpu::Buffer]) -> Result<()> {
        self.map(buffers, wgpu::MapMode::Read)
    }

    /// Maps whole buffers (no longer in use by the GPU) for `mode` and waits once.
    pub fn map(&self, buffers: &[&wgpu::Buffer], mode: wgpu::MapMode) -> Result<()> {
        let what = if mode == wgpu::MapMode::Read { "GPU read-back failed" } else { "GPU upload failed" };
        let (tx, rx) = std::sync::mpsc::channel();
        for buf in buffers {
            let tx = tx.clone();
            buf.slice(..).map_async(mode, move |r| {
                let _ = tx.send(r);
            });
        }
        self.device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| anyhow!("{what}: {e}"))?;
        for _ in buffers {
            rx.recv()?.map_err(|e| anyhow!("{what}: {e}"))?;
        }
        Ok(())
    }
}
