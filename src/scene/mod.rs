//! The scene graph and the scene file (TOML; documented in docs/scene-format.md).
//!
//! A scene is parsed once into plain objects ([`SceneFile`]), checked, and then holds its
//! data lazily: a node's file is read (and cached) only when a renderer asks for it, so a
//! render loads exactly the nodes it draws.
//!
//! Here: `Scene` itself (loading and checking, cameras, time, views); `file` the scene
//! file's plain objects, `parse` reading its text (one-line errors, `--set` overrides),
//! `data` the nodes' data read lazily.

pub mod animation;
pub mod auto;
pub mod camera;
pub mod crop;
mod data;
pub mod drape;
mod file;
pub mod measurement;
mod parse;
pub mod presets;
pub mod transfer;
pub mod view_window;

pub use camera::{Camera, Ray, RayGenerator};
pub use crop::{ClipPlane, CropBox, HalfSpace};
pub use data::{NodeData, TerrainData};
pub use file::*;
pub use measurement::{Measurement, MeasurementKind, SliceOverlay, SlicePlane, SliceViews};
pub use parse::apply_overrides;
use parse::*;
pub use transfer::{TransferFunction, VolumeShading};

use crate::catalog::{self, NodeSettings, RendererDecl};
use crate::shared_error::SharedError;
use anyhow::{anyhow, bail, Context, Result};
use glam::{DMat4, DVec3};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};
use volterra_formats::geotiff::HeldBytes;
use volterra_formats::geotiff_rows::GeoTiffRows;
use volterra_formats::heightfield::GridGeoref;
use volterra_formats::png_height::PngHeightOptions;
use volterra_formats::series::{self, TimeSeries};
use volterra_formats::{Dataset, Heightfield, Limits, LoadOptions, ParticleArrayNames, ParticleSet, Volume};

pub struct Scene {
    pub file: SceneFile,
    /// Directory the scene's relative paths start from.
    pub base_dir: PathBuf,
    /// Scene file path, for messages.
    pub source: PathBuf,
    world: Vec<DMat4>,
    /// Each node's renderer and its checked settings (None for groups).
    renderers: Vec<Option<(&'static RendererDecl, NodeSettings)>>,
    data: Vec<OnceLock<Result<NodeData, SharedError>>>,
    textures: Vec<OnceLock<Result<Arc<drape::Drape>, SharedError>>>,
    /// A heightfield node's GeoTIFF opened to be read row by row (see `terrain_data`).
    height_rows: Vec<OnceLock<Result<Arc<GeoTiffRows>, SharedError>>>,
    /// A volume node's value statistics, for its preset (computed on first use).
    stats: Vec<OnceLock<Arc<presets::ValueStats>>>,
    /// Each node's time series, where its `file` names one (found at load, no data read).
    series: Vec<Option<Arc<TimeSeries>>>,
    /// The animation time drawn (None: a still; series nodes draw their first step, a 4-D
    /// NIfTI its `volume_index`).
    time: Option<f64>,
    /// The memory limits handed to every reader of the scene's data and to every renderer's
    /// preparation (`--max-memory`).
    limits: Limits,
    /// Heightfield nodes read only where the renders' cameras see them (`with_views`).
    view_windows: Vec<Option<Arc<view_window::ViewWindow>>>,
}

impl Scene {
    /// Reads, checks and resolves a scene file; no data file is read yet.
    pub fn load(path: &Path, overrides: &[String]) -> Result<Scene> {
        let text = std::fs::read_to_string(path).map_err(|e| anyhow!("{}: cannot read scene file: {e}", path.display()))?;
        // Parse the text as written first, so errors point at its lines.
        check_node_keys(&text, path)?;
        let _: SceneFile = parse_toml(&text, path)?;
        let lines = SettingLines::of(&text);
        let file: SceneFile = if overrides.is_empty() {
            parse_toml(&text, path)?
        } else {
            let mut doc: toml::Table = parse_toml(&text, path)?;
            apply_overrides(&mut doc, overrides)?;
            doc.try_into().map_err(|e: toml::de::Error| anyhow!("{}: after --set: {}", path.display(), one_line(e.message())))?
        };
        let base_dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
        Scene::from_file_with_lines(file, base_dir, path.to_path_buf(), &lines, None)
    }

    /// A scene from parsed objects (errors name no lines).
    pub fn from_file(file: SceneFile, base_dir: PathBuf, source: PathBuf) -> Result<Scene> {
        Scene::from_file_with_lines(file, base_dir, source, &SettingLines::default(), None)
    }

