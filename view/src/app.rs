//! The viewer's state and UI. Everything the window shows is drawn from here; renders come
//! from the [`RenderWorker`] thread, so the UI never waits on a renderer.
//!
//! Progressive rendering: every change (camera, transfer function, settings) bumps a
//! version. While the user is moving things, quarter-resolution previews are requested;
//! once nothing has changed for [`SETTLE`], the full-resolution frame, which is exactly what
//! `volterra render` draws for the scene "Save scene" writes.

use super::files::{start_dir, FileDialog};
use super::measure::{RoiStats, Tool};
use super::navigate::{self, AxisView};
use super::slices::{Overlay, Plane, SliceImage, SliceSource};
use super::transfer_editor::{srgb, TfEditor};
use super::worker::{Done, Job, Quality, RenderWorker};
use anyhow::{anyhow, Result};
use egui::{Color32, Pos2, Rect, Sense, Vec2};
use glam::DVec3;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::{Duration, Instant};
use volterra::render::registry;
use volterra::render::Frame;
use volterra::scene::auto::{fit_camera, relative_path, scene_for_file};
use volterra::scene::presets::ValueStats;
use volterra::scene::{BlendMode, Camera, Measurement, MeasurementKind, NodeData, NodeKind, Scene, TerrainData, VolumeShading};
use volterra_formats::LoadOptions;

/// How long the view must stay unchanged before the full-resolution frame is requested.
pub const SETTLE: Duration = Duration::from_millis(250);
/// Previews render one pixel per PREVIEW_DIV² of the viewport.
const PREVIEW_DIV: usize = 4;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NavMode {
    /// Trackball about the focal point (ParaView/pyvista).
    Orbit,
    /// Mouse look about the eye, WASD along the view, Q/E down and up.
    Fly,
    /// As fly, with the eye kept `eye_height` above the terrain.
    Walk,
}

/// A document read off the UI thread, ready to show.
struct Opened {
    path: PathBuf,
    scene: Scene,
    stats: Vec<Option<Arc<ValueStats>>>,
    camera: Camera,
}

/// What opening a path gives: a document, or a DICOM folder's series to choose from.
enum Loaded {
    Document(Box<Opened>),
    Series { dir: PathBuf, series: Vec<volterra_formats::dicom::SeriesSummary> },
}

/// Reads what `path` names: a folder holding several DICOM series (none chosen in `load`)
/// gives the list to choose from, anything else the document.
fn load_path(path: &Path, load: &LoadOptions) -> Result<Loaded> {
    if path.is_dir() && load.dicom.series.is_none() {
        let series = volterra_formats::dicom::list_series(path, &load.limits)?;
        if series.len() > 1 {
            return Ok(Loaded::Series { dir: path.to_path_buf(), series });
        }
    }
    load_document(path, load).map(|o| Loaded::Document(Box::new(o)))
}

/// Reads a scene file or a data file, and everything the viewer derives from the data.
fn load_document(path: &Path, load: &LoadOptions) -> Result<Opened> {
    let is_scene = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("toml"));
    let scene = if is_scene { Scene::load(path, &[])?.with_limits(load.limits) } else { scene_for_file(path, load)? };
    let mut stats = vec![None; scene.nodes().len()];
    for (i, n) in scene.nodes().iter().enumerate() {
        if n.kind == NodeKind::Volume {
            // The scene's own statistics, which its presets are placed by too.
            stats[i] = Some(scene.value_stats(i)?);
        } else if n.kind == NodeKind::Heightfield {
            // Opened now as its renderer reads it (a GeoTIFF by rows, not held), and its
            // range found (the metadata panel and the terrain's preparation need it).
            if let TerrainData::Rows(rows) = scene.terrain_data(i)? {
                rows.summary();
                if let Some(why) = rows.failure() {
                    anyhow::bail!("{why}");
                }
            }
        } else if n.kind != NodeKind::Group {
            // Read now, not on the render thread's first frame.
            scene.data(i)?;
        }
    }
    let camera = if is_scene { scene.camera(None)? } else { scene.file.camera.clone() };
    Ok(Opened { path: path.to_path_buf(), scene, stats, camera })
}

/// The open scene and what the viewer derived from it.
struct Document {
    scene: Arc<Scene>,
    /// Per node: value statistics of volumes (histogram, presets).
    stats: Vec<Option<Arc<ValueStats>>>,
    /// The camera "Reset camera" returns to.
    home: Camera,
    /// The measurements taken on the slices (saved as the scene's `[[measurement]]`s),
    /// each with an ellipse's statistics.
    measurements: Vec<(Measurement, Option<RoiStats>)>,
}

/// An ellipse measurement's statistics on its volume node (None for other kinds).
fn measurement_stats(scene: &Scene, m: &Measurement) -> Option<RoiStats> {
    if m.kind != MeasurementKind::Ellipse {
        return None;
    }
    let node = scene.nodes().iter().position(|n| n.name == m.node)?;
    let source = SliceSource::new(scene.volume(node).ok()?, scene.world_transform(node));
    let plane = Plane::ALL.into_iter().find(|p| Some(p.scene_plane()) == m.plane)?;
    super::measure::roi_stats(&source, plane, m)
}

struct StatusError {
    text: String,
    from_render: bool,
}

impl StatusError {
    /// An error of an action (open, save, an edit the scene refused): it stays until the
    /// next action succeeds, whatever frames arrive meanwhile.
    fn action(text: impl Into<String>) -> Self {
        Self { text: text.into(), from_render: false }
    }
}

struct Shown {
    version: u64,
    quality: Quality,
    texture: egui::TextureHandle,
    steps: Option<egui::TextureHandle>,
    seconds: f64,
    renderer: String,
    size: (usize, usize),
}

struct SliceState {
    node: usize,
    source: SliceSource,
    cross: DVec3,
    window: f64,
    level: f64,
    images: Vec<(SliceImage, egui::TextureHandle)>,
    /// Each slice's colours as shown (the grey, fused with the overlay).
    shown: Vec<Vec<[u8; 3]>>,
    overlay: Option<OverlayState>,
    /// Where each slice was drawn last frame.
    rects: Vec<Rect>,
    dirty: bool,
}

/// A second volume fused over the slices.
struct OverlayState {
    node: usize,
    source: SliceSource,
    window: f64,
    level: f64,
    colormap: volterra::render::colormap::Colormap,
    opacity: f64,
}

pub struct Viewer {
    doc: Option<Document>,
    worker: RenderWorker,
    wake: Arc<OnceLock<egui::Context>>,
    camera: Camera,
    version: u64,
    submitted: Option<(u64, Quality, (usize, usize))>,
    shown: Option<Shown>,
    /// The newest full-quality frame and the version it shows.
    last_full: Option<(u64, Frame)>,
    /// Relative RMSE of the full frame against the reference renderer, by version.
    error_vs_reference: Option<(u64, Result<f64, String>)>,
    reference_pending: bool,
    changed_at: Option<Instant>,
    /// The error the status bar shows, and whether a render reported it: a frame that
    /// arrives clears only a render's error — a late frame of the old scene once wiped the
    /// error of a file dropped just after it.
    error: Option<StatusError>,
    message: Option<String>,
    selected: usize,
    tf_editor: TfEditor,
    slices: Option<SliceState>,
    show_slices: bool,
    /// The orientation marker and scale bar over the 3-D view.
    show_view_marks: bool,
    /// What a click does: move the cross-hair (3-D view: nothing) or place a measurement's
    /// points on a slice or the 3-D view's surface.
    tool: Tool,
    /// The points of the measurement being placed, and where: slice k, or None for the 3-D
    /// view's surface.
    pending: Vec<DVec3>,
    pending_on: Option<usize>,
    /// The slice views a scene was saved with, applied when they are next built.
    restore_slices: Option<volterra::scene::SliceViews>,
    dialog: FileDialog,
    save_path: String,
    mode: NavMode,
    eye_height: f64,
    show_steps: bool,
    load: LoadOptions,
    /// Write a PNG of the window after the first full frame, then close (for checking a
    /// real window, e.g. under Xvfb).
    screenshot_then_quit: Option<PathBuf>,
    screenshot_state: Arc<Mutex<ScreenshotState>>,
    /// Where the 3-D view was laid out last frame (its size is the render size).
    viewport_rect: Option<Rect>,
    last_size: Option<(usize, usize)>,
    /// Frames shown so far, by quality (previews, full).
    frames_shown: [usize; 3],
    /// A file being read in the background.
    opening: Option<(PathBuf, std::sync::mpsc::Receiver<Result<Loaded>>)>,
    /// A DICOM folder's series, shown for the user to choose one.
    series_choice: Option<SeriesChoice>,
    /// The crop box face whose handle is being dragged in the 3-D view.
    crop_drag: Option<usize>,
    /// Playing a time series: the next step follows each full frame.
    playing: bool,
}

/// The series browser's state: the folder, its series, the row selected.
struct SeriesChoice {
    dir: PathBuf,
    series: Vec<volterra_formats::dicom::SeriesSummary>,
    selected: usize,
}

#[derive(Default, PartialEq)]
enum ScreenshotState {
    #[default]
    Waiting,
    /// The full frame was painted once; the request goes out on the next frame.
    Painted(u32),
    Requested,
    Saved(Result<(), String>),
}

impl Viewer {
    pub fn new(load: LoadOptions) -> Viewer {
        let wake: Arc<OnceLock<egui::Context>> = Arc::default();
        let w = wake.clone();
        let worker = RenderWorker::start(move || {
            if let Some(ctx) = w.get() {
                ctx.request_repaint();
            }
        });
        Viewer {
            doc: None,
            worker,
            wake,
            camera: Camera {
                position: [0.0, 1.0, 0.0],
                focal_point: [0.0; 3],
                view_up: [0.0, 0.0, 1.0],
                view_angle: 30.0,
                parallel_projection: false,
                parallel_scale: 1.0,
            },
            version: 0,
            submitted: None,
            shown: None,
            last_full: None,
            error_vs_reference: None,
            reference_pending: false,
            changed_at: None,
            error: None,
            message: None,
            selected: 0,
            tf_editor: TfEditor::default(),
            slices: None,
            show_slices: true,
            show_view_marks: true,
            tool: Tool::CrossHair,
            pending: vec![],
            pending_on: None,
            restore_slices: None,
            dialog: FileDialog::new(start_dir(None)),
            save_path: String::new(),
            mode: NavMode::Orbit,
            crop_drag: None,
            playing: false,
            series_choice: None,
            eye_height: 1.7,
            show_steps: false,
            load,
            screenshot_then_quit: None,
            screenshot_state: Arc::default(),
            viewport_rect: None,
            last_size: None,
            opening: None,
            frames_shown: [0; 3],
        }
    }

    /// After the first full frame, save a PNG of the whole window to `path` and close.
    pub fn screenshot_then_quit(&mut self, path: PathBuf) {
        self.screenshot_then_quit = Some(path);
    }

    /// Opens a scene file (.toml) or a data file / DICOM folder, waiting for it to load.
    pub fn open(&mut self, path: &Path) -> Result<()> {
        let loaded = load_path(path, &self.load)?;
        self.take_loaded(loaded);
        Ok(())
    }

