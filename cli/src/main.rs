//! The `volterra` command line: a thin layer over the library.

use anyhow::{anyhow, bail, Context, Result};
use clap::{Args, Parser, Subcommand};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
#[macro_use]
mod verbosity;
mod bench;
mod child;
mod cluster;
mod gallery;
mod movie;
mod progress;

use volterra::scene::animation::{self, Shard};
use volterra::scene::{Camera, Scene};
use volterra::{compare, info, render};
use volterra_formats::{self as formats, dicom, Dataset, Limits, LoadOptions};

#[derive(Parser)]
#[command(
    name = "volterra",
    version = VERSION,
    about = "Medical and scientific visualization: volumes, terrain, particles",
    after_help = EXIT_CODES
)]
struct Cli {
    /// Say only warnings and errors on stderr: no progress, no "wrote …", no statistics.
    #[arg(short, long, global = true, conflicts_with = "verbose")]
    quiet: bool,
    /// Say more on stderr: every animation frame's statistics, and a closing line with the
    /// command's time and peak memory.
    #[arg(short, long, global = true)]
    verbose: bool,
    /// The memory the whole command may hold (e.g. 4G, 512M): reading, preparation,
    /// rendering and outputs; work that would need more is refused before it starts, naming
    /// what it needs. Default: the memory available.
    #[arg(long, global = true, value_name = "SIZE")]
    max_memory: Option<String>,
    #[command(subcommand)]
    command: Command,
}

/// The version and the commit it was built from (cli/build.rs).
const VERSION: &str = concat!(env!("CARGO_PKG_VERSION"), " (", env!("VOLTERRA_COMMIT"), ")");

/// What the exit status means, as `--help` ends.
const EXIT_CODES: &str = "Exit status: 0 success; 1 an error (one line on stderr naming the file and the problem); \
2 a usage error (unknown flag, bad value); 130 interrupted by SIGINT (Ctrl-C), 143 by SIGTERM \
(no output is left written partially).";

/// What a render draws and writes: `render` and `slurm` (whose tasks render) alike.
#[derive(Args)]
struct RenderArgs {
    scene: PathBuf,
    /// Output image: `.exr` (every channel, linear) or `.png` (sRGB preview); numbered per
    /// frame with --frames.
    #[arg(short, long)]
    output: PathBuf,
    /// Also write an sRGB PNG preview.
    #[arg(long)]
    png: Option<PathBuf>,
    /// Override a scene value: `camera.view_angle=20`, `image.width=256`,
    /// `node.NAME.settings.step=0.25` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    sets: Vec<String>,
}

#[derive(Args, Clone, Default)]
struct ReadArgs {
    /// DICOM directory with several series: the SeriesInstanceUID (or a prefix, or the
    /// number `info` lists) to read.
    #[arg(long)]
    series: Option<String>,
    /// DICOM: resample slices with non-uniform spacing or gaps instead of refusing them.
    #[arg(long)]
    resample: bool,
    /// NIfTI 4-D: which volume to read (0-based; default the first, and for `convert` all of
    /// them).
    #[arg(long)]
    volume: Option<usize>,
    #[command(flatten)]
    heightmap: HeightmapArgs,
}

/// How a PNG heightmap is read (it carries no units or georeferencing).
#[derive(Args, Clone, Default)]
struct HeightmapArgs {
    /// PNG heightmap: metres per grey level.
    #[arg(long)]
    vertical_scale: Option<f64>,
    /// PNG heightmap: metres added after scaling.
    #[arg(long)]
    vertical_offset: Option<f64>,
    /// PNG heightmap: metres between samples.
    #[arg(long)]
    cell_size: Option<f64>,
    /// PNG heightmap: how heights are stored in the pixels.
    #[arg(long, value_enum)]
    encoding: Option<Encoding>,
}

/// `--encoding`, as formats::png_height::HeightEncoding (the formats crate knows no clap).
#[derive(clap::ValueEnum, Clone, Copy)]
enum Encoding {
    /// 8- or 16-bit grey levels times the vertical scale.
    #[value(alias = "gray")]
    Grey,
    /// Mapzen terrarium RGB: (R·256 + G + B/256) − 32768 metres.
    Terrarium,
    /// Mapbox terrain-RGB: −10000 + (R·65536 + G·256 + B)·0.1 metres.
    Mapbox,
}

impl ReadArgs {
    fn options(&self, limits: Limits) -> Result<LoadOptions> {
        let mut o = self.heightmap.options(limits)?;
        o.dicom.series = self.series.clone();
        o.dicom.resample = self.resample;
        o.nifti.volume_index = self.volume.unwrap_or(0);
        Ok(o)
    }
}

impl HeightmapArgs {
    fn options(&self, limits: Limits) -> Result<LoadOptions> {
        let mut o = LoadOptions { limits, ..LoadOptions::default() };
        if let Some(v) = self.vertical_scale {
            o.png.vertical_scale = Some(v);
        }
        if let Some(v) = self.vertical_offset {
            o.png.vertical_offset = v;
        }
        if let Some(v) = self.cell_size {
            o.png.cell_size = Some(v);
        }
        if let Some(e) = self.encoding {
            o.png.encoding = match e {
                Encoding::Grey => formats::png_height::HeightEncoding::Grey,
                Encoding::Terrarium => formats::png_height::HeightEncoding::Terrarium,
                Encoding::Mapbox => formats::png_height::HeightEncoding::Mapbox,
            };
        }
        Ok(o)
    }
}

