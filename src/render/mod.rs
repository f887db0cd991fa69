//! Renderers. Each takes the scene (and a node) with its settings and returns a [`Frame`];
//! none reaches into another. `render_scene` draws every visible node with the renderer it
//! names and composites the results by depth.

pub mod frame;
pub mod geometry;
pub mod reference_volume;
pub mod shear_warp;
pub mod smoke;
pub mod terrain;

pub use frame::{Frame, FrameStats};

use crate::scene::{Camera, NodeKind, Scene};
use anyhow::{anyhow, bail, Context, Result};
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

/// Renderers by name, with the node kinds they draw and whether they exist yet.
pub const RENDERERS: &[(&str, NodeKind, bool)] = &[
    ("reference", NodeKind::Volume, true),
    ("shear-warp", NodeKind::Volume, true),
    ("terrain", NodeKind::Heightfield, true),
    ("terrain-reference", NodeKind::Heightfield, true),
    ("smoke", NodeKind::Particles, true),
];

/// The renderer a node uses when it names none: the best one available for its kind.
pub fn default_renderer(kind: NodeKind) -> Option<&'static str> {
    RENDERERS.iter().find(|(_, k, ready)| *k == kind && *ready).map(|(n, _, _)| *n)
}

fn settings<T: serde::de::DeserializeOwned + Default>(table: &toml::Table, node: &str, renderer: &str) -> Result<T> {
    if table.is_empty() {
        return Ok(T::default());
    }
    toml::Value::Table(table.clone())
        .try_into()
        .map_err(|e: toml::de::Error| anyhow!("node '{node}': settings for renderer '{renderer}': {}", e.message().trim()))
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
    if !desc.visible || desc.kind == NodeKind::Group {
        return Ok(None);
    }
    let name = match &desc.renderer {
        Some(r) => r.as_str(),
        None => default_renderer(desc.kind)
            .ok_or_else(|| anyhow!("node '{}': no renderer for {:?} nodes is available yet", desc.name, desc.kind))?,
    };
    let Some(&(_, kind, ready)) = RENDERERS.iter().find(|(n, _, _)| *n == name) else {
        let names: Vec<&str> = RENDERERS.iter().map(|r| r.0).collect();
        bail!("node '{}': unknown renderer '{name}' (known: {})", desc.name, names.join(", "));
    };
    if kind != desc.kind {
        bail!("node '{}': renderer '{name}' draws {:?} nodes, not {:?}", desc.name, kind, desc.kind);
    }
    if !ready {
        bail!("node '{}': renderer '{name}' is not implemented yet", desc.name);
    }
    let rays = camera.rays(size.0, size.1);
    let frame = match name {
        "reference" => {
            let s: reference_volume::Settings = settings(&desc.settings, &desc.name, name)?;
            let tf = desc.transfer_function.as_ref().ok_or_else(|| anyhow!("node '{}': a volume needs a transfer_function", desc.name))?;
            let vol = scene.volume(node)?;
            let input = reference_volume::VolumeInput { volume: &vol, node_to_world: scene.world_transform(node), tf, blend: desc.blend };
            reference_volume::render(&input, &rays, &s)?
        }
        "shear-warp" => {
            let s: shear_warp::Settings = settings(&desc.settings, &desc.name, name)?;
            let tf = desc.transfer_function.as_ref().ok_or_else(|| anyhow!("node '{}': a volume needs a transfer_function", desc.name))?;
            let prepared = cache.shear_warp(&scene.volume(node)?)?;
            let input = shear_warp::Input { prepared: &prepared, node_to_world: scene.world_transform(node), tf, blend: desc.blend };
            shear_warp::render(&input, &rays, &s)?
        }
        "terrain" | "terrain-reference" => {
            let s: terrain::Settings = settings(&desc.settings, &desc.name, name)?;
            let hf = scene.heightfield(node)?;
            let texture = scene.texture(node)?;
            let input = terrain::TerrainInput {
                heightfield: &hf,
                texture: texture.as_deref(),
                node_to_world: scene.world_transform(node),
                lights: &scene.file.lights,
            };
            if name == "terrain" {
                terrain::render(&input, &rays, &s)?
            } else {
                terrain::render_reference(&input, &rays, &s)?
            }
        }
        "smoke" => {
            let s: smoke::Settings = settings(&desc.settings, &desc.name, name)?;
            let medium = desc
                .medium
                .as_ref()
                .ok_or_else(|| anyhow!("node '{}': a particle node needs medium = {{ c_ext = …, albedo = …, g = … }}", desc.name))?;
            let particles = scene.particles(node)?;
            let input =
                smoke::SmokeInput { particles: &particles, node_to_world: scene.world_transform(node), medium, lights: &scene.file.lights };
            smoke::render(&input, &rays, &s).with_context(|| format!("node '{}'", desc.name))?
        }
        _ => unreachable!(),
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