    fn from_file_with_lines(
        file: SceneFile,
        base_dir: PathBuf,
        source: PathBuf,
        lines: &SettingLines,
        known_series: Option<&HashMap<PathBuf, Option<Arc<TimeSeries>>>>,
    ) -> Result<Scene> {
        let src = source.display().to_string();
        file.camera.validate().map_err(|m| anyhow!("{src}: {m}"))?;
        if !(file.image.exposure.is_finite() && file.image.exposure.abs() <= 30.0) {
            bail!("{src}: image exposure {} must be a number of stops in -30..30", file.image.exposure);
        }
        if file.image.width == 0 || file.image.height == 0 || file.image.width > 16384 || file.image.height > 16384 {
            bail!("{src}: image size {}×{} must be between 1 and 16384", file.image.width, file.image.height);
        }
        let mut index: HashMap<&str, usize> = HashMap::new();
        for (i, n) in file.nodes.iter().enumerate() {
            if index.insert(n.name.as_str(), i).is_some() {
                bail!("{src}: two nodes are named '{}'", n.name);
            }
            if n.kind != NodeKind::Group && n.file.is_none() {
                bail!("{src}: node '{}' ({:?}) needs a file", n.name, n.kind);
            }
            if let Some(f) = &n.file {
                let p = base_dir.join(f);
                if !p.exists() && !series::is_series_name(&p) {
                    bail!("{src}: node '{}': data file {} not found", n.name, p.display());
                }
            }
            if let Some(tf) = &n.transfer_function {
                tf.validate().map_err(|m| anyhow!("{src}: node '{}': {m}", n.name))?;
            }
            if n.kind != NodeKind::Volume && (n.preset.is_some() || n.modality.is_some() || n.preset_shift != 0.0) {
                bail!("{src}: node '{}': preset, preset_shift and modality apply to volume nodes only", n.name);
            }
            if let Some(p) = &n.preset {
                presets::Preset::from_name(p).map_err(|m| anyhow!("{src}: node '{}': {m}", n.name))?;
                if n.transfer_function.is_some() {
                    bail!("{src}: node '{}': give a transfer_function or a preset, not both", n.name);
                }
            }
            if n.opacity_scale != 1.0 && n.kind != NodeKind::Volume {
                bail!("{src}: node '{}': opacity_scale applies to volume nodes only", n.name);
            }
            if !(n.opacity_scale.is_finite() && (0.0..=1000.0).contains(&n.opacity_scale)) {
                bail!("{src}: node '{}': opacity_scale {} must be between 0 and 1000", n.name, n.opacity_scale);
            }
            if !n.preset_shift.is_finite() {
                bail!("{src}: node '{}': preset_shift must be finite", n.name);
            }
            if let Some(m) = &n.modality {
                if presets::modality_code(m).is_none() {
                    let known: Vec<String> = presets::MODALITIES
                        .iter()
                        .map(|(code, names)| if names.is_empty() { code.to_string() } else { format!("{code} ({})", names.join(", ")) })
                        .collect();
                    bail!("{src}: node '{}': unknown modality '{m}' (known: {})", n.name, known.join(", "));
                }
            }
            if let Some(s) = &n.shading {
                if n.kind != NodeKind::Volume {
                    bail!("{src}: node '{}': shading applies to volume nodes only", n.name);
                }
                s.validate().map_err(|m| anyhow!("{src}: node '{}': {m}", n.name))?;
            }
            if let Some(e) = n.extent {
                if n.kind != NodeKind::Heightfield {
                    bail!("{src}: node '{}': extent applies to heightfield nodes only", n.name);
                }
                if !e.iter().all(|v| v.is_finite()) || e[0] >= e[2] || e[1] >= e[3] {
                    bail!("{src}: node '{}': extent {e:?} must be [west, south, east, north], west < east, south < north", n.name);
                }
            }
            if n.kind != NodeKind::Heightfield && (n.texture.is_some() || n.texture_colormap.is_some() || n.texture_range.is_some()) {
                bail!("{src}: node '{}': texture, texture_colormap and texture_range apply to heightfield nodes only", n.name);
            }
            if n.texture.is_none() && (n.texture_colormap.is_some() || n.texture_range.is_some()) {
                bail!("{src}: node '{}': texture_colormap and texture_range colour a texture, and the node has none", n.name);
            }
            if let Some(c) = &n.texture_colormap {
                if crate::colormap::Colormap::from_name(c).is_none() {
                    let names: Vec<&str> = crate::colormap::Colormap::ALL.iter().map(|c| c.name()).collect();
                    bail!("{src}: node '{}': unknown texture_colormap '{c}' (known: {})", n.name, names.join(", "));
                }
            }
            if let Some([lo, hi]) = n.texture_range {
                if !(lo.is_finite() && hi.is_finite() && lo < hi) {
                    bail!("{src}: node '{}': texture_range [{lo}, {hi}] must be two finite values, low < high", n.name);
                }
            }
            if let Some([lo, hi]) = n.elevation_range {
                if n.kind != NodeKind::Heightfield {
                    bail!("{src}: node '{}': elevation_range applies to heightfield nodes only", n.name);
                }
                if !(lo.is_finite() && hi.is_finite() && lo < hi) {
                    bail!("{src}: node '{}': elevation_range [{lo}, {hi}] must be two finite values, low < high", n.name);
                }
            }
            if n.kind != NodeKind::Particles && (n.color_by.is_some() || n.color_range.is_some()) {
                bail!("{src}: node '{}': color_by and color_range apply to particle nodes only", n.name);
            }
            if n.scale_over != ScaleOver::Series && n.kind != NodeKind::Particles {
                bail!("{src}: node '{}': scale_over applies to particle nodes only", n.name);
            }
            if let Some([lo, hi]) = n.color_range {
                if !(lo.is_finite() && hi.is_finite() && lo < hi) {
                    bail!("{src}: node '{}': color_range [{lo}, {hi}] must be two finite values, the first smaller", n.name);
                }
            }
            if n.kind != NodeKind::Volume && (n.crop.is_some() || !n.clip.is_empty()) {
                bail!("{src}: node '{}': crop and clip apply to volume nodes only", n.name);
            }
            if let Some(c) = &n.crop {
                c.validate().map_err(|m| anyhow!("{src}: node '{}': {m}", n.name))?;
            }
            for c in &n.clip {
                c.validate().map_err(|m| anyhow!("{src}: node '{}': {m}", n.name))?;
            }
        }
        // Each node's renderer and settings, checked before any data file is read.
        let mut renderers = Vec::with_capacity(file.nodes.len());
        for n in &file.nodes {
            let decl = catalog::resolve(n.kind, n.renderer.as_deref(), &n.settings)
                .map_err(|m| anyhow!("{src}:{}: node '{}': {m}", lines.at(&n.name, None), n.name))?;
            renderers.push(match decl {
                None => None,
                Some(d) => Some((
                    d,
                    (d.parse)(&n.settings)
                        .map_err(|e| anyhow!("{src}:{}: node '{}': {} {e}", lines.at(&n.name, Some(&e.key)), n.name, d.name))?,
                )),
            });
        }
        for (k, m) in file.measurements.iter().enumerate() {
            let node = index.get(m.node.as_str()).ok_or_else(|| anyhow!("{src}: measurement {}: no node named '{}'", k + 1, m.node))?;
            if m.plane.is_some() && file.nodes[*node].kind != NodeKind::Volume {
                bail!("{src}: measurement {}: node '{}' is not a volume (slices are a volume's)", k + 1, m.node);
            }
            m.validate().map_err(|e| anyhow!("{src}: measurement {}: {e}", k + 1))?;
        }
        if let Some(v) = &file.slices {
            for name in std::iter::once(&v.node).chain(v.overlay.as_ref().map(|o| &o.node)) {
                let node = index.get(name.as_str()).ok_or_else(|| anyhow!("{src}: slices: no node named '{name}'"))?;
                if file.nodes[*node].kind != NodeKind::Volume {
                    bail!("{src}: slices: node '{name}' is not a volume");
                }
            }
            v.validate().map_err(|e| anyhow!("{src}: slices: {e}"))?;
        }
        if let Some(w) = &file.walk {
            let node = index.get(w.node.as_str()).ok_or_else(|| anyhow!("{src}: walk: no node named '{}'", w.node))?;
            if file.nodes[*node].kind != NodeKind::Heightfield {
                bail!("{src}: walk: node '{}' is not a heightfield", w.node);
            }
            if !(w.eye_height.is_finite() && w.eye_height >= 0.0) {
                bail!("{src}: walk: eye_height {} must be a non-negative number of metres", w.eye_height);
            }
        }
        if let Some(o) = &file.orbit {
            o.validate().map_err(|m| anyhow!("{src}: {m}"))?;
            if !file.keyframes.is_empty() {
                bail!("{src}: give [[keyframe]]s or an [orbit], not both");
            }
        }
        for (k, key) in file.keyframes.iter().enumerate() {
            let cam = Camera { position: key.position, focal_point: key.focal_point, ..file.camera.clone() };
            cam.validate().map_err(|m| anyhow!("{src}: keyframe {}: {m}", k + 1))?;
        }
        // World transforms, parents first; a cycle is an error.
        let mut world: Vec<Option<DMat4>> = vec![None; file.nodes.len()];
        for i in 0..file.nodes.len() {
            let mut chain = vec![i];
            let mut cur = i;
            while let Some(p) = &file.nodes[cur].parent {
                let pi =
                    *index.get(p.as_str()).ok_or_else(|| anyhow!("{src}: node '{}': parent '{p}' does not exist", file.nodes[cur].name))?;
                if chain.contains(&pi) {
                    bail!("{src}: node '{}': parents form a cycle", file.nodes[i].name);
                }
                chain.push(pi);
                cur = pi;
            }
            let mut m = DMat4::IDENTITY;
            for &c in chain.iter().rev() {
                let local = file.nodes[c].transform.to_mat4().with_context(|| format!("{src}: node '{}'", file.nodes[c].name))?;
                m *= local;
            }
            world[i] = Some(m);
        }
        // Time series, found from their names (a directory listing, a collection's XML or
        // a NIfTI header): no data is read.
        let mut found = Vec::with_capacity(file.nodes.len());
        for n in &file.nodes {
            let s = match (&n.file, known_series) {
                (None, _) => None,
                (Some(f), Some(known)) if known.contains_key(f) => known[f].clone(),
                (Some(f), _) => series::discover(&base_dir.join(f)).map_err(|e| anyhow!("{src}: node '{}': {e}", n.name))?.map(Arc::new),
            };
            if s.is_some() && n.kind == NodeKind::Heightfield {
                bail!("{src}: node '{}': a heightfield cannot be a time series", n.name);
            }
            found.push(s);
        }
        let n = file.nodes.len();
        Ok(Scene {
            file,
            base_dir,
            source,
            world: world.into_iter().map(Option::unwrap).collect(),
            renderers,
            data: (0..n).map(|_| OnceLock::new()).collect(),
            textures: (0..n).map(|_| OnceLock::new()).collect(),
            height_rows: (0..n).map(|_| OnceLock::new()).collect(),
            stats: (0..n).map(|_| OnceLock::new()).collect(),
            series: found,
            time: None,
            limits: Limits::default(),
            view_windows: vec![None; n],
        })
    }

