//! `volterra slurm`: an animation as a Slurm job array. The batch script runs this same
//! executable's `render --frames --shard $SLURM_ARRAY_TASK_ID/M` in every array task, so
//! task K of M renders the frames i with i mod M = K, each written atomically. The script
//! names M itself rather than reading it from the array at run time, so any subset of the
//! array can be submitted again (`sbatch --array=1,3 SCRIPT`, Slurm's way to re-run failed
//! tasks) and each task still renders its own frames; `--resume` in the script lets a
//! resubmission render only what is missing.

use anyhow::{anyhow, bail, Context, Result};
use std::path::{Path, PathBuf};
use std::process::Command;
use volterra::scene::{animation, Scene};

/// What `volterra slurm` was asked for.
pub struct SlurmJob<'a> {
    pub scene: &'a Path,
    pub output: &'a Path,
    pub png: Option<&'a Path>,
    pub sets: &'a [String],
    pub frames: Option<usize>,
    pub tasks: usize,
    pub cpus_per_task: usize,
    pub time: Option<&'a str>,
    pub partition: Option<&'a str>,
    pub resume: bool,
    pub script: Option<&'a Path>,
    /// `--max-memory`, passed on to every task.
    pub max_memory: Option<&'a str>,
    pub submit: bool,
    pub wait: bool,
}

/// A path made absolute against the working directory (the job runs elsewhere) and
/// normalised: `.`, `..` and symbolic links of the folders that exist resolved (a script
/// written from another folder, or through a link, still names the same files).
fn absolute(p: &Path) -> Result<PathBuf> {
    let abs = std::path::absolute(p).with_context(|| format!("{}: cannot make the path absolute", p.display()))?;
    if let Ok(c) = abs.canonicalize() {
        return Ok(c);
    }
    // A file not written yet: its folder resolved, its name kept.
    match (abs.parent().and_then(|d| d.canonicalize().ok()), abs.file_name()) {
        (Some(dir), Some(name)) => Ok(dir.join(name)),
        _ => Ok(abs),
    }
}

/// A word for bash: single-quoted, with any single quote closed, escaped and reopened.
fn quoted(s: &str) -> String {
    format!("'{}'", s.replace('\'', r"'\''"))
}

/// Writes the job array's batch script (and submits it): the scene is loaded and its frames
/// counted first, so a scene with a mistake is refused here, not in every task.
pub fn run(job: &SlurmJob) -> Result<()> {
    if job.tasks == 0 {
        bail!("--tasks must be at least 1");
    }
    if job.cpus_per_task == 0 {
        bail!("--cpus-per-task must be at least 1");
    }
    let scene = Scene::load(job.scene, job.sets)?;
    let frames = animation::frames(&scene, job.frames)?;
    // No task without a frame.
    let tasks = job.tasks.min(frames.len());
    let output = absolute(job.output)?;
    let out_dir = output.parent().map(Path::to_path_buf).unwrap_or_default();
    if !out_dir.is_dir() {
        bail!("{}: the output directory {} does not exist", job.output.display(), out_dir.display());
    }
    let stem = job.scene.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "scene".into());
    let script = match job.script {
        Some(s) => absolute(s)?,
        None => out_dir.join(format!("volterra-{stem}.sbatch")),
    };
    let exe = std::env::current_exe().context("the volterra executable's path")?;
    let mut render = vec![quoted(&exe.to_string_lossy())];
    if let Some(m) = job.max_memory {
        render.extend(["--max-memory".into(), quoted(m)]);
    }
    render.extend(["render".into(), quoted(&absolute(job.scene)?.to_string_lossy()), "-o".into(), quoted(&output.to_string_lossy())]);
    if let Some(p) = job.png {
        render.extend(["--png".into(), quoted(&absolute(p)?.to_string_lossy())]);
    }
    for s in job.sets {
        render.extend(["--set".into(), quoted(s)]);
    }
    render.push("--frames".into());
    if let Some(n) = job.frames {
        render.push(n.to_string());
    }
    // The task's own index over the total named here (see the module's doc).
    render.extend(["--shard".into(), format!("\"${{SLURM_ARRAY_TASK_ID:?submit this script with sbatch}}/{tasks}\"")]);
    if job.resume {
        render.push("--resume".into());
    }
    let mut text = format!(
        "#!/bin/bash\n# Written by `volterra slurm`: the {} frames of {} as a Slurm job array; task K\n\
         # renders the frames i with i mod {tasks} = K (`render --shard K/{tasks}`). Failed tasks can be\n\
         # submitted again alone: sbatch --array=K1,K2 THIS_SCRIPT\n\
         #SBATCH --job-name={}\n#SBATCH --array=0-{}\n#SBATCH --cpus-per-task={}\n#SBATCH --output={}\n",
        frames.len(),
        job.scene.display(),
        quoted(&format!("volterra-{stem}")),
        tasks - 1,
        job.cpus_per_task,
        quoted(&out_dir.join(format!("slurm-{stem}-%A_%a.log")).to_string_lossy()),
    );
    if let Some(t) = job.time {
        text += &format!("#SBATCH --time={}\n", quoted(t));
    }
    if let Some(p) = job.partition {
        text += &format!("#SBATCH --partition={}\n", quoted(p));
    }
    text += &format!(
        "set -eu\n# As many render threads as the task has CPUs (rayon's, and lavapipe's for GPU renderers).\n\
         export RAYON_NUM_THREADS=\"${{SLURM_CPUS_PER_TASK:-1}}\" LP_NUM_THREADS=\"${{SLURM_CPUS_PER_TASK:-1}}\"\nexec {}\n",
        render.join(" ")
    );
    volterra_formats::atomic::write_bytes_atomically(&script, text.as_bytes())?;
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&script, std::fs::Permissions::from_mode(0o755)).with_context(|| script.display().to_string())?;
    }
    say!("wrote {} ({} frames over {tasks} array tasks)", script.display(), frames.len());
    if !job.submit {
        println!("{}", script.display());
        return Ok(());
    }
    let mut sbatch = Command::new("sbatch");
    sbatch.arg("--parsable");
    if job.wait {
        sbatch.arg("--wait");
    }
    let out = sbatch.arg(&script).output().map_err(|e| match e.kind() {
        std::io::ErrorKind::NotFound => {
            anyhow!("sbatch not found: install Slurm's client (Debian: slurm-client) or submit {} yourself", script.display())
        }
        _ => anyhow!("sbatch: {e}"),
    })?;
    let stdout = String::from_utf8_lossy(&out.stdout);
    let id = stdout.lines().next().unwrap_or("").split(';').next().unwrap_or("").trim().to_string();
    if !out.status.success() {
        let why = crate::child::first_line(&out.stderr);
        if job.wait && !id.is_empty() {
            bail!("job {id} ended with a failed task ({why}); logs: {}", out_dir.join(format!("slurm-{stem}-{id}_*.log")).display());
        }
        bail!("sbatch {} failed: {why}", script.display());
    }
    println!("{id}");
    say!("submitted job {id}{}", if job.wait { ", finished" } else { "" });
    Ok(())
}
