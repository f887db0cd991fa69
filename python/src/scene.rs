//! `Scene`: a scene file loaded, or a scene built from arrays in memory, with its camera
//! and lights; rendered to a `Frame` with the GIL released and Ctrl-C cancelling, and
//! written back as a scene file (its in-memory data beside it) that `volterra render`
//! draws the same.
//!
//! Every edit goes through the library's `Scene::edited_with_data`: the whole scene is
//! checked again as a scene file is (a bad key fails at the call that set it), and the data
//! already read or given is kept.

use crate::frame::PyFrame;
use crate::input;
use crate::scene_error;
use pyo3::exceptions::{PyKeyError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;
use volterra::render::{self, driver, RenderCache};
use volterra::scene::animation::{self, AnimationFrame};
use volterra::scene::auto::{fit_camera, relocate};
use volterra::scene::drape::Drape;
use volterra::scene::presets::Preset;
use volterra::scene::{Camera, ImageSettings, Light, NodeData, NodeDesc, NodeKind, Scene, SceneFile, VolumeShading};
use volterra_formats::{Dataset, ParticleArrayNames, RgbImage};

/// What a scene built in Python is named in messages (it has no file).
const IN_MEMORY: &str = "<scene from Python>";

/// A scene: nodes (volumes, heightfields, particles), a camera, lights and the image's
/// size, as a scene file describes them (docs/scene-format.md).
#[pyclass(module = "volterra", name = "Scene")]
pub struct PyScene {
    pub(crate) scene: Scene,
    /// What renders keep from frame to frame (shear-warp's preparation, the terrain's
    /// pyramid): a camera moved renders without preparing again.
    cache: RenderCache,
    /// Whether the camera still frames the data by itself (until the caller moves it).
    auto_camera: bool,
}

impl PyScene {
    /// The scene with `file` in place of its description, `given` data for new nodes.
    fn edit(&mut self, file: SceneFile, given: Vec<(String, NodeData)>) -> PyResult<()> {
        self.scene = self.scene.edited_with_data(file, given).map_err(scene_error)?;
        self.cache.keep_only_for(&self.scene);
        Ok(())
    }

    /// The scene with its description changed by `f` (no new data), checked whole.
    fn change(&mut self, f: impl FnOnce(&mut SceneFile)) -> PyResult<()> {
        let mut file = self.scene.file.clone();
        f(&mut file);
        self.edit(file, Vec::new())
    }

    fn unique_name(&self, base: &str) -> String {
        let taken = |n: &str| self.scene.node_index(n).is_some();
        if !taken(base) {
            return base.to_string();
        }
        (2..).map(|k| format!("{base}{k}")).find(|n| !taken(n)).expect("a free name")
    }

    /// Adds node `name` of `kind` with the scene-file keys `options` and data in memory.
    fn add(&mut self, kind: NodeKind, name: Option<String>, options: serde_json::Value, data: NodeData) -> PyResult<String> {
        let name = name.unwrap_or_else(|| self.unique_name(kind_name(kind)));
        let node = node_desc(&name, kind, options)?;
        let mut file = self.scene.file.clone();
        file.nodes.push(node);
        self.edit(file, vec![(name.clone(), data)])?;
        if self.auto_camera {
            // Data with no finite extent (all NoData) leaves the camera where it was: the
            // node is added all the same, and `reset` says why it cannot frame it.
            let _ = self.frame_data();
        }
        Ok(name)
    }

    /// Points the camera at everything the scene holds, as `volterra view` frames a file.
    fn frame_data(&mut self) -> PyResult<()> {
        let mut lo = glam::DVec3::splat(f64::INFINITY);
        let mut hi = glam::DVec3::splat(f64::NEG_INFINITY);
        let mut kinds = Vec::new();
        for i in 0..self.scene.nodes().len() {
            if self.scene.nodes()[i].kind == NodeKind::Group || !self.scene.nodes()[i].visible {
                continue;
            }
            if let Some((a, b)) = self.scene.bounds(i).map_err(scene_error)? {
                lo = lo.min(a);
                hi = hi.max(b);
                kinds.push(self.scene.nodes()[i].kind);
            }
        }
        if kinds.is_empty() {
            return Err(PyValueError::new_err("reset: the scene holds no data with a finite extent to frame"));
        }
        // A scene of one kind is framed as that kind is; a mix as volumes are.
        let kind = if kinds.iter().all(|k| *k == kinds[0]) { kinds[0] } else { NodeKind::Volume };
        let camera = fit_camera(kind, (lo, hi));
        self.change(|file| file.camera = Camera { parallel_projection: file.camera.parallel_projection, ..camera })
    }

    fn camera_edit(&mut self, f: impl FnOnce(&mut Camera) -> PyResult<()>) -> PyResult<()> {
        let mut file = self.scene.file.clone();
        f(&mut file.camera)?;
        self.edit(file, Vec::new())?;
        self.auto_camera = false;
        Ok(())
    }

    /// Renders the scene's camera (or animation frame `frame`) at `size`, the GIL released;
    /// Ctrl-C stops it between bands of rows and raises KeyboardInterrupt.
    fn render_at(&self, py: Python<'_>, scene: &Scene, frame: Option<AnimationFrame>, size: (usize, usize)) -> PyResult<PyFrame> {
        let camera = scene.camera_at(frame).map_err(scene_error)?;
        let cancel = Arc::new(Cancel(AtomicBool::new(false)));
        let done = AtomicBool::new(false);
        let waiting = std::thread::current();
        let cache = &self.cache;
        let result = std::thread::scope(|s| {
            let worker = s.spawn(|| {
                // Raised on the way out, a panic included, so the wait below always ends.
                let _finished = Finished(&done, &waiting);
                driver::observed(cancel.clone(), || render::render_view(scene, &camera, size, cache))
            });
            // This thread waits without the GIL (woken as the render ends) and takes it back
            // every 50 ms to see whether Ctrl-C was pressed (Python sees signals on its
            // main thread only).
            let mut interrupted = None;
            while !done.load(Ordering::Acquire) {
                py.detach(|| std::thread::park_timeout(Duration::from_millis(50)));
                if interrupted.is_none() {
                    if let Err(e) = py.check_signals() {
                        cancel.0.store(true, Ordering::Relaxed);
                        interrupted = Some(e);
                    }
                }
            }
            let r = py.detach(|| worker.join()).map_err(|_| PyValueError::new_err("the render panicked"))?;
            match (interrupted, r) {
                (Some(e), _) => Err(e),
                (None, r) => r.map_err(scene_error),
            }
        })?;
        let image = &scene.file.image;
        Ok(PyFrame::new(result, image.background, image.exposure))
    }
}

/// Raises its flag and wakes the waiting thread when dropped: the render thread has
/// ended, however it ended.
struct Finished<'a>(&'a AtomicBool, &'a std::thread::Thread);

impl Drop for Finished<'_> {
    fn drop(&mut self) {
        self.0.store(true, Ordering::Release);
        self.1.unpark();
    }
}