    /// Opens `path` now; a DICOM folder of several series without `--series` is an error
    /// (for `--screenshot`, where no one is there to choose in the series browser).
    pub fn open_without_choosing(&mut self, path: &Path) -> Result<()> {
        let opened = load_document(path, &self.load)?;
        self.install(opened);
        Ok(())
    }

    fn take_loaded(&mut self, loaded: Loaded) {
        match loaded {
            Loaded::Document(o) => self.install(*o),
            Loaded::Series { dir, series } => {
                self.message = Some(format!("{} holds {} series: choose one", dir.display(), series.len()));
                self.series_choice = Some(SeriesChoice { dir, series, selected: 0 });
            }
        }
    }

    /// The series of the DICOM folder being chosen from, if any.
    pub fn series_to_choose(&self) -> Option<&[volterra_formats::dicom::SeriesSummary]> {
        self.series_choice.as_ref().map(|c| c.series.as_slice())
    }

    /// Opens series `uid` of the DICOM folder `dir` (the series browser's choice).
    pub fn open_series(&mut self, dir: PathBuf, uid: String) {
        let mut load = self.load.clone();
        load.dicom.series = Some(uid);
        self.series_choice = None;
        self.open_with(dir, load);
    }

    /// Starts loading `path` on a thread; the UI keeps running and shows the document
    /// when it is read (a DICOM series of a thousand slices takes seconds).
    pub fn open_in_background(&mut self, path: PathBuf) {
        self.open_with(path, self.load.clone());
    }

    fn open_with(&mut self, path: PathBuf, load: LoadOptions) {
        let (tx, rx) = std::sync::mpsc::channel();
        let wake = self.wake.clone();
        let p = path.clone();
        std::thread::spawn(move || {
            let _ = tx.send(load_path(&p, &load));
            if let Some(ctx) = wake.get() {
                ctx.request_repaint();
            }
        });
        self.message = Some(format!("reading {}", path.display()));
        self.opening = Some((path, rx));
    }

    /// True while a file given to [`Self::open_in_background`] is still being read.
    pub fn loading(&self) -> bool {
        self.opening.is_some()
    }

    fn poll_opening(&mut self) {
        let Some((_, rx)) = &self.opening else { return };
        match rx.try_recv() {
            Ok(Ok(loaded)) => {
                self.opening = None;
                self.take_loaded(loaded);
            }
            Ok(Err(e)) => {
                self.opening = None;
                self.error = Some(StatusError::action(format!("{e:#}")));
            }
            Err(std::sync::mpsc::TryRecvError::Empty) => {}
            Err(std::sync::mpsc::TryRecvError::Disconnected) => {
                self.opening = None;
                self.error = Some(StatusError::action("reading the file stopped unexpectedly"));
            }
        }
    }

    fn install(&mut self, o: Opened) {
        self.camera = o.camera;
        if let Some(w) = &o.scene.file.walk {
            self.eye_height = w.eye_height;
            self.mode = NavMode::Walk;
        } else {
            self.mode = NavMode::Orbit;
        }
        self.selected = o.scene.nodes().iter().position(|n| n.kind != NodeKind::Group).unwrap_or(0);
        // The slice views as the scene was saved: their volume selected, the rest restored
        // when the slice panel is built.
        self.restore_slices = o.scene.file.slices.clone();
        if let Some(i) = self.restore_slices.as_ref().and_then(|v| o.scene.nodes().iter().position(|n| n.name == v.node)) {
            self.selected = i;
        }
        self.dialog.dir = start_dir(Some(&o.path));
        self.save_path = default_save_path(&o.path);
        self.message = Some(format!("opened {}", o.path.display()));
        let measurements = o.scene.file.measurements.iter().map(|m| (m.clone(), measurement_stats(&o.scene, m))).collect();
        self.doc = Some(Document { home: self.camera.clone(), scene: Arc::new(o.scene), stats: o.stats, measurements });
        self.tf_editor = TfEditor::default();
        self.slices = None;
        self.shown = None;
        self.last_full = None;
        self.error_vs_reference = None;
        self.error = None;
        // A preview first, as after a camera move: something to look at within a moment.
        self.bump(true);
    }

    /// The scene as the viewer shows it now (camera included).
    pub fn scene(&self) -> Option<&Scene> {
        self.doc.as_ref().map(|d| &*d.scene)
    }

    pub fn camera(&self) -> &Camera {
        &self.camera
    }

    /// The newest full-quality frame, if it shows the current state.
    pub fn current_full_frame(&self) -> Option<&Frame> {
        self.last_full.as_ref().filter(|(v, _)| *v == self.version).map(|(_, f)| f)
    }

    /// The cross-hair of the slice views (world RAS+ mm), once they are shown.
    pub fn slice_cross(&self) -> Option<DVec3> {
        self.slices.as_ref().map(|s| s.cross)
    }

    /// The colours a slice view shows (sRGB; `plane`: 0 axial, 1 coronal, 2 sagittal), with
    /// its size.
    pub fn slice_colours(&self, plane: usize) -> Option<(usize, usize, &[[u8; 3]])> {
        let s = self.slices.as_ref()?;
        let (img, _) = s.images.get(plane)?;
        Some((img.width, img.height, s.shown.get(plane)?.as_slice()))
    }

    /// The measurements taken (in the order taken), with each ellipse's statistics.
    pub fn measurements(&self) -> &[(Measurement, Option<RoiStats>)] {
        self.doc.as_ref().map_or(&[], |d| &d.measurements)
    }

    /// The newest distance measured on the slices, in millimetres.
    pub fn measured_mm(&self) -> Option<f64> {
        self.measurements().iter().rev().find(|(m, _)| m.kind == MeasurementKind::Distance).map(|(m, _)| m.value())
    }

    /// Drops every measurement.
    pub fn clear_measurements(&mut self) {
        if let Some(d) = &mut self.doc {
            d.measurements.clear();
        }
    }

    /// Where slice view `plane` (0 axial, 1 coronal, 2 sagittal) was drawn, and the world
    /// point under a window position in it.
    pub fn slice_point(&self, plane: usize, pos: Pos2) -> Option<(Rect, DVec3)> {
        let s = self.slices.as_ref()?;
        let (r, (img, _)) = (s.rects.get(plane)?, s.images.get(plane)?);
        let u = (pos.x - r.left()) / r.width() * img.width as f32;
        let v = (pos.y - r.top()) / r.height() * img.height as f32;
        Some((*r, img.world_at(u as f64, v as f64)))
    }

    /// The slice views' window and level.
    pub fn window_level(&self) -> Option<(f64, f64)> {
        self.slices.as_ref().map(|s| (s.window, s.level))
    }

    /// The 3-D view's orientation marker (the world axes' screen directions) and scale bar
    /// (world length, points), as drawn; None while they are hidden or nothing is shown.
    pub fn view_marks(&self) -> Option<([Vec2; 3], (f64, f32))> {
        let rect = self.viewport_rect?;
        (self.show_view_marks && self.doc.is_some())
            .then(|| (super::view_marks::marker_axes(&self.camera), super::view_marks::scale_bar(&self.camera, rect)))
    }

    /// Where the 3-D view lies in the window (points).
    pub fn viewport_rect(&self) -> Option<Rect> {
        self.viewport_rect
    }

    /// How many frames of quality `q` have been shown (tests of progressive rendering).
    pub fn frames_shown(&self, q: Quality) -> usize {
        self.frames_shown[q as usize]
    }

    /// The last error a render or an action reported.
    pub fn last_error(&self) -> Option<&str> {
        self.error.as_ref().map(|e| e.text.as_str())
    }

    /// Messages of the status bar (tests read what an action said).
    pub fn message(&self) -> Option<&str> {
        self.message.as_deref()
    }

    /// True while the worker renders or has work queued.
    pub fn rendering(&self) -> bool {
        self.worker.busy()
    }

    /// Blocks until the render thread is idle (tests).
    pub fn wait_for_renders(&self, timeout: Duration) -> bool {
        self.worker.wait_idle(timeout)
    }

    /// Marks the state changed; `moving` means more changes are coming (preview quality).
    fn bump(&mut self, moving: bool) {
        self.version += 1;
        self.changed_at = if moving { Some(Instant::now()) } else { None };
    }

    /// Applies an edit to the scene description and rebuilds the scene (data kept).
    fn edit(&mut self, moving: bool, f: impl FnOnce(&mut volterra::scene::SceneFile)) {
        let Some(doc) = &mut self.doc else { return };
        let mut file = doc.scene.file.clone();
        f(&mut file);
        match doc.scene.edited(file) {
            Ok(s) => {
                doc.scene = Arc::new(s);
                self.bump(moving);
            }
            Err(e) => self.error = Some(StatusError::action(format!("{e:#}"))),
        }
    }

    /// Writes the current view as a scene file that `volterra render` reproduces: the
    /// camera, the size of the full-resolution frame, data paths relative to the new file.
    pub fn save_scene(&self, path: &Path) -> Result<()> {
        let doc = self.doc.as_ref().ok_or_else(|| anyhow!("nothing is open"))?;
        let mut file = doc.scene.file.clone();
        file.camera = self.camera.clone();
        file.measurements = doc.measurements.iter().map(|(m, _)| m.clone()).collect();
        // The slice views as shown (else as the scene had them, if never built).
        if let Some(s) = &self.slices {
            let name = |i: usize| doc.scene.nodes()[i].name.clone();
            file.slices = Some(volterra::scene::SliceViews {
                node: name(s.node),
                window: s.window,
                level: s.level,
                cross: s.cross.to_array(),
                overlay: s.overlay.as_ref().map(|o| volterra::scene::SliceOverlay {
                    node: name(o.node),
                    colormap: o.colormap.name().to_string(),
                    window: o.window,
                    level: o.level,
                    opacity: o.opacity,
                }),
            });
        }
        if let Some(s) = &self.shown {
            let (w, h) = if s.quality == Quality::Full { s.size } else { (s.size.0 * PREVIEW_DIV, s.size.1 * PREVIEW_DIV) };
            file.image.width = w;
            file.image.height = h;
        }
        // The eye height of a walk is already applied to the camera; keep walking on.
        if let (NavMode::Walk, None) = (self.mode, &file.walk) {
            if let Some(n) = file.nodes.iter().find(|n| n.kind == NodeKind::Heightfield) {
                file.walk = Some(volterra::scene::Walk { node: n.name.clone(), eye_height: self.eye_height });
            }
        }
        let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
        for n in &mut file.nodes {
            if let Some(f) = &n.file {
                n.file = Some(relative_path(&doc.scene.base_dir.join(f), dir));
            }
            if let Some(t) = &n.texture {
                n.texture = Some(relative_path(&doc.scene.base_dir.join(t), dir));
            }
        }
        let text = toml::to_string(&file).map_err(|e| anyhow!("{}: cannot write the scene: {e}", path.display()))?;
        let text = format!("# Saved by `volterra view`; render with `volterra render {} -o OUT.exr`.\n{text}", path.display());
        volterra_formats::atomic::write_bytes_atomically(path, text.as_bytes())?;
        Ok(())
    }

