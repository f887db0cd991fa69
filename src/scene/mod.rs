//! The scene graph and the scene file (TOML; documented in docs/scene-format.md).
//!
//! A scene is parsed once into plain objects ([`SceneFile`]), checked, and then holds its
//! data lazily: a node's file is read (and cached) only when a renderer asks for it, so a
//! render loads exactly the nodes it draws.

pub mod animation;
pub mod auto;
pub mod camera;
pub mod crop;
pub mod drape;
pub mod measurement;
pub mod presets;
pub mod transfer;
pub mod view_window;

pub use camera::{Camera, Ray, RayGenerator};
pub use crop::{ClipPlane, CropBox, HalfSpace};
pub use measurement::{Measurement, MeasurementKind, SliceOverlay, SlicePlane, SliceViews};
pub use transfer::{TransferFunction, VolumeShading};

use crate::render::registry::{self, NodeSettings, RendererDecl};
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

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ImageSettings {
    #[serde(default = "default_size")]
    pub width: usize,
    #[serde(default = "default_size")]
    pub height: usize,
    /// Linear RGB.
    #[serde(default)]
    pub background: [f64; 3],
    /// The PNG preview's exposure in stops (×2^exposure); EXR outputs stay linear.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub exposure: f64,
}

fn default_size() -> usize {
    512
}

impl Default for ImageSettings {
    fn default() -> Self {
        ImageSettings { width: 512, height: 512, background: [0.0; 3], exposure: 0.0 }
    }
}

#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum NodeKind {
    Group,
    Volume,
    Heightfield,
    Particles,
}

#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "lowercase")]
pub enum BlendMode {
    /// Front-to-back emission-absorption compositing.
    #[default]
    Composite,
    /// Maximum intensity projection.
    Mip,
}

/// What a time series node's automatic scales are taken over: the colour range of a
/// particle node without `color_range`, and smoke's c_ext where its medium gives none.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "lowercase")]
pub enum ScaleOver {
    /// Every step of the series (ParaView's "over all timesteps"): a colour means one
    /// value in every frame, and the smoke's extinction does not change from step to step.
    #[default]
    Series,
    /// Each step on its own (its own range, its own c_ext).
    Step,
}

impl ScaleOver {
    fn is_series(&self) -> bool {
        *self == ScaleOver::Series
    }
}

/// A node's placement relative to its parent: `matrix` (4×4, row-major), or scale, then
/// rotate (degrees about x, then y, then z), then translate.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, Default)]
#[serde(deny_unknown_fields)]
pub struct Transform {
    pub matrix: Option<[[f64; 4]; 4]>,
    pub translate: Option<[f64; 3]>,
    pub rotate: Option<[f64; 3]>,
    pub scale: Option<[f64; 3]>,
}

impl Transform {
    pub fn to_mat4(&self) -> Result<DMat4> {
        if let Some(m) = self.matrix {
            if self.translate.is_some() || self.rotate.is_some() || self.scale.is_some() {
                bail!("transform: give either matrix or translate/rotate/scale, not both");
            }
            let rows = DMat4::from_cols_array_2d(&m);
            return Ok(rows.transpose());
        }
        let s = DVec3::from(self.scale.unwrap_or([1.0; 3]));
        let r = self.rotate.unwrap_or([0.0; 3]);
        let t = DVec3::from(self.translate.unwrap_or([0.0; 3]));
        let rot = DMat4::from_rotation_z(r[2].to_radians())
            * DMat4::from_rotation_y(r[1].to_radians())
            * DMat4::from_rotation_x(r[0].to_radians());
        Ok(DMat4::from_translation(t) * rot * DMat4::from_scale(s))
    }
}