    /// Node `node`'s time series, if its file names one.
    pub fn series(&self, node: usize) -> Option<&TimeSeries> {
        self.series[node].as_deref()
    }

    /// The times of every series in the scene, merged and sorted (empty: none).
    pub fn timeline(&self) -> Vec<f64> {
        let mut t: Vec<f64> = self.series.iter().flatten().flat_map(|s| s.times()).collect();
        t.sort_by(f64::total_cmp);
        t.dedup();
        t
    }

    /// The animation time this scene draws (None: a still).
    pub fn time(&self) -> Option<f64> {
        self.time
    }

    /// The step of node `node`'s series drawn now (None: the node is no series).
    pub fn step(&self, node: usize) -> Option<usize> {
        let s = self.series[node].as_ref()?;
        match self.time {
            Some(t) => Some(s.step_at(t)),
            // A still draws a 4-D NIfTI's `volume_index` (as before series), others their
            // first step.
            None => Some(if s.steps[0].volume_index.is_some() { self.file.nodes[node].volume_index.min(s.steps.len() - 1) } else { 0 }),
        }
    }

    /// This scene at animation time `t`: each series node draws its step at `t` (the
    /// last at or before it); data already read is kept for every other node and for
    /// series nodes whose step did not change. Dropping the old scene (and
    /// `RenderCache::keep_only_for` the new one) frees the steps no longer drawn, so an
    /// animation holds the step of each series it draws.
    pub fn at_time(&self, t: f64) -> Scene {
        let n = self.file.nodes.len();
        let next = Scene {
            file: self.file.clone(),
            base_dir: self.base_dir.clone(),
            source: self.source.clone(),
            world: self.world.clone(),
            renderers: self.renderers.clone(),
            data: (0..n).map(|_| OnceLock::new()).collect(),
            textures: (0..n).map(|_| OnceLock::new()).collect(),
            height_rows: (0..n).map(|_| OnceLock::new()).collect(),
            stats: (0..n).map(|_| OnceLock::new()).collect(),
            series: self.series.clone(),
            time: Some(t),
            limits: self.limits,
            view_windows: self.view_windows.clone(),
        };
        for i in 0..n {
            let same_step = self.step(i) == next.step(i);
            self.carry_over(i, &next, i, same_step, true);
        }
        next
    }