    /// Writes the newest full frame as EXR (R, G, B, A, Z and extra channels) or PNG.
    pub fn save_image(&self, path: &Path) -> Result<()> {
        let doc = self.doc.as_ref().ok_or_else(|| anyhow!("nothing is open"))?;
        let (_, frame) = self.last_full.as_ref().ok_or_else(|| anyhow!("no full-quality frame yet"))?;
        let (bg, exposure) = (doc.scene.file.image.background, doc.scene.file.image.exposure);
        let lower = path.to_string_lossy().to_ascii_lowercase();
        if lower.ends_with(".exr") {
            volterra_formats::exr_io::write_exr(path, &frame.to_image(bg))?;
        } else if lower.ends_with(".png") {
            volterra_formats::image::write_png_preview(path, frame.width, frame.height, &frame.preview_rgba(bg, exposure))?;
        } else {
            return Err(anyhow!("{}: save images as .exr or .png", path.display()));
        }
        Ok(())
    }

    fn save(&mut self) {
        let path = PathBuf::from(self.save_path.trim());
        let lower = self.save_path.to_ascii_lowercase();
        let r = if lower.ends_with(".toml") { self.save_scene(&path) } else { self.save_image(&path) };
        match r {
            Ok(()) => {
                self.message = Some(format!("saved {}", path.display()));
                self.error = None;
            }
            Err(e) => self.error = Some(StatusError::action(format!("{e:#}"))),
        }
    }

    /// One frame of UI.
    pub fn ui(&mut self, ui: &mut egui::Ui) {
        let ctx = ui.ctx().clone();
        let _ = self.wake.set(ctx.clone());
        self.receive(&ctx);
        self.play_step(&ctx);
        self.handle_dropped_files(&ctx);
        self.poll_opening();
        if let Some(p) = self.dialog.show(&ctx) {
            self.open_in_background(p);
        }
        self.series_browser(&ctx);

        egui::Panel::top("toolbar").show(ui, |ui| self.toolbar(ui));
        egui::Panel::bottom("status").show(ui, |ui| self.status_bar(ui));
        if self.doc.is_some() {
            egui::Panel::left("scene").default_size(340.0).resizable(true).show(ui, |ui| {
                egui::ScrollArea::vertical().show(ui, |ui| self.scene_panel(ui));
            });
            if self.show_slices && self.selected_volume().is_some() {
                egui::Panel::right("slices").default_size(260.0).resizable(true).show(ui, |ui| {
                    egui::ScrollArea::vertical().show(ui, |ui| self.slice_panel(ui));
                });
            }
        }
        egui::CentralPanel::no_frame().show(ui, |ui| self.viewport(ui));
        self.schedule(&ctx);
        self.screenshot_step(&ctx);
    }

    /// Where the selected volume's crop box handle of face `face` (axis face / 2; min face
    /// when face % 2 = 0) is drawn in the window, if it has a crop box.
    pub fn crop_handle(&self, face: usize) -> Option<Pos2> {
        let (i, rect) = (self.selected_volume()?, self.viewport_rect?);
        let doc = self.doc.as_ref()?;
        let c = doc.scene.nodes()[i].crop?;
        super::crop::handle_position(&c, face, doc.scene.world_transform(i), |p| project(&self.camera, rect, p))
    }

    fn selected_volume(&self) -> Option<usize> {
        let doc = self.doc.as_ref()?;
        (doc.scene.nodes().get(self.selected)?.kind == NodeKind::Volume).then_some(self.selected)
    }

    fn receive(&mut self, ctx: &egui::Context) {
        for done in self.worker.poll() {
            self.take_done(ctx, done);
        }
    }

    fn take_done(&mut self, ctx: &egui::Context, done: Done) {
        let frame = match done.result {
            Ok(f) => f,
            Err(e) => {
                if done.quality == Quality::Reference {
                    self.reference_pending = false;
                    self.error_vs_reference = Some((done.version, Err(e)));
                } else {
                    self.error = Some(StatusError { text: e, from_render: true });
                }
                return;
            }
        };
        if done.quality == Quality::Reference {
            self.reference_pending = false;
            let err = match &self.last_full {
                Some((v, f)) if *v == done.version => Ok(volterra::compare::rgba_rel_rmse(&f.rgba, &frame.rgba)),
                _ => Err("the view changed while the reference rendered".to_string()),
            };
            self.error_vs_reference = Some((done.version, err));
            return;
        }
        // A late preview never replaces a newer frame.
        if let Some(s) = &self.shown {
            if s.version > done.version || (s.version == done.version && s.quality == Quality::Full) {
                return;
            }
        }
        if self.error.as_ref().is_some_and(|e| e.from_render) {
            self.error = None;
        }
        if frame.stats.notes.iter().any(|n| n == super::worker::EYE_INSIDE_NOTE) {
            self.message = Some(super::worker::EYE_INSIDE_NOTE.into());
        }
        let (bg, exposure) =
            self.doc.as_ref().map(|d| (d.scene.file.image.background, d.scene.file.image.exposure)).unwrap_or(([0.0; 3], 0.0));
        let texture = ctx.load_texture("view", frame_image(&frame, bg, exposure), egui::TextureOptions::LINEAR);
        let steps = frame
            .extra
            .iter()
            .find(|(n, _)| n == "steps")
            .map(|(_, s)| ctx.load_texture("steps", steps_image(&frame, s), egui::TextureOptions::NEAREST));
        self.frames_shown[done.quality as usize] += 1;
        self.shown = Some(Shown {
            version: done.version,
            quality: done.quality,
            texture,
            steps,
            seconds: done.seconds,
            renderer: frame.stats.renderer.clone(),
            size: done.size,
        });
        if done.quality == Quality::Full {
            self.last_full = Some((done.version, frame));
        }
    }

    fn handle_dropped_files(&mut self, ctx: &egui::Context) {
        let dropped: Vec<PathBuf> =
            ctx.input(|i| i.raw.dropped_files.iter().map(|f| f.path().to_path_buf()).filter(|p| !p.as_os_str().is_empty()).collect());
        if let Some(p) = dropped.into_iter().next() {
            self.open_in_background(p);
        }
    }

    /// Requests the frame the current state needs, if it is not already coming.
    fn schedule(&mut self, ctx: &egui::Context) {
        let Some(doc) = &self.doc else { return };
        let size = self.viewport_pixels(ctx);
        if size.0 == 0 || size.1 == 0 {
            return;
        }
        // A new view size (window resized, panels laid out) settles like a camera move:
        // previews first, one full frame once the size holds still.
        if self.last_size != Some(size) {
            if self.last_size.is_some() {
                self.changed_at = Some(Instant::now());
            }
            self.last_size = Some(size);
        }
        let moving = self.changed_at.is_some_and(|t| t.elapsed() < SETTLE);
        let (quality, want) = if moving {
            (Quality::Preview, ((size.0 / PREVIEW_DIV).max(16), (size.1 / PREVIEW_DIV).max(16)))
        } else {
            (Quality::Full, size)
        };
        if moving {
            ctx.request_repaint_after(SETTLE);
        }
        let have_full = self.last_full.as_ref().is_some_and(|(v, f)| *v == self.version && (f.width, f.height) == size);
        if self.submitted == Some((self.version, quality, want)) || (quality == Quality::Full && have_full) {
            return;
        }
        self.worker.submit(Job { version: self.version, quality, scene: doc.scene.clone(), camera: self.camera.clone(), size: want });
        self.submitted = Some((self.version, quality, want));
    }

    /// Size of the 3-D view in physical pixels, as the last frame laid it out.
    fn viewport_pixels(&self, ctx: &egui::Context) -> (usize, usize) {
        let ppp = ctx.pixels_per_point();
        self.viewport_rect
            .map(|r| ((r.width() * ppp).round().max(0.0) as usize, (r.height() * ppp).round().max(0.0) as usize))
            .unwrap_or((0, 0))
    }

    fn toolbar(&mut self, ui: &mut egui::Ui) {
        ui.horizontal_wrapped(|ui| {
            if ui.button("Open…").clicked() || ui.input(|i| i.modifiers.command && i.key_pressed(egui::Key::O)) {
                self.dialog.open = true;
            }
            let label = ui.label("Save as");
            ui.add(egui::TextEdit::singleline(&mut self.save_path).desired_width(220.0).hint_text("view.toml / view.exr / view.png"))
                .labelled_by(label.id);
            if ui.button("Save").on_hover_text(".toml: the view as a scene file; .exr/.png: the full-quality frame").clicked() {
                self.save();
            }
            ui.separator();
            let has_doc = self.doc.is_some();
            if ui.add_enabled(has_doc, egui::Button::new("Reset camera")).clicked() {
                if let Some(d) = &self.doc {
                    self.camera = d.home.clone();
                    self.bump(false);
                }
            }
            for v in AxisView::ALL {
                let hover = format!("View from the {:?} side", v).to_lowercase();
                if ui.add_enabled(has_doc, egui::Button::new(v.label())).on_hover_text(hover).clicked() {
                    navigate::axis_view(&mut self.camera, v);
                    self.bump(false);
                }
            }
            let mut parallel = self.camera.parallel_projection;
            if ui
                .add_enabled(has_doc, egui::Checkbox::new(&mut parallel, "Parallel"))
                .on_hover_text("Parallel projection (off: perspective, as 3D Slicer draws volumes)")
                .changed()
            {
                navigate::set_parallel(&mut self.camera, parallel);
                self.bump(false);
            }
            self.tool_menu(ui, has_doc);
            ui.checkbox(&mut self.show_view_marks, "Axes and scale")
                .on_hover_text("An orientation marker and a scale bar over the 3-D view (the bar holds at the focal point's depth)");
            ui.separator();
            for (m, label) in [(NavMode::Orbit, "Orbit"), (NavMode::Fly, "Fly"), (NavMode::Walk, "Walk")] {
                if ui.selectable_label(self.mode == m, label).clicked() && self.mode != m {
                    self.mode = m;
                    if m == NavMode::Walk {
                        self.settle_walk();
                    }
                }
            }
            self.time_controls(ui);
        });
    }

    /// The DICOM series browser: a folder's series (patient, study, series description,
    /// modality, size, images); a double-click or "Open series" opens the selected one.
    /// The measuring tool: distances and angles on the slices or the 3-D view's surface,
    /// elliptical ROIs on the slices.
    fn tool_menu(&mut self, ui: &mut egui::Ui, enabled: bool) {
        if !enabled {
            return;
        }
        let before = self.tool;
        egui::ComboBox::from_label("Measuring tool").selected_text(self.tool.label()).show_ui(ui, |ui| {
            for t in Tool::ALL {
                ui.selectable_value(&mut self.tool, t, t.label()).on_hover_text(t.hint());
            }
        });
        if self.tool != before {
            self.pending.clear();
        }
        if self.doc.as_ref().is_some_and(|d| !d.measurements.is_empty()) && ui.button("Clear measurements").clicked() {
            self.clear_measurements();
        }
    }

