//! The command line's definitions (clap): the global flags, every command and its
//! arguments, and their parsing rules. `main.rs` runs them; `commands/` does the work.

use anyhow::{anyhow, Result};
use clap::{Args, Parser, Subcommand};
use std::path::PathBuf;
use volterra_formats::{self as formats, Limits, LoadOptions};

#[derive(Parser)]
#[command(
    name = "volterra",
    version = VERSION,
    about = "Medical and scientific visualization: volumes, terrain, particles",
    after_help = EXIT_CODES
)]
pub(crate) struct Cli {
    /// Say only warnings and errors on stderr: no progress, no "wrote …", no statistics.
    #[arg(short, long, global = true, conflicts_with = "verbose")]
    pub(crate) quiet: bool,
    /// Say more on stderr: every animation frame's statistics, and a closing line with the
    /// command's time and peak memory.
    #[arg(short, long, global = true)]
    pub(crate) verbose: bool,
    /// The memory the whole command may hold (e.g. 4G, 512M): reading, preparation,
    /// rendering and outputs; work that would need more is refused before it starts, naming
    /// what it needs. Default: the memory available.
    #[arg(long, global = true, value_name = "SIZE")]
    pub(crate) max_memory: Option<String>,
    #[command(subcommand)]
    pub(crate) command: Command,
}

/// The version and the commit it was built from (cli/build.rs).
pub(crate) const VERSION: &str = concat!(env!("CARGO_PKG_VERSION"), " (", env!("VOLTERRA_COMMIT"), ")");

/// What the exit status means, as `--help` ends.
pub(crate) const EXIT_CODES: &str = "Exit status: 0 success; 1 an error (one line on stderr naming the file and the problem); \
2 a usage error (unknown flag, bad value); 130 interrupted by SIGINT (Ctrl-C), 143 by SIGTERM \
(no output is left written partially).";

/// What a render draws and writes: `render` and `slurm` (whose tasks render) alike.
#[derive(Args)]
pub(crate) struct RenderArgs {
    pub(crate) scene: PathBuf,
    /// Output image: `.exr` (every channel, linear) or `.png` (sRGB preview); numbered per
    /// frame with --frames.
    #[arg(short, long)]
    pub(crate) output: PathBuf,
    /// Also write an sRGB PNG preview.
    #[arg(long)]
    pub(crate) png: Option<PathBuf>,
    /// Override a scene value: `camera.view_angle=20`, `image.width=256`,
    /// `node.NAME.settings.step=0.25` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub(crate) sets: Vec<String>,
}

#[derive(Args, Clone, Default)]
pub(crate) struct ReadArgs {
    /// DICOM directory with several series: the SeriesInstanceUID (or a prefix, or the
    /// number `info` lists) to read.
    #[arg(long)]
    pub(crate) series: Option<String>,
    /// DICOM: resample slices with non-uniform spacing or gaps instead of refusing them.
    #[arg(long)]
    pub(crate) resample: bool,
    /// NIfTI 4-D: which volume to read (0-based; default the first, and for `convert` all of
    /// them).
    #[arg(long)]
    pub(crate) volume: Option<usize>,
    #[command(flatten)]
    pub(crate) heightmap: HeightmapArgs,
}

/// How a PNG heightmap is read (it carries no units or georeferencing).
#[derive(Args, Clone, Default)]
pub(crate) struct HeightmapArgs {
    /// PNG heightmap: metres per grey level.
    #[arg(long)]
    pub(crate) vertical_scale: Option<f64>,
    /// PNG heightmap: metres added after scaling.
    #[arg(long)]
    pub(crate) vertical_offset: Option<f64>,
    /// PNG heightmap: metres between samples.
    #[arg(long)]
    pub(crate) cell_size: Option<f64>,
    /// PNG heightmap: how heights are stored in the pixels.
    #[arg(long, value_enum)]
    pub(crate) encoding: Option<Encoding>,
}

/// `--encoding`, as formats::png_height::HeightEncoding (the formats crate knows no clap).
#[derive(clap::ValueEnum, Clone, Copy)]
pub(crate) enum Encoding {
    /// 8- or 16-bit grey levels times the vertical scale.
    #[value(alias = "gray")]
    Grey,
    /// Mapzen terrarium RGB: (R·256 + G + B/256) − 32768 metres.
    Terrarium,
    /// Mapbox terrain-RGB: −10000 + (R·65536 + G·256 + B)·0.1 metres.
    Mapbox,
}