/// The flag Ctrl-C raises: the render stops between bands of rows.
struct Cancel(AtomicBool);

impl driver::Progress for Cancel {
    fn begin(&self, _: &str, _: u64) {}
    fn update(&self, _: u64) {}
    fn end(&self) {}
    fn cancelled(&self) -> bool {
        self.0.load(Ordering::Relaxed)
    }
}

fn kind_name(kind: NodeKind) -> &'static str {
    match kind {
        NodeKind::Volume => "volume",
        NodeKind::Heightfield => "heightfield",
        NodeKind::Particles => "particles",
        NodeKind::Group => "group",
    }
}

/// A node from the scene-file keys given as keyword arguments (`shading=True` for
/// `shading = { shade = true }`).
fn node_desc(name: &str, kind: NodeKind, mut options: serde_json::Value) -> PyResult<NodeDesc> {
    let serde_json::Value::Object(map) = &mut options else { unreachable!("keyword arguments are a dict") };
    if let Some(serde_json::Value::Bool(b)) = map.get("shading") {
        let v = shading_switch(*b, map.get("preset").and_then(|p| p.as_str()));
        map.insert("shading".into(), v);
    }
    for key in ["name", "kind", "file"] {
        if map.contains_key(key) {
            return Err(PyValueError::new_err(format!("node '{name}': '{key}' is not a keyword here (the node holds its data in memory)")));
        }
    }
    map.insert("name".into(), name.into());
    map.insert("kind".into(), kind_name(kind).into());
    serde_json::from_value(options).map_err(|e| PyValueError::new_err(format!("node '{name}': {e}")))
}

