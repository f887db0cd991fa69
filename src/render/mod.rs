//! Renderers. Each takes the scene (and a node) with its settings and returns a [`Frame`];
//! none reaches into another. `render_scene` draws every visible node with the renderer it
//! names and composites the results by depth.

pub mod driver;
pub mod frame;
pub mod geometry;
pub mod reference_volume;
pub mod registry;
pub mod settings;
pub mod shear_warp;
pub mod smoke;
pub mod terrain;

pub use frame::{Frame, FrameStats};

use crate::scene::{Camera, Scene};
use registry::NodeSettings;
use anyhow::{anyhow, Context, Result};
use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use volterra_formats::Volume;

/// What renderers may keep between frames of one scene: the shear-warp preparation of each
/// volume (quantised copy, permuted axes, min-max maps), which depends only on the volume,
/// not on the camera or the transfer function. An interactive viewer keeps one for its
/// scene; a one-off render uses a fresh one.
#[derive(Default)]
pub struct RenderCache {
    /// Keyed by the volume's address: a node whose data is replaced gets a new entry.
    prepared: Mutex<HashMap<usize, PreparedVolume>>,
}

/// A volume and its shear-warp preparation (the volume is held so its address stays taken).
type PreparedVolume = (Arc<Volume>, Arc<shear_warp::Prepared>);

impl RenderCache {
    fn shear_warp(&self, volume: &Arc<Volume>) -> Result<Arc<shear_warp::Prepared>> {
        let key = Arc::as_ptr(volume) as usize;
        let mut map = self.prepared.lock().unwrap();
        // Entries keep their volume alive, so an address is never reused while cached.
        if let Some((_, p)) = map.get(&key) {
            return Ok(p.clone());
        }
        let p = Arc::new(shear_warp::Prepared::new(volume)?);
        map.insert(key, (volume.clone(), p.clone()));
        Ok(p)
    }
}

/// Renders one node seen by `camera` at the scene's image size. Returns None for nodes
/// nothing is drawn for (groups, hidden nodes).
pub fn render_node(scene: &Scene, node: usize, camera: &Camera) -> Result<Option<Frame>> {
    let (w, h) = (scene.file.image.width, scene.file.image.height);
    render_node_with(scene, node, camera, (w, h), &RenderCache::default())
}

/// As [`render_node`], at `size` (width, height) pixels, reusing what `cache` holds.
pub fn render_node_with(scene: &Scene, node: usize, camera: &Camera, size: (usize, usize), cache: &RenderCache) -> Result<Option<Frame>> {
    let desc = &scene.nodes()[node];
    // Groups have no settings; the scene checked every other node's at load.
    let Some(settings) = scene.node_settings(node) else { return Ok(None) };
    if !desc.visible {
        return Ok(None);
    }
    let rays = camera.rays(size.0, size.1);
    let transfer_function =
        || desc.transfer_function.as_ref().ok_or_else(|| anyhow!("node '{}': a volume needs a transfer_function", desc.name));
    let frame = match settings {
        NodeSettings::Reference(s) => {
            let tf = transfer_function()?;
            let vol = scene.volume(node)?;
            let input = reference_volume::VolumeInput { volume: &vol, node_to_world: scene.world_transform(node), tf, blend: desc.blend };
            reference_volume::render(&input, &rays, s)?
        }
        NodeSettings::ShearWarp(s) => {
            let tf = transfer_function()?;
            let prepared = cache.shear_warp(&scene.volume(node)?)?;
            let input = shear_warp::Input { prepared: &prepared, node_to_world: scene.world_transform(node), tf, blend: desc.blend };
            shear_warp::render(&input, &rays, s)?
        }
        NodeSettings::Terrain(_) | NodeSettings::TerrainReference(_) => {
            let hf = scene.heightfield(node)?;
            let texture = scene.texture(node)?;
            let input = terrain::TerrainInput {
                heightfield: &hf,
                texture: texture.as_deref(),
                node_to_world: scene.world_transform(node),
                lights: &scene.file.lights,
            };
            match settings {
                NodeSettings::Terrain(s) => terrain::render(&input, &rays, s)?,
                NodeSettings::TerrainReference(s) => terrain::render_reference(&input, &rays, &s.into())?,
                _ => unreachable!(),
            }
        }
        NodeSettings::Smoke(s) => {
            let medium = desc
                .medium
                .as_ref()
                .ok_or_else(|| anyhow!("node '{}': a particle node needs medium = {{ c_ext = …, albedo = …, g = … }}", desc.name))?;
            let particles = scene.particles(node)?;
            let input =
                smoke::SmokeInput { particles: &particles, node_to_world: scene.world_transform(node), medium, lights: &scene.file.lights };
            smoke::render(&input, &rays, s).with_context(|| format!("node '{}'", desc.name))?
        }
    };
    Ok(Some(frame))
}

/// Renders the scene's camera (or frame k of n along its keyframes).
pub fn render_scene(scene: &Scene, frame: Option<(usize, usize)>) -> Result<Frame> {
    let camera = scene.camera(frame)?;
    let size = (scene.file.image.width, scene.file.image.height);
    render_view(scene, &camera, size, &RenderCache::default())
}

/// Renders every visible node seen by `camera` at `size` and composites them by depth.
pub fn render_view(scene: &Scene, camera: &Camera, size: (usize, usize), cache: &RenderCache) -> Result<Frame> {
    // Each layer's colour and depth, and the composite, against the memory limit.
    let layers_max = scene.nodes().len() as u64 + 1;
    volterra_formats::memory::check_alloc(&scene.source, "the frames", &[size.0 as u64, size.1 as u64, 20, layers_max])?;
    let mut layers = Vec::new();
    for i in 0..scene.nodes().len() {
        if let Some(f) = render_node_with(scene, i, camera, size, cache).with_context(|| scene.source.display().to_string())? {
            layers.push(f);
        }
    }
    if layers.len() == 1 {
        return Ok(layers.pop().unwrap());
    }
    Ok(Frame::composite(size.0, size.1, &layers))
}
