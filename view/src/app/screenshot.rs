//! `--screenshot`: the whole window saved after the first full-quality frame, then quit.

use super::*;

impl Viewer {
    /// After the first full frame, save a PNG of the whole window to `path` and close.
    pub fn screenshot_then_quit(&mut self, path: PathBuf) {
        self.screenshot_then_quit = Some(path);
    }

    pub(super) fn screenshot_step(&mut self, ctx: &egui::Context) {
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
