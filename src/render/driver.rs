//! The one parallel driver of the CPU renderers (after pbrt-v4's `ImageTileIntegrator`):
//! an image's rows in bands, one rayon task each, with progress reported to whoever asked
//! for the render, cancellation between bands, and timing. Each renderer supplies only
//! what it does for one band of rows.
//!
//! Progress goes to the [`Progress`] the caller installed with [`observed`] around the
//! render (a terminal bar in the CLI, a field of the viewer's worker); renders nobody
//! observes report nothing. It is picked up on the thread that starts the work, so two
//! renders on two threads report to their own callers.

use std::cell::RefCell;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Instant;

/// Where a render's progress goes, and whether its result is still wanted.
pub trait Progress: Send + Sync {
    /// A piece of work of `total` units starts (rows, photons).
    fn begin(&self, what: &str, total: u64);
    /// `done` of its units are finished.
    fn update(&self, done: u64);
    /// It has ended (finished or cancelled).
    fn end(&self);
    /// True once the caller no longer wants the result: the work stops between bands.
    fn cancelled(&self) -> bool {
        false
    }
}

thread_local! {
    static OBSERVER: RefCell<Option<Arc<dyn Progress>>> = const { RefCell::new(None) };
}

/// Runs `f`, sending the progress of the work it starts on this thread to `progress`.
pub fn observed<R>(progress: Arc<dyn Progress>, f: impl FnOnce() -> R) -> R {
    let before = OBSERVER.with(|o| o.replace(Some(progress)));
    // Restore on the way out, also when `f` panics.
    struct Restore(Option<Arc<dyn Progress>>);
    impl Drop for Restore {
        fn drop(&mut self) {
            let before = self.0.take();
            OBSERVER.with(|o| *o.borrow_mut() = before);
        }
    }
    let _restore = Restore(before);
    f()
}

/// The error of work stopped because its caller cancelled it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Cancelled;

impl std::fmt::Display for Cancelled {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("cancelled")
    }
}

impl std::error::Error for Cancelled {}

/// One piece of work being reported, from begin to end (on drop). Shareable across
/// rayon's threads.
pub struct Task {
    progress: Option<Arc<dyn Progress>>,
    done: AtomicU64,
    start: Instant,
}

impl Task {
    /// Starts reporting `total` units of `what` to the caller's progress, if any.
    pub fn begin(what: &str, total: u64) -> Task {
        let progress = OBSERVER.with(|o| o.borrow().clone());
        if let Some(p) = &progress {
            p.begin(what, total);
        }
        Task { progress, done: AtomicU64::new(0), start: Instant::now() }
    }

    /// `units` more are finished.
    pub fn advance(&self, units: u64) {
        let done = self.done.fetch_add(units, Ordering::Relaxed) + units;
        if let Some(p) = &self.progress {
            p.update(done);
        }
    }

    pub fn cancelled(&self) -> bool {
        self.progress.as_ref().is_some_and(|p| p.cancelled())
    }

    /// Seconds since the task began.
    pub fn seconds(&self) -> f64 {
        self.start.elapsed().as_secs_f64()
    }
}

impl Drop for Task {
    fn drop(&mut self) {
        if let Some(p) = &self.progress {
            p.end();
        }
    }
}

/// One band of consecutive rows of the planes being rendered.
pub struct Band<'a> {
    /// The band's first row.
    pub y0: usize,
    pub rows: usize,
    /// `rows × width` pixels of each plane, row-major.
    pub rgba: &'a mut [[f32; 4]],
    pub depth: &'a mut [f32],
    /// The extra planes, in the order given.
    pub extra: Vec<&'a mut [f32]>,
}

