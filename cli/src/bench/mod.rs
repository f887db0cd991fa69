//! `volterra bench …`: speed against error, side by side with the peers (pydicom/nibabel,
//! VTK, Mitsuba) in one run. Each benchmark is its own subcommand with its own flags.

pub mod clinical;
pub mod formats;
pub mod frames;
pub mod gpu_volume;
pub mod points;
pub mod report;
pub mod shear_warp;
pub mod smoke;
pub mod terrain;

use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};
/// A memory line of /proc/self/status, in bytes (the memory limit's own reader).
pub use volterra_formats::memory::proc_status_bytes;
use volterra_formats::Limits;

/// What every benchmark runs with, whichever it is.
pub struct BenchEnv {
    /// Where the benchmark inputs are written (reused between runs).
    pub work_dir: PathBuf,
    /// Python with the reference packages (pydicom, nibabel, VTK, Mitsuba, matplotlib).
    pub python: PathBuf,
    /// The reference scripts (tests/reference).
    pub scripts: PathBuf,
    /// The memory limits for what the benchmark reads and prepares (`--max-memory`).
    pub limits: Limits,
    /// The page whose section for this benchmark its results go into (`--markdown`).
    pub markdown: Option<PathBuf>,
}

/// The reference scripts the benchmarks run (tests/reference in a checkout): `given`, else
/// found beside the executable (target/{debug,release}/volterra in a checkout) or under
/// the working directory.
pub fn scripts_dir(given: Option<&Path>) -> Result<PathBuf> {
    let marker = "bench_readers.py";
    if let Some(d) = given {
        if !d.join(marker).is_file() {
            bail!("--scripts {}: no {marker} there (give the checkout's tests/reference)", d.display());
        }
        return Ok(d.to_path_buf());
    }
    let exe = std::env::current_exe().ok();
    let beside_exe =
        exe.as_deref().and_then(Path::parent).and_then(Path::parent).and_then(Path::parent).map(|root| root.join("tests/reference"));
    let candidates: Vec<PathBuf> = beside_exe.into_iter().chain([PathBuf::from("tests/reference")]).collect();
    candidates.into_iter().find(|d| d.join(marker).is_file()).ok_or_else(|| {
        anyhow::anyhow!(
            "the benchmarks' reference scripts (tests/reference/*.py of a volterra checkout) are neither beside this \
             executable nor under the working directory; give --scripts DIR"
        )
    })
}

/// Runs the plot script `scripts/SCRIPT` on `data`, writing `out`; says on stderr where
/// the `what` went, or that it was skipped (no matplotlib in `python`).
pub fn plot(python: &Path, scripts: &Path, script: &str, data: &Path, out: &Path, what: &str) {
    let status = std::process::Command::new(python).arg(scripts.join(script)).arg(data).arg(out).status();
    match status {
        Ok(s) if s.success() => say!("{what} written to {}", out.display()),
        _ => say!("{what} skipped (needs matplotlib in {})", python.display()),
    }
}

/// Runs tests/reference/vtk_volume.py in `mode` (`--bench` or `--clinical`) on the spec
/// file `spec`, returning what it prints (JSON); its last stderr line where it fails.
pub fn run_vtk_volume(env: &BenchEnv, mode: &str, spec: &Path) -> Result<serde_json::Value> {
    let out = std::process::Command::new(&env.python)
        .arg(env.scripts.join("vtk_volume.py"))
        .arg(mode)
        .arg(spec)
        .output()
        .with_context(|| format!("cannot run {}", env.python.display()))?;
    if !out.status.success() {
        bail!("vtk_volume.py failed: {}", crate::child::last_line(&out.stderr));
    }
    Ok(serde_json::from_slice(&out.stdout)?)
}

/// A stable hash for the cache keys of reference images (the shear-warp and clinical
/// benches).
pub fn fxhash<T: std::hash::Hash>(t: &T) -> u64 {
    use std::hash::Hasher;
    let mut h = std::collections::hash_map::DefaultHasher::new();
    t.hash(&mut h);
    h.finish()
}

/// The median (sorts `v`).
pub fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    let m = v.len() / 2;
    if v.len() % 2 == 1 {
        v[m]
    } else {
        0.5 * (v[m - 1] + v[m])
    }
}

/// Runs the benchmark `bench` names.
pub fn dispatch(bench: crate::args::BenchCommand, limits: Limits) -> Result<()> {
    use crate::args::BenchCommand;
    // The directory a plot goes into exists before the benchmark runs.
    let plot_dir = |plot: &Path| -> Result<()> {
        match plot.parent().filter(|d| !d.as_os_str().is_empty()) {
            Some(dir) => Ok(std::fs::create_dir_all(dir)?),
            None => Ok(()),
        }
    };
    match bench {
        BenchCommand::Formats { runs, json, common } => {
            formats::run(&formats::FormatsBench { env: common.resolve(limits)?, runs: runs.runs as usize, json })
        }
        BenchCommand::ShearWarp { scene, only, json, plot, runs, common } => {
            plot_dir(&plot)?;
            shear_warp::run(&shear_warp::ShearWarpBench { env: common.resolve(limits)?, scene, runs: runs.runs as usize, json, plot, only })
        }
        BenchCommand::Terrain { sizes, image: (width, height), large, json, plot, runs, common } => {
            plot_dir(&plot)?;
            terrain::run(&terrain::TerrainBench {
                env: common.resolve(limits)?,
                sizes: sizes.into_iter().map(|s| s as usize).collect(),
                large,
                width,
                height,
                runs: runs.runs as usize,
                json,
                plot,
            })
        }
        BenchCommand::Clinical { slices, frames, json, sets, error, curve, plot, common } => {
            if curve {
                plot_dir(&plot)?;
            }
            clinical::run(&clinical::ClinicalBench {
                env: common.resolve(limits)?,
                slices,
                frames,
                json,
                sets,
                error: error || curve,
                curve: curve.then_some(plot),
            })
        }
        BenchCommand::GpuVolume { slices, frames, sizes, aneurism, error, json, sets, no_vtk, common } => {
            // The aneurism of the shared data, where it is beside the checkout.
            let aneurism = aneurism.or_else(|| {
                let shared = std::env::var_os("VOLTERRA_SHARED_DATA").map(PathBuf::from).unwrap_or_else(|| PathBuf::from("../shared/data"));
                Some(shared.join("volumes/aneurism/aneurism.nii.gz")).filter(|p| p.is_file())
            });
            gpu_volume::run(&gpu_volume::GpuVolumeBench {
                env: common.resolve(limits)?,
                slices,
                frames,
                sizes,
                aneurism,
                error,
                json,
                sets,
                no_vtk,
            })
        }
        BenchCommand::Points { count, style, image: (width, height), runs, json, common } => {
            points::run(&points::PointsBench { env: common.resolve(limits)?, count, style, width, height, runs, json })
        }
        BenchCommand::Frames { steps, particles, image: (width, height), renderers, json, common } => {
            std::fs::create_dir_all(&common.work_dir)?;
            frames::run(&frames::FramesBench { env: common.resolve(limits)?, steps, particles, width, height, renderers, json })
        }
        BenchCommand::Smoke { scene, photons, image: (width, height), json, race_only, common } => {
            std::fs::create_dir_all(&common.work_dir)?;
            smoke::run(&smoke::SmokeBench { env: common.resolve(limits)?, scene, width, height, photons, json, race_only })
        }
    }
}
