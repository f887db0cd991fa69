//! Renderers. Each takes the scene (and a node) with its settings and returns a [`Frame`];
//! none reaches into another. `render_scene` draws every visible node with the renderer it
//! names and composites the results by depth.

pub mod colormap;
pub mod driver;
pub mod frame;
pub mod geometry;
pub mod gpu;
pub mod points;
pub mod reference_volume;
pub mod registry;
pub mod scalar_bar;
pub mod settings;
pub mod shear_warp;
pub mod smoke;
pub mod terrain;
pub mod text;
pub mod volume_shading;

pub use frame::{Frame, FrameStats, NodeTime};

use crate::scene::{Camera, NodeData, Scene};
use anyhow::{anyhow, Context, Result};
use registry::NodeSettings;
use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::Instant;
use volterra_formats::{Heightfield, Limits, RgbImage, Volume};

/// What renderers may keep between frames of one scene: the shear-warp preparation of each
/// volume (quantised copy, permuted axes, min-max maps), which depends only on the volume,
/// and each placed heightfield's terrain grid and GPU pyramid — not on the camera or the
/// transfer function. The viewer keeps one for its scene, `render --frames` one for all
/// its frames; a one-off render uses a fresh one.
#[derive(Default)]
pub struct RenderCache {
    /// Keyed by the volume's address: a node whose data is replaced gets a new entry.
    prepared: Mutex<HashMap<usize, PreparedVolume>>,
    /// Keyed by the heightfield's and texture's addresses; one placement each (a new one,
    /// such as the viewer's exaggeration slider, replaces the entry instead of adding one).
    terrain: Mutex<HashMap<TerrainKey, PreparedTerrain>>,
}

/// A volume and its shear-warp preparation (the volume is held so its address stays taken).
type PreparedVolume = (Arc<Volume>, Arc<shear_warp::Prepared>);
type TerrainKey = (usize, usize);
/// A heightfield, the placement's bits and the terrain preparation for it (the
/// heightfield is held, so its address stays taken).
type PreparedTerrain = (Arc<Heightfield>, [u64; 16], Arc<terrain::Prepared>);

impl RenderCache {
    /// Keeps only what was prepared for data `scene` holds now, dropping the rest (the
    /// steps of a time series an animation has moved past), so an animation's memory stays
    /// that of the steps it draws, not of every step it drew. (Reference counts cannot
    /// tell: a preparation holds its own data.)
    pub fn keep_only_for(&self, scene: &Scene) {
        let held: std::collections::HashSet<usize> = scene
            .loaded_data()
            .map(|d| match d {
                NodeData::Volume(v) => Arc::as_ptr(&v) as usize,
                NodeData::Heightfield(h) => Arc::as_ptr(&h) as usize,
                NodeData::Particles(p) => Arc::as_ptr(&p) as usize,
            })
            .collect();
        self.prepared.lock().unwrap().retain(|k, _| held.contains(k));
        self.terrain.lock().unwrap().retain(|k, _| held.contains(&k.0));
    }

    fn shear_warp(&self, volume: &Arc<Volume>, limits: &Limits) -> Result<Arc<shear_warp::Prepared>> {
        let key = Arc::as_ptr(volume) as usize;
        let mut map = self.prepared.lock().unwrap();
        // Entries keep their volume alive, so an address is never reused while cached.
        if let Some((_, p)) = map.get(&key) {
            return Ok(p.clone());
        }
        let p = Arc::new(shear_warp::Prepared::shared(volume.clone(), limits)?);
        map.insert(key, (volume.clone(), p.clone()));
        Ok(p)
    }

