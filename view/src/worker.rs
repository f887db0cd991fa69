//! The viewer's render thread: renderers run here, never on the UI thread. It holds one
//! pending job (a newer one replaces it, so a moving camera never queues stale frames) and
//! one [`RenderCache`], so shear-warp's prepared volume and min-max maps are built once
//! per volume, not per frame.

use std::path::PathBuf;
use std::sync::mpsc::{channel, Receiver, Sender};
use std::sync::{Arc, Condvar, Mutex};
use std::time::Instant;
use volterra::render::{self, shear_warp, Frame, RenderCache};
use volterra::scene::{Camera, Scene};

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Quality {
    /// While the camera moves: a fraction of the pixels.
    Preview,
    /// Once it stops: every pixel, as `volterra render` draws the saved scene.
    Full,
    /// The brute-force reference renderers at the same view, to measure the error.
    Reference,
}

pub struct Job {
    /// The viewer's state version the job shows.
    pub version: u64,
    pub quality: Quality,
    pub scene: Arc<Scene>,
    pub camera: Camera,
    pub size: (usize, usize),
}

pub struct Done {
    pub version: u64,
    pub quality: Quality,
    pub size: (usize, usize),
    pub result: Result<Frame, String>,
    /// Wall time of the render, including data loading on first use.
    pub seconds: f64,
}

#[derive(Default)]
struct Mailbox {
    job: Option<Job>,
    busy: bool,
    quit: bool,
}

pub struct RenderWorker {
    mailbox: Arc<(Mutex<Mailbox>, Condvar)>,
    done: Receiver<Done>,
    progress: Arc<WorkerProgress>,
}

/// The render thread's progress, for the status bar. A preview or full frame still
/// rendering when a newer job is queued is cancelled: its picture is already stale.
struct WorkerProgress {
    mailbox: Arc<(Mutex<Mailbox>, Condvar)>,
    /// (what, done, total) of the work running now.
    now: Mutex<Option<(String, u64, u64)>>,
    /// Whether the running job may be cancelled by a newer one.
    cancellable: std::sync::atomic::AtomicBool,
}

impl render::driver::Progress for WorkerProgress {
    fn begin(&self, what: &str, total: u64) {
        *self.now.lock().unwrap() = Some((what.to_string(), 0, total));
    }
    fn update(&self, done: u64) {
        if let Some(n) = self.now.lock().unwrap().as_mut() {
            n.1 = n.1.max(done);
        }
    }
    fn end(&self) {
        *self.now.lock().unwrap() = None;
    }
    fn cancelled(&self) -> bool {
        self.cancellable.load(std::sync::atomic::Ordering::Relaxed) && self.mailbox.0.lock().unwrap().job.is_some()
    }
}

impl RenderWorker {
    /// Starts the thread; `wake` is called after every finished job (the UI repaints).
    pub fn start(wake: impl Fn() + Send + 'static) -> RenderWorker {
        let mailbox: Arc<(Mutex<Mailbox>, Condvar)> = Arc::default();
        let (tx, done) = channel();
        let mb = mailbox.clone();
        let progress = Arc::new(WorkerProgress { mailbox: mailbox.clone(), now: Mutex::new(None), cancellable: Default::default() });
        let p = progress.clone();
        // Detached: a render in progress when the viewer closes is left to finish on its
        // own (its result goes nowhere) rather than holding up the window's closing.
        std::thread::Builder::new()
            .name("volterra-render".into())
            .spawn(move || render::driver::observed(p.clone(), || work(mb, tx, wake, &p)))
            .expect("spawn render thread");
        RenderWorker { mailbox, done, progress }
    }

    /// What the render thread is doing now: (what, done, total).
    pub fn progress(&self) -> Option<(String, u64, u64)> {
        self.progress.now.lock().unwrap().clone()
    }

    /// Queues `job`, replacing any job not yet started.
    pub fn submit(&self, job: Job) {
        let (lock, cv) = &*self.mailbox;
        lock.lock().unwrap().job = Some(job);
        cv.notify_all();
    }

    /// Finished jobs, oldest first.
    pub fn poll(&self) -> Vec<Done> {
        self.done.try_iter().collect()
    }

    /// True while a job is queued or rendering.
    pub fn busy(&self) -> bool {
        let m = self.mailbox.0.lock().unwrap();
        m.busy || m.job.is_some()
    }

    /// Blocks until nothing is queued or rendering (tests, and saving a final image).
    pub fn wait_idle(&self, timeout: std::time::Duration) -> bool {
        let (lock, cv) = &*self.mailbox;
        let deadline = Instant::now() + timeout;
        let mut m = lock.lock().unwrap();
        while m.busy || m.job.is_some() {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return false;
            }
            m = cv.wait_timeout(m, left).unwrap().0;
        }
        true
    }
}

impl Drop for RenderWorker {
    fn drop(&mut self) {
        let (lock, cv) = &*self.mailbox;
        lock.lock().unwrap().quit = true;
        cv.notify_all();
    }
}