    fn series_browser(&mut self, ctx: &egui::Context) {
        let Some(choice) = &mut self.series_choice else { return };
        let mut open = None;
        let mut keep = true;
        egui::Window::new("DICOM series").open(&mut keep).default_size([640.0, 300.0]).show(ctx, |ui| {
            ui.label(format!("{} holds {} series", choice.dir.display(), choice.series.len()));
            egui::Grid::new("series").striped(true).num_columns(7).show(ui, |ui| {
                for h in ["", "Patient", "Study", "Series", "Modality", "Size", "Images"] {
                    ui.strong(h);
                }
                ui.end_row();
                for (k, s) in choice.series.iter().enumerate() {
                    let study = if s.study_date.is_empty() { s.study.clone() } else { format!("{} ({})", s.study, s.study_date) };
                    let description = if s.description.is_empty() { s.uid.clone() } else { s.description.clone() };
                    let row = ui.selectable_label(choice.selected == k, format!("{}", k + 1)).on_hover_text(&s.uid);
                    let cells = [
                        s.patient.clone(),
                        study,
                        description,
                        s.modality.clone(),
                        format!("{} × {}", s.columns, s.rows),
                        s.files.to_string(),
                    ];
                    let mut clicked = row.clicked();
                    let mut double = row.double_clicked();
                    for c in cells {
                        let r = ui.add(egui::Label::new(c).sense(Sense::click()));
                        clicked |= r.clicked();
                        double |= r.double_clicked();
                    }
                    if clicked {
                        choice.selected = k;
                    }
                    if double {
                        open = Some(k);
                    }
                    ui.end_row();
                }
            });
            if ui.button("Open series").clicked() {
                open = Some(choice.selected);
            }
        });
        if let Some(k) = open {
            let (dir, uid) = (choice.dir.clone(), choice.series[k].uid.clone());
            self.open_series(dir, uid);
        } else if !keep {
            self.series_choice = None;
        }
    }

    /// The time series' controls, where the scene has one: a slider over its steps
    /// (labelled with the step's time), a step back and forward ("<", ">"), and play (the next step
    /// follows each full frame, so playback goes as fast as the renderer draws).
    fn time_controls(&mut self, ui: &mut egui::Ui) {
        let Some(doc) = &self.doc else { return };
        let times = doc.scene.timeline();
        if times.len() < 2 {
            return;
        }
        ui.separator();
        let mut index = self.time_index(&times);
        let last = times.len() - 1;
        if ui.button("<").on_hover_text("Previous step").clicked() {
            index = index.saturating_sub(1);
        }
        let label = ui.label("Time");
        let shown = times.clone();
        ui.add(
            egui::Slider::new(&mut index, 0..=last)
                .custom_formatter(move |i, _| format!("{} (step {} of {})", shown[i as usize], i as usize + 1, shown.len())),
        )
        .labelled_by(label.id);
        if ui.button(">").on_hover_text("Next step").clicked() {
            index = (index + 1).min(last);
        }
        let play = if self.playing { "Pause" } else { "Play" };
        if ui.button(play).clicked() {
            self.playing = !self.playing;
        }
        if index != self.time_index(&times) {
            self.set_time(times[index]);
        }
    }

    /// The step of `times` the scene draws (a still draws the first).
    fn time_index(&self, times: &[f64]) -> usize {
        let t = self.doc.as_ref().and_then(|d| d.scene.time()).unwrap_or(times[0]);
        times.iter().rposition(|x| *x <= t).unwrap_or(0)
    }

    /// Draws the scene at time `t`: each series node reads its step there when the frame is
    /// drawn (off the UI thread); the other nodes keep their data.
    pub fn set_time(&mut self, t: f64) {
        let Some(doc) = &mut self.doc else { return };
        doc.scene = Arc::new(doc.scene.at_time(t));
        self.bump(false);
    }

    /// Playing: once the current step's full frame is shown, on to the next (from the last
    /// back to the first).
    fn play_step(&mut self, ctx: &egui::Context) {
        if !self.playing {
            return;
        }
        let Some(doc) = &self.doc else { return };
        let times = doc.scene.timeline();
        if times.len() < 2 {
            self.playing = false;
            return;
        }
        let done = self.shown.as_ref().is_some_and(|s| s.version == self.version && s.quality == Quality::Full);
        if done {
            let next = (self.time_index(&times) + 1) % times.len();
            self.set_time(times[next]);
        }
        ctx.request_repaint_after(std::time::Duration::from_millis(30));
    }

    fn status_bar(&mut self, ui: &mut egui::Ui) {
        ui.horizontal_wrapped(|ui| {
            if self.worker.busy() || self.opening.is_some() {
                ui.spinner();
                if let Some((what, pos, len)) = self.worker.progress() {
                    ui.add(egui::ProgressBar::new(pos as f32 / len.max(1) as f32).desired_width(160.0).text(format!("{what} {pos}/{len}")));
                }
            }
            if let Some(s) = &self.shown {
                let q = match s.quality {
                    Quality::Preview => "preview",
                    Quality::Full => "full",
                    Quality::Reference => "reference",
                };
                ui.label(format!("{} · {} {}×{} · {:.0} ms", s.renderer, q, s.size.0, s.size.1, s.seconds * 1e3));
            }
            match &self.error_vs_reference {
                Some((v, Ok(e))) if *v == self.version => {
                    ui.label(format!("· error vs reference {:.2} %", 100.0 * e));
                }
                Some((v, Err(e))) if *v == self.version => {
                    ui.label(format!("· no error figure: {e}"));
                }
                _ => {}
            }
            let can_measure = self.current_full_frame().is_some() && !self.reference_pending;
            if ui
                .add_enabled(can_measure, egui::Button::new("Measure error"))
                .on_hover_text("Render this view with the brute-force reference and compare")
                .clicked()
            {
                self.measure_error();
            }
            if let Some(e) = &self.error {
                ui.colored_label(Color32::from_rgb(230, 90, 80), &e.text);
            } else if let Some(m) = &self.message {
                ui.label(egui::RichText::new(m).weak());
            }
        });
    }

    /// Queues the reference render of the current view (the worker compares when it ends).
    pub fn measure_error(&mut self) {
        let (Some(doc), Some((v, f))) = (&self.doc, &self.last_full) else { return };
        if *v != self.version {
            return;
        }
        self.worker.submit(Job {
            version: *v,
            quality: Quality::Reference,
            scene: doc.scene.clone(),
            camera: self.camera.clone(),
            size: (f.width, f.height),
        });
        self.submitted = Some((*v, Quality::Reference, (f.width, f.height)));
        self.reference_pending = true;
    }

    /// The relative RMSE measured by [`Self::measure_error`] for the current state.
    pub fn error_vs_reference(&self) -> Option<&Result<f64, String>> {
        self.error_vs_reference.as_ref().filter(|(v, _)| *v == self.version).map(|(_, e)| e)
    }

    fn scene_panel(&mut self, ui: &mut egui::Ui) {
        let Some(doc) = &self.doc else { return };
        let scene = doc.scene.clone();
        ui.heading("Scene");
        ui.label(egui::RichText::new(scene.source.display().to_string()).small());
        for (i, n) in scene.nodes().iter().enumerate() {
            let label = format!("{} ({:?})", n.name, n.kind).to_lowercase();
            if ui.selectable_label(self.selected == i, label).clicked() {
                self.selected = i;
                self.tf_editor = TfEditor::default();
            }
        }
        ui.separator();
        let i = self.selected;
        let Some(n) = scene.nodes().get(i).cloned() else { return };
        ui.heading(&n.name);
        // Metadata, as `volterra info` prints it.
        if n.kind != NodeKind::Group {
            match node_json(&scene, i) {
                Ok(json) => metadata_grid(ui, json),
                Err(e) => {
                    ui.colored_label(Color32::from_rgb(230, 90, 80), format!("{e:#}"));
                }
            }
        }
        let mut visible = n.visible;
        if ui.checkbox(&mut visible, "Visible").changed() {
            self.edit(false, |f| f.nodes[i].visible = visible);
        }
        // Renderer choice among those that draw this kind.
        let Some(current) = scene.renderer(i) else { return };
        let mut chosen = None;
        egui::ComboBox::from_label("Renderer").selected_text(current.name).show_ui(ui, |ui| {
            for r in registry::for_kind(n.kind) {
                if ui.selectable_label(current.name == r.name, r.name).on_hover_text(volterra::render::settings::summary(r.doc)).clicked() {
                    chosen = Some(r.name);
                }
            }
        });
        if let Some(r) = chosen.filter(|r| *r != current.name) {
            self.edit(false, |f| {
                f.nodes[i].renderer = Some(r.to_string());
                // Each renderer has its own settings: those of the previous one go.
                f.nodes[i].settings = toml::Table::new();
            });
        }
        match n.kind {
            NodeKind::Volume => self.volume_controls(ui, i, current),
            NodeKind::Heightfield => self.terrain_controls(ui, i, current),
            NodeKind::Particles if current.name == volterra::render::points::RENDERER.name => self.points_controls(ui, i, current),
            NodeKind::Particles => self.smoke_controls(ui, i, current),
            NodeKind::Group => {}
        }
    }

    /// The controls the node's renderer declares for its settings.
    fn setting_controls(&mut self, ui: &mut egui::Ui, i: usize, renderer: &registry::RendererDecl, settings: &toml::Table) {
        if let Some(c) = super::settings_controls::show(ui, renderer, settings) {
            self.edit(c.moving, |f| {
                f.nodes[i].settings.insert(c.key.to_string(), c.value);
            });
        }
    }

    fn volume_controls(&mut self, ui: &mut egui::Ui, i: usize, renderer: &registry::RendererDecl) {
        let Some(doc) = &self.doc else { return };
        let n = doc.scene.nodes()[i].clone();
        let stats = doc.stats.get(i).cloned().flatten();
        let volume = doc.scene.volume(i).ok();
        // The transfer function drawn: the node's points, else its preset's on its data.
        let drawn_tf = n.transfer_function.clone().or_else(|| doc.scene.transfer_function(i).ok());
        let modality_preset = (n.transfer_function.is_none() && n.preset.is_none()).then(|| doc.scene.preset(i).ok()).flatten();
        let drawn_shading = doc.scene.shading(i);
        let mut mip = n.blend == BlendMode::Mip;
        if ui.checkbox(&mut mip, "Maximum intensity projection").changed() {
            self.edit(false, |f| f.nodes[i].blend = if mip { BlendMode::Mip } else { BlendMode::Composite });
        }
        ui.add_enabled_ui(!mip, |ui| {
            ui.horizontal(|ui| {
                // Fades one volume of a fused pair (its extinction scaled; saved as opacity_scale).
                let mut scale = n.opacity_scale;
                let lbl = ui.label("Opacity scale");
                let r = ui.add(egui::Slider::new(&mut scale, 0.0..=10.0).logarithmic(true)).labelled_by(lbl.id);
                if r.changed() {
                    self.edit(r.dragged(), |f| f.nodes[i].opacity_scale = scale);
                }
            });
        });
        self.setting_controls(ui, i, renderer, &n.settings);
        ui.checkbox(&mut self.show_slices, "Slice views");
        ui.separator();
        ui.label(egui::RichText::new("Transfer function").strong());
        let Some(stats) = stats else { return };
        if let Some(p) = &n.preset {
            ui.label(format!("Preset {p} (saved by name; editing a point makes it points)"));
        } else if let Some(p) = modality_preset {
            ui.label(format!("Preset {} (the modality's)", p.name()));
        }
        let Some(mut tf) = drawn_tf else {
            if ui.button("Add a transfer function").clicked() {
                if let Some(v) = volume {
                    let modality = n.modality.as_deref().or(v.modality.as_deref());
                    let p = volterra::scene::presets::Preset::for_modality(modality, &stats);
                    self.edit(false, |f| f.nodes[i].preset = Some(p.name().to_string()));
                }
            }
            return;
        };
        if self.tf_editor.show(ui, &mut tf, &stats) {
            if let Some(p) = self.tf_editor.chosen_preset.take() {
                // A preset chosen is saved as such (its name), with Slicer's shading
                // unless the node has its own.
                self.edit(false, |f| {
                    f.nodes[i].transfer_function = None;
                    f.nodes[i].preset = Some(p.name().to_string());
                    f.nodes[i].preset_shift = 0.0;
                });
            } else if tf.validate().is_ok() {
                // Points moved by hand replace the preset; the shading it gave is kept.
                let moving = ui.input(|inp| inp.pointer.any_down());
                self.edit(moving, |f| {
                    f.nodes[i].transfer_function = Some(tf);
                    if f.nodes[i].preset.take().is_some() {
                        f.nodes[i].shading = drawn_shading;
                        f.nodes[i].preset_shift = 0.0;
                    }
                });
            }
        }
        ui.separator();
        self.modality_control(ui, i, n.modality.as_deref());
        self.shading_controls(ui, i, drawn_shading.unwrap_or_default(), mip);
        ui.separator();
        if let Some(v) = volume {
            if let Some(e) = super::crop::controls(ui, n.crop, &n.clip, super::crop::volume_box(&v)) {
                self.edit(e.moving, |f| {
                    f.nodes[i].crop = e.crop;
                    f.nodes[i].clip = e.clip;
                });
            }
        }
    }

