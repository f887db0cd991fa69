//! Progress display for long work on a terminal: bars, nothing when output is redirected
//! (indicatif hides itself when stderr is not a terminal). [`TerminalProgress`] shows the
//! renderers' progress (see `render::driver`) as bars.

use indicatif::{ProgressBar, ProgressStyle};
use std::sync::Mutex;

/// A bar counting `len` units of work.
pub fn bar(len: u64, what: &str) -> ProgressBar {
    let pb = ProgressBar::new(len);
    pb.set_style(ProgressStyle::with_template("{msg:>24} [{bar:40}] {pos}/{len} ({eta})").unwrap().progress_chars("=> "));
    pb.set_message(what.to_string());
    pb
}

/// A spinner for work of unknown length (reading a file).
pub fn spinner(what: &str) -> ProgressBar {
    let pb = ProgressBar::new_spinner();
    pb.set_message(what.to_string());
    pb.enable_steady_tick(std::time::Duration::from_millis(120));
    pb
}

/// The renderers' progress as a terminal bar, one per piece of work.
#[derive(Default)]
pub struct TerminalProgress {
    bar: Mutex<Option<ProgressBar>>,
}

impl crate::render::driver::Progress for TerminalProgress {
    fn begin(&self, what: &str, total: u64) {
        *self.bar.lock().unwrap() = Some(bar(total, what));
    }
    fn update(&self, done: u64) {
        if let Some(b) = self.bar.lock().unwrap().as_ref() {
            b.set_position(done.max(b.position()));
        }
    }
    fn end(&self) {
        if let Some(b) = self.bar.lock().unwrap().take() {
            b.finish_and_clear();
        }
    }
}