/// Participating-medium parameters for particle smoke.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Medium {
    /// σ_t = c_ext · ρ (m² per kg when ρ is in kg/m³). Not given: chosen from the data so
    /// that the densest column has optical depth 2 (`render::smoke::extinction`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub c_ext: Option<f64>,
    /// Single-scattering albedo σ_s / σ_t.
    pub albedo: f64,
    /// Henyey–Greenstein asymmetry g in (−1, 1).
    #[serde(default)]
    pub g: f64,
}

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct NodeDesc {
    pub name: String,
    pub kind: NodeKind,
    /// Data file, relative to the scene file.
    pub file: Option<PathBuf>,
    pub parent: Option<String>,
    #[serde(default)]
    pub transform: Transform,
    /// Which renderer draws the node (see `volterra render --help`).
    pub renderer: Option<String>,
    #[serde(default = "yes")]
    pub visible: bool,
    /// Renderer quality settings; each renderer checks its own keys.
    #[serde(default)]
    pub settings: toml::Table,
    // --- volumes
    pub series: Option<String>,
    #[serde(default, skip_serializing_if = "is_zero_usize")]
    pub volume_index: usize,
    #[serde(default, skip_serializing_if = "is_false")]
    pub resample: bool,
    pub transfer_function: Option<TransferFunction>,
    /// A transfer-function preset by name (`presets::Preset::name`: 3D Slicer's names),
    /// for a volume that gives no `transfer_function`; its shading too, unless the node
    /// gives its own. A volume with neither gets the preset for its modality.
    pub preset: Option<String>,
    /// Moves the preset along the value axis (3D Slicer's "Shift"), in the data's units.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub preset_shift: f64,
    /// The modality (CT, MR, PT, NM; or PET, SPECT, MRI) of data whose file does not say it (NIfTI): it picks
    /// the preset when none is named.
    pub modality: Option<String>,
    /// Gradient shading of a volume (vtkVolumeProperty's `shade`, `ambient`, …).
    pub shading: Option<VolumeShading>,
    /// The cropping box (millimetres, the node's own coordinates): only what lies inside
    /// is drawn (vtkVolumeMapper's cropping region).
    pub crop: Option<CropBox>,
    /// Clipping planes (node coordinates), each keeping the side its normal points to.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub clip: Vec<ClipPlane>,
    #[serde(default, skip_serializing_if = "BlendMode::is_composite")]
    pub blend: BlendMode,
    /// Scales a volume's extinction: the transfer function's opacity a per unit distance
    /// becomes 1 − (1 − a)^s (its unit distance divided by s), so one volume of a fused
    /// pair fades (s < 1) or thickens (s > 1) without editing its points; 0 hides it,
    /// opacity 1 stays 1. Colour and MIP are unchanged.
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub opacity_scale: f64,
    // --- heightfields
    pub png: Option<PngHeightOptions>,
    /// Only the part of a GeoTIFF heightfield inside [west, south, east, north] (its CRS's
    /// units): the samples whose centres lie there, reading only the tiles or strips that
    /// hold them (as `gdal_translate -projwin`, on sample centres).
    pub extent: Option<[f64; 4]>,
    /// Colour image draped over the terrain, relative to the scene file: a PNG (stretched
    /// over the heightfield's extent) or a GeoTIFF (placed by its georeferencing, in the
    /// heightfield's CRS).
    pub texture: Option<PathBuf>,
    /// A single-band GeoTIFF texture's colour map (default grey).
    pub texture_colormap: Option<String>,
    /// A single-band GeoTIFF texture's values at the colour map's ends (default: its range).
    pub texture_range: Option<[f64; 2]>,
    /// The elevations (metres) at the ends of the terrain renderer's elevation colour map
    /// (default: the lowest and highest valid sample read — for a view window, the whole
    /// raster's, so the colours do not change with what is read).
    pub elevation_range: Option<[f64; 2]>,
    // --- particles
    pub arrays: Option<ParticleArrayNames>,
    pub medium: Option<Medium>,
    /// The point array the `points` renderer colours by (default: density).
    pub color_by: Option<String>,
    /// The values at the colour map's ends (default: the array's range — over every step
    /// of a time series, unless `scale_over = "step"`).
    pub color_range: Option<[f64; 2]>,
    /// For a time series: whether automatic scales (the colour range, smoke's c_ext) are
    /// taken over the whole series (default) or each step.
    #[serde(default, skip_serializing_if = "ScaleOver::is_series")]
    pub scale_over: ScaleOver,
}

fn yes() -> bool {
    true
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

fn is_zero_usize(v: &usize) -> bool {
    *v == 0
}

fn is_false(v: &bool) -> bool {
    !*v
}

impl BlendMode {
    fn is_composite(&self) -> bool {
        *self == BlendMode::Composite
    }
}

fn one() -> f64 {
    1.0
}

fn is_one(v: &f64) -> bool {
    *v == 1.0
}

#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum LightKind {
    Directional,
    Point,
    Spot,
}