    /// The modality of data whose file does not say it (NIfTI): it picks the preset.
    fn modality_control(&mut self, ui: &mut egui::Ui, i: usize, modality: Option<&str>) {
        let mut chosen = modality.map(str::to_string);
        egui::ComboBox::from_label("Modality").selected_text(modality.unwrap_or("from the file")).show_ui(ui, |ui| {
            ui.selectable_value(&mut chosen, None, "from the file");
            for m in volterra::scene::presets::MODALITIES.iter().map(|(code, _)| *code) {
                ui.selectable_value(&mut chosen, Some(m.to_string()), m);
            }
        });
        if chosen.as_deref() != modality {
            self.edit(false, |f| f.nodes[i].modality = chosen);
        }
    }

    /// Gradient shading of a volume node, with vtkVolumeProperty's coefficients (MIP is
    /// never shaded). Turning it off keeps the coefficients, as `shade = false`.
    fn shading_controls(&mut self, ui: &mut egui::Ui, i: usize, mut shading: VolumeShading, mip: bool) {
        ui.add_enabled_ui(!mip, |ui| {
            let mut changed = ui
                .checkbox(&mut shading.shade, "Shading")
                .on_hover_text("Gradient shading as VTK's ShadeOn, lit by the scene's lights or a headlight")
                .changed();
            let mut moving = false;
            if shading.shade {
                let VolumeShading { ambient, diffuse, specular, specular_power, .. } = &mut shading;
                for (label, value, hi) in [
                    ("Ambient", ambient, 1.0),
                    ("Diffuse", diffuse, 1.0),
                    ("Specular", specular, 1.0),
                    ("Specular power", specular_power, 128.0),
                ] {
                    ui.horizontal(|ui| {
                        let lbl = ui.label(label);
                        let r = ui.add(egui::Slider::new(value, 0.0..=hi)).labelled_by(lbl.id);
                        changed |= r.changed();
                        moving |= r.dragged();
                    });
                }
            }
            if changed {
                self.edit(moving, |f| f.nodes[i].shading = Some(shading));
            }
        });
    }

    fn terrain_controls(&mut self, ui: &mut egui::Ui, i: usize, renderer: &registry::RendererDecl) {
        let Some(doc) = &self.doc else { return };
        let n = doc.scene.nodes()[i].clone();
        let lights = doc.scene.file.lights.clone();
        self.setting_controls(ui, i, renderer, &n.settings);
        let mut exaggeration = n.transform.scale.map(|s| s[2]).unwrap_or(1.0);
        ui.horizontal(|ui| {
            let lbl = ui.label("Vertical exaggeration");
            let r = ui.add(egui::Slider::new(&mut exaggeration, 0.1..=10.0).logarithmic(true)).labelled_by(lbl.id);
            if r.changed() {
                self.edit(r.dragged(), |f| {
                    let s = f.nodes[i].transform.scale.get_or_insert([1.0; 3]);
                    s[2] = exaggeration;
                });
            }
        });
        self.sun_controls(ui, &lights);
        ui.checkbox(&mut self.show_steps, "Step-count heat map");
        if self.mode == NavMode::Walk {
            ui.horizontal(|ui| {
                let lbl = ui.label("Eye height (m)");
                if ui.add(egui::DragValue::new(&mut self.eye_height).speed(0.1).range(0.0..=10000.0)).labelled_by(lbl.id).changed() {
                    self.settle_walk();
                }
            });
        }
        ui.label(egui::RichText::new("Fly/Walk: drag to look, W A S D to move, Q/E down/up (fly), Shift faster").weak());
    }

    /// Sun azimuth (degrees clockwise from north, where the light comes from) and
    /// elevation above the horizon, editing the first directional light.
    fn sun_controls(&mut self, ui: &mut egui::Ui, lights: &[volterra::scene::Light]) {
        let Some(li) = lights.iter().position(|l| l.kind == volterra::scene::LightKind::Directional) else { return };
        let d = DVec3::from(lights[li].direction.unwrap_or([0.0, 0.0, -1.0])).normalize();
        let from = -d;
        let mut azimuth = from.x.atan2(from.y).to_degrees().rem_euclid(360.0);
        let mut elevation = from.z.clamp(-1.0, 1.0).asin().to_degrees();
        let mut changed = None;
        ui.horizontal(|ui| {
            let lbl = ui.label("Sun azimuth");
            let r = ui.add(egui::Slider::new(&mut azimuth, 0.0..=360.0).suffix("°")).labelled_by(lbl.id);
            if r.changed() {
                changed = Some(r.dragged());
            }
        });
        ui.horizontal(|ui| {
            let lbl = ui.label("Sun elevation");
            let r = ui.add(egui::Slider::new(&mut elevation, 1.0..=90.0).suffix("°")).labelled_by(lbl.id);
            if r.changed() {
                changed = Some(r.dragged());
            }
        });
        if let Some(moving) = changed {
            let (a, e) = (azimuth.to_radians(), elevation.to_radians());
            let from = DVec3::new(a.sin() * e.cos(), a.cos() * e.cos(), e.sin());
            self.edit(moving, |f| f.lights[li].direction = Some((-from).to_array()));
        }
    }

    fn smoke_controls(&mut self, ui: &mut egui::Ui, i: usize, renderer: &registry::RendererDecl) {
        let Some(doc) = &self.doc else { return };
        let n = doc.scene.nodes()[i].clone();
        let lights = doc.scene.file.lights.clone();
        if let Some(mut m) = n.medium.clone() {
            let mut changed = None;
            ui.horizontal(|ui| {
                let lbl = ui.label("Albedo");
                let r = ui.add(egui::Slider::new(&mut m.albedo, 0.0..=1.0)).labelled_by(lbl.id);
                if r.changed() {
                    changed = Some(r.dragged());
                }
            });
            ui.horizontal(|ui| {
                // Automatic: optical depth 2 through the densest column, in any units.
                let mut auto = m.c_ext.is_none();
                if ui.checkbox(&mut auto, "Automatic C_ext").changed() {
                    m.c_ext = if auto { None } else { Some(10.0) };
                    changed = Some(false);
                }
                if let Some(c) = m.c_ext.as_mut() {
                    let lbl = ui.label("C_ext (m²/kg)");
                    let r = ui.add(egui::Slider::new(c, 0.01..=1000.0).logarithmic(true)).labelled_by(lbl.id);
                    if r.changed() {
                        changed = Some(r.dragged());
                    }
                }
            });
            ui.horizontal(|ui| {
                let lbl = ui.label("g (Henyey–Greenstein)");
                let r = ui.add(egui::Slider::new(&mut m.g, -0.95..=0.95)).labelled_by(lbl.id);
                if r.changed() {
                    changed = Some(r.dragged());
                }
            });
            if let Some(moving) = changed {
                self.edit(moving, |f| f.nodes[i].medium = Some(m));
            }
        }
        self.setting_controls(ui, i, renderer, &n.settings);
        self.sun_controls(ui, &lights);
        ui.label(egui::RichText::new("Traced photons are cached on disk: moving the camera reuses them.").weak());
    }

    /// The points renderer's controls: what colours the particles (any of their point
    /// arrays), then the declared settings; opacity only for splats (spheres refuse it).
    fn points_controls(&mut self, ui: &mut egui::Ui, i: usize, renderer: &registry::RendererDecl) {
        let Some(doc) = &self.doc else { return };
        let n = doc.scene.nodes()[i].clone();
        if let Ok(NodeData::Particles(p)) = doc.scene.data(i) {
            let mut names: Vec<String> =
                [("density", p.density.is_some()), ("mass", p.mass.is_some()), ("h", p.smoothing_length.is_some())]
                    .iter()
                    .filter(|(_, present)| *present)
                    .map(|(n, _)| n.to_string())
                    .collect();
            names.extend(p.arrays.iter().map(|a| a.name.clone()));
            let current = n.color_by.clone().unwrap_or_else(|| if p.density.is_some() { "density".into() } else { "(one colour)".into() });
            let mut pick = None;
            egui::ComboBox::from_label("Colour by").selected_text(&current).show_ui(ui, |ui| {
                for name in &names {
                    if ui.selectable_label(*name == current, name).clicked() {
                        pick = Some(name.clone());
                    }
                }
            });
            if let Some(name) = pick.filter(|p| *p != current) {
                // A range given for another array would not fit this one.
                self.edit(false, |f| {
                    f.nodes[i].color_by = Some(name);
                    f.nodes[i].color_range = None;
                });
            }
        }
        let splats = n.settings.get("style").and_then(|v| v.as_str()) == Some(volterra::render::points::PointStyle::Splats.name());
        let decls = renderer.settings.iter().filter(|d| splats || d.key != "opacity");
        if let Some(c) = super::settings_controls::show_some(ui, decls, &n.settings) {
            self.edit(c.moving, |f| {
                let settings = &mut f.nodes[i].settings;
                settings.insert(c.key.to_string(), c.value);
                if settings.get("style").and_then(|v| v.as_str()) != Some("splats") {
                    settings.remove("opacity");
                }
            });
        }
    }