    /// Hands what node `from` has read to node `to` of `next`: its data and value statistics
    /// when `same_data`, its texture when `same_texture`.
    fn carry_over(&self, from: usize, next: &Scene, to: usize, same_data: bool, same_texture: bool) {
        if let (true, Some(d)) = (same_data, self.data[from].get()) {
            let _ = next.data[to].set(d.clone());
        }
        if let (true, Some(r)) = (same_data, self.height_rows[from].get()) {
            let _ = next.height_rows[to].set(r.clone());
        }
        if let (true, Some(s)) = (same_data, self.stats[from].get()) {
            let _ = next.stats[to].set(s.clone());
        }
        if let (true, Some(t)) = (same_texture, self.textures[from].get()) {
            let _ = next.textures[to].set(t.clone());
        }
    }

    /// The scene with `limits` for everything it reads and prepares from now on.
    pub fn with_limits(mut self, limits: Limits) -> Scene {
        self.limits = limits;
        self
    }

    pub fn limits(&self) -> &Limits {
        &self.limits
    }

    pub fn nodes(&self) -> &[NodeDesc] {
        &self.file.nodes
    }

    /// The renderer that draws the node (None for groups).
    pub fn renderer(&self, node: usize) -> Option<&'static RendererDecl> {
        self.renderers[node].as_ref().map(|r| r.0)
    }

