//! Progressive rendering: the newest frames taken from the render thread, and the next job
//! asked of it (previews while the view changes, the full frame once it settles).

use super::*;

impl Viewer {
    pub(super) fn receive(&mut self, ctx: &egui::Context) {
        for done in self.worker.poll() {
            self.take_done(ctx, done);
        }
    }

    pub(super) fn take_done(&mut self, ctx: &egui::Context, done: Done) {
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
        if frame.stats.notes.iter().any(|n| n == crate::worker::EYE_INSIDE_NOTE) {
            self.message = Some(crate::worker::EYE_INSIDE_NOTE.into());
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

    /// Requests the frame the current state needs, if it is not already coming.
    pub(super) fn schedule(&mut self, ctx: &egui::Context) {
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
}
