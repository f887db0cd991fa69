//! The series browser: a DICOM folder of several series, one row each, to choose from.

use super::*;

impl Viewer {
    pub(super) fn series_browser(&mut self, ctx: &egui::Context) {
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
}
