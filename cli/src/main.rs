//! The `volterra` command line: a thin layer over the library.

use anyhow::Result;
use clap::Parser;
use std::path::Path;
use std::process::ExitCode;
#[macro_use]
mod verbosity;
mod args;
mod bench;
mod child;
mod cluster;
mod commands;
mod movie;
mod progress;

use args::*;
use volterra::render;
use volterra::scene::animation::Shard;
use volterra_formats::{self as formats, Limits};

/// On SIGINT or SIGTERM: remove the temporary files of outputs being written (outputs are
/// renamed into place only when complete, so an older file stays intact), say so, and exit
/// with 128 + the signal number as shells do.
#[cfg(unix)]
fn exit_cleanly_on_signals() {
    use signal_hook::consts::{SIGINT, SIGTERM};
    let Ok(mut signals) = signal_hook::iterator::Signals::new([SIGINT, SIGTERM]) else { return };
    std::thread::spawn(move || {
        if let Some(sig) = signals.forever().next() {
            let removed = formats::atomic::remove_pending();
            let name = if sig == SIGINT { "SIGINT" } else { "SIGTERM" };
            let what = if removed > 0 { format!(", {removed} unfinished output(s) removed") } else { String::new() };
            eprintln!("error: interrupted by {name}{what}; no output was written partially");
            std::process::exit(128 + sig);
        }
    });
}

#[cfg(not(unix))]
fn exit_cleanly_on_signals() {}