/// `shading=True` or `False` as the node's shading table: the named preset's coefficients
/// where it has them (CT-AAA shades as 3D Slicer does), else VTK's defaults, switched on
/// or off.
fn shading_switch(on: bool, preset: Option<&str>) -> serde_json::Value {
    let coefficients = preset.and_then(|p| Preset::from_name(p).ok()).and_then(Preset::shading).unwrap_or_default();
    let shading = VolumeShading { shade: on, ..coefficients };
    serde_json::to_value(shading).expect("plain numbers")
}

/// Keyword arguments as JSON (an empty object where none).
fn options_of(kwargs: Option<&Bound<'_, PyDict>>) -> PyResult<serde_json::Value> {
    match kwargs {
        Some(k) => input::to_json(k.as_any()),
        None => Ok(serde_json::Value::Object(Default::default())),
    }
}

/// Where the data of in-memory node `node` is written beside a scene file `toml`.
fn data_file_name(toml: &Path, node: &NodeDesc) -> PathBuf {
    let stem = toml.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "scene".into());
    let safe: String = node.name.chars().map(|c| if c.is_ascii_alphanumeric() || c == '-' || c == '_' { c } else { '_' }).collect();
    let ext = match node.kind {
        NodeKind::Volume => "nrrd",
        NodeKind::Heightfield => "tif",
        _ => "vtp",
    };
    PathBuf::from(format!("{stem}-{safe}.{ext}"))
}

#[pymethods]
impl PyScene {
    /// An empty scene of `width` × `height` pixels over `background` (linear RGB): add
    /// data with `add_volume`, `add_heightfield` and `add_particles`. Until the camera is
    /// moved, it frames whatever the scene holds.
    #[new]
    #[pyo3(signature = (*, width=512, height=512, background=(0.0, 0.0, 0.0), max_memory=None))]
    fn new(width: usize, height: usize, background: (f64, f64, f64), max_memory: Option<&Bound<'_, PyAny>>) -> PyResult<PyScene> {
        let file = SceneFile {
            image: ImageSettings { width, height, background: [background.0, background.1, background.2], exposure: 0.0 },
            camera: fit_camera(NodeKind::Volume, (glam::DVec3::ZERO, glam::DVec3::ONE)),
            walk: None,
            keyframes: Vec::new(),
            orbit: None,
            lights: Vec::new(),
            nodes: Vec::new(),
            measurements: Vec::new(),
            slices: None,
        };
        let base = std::env::current_dir().unwrap_or_default();
        let scene = Scene::from_memory(file, base, PathBuf::from(IN_MEMORY), Vec::new()).map_err(scene_error)?;
        Ok(PyScene { scene: scene.with_limits(crate::limits_of(max_memory)?), cache: RenderCache::default(), auto_camera: true })
    }

    /// Reads and checks a scene file (data files are read when first rendered); `set`:
    /// overrides as `volterra render --set` takes them ("node.ct.preset=CT-Bone").
    #[staticmethod]
    #[pyo3(signature = (path, *, set=None, max_memory=None))]
    fn load(path: PathBuf, set: Option<Vec<String>>, max_memory: Option<&Bound<'_, PyAny>>) -> PyResult<PyScene> {
        let scene = Scene::load(&path, &set.unwrap_or_default()).map_err(scene_error)?;
        Ok(PyScene { scene: scene.with_limits(crate::limits_of(max_memory)?), cache: RenderCache::default(), auto_camera: false })
    }

