//! Progress display for long work: bars on a terminal, nothing when output is redirected
//! (indicatif hides itself when stderr is not a terminal). The newest bar is also kept
//! where the viewer's status bar can read it.

use indicatif::{ProgressBar, ProgressStyle};
use std::sync::Mutex;

static CURRENT: Mutex<Option<(String, ProgressBar)>> = Mutex::new(None);

/// A bar counting `len` units of work.
pub fn bar(len: u64, what: &str) -> ProgressBar {
    let pb = ProgressBar::new(len);
    pb.set_style(ProgressStyle::with_template("{msg:>24} [{bar:40}] {pos}/{len} ({eta})").unwrap().progress_chars("=> "));
    pb.set_message(what.to_string());
    *CURRENT.lock().unwrap() = Some((what.to_string(), pb.clone()));
    pb
}

/// The newest bar that has not finished: (what, position, length).
pub fn current() -> Option<(String, u64, u64)> {
    let g = CURRENT.lock().unwrap();
    let (what, pb) = g.as_ref()?;
    (!pb.is_finished()).then(|| (what.clone(), pb.position(), pb.length().unwrap_or(0)))
}

/// A spinner for work of unknown length (reading a file).
pub fn spinner(what: &str) -> ProgressBar {
    let pb = ProgressBar::new_spinner();
    pb.set_message(what.to_string());
    pb.enable_steady_tick(std::time::Duration::from_millis(120));
    pb
}