/// A closed pipe (`volterra info --json F | head -1`) ends the program quietly, as Unix
/// tools do: Rust ignores SIGPIPE, so `println!` would panic on the failed write instead.
#[cfg(unix)]
fn default_sigpipe() {
    // SAFETY: restoring a signal's default disposition at start-up, before any thread exists.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

#[cfg(not(unix))]
fn default_sigpipe() {}

/// Without a usable XDG_RUNTIME_DIR (CI shells, cron, ssh without a login session), Mesa's
/// device-select Vulkan layer asks libwayland for a display while wgpu lists adapters, and
/// libwayland prints "error: XDG_RUNTIME_DIR is invalid or not set" on every GPU render. The
/// layer only orders GPUs for a desktop session, which is not there: turn it off, as its
/// manifest allows (NODEVICE_SELECT=1), unless the user chose otherwise.
fn quiet_vulkan_device_select() {
    let runtime_ok = std::env::var_os("XDG_RUNTIME_DIR").is_some_and(|d| Path::new(&d).is_dir());
    if !runtime_ok && std::env::var_os("NODEVICE_SELECT").is_none() {
        // Before any thread exists: nothing reads the environment concurrently.
        std::env::set_var("NODEVICE_SELECT", "1");
    }
}

/// Every heap allocation counted, so that `--max-memory` bounds what the whole command holds.
#[global_allocator]
static ALLOCATOR: formats::memory::CountingAllocator = formats::memory::CountingAllocator;

fn main() -> ExitCode {
    quiet_vulkan_device_select();
    default_sigpipe();
    exit_cleanly_on_signals();
    let cli = Cli::parse_from(gdal_style_args(std::env::args_os()));
    verbosity::set(cli.quiet, cli.verbose);
    let started = std::time::Instant::now();
    // The renderers' progress, as bars on the terminal (none under -q).
    let work = || {
        let limits = cli.limits()?;
        run(cli, limits).map(|()| limits)
    };
    let outcome = if verbosity::quiet() {
        work()
    } else {
        volterra::render::driver::observed(std::sync::Arc::new(crate::progress::TerminalProgress::default()), work)
    };
    if let Ok(Limits { max_bytes: Some(limit) }) = outcome {
        // What the command held at most, against the limit it was given.
        let peak = formats::memory::peak();
        let over = if peak > limit { " — over the limit: a bug, please report it" } else { "" };
        // Where the GPU's memory is the host's, its textures and buffers are in the count.
        let gpu = formats::memory::host_gpu()
            .map(|g| format!(" (with the GPU '{g}''s textures and buffers, which live in host memory)"))
            .unwrap_or_default();
        say!("memory: peak {} of the {} limit{gpu}{over}", formats::memory::human_bytes(peak), formats::memory::human_bytes(limit));
    }
    if verbosity::verbose() {
        let status = if outcome.is_ok() { "done" } else { "failed" };
        eprintln!(
            "volterra: {status} in {:.3} s, peak memory {} (heap)",
            started.elapsed().as_secs_f64(),
            formats::memory::human_bytes(formats::memory::peak())
        );
    }
    match outcome {
        Ok(_) => ExitCode::SUCCESS,
        Err(e) => {
            // One line: the chain of contexts, outermost first.
            let msg: Vec<String> = e.chain().map(|c| c.to_string()).collect();
            eprintln!("error: {}", msg.join(": "));
            ExitCode::from(1)
        }
    }
}

fn run(cli: Cli, limits: Limits) -> Result<()> {
    let max_memory = cli.max_memory.clone();
    match cli.command {
        Command::Info { path, json, stats, read } => {
            commands::files::cmd_info(&path, json, stats, read.volume.is_none(), &read.options(limits)?)
        }
        Command::Convert { input, output, read } => commands::files::cmd_convert(&input, &output, &read, &read.options(limits)?),
        Command::Compare { a, b, json } => commands::files::cmd_compare(&a, &b, json, &limits),
        Command::Dem(args) => commands::dem::run(args, limits),
        Command::Renderers { json } => {
            if json {
                println!("{}", serde_json::to_string_pretty(&volterra::catalog::json())?);
            } else {
                print!("{}", volterra::catalog::markdown());
            }
            Ok(())
        }
        Command::Cache { clear } => {
            use volterra::render::smoke::cache;
            if clear {
                println!("removed {} cached photon file(s)", cache::clear());
            }
            match cache::usage() {
                Some((dir, n, bytes)) => println!(
                    "{}: {n} file(s), {:.1} MB of at most {:.1} MB (VOLTERRA_CACHE_MAX)",
                    dir.display(),
                    bytes as f64 / 1e6,
                    cache::max_bytes() as f64 / 1e6
                ),
                None => println!("no cache directory (set VOLTERRA_CACHE_DIR)"),
            }
            Ok(())
        }
        Command::Render { what: RenderArgs { scene, output, png, sets }, frames, shard, resume } => match frames {
            None => commands::render::cmd_render(&scene, &output, png.as_deref(), &sets, limits),
            Some(count) => {
                let shard = match shard {
                    None => Shard::ALL,
                    Some(s) => Shard::parse(&s, &|k| std::env::var(k).ok()).map_err(anyhow::Error::msg)?,
                };
                commands::render::cmd_render_frames(
                    &scene,
                    &output,
                    png.as_deref(),
                    &sets,
                    commands::render::FrameJob { count, shard, resume },
                    limits,
                )
            }
        },
        Command::Slurm {
            what: RenderArgs { scene, output, png, sets },
            frames,
            tasks,
            cpus_per_task,
            time,
            partition,
            resume,
            script,
            submit,
            wait,
        } => cluster::run(&cluster::SlurmJob {
            max_memory: max_memory.as_deref(),
            scene: &scene,
            output: &output,
            png: png.as_deref(),
            sets: &sets,
            frames: frames.flatten(),
            tasks,
            cpus_per_task,
            time: time.as_deref(),
            partition: partition.as_deref(),
            resume,
            script: script.as_deref(),
            submit,
            wait,
        }),
        Command::Movie { frames, output, fps } => movie::run(&frames, &output, fps),
        Command::Samples { dir } => {
            volterra::samples::write_samples(&dir)?;
            say!("wrote samples and scenes into {}", dir.display());
            Ok(())
        }
        Command::Completions { shell } => {
            commands::manual::completions(shell);
            Ok(())
        }
        Command::Man { dir } => commands::manual::cmd_man(&dir),
        Command::Demo { gallery: Some(dir), .. } => commands::demo::gallery(&dir, limits),
        Command::Demo { out, gallery: None, json } => commands::demo::run(&out, json, limits),
        Command::View { path, screenshot, read } => volterra_view::run(path, read.options(limits)?, screenshot),
        Command::Bench { bench } => bench::dispatch(bench, limits),
    }
}