    /// The node's settings, checked and typed at load (None for groups).
    pub fn node_settings(&self, node: usize) -> Option<&NodeSettings> {
        self.renderers[node].as_ref().map(|r| &r.1)
    }

    /// The camera to render: `[camera]`, or frame `k` of `n` along the keyframes (or the
    /// orbit); with `[walk]`, its eye put `eye_height` above the ground.
    pub fn camera(&self, frame: Option<(usize, usize)>) -> Result<Camera> {
        if let (Some((k, n)), true) = (frame, self.file.keyframes.is_empty() && self.file.orbit.is_none()) {
            bail!("{}: rendering frames needs [[keyframe]]s or an [orbit] in the scene (frame {k} of {n})", self.source.display());
        }
        self.camera_at(frame.map(|(k, n)| animation::AnimationFrame {
            index: k,
            count: n,
            path: if n > 1 { k as f64 / (n - 1) as f64 } else { 0.0 },
            time: None,
        }))
    }

    /// The camera of an animation frame (`[camera]` for None): along the keyframes at
    /// `frame.path`, or turned by the orbit's angle for frame `index` of `count`.
    pub fn camera_at(&self, frame: Option<animation::AnimationFrame>) -> Result<Camera> {
        let mut cam = self.file.camera.clone();
        if let Some(f) = frame {
            let keys = &self.file.keyframes;
            if !keys.is_empty() {
                cam.position = catmull_rom(&keys.iter().map(|k| k.position).collect::<Vec<_>>(), f.path);
                cam.focal_point = catmull_rom(&keys.iter().map(|k| k.focal_point).collect::<Vec<_>>(), f.path);
            }
            if let Some(o) = &self.file.orbit {
                let turn = glam::DQuat::from_axis_angle(DVec3::from(o.axis).normalize(), o.angle(f.index, f.count).to_radians());
                let focal = DVec3::from(cam.focal_point);
                cam.position = (focal + turn * (DVec3::from(cam.position) - focal)).to_array();
                cam.view_up = (turn * DVec3::from(cam.view_up)).to_array();
            }
        }
        if let Some(w) = &self.file.walk {
            let node = self.file.nodes.iter().position(|n| n.name == w.node).expect("checked at load");
            // The heights as the GPU ray-caster reads them: a GeoTIFF is not read whole for
            // the ground under one eye.
            let heights = self.terrain_data(node)?;
            let m = self.world_transform(node);
            let local = m.inverse().transform_point3(DVec3::new(cam.position[0], cam.position[1], 0.0));
            let ground = heights.surface_height(local.x, local.y).ok_or_else(|| {
                // The ground's rows may be those of a chunk that failed to decode.
                if let Some(why) = heights.failure() {
                    return anyhow!("{}: walk: the ground under the eye could not be read: {why}", self.source.display());
                }
                anyhow!(
                    "{}: walk: the eye at ({:.1}, {:.1}) is not over the terrain of node '{}' (outside it, or over NoData)",
                    self.source.display(),
                    cam.position[0],
                    cam.position[1],
                    w.node
                )
            })?;
            let z = m.transform_point3(DVec3::new(local.x, local.y, ground)).z + w.eye_height;
            let lift = z - cam.position[2];
            cam.position[2] = z;
            cam.focal_point[2] += lift;
        }
        cam.validate().map_err(|m| anyhow!("{}: {m}", self.source.display()))?;
        Ok(cam)
    }

