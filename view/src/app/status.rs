//! The status bar: what is loading or rendering, errors, frame times, and the error against the reference renderer.

use super::*;

impl Viewer {
    pub(super) fn status_bar(&mut self, ui: &mut egui::Ui) {
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
}