#[derive(Subcommand)]
enum Command {
    /// Show what a file (or DICOM directory) holds.
    Info {
        path: PathBuf,
        /// Print one JSON object instead of text.
        #[arg(long)]
        json: bool,
        /// A raster's mean and standard deviation over its valid samples (gdalinfo -stats;
        /// always in the JSON).
        #[arg(long)]
        stats: bool,
        #[command(flatten)]
        read: ReadArgs,
    },
    /// Convert: volume → .nii/.nii.gz, heightfield → .tif/.exr, particles → .vtp.
    Convert {
        input: PathBuf,
        output: PathBuf,
        #[command(flatten)]
        read: ReadArgs,
    },
    /// Render a scene to EXR (colour, alpha, depth Z, extra channels) or PNG (an sRGB
    /// preview), as the output's extension says; optionally a PNG beside an EXR.
    Render {
        #[command(flatten)]
        what: RenderArgs,
        /// Render an animation into OUTPUT_0000.exr, OUTPUT_0001.exr, … (and
        /// PNG_0000.png, …): with no N, one frame per timestep of the scene's time series
        /// (or the [orbit]'s frames); with N, N frames over the series' time and along the
        /// [[keyframe]]s or [orbit].
        #[arg(long, value_name = "N", num_args = 0..=1)]
        frames: Option<Option<usize>>,
        /// Render only the frames i with i mod M = K (with --frames): `K/M`, `auto` (a
        /// Slurm job array: SLURM_ARRAY_TASK_ID and its COUNT, or MIN and MAX) or `auto/M`
        /// (a Kubernetes Indexed Job: JOB_COMPLETION_INDEX of M).
        #[arg(long, value_name = "K/M|auto|auto/M", requires = "frames")]
        shard: Option<String>,
        /// Skip frames whose outputs all exist (with --frames; outputs are written
        /// atomically, so an existing file is complete).
        #[arg(long, requires = "frames")]
        resume: bool,
    },
    /// Open the interactive viewer on a scene file, a data file or a DICOM folder (or on
    /// nothing: open one from the window, or drop it there).
    View {
        path: Option<PathBuf>,
        /// Save a PNG of the window after the first full-quality frame, then close.
        #[arg(long, value_name = "PNG")]
        screenshot: Option<PathBuf>,
        #[command(flatten)]
        read: ReadArgs,
    },
    /// Write a Slurm job-array batch script that renders an animation's frames over M
    /// array tasks (each `render --frames --shard auto`), and with --submit submit it.
    Slurm {
        #[command(flatten)]
        what: RenderArgs,
        /// The frames, as `render --frames [N]`.
        #[arg(long, value_name = "N", num_args = 0..=1, required = true)]
        frames: Option<Option<usize>>,
        /// Array tasks (M); at most one per frame.
        #[arg(long, value_name = "M")]
        tasks: usize,
        /// CPUs (render threads) per task.
        #[arg(long, default_value_t = 1)]
        cpus_per_task: usize,
        /// Each task's time limit (sbatch --time, e.g. 30:00).
        #[arg(long)]
        time: Option<String>,
        #[arg(long)]
        partition: Option<String>,
        /// Tasks skip frames already written (resubmit after a failure).
        #[arg(long)]
        resume: bool,
        /// Where the script goes (default: OUTPUT's folder, volterra-SCENE.sbatch).
        #[arg(long)]
        script: Option<PathBuf>,
        /// Submit it with sbatch (prints the job id).
        #[arg(long)]
        submit: bool,
        /// Wait for the whole array to finish (sbatch --wait); fails if a task failed.
        #[arg(long, requires = "submit")]
        wait: bool,
    },
    /// Encode rendered PNG frames ('out/f_*.png' or out/f_####.png) into an MP4 (H.264)
    /// or GIF movie through the system's ffmpeg.
    Movie {
        frames: PathBuf,
        /// OUT.mp4 or OUT.gif.
        #[arg(short, long)]
        output: PathBuf,
        /// Frames per second.
        #[arg(long, default_value_t = 24.0)]
        fps: f64,
    },
    /// Write the built-in sample data and a scene for each into DIR.
    Samples { dir: PathBuf },
    /// The main job on built-in samples: write them, render every scene a renderer exists
    /// for, write EXR and PNG into OUT, print a summary.
    Demo {
        #[arg(long, default_value = "out")]
        out: PathBuf,
        /// Write only the README's gallery pictures into DIR (docs/images): small PNGs of
        /// the samples, and the sample DEM's hillshade.
        #[arg(long, value_name = "DIR", conflicts_with = "out")]
        gallery: Option<PathBuf>,
    },
    /// Benchmarks: speed against error, side by side with the peers in one run.
    Bench {
        #[command(subcommand)]
        bench: BenchCommand,
    },
    /// The renderers, the node kinds they draw and every setting they take (type, default,
    /// allowed values, meaning), as the tables in docs/scene-format.md.
    Renderers,
    /// The photon cache of the smoke renderer: where it is and how large (`cache`), or empty
    /// it (`cache --clear`). Its limit is VOLTERRA_CACHE_MAX (default 1G; 0 turns it off).
    Cache {
        #[arg(long)]
        clear: bool,
    },
    /// Shell completions for bash, zsh, fish, elvish or PowerShell on stdout: e.g.
    /// `volterra completions bash > ~/.local/share/bash-completion/completions/volterra`.
    Completions {
        #[arg(value_enum)]
        shell: clap_complete::Shell,
    },
    /// Manual pages (roff): volterra.1 and one for each command (volterra-render.1, …)
    /// written into DIR, for `man -l DIR/volterra.1` or a MANPATH.
    Man {
        #[arg(default_value = "man")]
        dir: PathBuf,
    },
    /// Compare two EXR images: RMSE, PSNR, max error, relative RMSE per channel.
    Compare {
        a: PathBuf,
        /// The reference image.
        b: PathBuf,
        #[arg(long)]
        json: bool,
    },
    /// DEM products as gdaldem makes them (Horn's gradient, its NoData and edge rules):
    /// hillshade (byte, NoData 0), slope and aspect (float, NoData −9999), color-relief
    /// (RGB or RGBA bytes through a gdaldem colour file), written as GeoTIFF on the input's
    /// grid with its georeferencing; contours as gdal_contour draws them, written as
    /// GeoJSON line features in the DEM's CRS.
    Dem {
        #[arg(value_enum)]
        product: DemProduct,
        /// A GeoTIFF or PNG heightmap.
        input: PathBuf,
        /// The GeoTIFF written.
        output: PathBuf,
        /// Output format (gdaldem -of, also written -of): GTiff, or COG (a Cloud-Optimised
        /// GeoTIFF as GDAL's COG driver writes it: tiled, overviews, directories first).
        #[arg(long = "of", value_name = "FORMAT", default_value = "GTiff")]
        output_format: String,
        /// A creation option (gdaldem -co, also written -co; repeatable). GTiff:
        /// COMPRESS=NONE|DEFLATE|LZW|ZSTD, PREDICTOR=1|2|3, TILED=YES, BLOCKXSIZE=N,
        /// BLOCKYSIZE=N, ZLEVEL=1..9, ZSTD_LEVEL=1..22 (default: uncompressed strips, as
        /// gdaldem). COG: COMPRESS (default LZW), LEVEL, PREDICTOR=YES|NO|STANDARD|FLOATING_POINT,
        /// BLOCKSIZE (512), RESAMPLING=CUBIC|BILINEAR (CUBIC), OVERVIEWS=AUTO|NONE.
        #[arg(long = "co", value_name = "KEY=VALUE")]
        creation_options: Vec<String>,
        /// Vertical exaggeration (gdaldem -z).
        #[arg(long, default_value_t = 1.0)]
        z: f64,
        /// Horizontal units per elevation unit (gdaldem -s): 111120 for a DEM in degrees
        /// with elevations in metres.
        #[arg(long, default_value_t = 1.0)]
        scale: f64,
        /// Light azimuth, degrees clockwise from north (hillshade).
        #[arg(long, default_value_t = 315.0)]
        azimuth: f64,
        /// Light altitude above the horizon, degrees (hillshade).
        #[arg(long, default_value_t = 45.0)]
        altitude: f64,
        /// Slope in percent instead of degrees.
        #[arg(long)]
        percent: bool,
        /// Aspect 0 instead of NoData where the ground is flat (gdaldem -zero_for_flat: as
        /// gdaldem, edge and void cells are 0 too and the output declares no NoData value).
        #[arg(long)]
        zero_for_flat: bool,
        /// Complete the 3 × 3 windows at the raster's edges and around NoData instead of
        /// leaving those cells NoData.
        #[arg(long)]
        compute_edges: bool,
        /// gdaldem -alg: Horn (default) or ZevenbergenThorne for slope, aspect and hillshade;
        /// Riley (default) or Wilson for TRI.
        #[arg(long, value_enum)]
        alg: Option<DemAlg>,
        /// hillshade: four lights weighted by the aspect (gdaldem -multidirectional).
        #[arg(long, conflicts_with = "combined")]
        multidirectional: bool,
        /// hillshade: shading and slope combined (gdaldem -combined).
        #[arg(long)]
        combined: bool,
        /// color-relief: the gdaldem colour file ("value R G B [A]" or "value name" lines;
        /// "nv" for NoData, "x%" of the elevation range).
        #[arg(long)]
        palette: Option<PathBuf>,
        /// color-relief: an alpha band too (gdaldem -alpha).
        #[arg(long)]
        alpha: bool,
        /// color-relief: only the palette's exact values get colours, others transparent
        /// black (gdaldem -exact_color_entry).
        #[arg(long, conflicts_with = "nearest_color_entry")]
        exact_color_entry: bool,
        /// color-relief: the nearest entry's colour instead of interpolating
        /// (gdaldem -nearest_color_entry).
        #[arg(long)]
        nearest_color_entry: bool,
        /// contours: a line every INTERVAL elevation units (gdal_contour -i).
        #[arg(long, conflicts_with = "levels")]
        interval: Option<f64>,
        /// contours: the levels are OFFSET + k · INTERVAL (gdal_contour -off).
        #[arg(long, default_value_t = 0.0, requires = "interval")]
        offset: f64,
        /// contours: these levels only, comma-separated (gdal_contour -fl).
        #[arg(long, value_delimiter = ',', num_args = 1..)]
        levels: Option<Vec<f64>>,
        /// contours: the name of each line's elevation attribute (gdal_contour -a).
        #[arg(long, default_value = "elev")]
        attribute: String,
        /// contours: vertices with the elevation as z (gdal_contour -3d).
        #[arg(long = "3d", conflicts_with = "polygons")]
        three_d: bool,
        /// contours: polygons of the bands between levels instead of lines, one
        /// MultiPolygon feature per band (gdal_contour -p).
        #[arg(long)]
        polygons: bool,
        /// contours --polygons: the name of each band's lower bound (gdal_contour -amin).
        #[arg(long, default_value = "ELEV_MIN", requires = "polygons")]
        attribute_min: String,
        /// contours --polygons: the name of each band's upper bound (gdal_contour -amax).
        #[arg(long, default_value = "ELEV_MAX", requires = "polygons")]
        attribute_max: String,
        #[command(flatten)]
        read: HeightmapArgs,
    },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum DemProduct {
    Hillshade,
    Slope,
    Aspect,
    ColorRelief,
    /// Terrain Ruggedness Index (gdaldem TRI).
    #[value(name = "TRI", alias = "tri")]
    Tri,
    /// Topographic Position Index (gdaldem TPI).
    #[value(name = "TPI", alias = "tpi")]
    Tpi,
    Roughness,
    Contours,
}

/// gdaldem's -alg: the gradient (slope, aspect, hillshade) or TRI's formula.
#[derive(clap::ValueEnum, Clone, Copy, PartialEq, Eq)]
enum DemAlg {
    #[value(name = "Horn", alias = "horn")]
    Horn,
    #[value(name = "ZevenbergenThorne", alias = "zevenbergen-thorne")]
    ZevenbergenThorne,
    #[value(name = "Riley", alias = "riley")]
    Riley,
    #[value(name = "Wilson", alias = "wilson")]
    Wilson,
}

/// color-relief's palette and how it is looked up.
struct ReliefArgs {
    palette: Option<PathBuf>,
    alpha: bool,
    mode: volterra::dem::ColorMode,
}

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

/// What every benchmark takes.
#[derive(Args)]
struct BenchCommon {
    /// Where the benchmark inputs are written (reused between runs).
    #[arg(long, default_value = "target/bench-data")]
    work_dir: PathBuf,
    /// Python with the reference packages (pydicom, nibabel, VTK, Mitsuba, matplotlib);
    /// default: the venv tests/setup_venv.py makes beside the scripts.
    #[arg(long)]
    python: Option<PathBuf>,
    /// The reference scripts (a checkout's tests/reference; default: found beside the
    /// executable or under the working directory).
    #[arg(long, value_name = "DIR")]
    scripts: Option<PathBuf>,
}

impl BenchCommon {
    /// The benchmark's environment: the scripts' directory, the Python to run them with.
    fn resolve(self, limits: Limits) -> Result<crate::bench::BenchEnv> {
        let scripts = crate::bench::scripts_dir(self.scripts.as_deref())?;
        let python = self.python.unwrap_or_else(|| scripts.join(".venv/bin/python"));
        Ok(crate::bench::BenchEnv { work_dir: self.work_dir, python, scripts, limits })
    }
}

/// Timed runs per configuration (medians are quoted).
#[derive(Args)]
struct Runs {
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u64).range(1..))]
    runs: u64,
}