    /// Node-local → world transform (parents applied). A heightfield read in a view window
    /// (`with_views`) has its window's south-west sample at the origin: the window's
    /// placement in the node's frame comes first.
    pub fn world_transform(&self, node: usize) -> DMat4 {
        match &self.view_windows[node] {
            Some(w) => self.world[node] * w.placement(),
            None => self.world[node],
        }
    }

    /// The elevations at the ends of heightfield node `node`'s elevation colours: its
    /// `elevation_range` (None: the terrain's own span — for a view window the whole
    /// raster's, `terrain_span`).
    pub fn elevation_range(&self, node: usize) -> Option<[f64; 2]> {
        self.file.nodes[node].elevation_range
    }

    /// The elevations heightfield node `node`'s solid spans at least: for a view window the
    /// whole raster's range, so the terrain draws as the whole would (None: what is read).
    pub fn terrain_span(&self, node: usize) -> Option<[f64; 2]> {
        self.view_windows[node].as_ref().map(|w| w.span)
    }

    /// What is said of a heightfield node read in a view window (which samples, why).
    pub fn view_window_note(&self, node: usize) -> Option<&str> {
        self.view_windows[node].as_ref().map(|w| w.note.as_str())
    }

    /// The scene, knowing the `cameras` its renders will take (at the image's size), before
    /// any data is read: a GeoTIFF heightfield node that names no `extent` and whose full
    /// raster passes the memory limit (at what its renderer holds a sample) is then read
    /// only where the cameras see it (`view_window`), at the finest level where that fits
    /// — rather than the largest overview of the whole that fits, or a refusal where the
    /// file has none. Unchanged: a scene with a `[walk]` (its cameras stand on the ground
    /// read), and a raster in a geographic CRS (its cells are converted to metres at the
    /// latitude of what is read, so a window would not keep the whole's scale).
    pub fn with_views(mut self, cameras: &[Camera]) -> Result<Scene> {
        if self.file.walk.is_some() {
            return Ok(self);
        }
        for node in 0..self.file.nodes.len() {
            if self.data[node].get().is_some() || self.height_rows[node].get().is_some() {
                // What was read or opened stays, placed as it was.
                continue;
            }
            let window = self.view_window(node, cameras).with_context(|| format!("node '{}'", self.file.nodes[node].name))?;
            self.view_windows[node] = window.map(Arc::new);
        }
        Ok(self)
    }