    fn terrain(
        &self,
        hf: &Arc<Heightfield>,
        texture: Option<Arc<RgbImage>>,
        node_to_world: glam::DMat4,
        limits: &Limits,
    ) -> Result<Arc<terrain::Prepared>> {
        let tex = texture.as_ref().map_or(0, |t| Arc::as_ptr(t) as usize);
        let key = (Arc::as_ptr(hf) as usize, tex);
        let placement = node_to_world.to_cols_array().map(f64::to_bits);
        let mut map = self.terrain.lock().unwrap();
        if let Some((_, at, p)) = map.get(&key) {
            if *at == placement {
                return Ok(p.clone());
            }
        }
        // The prepared terrain holds the texture, so its address stays taken too.
        let p = Arc::new(terrain::Prepared::new(hf, texture, node_to_world, limits)?);
        map.insert(key, (hf.clone(), placement, p.clone()));
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
    let medium = || {
        desc.medium
            .as_ref()
            .ok_or_else(|| anyhow!("node '{}': a particle node needs medium = {{ c_ext = …, albedo = …, g = … }}", desc.name))
    };
    // What the node's description lacks is an error before its data is read.
    if matches!(settings, NodeSettings::Smoke(_)) {
        medium()?;
    }
    // Reading the data (once per scene: the scene keeps it), preparing what the renderer
    // keeps across frames, and the render itself, timed apart.
    let t = Instant::now();
    let data = scene.data(node)?;
    let texture = scene.texture(node)?;
    let load = t.elapsed().as_secs_f64();
    let mut prepare = 0.0;
    let node_to_world = scene.world_transform(node);
    let t = Instant::now();
    let mut frame = match (settings, data) {
        (NodeSettings::Reference(s), NodeData::Volume(vol)) => {
            let (tf, shading, crop) = (scene.transfer_function(node)?, scene.shading(node), scene.crop_region(node));
            let input = reference_volume::VolumeInput {
                volume: &vol,
                node_to_world,
                tf: &tf,
                blend: desc.blend,
                shading: shading.as_ref(),
                lights: &scene.file.lights,
                crop: &crop,
            };
            reference_volume::render(&input, &rays, s)?
        }
        (NodeSettings::ShearWarp(s), NodeData::Volume(vol)) => {
            let prepared = timed(&mut prepare, || cache.shear_warp(&vol, scene.limits()))?;
            let (tf, shading, crop) = (scene.transfer_function(node)?, scene.shading(node), scene.crop_region(node));
            let input = shear_warp::Input {
                prepared: &prepared,
                node_to_world,
                tf: &tf,
                blend: desc.blend,
                shading: shading.as_ref(),
                lights: &scene.file.lights,
                crop: &crop,
            };
            shear_warp::render(&input, &rays, s)?
        }
        (NodeSettings::Terrain(_) | NodeSettings::TerrainReference(_), NodeData::Heightfield(hf)) => {
            let prepared = timed(&mut prepare, || {
                let p = cache.terrain(&hf, texture.clone(), node_to_world, scene.limits())?;
                if matches!(settings, NodeSettings::Terrain(_)) {
                    p.prepare_gpu()?;
                }
                Ok(p)
            })?;
            match settings {
                NodeSettings::Terrain(s) => prepared.render(&scene.file.lights, &rays, s)?,
                NodeSettings::TerrainReference(s) => prepared.render_reference(&scene.file.lights, &rays, &s.into())?,
                _ => unreachable!(),
            }
        }
        (NodeSettings::Smoke(s), NodeData::Particles(particles)) => {
            let input = smoke::SmokeInput {
                particles: &particles,
                node_to_world,
                medium: medium()?,
                lights: &scene.file.lights,
                limits: *scene.limits(),
            };
            smoke::render(&input, &rays, s).with_context(|| format!("node '{}'", desc.name))?
        }
        (NodeSettings::Points(s), NodeData::Particles(particles)) => {
            let input =
                points::PointsInput { particles: &particles, node_to_world, color_by: desc.color_by.as_deref(), range: desc.color_range };
            points::render(&input, &rays, s).with_context(|| format!("node '{}'", desc.name))?
        }
        _ => unreachable!("the scene checked that the node's data is of its kind and its renderer draws that kind"),
    };
    let render = t.elapsed().as_secs_f64() - prepare;
    frame.stats.nodes.push(NodeTime { node: desc.name.clone(), renderer: frame.stats.renderer.clone(), load, prepare, render });
    Ok(Some(frame))
}

/// `f()`, its seconds added to `total`.
fn timed<T>(total: &mut f64, f: impl FnOnce() -> Result<T>) -> Result<T> {
    let t = Instant::now();
    let r = f();
    *total += t.elapsed().as_secs_f64();
    r
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
    scene.limits().check(&scene.source, "the frames", &[size.0 as u64, size.1 as u64, 20, layers_max])?;
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