/// Light power: a directional light's `intensity` is irradiance (W/m²) on a surface facing
/// it; a point or spot light's is radiant intensity (W/sr).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Light {
    pub kind: LightKind,
    /// Direction the light travels (directional, spot).
    pub direction: Option<[f64; 3]>,
    pub position: Option<[f64; 3]>,
    #[serde(default = "white")]
    pub color: [f64; 3],
    #[serde(default = "unit")]
    pub intensity: f64,
    /// Spot cone half-angle in degrees.
    pub cone_angle: Option<f64>,
}

impl Light {
    /// The unit direction the light travels (directional and spot lights; straight down
    /// when the scene gives none).
    pub fn travel_direction(&self) -> Result<DVec3> {
        let d = DVec3::from(self.direction.unwrap_or([0.0, 0.0, -1.0]));
        if !(d.length() > 0.0 && d.is_finite()) {
            bail!("a {} light needs a non-zero direction", self.kind_name());
        }
        Ok(d.normalize())
    }

    /// Where the light is (point and spot lights).
    pub fn location(&self) -> Result<DVec3> {
        let p = self.position.map(DVec3::from).filter(|p| p.is_finite());
        p.ok_or_else(|| anyhow!("a {} light needs a position", self.kind_name()))
    }

    fn kind_name(&self) -> &'static str {
        match self.kind {
            LightKind::Directional => "directional",
            LightKind::Point => "point",
            LightKind::Spot => "spot",
        }
    }
}

fn white() -> [f64; 3] {
    [1.0; 3]
}
fn unit() -> f64 {
    1.0
}

/// Walk-through: the eye is kept `eye_height` metres above the ground of a heightfield node
/// (the camera's and every keyframe's z is replaced; the focal point moves with it, so the
/// view keeps its pitch).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Walk {
    pub node: String,
    #[serde(default = "default_eye_height")]
    pub eye_height: f64,
}

fn default_eye_height() -> f64 {
    1.7
}

/// A camera keyframe; `volterra render --frames N` renders N frames along a Catmull-Rom
/// spline through them (view_up and the angle come from `[camera]`).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Keyframe {
    pub position: [f64; 3],
    pub focal_point: [f64; 3],
}

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    #[serde(default)]
    pub image: ImageSettings,
    pub camera: Camera,
    pub walk: Option<Walk>,
    #[serde(default, rename = "keyframe")]
    pub keyframes: Vec<Keyframe>,
    /// A turntable camera path (instead of keyframes).
    pub orbit: Option<animation::Orbit>,
    #[serde(default, rename = "light")]
    pub lights: Vec<Light>,
    #[serde(default, rename = "node")]
    pub nodes: Vec<NodeDesc>,
    /// Measurements taken in the viewer, on slices or the 3-D surface (not drawn by renders).
    #[serde(default, rename = "measurement", skip_serializing_if = "Vec::is_empty")]
    pub measurements: Vec<Measurement>,
    /// What the viewer's slice views showed when the scene was saved (not used by renders).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub slices: Option<SliceViews>,
}

/// The heights of a heightfield node as a renderer takes them: the heightfield held, or
/// its GeoTIFF read row by row, by windows of tiles or strips, into the renderer's store.
#[derive(Clone)]
pub enum TerrainData {
    Held(Arc<Heightfield>),
    Rows(Arc<GeoTiffRows>),
}

impl TerrainData {
    /// Where the samples lie.
    pub fn georef(&self) -> GridGeoref {
        match self {
            TerrainData::Held(hf) => hf.georef(),
            TerrainData::Rows(rows) => rows.georef().clone(),
        }
    }

    /// What identifies these heights while they are held (for caches of work on them).
    pub fn address(&self) -> usize {
        match self {
            TerrainData::Held(hf) => Arc::as_ptr(hf) as usize,
            TerrainData::Rows(rows) => Arc::as_ptr(rows) as usize,
        }
    }

    /// What the reader noted of the raster (an overview read instead of the full raster,
    /// degrees converted to metres, …).
    pub fn notes(&self) -> &[String] {
        match self {
            TerrainData::Held(hf) => &hf.notes,
            TerrainData::Rows(rows) => &rows.notes,
        }
    }