#[derive(Subcommand)]
enum BenchCommand {
    /// Loading DICOM series and gzipped NIfTI against pydicom + numpy and nibabel.
    Formats {
        #[command(flatten)]
        runs: Runs,
        #[command(flatten)]
        common: BenchCommon,
    },
    /// Shear-warp's configurations and VTK's fixed-point mapper against their error from
    /// the reference ray caster.
    ShearWarp {
        /// One volume node; its camera's view is drawn in parallel projection and in
        /// perspective (30°).
        #[arg(long, default_value = "samples/aneurysm.toml")]
        scene: PathBuf,
        /// Time only the configurations whose name contains this text (e.g.
        /// "overlapped ×1", "vtk"); for profiling one path.
        #[arg(long)]
        only: Option<String>,
        /// Print the rows as JSON.
        #[arg(long)]
        json: bool,
        /// Where to write the plot.
        #[arg(long, default_value = "out/bench_shear_warp.png")]
        plot: PathBuf,
        #[command(flatten)]
        runs: Runs,
        #[command(flatten)]
        common: BenchCommon,
    },
    /// A clinical-size CT (512 × 512 × N int16 phantom) opened as a radiologist would
    /// (CT-AAA, shaded, perspective, 512²): the first frame from the file and further
    /// frames, and peak memory, against VTK's fixed-point mapper (nibabel + numpy).
    Clinical {
        /// N, the number of slices.
        #[arg(long, default_value_t = 400)]
        slices: usize,
        /// Frames after the first, each from another direction.
        #[arg(long, default_value_t = 4)]
        frames: usize,
        /// Override a key of the scene our side draws (node "ct"), as `render --set`:
        /// e.g. node.ct.settings.supersampling=1.
        #[arg(long = "set", value_name = "PATH=VALUE")]
        sets: Vec<String>,
        /// Also measure the first view of each side against the reference ray caster (the
        /// truth: shaded, f64, 0.05-voxel steps; rendered once and cached in the work
        /// directory, about 45 s at N = 400 on 2 cores).
        #[arg(long)]
        error: bool,
        /// Also draw speed against error (measures the error too): our configurations
        /// (the defaults, ratios 1, 1.5 and 2, one sample per slab, the nearest warp) and
        /// VTK's at sample distances 0.5, 1 and 2 voxels × ImageSampleDistance 1 and 2, each
        /// as its further frames' median against its first view's error, the Pareto front
        /// marked; the plot goes to --plot.
        #[arg(long)]
        curve: bool,
        /// Where to write the speed/error plot (--curve).
        #[arg(long, default_value = "out/bench_clinical.png")]
        plot: PathBuf,
        /// Print the results as JSON.
        #[arg(long)]
        json: bool,
        #[command(flatten)]
        common: BenchCommon,
    },
    /// The GPU ray-caster's traversals on 256²..4096² DEMs, fly- and walk-through, with
    /// steps per ray and depth error against the f64 reference.
    Terrain {
        /// Heightfield sizes (samples per side, at least 2).
        #[arg(long, value_delimiter = ',', default_values_t = [256u64, 512, 1024, 2048, 4096], value_parser = clap::value_parser!(u64).range(2..))]
        sizes: Vec<u64>,
        /// Image size in pixels, as in the paper.
        #[arg(long, default_value = "1920x1080", value_parser = parse_image_size)]
        image: (usize, usize),
        /// Also a large DEM of this many samples (e.g. 20000x3000; tiled where a side
        /// exceeds the GPU's largest texture): memory, pyramid build and time per frame.
        #[arg(long, value_parser = parse_image_size)]
        large: Option<(usize, usize)>,
        /// Print the rows as JSON.
        #[arg(long)]
        json: bool,
        /// Where to write the step histogram.
        #[arg(long, default_value = "out/bench_terrain.png")]
        plot: PathBuf,
        #[command(flatten)]
        runs: Runs,
        #[command(flatten)]
        common: BenchCommon,
    },
    /// An animation's throughput: the built-in plume series (24 steps) at 500×500 rendered
    /// serially and as 2 shards side by side (frames per minute, frames compared bit for
    /// bit); for smoke, a second view of one step against the first: in a new process
    /// (photons from the disk cache) and in the same one (the preparation kept).
    Frames {
        /// Timesteps (frames).
        #[arg(long, default_value_t = 24)]
        steps: usize,
        /// Particles in the last step (the plume rises: earlier steps hold fewer).
        #[arg(long, default_value_t = 12_000)]
        particles: usize,
        #[arg(long, default_value = "500x500", value_parser = parse_image_size)]
        image: (usize, usize),
        /// points, smoke, or both (repeat the flag).
        #[arg(long = "renderer", default_values_t = ["points".to_string(), "smoke".to_string()])]
        renderers: Vec<String>,
        #[arg(long)]
        json: bool,
        #[command(flatten)]
        common: BenchCommon,
    },
    /// Photon map and particle map, with and without the irradiance map, against their
    /// error from Mitsuba.
    Smoke {
        /// One particle node with a Mitsuba reference in ../data.
        #[arg(long, default_value = "tests/reference/smoke_scenes/plume110k.toml")]
        scene: PathBuf,
        /// Photons traced.
        #[arg(long, default_value_t = 640_000)]
        photons: usize,
        /// Image size in pixels, as in the paper.
        #[arg(long, default_value = "500x500", value_parser = parse_image_size)]
        image: (usize, usize),
        /// Print the rows as JSON.
        #[arg(long)]
        json: bool,
        /// Only the first view at the defaults against Mitsuba (the bench scene's plume and
        /// the built-in 400k plume), not the paper's table.
        #[arg(long)]
        race_only: bool,
        #[command(flatten)]
        common: BenchCommon,
    },
    /// N particles (the plume, 1M by default) as spheres or splats at 1920×1080: our GPU
    /// points renderer against VTK's vtkPointGaussianMapper (pyvista's spheres, or its
    /// Gaussian splats) in the same run.
    Points {
        /// Particles.
        #[arg(long, default_value_t = 1_000_000)]
        count: usize,
        /// spheres or splats.
        #[arg(long, default_value = "spheres", value_parser = parse_point_style)]
        style: volterra::render::points::PointStyle,
        #[arg(long, default_value = "1920x1080", value_parser = parse_image_size)]
        image: (usize, usize),
        /// Frames timed after the first (each turned by half a degree).
        #[arg(long, default_value_t = 10)]
        runs: usize,
        #[arg(long)]
        json: bool,
        #[command(flatten)]
        common: BenchCommon,
    },
}

