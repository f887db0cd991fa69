//! The viewer's state and UI. Everything the window shows is drawn from here; renders come
//! from the [`RenderWorker`] thread, so the UI never waits on a renderer.
//!
//! Progressive rendering: every change (camera, transfer function, settings) bumps a
//! version. While the user is moving things, quarter-resolution previews are requested;
//! once nothing has changed for [`SETTLE`], the full-resolution frame, which is exactly what
//! `volterra render` draws for the scene "Save scene" writes.

//!
//! The state lives here (`Viewer` and what it holds); each panel draws from it in a module
//! of its own: `toolbar`, `time`, `series` (the series browser), `scene_panel` with
//! `node_controls` (each node kind's), `slice_panel`, `viewport` (the 3-D view, navigation,
//! surface measurements), `status`; `document` opens and saves, `render` asks the render
//! thread for frames and takes them, `screenshot` serves `--screenshot`.

mod document;
mod node_controls;
mod render;
mod scene_panel;
mod screenshot;
mod series;
mod slice_panel;
mod status;
mod time;
mod toolbar;
mod viewport;

use document::Loaded;
use viewport::{frame_image, steps_image};

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
use volterra::catalog;
use volterra::render::Frame;
use volterra::scene::auto::{fit_camera, relocate, scene_for_file};
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
    colormap: volterra::colormap::Colormap,
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

    /// The 3-D view's orientation marker (the world axes' screen directions) and scale bar
    /// (world length, points), as drawn; None while they are hidden or nothing is shown.
    pub fn view_marks(&self) -> Option<([Vec2; 3], (f64, f32))> {
        let rect = self.viewport_rect?;
        (self.show_view_marks && self.doc.is_some())
            .then(|| (super::view_marks::marker_axes(&self.camera), super::view_marks::scale_bar(&self.camera, rect)))
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

    fn selected_volume(&self) -> Option<usize> {
        let doc = self.doc.as_ref()?;
        (doc.scene.nodes().get(self.selected)?.kind == NodeKind::Volume).then_some(self.selected)
    }
}

impl eframe::App for Viewer {
    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        Viewer::ui(self, ui);
    }
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