impl ReadArgs {
    pub(crate) fn options(&self, limits: Limits) -> Result<LoadOptions> {
        let mut o = self.heightmap.options(limits)?;
        o.dicom.series = self.series.clone();
        o.dicom.resample = self.resample;
        o.nifti.volume_index = self.volume.unwrap_or(0);
        Ok(o)
    }
}

impl HeightmapArgs {
    pub(crate) fn options(&self, limits: Limits) -> Result<LoadOptions> {
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
pub(crate) enum Command {
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
        /// Print the summary as JSON (one object per scene) instead of a table.
        #[arg(long, conflicts_with = "gallery")]
        json: bool,
    },
    /// Benchmarks: speed against error, side by side with the peers in one run.
    Bench {
        #[command(subcommand)]
        bench: BenchCommand,
    },
    /// The renderers, the node kinds they draw and every setting they take (type, default,
    /// allowed values, meaning), as the tables in docs/scene-format.md.
    Renderers {
        /// Print them as JSON (one object per renderer, each setting with its type, default,
        /// unit, range and doc) instead of Markdown tables.
        #[arg(long)]
        json: bool,
    },
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
    Dem(DemArgs),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub(crate) enum DemProduct {
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
pub(crate) enum DemAlg {
    #[value(name = "Horn", alias = "horn")]
    Horn,
    #[value(name = "ZevenbergenThorne", alias = "zevenbergen-thorne")]
    ZevenbergenThorne,
    #[value(name = "Riley", alias = "riley")]
    Riley,
    #[value(name = "Wilson", alias = "wilson")]
    Wilson,
}

/// `volterra dem`'s flags (gdaldem's, with its own spellings `-of` and `-co`).
#[derive(Args)]
pub(crate) struct DemArgs {
    #[arg(value_enum)]
    pub(crate) product: DemProduct,
    /// A GeoTIFF or PNG heightmap.
    pub(crate) input: PathBuf,
    /// The GeoTIFF written.
    pub(crate) output: PathBuf,
    /// Output format (gdaldem -of, also written -of): GTiff, or COG (a Cloud-Optimised
    /// GeoTIFF as GDAL's COG driver writes it: tiled, overviews, directories first).
    #[arg(long = "of", value_name = "FORMAT", default_value = "GTiff")]
    pub(crate) output_format: String,
    /// A creation option (gdaldem -co, also written -co; repeatable). GTiff:
    /// COMPRESS=NONE|DEFLATE|LZW|ZSTD, PREDICTOR=1|2|3, TILED=YES, BLOCKXSIZE=N,
    /// BLOCKYSIZE=N, ZLEVEL=1..9, ZSTD_LEVEL=1..22 (default: uncompressed strips, as
    /// gdaldem). COG: COMPRESS (default LZW), LEVEL, PREDICTOR=YES|NO|STANDARD|FLOATING_POINT,
    /// BLOCKSIZE (512), RESAMPLING=CUBIC|BILINEAR (CUBIC), OVERVIEWS=AUTO|NONE.
    #[arg(long = "co", value_name = "KEY=VALUE")]
    pub(crate) creation_options: Vec<String>,
    /// Vertical exaggeration (gdaldem -z).
    #[arg(long, default_value_t = 1.0)]
    pub(crate) z: f64,
    /// Horizontal units per elevation unit (gdaldem -s): 111120 for a DEM in degrees
    /// with elevations in metres.
    #[arg(long, default_value_t = 1.0)]
    pub(crate) scale: f64,
    /// Light azimuth, degrees clockwise from north (hillshade).
    #[arg(long, default_value_t = 315.0)]
    pub(crate) azimuth: f64,
    /// Light altitude above the horizon, degrees (hillshade).
    #[arg(long, default_value_t = 45.0)]
    pub(crate) altitude: f64,
    /// Slope in percent instead of degrees.
    #[arg(long)]
    pub(crate) percent: bool,
    /// Aspect 0 instead of NoData where the ground is flat (gdaldem -zero_for_flat: as
    /// gdaldem, edge and void cells are 0 too and the output declares no NoData value).
    #[arg(long)]
    pub(crate) zero_for_flat: bool,
    /// Complete the 3 × 3 windows at the raster's edges and around NoData instead of
    /// leaving those cells NoData.
    #[arg(long)]
    pub(crate) compute_edges: bool,
    /// gdaldem -alg: Horn (default) or ZevenbergenThorne for slope, aspect and hillshade;
    /// Riley (default) or Wilson for TRI.
    #[arg(long, value_enum)]
    pub(crate) alg: Option<DemAlg>,
    /// hillshade: four lights weighted by the aspect (gdaldem -multidirectional).
    #[arg(long, conflicts_with = "combined")]
    pub(crate) multidirectional: bool,
    /// hillshade: shading and slope combined (gdaldem -combined).
    #[arg(long)]
    pub(crate) combined: bool,
    /// color-relief: the gdaldem colour file ("value R G B [A]" or "value name" lines;
    /// "nv" for NoData, "x%" of the elevation range).
    #[arg(long)]
    pub(crate) palette: Option<PathBuf>,
    /// color-relief: an alpha band too (gdaldem -alpha).
    #[arg(long)]
    pub(crate) alpha: bool,
    /// color-relief: only the palette's exact values get colours, others transparent
    /// black (gdaldem -exact_color_entry).
    #[arg(long, conflicts_with = "nearest_color_entry")]
    pub(crate) exact_color_entry: bool,
    /// color-relief: the nearest entry's colour instead of interpolating
    /// (gdaldem -nearest_color_entry).
    #[arg(long)]
    pub(crate) nearest_color_entry: bool,
    /// contours: a line every INTERVAL elevation units (gdal_contour -i).
    #[arg(long, conflicts_with = "levels")]
    pub(crate) interval: Option<f64>,
    /// contours: the levels are OFFSET + k · INTERVAL (gdal_contour -off).
    #[arg(long, default_value_t = 0.0, requires = "interval")]
    pub(crate) offset: f64,
    /// contours: these levels only, comma-separated (gdal_contour -fl).
    #[arg(long, value_delimiter = ',', num_args = 1..)]
    pub(crate) levels: Option<Vec<f64>>,
    /// contours: the name of each line's elevation attribute (gdal_contour -a).
    #[arg(long, default_value = "elev")]
    pub(crate) attribute: String,
    /// contours: vertices with the elevation as z (gdal_contour -3d).
    #[arg(long = "3d", conflicts_with = "polygons")]
    pub(crate) three_d: bool,
    /// contours: polygons of the bands between levels instead of lines, one
    /// MultiPolygon feature per band (gdal_contour -p).
    #[arg(long)]
    pub(crate) polygons: bool,
    /// contours --polygons: the name of each band's lower bound (gdal_contour -amin).
    #[arg(long, default_value = "ELEV_MIN", requires = "polygons")]
    pub(crate) attribute_min: String,
    /// contours --polygons: the name of each band's upper bound (gdal_contour -amax).
    #[arg(long, default_value = "ELEV_MAX", requires = "polygons")]
    pub(crate) attribute_max: String,
    #[command(flatten)]
    pub(crate) read: HeightmapArgs,
}

/// color-relief's palette and how it is looked up.
pub(crate) struct ReliefArgs {
    pub(crate) palette: Option<PathBuf>,
    pub(crate) alpha: bool,
    pub(crate) mode: volterra::dem::ColorMode,
}

/// What every benchmark takes.
#[derive(Args)]
pub(crate) struct BenchCommon {
    /// Where the benchmark inputs are written (reused between runs).
    #[arg(long, default_value = "target/bench-data")]
    pub(crate) work_dir: PathBuf,
    /// Python with the reference packages (pydicom, nibabel, VTK, Mitsuba, matplotlib);
    /// default: the venv tests/setup_venv.py makes beside the scripts.
    #[arg(long)]
    pub(crate) python: Option<PathBuf>,
    /// The reference scripts (a checkout's tests/reference; default: found beside the
    /// executable or under the working directory).
    #[arg(long, value_name = "DIR")]
    pub(crate) scripts: Option<PathBuf>,
    /// Also write the results as Markdown into FILE's section for this benchmark (made or
    /// replaced; the rest of FILE kept), with the command, machine, date and commit: how
    /// docs/benchmarks.md is made.
    #[arg(long, value_name = "FILE")]
    pub(crate) markdown: Option<PathBuf>,
}

impl BenchCommon {
    /// The benchmark's environment: the scripts' directory, the Python to run them with.
    pub(crate) fn resolve(self, limits: Limits) -> Result<crate::bench::BenchEnv> {
        let scripts = crate::bench::scripts_dir(self.scripts.as_deref())?;
        let python = self.python.unwrap_or_else(|| scripts.join(".venv/bin/python"));
        Ok(crate::bench::BenchEnv { work_dir: self.work_dir, python, scripts, limits, markdown: self.markdown })
    }
}

/// Timed runs per configuration (medians are quoted).
#[derive(Args)]
pub(crate) struct Runs {
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u64).range(1..))]
    pub(crate) runs: u64,
}

