//! `volterra view`: the interactive viewer (eframe/egui on wgpu).
//!
//! - `app`: the viewer's state, and its panels one module each (`app/`); progressive rendering;
//! - `worker`: the render thread (renderers never run on the UI thread);
//! - `navigate`: orbit / pan / zoom / fly / walk on the scene's camera;
//! - `transfer_editor`: opacity and colour over the histogram, presets;
//! - `settings_controls`: widgets for the renderer settings the renderers declare;
//! - `slices`: axial, coronal and sagittal views with a cross-hair;
//! - `measure`: distances, angles and elliptical ROIs on the slices;
//! - `view_marks`: the 3-D view's orientation marker and scale bar;
//! - `crop`: a volume's crop box and clipping planes, with handles in the 3-D view;
//! - `files`: the open dialog.

pub mod app;
pub mod crop;
pub mod files;
pub mod measure;
pub mod navigate;
pub mod settings_controls;
pub mod slices;
pub mod transfer_editor;
pub mod view_marks;
pub mod worker;

pub use app::Viewer;

use anyhow::{anyhow, Result};
use std::path::PathBuf;
use volterra_formats::LoadOptions;

/// Opens the window and runs until it is closed. `screenshot`: save a PNG of the window
/// after the first full-quality frame, then close (checks a real window, e.g. under Xvfb).
pub fn run(target: Option<PathBuf>, load: LoadOptions, screenshot: Option<PathBuf>) -> Result<()> {
    let mut viewer = Viewer::new(load);
    // With a screenshot to take, a file that cannot be read is an error of the command;
    // otherwise the window opens at once and reads the file in the background.
    match (&target, &screenshot) {
        // No one is there to choose a series: a folder of several is the reader's one-line
        // error (choose one with --series), not a browser waiting for a click.
        (Some(p), Some(_)) => viewer.open_without_choosing(p)?,
        (Some(p), None) => viewer.open_in_background(p.clone()),
        _ => {}
    }
    if let Some(s) = screenshot {
        if target.is_none() {
            return Err(anyhow!("--screenshot needs a file or scene to show"));
        }
        viewer.screenshot_then_quit(s);
    }
    let title = match &target {
        Some(p) => format!("volterra — {}", p.display()),
        None => "volterra".to_string(),
    };
    let options = eframe::NativeOptions {
        viewport: egui::ViewportBuilder::default().with_title(title).with_inner_size([1280.0, 800.0]).with_drag_and_drop(true),
        renderer: eframe::Renderer::Wgpu,
        ..Default::default()
    };
    let result = std::sync::Arc::new(std::sync::Mutex::new(None));
    let r = result.clone();
    eframe::run_native("volterra", options, Box::new(move |_cc| Ok(Box::new(Shell { viewer, result: r }))))
        .map_err(|e| anyhow!("cannot open the viewer window: {e}"))?;
    let outcome = result.lock().unwrap().take();
    match outcome {
        Some(Err(e)) => Err(anyhow!("screenshot: {e}")),
        _ => Ok(()),
    }
}

/// The eframe app: the viewer, and where the screenshot's outcome is handed back.
struct Shell {
    viewer: Viewer,
    result: std::sync::Arc<std::sync::Mutex<Option<Result<(), String>>>>,
}

impl eframe::App for Shell {
    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        self.viewer.ui(ui);
        if let Some(r) = self.viewer.screenshot_result() {
            *self.result.lock().unwrap() = Some(r);
        }
    }
}