    /// Node `node`'s view window for `cameras`; None where it is read as before: not a
    /// GeoTIFF heightfield drawn, an `extent` named, a PNG drape (stretched over what is
    /// read), the whole fitting, a geographic CRS, or the whole of the level that fits seen
    /// anyway.
    fn view_window(&self, node: usize, cameras: &[Camera]) -> Result<Option<view_window::ViewWindow>> {
        use volterra_formats::geotiff::{elevation_plan, GeoTiffOptions};
        let n = &self.file.nodes[node];
        if n.kind != NodeKind::Heightfield || !n.visible || n.extent.is_some() || self.renderer(node).is_none() {
            return Ok(None);
        }
        let (path, _) = self.load_plan(node)?;
        if volterra_formats::detect(&path)? != volterra_formats::FileKind::GeoTiff {
            return Ok(None);
        }
        // A PNG drape is stretched over what is read: over a window it would shrink.
        if n.texture.as_deref().is_some_and(drape::is_stretched) {
            return Ok(None);
        }
        let held_by_renderer = self.renderer(node).and_then(|r| r.heights_held);
        let held = held_by_renderer.as_ref().map(|h| h as HeldBytes);
        let whole = GeoTiffOptions::default();
        let read_whole = elevation_plan(&path, &whole, &self.limits, held).ok();
        if read_whole.as_ref().is_some_and(|p| p.level == 0) {
            return Ok(None);
        }
        // The full raster's grid: the whole's plan carries it; where nothing of the whole
        // fits, a plan holding nothing (any level "fits").
        let full = match &read_whole {
            Some(p) => p.clone(),
            None => elevation_plan(&path, &whole, &self.limits, Some(&|_| 0))?,
        };
        if full.crs.geographic {
            return Ok(None);
        }
        // Its elevation range from its coarsest level, one pass over the rows; an overview
        // averages, so its range is widened by a tenth either way.
        let coarsest = GeoTiffOptions { level: Some(full.levels - 1), ..whole };
        let Some((lo, hi)) = GeoTiffRows::open(&path, &coarsest, &self.limits, 0)?.summary().range else {
            return Ok(None);
        };
        let widen = if full.levels > 1 { 0.1 * (hi - lo) as f64 + 1.0 } else { 0.0 };
        let z = (lo as f64 - widen, hi as f64 + widen);
        let image = (self.file.image.width, self.file.image.height);
        // In the node's frame the full raster's south-west sample is the origin; a
        // projected CRS's units are metres.
        let cell = full.full_cell_size_native;
        let Some([c0, r0, c1, r1]) = view_window::visible_window(cameras, image, self.world[node], full.full_size, cell, z) else {
            return Ok(None);
        };
        // Those samples' centres, a quarter cell of slack round them.
        let [ox, oy] = full.full_origin;
        let extent = [
            ox + (c0 as f64 - 0.25) * cell[0],
            oy - (r1 as f64 + 0.25) * cell[1],
            ox + (c1 as f64 + 0.25) * cell[0],
            oy - (r0 as f64 - 0.25) * cell[1],
        ];
        let plan = elevation_plan(&path, &GeoTiffOptions { extent: Some(extent), level: None }, &self.limits, held)?;
        let [w0, v0, w1, v1] = plan.window;
        if read_whole.is_some_and(|p| p.level == plan.level) && [w0, v0, w1 + 1, v1 + 1] == [0, 0, plan.level_size[0], plan.level_size[1]] {
            // The views see the whole of the level read anyway: nothing to gain.
            return Ok(None);
        }
        // Where the window's south-west sample lies, east and north of the full raster's.
        let south_west =
            |origin: [f64; 2], scale: [f64; 2], rows: u32| DVec3::new(origin[0], origin[1] - (rows - 1) as f64 * scale[1], 0.0);
        let offset = south_west(plan.origin, plan.cell_size_native, v1 - v0 + 1) - south_west(full.full_origin, cell, full.full_size[1]);
        let level =
            if plan.level == 0 { "full raster".to_string() } else { format!("{}×{} overview", plan.level_size[0], plan.level_size[1]) };
        let note = format!(
            "read only what the views see: columns {w0}..={w1}, rows {v0}..={v1} of the {level} ({}×{} samples), the whole {}×{} raster needing more than the memory limit",
            w1 - w0 + 1,
            v1 - v0 + 1,
            full.full_size[0],
            full.full_size[1]
        );
        let span = [lo as f64, hi as f64];
        Ok(Some(view_window::ViewWindow { extent, level: plan.level, offset: offset.truncate(), span, note }))
    }

    pub fn node_index(&self, name: &str) -> Option<usize> {
        self.file.nodes.iter().position(|n| n.name == name)
    }

    /// A scene from an edited copy of this one's description (same base directory and
    /// source), keeping the data already read for every node whose data-reading keys
    /// did not change: editing a transfer function or the camera reads nothing again.
    pub fn edited(&self, file: SceneFile) -> Result<Scene> {
        // Series already found are not looked for again (the viewer edits often).
        let known: HashMap<PathBuf, Option<Arc<TimeSeries>>> =
            self.file.nodes.iter().zip(&self.series).filter_map(|(n, s)| Some((n.file.clone()?, s.clone()))).collect();
        let mut next =
            Scene::from_file_with_lines(file, self.base_dir.clone(), self.source.clone(), &SettingLines::default(), Some(&known))?
                .with_limits(self.limits);
        next.time = self.time;
        for (i, n) in next.file.nodes.iter().enumerate() {
            let Some(j) = self.node_index(&n.name) else { continue };
            let o = &self.file.nodes[j];
            let same_data = (&o.kind, &o.file, &o.series, o.volume_index, o.resample, &o.png, &o.arrays, o.extent)
                == (&n.kind, &n.file, &n.series, n.volume_index, n.resample, &n.png, &n.arrays, n.extent);
            self.carry_over(
                j,
                &next,
                i,
                same_data,
                same_data && o.texture == n.texture && o.texture_colormap == n.texture_colormap && o.texture_range == n.texture_range,
            );
        }
        Ok(next)
    }

