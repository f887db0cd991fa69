//! Renderers. Each takes the scene (and a node) with its settings and returns a [`Frame`];
//! none reaches into another. `render_scene` draws every visible node with the renderer it
//! names and composites the results by depth.

pub mod driver;
pub mod frame;
pub mod gpu_volume;
pub mod points;
pub mod preint;
pub mod reference_volume;
pub mod scalar_bar;
pub mod series_scale;
pub mod shear_warp;
pub mod smoke;
pub mod terrain;
pub mod text;
pub mod volume_shading;

pub use frame::{Frame, FrameStats, NodeTime};

use crate::catalog::NodeSettings;
use crate::scene::{Camera, NodeData, Scene, TerrainData};
use anyhow::{anyhow, Context, Result};
use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::Instant;
use volterra_formats::{Limits, Volume};

/// What renderers may keep between frames of one scene: the shear-warp preparation of each
/// volume (quantised copy, permuted axes, min-max maps), which depends only on the volume,
/// each placed heightfield's terrain grid and GPU pyramid — not on the camera or the
/// transfer function — and each particle node's smoke preparation (medium, density grid,
/// photons, transmittance grids; the irradiance map where g = 0). The viewer keeps one for
/// its scene, `render --frames` one for all its frames; a one-off render uses a fresh one.
#[derive(Default)]
pub struct RenderCache {
    /// Keyed by the volume's address: a node whose data is replaced gets a new entry.
    prepared: Mutex<HashMap<usize, PreparedVolume>>,
    /// Keyed by the heightfield's and texture's addresses; one placement each (a new one,
    /// such as the viewer's exaggeration slider, replaces the entry instead of adding one).
    terrain: Mutex<HashMap<TerrainKey, PreparedTerrain>>,
    /// Each fused pair on its grid (`shear_warp::fusion::FusionGrid`), prepared: keyed by
    /// both volumes' addresses and the second's placement relative to the first.
    fused: Mutex<HashMap<FusedKey, PreparedPair>>,
    /// Keyed by the particles' address; one preparation each (other settings, a medium or
    /// lights edited in the viewer, replace the entry instead of adding one).
    smoke: Mutex<HashMap<usize, PreparedSmoke>>,
    /// The automatic scales over each particle series (`series_scale`), keyed by the
    /// series' address, the node, what is coloured and the placement: found in one pass
    /// over its steps, kept for every frame.
    series: Mutex<HashMap<SeriesKey, Arc<series_scale::SeriesScale>>>,
    /// Each particle set's nearest-neighbour radii (`points::spacing_radii`), keyed by the
    /// particles' address (held, so it stays taken).
    spacing: Mutex<HashMap<usize, PreparedSpacing>>,
    /// Each volume on the GPU (`gpu_volume::Prepared`), keyed by the volume's address; one
    /// upload each (other bricks or a longer step replace it).
    gpu_volumes: Mutex<HashMap<usize, PreparedGpuVolume>>,
}

/// The volume (held so its address stays taken), the brick edge, reach and way of holding
/// it was uploaded for, and the upload.
type PreparedGpuVolume = (Arc<Volume>, (usize, usize, gpu_volume::Voxels), Arc<gpu_volume::Prepared>);

/// The particles (held so their address stays taken) and their nearest-neighbour radii.
type PreparedSpacing = (Arc<volterra_formats::ParticleSet>, Arc<Vec<f32>>);

type SeriesKey = (usize, usize, Option<String>, [u64; 16], bool);

/// The particles (held so their address stays taken), the preparation's key
/// (`smoke::prepare::Prepared::key`) and the preparation.
type PreparedSmoke = (Arc<volterra_formats::ParticleSet>, u64, Arc<smoke::prepare::Prepared>);

type FusedKey = (usize, usize, [u64; 16]);
/// Both volumes (held so their addresses stay taken) and the pair's preparations on its
/// grid: the first's (its own where the grid is not refined), the second's.
type PreparedPair = (Arc<Volume>, Arc<Volume>, FusedPreparation);

/// A fused pair as shear-warp draws it: both volumes prepared on one grid.
#[derive(Clone)]
pub struct FusedPreparation {
    pub grid: shear_warp::fusion::FusionGrid,
    pub first: Arc<shear_warp::Prepared>,
    pub second: Arc<shear_warp::Prepared>,
}