    fn slice_panel(&mut self, ui: &mut egui::Ui) {
        let Some(i) = self.selected_volume() else { return };
        let Some(doc) = &self.doc else { return };
        let Ok(volume) = doc.scene.volume(i) else { return };
        let stats = doc.stats[i].clone();
        // (Re)build the source when another volume (or its placement) is selected.
        let world = doc.scene.world_transform(i);
        let rebuild = self.slices.as_ref().is_none_or(|s| s.node != i || !Arc::ptr_eq(&s.source.volume, &volume));
        if rebuild {
            let source = SliceSource::new(volume.clone(), world);
            let (window, level) = stats
                .as_ref()
                .map(|s| {
                    let (a, b) = (s.percentile(0.005), s.percentile(0.999));
                    let (a, b) = if b > a { (a, b) } else { (s.min, s.max.max(s.min + 1.0)) };
                    (b - a, 0.5 * (a + b))
                })
                .unwrap_or((1.0, 0.5));
            let restore = self.restore_slices.take().filter(|r| r.node == doc.scene.nodes()[i].name);
            let (window, level, cross) = match &restore {
                Some(r) => (r.window, r.level, DVec3::from(r.cross)),
                None => (window, level, source.centre()),
            };
            let overlay = restore.and_then(|r| r.overlay).and_then(|o| {
                let j = doc.scene.nodes().iter().position(|n| n.name == o.node)?;
                Some(OverlayState {
                    node: j,
                    source: SliceSource::new(doc.scene.volume(j).ok()?, doc.scene.world_transform(j)),
                    window: o.window,
                    level: o.level,
                    colormap: volterra::render::colormap::Colormap::from_name(&o.colormap)?,
                    opacity: o.opacity,
                })
            });
            self.slices = Some(SliceState {
                node: i,
                cross,
                source,
                window,
                level,
                images: vec![],
                shown: vec![],
                overlay,
                rects: vec![],
                dirty: true,
            });
        }
        // The CT presets apply to values in Hounsfield units: a CT (the node's modality, else
        // the file's) or values the file says are HU.
        let node = &doc.scene.nodes()[i];
        let ct = node.modality.as_deref().or(volume.modality.as_deref()).is_some_and(|m| m.eq_ignore_ascii_case("CT"))
            || volume.units.as_deref() == Some("HU");
        let s = self.slices.as_mut().unwrap();
        ui.horizontal(|ui| {
            let current = super::slices::CT_WINDOWS.iter().find(|(_, w, l)| *w == s.window && *l == s.level).map_or("Custom", |p| p.0);
            ui.add_enabled_ui(ct, |ui| {
                egui::ComboBox::from_label("W/L preset")
                    .selected_text(current)
                    .show_ui(ui, |ui| {
                        for &(name, w, l) in super::slices::CT_WINDOWS {
                            if ui.selectable_label(current == name, format!("{name} (W {w} / L {l})")).clicked() {
                                (s.window, s.level, s.dirty) = (w, l, true);
                            }
                        }
                    })
                    .response
                    .on_disabled_hover_text("CT window presets need values in Hounsfield units (a CT, or set the node's modality to CT)");
            });
        });
        s.dirty |= window_level_controls(ui, ("Window", "Level"), &mut s.window, &mut s.level);
        // Fusion: another volume node over these slices, through a colour map.
        let others: Vec<(usize, String)> = doc
            .scene
            .nodes()
            .iter()
            .enumerate()
            .filter(|(j, n)| *j != i && n.kind == NodeKind::Volume)
            .map(|(j, n)| (j, n.name.clone()))
            .collect();
        if !others.is_empty() {
            let current =
                s.overlay.as_ref().and_then(|o| others.iter().find(|(j, _)| *j == o.node)).map_or("None".to_string(), |(_, n)| n.clone());
            let mut pick: Option<Option<usize>> = None;
            egui::ComboBox::from_label("Overlay").selected_text(&current).show_ui(ui, |ui| {
                if ui.selectable_label(s.overlay.is_none(), "None").clicked() {
                    pick = Some(None);
                }
                for (j, name) in &others {
                    if ui.selectable_label(current == *name, name).clicked() {
                        pick = Some(Some(*j));
                    }
                }
            });
            match pick {
                Some(None) => {
                    s.overlay = None;
                    s.dirty = true;
                }
                Some(Some(j)) => {
                    if let Ok(v) = doc.scene.volume(j) {
                        // The window from the overlay's own values (0.5 % to 99.9 %).
                        let (lo, hi) =
                            doc.scene.value_stats(j).map(|st| (st.percentile(0.005), st.percentile(0.999))).unwrap_or((0.0, 1.0));
                        let (lo, hi) = if hi > lo { (lo, hi) } else { (lo, lo + 1.0) };
                        s.overlay = Some(OverlayState {
                            node: j,
                            source: SliceSource::new(v, doc.scene.world_transform(j)),
                            window: hi - lo,
                            level: 0.5 * (lo + hi),
                            colormap: volterra::render::colormap::Colormap::Hot,
                            opacity: 0.5,
                        });
                        s.dirty = true;
                    }
                }
                None => {}
            }
        }
        if let Some(o) = s.overlay.as_mut() {
            use volterra::render::colormap::Colormap;
            egui::ComboBox::from_label("Overlay colours").selected_text(o.colormap.name()).show_ui(ui, |ui| {
                for &c in Colormap::ALL {
                    if ui.selectable_label(o.colormap == c, c.name()).clicked() && o.colormap != c {
                        o.colormap = c;
                        s.dirty = true;
                    }
                }
            });
            ui.horizontal(|ui| {
                let lbl = ui.label("Overlay opacity");
                s.dirty |= ui.add(egui::Slider::new(&mut o.opacity, 0.0..=1.0)).labelled_by(lbl.id).changed();
            });
            s.dirty |= window_level_controls(ui, ("Overlay window", "level"), &mut o.window, &mut o.level);
            // The scalar bar: the map from the window's bottom to its top, with the values.
            let (rect, _) = ui.allocate_exact_size(Vec2::new(ui.available_width().min(240.0), 12.0), Sense::hover());
            let painter = ui.painter_at(rect);
            let steps = 64;
            for k in 0..steps {
                let c = o.colormap.at((k as f64 + 0.5) / steps as f64).map(f64::from);
                let x0 = rect.left() + rect.width() * k as f32 / steps as f32;
                let x1 = rect.left() + rect.width() * (k + 1) as f32 / steps as f32;
                painter.rect_filled(
                    Rect::from_min_max(Pos2::new(x0, rect.top()), Pos2::new(x1, rect.bottom())),
                    0.0,
                    Color32::from_rgb(srgb(c[0]), srgb(c[1]), srgb(c[2])),
                );
            }
            ui.horizontal(|ui| {
                ui.label(format!("{:.4}", o.level - 0.5 * o.window));
                ui.add_space((rect.width() - 120.0).max(0.0));
                ui.label(format!("{:.4}", o.level + 0.5 * o.window));
            });
        }
        if s.dirty {
            let overlay = s.overlay.as_ref().map(|o| Overlay {
                source: &o.source,
                window: o.window,
                level: o.level,
                colormap: o.colormap,
                opacity: o.opacity,
            });
            s.shown.clear();
            s.images = Plane::ALL
                .iter()
                .map(|&p| {
                    let img = s.source.slice(p, s.cross, s.window, s.level);
                    let rgb = super::slices::fused(&img, overlay.as_ref());
                    let flat: Vec<u8> = rgb.iter().flatten().copied().collect();
                    let tex = ui.ctx().load_texture(
                        format!("slice-{}", p.label()),
                        egui::ColorImage::from_rgb([img.width, img.height], &flat),
                        egui::TextureOptions::LINEAR,
                    );
                    s.shown.push(rgb);
                    (img, tex)
                })
                .collect();
            s.dirty = false;
        }
        let width = ui.available_width();
        let mut new_cross = None;
        let mut taken = None;
        let node_name = doc.scene.nodes()[i].name.clone();
        // The values' units: the file's, else HU for a CT (as the W/L presets take them).
        let units = volume.units.clone().or_else(|| ct.then(|| "HU".to_string()));
        s.rects.clear();
        for (k, plane) in Plane::ALL.iter().enumerate() {
            let (img, tex) = &s.images[k];
            ui.label(format!(
                "{} ({:.1} mm)",
                plane.label(),
                match plane {
                    Plane::Axial => s.cross.z,
                    Plane::Coronal => s.cross.y,
                    Plane::Sagittal => s.cross.x,
                }
            ));
            let aspect = img.height as f32 / img.width as f32;
            let size = Vec2::new(width, (width * aspect).min(width * 1.5));
            let (resp, painter) = ui.allocate_painter(size, Sense::click_and_drag());
            let r = resp.rect;
            s.rects.push(r);
            painter.image(tex.id(), r, Rect::from_min_max(Pos2::ZERO, Pos2::new(1.0, 1.0)), Color32::WHITE);
            let on_screen = |p: DVec3| {
                let (u, v) = img.pixel_of(p);
                Pos2::new(r.left() + (u as f32 / img.width as f32) * r.width(), r.top() + (v as f32 / img.height as f32) * r.height())
            };
            // Cross-hair.
            let p = on_screen(s.cross);
            let stroke = egui::Stroke::new(1.0, Color32::from_rgb(255, 210, 0));
            painter.line_segment([Pos2::new(r.left(), p.y), Pos2::new(r.right(), p.y)], stroke);
            painter.line_segment([Pos2::new(p.x, r.top()), Pos2::new(p.x, r.bottom())], stroke);
            let [l, rt, t, b] = plane.edge_labels();
            let font = egui::FontId::proportional(13.0);
            let c = Color32::from_rgb(120, 220, 255);
            painter.text(Pos2::new(r.left() + 4.0, r.center().y), egui::Align2::LEFT_CENTER, l, font.clone(), c);
            painter.text(Pos2::new(r.right() - 4.0, r.center().y), egui::Align2::RIGHT_CENTER, rt, font.clone(), c);
            painter.text(Pos2::new(r.center().x, r.top() + 2.0), egui::Align2::CENTER_TOP, t, font.clone(), c);
            painter.text(Pos2::new(r.center().x, r.bottom() - 2.0), egui::Align2::CENTER_BOTTOM, b, font, c);
            // The measurements on this slice (this volume, this plane, this slice position:
            // within half a slice pixel of the cross-hair along the normal).
            let axis = plane.scene_plane().normal_axis();
            let on_this_slice = |p: &[f64; 3]| (p[axis] - s.cross[axis]).abs() <= 0.5 * s.source.slice_pixel(*plane);
            let clip = painter.with_clip_rect(r);
            for (m, stats) in &doc.measurements {
                if m.node == node_name && m.plane == Some(plane.scene_plane()) && on_this_slice(&m.points[0]) {
                    let pts: Vec<Pos2> = m.points.iter().map(|&q| on_screen(DVec3::from(q))).collect();
                    let lines = super::measure::describe(m, stats.as_ref(), units.as_deref(), volume.suv_bw);
                    super::measure::draw(&clip, m.kind, &pts, &lines);
                }
            }
            if let (Tool::Measure(kind), true) = (self.tool, self.pending_on == Some(k) && !self.pending.is_empty()) {
                let pts: Vec<Pos2> = self.pending.iter().map(|&q| on_screen(q)).collect();
                super::measure::draw(&clip, kind, &pts, &[]);
            }
            if let Some(pos) = resp.interact_pointer_pos().filter(|_| resp.clicked() || (resp.dragged() && self.tool == Tool::CrossHair)) {
                let u = (pos.x - r.left()) / r.width() * img.width as f32;
                let v = (pos.y - r.top()) / r.height() * img.height as f32;
                let world = img.world_at(u as f64, v as f64);
                match self.tool {
                    Tool::CrossHair => new_cross = Some(world),
                    Tool::Measure(kind) => {
                        // A click on another slice starts over there.
                        if self.pending_on != Some(k) {
                            self.pending.clear();
                            self.pending_on = Some(k);
                        }
                        self.pending.push(world);
                        if self.pending.len() == kind.points() {
                            let points = self.pending.drain(..).map(|p| p.to_array()).collect();
                            taken = Some(Measurement { kind, node: node_name.clone(), plane: Some(plane.scene_plane()), points });
                        }
                    }
                }
            }
        }
        if let Some(c) = new_cross {
            let (lo, hi) = s.source.bounds();
            s.cross = c.clamp(lo, hi);
            s.dirty = true;
        }
        let Some(doc) = &mut self.doc else { return };
        if let Some(m) = taken {
            let stats = measurement_stats(&doc.scene, &m);
            doc.measurements.push((m, stats));
        }
    }