    /// Why rows could not be read (a chunk of the GeoTIFF that failed to decode), if so.
    pub fn failure(&self) -> Option<String> {
        match self {
            TerrainData::Held(_) => None,
            TerrainData::Rows(rows) => rows.failure(),
        }
    }

    /// The bilinear surface height at (x, y) metres east and north of the south-west
    /// sample (see `Heightfield::surface_height`).
    pub fn surface_height(&self, x: f64, y: f64) -> Option<f64> {
        match self {
            TerrainData::Held(hf) => hf.surface_height(x, y),
            TerrainData::Rows(rows) => rows.surface_height(x, y),
        }
    }
}

/// A node's data, loaded on first use.
#[derive(Debug, Clone)]
pub enum NodeData {
    Volume(Arc<Volume>),
    Heightfield(Arc<Heightfield>),
    Particles(Arc<ParticleSet>),
}

impl From<Dataset> for NodeData {
    fn from(d: Dataset) -> NodeData {
        match d {
            Dataset::Volume(v) => NodeData::Volume(Arc::new(v)),
            Dataset::Heightfield(h) => NodeData::Heightfield(Arc::new(h)),
            Dataset::Particles(p) => {
                // Particles at positions that are not finite are left out (the reader's
                // note says how many); renderers need mass, h and density: fill the
                // documented defaults.
                let mut p = p.drawable();
                volterra_formats::sph::fill_defaults(&mut p);
                NodeData::Particles(Arc::new(p))
            }
        }
    }
}

impl NodeData {
    pub fn kind(&self) -> NodeKind {
        match self {
            NodeData::Volume(_) => NodeKind::Volume,
            NodeData::Heightfield(_) => NodeKind::Heightfield,
            NodeData::Particles(_) => NodeKind::Particles,
        }
    }
}

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

/// What the GPU ray-caster holds for a GeoTIFF level's samples
/// (`render::terrain::gpu_held_bytes`), with the GPU opened first: where its memory is the
/// host's, what its driver holds from then on (its compiled pipelines) is in use when a
/// level is chosen. Without a GPU the renderer says so when it draws.
fn gpu_held_bytes() -> impl Fn(u64) -> u64 {
    let _ = crate::render::terrain::gpu::gpu();
    crate::render::terrain::gpu_held_bytes
}

/// The line (1-based) of a byte offset in `text`.
fn line_of(text: &str, offset: usize) -> usize {
    text[..offset.min(text.len())].bytes().filter(|&b| b == b'\n').count() + 1
}

fn one_line(s: &str) -> String {
    s.split_whitespace().collect::<Vec<_>>().join(" ")
}

/// Parses TOML text into `T`, turning errors into one line that names the file and line;
/// an unknown key gets the nearest known one suggested (and in a node, the keys its kind
/// takes).
fn parse_toml<T: serde::de::DeserializeOwned>(text: &str, path: &Path) -> Result<T> {
    toml::from_str(text).map_err(|e| {
        let line = e.span().map(|s| format!(" line {}", line_of(text, s.start))).unwrap_or_default();
        let message = one_line(e.message());
        let message = e.span().and_then(|s| unknown_key_message(text, s.start, &message)).unwrap_or(message);
        anyhow!("{}:{line}: {message}", path.display())
    })
}

/// The keys a node of each kind takes (besides those every node takes).
const NODE_KEYS: [&str; 8] = ["name", "kind", "file", "parent", "transform", "renderer", "visible", "settings"];
fn node_kind_keys(kind: &str) -> &'static [&'static str] {
    match kind {
        "volume" => &[
            "series",
            "volume_index",
            "resample",
            "transfer_function",
            "preset",
            "preset_shift",
            "modality",
            "shading",
            "crop",
            "clip",
            "blend",
            "opacity_scale",
        ],
        "heightfield" => &["png", "extent", "texture", "texture_colormap", "texture_range", "elevation_range"],
        "particles" => &["arrays", "medium", "color_by", "color_range", "scale_over"],
        _ => &[],
    }
}