fn parse_point_style(s: &str) -> Result<volterra::render::points::PointStyle, String> {
    use volterra::render::points::PointStyle;
    PointStyle::ALL.iter().copied().find(|p| p.name() == s).ok_or_else(|| format!("'{s}': spheres or splats"))
}

/// `WIDTHxHEIGHT`, e.g. 1920x1080.
fn parse_image_size(s: &str) -> Result<(usize, usize), String> {
    s.split_once('x')
        .and_then(|(w, h)| Some((w.parse().ok()?, h.parse().ok()?)))
        .filter(|&(w, h): &(usize, usize)| w > 0 && h > 0)
        .ok_or_else(|| format!("expected WIDTHxHEIGHT, e.g. 1920x1080, not {s}"))
}

/// `volterra dem` takes gdaldem's own spellings of its output options, `-of` and `-co`, as
/// well as `--of` and `--co`.
fn gdal_style_args(args: impl Iterator<Item = std::ffi::OsString>) -> Vec<std::ffi::OsString> {
    let args: Vec<std::ffi::OsString> = args.collect();
    let dem = args.iter().skip(1).find(|a| !a.to_string_lossy().starts_with('-')).is_some_and(|a| a == "dem");
    args.into_iter()
        .map(|a| match (dem, a.to_str()) {
            (true, Some("-co")) => "--co".into(),
            (true, Some("-of")) => "--of".into(),
            _ => a,
        })
        .collect()
}

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

impl Cli {
    /// The memory limits every reader and preparation of this command is handed.
    fn limits(&self) -> Result<Limits> {
        Ok(match &self.max_memory {
            None => Limits::default(),
            Some(m) => {
                Limits::max(formats::memory::parse_size(m).ok_or_else(|| anyhow!("--max-memory {m}: expected a size such as 512M or 4G"))?)
            }
        })
    }
}

