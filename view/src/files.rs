//! The open dialog, drawn by egui itself: a native dialog would need GTK or an XDG portal
//! (D-Bus) on Linux, neither of which a headless CI machine or a minimal workstation has.
//! It lists folders and the files volterra reads; DICOM series folders open as a whole.

use std::path::{Path, PathBuf};

pub struct FileDialog {
    pub open: bool,
    pub dir: PathBuf,
    /// What the path field holds (a file, a folder, or a scene).
    pub path_text: String,
    entries: Vec<(String, bool)>,
    listed: Option<PathBuf>,
}

const READABLE: &[&str] = &[
    ".toml", ".nii", ".nii.gz", ".hdr", ".dcm", ".mha", ".mhd", ".nrrd", ".nhdr", ".vti", ".tif", ".tiff", ".png", ".vtk", ".vtp", ".vtu",
    ".pvd",
];

fn readable(name: &str) -> bool {
    let n = name.to_ascii_lowercase();
    READABLE.iter().any(|e| n.ends_with(e))
}

impl FileDialog {
    pub fn new(dir: PathBuf) -> FileDialog {
        FileDialog { open: false, path_text: String::new(), dir, entries: vec![], listed: None }
    }

    fn list(&mut self) {
        if self.listed.as_deref() == Some(self.dir.as_path()) {
            return;
        }
        self.entries.clear();
        if let Ok(rd) = std::fs::read_dir(&self.dir) {
            for e in rd.flatten() {
                let name = e.file_name().to_string_lossy().into_owned();
                if name.starts_with('.') {
                    continue;
                }
                let is_dir = e.path().is_dir();
                if is_dir || readable(&name) {
                    self.entries.push((name, is_dir));
                }
            }
        }
        self.entries.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.to_lowercase().cmp(&b.0.to_lowercase())));
        self.listed = Some(self.dir.clone());
    }

    /// Shows the dialog window; returns the path to open when the user chose one.
    pub fn show(&mut self, ctx: &egui::Context) -> Option<PathBuf> {
        if !self.open {
            return None;
        }
        self.list();
        let mut chosen = None;
        let mut open = self.open;
        egui::Window::new("Open").open(&mut open).default_size([520.0, 420.0]).show(ctx, |ui| {
            ui.horizontal(|ui| {
                if ui.button("Up").clicked() {
                    if let Some(p) = self.dir.parent() {
                        self.dir = p.to_path_buf();
                    }
                }
                ui.label(self.dir.display().to_string());
            });
            ui.horizontal(|ui| {
                let lbl = ui.label("Path");
                let r = ui.add(egui::TextEdit::singleline(&mut self.path_text).desired_width(340.0)).labelled_by(lbl.id);
                let enter = r.lost_focus() && ui.input(|i| i.key_pressed(egui::Key::Enter));
                if ui.button("Open").clicked() || enter {
                    let p = PathBuf::from(self.path_text.trim());
                    chosen = Some(if p.is_relative() { self.dir.join(p) } else { p });
                }
            });
            if ui.button("Open this folder (DICOM series)").clicked() {
                chosen = Some(self.dir.clone());
            }
            ui.separator();
            egui::ScrollArea::vertical().show(ui, |ui| {
                let mut enter_dir = None;
                for (name, is_dir) in &self.entries {
                    let label = if *is_dir { format!("{name}/") } else { name.clone() };
                    let r = ui.selectable_label(self.path_text == *name, label);
                    if r.clicked() {
                        self.path_text = name.clone();
                    }
                    if r.double_clicked() {
                        if *is_dir {
                            enter_dir = Some(self.dir.join(name));
                        } else {
                            chosen = Some(self.dir.join(name));
                        }
                    }
                }
                if let Some(d) = enter_dir {
                    self.dir = d;
                    self.path_text.clear();
                }
            });
        });
        self.open = open && chosen.is_none();
        chosen
    }
}

/// The folder a dialog starts in: the opened file's, else the working directory.
pub fn start_dir(current: Option<&Path>) -> PathBuf {
    current
        .and_then(Path::parent)
        .filter(|p| !p.as_os_str().is_empty())
        .map(Path::to_path_buf)
        .unwrap_or_else(|| std::env::current_dir().unwrap_or_default())
}
