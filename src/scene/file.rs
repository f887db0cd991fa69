//! The scene file's plain objects, as TOML spells them (docs/scene-format.md): the image,
//! camera, nodes, lights, walk and keyframes, with their defaults.

use super::*;

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

pub(super) fn default_size() -> usize {
    512
}

impl Default for ImageSettings {
    fn default() -> Self {
        ImageSettings { width: 512, height: 512, background: [0.0; 3], exposure: 0.0 }
    }
}

pub use crate::catalog::NodeKind;

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
    pub(super) fn is_series(&self) -> bool {
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

impl NodeDesc {
    /// A node of `kind` with every key at its default: no file, the kind's default
    /// renderer, visible.
    pub fn new(name: &str, kind: NodeKind) -> NodeDesc {
        NodeDesc {
            name: name.to_string(),
            kind,
            file: None,
            parent: None,
            transform: Transform::default(),
            renderer: None,
            visible: true,
            settings: toml::Table::new(),
            series: None,
            volume_index: 0,
            resample: false,
            transfer_function: None,
            preset: None,
            preset_shift: 0.0,
            modality: None,
            shading: None,
            crop: None,
            clip: Vec::new(),
            blend: BlendMode::default(),
            opacity_scale: 1.0,
            png: None,
            extent: None,
            texture: None,
            texture_colormap: None,
            texture_range: None,
            elevation_range: None,
            arrays: None,
            medium: None,
            color_by: None,
            color_range: None,
            scale_over: ScaleOver::default(),
        }
    }
}

pub(super) fn yes() -> bool {
    true
}

pub(super) fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

pub(super) fn is_zero_usize(v: &usize) -> bool {
    *v == 0
}

pub(super) fn is_false(v: &bool) -> bool {
    !*v
}

impl BlendMode {
    pub(super) fn is_composite(&self) -> bool {
        *self == BlendMode::Composite
    }
}

pub(super) fn one() -> f64 {
    1.0
}

pub(super) fn is_one(v: &f64) -> bool {
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

    pub(super) fn kind_name(&self) -> &'static str {
        match self.kind {
            LightKind::Directional => "directional",
            LightKind::Point => "point",
            LightKind::Spot => "spot",
        }
    }
}

pub(super) fn white() -> [f64; 3] {
    [1.0; 3]
}
pub(super) fn unit() -> f64 {
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

pub(super) fn default_eye_height() -> f64 {
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
