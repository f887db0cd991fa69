//! Opening a file, folder or scene (in the background), installing it as the document, and saving the scene or the frame.

use super::*;

/// A document read off the UI thread, ready to show.
pub(super) struct Opened {
    path: PathBuf,
    scene: Scene,
    stats: Vec<Option<Arc<ValueStats>>>,
    camera: Camera,
    /// Which renderer draws the volumes, where the viewer chose it.
    gpu_note: Option<String>,
}

/// What opening a path gives: a document, or a DICOM folder's series to choose from.
pub(super) enum Loaded {
    Document(Box<Opened>),
    Series { dir: PathBuf, series: Vec<volterra_formats::dicom::SeriesSummary> },
}

/// Reads what `path` names: a folder holding several DICOM series (none chosen in `load`)
/// gives the list to choose from, anything else the document.
pub(super) fn load_path(path: &Path, load: &LoadOptions) -> Result<Loaded> {
    if path.is_dir() && load.dicom.series.is_none() {
        let series = volterra_formats::dicom::list_series(path, &load.limits)?;
        if series.len() > 1 {
            return Ok(Loaded::Series { dir: path.to_path_buf(), series });
        }
    }
    load_document(path, load).map(|o| Loaded::Document(Box::new(o)))
}

/// Reads a scene file or a data file, and everything the viewer derives from the data.
pub(super) fn load_document(path: &Path, load: &LoadOptions) -> Result<Opened> {
    let is_scene = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("toml"));
    let scene = if is_scene { Scene::load(path, &[])?.with_limits(load.limits) } else { scene_for_file(path, load)? };
    let (scene, gpu_note) = volumes_on_the_gpu(scene, !is_scene)?;
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
    Ok(Opened { path: path.to_path_buf(), scene, stats, camera, gpu_note })
}

/// The volume renderer the viewer draws with where the choice is open: the GPU ray-caster
/// (`gpu-raycast`) on a hardware GPU; shear-warp, the CPU path, on a CPU adapter
/// (lavapipe), where `volterra bench gpu-volume` finds neither faster throughout (2 cores,
/// a further frame at 512²: the aneurism 315 ms by shear-warp against 376 ms on lavapipe,
/// the 512 × 512 × 400 CT 398 against 209 ms; VTK's GPU ray caster on llvmpipe 461 and
/// 806 ms). With the reason, for the status line.
pub(super) fn volume_renderer() -> (&'static str, String) {
    use volterra::render::{gpu_volume, shear_warp};
    match volterra::gpu::device() {
        Ok(d) if !d.is_software() => {
            (gpu_volume::RENDERER.name, format!("volumes drawn by {} on the GPU '{}'", gpu_volume::RENDERER.name, d.info.name))
        }
        Ok(d) => (
            shear_warp::RENDERER.name,
            format!("volumes drawn by {} on the CPU ('{}' is a software GPU)", shear_warp::RENDERER.name, d.info.name),
        ),
        Err(_) => (shear_warp::RENDERER.name, format!("volumes drawn by {} on the CPU (no GPU adapter)", shear_warp::RENDERER.name)),
    }
}

/// The scene with its volume nodes drawn by `volume_renderer()` where their renderer is
/// open: every volume of a data file opened without a scene (`from_data`), the volume
/// nodes of a scene file that name none. A renderer the scene names stays; the node's
/// Renderer box changes either. With what was chosen, where any volume was.
fn volumes_on_the_gpu(scene: Scene, from_data: bool) -> Result<(Scene, Option<String>)> {
    let open: Vec<usize> = (0..scene.nodes().len())
        .filter(|&i| scene.nodes()[i].kind == NodeKind::Volume && (from_data || scene.nodes()[i].renderer.is_none()))
        .collect();
    if open.is_empty() {
        return Ok((scene, None));
    }
    let (renderer, why) = volume_renderer();
    // Shear-warp is what they are drawn with already (the kind's default, a data file's
    // choice): the scene stays as it was read.
    if renderer == volterra::render::shear_warp::RENDERER.name {
        return Ok((scene, Some(why)));
    }
    let mut file = scene.file.clone();
    for &i in &open {
        file.nodes[i].renderer = Some(renderer.to_string());
    }
    Ok((scene.edited(file)?, Some(why)))
}

impl Viewer {
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

    pub(super) fn take_loaded(&mut self, loaded: Loaded) {
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

    pub(super) fn open_with(&mut self, path: PathBuf, load: LoadOptions) {
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

    pub(super) fn poll_opening(&mut self) {
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

    pub(super) fn install(&mut self, o: Opened) {
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
        self.message = Some(match &o.gpu_note {
            Some(note) => format!("opened {}; {note}", o.path.display()),
            None => format!("opened {}", o.path.display()),
        });
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
        relocate(&mut file, &doc.scene.base_dir, dir);
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
}

/// Where "Save" writes by default: `<stem>_view.toml` beside the opened file.
pub(super) fn default_save_path(opened: &Path) -> String {
    let stem =
        opened.file_name().map(|n| n.to_string_lossy().split('.').next().unwrap_or("view").to_string()).unwrap_or_else(|| "view".into());
    start_dir(Some(opened)).join(format!("{stem}_view.toml")).display().to_string()
}
