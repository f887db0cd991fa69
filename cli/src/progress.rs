//! Progress display for long work: bars on a terminal; when stderr is redirected (a Slurm
//! log, a pipe) indicatif hides its bars, and [`TerminalProgress`] writes plain lines
//! instead for every piece of work that runs longer than a second. It shows the
//! renderers' progress (see `render::driver`).

use indicatif::{ProgressBar, ProgressStyle};
use std::io::IsTerminal;
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// A bar counting `len` units of work (hidden under `-q`).
pub fn bar(len: u64, what: &str) -> ProgressBar {
    if crate::verbosity::quiet() {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(len);
    pb.set_style(ProgressStyle::with_template("{msg:>24} [{bar:40}] {pos}/{len} ({eta})").unwrap().progress_chars("=> "));
    pb.set_message(what.to_string());
    pb
}

/// A spinner for work of unknown length (reading a file; hidden under `-q`).
pub fn spinner(what: &str) -> ProgressBar {
    if crate::verbosity::quiet() {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new_spinner();
    pb.set_message(what.to_string());
    pb.enable_steady_tick(std::time::Duration::from_millis(120));
    pb
}

/// Whether progress goes to a terminal (bars) or elsewhere (plain lines).
pub fn on_terminal() -> bool {
    std::io::stderr().is_terminal()
}

/// The renderers' progress as a terminal bar, one per piece of work, or as plain lines
/// when stderr is not a terminal.
#[derive(Default)]
pub struct TerminalProgress {
    bar: Mutex<Option<ProgressBar>>,
    plain: Mutex<Option<PlainTask>>,
}

/// A piece of work reported as lines: at most one every [`PLAIN_EVERY`], none for work
/// that ends within a second.
struct PlainTask {
    what: String,
    total: u64,
    done: u64,
    start: Instant,
    last: Option<Instant>,
}

const PLAIN_EVERY: Duration = Duration::from_secs(5);

impl crate::render::driver::Progress for TerminalProgress {
    fn begin(&self, what: &str, total: u64) {
        if on_terminal() {
            *self.bar.lock().unwrap() = Some(bar(total, what));
        } else {
            *self.plain.lock().unwrap() = Some(PlainTask { what: what.into(), total, done: 0, start: Instant::now(), last: None });
        }
    }
    fn update(&self, done: u64) {
        if let Some(b) = self.bar.lock().unwrap().as_ref() {
            b.set_position(done.max(b.position()));
        }
        if let Some(t) = self.plain.lock().unwrap().as_mut() {
            t.done = t.done.max(done);
            // The first line after a second, then one every PLAIN_EVERY.
            let due = match t.last {
                None => t.start.elapsed() >= Duration::from_secs(1),
                Some(last) => last.elapsed() >= PLAIN_EVERY,
            };
            if due {
                let pct = 100.0 * t.done as f64 / t.total.max(1) as f64;
                eprintln!("{}: {pct:.0} % ({}/{}, {:.1} s)", t.what, t.done, t.total, t.start.elapsed().as_secs_f64());
                t.last = Some(Instant::now());
            }
        }
    }
    fn end(&self) {
        if let Some(b) = self.bar.lock().unwrap().take() {
            b.finish_and_clear();
        }
        if let Some(t) = self.plain.lock().unwrap().take() {
            let s = t.start.elapsed().as_secs_f64();
            if s >= 1.0 {
                eprintln!("{}: done in {s:.1} s", t.what);
            }
        }
    }
}