    fn viewport(&mut self, ui: &mut egui::Ui) {
        let (resp, painter) = ui.allocate_painter(ui.available_size(), Sense::click_and_drag());
        let rect = resp.rect;
        self.viewport_rect = Some(rect);
        painter.rect_filled(rect, 0.0, Color32::from_gray(18));
        let Some(_) = &self.doc else {
            painter.text(
                rect.center(),
                egui::Align2::CENTER_CENTER,
                "Open a file or scene (Ctrl+O), or drop one here",
                egui::FontId::proportional(18.0),
                Color32::GRAY,
            );
            return;
        };
        if let Some(s) = &self.shown {
            let uv = Rect::from_min_max(Pos2::ZERO, Pos2::new(1.0, 1.0));
            painter.image(s.texture.id(), rect, uv, Color32::WHITE);
            if self.show_steps {
                if let Some(t) = &s.steps {
                    painter.image(t.id(), rect, uv, Color32::from_white_alpha(200));
                }
            }
        }
        self.draw_surface_measurements(&painter, rect);
        if self.show_view_marks {
            let world = self.doc.as_ref().map_or(super::view_marks::World::Plain, |d| view_world(&d.scene));
            super::view_marks::draw(&painter, &self.camera, rect, world);
        }
        // Cross-hair of the slice views, projected.
        if let (Some(sl), true) = (&self.slices, self.show_slices && self.selected_volume().is_some()) {
            if let Some(p) = project(&self.camera, rect, sl.cross) {
                let c = Color32::from_rgb(255, 210, 0);
                painter.line_segment([p - Vec2::new(8.0, 0.0), p + Vec2::new(8.0, 0.0)], egui::Stroke::new(1.5, c));
                painter.line_segment([p - Vec2::new(0.0, 8.0), p + Vec2::new(0.0, 8.0)], egui::Stroke::new(1.5, c));
            }
        }
        if !self.crop_handles(&resp, &painter, rect) {
            self.navigate(ui, &resp, rect);
        }
    }

    /// The selected volume's crop box over the 3-D view, a handle on each face; a drag
    /// that starts on a handle moves that face (previews while it moves). True while
    /// such a drag goes on (the camera stays put).
    fn crop_handles(&mut self, resp: &egui::Response, painter: &egui::Painter, rect: Rect) -> bool {
        let Some(i) = self.selected_volume() else { return false };
        let Some(doc) = &self.doc else { return false };
        let Some(mut c) = doc.scene.nodes()[i].crop else { return false };
        let to_world = doc.scene.world_transform(i);
        let cam = self.camera.clone();
        let project = |p: DVec3| project(&cam, rect, p);
        super::crop::draw(painter, &c, to_world, project);
        if resp.drag_started_by(egui::PointerButton::Primary) {
            self.crop_drag =
                resp.ctx.input(|inp| inp.pointer.press_origin()).and_then(|pos| super::crop::handle_at(&c, to_world, pos, project));
        }
        let Some(face) = self.crop_drag else { return false };
        if resp.dragged() && resp.drag_delta() != Vec2::ZERO {
            super::crop::drag_face(&mut c, face, resp.drag_delta(), to_world, project);
            self.edit(true, |f| f.nodes[i].crop = Some(c));
        }
        if resp.drag_stopped() || !resp.dragged() {
            self.crop_drag = None;
            self.bump(false); // the full frame, now that the face is let go
        }
        true
    }

    fn navigate(&mut self, ui: &mut egui::Ui, resp: &egui::Response, rect: Rect) {
        // Double-click (or Ctrl+click) on the volume: the slice views jump there (the depth where the
        // accumulated opacity passed 0.5 along that pixel's ray, from the full frame).
        let command = ui.input(|i| i.modifiers.command);
        if resp.double_clicked() || (resp.clicked() && command) {
            if let Some(pos) = resp.interact_pointer_pos() {
                self.jump_slices_to(rect, pos);
            }
        } else if resp.clicked() && self.tool != Tool::CrossHair {
            if let Some(pos) = resp.interact_pointer_pos() {
                self.place_surface_point(rect, pos);
            }
        }
        let mut moved = false;
        let d = resp.drag_delta();
        let (shift, scroll) = ui.input(|i| (i.modifiers.shift, i.smooth_scroll_delta.y));
        let h = rect.height().max(1.0) as f64;
        let primary = resp.dragged_by(egui::PointerButton::Primary);
        // As ParaView and pyvista: left rotates, middle (or Shift+left) pans, right zooms.
        let pan_drag = resp.dragged_by(egui::PointerButton::Middle) || (primary && shift && self.mode == NavMode::Orbit);
        if d != Vec2::ZERO {
            if resp.dragged_by(egui::PointerButton::Secondary) {
                navigate::zoom(&mut self.camera, (-2.0 * d.y as f64 / h).exp());
                moved = true;
            } else if pan_drag {
                navigate::pan(&mut self.camera, d.x as f64 / h, d.y as f64 / h);
                moved = true;
            } else if primary {
                match self.mode {
                    NavMode::Orbit => navigate::orbit(&mut self.camera, d.x as f64 * 180.0 / h, d.y as f64 * 180.0 / h),
                    NavMode::Fly | NavMode::Walk => navigate::look(&mut self.camera, d.x as f64 * 90.0 / h, -d.y as f64 * 90.0 / h),
                }
                moved = true;
            }
        }
        if resp.hovered() && scroll != 0.0 {
            navigate::zoom(&mut self.camera, (scroll as f64 / 300.0).exp());
            moved = true;
        }
        if self.mode != NavMode::Orbit && (resp.hovered() || resp.has_focus()) {
            let dt = ui.input(|i| i.stable_dt).min(0.1) as f64;
            let extent = self.doc.as_ref().and_then(|d| scene_extent(&d.scene)).unwrap_or(100.0);
            let speed = extent * 0.15 * dt * if shift { 5.0 } else { 1.0 };
            let key = |k| ui.input(|i| i.key_down(k));
            let f = (key(egui::Key::W) as i32 - key(egui::Key::S) as i32) as f64;
            let s = (key(egui::Key::D) as i32 - key(egui::Key::A) as i32) as f64;
            let r = if self.mode == NavMode::Fly { (key(egui::Key::E) as i32 - key(egui::Key::Q) as i32) as f64 } else { 0.0 };
            if f != 0.0 || s != 0.0 || r != 0.0 {
                navigate::travel(&mut self.camera, f * speed, s * speed, r * speed, self.mode == NavMode::Walk);
                if self.mode == NavMode::Walk {
                    self.settle_walk();
                }
                moved = true;
                ui.ctx().request_repaint();
            }
        }
        if moved {
            self.bump(true);
        }
    }

    /// Moves the slice views' cross-hair to the surface under window position `pos`.
    /// The world point on the surface under a window position in the 3-D view: along that
    /// pixel's ray at the full frame's depth (where the accumulated opacity passed 0.5, for
    /// volumes; the hit, for terrain and spheres). An error line where there is none.
    fn surface_point(&self, rect: Rect, pos: Pos2) -> Result<DVec3, &'static str> {
        let Some((v, f)) = &self.last_full else { return Err("no full frame yet") };
        if *v != self.version {
            return Err("the full frame is still being drawn");
        }
        let x = ((pos.x - rect.left()) / rect.width() * f.width as f32).floor().max(0.0) as usize;
        let y = ((pos.y - rect.top()) / rect.height() * f.height as f32).floor().max(0.0) as usize;
        let (x, y) = (x.min(f.width - 1), y.min(f.height - 1));
        let depth = f.depth[y * f.width + x];
        if !depth.is_finite() {
            return Err("nothing opaque under the pointer");
        }
        let ray = self.camera.rays(f.width, f.height).ray(x as f64 + 0.5, y as f64 + 0.5);
        Ok(ray.origin + ray.dir * depth as f64)
    }

    fn jump_slices_to(&mut self, rect: Rect, pos: Pos2) {
        match self.surface_point(rect, pos) {
            Ok(p) => {
                if let Some(s) = &mut self.slices {
                    let (lo, hi) = s.source.bounds();
                    s.cross = p.clamp(lo, hi);
                    s.dirty = true;
                }
            }
            Err(e) => self.message = Some(e.into()),
        }
    }

    /// A click on the 3-D view with a distance or angle tool places a point on the surface.
    fn place_surface_point(&mut self, rect: Rect, pos: Pos2) {
        let Tool::Measure(kind) = self.tool else { return };
        if kind == MeasurementKind::Ellipse {
            self.message = Some("an elliptical ROI is drawn on a slice".into());
            return;
        }
        let p = match self.surface_point(rect, pos) {
            Ok(p) => p,
            Err(e) => {
                self.message = Some(e.into());
                return;
            }
        };
        if self.pending_on.is_some() {
            self.pending.clear();
            self.pending_on = None;
        }
        self.pending.push(p);
        if self.pending.len() == kind.points() {
            let Some(doc) = &mut self.doc else { return };
            let node = doc.scene.nodes().get(self.selected).map(|n| n.name.clone()).unwrap_or_default();
            let points = self.pending.drain(..).map(|p| p.to_array()).collect();
            doc.measurements.push((Measurement { kind, node, plane: None, points }, None));
        }
    }

    /// The measurements between surface points, and the one being placed, over the 3-D view.
    fn draw_surface_measurements(&self, painter: &egui::Painter, rect: Rect) {
        let Some(doc) = &self.doc else { return };
        let screen = |q: DVec3| project(&self.camera, rect, q);
        let clip = painter.with_clip_rect(rect);
        for (m, _) in doc.measurements.iter().filter(|(m, _)| m.plane.is_none()) {
            if let Some(pts) = m.points.iter().map(|&q| screen(DVec3::from(q))).collect::<Option<Vec<Pos2>>>() {
                super::measure::draw(&clip, m.kind, &pts, &super::measure::describe_in(m, None, None, view_world(&doc.scene)));
            }
        }
        if let (Tool::Measure(kind), None) = (self.tool, self.pending_on) {
            if let Some(pts) = self.pending.iter().map(|&q| screen(q)).collect::<Option<Vec<Pos2>>>() {
                super::measure::draw(&clip, kind, &pts, &[]);
            }
        }
    }

    fn settle_walk(&mut self) {
        let Some(doc) = &self.doc else { return };
        let Some(i) = doc.scene.nodes().iter().position(|n| n.kind == NodeKind::Heightfield) else { return };
        let Ok(hf) = doc.scene.terrain_data(i) else { return };
        let m = doc.scene.world_transform(i);
        let eye = DVec3::from(self.camera.position);
        let local = m.inverse().transform_point3(DVec3::new(eye.x, eye.y, 0.0));
        if let Some(ground) = hf.surface_height(local.x, local.y) {
            let z = m.transform_point3(DVec3::new(local.x, local.y, ground)).z + self.eye_height;
            let lift = z - eye.z;
            self.camera.position[2] = z;
            self.camera.focal_point[2] += lift;
            self.bump(true);
        }
    }

    fn screenshot_step(&mut self, ctx: &egui::Context) {
        let Some(path) = self.screenshot_then_quit.clone() else { return };
        let full_shown = self.shown.as_ref().is_some_and(|s| s.quality == Quality::Full && s.version == self.version);
        let mut st = self.screenshot_state.lock().unwrap();
        match &*st {
            ScreenshotState::Waiting if full_shown => {
                *st = ScreenshotState::Painted(0);
                ctx.request_repaint();
            }
            // No frame will come (the renderer refused the scene, the file did not open): end
            // with the error instead of waiting for ever.
            ScreenshotState::Waiting if self.error.is_some() => {
                let e = self.error.as_ref().map(|e| e.text.clone()).unwrap_or_default();
                *st = ScreenshotState::Saved(Err(format!("no frame to save: {e}")));
                ctx.request_repaint();
            }
            // Let a couple of frames through so the texture is on screen.
            ScreenshotState::Painted(n) if *n < 2 => {
                *st = ScreenshotState::Painted(n + 1);
                ctx.request_repaint();
            }
            ScreenshotState::Painted(_) => {
                *st = ScreenshotState::Requested;
                let state = self.screenshot_state.clone();
                let c = ctx.clone();
                ctx.request_screenshot(move |img| {
                    let bytes: Vec<u8> = img.pixels.iter().flat_map(|p| p.to_array()).collect();
                    let r = volterra_formats::image::write_png_rgba8(&path, img.size[0], img.size[1], &bytes).map_err(|e| e.to_string());
                    *state.lock().unwrap() = ScreenshotState::Saved(r);
                    c.request_repaint();
                });
            }
            ScreenshotState::Saved(_) => {
                ctx.send_viewport_cmd(egui::ViewportCommand::Close);
            }
            _ => {
                ctx.request_repaint_after(Duration::from_millis(50));
            }
        }
    }

    /// Result of the screenshot-then-quit run: None until saved.
    pub fn screenshot_result(&self) -> Option<Result<(), String>> {
        match &*self.screenshot_state.lock().unwrap() {
            ScreenshotState::Saved(r) => Some(r.clone()),
            _ => None,
        }
    }
}

