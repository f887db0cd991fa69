//! A time series' controls: the time slider, steps, and play.

use super::*;

impl Viewer {
    /// The time series' controls, where the scene has one: a slider over its steps
    /// (labelled with the step's time), a step back and forward ("<", ">"), and play (the next step
    /// follows each full frame, so playback goes as fast as the renderer draws).
    pub(super) fn time_controls(&mut self, ui: &mut egui::Ui) {
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
    pub(super) fn time_index(&self, times: &[f64]) -> usize {
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
    pub(super) fn play_step(&mut self, ctx: &egui::Context) {
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
}