    /// Adds a volume: a `Volume` from `read`, or an array indexed (i, j, k) with its 4×4
    /// affine (voxel index → RAS+ mm; nibabel's `affine`). Other keywords are the scene
    /// file's node keys: `preset="CT-AAA"`, `shading=True`, `renderer="reference"`,
    /// `settings={...}`, `transfer_function={...}`, `crop`, `clip`, `blend="mip"`,
    /// `opacity_scale`, `modality`, `transform`. Returns the node's name.
    #[pyo3(signature = (data, affine=None, *, name=None, **options))]
    fn add_volume(
        &mut self,
        data: &Bound<'_, PyAny>,
        affine: Option<&Bound<'_, PyAny>>,
        name: Option<String>,
        options: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<String> {
        let volume = input::volume("add_volume", data, affine)?;
        self.add(NodeKind::Volume, name, options_of(options)?, NodeData::from(Dataset::Volume(volume)))
    }

    /// Adds a heightfield: a `Heightfield` from `read`, or a 2-D array of elevations in
    /// metres (rows from the north, NaN for NoData) with GDAL's geotransform in metres
    /// (`epsg`: the projected CRS it is in). `drape`: an sRGB image, uint8 (rows, columns,
    /// 3), stretched over the heightfield's extent (an aerial photo, a land-cover map).
    /// Other keywords are node keys: `renderer`, `settings`, `elevation_range`, `texture`
    /// (a file instead of `drape`), `transform`.
    #[pyo3(signature = (data, transform=None, *, name=None, epsg=None, drape=None, **options))]
    fn add_heightfield(
        &mut self,
        data: &Bound<'_, PyAny>,
        transform: Option<&Bound<'_, PyAny>>,
        name: Option<String>,
        epsg: Option<u32>,
        drape: Option<&Bound<'_, PyAny>>,
        options: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<String> {
        let hf = input::heightfield(data, transform, epsg)?;
        let options = options_of(options)?;
        let image = drape.map(input::drape).transpose()?;
        if image.is_some() && options.get("texture").is_some() {
            return Err(PyValueError::new_err("add_heightfield: give a drape or a texture file, not both"));
        }
        let name = self.add(NodeKind::Heightfield, name, options, NodeData::from(Dataset::Heightfield(hf)))?;
        if let Some(image) = image {
            let node = self.scene.node_index(&name).expect("just added");
            self.scene.provide_texture(node, Arc::new(Drape::stretched(&image))).map_err(scene_error)?;
        }
        Ok(name)
    }

    /// Adds particles: `Particles` from `read`, or positions (N × 3) and a dict of point
    /// arrays ((N,) or (N, k)). Other keywords are node keys: `renderer="points"` or
    /// `"smoke"`, `color_by="h"`, `color_range`, `medium={...}`, `settings`, `transform`;
    /// `array_names={"mass": …, "density": …, "smoothing_length": …}` says which arrays
    /// hold the SPH quantities (default mass, density, h).
    #[pyo3(signature = (data, arrays=None, *, name=None, array_names=None, **options))]
    fn add_particles(
        &mut self,
        data: &Bound<'_, PyAny>,
        arrays: Option<&Bound<'_, PyDict>>,
        name: Option<String>,
        array_names: Option<&Bound<'_, PyDict>>,
        options: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<String> {
        let mut options = options_of(options)?;
        let names: ParticleArrayNames = match array_names {
            Some(d) => {
                let v = input::to_json(d.as_any())?;
                options["arrays"] = v.clone();
                serde_json::from_value(v).map_err(|e| PyValueError::new_err(format!("array_names: {e}")))?
            }
            None => ParticleArrayNames::default(),
        };
        let set = input::particles(data, arrays, &names)?;
        self.add(NodeKind::Particles, name, options, NodeData::from(Dataset::Particles(set)))
    }

    /// Changes node keys of node `name` (`scene.update("ct", preset="CT-Bone")`; None
    /// removes a key).
    #[pyo3(signature = (name, **options))]
    fn update(&mut self, name: &str, options: Option<&Bound<'_, PyDict>>) -> PyResult<()> {
        let i = self.scene.node_index(name).ok_or_else(|| PyKeyError::new_err(format!("no node named '{name}'")))?;
        let mut file = self.scene.file.clone();
        let mut node = serde_json::to_value(&file.nodes[i]).map_err(|e| PyValueError::new_err(e.to_string()))?;
        let serde_json::Value::Object(changes) = options_of(options)? else { unreachable!() };
        for (k, v) in changes {
            if matches!(k.as_str(), "name" | "kind" | "file") {
                return Err(PyValueError::new_err(format!("node '{name}': '{k}' cannot be changed")));
            }
            node[k] = v;
        }
        if let Some(on) = node["shading"].as_bool() {
            node["shading"] = shading_switch(on, node["preset"].as_str());
        }
        if let serde_json::Value::Object(m) = &mut node {
            m.retain(|_, v| !v.is_null());
        }
        file.nodes[i] = serde_json::from_value(node).map_err(|e| PyValueError::new_err(format!("node '{name}': {e}")))?;
        self.edit(file, Vec::new())
    }

    /// Removes node `name`.
    fn remove(&mut self, name: &str) -> PyResult<()> {
        let i = self.scene.node_index(name).ok_or_else(|| PyKeyError::new_err(format!("no node named '{name}'")))?;
        self.change(|file| {
            file.nodes.remove(i);
        })
    }

    /// The nodes' names, in drawing order.
    #[getter]
    fn nodes(&self) -> Vec<String> {
        self.scene.nodes().iter().map(|n| n.name.clone()).collect()
    }

    /// Node `name`'s keys as the scene file writes them.
    fn node(&self, py: Python<'_>, name: &str) -> PyResult<Py<PyAny>> {
        let i = self.scene.node_index(name).ok_or_else(|| PyKeyError::new_err(format!("no node named '{name}'")))?;
        let v = serde_json::to_value(&self.scene.nodes()[i]).map_err(|e| PyValueError::new_err(e.to_string()))?;
        crate::to_python(py, &v)
    }

    /// Adds a light (`kind` "directional", "point" or "spot"): a directional light's
    /// `intensity` is irradiance (W/m²), a point or spot light's radiant intensity (W/sr).
    /// Lights shade heightfields and particle smoke (volumes are shaded from the camera,
    /// as VTK does).
    #[pyo3(signature = (kind="directional", *, direction=None, position=None, color=(1.0, 1.0, 1.0), intensity=1.0, cone_angle=None))]
    fn add_light(
        &mut self,
        kind: &str,
        direction: Option<[f64; 3]>,
        position: Option<[f64; 3]>,
        color: (f64, f64, f64),
        intensity: f64,
        cone_angle: Option<f64>,
    ) -> PyResult<()> {
        let light: Light = serde_json::from_value(serde_json::json!({
            "kind": kind, "direction": direction, "position": position,
            "color": [color.0, color.1, color.2], "intensity": intensity, "cone_angle": cone_angle,
        }))
        .map_err(|e| PyValueError::new_err(format!("add_light: {e}")))?;
        match light.kind {
            volterra::scene::LightKind::Directional => light.travel_direction().map(|_| ()),
            volterra::scene::LightKind::Point => light.location().map(|_| ()),
            volterra::scene::LightKind::Spot => light.travel_direction().and(light.location()).map(|_| ()),
        }
        .map_err(|e| PyValueError::new_err(format!("add_light: {e}")))?;
        self.change(|file| file.lights.push(light))
    }

    /// The lights, as the scene file writes them.
    #[getter]
    fn lights(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        let v = serde_json::to_value(&self.scene.file.lights).map_err(|e| PyValueError::new_err(e.to_string()))?;
        crate::to_python(py, &v)
    }

    fn clear_lights(&mut self) -> PyResult<()> {
        self.change(|file| file.lights.clear())
    }

    /// The camera (vtkCamera's semantics): changes to it change the scene's.
    #[getter]
    fn camera(slf: Bound<'_, Self>) -> PyCamera {
        PyCamera { scene: slf.unbind() }
    }

    /// Image width in pixels.
    #[getter]
    fn width(&self) -> usize {
        self.scene.file.image.width
    }
    #[setter]
    fn set_width(&mut self, width: usize) -> PyResult<()> {
        self.change(|file| file.image.width = width)
    }
    /// Image height in pixels.
    #[getter]
    fn height(&self) -> usize {
        self.scene.file.image.height
    }
    #[setter]
    fn set_height(&mut self, height: usize) -> PyResult<()> {
        self.change(|file| file.image.height = height)
    }
    /// Background colour, linear RGB.
    #[getter]
    fn background(&self) -> (f64, f64, f64) {
        let b = self.scene.file.image.background;
        (b[0], b[1], b[2])
    }
    #[setter]
    fn set_background(&mut self, b: (f64, f64, f64)) -> PyResult<()> {
        self.change(|file| file.image.background = [b.0, b.1, b.2])
    }

    /// Renders the scene's camera to a Frame, at the scene's image size unless `width`
    /// and `height` are given (for this render only). The GIL is released; Ctrl-C stops
    /// the render and raises KeyboardInterrupt.
    #[pyo3(signature = (width=None, height=None))]
    fn render(&self, py: Python<'_>, width: Option<usize>, height: Option<usize>) -> PyResult<PyFrame> {
        let image = &self.scene.file.image;
        let size = (width.unwrap_or(image.width), height.unwrap_or(image.height));
        if size.0 == 0 || size.1 == 0 || size.0 > 16384 || size.1 > 16384 {
            return Err(PyValueError::new_err(format!("render: image size {}×{} must be between 1 and 16384", size.0, size.1)));
        }
        self.render_at(py, &self.scene, None, size)
    }

    /// Makes the scene's animation a turntable: `degrees` about `axis` through the focal
    /// point over `frames` frames (the scene file's `[orbit]`; a whole number of turns
    /// loops). Replaces keyframes.
    #[pyo3(signature = (degrees=360.0, *, frames=None, axis=(0.0, 0.0, 1.0)))]
    fn set_orbit(&mut self, degrees: f64, frames: Option<usize>, axis: (f64, f64, f64)) -> PyResult<()> {
        let orbit: animation::Orbit =
            serde_json::from_value(serde_json::json!({ "degrees": degrees, "frames": frames, "axis": [axis.0, axis.1, axis.2] }))
                .map_err(|e| PyValueError::new_err(format!("set_orbit: {e}")))?;
        self.change(|file| {
            file.orbit = Some(orbit);
            file.keyframes.clear();
        })
    }

    /// The frames of the scene's animation (its time series' steps, its keyframes or
    /// orbit; `count` frames where given), rendered one at a time as they are taken:
    /// `for frame in scene.render_frames(): ...`.
    #[pyo3(signature = (count=None))]
    fn render_frames(slf: Bound<'_, Self>, count: Option<usize>) -> PyResult<PyFrames> {
        let frames = animation::frames(&slf.borrow().scene, count).map_err(scene_error)?;
        Ok(PyFrames { scene: slf.unbind(), frames, next: 0 })
    }

    /// The scene file's text. With `path`, it is also written there, and the data of nodes
    /// held in memory is written beside it (volumes as NRRD, heightfields as GeoTIFF,
    /// particles as VTK .vtp), so that `volterra render path` draws this scene.
    #[pyo3(signature = (path=None))]
    fn to_toml(&self, py: Python<'_>, path: Option<PathBuf>) -> PyResult<String> {
        let mut file = self.scene.file.clone();
        let memory: Vec<usize> =
            (0..file.nodes.len()).filter(|&i| file.nodes[i].kind != NodeKind::Group && file.nodes[i].file.is_none()).collect();
        let Some(path) = path else {
            if let Some(&i) = memory.first() {
                return Err(PyValueError::new_err(format!(
                    "to_toml: node '{}' holds its data in memory; give a path, and its data is written beside the scene file",
                    file.nodes[i].name
                )));
            }
            return toml::to_string(&file).map_err(|e| PyValueError::new_err(format!("to_toml: {e}")));
        };
        let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).map(Path::to_path_buf).unwrap_or_else(|| PathBuf::from("."));
        relocate(&mut file, &self.scene.base_dir, &dir);
        for &i in &memory {
            let data = self.scene.data(i).map_err(scene_error)?;
            let name = data_file_name(&path, &file.nodes[i]);
            let target = dir.join(&name);
            let names = file.nodes[i].arrays.clone().unwrap_or_default();
            py.detach(|| match &data {
                NodeData::Volume(v) => volterra_formats::nrrd::write_nrrd(&target, v),
                NodeData::Heightfield(h) => volterra_formats::geotiff_write::write_geotiff(&target, h),
                NodeData::Particles(p) => volterra_formats::vtk::write_vtp(&target, p, &names),
            })
            .map_err(crate::py_error)?;
            file.nodes[i].file = Some(name);
        }
        // Drapes held in memory, written as the PNGs a scene file stretches over its node.
        for i in 0..file.nodes.len() {
            if file.nodes[i].texture.is_some() {
                continue;
            }
            let Some(drape) = self.scene.texture(i).map_err(scene_error)? else { continue };
            let name = data_file_name(&path, &file.nodes[i]).with_extension("drape.png");
            let image = RgbImage {
                width: drape.width,
                height: drape.height,
                data: drape.rgba.chunks_exact(4).flat_map(|p| [p[0], p[1], p[2]]).collect(),
            };
            volterra_formats::image::write_png_rgb8(&dir.join(&name), &image).map_err(crate::py_error)?;
            file.nodes[i].texture = Some(name);
        }
        let text = toml::to_string(&file).map_err(|e| PyValueError::new_err(format!("to_toml: {e}")))?;
        let text = format!("# Written by volterra's Python package; render with `volterra render {} -o OUT.exr`.\n{text}", path.display());
        volterra_formats::atomic::write_bytes_atomically(&path, text.as_bytes()).map_err(crate::py_error)?;
        Ok(text)
    }

    fn __repr__(&self) -> String {
        let nodes: Vec<String> = self.scene.nodes().iter().map(|n| format!("{} ({})", n.name, kind_name(n.kind))).collect();
        format!("<volterra.Scene {}×{}: {}>", self.scene.file.image.width, self.scene.file.image.height, nodes.join(", "))
    }
}

/// The frames of a scene's animation, each rendered when it is taken.
#[pyclass(module = "volterra", name = "Frames")]
pub struct PyFrames {
    scene: Py<PyScene>,
    frames: Vec<AnimationFrame>,
    next: usize,
}

#[pymethods]
impl PyFrames {
    fn __iter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }
    fn __len__(&self) -> usize {
        self.frames.len()
    }
    fn __next__(&mut self, py: Python<'_>) -> PyResult<Option<PyFrame>> {
        let Some(f) = self.frames.get(self.next).copied() else { return Ok(None) };
        self.next += 1;
        let this = self.scene.borrow(py);
        let size = (this.scene.file.image.width, this.scene.file.image.height);
        match f.time {
            Some(t) => {
                let at = this.scene.at_time(t);
                this.cache.keep_only_for(&at);
                this.render_at(py, &at, Some(f), size)
            }
            None => this.render_at(py, &this.scene, Some(f), size),
        }
        .map(Some)
    }
}

/// The scene's camera, with vtkCamera's names: `position`, `focal_point`, `view_up`,
/// `view_angle` (degrees), `parallel_projection`, `parallel_scale`; `azimuth`,
/// `elevation`, `zoom`, `dolly` and `reset` move it as VTK's do.
#[pyclass(module = "volterra", name = "Camera")]
pub struct PyCamera {
    scene: Py<PyScene>,
}

impl PyCamera {
    fn get<T>(&self, py: Python<'_>, f: impl FnOnce(&Camera) -> T) -> T {
        f(&self.scene.borrow(py).scene.file.camera)
    }
    fn set(&self, py: Python<'_>, f: impl FnOnce(&mut Camera) -> PyResult<()>) -> PyResult<()> {
        self.scene.borrow_mut(py).camera_edit(f)
    }
}

fn finite3(what: &str, v: [f64; 3]) -> PyResult<[f64; 3]> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(v)
    } else {
        Err(PyValueError::new_err(format!("camera {what} {v:?} must be finite")))
    }
}