fn run(cli: Cli, limits: Limits) -> Result<()> {
    let max_memory = cli.max_memory.clone();
    match cli.command {
        Command::Info { path, json, stats, read } => cmd_info(&path, json, stats, read.volume.is_none(), &read.options(limits)?),
        Command::Convert { input, output, read } => cmd_convert(&input, &output, &read, &read.options(limits)?),
        Command::Compare { a, b, json } => cmd_compare(&a, &b, json, &limits),
        Command::Dem {
            product,
            input,
            output,
            output_format,
            creation_options,
            z,
            scale,
            azimuth,
            altitude,
            percent,
            zero_for_flat,
            compute_edges,
            alg,
            multidirectional,
            combined,
            palette,
            alpha,
            exact_color_entry,
            nearest_color_entry,
            interval,
            offset,
            levels,
            attribute,
            three_d,
            polygons,
            attribute_min,
            attribute_max,
            read,
        } => {
            let contour_args = interval.is_some() || levels.is_some() || three_d || polygons || attribute != "elev";
            let contours = match (product, interval, levels) {
                (DemProduct::Contours, Some(interval), None) => Some(volterra::dem::contours::Levels::Interval { interval, offset }),
                (DemProduct::Contours, None, Some(levels)) => Some(volterra::dem::contours::Levels::Fixed(levels)),
                (DemProduct::Contours, ..) => anyhow::bail!("contours need --interval or --levels"),
                _ if contour_args => anyhow::bail!("--interval, --levels, --attribute, --3d and --polygons are for contours only"),
                _ => None,
            };
            if contours.is_some() && (output_format != "GTiff" || !creation_options.is_empty()) {
                anyhow::bail!("-of and -co are for the raster products; contours are written as GeoJSON");
            }
            if let Some(levels) = contours {
                let output_kind = if polygons {
                    ContourOutput::Polygons { min: &attribute_min, max: &attribute_max }
                } else {
                    ContourOutput::Lines { attribute: &attribute, three_d }
                };
                return cmd_contours(&input, &output, &levels, output_kind, &read.options(limits)?);
            }
            use volterra::dem::{GradientAlg, Shading, TriAlg};
            let gradient_product = matches!(product, DemProduct::Slope | DemProduct::Aspect | DemProduct::Hillshade);
            let (gradient, tri) = match (alg, product) {
                (None, _) => (GradientAlg::Horn, TriAlg::Riley),
                (Some(DemAlg::Horn), _) if gradient_product => (GradientAlg::Horn, TriAlg::Riley),
                (Some(DemAlg::ZevenbergenThorne), _) if gradient_product => (GradientAlg::ZevenbergenThorne, TriAlg::Riley),
                (Some(DemAlg::Riley), DemProduct::Tri) => (GradientAlg::Horn, TriAlg::Riley),
                (Some(DemAlg::Wilson), DemProduct::Tri) => (GradientAlg::Horn, TriAlg::Wilson),
                _ => anyhow::bail!("--alg: Horn or ZevenbergenThorne for slope, aspect and hillshade; Riley or Wilson for TRI"),
            };
            if (multidirectional || combined) && product != DemProduct::Hillshade {
                anyhow::bail!("--multidirectional and --combined are for hillshade");
            }
            let shading = match (multidirectional, combined) {
                (true, _) => Shading::MultiDirectional,
                (_, true) => Shading::Combined,
                _ => Shading::Single,
            };
            let options =
                volterra::dem::Options { z, scale, azimuth, altitude, percent, zero_for_flat, compute_edges, gradient, tri, shading };
            let mode = match (exact_color_entry, nearest_color_entry) {
                (true, _) => volterra::dem::ColorMode::Exact,
                (_, true) => volterra::dem::ColorMode::Nearest,
                _ => volterra::dem::ColorMode::Interpolate,
            };
            let write = match output_format.to_ascii_uppercase().as_str() {
                "GTIFF" => {
                    formats::geotiff_write::WriteOptions::from_creation_options(&creation_options).map_err(|e| anyhow!("-co: {e}"))?
                }
                "COG" => {
                    formats::geotiff_write::WriteOptions::from_cog_creation_options(&creation_options).map_err(|e| anyhow!("-co: {e}"))?
                }
                other => anyhow::bail!("-of {other}: volterra dem writes GTiff or COG"),
            };
            cmd_dem(product, &input, &output, &options, &ReliefArgs { palette, alpha, mode }, &write, &read.options(limits)?)
        }
        Command::Renderers => {
            print!("{}", volterra::render::registry::markdown());
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
            None => cmd_render(&scene, &output, png.as_deref(), &sets, limits),
            Some(count) => {
                let shard = match shard {
                    None => Shard::ALL,
                    Some(s) => Shard::parse(&s, &|k| std::env::var(k).ok()).map_err(anyhow::Error::msg)?,
                };
                cmd_render_frames(&scene, &output, png.as_deref(), &sets, FrameJob { count, shard, resume }, limits)
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
            clap_complete::generate(shell, &mut <Cli as clap::CommandFactory>::command(), "volterra", &mut std::io::stdout());
            Ok(())
        }
        Command::Man { dir } => cmd_man(&dir),
        Command::Demo { gallery: Some(dir), .. } => gallery::write(&dir, limits),
        Command::Demo { out, gallery: None } => cmd_demo(&out, limits),
        Command::View { path, screenshot, read } => volterra_view::run(path, read.options(limits)?, screenshot),
        Command::Bench { bench } => cmd_bench(bench, limits),
    }
}

fn cmd_bench(bench: BenchCommand, limits: Limits) -> Result<()> {
    use crate::bench as b;
    // The directory a plot goes into exists before the benchmark runs.
    let plot_dir = |plot: &Path| -> Result<()> {
        match plot.parent().filter(|d| !d.as_os_str().is_empty()) {
            Some(dir) => Ok(std::fs::create_dir_all(dir)?),
            None => Ok(()),
        }
    };
    match bench {
        BenchCommand::Formats { runs, common } => {
            b::formats::run(&b::formats::FormatsBench { env: common.resolve(limits)?, runs: runs.runs as usize })
        }
        BenchCommand::ShearWarp { scene, only, json, plot, runs, common } => {
            plot_dir(&plot)?;
            b::shear_warp::run(&b::shear_warp::ShearWarpBench {
                env: common.resolve(limits)?,
                scene,
                runs: runs.runs as usize,
                json,
                plot,
                only,
            })
        }
        BenchCommand::Terrain { sizes, image: (width, height), large, json, plot, runs, common } => {
            plot_dir(&plot)?;
            b::terrain::run(&b::terrain::TerrainBench {
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
            b::clinical::run(&b::clinical::ClinicalBench {
                env: common.resolve(limits)?,
                slices,
                frames,
                json,
                sets,
                error: error || curve,
                curve: curve.then_some(plot),
            })
        }
        BenchCommand::Points { count, style, image: (width, height), runs, json, common } => {
            b::points::run(&b::points::PointsBench { env: common.resolve(limits)?, count, style, width, height, runs, json })
        }
        BenchCommand::Frames { steps, particles, image: (width, height), renderers, json, common } => {
            std::fs::create_dir_all(&common.work_dir)?;
            b::frames::run(&b::frames::FramesBench { env: common.resolve(limits)?, steps, particles, width, height, renderers, json })
        }
        BenchCommand::Smoke { scene, photons, image: (width, height), json, race_only, common } => {
            std::fs::create_dir_all(&common.work_dir)?;
            b::smoke::run(&b::smoke::SmokeBench { env: common.resolve(limits)?, scene, width, height, photons, json, race_only })
        }
    }
}

/// `whole_series`: list every step of a 4-D NIfTI (no --volume given).
fn cmd_info(path: &Path, json: bool, stats: bool, whole_series: bool, opts: &LoadOptions) -> Result<()> {
    let series = formats::series::discover(path)?.filter(|s| whole_series || s.steps[0].volume_index.is_none());
    if let Some(series) = series {
        // Every step read in turn (one in memory at a time) for its size and ranges.
        let bar = crate::progress::bar(series.steps.len() as u64, "timesteps");
        let mut steps = Vec::with_capacity(series.steps.len());
        for step in &series.steps {
            let mut o = opts.clone();
            o.nifti.volume_index = step.volume_index.unwrap_or(0);
            let data = formats::load(&step.file, &o)?;
            steps.push(info::step_json(step, &data, &opts.particles));
            bar.inc(1);
        }
        bar.finish_and_clear();
        if json {
            let o = serde_json::json!({"series": series.source.display().to_string(), "kind": series.kind,
                "time_unit": series.time_unit, "timesteps": steps});
            println!("{}", serde_json::to_string_pretty(&o)?);
        } else {
            print!("{}", info::series_text(&series, &steps));
        }
        return Ok(());
    }
    if path.is_dir() && opts.dicom.series.is_none() {
        let list = dicom::list_series(path, &opts.limits)?;
        if list.len() > 1 {
            if json {
                println!("{}", serde_json::to_string_pretty(&info::series_json(&list))?);
            } else {
                println!("{} series (choose one with --series):", list.len());
                for (i, s) in list.iter().enumerate() {
                    println!(
                        "  {}: '{}' {}, {} files of {}×{} (UID {})",
                        i + 1,
                        s.description,
                        s.modality,
                        s.files,
                        s.columns,
                        s.rows,
                        s.uid
                    );
                }
            }
            return Ok(());
        }
    }
    let spin = crate::progress::spinner(&format!("reading {}", path.display()));
    if formats::detect(path)? == formats::FileKind::GeoTiff {
        // Read by rows, never held: the range and NoData count come from one pass, so a
        // DEM larger than memory is described at its full resolution.
        let rows =
            formats::geotiff_rows::GeoTiffRows::open(path, &opts.geotiff, &opts.limits, 0).inspect_err(|_| spin.finish_and_clear())?;
        let summary = info::GridSummary::of_rows(&rows);
        spin.finish_and_clear();
        if let Some(failure) = rows.failure() {
            bail!("{failure}");
        }
        match json {
            true => println!("{}", serde_json::to_string_pretty(&info::grid_json(&summary))?),
            false => print!("{}", info::grid_text(&summary, stats)),
        }
        return Ok(());
    }
    let data = formats::load(path, opts);
    spin.finish_and_clear();
    let data = data?;
    if json {
        println!("{}", serde_json::to_string_pretty(&info::dataset_json(&data, &opts.particles))?);
    } else {
        print!("{}", info::dataset_text(&data, &opts.particles, stats));
    }
    Ok(())
}

fn lower_name(p: &Path) -> String {
    p.file_name().map(|n| n.to_string_lossy().to_ascii_lowercase()).unwrap_or_default()
}

fn cmd_convert(input: &Path, output: &Path, read: &ReadArgs, opts: &LoadOptions) -> Result<()> {
    check_output_dir(output)?;
    let out = lower_name(output);
    let nifti_out = out.ends_with(".nii") || out.ends_with(".nii.gz");
    // A 4-D NIfTI converts whole (a 4-D file out) unless --volume names one: never only the
    // first volume without a word.
    if read.volume.is_none() && nifti_out && formats::detect(input)? == formats::FileKind::Nifti {
        let header = formats::nifti::read_nifti_header(input)?;
        if (4..=header.dim[0]).any(|i| header.dim[i as usize] > 1) {
            let spin = crate::progress::spinner(&format!("reading {}", input.display()));
            let all = formats::nifti::read_nifti_volumes(input, &opts.limits);
            spin.finish_and_clear();
            let all = all?;
            formats::nifti::write_nifti_volumes(output, &all.volumes, &all.extra_dims, all.time_step, all.time_unit)?;
            say!("wrote {} ({} volumes)", output.display(), all.volumes.len());
            return Ok(());
        }
    }
    if (out.ends_with(".tif") || out.ends_with(".tiff")) && formats::detect(input)? == formats::FileKind::GeoTiff {
        return convert_geotiff(input, output, opts);
    }
    let spin = crate::progress::spinner(&format!("reading {}", input.display()));
    let data = formats::load(input, opts);
    spin.finish_and_clear();
    let data = data?;
    match data {
        Dataset::Volume(v) if out.ends_with(".nii") || out.ends_with(".nii.gz") => formats::nifti::write_nifti(output, &v)?,
        Dataset::Volume(v) if out.ends_with(".nrrd") => formats::nrrd::write_nrrd(output, &v)?,
        Dataset::Heightfield(h) if out.ends_with(".tif") || out.ends_with(".tiff") => formats::geotiff::write_geotiff(output, &h)?,
        Dataset::Heightfield(h) if out.ends_with(".exr") => {
            let mut img = formats::FloatImage::new(h.width, h.height);
            img.add_channel("Y", h.elevations.clone());
            formats::exr_io::write_exr(output, &img)?
        }
        Dataset::Particles(p) if out.ends_with(".vtp") => formats::vtk::write_vtp(output, &p, &opts.particles)?,
        d => {
            let (kind, allowed) = match d {
                Dataset::Volume(_) => ("a volume", ".nii, .nii.gz or .nrrd"),
                Dataset::Heightfield(_) => ("a heightfield", ".tif or .exr"),
                Dataset::Particles(_) => ("a particle set", ".vtp"),
            };
            bail!("{}: {} converts to {allowed}", output.display(), kind);
        }
    }
    say!("wrote {}", output.display());
    Ok(())
}

/// A GeoTIFF DEM (or its `--extent`) to a float32 GeoTIFF in metres, as `write_geotiff`
/// writes a heightfield held, but read by rows and written strip by strip at full
/// resolution: what is held is a few strips, whatever the DEM's size.
fn convert_geotiff(input: &Path, output: &Path, opts: &LoadOptions) -> Result<()> {
    use formats::geotiff_write::{default_rows_per_strip, write_band_strips, BandKind, StripMut, NODATA_WHERE_NONE_DECLARED};
    let rows = formats::geotiff_rows::GeoTiffRows::open(input, &opts.geotiff, &opts.limits, 0)?;
    let grid = rows.georef().clone();
    // A NoData value is declared where the file declares one or where samples are NoData
    // (values out of range, NaN): that takes a pass over the rows first.
    let nodata = rows.nodata_value.or_else(|| (rows.summary().nodata > 0).then_some(NODATA_WHERE_NONE_DECLARED));
    let rows_per_strip = default_rows_per_strip(grid.width, BandKind::F32);
    let writer = formats::geotiff_write::writer_bytes(grid.width, BandKind::F32, rows_per_strip);
    opts.limits.check(output, "the GeoTIFF writer's strips", &[writer])?;
    let progress = progress::TerminalProgress::default();
    use volterra::render::driver::Progress as _;
    progress.begin("converting", grid.height as u64);
    let w = grid.width;
    let written = write_band_strips(output, &grid, BandKind::F32, nodata, true, rows_per_strip, |first, strip| -> Result<()> {
        let StripMut::F32(cells) = strip else { unreachable!("a float band") };
        for (k, row) in cells.chunks_exact_mut(w).enumerate() {
            rows.read_row(first + k, 0, row);
        }
        if let Some(why) = rows.failure() {
            bail!("{why}");
        }
        if let Some(v) = nodata {
            cells.iter_mut().filter(|z| !z.is_finite()).for_each(|z| *z = v as f32);
        }
        progress.update((first + cells.len() / w) as u64);
        Ok(())
    });
    progress.end();
    written?;
    say!("wrote {} ({}×{})", output.display(), grid.width, grid.height);
    Ok(())
}

fn cmd_dem(
    product: DemProduct,
    input: &Path,
    output: &Path,
    options: &volterra::dem::Options,
    relief: &ReliefArgs,
    write: &formats::geotiff_write::WriteOptions,
    load: &LoadOptions,
) -> Result<()> {
    use volterra::dem::{self, Op, Product};
    // The palette first: a missing one is an error before the DEM is read.
    let palette = match product {
        DemProduct::ColorRelief => {
            let path = relief.palette.as_deref().ok_or_else(|| anyhow::anyhow!("color-relief needs --palette FILE"))?;
            let text = std::fs::read_to_string(path).with_context(|| format!("{}: cannot read the palette", path.display()))?;
            Some((path, text))
        }
        _ => None,
    };
    let (src, grid, nodata_value) = dem_source(input, load)?;
    let palette = match palette {
        Some((path, text)) => {
            let no_range = std::cell::Cell::new(false);
            let palette = dem::parse_palette(&text, nodata_value, || {
                let range = dem::elevation_range(&*src);
                no_range.set(range.is_none());
                range
            });
            if no_range.get() && src.failure().is_none() {
                eprintln!(
                    "warning: {}: no valid samples, so the palette's percentages have no range: each is taken as 0 (as gdaldem)",
                    input.display()
                );
            }
            // A range pass that stopped at a row it could not read: that, not the palette.
            if let Some(why) = src.failure() {
                bail!("{why}");
            }
            Some(palette.with_context(|| path.display().to_string())?)
        }
        None => None,
    };
    let (op, what) = match product {
        DemProduct::Hillshade => (Op::Product(Product::Hillshade, *options), "hillshade"),
        DemProduct::Slope => (Op::Product(Product::Slope, *options), "slope"),
        DemProduct::Aspect => (Op::Product(Product::Aspect, *options), "aspect"),
        DemProduct::Tri => (Op::Product(Product::Tri, *options), "TRI"),
        DemProduct::Tpi => (Op::Product(Product::Tpi, *options), "TPI"),
        DemProduct::Roughness => (Op::Product(Product::Roughness, *options), "roughness"),
        DemProduct::ColorRelief => {
            let palette = palette.as_deref().expect("read above");
            (Op::Relief { palette, mode: relief.mode, alpha: relief.alpha, nodata_value }, "color-relief")
        }
        DemProduct::Contours => unreachable!("contours are drawn by cmd_contours"),
    };
    op.check(src.size()).with_context(|| input.display().to_string())?;
    // Slopes and shading compare a height step with a cell step: without metres for both
    // (a PNG heightmap given no vertical scale or cell size) the angles mean nothing.
    if matches!(product, DemProduct::Slope | DemProduct::Hillshade) && grid.units != formats::GridUnits::METRES {
        let lacks = match (grid.units.elevation_in_metres, grid.units.cell_size_in_metres) {
            (false, false) => {
                "its elevations are grey levels and its cells have no size (give --vertical-scale and --cell-size, in metres)"
            }
            (false, true) => "its elevations are grey levels (give --vertical-scale, metres per level)",
            _ => "its cells have no size (give --cell-size, in metres)",
        };
        eprintln!("warning: {}: the {what}'s angles mean nothing: {lacks}", input.display());
    }
    let progress = progress::TerminalProgress::default();
    use volterra::render::driver::Progress as _;
    progress.begin(what, grid.height as u64);
    let written = dem::write_product(&*src, &grid, &op, output, write, &load.limits, &|rows| progress.update(rows as u64));
    progress.end();
    let valid = written?;
    if valid == 0 {
        let what = match (product, op.nodata()) {
            (DemProduct::ColorRelief, _) => "every cell has the palette's NoData colour (its nv entry, else its lowest)".to_string(),
            (_, Some(v)) => format!("every cell of the output is NoData ({v})"),
            (_, None) => "every cell of the output is 0".to_string(),
        };
        eprintln!("warning: {}: no valid samples (every one NoData): {what}", input.display());
    }
    say!("wrote {} ({}×{})", output.display(), grid.width, grid.height);
    Ok(())
}

/// A DEM's rows as the products read them: a GeoTIFF a band of rows at a time (at full
/// resolution whatever its size: what is held is a few rows), other DEMs whole; where
/// they lie, and the NoData value the file declares.
fn dem_source(
    input: &Path,
    load: &LoadOptions,
) -> Result<(Box<dyn formats::heightfield::HeightRows>, formats::heightfield::GridGeoref, Option<f64>)> {
    if formats::detect(input)? == formats::FileKind::GeoTiff {
        let rows = formats::geotiff_rows::GeoTiffRows::open(input, &load.geotiff, &load.limits, 0)?;
        let (grid, nodata) = (rows.georef().clone(), rows.nodata_value);
        return Ok((Box::new(rows), grid, nodata));
    }
    let formats::Dataset::Heightfield(hf) = formats::load(input, load)? else {
        anyhow::bail!("{}: not a heightfield (a GeoTIFF or PNG DEM)", input.display());
    };
    let (grid, nodata) = (hf.georef(), hf.nodata_value);
    Ok((Box::new(hf), grid, nodata))
}

/// What `dem contours` writes: lines (gdal_contour's default) or band polygons (-p).
enum ContourOutput<'a> {
    Lines { attribute: &'a str, three_d: bool },
    Polygons { min: &'a str, max: &'a str },
}

fn cmd_contours(
    input: &Path,
    output: &Path,
    levels: &volterra::dem::contours::Levels,
    kind: ContourOutput,
    load: &LoadOptions,
) -> Result<()> {
    let ext = output.extension().and_then(|e| e.to_str()).unwrap_or_default().to_ascii_lowercase();
    if ext != "geojson" && ext != "json" {
        anyhow::bail!("{}: contours are written as GeoJSON; name the output .geojson", output.display());
    }
    let (src, grid, _) = dem_source(input, load)?;
    // The rows are read once for the elevation range where an interval needs it, then to
    // draw: progress counts both passes.
    let passes = if matches!(levels, volterra::dem::contours::Levels::Interval { .. }) { 2 } else { 1 };
    let progress = progress::TerminalProgress::default();
    use volterra::render::driver::Progress as _;
    progress.begin("contours", (passes * grid.height) as u64);
    let src = RowsRead { rows: &*src, progress: &progress, read: Default::default(), any_valid: Default::default() };
    let drawn = contours_to(&src, &grid, input, output, levels, kind);
    progress.end();
    if drawn.is_ok() && !src.any_valid.load(std::sync::atomic::Ordering::Relaxed) {
        eprintln!("warning: {}: no valid samples (every one NoData): the output holds no contour", input.display());
    }
    drawn
}

/// A DEM's rows, reporting the rows read to a progress bar.
struct RowsRead<'a> {
    rows: &'a dyn formats::heightfield::HeightRows,
    progress: &'a progress::TerminalProgress,
    read: std::sync::atomic::AtomicU64,
    /// Whether any row read held a valid (finite) sample.
    any_valid: std::sync::atomic::AtomicBool,
}

impl formats::heightfield::HeightRows for RowsRead<'_> {
    fn size(&self) -> [usize; 2] {
        self.rows.size()
    }
    fn cell_size(&self) -> [f64; 2] {
        self.rows.cell_size()
    }
    fn read_row(&self, row: usize, col: usize, out: &mut [f32]) {
        use volterra::render::driver::Progress as _;
        self.rows.read_row(row, col, out);
        if out.iter().any(|z| z.is_finite()) {
            self.any_valid.store(true, std::sync::atomic::Ordering::Relaxed);
        }
        self.progress.update(self.read.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1);
    }
    fn failure(&self) -> Option<String> {
        self.rows.failure()
    }
}

/// An error of the contours, named by the input file unless it names a file already (the
/// output's errors name the output; the reader's name the input).
fn named_input(e: anyhow::Error, input: &Path) -> anyhow::Error {
    let named = e.is::<formats::FormatError>() || e.to_string().starts_with(&input.display().to_string());
    if named {
        e
    } else {
        e.context(input.display().to_string())
    }
}

fn contours_to(
    src: &dyn formats::heightfield::HeightRows,
    grid: &formats::heightfield::GridGeoref,
    input: &Path,
    output: &Path,
    levels: &volterra::dem::contours::Levels,
    kind: ContourOutput,
) -> Result<()> {
    match kind {
        ContourOutput::Lines { attribute, three_d } => {
            // Each line written as soon as it is complete: what is held is two rows and the
            // lines still open, not every line of the DEM.
            let (mut count, mut vertices) = (0usize, 0usize);
            formats::geojson::write_lines_from(output, "contour", &grid.crs, attribute, three_d, |emit| -> Result<()> {
                volterra::dem::contours::contours_each(src, grid, levels, |l| {
                    (count, vertices) = (count + 1, vertices + l.points.len());
                    Ok(emit(formats::geojson::LineFeature { points: &l.points, value: l.level })?)
                })
                .map_err(|e| named_input(e, input))
            })?;
            say!("wrote {} ({count} lines, {vertices} vertices)", output.display());
        }
        ContourOutput::Polygons { min, max } => {
            let bands = volterra::dem::contours::contour_polygons(src, grid, levels).map_err(|e| named_input(e, input))?;
            let features = bands.iter().map(|b| formats::geojson::PolygonFeature { polygons: &b.polygons, min: b.min, max: b.max });
            formats::geojson::write_polygons(output, "contour", &grid.crs, (min, max), features)?;
            let polygons: usize = bands.iter().map(|b| b.polygons.len()).sum();
            say!("wrote {} ({} bands, {polygons} polygons)", output.display(), bands.len());
        }
    }
    Ok(())
}

fn cmd_compare(a: &Path, b: &Path, json: bool, limits: &Limits) -> Result<()> {
    let ia = formats::exr_io::read_exr(a, limits)?;
    let ib = formats::exr_io::read_exr(b, limits)?;
    let c = compare::compare(&ia, &ib).with_context(|| format!("{} vs {}", a.display(), b.display()))?;
    if json {
        println!("{}", serde_json::to_string_pretty(&c)?);
    } else {
        println!("{:<8} {:>12} {:>10} {:>12} {:>12}", "channel", "RMSE", "PSNR dB", "max |err|", "rel. RMSE");
        for s in c.channels.iter().chain(std::iter::once(&c.overall)) {
            println!("{:<8} {:>12.6} {:>10.2} {:>12.6} {:>11.4}%", s.channel, s.rmse, s.psnr_db, s.max_abs, 100.0 * s.relative_rmse);
        }
        println!("coverage mismatch: {} pixels", c.coverage_mismatch);
    }
    Ok(())
}

fn cmd_render(scene_path: &Path, output: &Path, png: Option<&Path>, sets: &[String], limits: Limits) -> Result<()> {
    check_render_outputs(output, png)?;
    let scene = Scene::load(scene_path, sets)?.with_limits(limits);
    let camera = scene.camera(None)?;
    // A DEM larger than memory allows is read only where the camera sees it.
    let scene = scene.with_views(std::slice::from_ref(&camera))?;
    write_frame(&scene, &camera, true, output, png, &render::RenderCache::default())
}

/// Renders one frame seen by `camera` with what `cache` kept from earlier frames, and
/// writes it; `report` prints its statistics and each node's times.
fn write_frame(scene: &Scene, camera: &Camera, report: bool, output: &Path, png: Option<&Path>, cache: &render::RenderCache) -> Result<()> {
    let image = render::render_view(scene, camera, (scene.file.image.width, scene.file.image.height), cache)?;
    if report {
        let counters: Vec<String> = image.stats.counters.iter().map(|(k, v)| format!("{k} {}", short(*v))).collect();
        say!("{}: {}", image.stats.renderer, counters.join(", "));
        for n in &image.stats.notes {
            say!("  {n}");
        }
        for t in &image.stats.nodes {
            say!("node '{}' ({}): load {:.3} s, preparation {:.3} s, render {:.3} s", t.node, t.renderer, t.load, t.prepare, t.render);
        }
    }
    let (bg, exposure) = (scene.file.image.background, scene.file.image.exposure);
    match output_format(output)? {
        OutputFormat::Exr => formats::exr_io::write_exr(output, &image.to_image(bg))?,
        OutputFormat::Png => formats::image::write_png_preview(output, image.width, image.height, &image.preview_rgba(bg, exposure))?,
    }
    if let Some(p) = png {
        formats::image::write_png_preview(p, image.width, image.height, &image.preview_rgba(bg, exposure))?;
    }
    Ok(())
}

/// What a rendered image is written as: decided by the output's extension, never assumed.
#[derive(Clone, Copy, PartialEq)]
enum OutputFormat {
    Exr,
    Png,
}

fn output_format(path: &Path) -> Result<OutputFormat> {
    match path.extension().map(|e| e.to_string_lossy().to_ascii_lowercase()).as_deref() {
        Some("exr") => Ok(OutputFormat::Exr),
        Some("png") => Ok(OutputFormat::Png),
        _ => bail!("{}: unsupported output format (render writes .exr or .png)", path.display()),
    }
}

/// A render's outputs, checked before any work: a format the extension names, directories
/// that exist.
fn check_render_outputs(output: &Path, png: Option<&Path>) -> Result<()> {
    output_format(output)?;
    check_output_dir(output)?;
    png.map_or(Ok(()), check_output_dir)
}

/// Refuses an output whose directory does not exist before any work is done (the atomic
/// writer would otherwise fail at the end with a bare "No such file or directory").
fn check_output_dir(path: &Path) -> Result<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        if !dir.is_dir() {
            bail!("{}: the output directory {} does not exist", path.display(), dir.display());
        }
    }
    Ok(())
}