    /// The preset that classifies volume node `node` when it gives no transfer function:
    /// the one it names, else the one for its modality (the node's `modality`, else the
    /// file's). Reads the data (for its modality and values) only when none is named.
    pub fn preset(&self, node: usize) -> Result<presets::Preset> {
        let n = &self.file.nodes[node];
        if let Some(p) = &n.preset {
            return presets::Preset::from_name(p).map_err(|m| anyhow!("node '{}': {m}", n.name));
        }
        let NodeData::Volume(v) = self.data(node)? else { bail!("node '{}' is not a volume", n.name) };
        let modality = n.modality.as_deref().or(v.modality.as_deref());
        Ok(presets::Preset::for_modality(modality, &*self.value_stats(node)?))
    }

    /// The transfer function that classifies volume node `node`: its own, else its preset's
    /// (see `preset`) placed on its data (the smallest voxel spacing as unit distance, as
    /// Slicer sets it), moved by `preset_shift`.
    pub fn transfer_function(&self, node: usize) -> Result<TransferFunction> {
        let n = &self.file.nodes[node];
        if let Some(tf) = &n.transfer_function {
            return Ok(tf.clone());
        }
        let preset = self.preset(node)?;
        let NodeData::Volume(v) = self.data(node)? else { bail!("node '{}' is not a volume", n.name) };
        let unit = v.spacing.iter().cloned().fold(f64::INFINITY, f64::min);
        Ok(preset.shifted(&*self.value_stats(node)?, unit, n.preset_shift))
    }

    /// The transfer function volume node `node` is drawn with: `transfer_function`'s,
    /// its extinction scaled by the node's `opacity_scale`.
    pub fn classification(&self, node: usize) -> Result<TransferFunction> {
        let mut tf = self.transfer_function(node)?;
        let s = self.file.nodes[node].opacity_scale;
        if s != 1.0 {
            // s = 0: an unreachable unit distance, every segment's opacity 0.
            tf.scalar_opacity_unit_distance = if s > 0.0 { tf.scalar_opacity_unit_distance / s } else { f64::MAX };
        }
        Ok(tf)
    }

    /// The region volume node `node` keeps (its crop box and clipping planes) as
    /// half-spaces in its own coordinates; empty: all of it.
    pub fn crop_region(&self, node: usize) -> Vec<HalfSpace> {
        let n = &self.file.nodes[node];
        crop::region(n.crop.as_ref(), &n.clip)
    }

    /// The shading of volume node `node`: its own `[node.shading]`, else the shading of its
    /// preset (named, or its modality's when it gives no transfer function; a transfer
    /// function given as points comes with none).
    pub fn shading(&self, node: usize) -> Option<VolumeShading> {
        let n = &self.file.nodes[node];
        if n.shading.is_some() || n.transfer_function.is_some() {
            return n.shading;
        }
        self.preset(node).ok().and_then(presets::Preset::shading)
    }

    /// World-space bounding box of a node's data as its renderer reads it (a heightfield's
    /// GeoTIFF by rows, not held: `terrain_data`), reading it on first use; None where
    /// nothing finite is there.
    pub fn bounds(&self, node: usize) -> Result<Option<(DVec3, DVec3)>> {
        let m = self.world_transform(node);
        match self.file.nodes[node].kind {
            NodeKind::Heightfield => Ok(auto::terrain_bounds(&self.terrain_data(node)?, m)),
            _ => Ok(auto::data_bounds(&self.data(node)?, m)),
        }
    }
}

/// The point at s ∈ [0, 1] on a uniform Catmull-Rom spline through `points` (ends
/// repeated), so that every key is passed through at s = i / (len − 1).
fn catmull_rom(points: &[[f64; 3]], s: f64) -> [f64; 3] {
    let n = points.len();
    if n == 1 {
        return points[0];
    }
    let u = s.clamp(0.0, 1.0) * (n - 1) as f64;
    let i = (u.floor() as usize).min(n - 2);
    let f = u - i as f64;
    let p = |k: i64| DVec3::from(points[k.clamp(0, n as i64 - 1) as usize]);
    let (p0, p1, p2, p3) = (p(i as i64 - 1), p(i as i64), p(i as i64 + 1), p(i as i64 + 2));
    let v =
        0.5 * ((2.0 * p1) + (p2 - p0) * f + (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3) * f * f + (3.0 * p1 - p0 - 3.0 * p2 + p3) * f * f * f);
    v.to_array()
}