/// `p` turned by `degrees` about the axis `axis` through `centre`.
fn rotate_about(p: glam::DVec3, centre: glam::DVec3, axis: glam::DVec3, degrees: f64) -> glam::DVec3 {
    centre + glam::DQuat::from_axis_angle(axis.normalize(), degrees.to_radians()) * (p - centre)
}

#[pymethods]
impl PyCamera {
    #[getter]
    fn position(&self, py: Python<'_>) -> [f64; 3] {
        self.get(py, |c| c.position)
    }
    #[setter]
    fn set_position(&self, py: Python<'_>, v: [f64; 3]) -> PyResult<()> {
        let v = finite3("position", v)?;
        self.set(py, |c| {
            c.position = v;
            Ok(())
        })
    }
    #[getter]
    fn focal_point(&self, py: Python<'_>) -> [f64; 3] {
        self.get(py, |c| c.focal_point)
    }
    #[setter]
    fn set_focal_point(&self, py: Python<'_>, v: [f64; 3]) -> PyResult<()> {
        let v = finite3("focal_point", v)?;
        self.set(py, |c| {
            c.focal_point = v;
            Ok(())
        })
    }
    #[getter]
    fn view_up(&self, py: Python<'_>) -> [f64; 3] {
        self.get(py, |c| c.view_up)
    }
    #[setter]
    fn set_view_up(&self, py: Python<'_>, v: [f64; 3]) -> PyResult<()> {
        let v = finite3("view_up", v)?;
        self.set(py, |c| {
            c.view_up = v;
            Ok(())
        })
    }
    /// Vertical field of view in degrees (perspective).
    #[getter]
    fn view_angle(&self, py: Python<'_>) -> f64 {
        self.get(py, |c| c.view_angle)
    }
    #[setter]
    fn set_view_angle(&self, py: Python<'_>, v: f64) -> PyResult<()> {
        self.set(py, |c| {
            c.view_angle = v;
            Ok(())
        })
    }
    #[getter]
    fn parallel_projection(&self, py: Python<'_>) -> bool {
        self.get(py, |c| c.parallel_projection)
    }
    #[setter]
    fn set_parallel_projection(&self, py: Python<'_>, v: bool) -> PyResult<()> {
        self.set(py, |c| {
            c.parallel_projection = v;
            Ok(())
        })
    }
    /// Half the view height in world units (parallel projection).
    #[getter]
    fn parallel_scale(&self, py: Python<'_>) -> f64 {
        self.get(py, |c| c.parallel_scale)
    }
    #[setter]
    fn set_parallel_scale(&self, py: Python<'_>, v: f64) -> PyResult<()> {
        self.set(py, |c| {
            c.parallel_scale = v;
            Ok(())
        })
    }