/// `out.exr` → `out_0007.exr`.
fn numbered(path: &Path, k: usize) -> PathBuf {
    let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let name = match path.extension() {
        Some(ext) => format!("{stem}_{k:04}.{}", ext.to_string_lossy()),
        None => format!("{stem}_{k:04}"),
    };
    path.with_file_name(name)
}

/// What `render --frames` renders: the animation's frames (`count` None: one per
/// timestep, or the orbit's), the shard's share of them, skipping finished ones.
struct FrameJob {
    count: Option<usize>,
    shard: Shard,
    resume: bool,
}

fn cmd_render_frames(scene_path: &Path, output: &Path, png: Option<&Path>, sets: &[String], job: FrameJob, limits: Limits) -> Result<()> {
    check_render_outputs(output, png)?;
    let scene = Scene::load(scene_path, sets)?.with_limits(limits);
    let frames = animation::frames(&scene, job.count)?;
    let outputs = |k: usize| (numbered(output, k), png.map(|p| numbered(p, k)));
    let mine: Vec<_> = frames.iter().filter(|f| job.shard.takes(f.index)).collect();
    // Outputs are renamed into place when complete, so one that exists is finished.
    let done = |k: usize| {
        let (o, p) = outputs(k);
        o.is_file() && p.is_none_or(|p| p.is_file())
    };
    let todo: Vec<animation::AnimationFrame> = mine.iter().filter(|f| !(job.resume && done(f.index))).map(|f| **f).collect();
    // A DEM larger than memory allows is read only where this task's frames see it (a
    // walk's cameras stand on the ground read: `with_views` leaves such a scene as it is).
    let scene = if scene.file.walk.is_none() {
        let cameras = todo.iter().map(|f| scene.camera_at(Some(*f))).collect::<Result<Vec<_>>>()?;
        scene.with_views(&cameras)?
    } else {
        scene
    };
    let shard = if job.shard == Shard::ALL { String::new() } else { format!("task {} of {}: ", job.shard.index, job.shard.of) };
    say!(
        "{shard}{} of the animation's {} frames to render{}",
        todo.len(),
        frames.len(),
        if todo.len() < mine.len() { format!(" ({} already written)", mine.len() - todo.len()) } else { String::new() }
    );
    let bar = crate::progress::bar(todo.len() as u64, "frames");
    // One cache for every frame: shear-warp's preparation and the terrain's pyramid are
    // built once, not per frame; a series' steps are read as frames reach them, and what
    // was read and prepared for a step is dropped once no frame draws it.
    let cache = render::RenderCache::default();
    let mut current = scene;
    let mut seconds = Vec::with_capacity(todo.len());
    for f in &todo {
        let t = std::time::Instant::now();
        if let Some(time) = f.time {
            current = current.at_time(time);
            cache.keep_only_for(&current);
        }
        let camera = current.camera_at(Some(*f))?;
        let (o, p) = outputs(f.index);
        write_frame(&current, &camera, verbosity::verbose(), &o, p.as_deref(), &cache)?;
        seconds.push(t.elapsed().as_secs_f64());
        bar.inc(1);
        if !crate::progress::on_terminal() || verbosity::verbose() {
            // A log (a Slurm task's): a line per frame.
            let time = f.time.map(|t| format!(" (time {})", info::num(t))).unwrap_or_default();
            say!("frame {}{time}: {} in {:.2} s", f.index, o.display(), seconds[seconds.len() - 1]);
        }
    }
    bar.finish_and_clear();
    if let (Some(first), Some(last)) = (todo.first(), todo.last()) {
        let first_s = seconds[0];
        seconds.sort_by(f64::total_cmp);
        say!(
            "wrote {} frame{}: {} … {} (first {:.3} s, median {:.3} s per frame)",
            todo.len(),
            if todo.len() == 1 { "" } else { "s" },
            outputs(first.index).0.display(),
            outputs(last.index).0.display(),
            first_s,
            seconds[seconds.len() / 2]
        );
    }
    Ok(())
}