impl eframe::App for Viewer {
    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        Viewer::ui(self, ui);
    }
}

/// `dir/name.view.toml` beside the opened file.
/// A window and a level as drag values labelled `labels` (the window kept positive, both
/// moving by a hundredth of the window); true when either changed.
fn window_level_controls(ui: &mut egui::Ui, labels: (&str, &str), window: &mut f64, level: &mut f64) -> bool {
    ui.horizontal(|ui| {
        let speed = window.abs() * 0.01 + 1e-6;
        let lbl = ui.label(labels.0);
        let w = ui.add(egui::DragValue::new(window).speed(speed).range(1e-9..=f64::MAX)).labelled_by(lbl.id).changed();
        let lbl = ui.label(labels.1);
        let l = ui.add(egui::DragValue::new(level).speed(speed)).labelled_by(lbl.id).changed();
        w | l
    })
    .inner
}

/// The world's axes and units as the scene's data sets them (docs/coordinates.md).
fn view_world(scene: &Scene) -> super::view_marks::World {
    use super::view_marks::World;
    let has = |k: NodeKind| scene.nodes().iter().any(|n| n.kind == k);
    if has(NodeKind::Volume) {
        World::Patient
    } else if has(NodeKind::Heightfield) {
        World::Terrain
    } else {
        World::Plain
    }
}

fn default_save_path(opened: &Path) -> String {
    let stem =
        opened.file_name().map(|n| n.to_string_lossy().split('.').next().unwrap_or("view").to_string()).unwrap_or_else(|| "view".into());
    start_dir(Some(opened)).join(format!("{stem}_view.toml")).display().to_string()
}

fn scene_extent(scene: &Scene) -> Option<f64> {
    let mut ext: Option<f64> = None;
    for (i, n) in scene.nodes().iter().enumerate() {
        if n.kind == NodeKind::Group || !scene.is_opened(i) {
            continue;
        }
        if let Some((lo, hi)) = scene.bounds(i).ok()? {
            ext = Some(ext.unwrap_or(0.0).max((hi - lo).length()));
        }
    }
    ext
}

/// Frames the data of every loaded node (used by `volterra view` on a scene with no
/// camera worth keeping; exposed for tests).
pub fn fit_scene_camera(scene: &Scene) -> Option<Camera> {
    let (i, n) = scene.nodes().iter().enumerate().find(|(_, n)| n.kind != NodeKind::Group)?;
    Some(fit_camera(n.kind, scene.bounds(i).ok()??))
}

/// The window position of a world point, if in front of the camera.
fn project(cam: &Camera, rect: Rect, p: DVec3) -> Option<Pos2> {
    let g = cam.rays(rect.width().max(1.0) as usize, rect.height().max(1.0) as usize);
    let (eye, right, up) = g.basis();
    let (hw, hh) = g.half_extent();
    let d = p - eye;
    let (x, y) = if g.is_parallel() {
        (d.dot(right), d.dot(up))
    } else {
        let z = d.dot(g.forward());
        if z <= 0.0 {
            return None;
        }
        (d.dot(right) / z, d.dot(up) / z)
    };
    let sx = 0.5 * (x / hw + 1.0);
    let sy = 0.5 * (1.0 - y / hh);
    Some(Pos2::new(rect.left() + sx as f32 * rect.width(), rect.top() + sy as f32 * rect.height()))
}

/// sRGB pixels of a frame over its background.
fn frame_image(frame: &Frame, bg: [f64; 3], exposure: f64) -> egui::ColorImage {
    let rgba = frame.preview_rgba(bg, exposure);
    let to8 = |v: f32| (volterra_formats::image::linear_to_srgb(v.clamp(0.0, 1.0)) * 255.0).round() as u8;
    let pixels = rgba.chunks_exact(4).map(|p| Color32::from_rgb(to8(p[0]), to8(p[1]), to8(p[2]))).collect();
    egui::ColorImage::new([frame.width, frame.height], pixels)
}

/// Terrain traversal steps per pixel as a heat map (black → red → yellow at the maximum).
fn steps_image(frame: &Frame, steps: &[f32]) -> egui::ColorImage {
    let max = steps.iter().cloned().fold(1.0f32, f32::max);
    let pixels = steps
        .iter()
        .map(|&s| {
            let t = (s / max).clamp(0.0, 1.0);
            let r = (t * 2.0).min(1.0);
            let g = (t * 2.0 - 1.0).max(0.0);
            Color32::from_rgb((r * 255.0) as u8, (g * 255.0) as u8, 0)
        })
        .collect();
    egui::ColorImage::new([frame.width, frame.height], pixels)
}

/// What `volterra info` prints of a node's data, as its renderer reads it (a heightfield's
/// GeoTIFF by rows, not held).
fn node_json(scene: &Scene, i: usize) -> Result<serde_json::Value> {
    if scene.nodes()[i].kind == NodeKind::Heightfield {
        if let TerrainData::Rows(rows) = scene.terrain_data(i)? {
            return Ok(volterra::info::grid_json(&volterra::info::GridSummary::of_rows(&rows)));
        }
    }
    Ok(match scene.data(i)? {
        NodeData::Volume(v) => {
            // The modality in effect: the node's where it sets one (a NIfTI says none).
            let mut json = volterra::info::volume_json(&v);
            if let Some(m) = scene.nodes()[i].modality.as_deref() {
                let code = volterra::scene::presets::modality_code(m).unwrap_or(m);
                let file = v.modality.as_deref().map(|f| format!("the file says {f}")).unwrap_or_else(|| "the file says none".into());
                json["modality"] = serde_json::json!(format!("{code} (the node's; {file})"));
            }
            json
        }
        NodeData::Heightfield(h) => volterra::info::heightfield_json(&h),
        NodeData::Particles(p) => volterra::info::particles_json(&p, &scene.nodes()[i].arrays.clone().unwrap_or_default()),
    })
}

fn metadata_grid(ui: &mut egui::Ui, json: serde_json::Value) {
    // What the file says about itself (codes, patient, series, compression, corners): whole,
    // under a header that starts closed so the panel keeps its layout.
    let details: Vec<(String, serde_json::Value)> = match &json {
        serde_json::Value::Object(map) => {
            ["attributes", "corners", "corners_lonlat"].iter().filter_map(|k| map.get(*k).map(|v| (k.to_string(), v.clone()))).collect()
        }
        _ => Vec::new(),
    };
    egui::Grid::new("metadata").num_columns(2).striped(true).show(ui, |ui| {
        if let serde_json::Value::Object(map) = json {
            for (k, v) in map {
                if ["notes", "affine", "attributes", "corners", "corners_lonlat", "orientation", "geotransform"].contains(&k.as_str()) {
                    continue;
                }
                ui.label(k);
                let text = match &v {
                    serde_json::Value::String(s) => s.clone(),
                    serde_json::Value::Null => "—".into(),
                    serde_json::Value::Array(a) if a.iter().all(|x| x.is_number()) => a
                        .iter()
                        .map(|x| {
                            if x.is_f64() {
                                format!("{:.6}", x.as_f64().unwrap()).trim_end_matches('0').trim_end_matches('.').to_string()
                            } else {
                                x.to_string()
                            }
                        })
                        .collect::<Vec<_>>()
                        .join(" × "),
                    other => {
                        let t = other.to_string();
                        if t.len() > 60 {
                            format!("{}…", &t[..t.char_indices().nth(60).map(|c| c.0).unwrap_or(t.len())])
                        } else {
                            t
                        }
                    }
                };
                ui.label(text);
                ui.end_row();
            }
        }
    });
    for (k, v) in details {
        let serde_json::Value::Object(o) = v else { continue };
        egui::CollapsingHeader::new(format!("file {k}")).default_open(false).show(ui, |ui| {
            egui::Grid::new(format!("metadata-{k}")).num_columns(2).striped(true).show(ui, |ui| {
                for (name, value) in o {
                    ui.label(name);
                    ui.label(value.as_str().map(str::to_string).unwrap_or_else(|| value.to_string()));
                    ui.end_row();
                }
            });
        });
    }
}