    /// Turns the camera `degrees` about the view-up axis through the focal point
    /// (vtkCamera::Azimuth: a turntable step).
    fn azimuth(&self, py: Python<'_>, degrees: f64) -> PyResult<()> {
        self.set(py, |c| {
            let (eye, focal, up) = (glam::DVec3::from(c.position), glam::DVec3::from(c.focal_point), glam::DVec3::from(c.view_up));
            c.position = rotate_about(eye, focal, up, degrees).to_array();
            Ok(())
        })
    }
    /// `azimuth`, by the name the turntable goes by.
    fn orbit(&self, py: Python<'_>, degrees: f64) -> PyResult<()> {
        self.azimuth(py, degrees)
    }
    /// Turns the camera `degrees` up about the axis through the focal point that is the
    /// view's horizontal (vtkCamera::Elevation; view_up follows, as OrthogonalizeViewUp).
    fn elevation(&self, py: Python<'_>, degrees: f64) -> PyResult<()> {
        self.set(py, |c| {
            let (eye, focal) = (glam::DVec3::from(c.position), glam::DVec3::from(c.focal_point));
            let forward = (focal - eye).normalize();
            let right = forward.cross(glam::DVec3::from(c.view_up)).normalize();
            let up = right.cross(forward);
            c.position = rotate_about(eye, focal, right, -degrees).to_array();
            c.view_up = rotate_about(up, glam::DVec3::ZERO, right, -degrees).to_array();
            Ok(())
        })
    }
    /// Narrows the view by `factor` (vtkCamera::Zoom: the angle, or the parallel scale).
    fn zoom(&self, py: Python<'_>, factor: f64) -> PyResult<()> {
        if !(factor.is_finite() && factor > 0.0) {
            return Err(PyValueError::new_err(format!("zoom factor {factor} must be positive")));
        }
        self.set(py, |c| {
            if c.parallel_projection {
                c.parallel_scale /= factor;
            } else {
                let half = (0.5 * c.view_angle.to_radians()).tan() / factor;
                c.view_angle = 2.0 * half.atan().to_degrees();
            }
            Ok(())
        })
    }
    /// Moves the eye toward the focal point, dividing their distance by `factor`
    /// (vtkCamera::Dolly).
    fn dolly(&self, py: Python<'_>, factor: f64) -> PyResult<()> {
        if !(factor.is_finite() && factor > 0.0) {
            return Err(PyValueError::new_err(format!("dolly factor {factor} must be positive")));
        }
        self.set(py, |c| {
            let (eye, focal) = (glam::DVec3::from(c.position), glam::DVec3::from(c.focal_point));
            c.position = (focal + (eye - focal) / factor).to_array();
            Ok(())
        })
    }
    /// Frames everything the scene holds, as `volterra view` frames a file (volumes from
    /// the front, terrain from its south-west, particles from the south).
    fn reset(&self, py: Python<'_>) -> PyResult<()> {
        let mut s = self.scene.borrow_mut(py);
        s.frame_data()
    }
    /// The camera as the scene file writes it.
    fn to_dict(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        let v = self.get(py, |c| serde_json::to_value(c)).map_err(|e| PyValueError::new_err(e.to_string()))?;
        crate::to_python(py, &v)
    }
    fn __repr__(&self, py: Python<'_>) -> String {
        self.get(py, |c| {
            format!(
                "<volterra.Camera position {:?}, focal_point {:?}, view_up {:?}, {}>",
                c.position,
                c.focal_point,
                c.view_up,
                if c.parallel_projection {
                    format!("parallel scale {}", c.parallel_scale)
                } else {
                    format!("view angle {}°", c.view_angle)
                }
            )
        })
    }
}