/// Writes volterra.1 and a page per command and subcommand (volterra-render.1,
/// volterra-bench-clinical.1, …) into `dir`, each written whole or not at all.
fn cmd_man(dir: &Path) -> Result<()> {
    fn pages(cmd: clap::Command, dir: &Path, written: &mut usize) -> Result<()> {
        for sub in cmd.get_subcommands().filter(|s| !s.is_hide_set()).cloned() {
            pages(sub, dir, written)?;
        }
        let man = clap_mangen::Man::new(cmd);
        let mut roff = Vec::new();
        man.render(&mut roff)?;
        formats::atomic::write_bytes_atomically(&dir.join(man.get_filename()), &roff)?;
        *written += 1;
        Ok(())
    }
    std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create the directory", dir.display()))?;
    let mut cmd = <Cli as clap::CommandFactory>::command().disable_help_subcommand(true);
    // Built, the subcommands carry their full names (volterra-render) for their pages.
    cmd.build();
    let mut written = 0;
    pages(cmd, dir, &mut written)?;
    say!("wrote {written} manual pages into {} (man -l {}/volterra.1)", dir.display(), dir.display());
    Ok(())
}

fn cmd_demo(out: &Path, limits: Limits) -> Result<()> {
    let samples = out.join("samples");
    volterra::samples::write_samples(&samples)?;
    say!("wrote built-in samples into {}", samples.display());
    println!("{:<18} {:<12} {:>9} {:>9}  result", "scene", "renderer", "size", "seconds");
    for (name, _) in volterra::samples::SCENES {
        let stem = name.trim_end_matches(".toml");
        let scene = Scene::load(&samples.join(name), &[])?.with_limits(limits);
        let renderer = (0..scene.nodes().len()).filter_map(|i| scene.renderer(i)).map(|r| r.name).collect::<Vec<_>>().join("+");
        let size = format!("{}×{}", scene.file.image.width, scene.file.image.height);
        let exr = out.join(format!("{stem}.exr"));
        let png = out.join(format!("{stem}.png"));
        let t = std::time::Instant::now();
        cmd_render(&samples.join(name), &exr, Some(&png), &[], limits)?;
        println!("{stem:<18} {renderer:<12} {size:>9} {:>9.2}  {} + {}", t.elapsed().as_secs_f64(), exr.display(), png.display());
    }
    Ok(())
}

/// A statistic for a one-line summary: integers as such, others to 4 significant digits
/// (a c_ext of 3.2e-6 in code units printed "0.0000" with 4 decimals).
fn short(v: f64) -> String {
    if !v.is_finite() || (v.fract() == 0.0 && v.abs() < 1e15) {
        return format!("{v:.0}");
    }
    let magnitude = v.abs().log10().floor() as i32;
    if !(-3..6).contains(&magnitude) {
        return format!("{v:.3e}");
    }
    format!("{v:.*}", (3 - magnitude).max(0) as usize)
}