fn work(mailbox: Arc<(Mutex<Mailbox>, Condvar)>, tx: Sender<Done>, wake: impl Fn(), progress: &WorkerProgress) {
    let (lock, cv) = &*mailbox;
    let mut cache = RenderCache::default();
    let mut cached_for: Option<PathBuf> = None;
    let mut cached_time: Option<f64> = None;
    loop {
        let job = {
            let mut m = lock.lock().unwrap();
            loop {
                if m.quit {
                    return;
                }
                if let Some(j) = m.job.take() {
                    m.busy = true;
                    break j;
                }
                m = cv.wait(m).unwrap();
            }
        };
        // A different scene file: drop the previous scene's prepared volumes.
        if cached_for.as_deref() != Some(job.scene.source.as_path()) {
            cache = RenderCache::default();
            cached_for = Some(job.scene.source.clone());
        }
        // Another step of a time series: what was prepared for steps no longer drawn goes
        // (only then: previews and full frames of one step share their preparations).
        if job.scene.time() != cached_time {
            cache.keep_only_for(&job.scene);
            cached_time = job.scene.time();
        }
        let start = Instant::now();
        progress.cancellable.store(job.quality != Quality::Reference, std::sync::atomic::Ordering::Relaxed);
        let result: anyhow::Result<Frame> = match job.quality {
            Quality::Reference => render_reference(&job.scene, &job.camera, job.size).map_err(anyhow::Error::msg),
            Quality::Preview => preview_of(&job.scene).and_then(|s| render::render_view(&s, &job.camera, job.size, &cache)),
            Quality::Full => render::render_view(&job.scene, &job.camera, job.size, &cache),
        };
        // Shear-warp refuses a camera inside a volume (one principal axis cannot hold rays
        // leaving the eye every way): the viewer draws that view with the reference ray
        // caster instead of showing the refusal, and says so — at its preview step (0.25
        // voxel) for full frames too, which keeps a full frame to seconds.
        let result = match result {
            Err(e) if job.quality != Quality::Reference && format!("{e:#}").contains(shear_warp::factor::EYE_INSIDE) => {
                let scene = volume_references(&job.scene).and_then(|s| preview_of(&s));
                scene.and_then(|s| render::render_view(&s, &job.camera, job.size, &cache)).map(|mut f| {
                    f.stats.notes.push(EYE_INSIDE_NOTE.into());
                    f
                })
            }
            r => r,
        };
        // A cancelled frame is stale: the job that cancelled it is already queued.
        let cancelled = result.as_ref().is_err_and(|e| e.root_cause().is::<render::driver::Cancelled>());
        let result = result.map_err(|e| format!("{e:#}"));
        let done = Done { version: job.version, quality: job.quality, size: job.size, result, seconds: start.elapsed().as_secs_f64() };
        if !cancelled {
            let _ = tx.send(done);
        }
        {
            let mut m = lock.lock().unwrap();
            m.busy = false;
        }
        cv.notify_all();
        wake();
    }
}

/// The scene with cheaper settings for previews: each renderer's declared preview values
/// (one camera ray per pixel for smoke, no supersampling and one sample per slab for
/// shear-warp, a 0.25-voxel step for the reference ray caster). Only settings the user
/// did not make cheaper already are touched.
fn preview_of(scene: &Scene) -> anyhow::Result<Scene> {
    let mut file = scene.file.clone();
    for (i, n) in file.nodes.iter_mut().enumerate() {
        if let Some(r) = scene.renderer(i) {
            volterra::settings::apply_preview(r.settings, &mut n.settings);
        }
    }
    scene.edited(file)
}

/// What the status bar says of a view drawn by the reference because the eye is inside
/// a volume.
pub const EYE_INSIDE_NOTE: &str =
    "the camera is inside the volume: drawn by the reference ray caster (slower; shear-warp needs the eye outside)";

/// The scene with its shear-warp volume nodes drawn by the reference ray caster (their
/// settings carried over), everything else as it is.
fn volume_references(scene: &Scene) -> anyhow::Result<Scene> {
    use volterra::catalog;
    let mut file = scene.file.clone();
    for (i, n) in file.nodes.iter_mut().enumerate() {
        let (Some(from), Some(to)) = (scene.renderer(i), catalog::reference_for(n.kind)) else { continue };
        if n.kind == volterra::scene::NodeKind::Volume && from.name == shear_warp::RENDERER.name {
            n.settings = catalog::carry_over(from, to, &n.settings);
            n.renderer = Some(to.name.into());
        }
    }
    scene.edited(file)
}

/// The same view through each node's brute-force reference (volumes: the f64 ray caster;
/// terrain: the f64 CPU reference), keeping the settings that are part of the picture.
/// Smoke has no reference renderer in-process (Mitsuba is the reference), so a scene with
/// particles has no error figure.
fn render_reference(scene: &Scene, camera: &Camera, size: (usize, usize)) -> Result<Frame, String> {
    use volterra::catalog;
    let mut file = scene.file.clone();
    for (i, n) in file.nodes.iter_mut().enumerate() {
        let Some(from) = scene.renderer(i) else { continue };
        match catalog::reference_for(n.kind) {
            Some(to) => {
                n.settings = catalog::carry_over(from, to, &n.settings);
                n.renderer = Some(to.name.into());
            }
            None if n.visible => return Err(format!("no in-process reference for {} (Mitsuba is its reference)", from.name)),
            None => {}
        }
    }
    let reference = scene.edited(file).map_err(|e| format!("{e:#}"))?;
    render::render_view(&reference, camera, size, &RenderCache::default()).map_err(|e| format!("{e:#}"))
}