/// A volume and its shear-warp preparation (the volume is held so its address stays taken).
type PreparedVolume = (Arc<Volume>, Arc<shear_warp::Prepared>);
type TerrainKey = (usize, usize);
/// Heights, the placement's bits and the terrain preparation for them (the heights are
/// held, so their address stays taken).
type PreparedTerrain = (TerrainData, [u64; 16], Arc<terrain::Prepared>);

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
            .chain(scene.opened_height_rows())
            .collect();
        self.prepared.lock().unwrap().retain(|k, _| held.contains(k));
        self.fused.lock().unwrap().retain(|k, _| held.contains(&k.0) && held.contains(&k.1));
        self.terrain.lock().unwrap().retain(|k, _| held.contains(&k.0));
        self.smoke.lock().unwrap().retain(|k, _| held.contains(k));
        self.spacing.lock().unwrap().retain(|k, _| held.contains(k));
        self.gpu_volumes.lock().unwrap().retain(|k, _| held.contains(k));
    }

    /// The particles' nearest-neighbour radii, found once per particle set.
    fn spacing(&self, particles: &Arc<volterra_formats::ParticleSet>) -> Arc<Vec<f32>> {
        let addr = Arc::as_ptr(particles) as usize;
        if let Some((_, r)) = self.spacing.lock().unwrap().get(&addr) {
            return r.clone();
        }
        let r = Arc::new(points::spacing_radii(particles));
        self.spacing.lock().unwrap().insert(addr, (particles.clone(), r.clone()));
        r
    }

    /// The smoke preparation of `particles` for `input` and `s`, kept while the
    /// particles, their placement, the medium, the lights and the settings stay. Prepared
    /// outside the lock: a render of another node need not wait for it.
    fn smoke(
        &self,
        particles: &Arc<volterra_formats::ParticleSet>,
        input: &smoke::SmokeInput,
        s: &smoke::Settings,
    ) -> Result<Arc<smoke::prepare::Prepared>> {
        let addr = Arc::as_ptr(particles) as usize;
        let key = smoke::prepare::Prepared::key(input, s);
        if let Some((_, k, p)) = self.smoke.lock().unwrap().get(&addr) {
            if *k == key {
                return Ok(p.clone());
            }
        }
        let p = Arc::new(smoke::prepare::Prepared::new(input, s)?);
        self.smoke.lock().unwrap().insert(addr, (particles.clone(), key, p.clone()));
        Ok(p)
    }

    /// The automatic scales over node `node`'s series (see `series_scale`), where it is one
    /// and takes its scales over the series; None otherwise.
    fn series_scale(
        &self,
        scene: &Scene,
        node: usize,
        node_to_world: glam::DMat4,
        column: bool,
    ) -> Result<Option<Arc<series_scale::SeriesScale>>> {
        let desc = &scene.nodes()[node];
        let Some(series) = scene.series(node) else { return Ok(None) };
        if desc.scale_over != crate::scene::ScaleOver::Series || series.steps.len() < 2 {
            return Ok(None);
        }
        let key = (series as *const _ as usize, node, desc.color_by.clone(), node_to_world.to_cols_array().map(f64::to_bits), column);
        if let Some(s) = self.series.lock().unwrap().get(&key) {
            return Ok(Some(s.clone()));
        }
        let s = Arc::new(series_scale::of_particles(scene, node, desc.color_by.as_deref(), node_to_world, column)?);
        self.series.lock().unwrap().insert(key, s.clone());
        Ok(Some(s))
    }

    /// The volume on the GPU for `settings` with the volume placed by `node_to_world`: in
    /// bricks of at most `settings.brick` voxels holding what its segments read (their
    /// reach follows the step and the placement), kept while the volume, bricks and reach
    /// stay.
    fn gpu_volume(
        &self,
        volume: &Arc<Volume>,
        node_to_world: glam::DMat4,
        settings: &gpu_volume::Settings,
        limits: &Limits,
        source: &std::path::Path,
    ) -> Result<Arc<gpu_volume::Prepared>> {
        let index_to_world = crate::geometry::index_to_world(node_to_world, crate::geometry::affine_matrix(&volume.affine))?;
        let (_, reach) = gpu_volume::step_and_reach(index_to_world, settings);
        let (edge, key) = (settings.brick, Arc::as_ptr(volume) as usize);
        if let Some((_, at, p)) = self.gpu_volumes.lock().unwrap().get(&key) {
            if *at == (edge, reach, settings.voxels) {
                return Ok(p.clone());
            }
        }
        // The old upload goes before the new one is made.
        self.gpu_volumes.lock().unwrap().remove(&key);
        let gpu = gpu_volume::gpu::gpu()?;
        let p = Arc::new(gpu_volume::Prepared::new(gpu, volume, settings.voxels, edge, reach, limits, source)?);
        self.gpu_volumes.lock().unwrap().insert(key, (volume.clone(), (edge, reach, settings.voxels), p.clone()));
        Ok(p)
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

    /// The pair on its grid (`shear_warp::fusion`: the first's, refined where the second is
    /// finer), both resampled onto it where needed and prepared, kept while both volumes
    /// and the placement stay.
    fn fused_pair(
        &self,
        (first, first_to_world): (&Arc<Volume>, glam::DMat4),
        (second, second_to_world): (&Arc<Volume>, glam::DMat4),
        limits: &Limits,
    ) -> Result<FusedPreparation> {
        use shear_warp::fusion;
        let relative = (first_to_world.inverse() * second_to_world).to_cols_array().map(f64::to_bits);
        let key = (Arc::as_ptr(first) as usize, Arc::as_ptr(second) as usize, relative);
        if let Some((_, _, p)) = self.fused.lock().unwrap().get(&key) {
            return Ok(p.clone());
        }
        let grid = fusion::FusionGrid::of(first, first_to_world, second, second_to_world);
        let (on_grid, first_prepared) = if grid.is_refined() {
            let refined = Arc::new(fusion::refine(first, grid.factor, limits)?);
            (refined.clone(), Arc::new(shear_warp::Prepared::shared(refined, limits)?))
        } else {
            (first.clone(), self.shear_warp(first, limits)?)
        };
        let resampled = fusion::resample_onto(&on_grid, first_to_world, second, second_to_world, limits)?;
        let second_prepared = Arc::new(shear_warp::Prepared::shared(Arc::new(resampled), limits)?);
        let p = FusedPreparation { grid, first: first_prepared, second: second_prepared };
        self.fused.lock().unwrap().insert(key, (first.clone(), second.clone(), p.clone()));
        Ok(p)
    }

    fn terrain(
        &self,
        heights: &TerrainData,
        texture: Option<Arc<crate::scene::drape::Drape>>,
        node_to_world: glam::DMat4,
        span: Option<[f64; 2]>,
        limits: &Limits,
    ) -> Result<Arc<terrain::Prepared>> {
        let tex = texture.as_ref().map_or(0, |t| Arc::as_ptr(t) as usize);
        let key = (heights.address(), tex);
        let placement = node_to_world.to_cols_array().map(f64::to_bits);
        let mut map = self.terrain.lock().unwrap();
        if let Some((_, at, p)) = map.get(&key) {
            if *at == placement {
                return Ok(p.clone());
            }
        }
        // The prepared terrain holds the texture, so its address stays taken too.
        // The span is the view window's, fixed with the heights the key names.
        let p = Arc::new(terrain::Prepared::new(heights, texture, node_to_world, span, limits)?);
        map.insert(key, (heights.clone(), placement, p.clone()));
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
    // A terrain's heights as its renderer takes them (the GPU's: a GeoTIFF read row by row
    // into its textures, not held here as well); every other node's data held.
    let data = match settings {
        NodeSettings::Terrain(_) | NodeSettings::TerrainReference(_) => Loaded::Terrain(scene.terrain_data(node)?),
        _ => Loaded::Data(scene.data(node)?),
    };
    let texture = scene.texture(node)?;
    let load = t.elapsed().as_secs_f64();
    let mut prepare = 0.0;
    let node_to_world = scene.world_transform(node);
    let t = Instant::now();
    let mut frame = match (settings, data) {
        (NodeSettings::Reference(s), Loaded::Data(NodeData::Volume(vol))) => {
            let (tf, shading, crop) = (scene.classification(node)?, scene.shading(node), scene.crop_region(node));
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
        (NodeSettings::ShearWarp(s), Loaded::Data(NodeData::Volume(vol))) => {
            let prepared = timed(&mut prepare, || cache.shear_warp(&vol, scene.limits()))?;
            let (tf, shading, crop) = (scene.classification(node)?, scene.shading(node), scene.crop_region(node));
            let input = shear_warp::Input {
                prepared: &prepared,
                node_to_world,
                tf: &tf,
                blend: desc.blend,
                shading: shading.as_ref(),
                lights: &scene.file.lights,
                crop: &crop,
                second: None,
            };
            shear_warp::render(&input, &rays, s)?
        }
        (NodeSettings::GpuRaycast(s), Loaded::Data(NodeData::Volume(vol))) => {
            let prepared = timed(&mut prepare, || {
                // The device opened first: its driver's memory is then in use when the
                // textures are checked against the memory limit.
                gpu_volume::gpu::gpu()?;
                cache.gpu_volume(&vol, node_to_world, s, scene.limits(), &scene.source)
            })
            .with_context(|| format!("node '{}'", desc.name))?;
            // The frame's buffers on the GPU and read back (colour, depth, samples: 24 bytes a
            // pixel each side), against the memory limit.
            scene
                .limits()
                .check(&scene.source, "the GPU volume frame's buffers", &[(size.0 * size.1) as u64 * 48])
                .with_context(|| format!("node '{}'", desc.name))?;
            let (tf, shading, crop) = (scene.classification(node)?, scene.shading(node), scene.crop_region(node));
            let input = gpu_volume::Input {
                prepared: &prepared,
                node_to_world,
                tf: &tf,
                blend: desc.blend,
                shading: shading.as_ref(),
                lights: &scene.file.lights,
                crop: &crop,
            };
            gpu_volume::render(&input, &rays, s).with_context(|| format!("node '{}'", desc.name))?
        }
        (NodeSettings::Terrain(_) | NodeSettings::TerrainReference(_), Loaded::Terrain(heights)) => {
            let prepared = timed(&mut prepare, || {
                // The GPU opened first: where its memory is the host's, what its driver holds
                // (its compiled pipelines) is then in use when the textures are checked
                // against the memory limit.
                if matches!(settings, NodeSettings::Terrain(_)) {
                    terrain::gpu::gpu()?;
                }
                let p = cache.terrain(&heights, texture.clone(), node_to_world, scene.terrain_span(node), scene.limits())?;
                if matches!(settings, NodeSettings::Terrain(_)) {
                    p.check_gpu_upload(scene.limits())?;
                    p.prepare_gpu()?;
                }
                Ok(p)
            })?;
            let mut frame = match settings {
                NodeSettings::Terrain(s) => prepared.render(&scene.file.lights, &rays, s, scene.elevation_range(node))?,
                NodeSettings::TerrainReference(s) => {
                    prepared.render_reference(&scene.file.lights, &rays, &s.into(), scene.elevation_range(node))?
                }
                _ => unreachable!(),
            };
            if !prepared.grid.any_valid {
                frame
                    .stats
                    .notes
                    .push(format!("node '{}': the heightfield has no valid sample (every one is NoData): nothing to draw", desc.name));
            }
            // What the reader noted of the raster (an overview read for the memory limit,
            // degrees converted to metres) is said with the frame.
            frame.stats.notes.extend(scene.view_window_note(node).map(|n| format!("node '{}': {n}", desc.name)));
            frame.stats.notes.extend(heights.notes().iter().map(|n| format!("node '{}': {n}", desc.name)));
            // A colour-mapped drape gets its scalar bar in the PNG preview.
            if let (Some((colormap, range)), Some(path)) = (texture.as_ref().and_then(|t| t.scale), &desc.texture) {
                let title = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
                frame.scales.push(crate::colormap::ColourScale { title, colormap, range });
            }
            frame
        }
        (NodeSettings::Smoke(s), Loaded::Data(NodeData::Particles(particles))) => {
            // No c_ext given: a series takes the one of its densest step for every frame.
            let mut medium = medium()?.clone();
            let mut series_note = None;
            if medium.c_ext.is_none() {
                let scale = timed(&mut prepare, || cache.series_scale(scene, node, node_to_world, true))?;
                if let Some((sc, c_ext)) = scale.as_ref().and_then(|sc| Some((sc, sc.c_ext()?))) {
                    medium.c_ext = Some(c_ext);
                    let (column, step) = sc.column.expect("c_ext comes from a column");
                    series_note = Some(format!(
                        "node '{}': c_ext {c_ext:.6e} for every step, chosen from the series' densest step ({} of {}: optical depth {} through its \
                         densest column, {column:.6e} mass per area); scale_over = \"step\" chooses it per step",
                        desc.name,
                        step + 1,
                        sc.steps,
                        smoke::extinction::TARGET_DEPTH
                    ));
                }
            }
            let input = smoke::SmokeInput {
                particles: &particles,
                node_to_world,
                medium: &medium,
                lights: &scene.file.lights,
                limits: *scene.limits(),
            };
            let prepared = timed(&mut prepare, || cache.smoke(&particles, &input, s)).with_context(|| format!("node '{}'", desc.name))?;
            let mut frame = prepared.render(&rays, s).with_context(|| format!("node '{}'", desc.name))?;
            frame.stats.notes.extend(series_note);
            frame.stats.notes.extend(particle_notes(&particles, &desc.name));
            frame
        }
        (NodeSettings::Points(s), Loaded::Data(NodeData::Particles(particles))) => {
            // No colour range given: a series is coloured over its array's range over all
            // its steps.
            let mut range = desc.color_range;
            let mut series_note = None;
            if range.is_none() {
                let scale = timed(&mut prepare, || cache.series_scale(scene, node, node_to_world, false))?;
                if let Some((sc, (array, r))) = scale.as_ref().and_then(|sc| Some((sc, sc.colour.clone()?))) {
                    range = Some(r);
                    series_note = Some(format!(
                        "node '{}': colours over '{array}' {} … {} across the series' {} steps; scale_over = \"step\" colours each step over its own range",
                        desc.name, r[0], r[1], sc.steps
                    ));
                }
            }
            let spacing = s.radius_by_spacing().then(|| timed(&mut prepare, || Ok(cache.spacing(&particles)))).transpose()?;
            // The GPU's buffers against the memory limit (in host memory on lavapipe): each
            // particle's instance or splat records (4.7 tiles a splat, 32 bytes each, at most
            // 128 MiB a pass), the targets and their read-back, the driver's working memory.
            let gpu_bytes = match s.style {
                points::PointStyle::Spheres => particles.len() as u64 * 64,
                points::PointStyle::Splats => (particles.len() as u64 * 160).min(128 << 20),
            } + (size.0 * size.1) as u64 * 48
                + crate::gpu::driver_working_memory();
            scene
                .limits()
                .check(&scene.source, "the points' GPU buffers", &[gpu_bytes])
                .with_context(|| format!("node '{}'", desc.name))?;
            let input = points::PointsInput {
                particles: &particles,
                node_to_world,
                color_by: desc.color_by.as_deref(),
                range,
                spacing: spacing.as_deref().map(|v| &v[..]),
            };
            let mut frame = points::render(&input, &rays, s).with_context(|| format!("node '{}'", desc.name))?;
            frame.stats.notes.extend(series_note);
            frame.stats.notes.extend(particle_notes(&particles, &desc.name));
            frame
        }
        _ => unreachable!("the scene checked that the node's data is of its kind and its renderer draws that kind"),
    };
    let render = t.elapsed().as_secs_f64() - prepare;
    frame.stats.nodes.push(NodeTime { node: desc.name.clone(), renderer: frame.stats.renderer.clone(), load, prepare, render });
    Ok(Some(frame))
}

/// What the reader noted of a node's particles (those left out for positions that are
/// not finite, defaults filled in), said with the frame.
fn particle_notes<'a>(particles: &'a volterra_formats::ParticleSet, node: &'a str) -> impl Iterator<Item = String> + 'a {
    particles.notes.iter().map(move |n| format!("node '{node}': {n}"))
}

/// A node's data as its renderer takes it.
enum Loaded {
    Data(NodeData),
    Terrain(TerrainData),
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
    let groups = fusion_groups(scene).with_context(|| scene.source.display().to_string())?;
    let mut layers = Vec::new();
    for i in 0..scene.nodes().len() {
        if groups.iter().any(|g| g.contains(&i)) {
            continue;
        }
        if let Some(f) = render_node_with(scene, i, camera, size, cache).with_context(|| scene.source.display().to_string())? {
            layers.push(f);
        }
    }
    for g in &groups {
        layers.push(render_fused_group(scene, g, camera, size, cache).with_context(|| scene.source.display().to_string())?);
    }
    if layers.len() == 1 {
        return Ok(layers.pop().unwrap());
    }
    Ok(Frame::composite(size.0, size.1, &layers))
}

/// The volume nodes whose boxes overlap in the world, in groups of two or more: each group
/// is drawn as one layer, its volumes fused sample by sample along every ray. Layers
/// sorted per pixel by depth cannot composite two translucent volumes that overlap (one
/// is wholly in front of the other at each pixel: a seam where the order flips). Visible
/// volumes drawn by `reference` or `shear-warp` in composite blending take part; MIP
/// volumes stay layers.
pub fn fusion_groups(scene: &Scene) -> Result<Vec<Vec<usize>>> {
    let mut boxes: Vec<(usize, glam::DVec3, glam::DVec3)> = Vec::new();
    for (i, n) in scene.nodes().iter().enumerate() {
        let fusable =
            matches!(scene.node_settings(i), Some(NodeSettings::Reference(_) | NodeSettings::ShearWarp(_) | NodeSettings::GpuRaycast(_)));
        if !n.visible || !fusable || n.blend != crate::scene::BlendMode::Composite {
            continue;
        }
        if let Some((lo, hi)) = crate::scene::auto::data_bounds(&scene.data(i)?, scene.world_transform(i)) {
            boxes.push((i, lo, hi));
        }
    }
    // Union of overlapping pairs (few volumes: pairwise is fine).
    let mut group: Vec<usize> = (0..boxes.len()).collect();
    fn root(g: &mut [usize], mut k: usize) -> usize {
        while g[k] != k {
            g[k] = g[g[k]];
            k = g[k];
        }
        k
    }
    for a in 0..boxes.len() {
        for b in a + 1..boxes.len() {
            let overlap = (0..3).all(|c| boxes[a].1[c] < boxes[b].2[c] && boxes[b].1[c] < boxes[a].2[c]);
            if overlap {
                let (ra, rb) = (root(&mut group, a), root(&mut group, b));
                group[ra.max(rb)] = ra.min(rb);
            }
        }
    }
    let mut groups: Vec<Vec<usize>> = Vec::new();
    for k in 0..boxes.len() {
        let r = root(&mut group, k);
        let members: Vec<usize> = (0..boxes.len()).filter(|&j| root(&mut group, j) == r).map(|j| boxes[j].0).collect();
        if r == k && members.len() > 1 {
            groups.push(members);
        }
    }
    Ok(groups)
}

/// Which of two shear-warp volume nodes is the first (whose grid both are drawn on) and
/// which the second, where shear-warp can fuse them; else why not. Shear-warp fuses two
/// volumes when the second's box of voxel centres lies within the first's (half a voxel of
/// slack; the first listed is tried first), neither is cropped, and the second is
/// transparent at its lowest value (what it takes outside its box).
pub fn shear_warp_pair(scene: &Scene, nodes: &[usize]) -> Result<(usize, usize), String> {
    let [a, b] = nodes else { return Err(format!("{} volumes (it fuses two)", nodes.len())) };
    let named = |i: usize| scene.nodes()[i].name.clone();
    for &i in nodes {
        if !matches!(scene.node_settings(i), Some(NodeSettings::ShearWarp(_))) {
            return Err(format!("'{}' names another renderer", named(i)));
        }
        if !scene.crop_region(i).is_empty() {
            return Err(format!("'{}' is cropped", named(i)));
        }
    }
    let inside = |first: usize, second: usize| -> Result<bool, String> {
        let volume = |i: usize| scene.volume(i).map_err(|e| format!("{e:#}"));
        let (v1, v2) = (volume(first)?, volume(second)?);
        let to1 = (scene.world_transform(first) * crate::geometry::affine_matrix(&v1.affine)).inverse()
            * scene.world_transform(second)
            * crate::geometry::affine_matrix(&v2.affine);
        Ok((0..8).all(|c| {
            let ijk = glam::DVec3::from(std::array::from_fn::<f64, 3, _>(|k| if c >> k & 1 == 0 { 0.0 } else { (v2.dims[k] - 1) as f64 }));
            let q = to1.transform_point3(ijk);
            (0..3).all(|k| q[k] >= -0.5 && q[k] <= v1.dims[k] as f64 - 0.5)
        }))
    };
    let (first, second) = if inside(*a, *b)? {
        (*a, *b)
    } else if inside(*b, *a)? {
        (*b, *a)
    } else {
        return Err("neither volume lies inside the other".into());
    };
    let tf = scene.classification(second).map_err(|e| format!("{e:#}"))?;
    let lowest = scene.value_stats(second).map_err(|e| format!("{e:#}"))?.min;
    if tf.opacity(lowest) > 0.0 {
        return Err(format!("'{}' is not transparent at its lowest value", named(second)));
    }
    // The grid both are sampled on (the first's, refined to the second's voxel size where
    // that is finer) must fit the memory limit; else the reference, on each volume's own
    // grid, draws them.
    let (v1, v2) = (scene.volume(first).map_err(|e| format!("{e:#}"))?, scene.volume(second).map_err(|e| format!("{e:#}"))?);
    let grid = shear_warp::fusion::FusionGrid::of(&v1, scene.world_transform(first), &v2, scene.world_transform(second));
    if let Err(e) = scene.limits().check(&scene.source, "the fused pair's grid", &[grid.voxels(), grid.bytes_per_voxel()]) {
        let [dx, dy, dz] = grid.dims;
        return Err(format!(
            "sampled at the voxel size of '{}', the pair's grid of {dx}×{dy}×{dz} voxels does not fit: {}",
            named(second),
            e.message
        ));
    }
    Ok((first, second))
}

/// The group `nodes`, every one naming `gpu-raycast` (`settings`), fused on the GPU, each
/// volume on its own grid: Ok(Err(why)) where the GPU cannot fuse them (more than two, a
/// volume in several bricks).
fn render_fused_on_gpu(
    scene: &Scene,
    nodes: &[usize],
    settings: &[&gpu_volume::Settings],
    camera: &Camera,
    size: (usize, usize),
    cache: &RenderCache,
) -> Result<Result<Frame, String>> {
    if nodes.len() != 2 {
        return Ok(Err(format!("{} volumes (the GPU fuses two)", nodes.len())));
    }
    // The finest step and latest termination of the two; skipping where both skip.
    let merged = gpu_volume::Settings {
        step: settings.iter().map(|s| s.step).fold(f64::INFINITY, f64::min),
        termination: settings.iter().map(|s| s.termination).fold(0.0, f64::max),
        skipping: settings.iter().all(|s| s.skipping),
        brick: settings[0].brick,
        voxels: settings[0].voxels,
    };
    let t = Instant::now();
    let mut owned = Vec::with_capacity(2);
    for &i in nodes {
        owned.push((scene.volume(i)?, scene.classification(i)?, scene.shading(i), scene.crop_region(i), scene.world_transform(i)));
    }
    let load = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let mut prepared = Vec::with_capacity(2);
    for (volume, _, _, _, node_to_world) in &owned {
        prepared.push(cache.gpu_volume(volume, *node_to_world, &merged, scene.limits(), &scene.source)?);
    }
    let prepare = t.elapsed().as_secs_f64();
    let inputs: Vec<gpu_volume::Input> = owned
        .iter()
        .zip(&prepared)
        .map(|((_, tf, shading, crop, node_to_world), p)| gpu_volume::Input {
            prepared: p,
            node_to_world: *node_to_world,
            tf,
            blend: crate::scene::BlendMode::Composite,
            shading: shading.as_ref(),
            lights: &scene.file.lights,
            crop,
        })
        .collect();
    if let Err(why) = gpu_volume::can_fuse(&inputs) {
        return Ok(Err(why));
    }
    let t = Instant::now();
    let mut frame = gpu_volume::render_fused(&inputs, &camera.rays(size.0, size.1), &merged)?;
    let names: Vec<&str> = nodes.iter().map(|&i| scene.nodes()[i].name.as_str()).collect();
    frame.stats.notes.push(format!("volumes {} overlap: fused along each ray on the GPU, each sampled on its own grid", names.join(", ")));
    frame.stats.nodes.push(NodeTime {
        node: names.join("+"),
        renderer: format!("{} (fused)", gpu_volume::RENDERER.name),
        load,
        prepare,
        render: t.elapsed().as_secs_f64(),
    });
    Ok(Ok(frame))
}

/// Draws the volume nodes `nodes` (a group from [`fusion_groups`]) fused along every ray:
/// on the GPU where both name `gpu-raycast` and it can (`render_fused_on_gpu`), by
/// shear-warp where the nodes name it and it can fuse them (`shear_warp_pair`: the
/// second resampled onto the first's grid, cached in `cache`), else by the reference ray
/// caster at the finest step and latest termination the nodes' own reference settings
/// give, or — where a node names shear-warp — at the reference's preview step (0.25
/// voxel), with the reason in the frame's notes.
pub fn render_fused_group(scene: &Scene, nodes: &[usize], camera: &Camera, size: (usize, usize), cache: &RenderCache) -> Result<Frame> {
    let names: Vec<&str> = nodes.iter().map(|&i| scene.nodes()[i].name.as_str()).collect();
    let gpu_settings: Vec<&gpu_volume::Settings> = nodes
        .iter()
        .filter_map(|&i| match scene.node_settings(i) {
            Some(NodeSettings::GpuRaycast(s)) => Some(s),
            _ => None,
        })
        .collect();
    let mut gpu_refusal = None;
    if gpu_settings.len() == nodes.len() {
        match render_fused_on_gpu(scene, nodes, &gpu_settings, camera, size, cache) {
            Ok(Ok(frame)) => return Ok(frame),
            Ok(Err(why)) => gpu_refusal = Some(why),
            Err(e) => return Err(e),
        }
    }
    let pair = shear_warp_pair(scene, nodes);
    if let Ok((first, second)) = pair {
        let t = Instant::now();
        let (v1, v2) = (scene.volume(first)?, scene.volume(second)?);
        let load = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let (m1, m2) = (scene.world_transform(first), scene.world_transform(second));
        let pair = cache.fused_pair((&v1, m1), (&v2, m2), scene.limits())?;
        let prepare = t.elapsed().as_secs_f64();
        let (tf1, tf2) = (scene.classification(first)?, scene.classification(second)?);
        let (shading1, shading2) = (scene.shading(first), scene.shading(second));
        let Some(NodeSettings::ShearWarp(settings)) = scene.node_settings(first) else { unreachable!("shear_warp_pair checked") };
        let input = shear_warp::Input {
            prepared: &pair.first,
            node_to_world: m1,
            tf: &tf1,
            blend: crate::scene::BlendMode::Composite,
            shading: shading1.as_ref(),
            lights: &scene.file.lights,
            crop: &[],
            second: Some(shear_warp::fusion::Second { prepared: &pair.second, tf: &tf2, shading: shading2.as_ref() }),
        };
        let t = Instant::now();
        let mut frame = shear_warp::render(&input, &camera.rays(size.0, size.1), settings)?;
        let (inner, outer) = (&scene.nodes()[second].name, &scene.nodes()[first].name);
        frame.stats.notes.push(if pair.grid.is_refined() {
            let [fx, fy, fz] = pair.grid.factor;
            let [dx, dy, dz] = pair.grid.dims;
            format!(
                "volumes {} overlap: fused along each ray by shear-warp on the grid of '{outer}' refined {fx}×{fy}×{fz} \
                 ({dx}×{dy}×{dz} voxels) to the voxel size of '{inner}', so neither loses detail",
                names.join(", ")
            )
        } else {
            format!(
                "volumes {} overlap: fused along each ray by shear-warp, '{inner}' resampled onto the grid of '{outer}'",
                names.join(", ")
            )
        });
        frame.stats.nodes.push(NodeTime {
            node: names.join("+"),
            renderer: format!("{} (fused)", shear_warp::RENDERER.name),
            load,
            prepare,
            render: t.elapsed().as_secs_f64(),
        });
        return Ok(frame);
    }
    let t = Instant::now();
    let mut owned = Vec::with_capacity(nodes.len());
    for &i in nodes {
        owned.push((scene.volume(i)?, scene.classification(i)?, scene.shading(i), scene.crop_region(i), scene.world_transform(i)));
    }
    let load = t.elapsed().as_secs_f64();
    let inputs: Vec<reference_volume::VolumeInput> = owned
        .iter()
        .zip(nodes)
        .map(|((volume, tf, shading, crop, node_to_world), &i)| reference_volume::VolumeInput {
            volume,
            node_to_world: *node_to_world,
            tf,
            blend: scene.nodes()[i].blend,
            shading: shading.as_ref(),
            lights: &scene.file.lights,
            crop,
        })
        .collect();
    let mut settings: Option<reference_volume::Settings> = None;
    let mut shear_warp_nodes = Vec::new();
    for &i in nodes {
        match scene.node_settings(i) {
            Some(NodeSettings::Reference(s)) => {
                let merged = settings.get_or_insert_with(|| s.clone());
                merged.step = merged.step.min(s.step);
                merged.termination = merged.termination.max(s.termination);
            }
            _ => shear_warp_nodes.push(scene.nodes()[i].name.clone()),
        }
    }
    if !shear_warp_nodes.is_empty() {
        settings = Some(reference_volume::Settings { step: settings.map_or(0.25, |s| s.step.min(0.25)), ..Default::default() });
    }
    let settings = settings.unwrap_or_default();
    let t = Instant::now();
    let mut frame = reference_volume::render_fused(&inputs, &camera.rays(size.0, size.1), &settings)?;
    if !shear_warp_nodes.is_empty() {
        let why = match gpu_refusal {
            Some(why) => format!("not on the GPU: {why}"),
            None => format!("not by shear-warp: {}", pair.err().unwrap_or_default()),
        };
        frame.stats.notes.push(format!(
            "volumes {} overlap: fused along each ray by the reference ray caster at step {} voxel ({why})",
            names.join(", "),
            settings.step,
        ));
    }
    frame.stats.nodes.push(NodeTime {
        node: names.join("+"),
        renderer: format!("{} (fused)", reference_volume::RENDERER.name),
        load,
        prepare: 0.0,
        render: t.elapsed().as_secs_f64(),
    });
    Ok(frame)
}
