//! The toolbar: open, save, view buttons, the tool menu, and files dropped on the window.

use super::*;

impl Viewer {
    pub(super) fn toolbar(&mut self, ui: &mut egui::Ui) {
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
    pub(super) fn tool_menu(&mut self, ui: &mut egui::Ui, enabled: bool) {
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

    pub(super) fn save(&mut self) {
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

    pub(super) fn handle_dropped_files(&mut self, ctx: &egui::Context) {
        let dropped: Vec<PathBuf> =
            ctx.input(|i| i.raw.dropped_files.iter().map(|f| f.path().to_path_buf()).filter(|p| !p.as_os_str().is_empty()).collect());
        if let Some(p) = dropped.into_iter().next() {
            self.open_in_background(p);
        }
    }
}