#[derive(Subcommand)]
pub(crate) enum BenchCommand {
    /// Loading DICOM series and gzipped NIfTI against pydicom + numpy and nibabel.
    Formats {
        #[command(flatten)]
        runs: Runs,
        /// Print the rows as JSON.
        #[arg(long)]
        json: bool,
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
    /// The GPU volume ray-caster against shear-warp, VTK's GPU ray caster (on this
    /// machine's OpenGL: Mesa's llvmpipe without a GPU) and VTK's fixed-point mapper: the
    /// 512 × 512 × N CT phantom (CT-AAA) and the aneurism (MR-Angio), shaded, perspective,
    /// at each image size; first frame from the file and further frames, each first view's
    /// error from the reference ray caster.
    GpuVolume {
        /// N, the CT phantom's slices.
        #[arg(long, default_value_t = 400)]
        slices: usize,
        /// Frames after the first, each from another direction.
        #[arg(long, default_value_t = 4)]
        frames: usize,
        /// Image sizes.
        #[arg(long, value_delimiter = ',', default_value = "512x512,1920x1080", value_parser = parse_image_size)]
        sizes: Vec<(usize, usize)>,
        /// The aneurism's NIfTI (default: ../shared/data/volumes/aneurism/aneurism.nii.gz,
        /// or under $VOLTERRA_SHARED_DATA, where it exists).
        #[arg(long)]
        aneurism: Option<PathBuf>,
        /// Also measure each first view against the reference ray caster (rendered once per
        /// volume and size, cached in the work directory: minutes at 1920×1080).
        #[arg(long)]
        error: bool,
        /// Override a key of the scene our GPU side draws (node "v"), as `render --set`:
        /// e.g. node.v.settings.step=1.
        #[arg(long = "set", value_name = "PATH=VALUE")]
        sets: Vec<String>,
        /// Leave VTK out (our own configurations only).
        #[arg(long)]
        no_vtk: bool,
        /// Print the rows as JSON.
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

pub(crate) fn parse_point_style(s: &str) -> Result<volterra::render::points::PointStyle, String> {
    use volterra::render::points::PointStyle;
    PointStyle::ALL.iter().copied().find(|p| p.name() == s).ok_or_else(|| format!("'{s}': spheres or splats"))
}

/// `WIDTHxHEIGHT`, e.g. 1920x1080.
pub(crate) fn parse_image_size(s: &str) -> Result<(usize, usize), String> {
    s.split_once('x')
        .and_then(|(w, h)| Some((w.parse().ok()?, h.parse().ok()?)))
        .filter(|&(w, h): &(usize, usize)| w > 0 && h > 0)
        .ok_or_else(|| format!("expected WIDTHxHEIGHT, e.g. 1920x1080, not {s}"))
}

/// `volterra dem` takes gdaldem's own spellings of its output options, `-of` and `-co`, as
/// well as `--of` and `--co`.
pub(crate) fn gdal_style_args(args: impl Iterator<Item = std::ffi::OsString>) -> Vec<std::ffi::OsString> {
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

impl Cli {
    /// The memory limits every reader and preparation of this command is handed.
    pub(crate) fn limits(&self) -> Result<Limits> {
        Ok(match &self.max_memory {
            None => Limits::default(),
            Some(m) => {
                Limits::max(formats::memory::parse_size(m).ok_or_else(|| anyhow!("--max-memory {m}: expected a size such as 512M or 4G"))?)
            }
        })
    }
}