/// Renders planes of `width` pixels per row in parallel bands of `band_rows` rows:
/// `shade` fills one band and returns its statistics. Progress counts rows. Returns each
/// band's statistics in band order (so totals do not depend on the thread count), or
/// [`Cancelled`] when the caller cancelled between bands.
pub fn render_bands<S: Send>(
    what: &str,
    width: usize,
    band_rows: usize,
    rgba: &mut [[f32; 4]],
    depth: &mut [f32],
    extra: &mut [&mut [f32]],
    shade: impl Fn(Band) -> S + Sync,
) -> Result<Vec<S>, Cancelled> {
    let height = rgba.len().checked_div(width).unwrap_or(0);
    assert!(depth.len() == rgba.len() && extra.iter().all(|e| e.len() == rgba.len()), "planes of one size");
    let task = Task::begin(what, height as u64);
    let chunk = (width * band_rows.max(1)).max(1);
    let mut extra_bands: Vec<_> = extra.iter_mut().map(|p| p.chunks_mut(chunk)).collect();
    let bands: Vec<Band> = rgba
        .chunks_mut(chunk)
        .zip(depth.chunks_mut(chunk))
        .enumerate()
        .map(|(i, (rgba, depth))| Band {
            y0: i * band_rows.max(1),
            rows: rgba.len() / width.max(1),
            rgba,
            depth,
            extra: extra_bands.iter_mut().map(|b| b.next().expect("planes of one size")).collect(),
        })
        .collect();
    use rayon::prelude::*;
    let sums: Vec<Option<S>> = bands
        .into_par_iter()
        .map(|band| {
            if task.cancelled() {
                return None;
            }
            let rows = band.rows as u64;
            let s = shade(band);
            task.advance(rows);
            Some(s)
        })
        .collect();
    sums.into_iter().collect::<Option<Vec<S>>>().ok_or(Cancelled)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::AtomicBool;
    use std::sync::Mutex;

    #[derive(Default)]
    struct Log {
        events: Mutex<Vec<String>>,
        cancel: AtomicBool,
        last: AtomicU64,
    }

    impl Progress for Log {
        fn begin(&self, what: &str, total: u64) {
            self.events.lock().unwrap().push(format!("begin {what} {total}"));
        }
        fn update(&self, done: u64) {
            self.last.fetch_max(done, Ordering::Relaxed);
        }
        fn end(&self) {
            self.events.lock().unwrap().push("end".into());
        }
        fn cancelled(&self) -> bool {
            self.cancel.load(Ordering::Relaxed)
        }
    }

    fn planes(w: usize, h: usize) -> (Vec<[f32; 4]>, Vec<f32>, Vec<f32>) {
        (vec![[0.0; 4]; w * h], vec![f32::INFINITY; w * h], vec![0.0; w * h])
    }

    #[test]
    fn every_row_is_shaded_once_in_its_band_and_progress_reaches_the_height() {
        let log = Arc::new(Log::default());
        let (w, h) = (5, 23);
        let (mut rgba, mut depth, mut extra) = planes(w, h);
        let rows = observed(log.clone(), || {
            render_bands("test", w, 4, &mut rgba, &mut depth, &mut [&mut extra[..]], |mut b| {
                for r in 0..b.rows {
                    for x in 0..w {
                        let y = b.y0 + r;
                        b.rgba[r * w + x][0] += y as f32;
                        b.depth[r * w + x] = x as f32;
                        b.extra[0][r * w + x] += 1.0;
                    }
                }
                b.rows
            })
        })
        .unwrap();
        assert_eq!(rows.iter().sum::<usize>(), h);
        assert_eq!(rows, [4, 4, 4, 4, 4, 3]);
        for y in 0..h {
            for x in 0..w {
                assert_eq!((rgba[y * w + x][0], depth[y * w + x], extra[y * w + x]), (y as f32, x as f32, 1.0));
            }
        }
        assert_eq!(*log.events.lock().unwrap(), ["begin test 23", "end"]);
        assert_eq!(log.last.load(Ordering::Relaxed), 23);
    }

    #[test]
    fn a_cancelled_render_stops_and_says_so_and_unobserved_work_reports_nothing() {
        let log = Arc::new(Log::default());
        log.cancel.store(true, Ordering::Relaxed);
        let (mut rgba, mut depth, _) = planes(3, 8);
        let r = observed(log.clone(), || render_bands("cancelled", 3, 1, &mut rgba, &mut depth, &mut [], |_| 1usize));
        assert_eq!(r, Err(Cancelled));
        // Outside `observed` nobody listens, and nothing cancels.
        let r = render_bands("quiet", 3, 1, &mut rgba, &mut depth, &mut [], |_| 1usize);
        assert_eq!(r.map(|v| v.len()), Ok(8));
        assert_eq!(*log.events.lock().unwrap(), ["begin cancelled 8", "end"]);
    }
}