/// Every `[[node]]`'s keys against the keys its kind takes: a key another kind takes, or
/// none does, is refused with its line, the nearest key of the kind suggested, and the
/// kind's keys listed (serde would list every key of every kind, or accept a volume's
/// `preset` on a particle node to refuse it later without a line).
fn check_node_keys(text: &str, path: &Path) -> Result<()> {
    let Ok(doc) = toml::from_str::<toml::Table>(text) else { return Ok(()) };
    let Some(nodes) = doc.get("node").and_then(|n| n.as_array()) else { return Ok(()) };
    // Where each [[node]] block starts in the text.
    let starts: Vec<usize> = text.match_indices("[[node]]").map(|(i, _)| i).collect();
    for (k, node) in nodes.iter().enumerate() {
        let Some(table) = node.as_table() else { continue };
        let kind = table.get("kind").and_then(|v| v.as_str()).unwrap_or("");
        let allowed: Vec<&str> = NODE_KEYS.iter().chain(node_kind_keys(kind)).copied().collect();
        for (key, value) in table {
            if allowed.contains(&key.as_str()) || (kind.is_empty() || !matches!(kind, "volume" | "heightfield" | "particles" | "group")) {
                continue;
            }
            // Scenes saved before these were skipped at their defaults carry them on every
            // node: harmless there.
            let default = match key.as_str() {
                "volume_index" => value.as_integer() == Some(0),
                "resample" => value.as_bool() == Some(false),
                "blend" => value.as_str() == Some("composite"),
                _ => false,
            };
            if default {
                continue;
            }
            let block = starts.get(k).map_or(0, |&s| s);
            let line = text[block..].lines().position(|l| l.trim_start().starts_with(key.as_str())).map(|n| line_of(text, block) + n);
            let at = line.map(|l| format!(" line {l}:")).unwrap_or_default();
            let nearest = allowed.iter().map(|k| (edit_distance(key, k), *k)).min().filter(|(d, _)| *d <= 2.max(key.len() / 3));
            let hint = nearest.map(|(_, k)| format!(" (did you mean `{k}`?)")).unwrap_or_default();
            let name = table.get("name").and_then(|v| v.as_str()).unwrap_or("?");
            bail!("{}:{at} node '{name}': unknown key `{key}`{hint}; a {kind} node takes: {}", path.display(), allowed.join(", "));
        }
    }
    Ok(())
}

/// Edits (insertions, deletions, substitutions) between two words.
fn edit_distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut row: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.chars().enumerate() {
        let mut prev = row[0];
        row[0] = i + 1;
        for (j, cb) in b.iter().enumerate() {
            let here = row[j + 1];
            row[j + 1] = (prev + usize::from(ca != *cb)).min(row[j] + 1).min(here + 1);
            prev = here;
        }
    }
    row[b.len()]
}

/// serde's "unknown field `x`, expected one of …" made useful: the nearest known key
/// suggested, and inside a `[[node]]` only the keys that node's kind takes listed.
fn unknown_key_message(text: &str, at: usize, message: &str) -> Option<String> {
    let key = message.strip_prefix("unknown field `")?.split('`').next()?.to_string();
    let expected: Vec<String> = message.split("expected one of ").nth(1)?.split(", ").map(|k| k.trim_matches('`').to_string()).collect();
    // The [[node]] the key is in, if any: its kind, read from its lines.
    let before = &text[..at.min(text.len())];
    let header = before.rfind("\n[")?;
    let in_node = before[header..].trim_start().starts_with("[[node]]");
    let (listed, what): (Vec<String>, String) = if in_node {
        let block_end = text[header + 1..].find("\n[").map_or(text.len(), |e| header + 1 + e);
        let kind = text[header..block_end]
            .lines()
            .find_map(|l| l.trim().strip_prefix("kind").map(|r| r.trim_start_matches([' ', '=']).trim().trim_matches('"').to_string()))
            .unwrap_or_default();
        let keys: Vec<String> = NODE_KEYS.iter().chain(node_kind_keys(&kind)).map(|k| k.to_string()).collect();
        let what = if kind.is_empty() { "a node takes".to_string() } else { format!("a {kind} node takes") };
        (keys, what)
    } else {
        (expected, "known keys".to_string())
    };
    let nearest = listed.iter().map(|k| (edit_distance(&key, k), k)).min()?;
    let hint = if nearest.0 <= 2.max(key.len() / 3) { format!(" (did you mean `{}`?)", nearest.1) } else { String::new() };
    Some(format!("unknown key `{key}`{hint}; {what}: {}", listed.join(", ")))
}

/// Applies `key=value` overrides to a parsed TOML document. Keys are dotted paths;
/// `node.NAME.rest` addresses the node whose name is NAME. Values are TOML (strings may
/// be given bare).
pub fn apply_overrides(doc: &mut toml::Table, sets: &[String]) -> Result<()> {
    for set in sets {
        let (key, raw) = set.split_once('=').ok_or_else(|| anyhow!("--set {set}: expected key=value"))?;
        let value: toml::Value = match toml::from_str::<toml::Table>(&format!("v = {raw}")) {
            Ok(mut t) => t.remove("v").unwrap(),
            Err(_) => toml::Value::String(raw.to_string()),
        };
        let parts: Vec<&str> = key.split('.').collect();
        let mut table: &mut toml::Table = doc;
        let mut rest = &parts[..];
        if parts.first() == Some(&"node") && parts.len() >= 3 {
            let nodes =
                table.get_mut("node").and_then(|n| n.as_array_mut()).ok_or_else(|| anyhow!("--set {key}: the scene has no nodes"))?;
            let node = nodes
                .iter_mut()
                .find(|n| n.get("name").and_then(|v| v.as_str()) == Some(parts[1]))
                .ok_or_else(|| anyhow!("--set {key}: no node named '{}'", parts[1]))?;
            table = node.as_table_mut().unwrap();
            rest = &parts[2..];
        }
        for p in &rest[..rest.len() - 1] {
            let entry = table.entry(p.to_string()).or_insert_with(|| toml::Value::Table(toml::Table::new()));
            table = entry.as_table_mut().ok_or_else(|| anyhow!("--set {key}: '{p}' is not a table"))?;
        }
        table.insert(rest[rest.len() - 1].to_string(), value);
    }
    Ok(())
}

/// Where a scene file's text sets each node's renderer and settings, for errors that
/// name the line. Empty for scenes built in code.
#[derive(Default)]
struct SettingLines {
    /// Per node name: the line of the node's `renderer` (or of its name) and of each setting.
    nodes: HashMap<String, (usize, HashMap<String, usize>)>,
}

impl SettingLines {
    fn of(text: &str) -> SettingLines {
        #[derive(Deserialize)]
        struct Node {
            name: toml::Spanned<String>,
            renderer: Option<toml::Spanned<toml::Value>>,
            #[serde(default)]
            settings: HashMap<String, toml::Spanned<toml::Value>>,
        }
        #[derive(Deserialize)]
        struct Doc {
            #[serde(default)]
            node: Vec<Node>,
        }
        let Ok(doc) = toml::from_str::<Doc>(text) else { return SettingLines::default() };
        let nodes = doc
            .node
            .into_iter()
            .map(|n| {
                let at = n.renderer.as_ref().map(|r| r.span().start).unwrap_or(n.name.span().start);
                let keys = n.settings.iter().map(|(k, v)| (k.clone(), line_of(text, v.span().start))).collect();
                (n.name.into_inner(), (line_of(text, at), keys))
            })
            .collect();
        SettingLines { nodes }
    }

    /// " line N" for the node's setting `key` (or its renderer), or " (from --set)" for a
    /// setting the file does not hold; empty when the scene has no text.
    fn at(&self, node: &str, key: Option<&str>) -> String {
        if self.nodes.is_empty() {
            return String::new();
        }
        match (self.nodes.get(node), key) {
            (Some((_, keys)), Some(k)) => keys.get(k).map(|l| format!(" line {l}")).unwrap_or_else(|| " (from --set)".into()),
            (Some((line, _)), None) => format!(" line {line}"),
            (None, _) => " (from --set)".into(),
        }
    }
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
                if crate::render::colormap::Colormap::from_name(c).is_none() {
                    let names: Vec<&str> = crate::render::colormap::Colormap::ALL.iter().map(|c| c.name()).collect();
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
            let decl = registry::resolve(n).map_err(|m| anyhow!("{src}:{}: node '{}': {m}", lines.at(&n.name, None), n.name))?;
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
        let gpu = matches!(self.node_settings(node), Some(NodeSettings::Terrain(_)));
        let gpu_held = gpu.then(gpu_held_bytes);
        let held = gpu_held.as_ref().map(|h| h as HeldBytes);
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

    /// The node's data, read on first call and cached.
    pub fn data(&self, node: usize) -> Result<NodeData> {
        let cell = &self.data[node];
        cell.get_or_init(|| self.read_node(node).map_err(SharedError::new)).clone().map_err(anyhow::Error::new)
    }

    /// Step `k` of node `node`'s series, read now and not kept (a pass over a whole series
    /// holds one step at a time), as the renderers take it.
    pub fn step_data(&self, node: usize, k: usize) -> Result<NodeData> {
        let (path, opts) = self.load_plan_at(node, Some(k))?;
        Ok(NodeData::from(volterra_formats::load(&path, &opts)?))
    }

    /// The file node `node` reads (its series' step now, where it has one) and how.
    fn load_plan(&self, node: usize) -> Result<(PathBuf, LoadOptions)> {
        self.load_plan_at(node, self.step(node))
    }

    /// The file node `node` reads at step `step` of its series (None: no series) and how.
    fn load_plan_at(&self, node: usize, step: Option<usize>) -> Result<(PathBuf, LoadOptions)> {
        let n = &self.file.nodes[node];
        let mut path = self.base_dir.join(n.file.as_ref().ok_or_else(|| anyhow!("node '{}' has no file", n.name))?);
        let mut opts = LoadOptions { limits: self.limits, ..LoadOptions::default() };
        opts.dicom.series = n.series.clone();
        opts.dicom.resample = n.resample;
        opts.nifti.volume_index = n.volume_index;
        if let (Some(s), Some(k)) = (&self.series[node], step) {
            let step = s.steps.get(k).ok_or_else(|| anyhow!("node '{}': its series has {} steps, not {}", n.name, s.steps.len(), k + 1))?;
            path = step.file.clone();
            opts.nifti.volume_index = step.volume_index.unwrap_or(n.volume_index);
        }
        if let Some(p) = &n.png {
            opts.png = p.clone();
        }
        if let Some(extent) = n.extent {
            if volterra_formats::detect(&path)? != volterra_formats::FileKind::GeoTiff {
                bail!("{}: node '{}': extent needs a georeferenced raster (a GeoTIFF)", path.display(), n.name);
            }
            opts.geotiff.extent = Some(extent);
        }
        if let Some(w) = &self.view_windows[node] {
            opts.geotiff.extent = Some(w.extent);
            opts.geotiff.level = Some(w.level);
        }
        if let Some(a) = &n.arrays {
            opts.particles = a.clone();
        }
        Ok((path, opts))
    }

    fn read_node(&self, node: usize) -> Result<NodeData> {
        let n = &self.file.nodes[node];
        let (path, opts) = self.load_plan(node)?;
        let d = match volterra_formats::load(&path, &opts) {
            // A folder of several series: the node's own key chooses, not a CLI flag.
            Err(e) if e.kind == volterra_formats::ErrorKind::Ambiguous && path.is_dir() => {
                let list = volterra_formats::dicom::list_series(&path, &self.limits)?;
                let which = if n.series.is_some() { "matches none or several of them" } else { "names none of them" };
                bail!(
                    "{}: node '{}': the folder holds {} series and the node's series = … {which}; give series = N (the number) or its UID: {}",
                    path.display(),
                    n.name,
                    list.len(),
                    volterra_formats::dicom::series_listing(&list)
                );
            }
            r => r?,
        };
        let data = NodeData::from(d);
        if data.kind() != n.kind {
            bail!("{}: node '{}' is a {:?} node but the file holds other data", path.display(), n.name, n.kind);
        }
        Ok(data)
    }

    /// The heights of heightfield node `node` as its renderer takes them. The GPU
    /// ray-caster copies them into textures of its own: for it a GeoTIFF is opened to be
    /// read row by row (at the finest level whose window fits the memory limit at the
    /// textures' bytes a sample), so the heights are held once, there, not twice. Held
    /// otherwise: for other renderers, other files, and where the heightfield is held
    /// already (read for another use).
    pub fn terrain_data(&self, node: usize) -> Result<TerrainData> {
        if let Some(Ok(NodeData::Heightfield(hf))) = self.data[node].get() {
            return Ok(TerrainData::Held(hf.clone()));
        }
        let n = &self.file.nodes[node];
        if n.kind != NodeKind::Heightfield {
            bail!("node '{}' is not a heightfield", n.name);
        }
        let (path, opts) = self.load_plan(node)?;
        let gpu = matches!(self.node_settings(node), Some(NodeSettings::Terrain(_)));
        if !gpu || volterra_formats::detect(&path)? != volterra_formats::FileKind::GeoTiff {
            return self.heightfield(node).map(TerrainData::Held);
        }
        let rows = self.height_rows[node]
            .get_or_init(|| {
                GeoTiffRows::open_holding(&path, &opts.geotiff, &self.limits, &gpu_held_bytes())
                    .map(Arc::new)
                    .map_err(|e| SharedError::new(e.into()))
            })
            .clone()
            .map_err(anyhow::Error::new)?;
        Ok(TerrainData::Rows(rows))
    }

    pub fn volume(&self, node: usize) -> Result<Arc<Volume>> {
        match self.data(node)? {
            NodeData::Volume(v) => Ok(v),
            _ => bail!("node '{}' is not a volume", self.file.nodes[node].name),
        }
    }
    pub fn heightfield(&self, node: usize) -> Result<Arc<Heightfield>> {
        match self.data(node)? {
            NodeData::Heightfield(h) => Ok(h),
            _ => bail!("node '{}' is not a heightfield", self.file.nodes[node].name),
        }
    }
    pub fn particles(&self, node: usize) -> Result<Arc<ParticleSet>> {
        match self.data(node)? {
            NodeData::Particles(p) => Ok(p),
            _ => bail!("node '{}' is not a particle set", self.file.nodes[node].name),
        }
    }
    /// The node's draped image, if it names one.
    pub fn texture(&self, node: usize) -> Result<Option<Arc<drape::Drape>>> {
        let desc = &self.file.nodes[node];
        let Some(t) = &desc.texture else { return Ok(None) };
        let path = self.base_dir.join(t);
        let band = (desc.texture_colormap.is_some() || desc.texture_range.is_some()).then(|| drape::BandColours {
            colormap: desc
                .texture_colormap
                .as_deref()
                .and_then(crate::render::colormap::Colormap::from_name)
                .unwrap_or(crate::render::colormap::Colormap::Grey),
            range: desc.texture_range,
        });
        let r = self.textures[node]
            .get_or_init(|| drape::Drape::load(&path, band, &self.limits).map(Arc::new).map_err(SharedError::new))
            .clone();
        r.map(Some).map_err(anyhow::Error::new)
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

    /// A volume node's value statistics (read and counted once).
    pub fn value_stats(&self, node: usize) -> Result<Arc<presets::ValueStats>> {
        if let Some(s) = self.stats[node].get() {
            return Ok(s.clone());
        }
        let NodeData::Volume(v) = self.data(node)? else { bail!("node '{}' is not a volume", self.file.nodes[node].name) };
        Ok(self.stats[node].get_or_init(|| Arc::new(presets::ValueStats::of(&v))).clone())
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

    /// Gives a node data already read (a viewer that opened a data file read it to build
    /// the scene). Does nothing if the node's data is already there.
    pub fn provide_data(&self, node: usize, data: NodeData) {
        let _ = self.data[node].set(Ok(data));
    }

    /// The data read so far, node by node (for caches that keep work per data set).
    pub fn loaded_data(&self) -> impl Iterator<Item = NodeData> + '_ {
        self.data.iter().filter_map(|c| c.get().and_then(|r| r.as_ref().ok()).cloned())
    }

    /// The addresses of the GeoTIFFs opened to be read row by row (`terrain_data`), for the
    /// same caches.
    pub fn opened_height_rows(&self) -> impl Iterator<Item = usize> + '_ {
        self.height_rows.iter().filter_map(|c| c.get().and_then(|r| r.as_ref().ok()).map(|r| Arc::as_ptr(r) as usize))
    }

    /// True if the node's data has been read (for tests of lazy loading).
    pub fn is_loaded(&self, node: usize) -> bool {
        self.data[node].get().is_some()
    }

    /// True if the node's data has been read, or its GeoTIFF opened to be read by rows.
    pub fn is_opened(&self, node: usize) -> bool {
        self.is_loaded(node) || self.height_rows[node].get().is_some()
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
