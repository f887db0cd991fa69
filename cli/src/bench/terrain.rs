//! `volterra bench terrain`: the GPU terrain ray-caster on fractal DEMs from 256² to 4096²
//! (30 m cells, 4000 m of relief), for a fly-through camera (above the highest peak) and a
//! walk-through camera (2 m above the ground): pyramid build time, median ms per frame,
//! steps per ray, for the paper's traversal and the two baselines (no raise, linear
//! march), and the depth error against the f64 reference; on the largest DEM, the cost and
//! colour error of 1, 4, 9 and 16 rays per pixel (anti-aliasing); with `--large W×H`, a
//! DEM of that size (tiled where a side exceeds the GPU's largest texture): peak memory,
//! pyramid build and time per frame.

use super::median;
use anyhow::{bail, Result};
use glam::DMat4;
use serde::Serialize;
use std::path::{Path, PathBuf};
use volterra::render::terrain::gpu::{self, GpuTerrain, StepStats, View};
use volterra::render::terrain::grid::{HeightRows, TerrainGrid};
use volterra::render::terrain::shading::{sun_lights, Shading};
use volterra::render::terrain::{depth_agreement, reference, Settings, Traversal};
use volterra::scene::camera::Camera;
use volterra_formats::{Crs, Heightfield};

pub struct TerrainBench {
    pub sizes: Vec<usize>,
    /// A large DEM's samples (east, north), for the memory and tiling rows.
    pub large: Option<(usize, usize)>,
    pub width: usize,
    pub height: usize,
    pub env: super::BenchEnv,
    pub runs: usize,
    pub json: bool,
    pub plot: PathBuf,
}

/// One configuration on one heightfield and camera. Steps and errors are absent for VTK.
#[derive(Debug, Clone, Serialize)]
pub struct Row {
    pub config: String,
    pub camera: String,
    pub size: usize,
    /// Lid map + quadtree on the GPU (ours); building the triangle mesh (VTK).
    pub build_ms: f64,
    pub median_ms: f64,
    pub mean_steps: Option<f64>,
    pub p95_steps: Option<u32>,
    pub max_steps: Option<u32>,
    pub capped_rays: Option<u64>,
    /// Depth against the f64 reference on a smaller image of the same view.
    pub median_rel_depth_error: Option<f64>,
    pub p999_rel_depth_error: Option<f64>,
    pub hit_mismatches_off_silhouette: Option<usize>,
    /// Anti-aliasing rows: colour relative RMSE from 256 rays per pixel (small image).
    pub colour_rel_rmse_vs_256: Option<f64>,
    /// Ours: GPU memory held (heights, pyramid); the large DEM's rows: how far the process's
    /// peak resident memory rose above what it held before making the DEM. VTK: resident
    /// memory its mesh and rendering added to the process (software OpenGL keeps GPU
    /// buffers there too).
    pub memory_mib: f64,
}

impl Row {
    /// A row of timings alone (no steps or errors), for the anti-aliasing, large-DEM and
    /// VTK rows.
    fn timed(config: String, camera: &str, size: usize, build_ms: f64, median_ms: f64, memory_mib: f64) -> Row {
        Row {
            config,
            camera: camera.into(),
            size,
            build_ms,
            median_ms,
            mean_steps: None,
            p95_steps: None,
            max_steps: None,
            capped_rays: None,
            median_rel_depth_error: None,
            p999_rel_depth_error: None,
            hit_mismatches_off_silhouette: None,
            colour_rel_rmse_vs_256: None,
            memory_mib,
        }
    }
}

/// A size² DEM, 30 m cells, 0..4000 m: the built-in fractal terrain, cropped.
pub fn bench_dem(size: usize) -> Heightfield {
    let levels = size.next_power_of_two().trailing_zeros().max(1);
    let dem = volterra::samples::fractal_dem(levels, 30.0, 11);
    let mut elevations = Vec::with_capacity(size * size);
    let mut nodata = Vec::with_capacity(size * size);
    for row in 0..size {
        for col in 0..size {
            let i = row * dem.width + col;
            elevations.push(dem.elevations[i] * 1.6);
            nodata.push(dem.nodata.get(i));
        }
    }
    Heightfield {
        width: size,
        height: size,
        cell_size: [30.0; 2],
        cell_size_native: [30.0; 2],
        origin: [0.0, 0.0],
        crs: Crs::local(),
        elevations,
        nodata: nodata.into_iter().collect(),
        nodata_value: None,
        notes: vec![],
        attributes: Vec::new(),
        units: volterra_formats::heightfield::GridUnits::METRES,
    }
}

/// Fly: from beyond the south-west corner, above the highest peak, looking across.
/// Walk: 2 m above the ground near the middle, looking north-east along the terrain.
pub fn bench_cameras(grid: &TerrainGrid) -> Vec<(&'static str, Camera)> {
    let ext = grid.cell[0] * grid.cells()[0] as f64;
    let top = grid.z_ref + grid.z_hi;
    let fly = Camera {
        position: [-0.05 * ext, -0.05 * ext, top + 0.25 * ext],
        focal_point: [0.5 * ext, 0.5 * ext, grid.z_ref],
        view_up: [0.0, 0.0, 1.0],
        view_angle: 50.0,
        parallel_projection: false,
        parallel_scale: 1.0,
    };
    let (x, y) = (0.55 * ext, 0.45 * ext);
    let ground = grid.surface_height(x, y).unwrap_or(grid.z_ref);
    let walk = Camera {
        position: [x, y, ground + 2.0],
        focal_point: [x + 0.3 * ext, y + 0.4 * ext, ground + 2.0 + 0.02 * ext],
        view_up: [0.0, 0.0, 1.0],
        view_angle: 60.0,
        parallel_projection: false,
        parallel_scale: 1.0,
    };
    vec![("fly", fly), ("walk", walk)]
}

pub fn run(b: &TerrainBench) -> Result<()> {
    if b.runs == 0 || b.sizes.is_empty() {
        bail!("--runs must be at least 1 and --sizes must name a size");
    }
    let gpu = gpu::gpu()?;
    eprintln!("GPU: {} ({:?}, {:?})", gpu.info.name, gpu.info.backend, gpu.info.device_type);
    std::fs::create_dir_all(&b.env.work_dir)?;
    let shading = Shading {
        lights: sun_lights(&[])?,
        ambient: 0.25,
        shadows: false,
        smooth: true,
        rays_per_side: 1,
        colormap: volterra::colormap::Colormap::Hypsometric,
        colour_range: None,
    };
    // The reference is f64 and cell by cell: its image is kept small.
    let (rw, rh) = (192usize, (192 * b.height / b.width).max(1));
    let mut rows = Vec::new();
    let mut histograms = Vec::new();
    let bar = crate::progress::bar(b.sizes.len() as u64 * 2, "terrain bench");
    for &size in &b.sizes {
        let hf = bench_dem(size);
        let grid = TerrainGrid::new(&hf, DMat4::IDENTITY)?;
        // The same DEM and cameras for VTK.
        write_npy(&b.env.work_dir.join(format!("dem_{size}.npy")), size, size, &hf.elevations)?;
        let cameras = bench_cameras(&grid);
        let cams: serde_json::Map<String, serde_json::Value> =
            cameras.iter().map(|(n, c)| (n.to_string(), serde_json::to_value(c).unwrap())).collect();
        std::fs::write(b.env.work_dir.join(format!("cams_{size}.json")), serde_json::to_string(&cams)?)?;
        let mut builds = Vec::new();
        let mut terrain = None;
        for _ in 0..b.runs.min(3) {
            let t = GpuTerrain::new(gpu, &grid, None)?;
            builds.push(t.build_seconds);
            terrain = Some(t);
        }
        let terrain = terrain.expect("built at least once");
        let build_ms = 1e3 * median(&mut builds);
        for (camera_name, cam) in cameras {
            let small = cam.rays(rw, rh);
            let truth = reference::render(&grid, None, &small, &shading)?;
            for &traversal in Traversal::ALL {
                let cap = Settings::default().step_cap(&grid);
                let rays = cam.rays(b.width, b.height);
                let view = View { grid: &grid, rays: &rays, shading: &shading, traversal, max_steps: cap };
                let mut times = terrain.time_frames(gpu, &view, b.runs)?;
                let frame = terrain.render(gpu, &view)?;
                let steps: Vec<u32> = frame.extra[0].1.iter().map(|&s| s as u32).collect();
                let st = StepStats::new(&steps);
                let capped = frame.stats.counter("rays at the step cap").map_or(0, |c| c as u64);
                let check = terrain.render(gpu, &View { rays: &small, ..view })?;
                let agree = depth_agreement(&check, &truth);
                if traversal == Traversal::Quadtree && size == *b.sizes.iter().max().unwrap() {
                    histograms.push(serde_json::json!({ "camera": camera_name, "size": size, "steps": steps }));
                }
                rows.push(Row {
                    config: traversal.name().into(),
                    camera: camera_name.into(),
                    size,
                    build_ms,
                    median_ms: 1e3 * median(&mut times),
                    mean_steps: Some(st.mean),
                    p95_steps: Some(st.p95),
                    max_steps: Some(st.max),
                    capped_rays: Some(capped),
                    median_rel_depth_error: Some(agree.median_rel),
                    p999_rel_depth_error: Some(agree.p999_rel),
                    hit_mismatches_off_silhouette: Some(agree.mismatched_off_silhouette),
                    colour_rel_rmse_vs_256: None,
                    memory_mib: terrain.gpu_bytes as f64 / (1 << 20) as f64,
                });
            }
            // Anti-aliasing on the largest DEM: time per frame and colour error against 256
            // rays per pixel, for k × k rays per pixel.
            if size == *b.sizes.iter().max().unwrap() {
                let cap = Settings::default().step_cap(&grid);
                let rays = cam.rays(b.width, b.height);
                let aa = |k: u32| Shading { rays_per_side: k, ..shading.clone() };
                let truth_shading = aa(16);
                let truth = terrain.render(
                    gpu,
                    &View { grid: &grid, rays: &small, shading: &truth_shading, traversal: Traversal::Quadtree, max_steps: cap },
                )?;
                for k in [1u32, 2, 3, 4] {
                    let sh = aa(k);
                    let view = View { grid: &grid, rays: &rays, shading: &sh, traversal: Traversal::Quadtree, max_steps: cap };
                    let mut times = terrain.time_frames(gpu, &view, b.runs)?;
                    let check = terrain.render(gpu, &View { rays: &small, ..view })?;
                    let memory = terrain.gpu_bytes as f64 / (1 << 20) as f64;
                    let config = format!("quadtree, {} rays/px", k * k);
                    rows.push(Row {
                        colour_rel_rmse_vs_256: Some(volterra::compare::rgba_rel_rmse(&check.rgba, &truth.rgba)),
                        ..Row::timed(config, camera_name, size, build_ms, 1e3 * median(&mut times), memory)
                    });
                }
                // What the view pays for, at 1 ray per pixel: the quadtree row above has smooth
                // normals and no shadows; these change one thing each.
                for (config, sh) in [
                    ("quadtree, faceted normals", Shading { smooth: false, ..shading.clone() }),
                    ("quadtree, with shadows", Shading { shadows: true, ..shading.clone() }),
                ] {
                    let view = View { grid: &grid, rays: &rays, shading: &sh, traversal: Traversal::Quadtree, max_steps: cap };
                    let mut times = terrain.time_frames(gpu, &view, b.runs)?;
                    let memory = terrain.gpu_bytes as f64 / (1 << 20) as f64;
                    rows.push(Row::timed(config.into(), camera_name, size, build_ms, 1e3 * median(&mut times), memory));
                }
            }
            bar.inc(1);
        }
    }
    bar.finish_and_clear();
    if let Some((w, h)) = b.large {
        rows.extend(large_rows(b, gpu, w, h, &shading)?);
    }
    match vtk_rows(b) {
        Ok(r) => rows.extend(r),
        Err(e) => eprintln!("VTK rows skipped: {e:#}"),
    }

    let steps_path = b.env.work_dir.join("terrain_steps.json");
    std::fs::write(&steps_path, serde_json::to_string(&histograms)?)?;
    super::plot(&b.env.python, &b.env.scripts, "plot_terrain_steps.py", &steps_path, &b.plot, "step histogram");
    if b.json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
    }
    let mut report = super::report::Report::new("terrain", TABLES);
    report.line(format!(
        "{}×{} image, median of {} frames; steps per ray; depth error on a {rw}×{rh} image against the f64 reference \
         (miss: hits that disagree off the silhouette); colour error (anti-aliasing rows) against 256 rays per pixel; GPU: {}.",
        b.width, b.height, b.runs, gpu.info.name
    ));
    let mut table = super::report::Table::new(COLUMNS);
    let opt = |v: Option<String>| v.unwrap_or_else(|| "-".into());
    for r in &rows {
        table.row(vec![
            r.size.to_string(),
            r.camera.to_string(),
            r.config.to_string(),
            format!("{:.2}", r.build_ms),
            format!("{:.2}", r.median_ms),
            opt(r.mean_steps.map(|v| format!("{v:.1}"))),
            opt(r.p95_steps.map(|v| v.to_string())),
            opt(r.max_steps.map(|v| v.to_string())),
            opt(r.capped_rays.map(|v| v.to_string())),
            opt(r.median_rel_depth_error.map(|v| format!("{v:.1e}"))),
            opt(r.p999_rel_depth_error.map(|v| format!("{v:.1e}"))),
            opt(r.hit_mismatches_off_silhouette.map(|v| v.to_string())),
            opt(r.colour_rel_rmse_vs_256.map(|v| format!("{:.2} %", 100.0 * v))),
            format!("{:.0}", r.memory_mib),
        ]);
    }
    report.table(table);
    report.image(&b.plot);
    report.finish(b.json, b.env.markdown.as_deref())
}

/// The columns of the bench's table.
const COLUMNS: &[&str] = &[
    "size",
    "camera",
    "config",
    "build ms",
    "ms/frame",
    "mean steps",
    "p95 steps",
    "max steps",
    "capped",
    "med. depth err",
    "p99.9 depth err",
    "miss",
    "colour err",
    "MiB",
];
pub const TABLES: &[&[&str]] = &[COLUMNS];

/// A w × h DEM of 30 m cells and 4000 m of relief: the 4097² fractal tile mirrored as often
/// as needed (continuous across the mirror lines), made row by row as the GPU upload reads
/// it — as a windowed reader of a DEM larger than memory would hand it over — so that the
/// memory measured is the renderer's own.
struct MirroredDem {
    base: Heightfield,
    size: [usize; 2],
}

impl MirroredDem {
    fn new(w: usize, h: usize) -> MirroredDem {
        MirroredDem { base: volterra::samples::fractal_dem(12, 30.0, 11), size: [w, h] }
    }

    /// The base tile's column (row) for column (row) c of the mirrored DEM.
    fn fold(&self, c: usize) -> usize {
        let n = self.base.width;
        let m = c % (2 * (n - 1));
        if m < n {
            m
        } else {
            2 * (n - 1) - m
        }
    }
}

impl HeightRows for MirroredDem {
    fn size(&self) -> [usize; 2] {
        self.size
    }

    fn cell_size(&self) -> [f64; 2] {
        self.base.cell_size
    }

    fn read_row(&self, row: usize, col: usize, out: &mut [f32]) {
        let base_row = &self.base.elevations[self.fold(row) * self.base.width..][..self.base.width];
        for (k, z) in out.iter_mut().enumerate() {
            *z = base_row[self.fold(col + k)] * 1.6;
        }
    }
}

/// The large DEM's rows: the process's peak memory from reading the DEM to the last frame
/// (the DEM's own float32 bytes beside it), the pyramid build, and time per frame for the
/// fly and walk cameras.
fn large_rows(b: &TerrainBench, gpu: &gpu::Gpu, w: usize, h: usize, shading: &Shading) -> Result<Vec<Row>> {
    // The resident peak is reset first (Linux: clear_refs 5), so it counts from here; what
    // the process held before (the adapter, the smaller DEMs' leftovers) is subtracted, so
    // the figure is the DEM's own cost, the "1.3× the DEM + 200 MB" on its terms.
    let _ = std::fs::write("/proc/self/clear_refs", "5");
    let before = status_mib("VmRSS:");
    let dem_mib = (4 * w * h) as f64 / (1 << 20) as f64;
    let grid = TerrainGrid::from_rows(std::sync::Arc::new(MirroredDem::new(w, h)), DMat4::IDENTITY)?;
    let terrain = GpuTerrain::new(gpu, &grid, None)?;
    let mut rows = Vec::new();
    for (camera_name, cam) in bench_cameras(&grid) {
        let rays = cam.rays(b.width, b.height);
        let cap = Settings::default().step_cap(&grid);
        let view = View { grid: &grid, rays: &rays, shading, traversal: Traversal::Quadtree, max_steps: cap };
        let mut times = terrain.time_frames(gpu, &view, b.runs)?;
        let peak = status_mib("VmHWM:") - before;
        eprintln!(
            "large DEM {w}×{h} ({dem_mib:.0} MiB as float32), {}: peak resident {peak:.0} MiB over the {before:.0} MiB held before ({:.2}× the DEM; GPU textures {:.0} MiB)",
            if terrain.tiled() { "tiled" } else { "one texture" },
            peak / dem_mib,
            terrain.gpu_bytes as f64 / (1 << 20) as f64
        );
        let config = format!("quadtree, {}", if terrain.tiled() { "tiled" } else { "one texture" });
        rows.push(Row::timed(config, camera_name, w.max(h), 1e3 * terrain.build_seconds, 1e3 * median(&mut times), peak));
    }
    Ok(rows)
}

/// A line of /proc/self/status in MiB (NaN where there is none: not Linux).
fn status_mib(key: &str) -> f64 {
    super::proc_status_bytes(key).map_or(f64::NAN, |b| b as f64 / (1 << 20) as f64)
}

/// VTK/pyvista's way: the same DEMs as triangle meshes, same cameras and image size.
fn vtk_rows(b: &TerrainBench) -> Result<Vec<Row>> {
    use anyhow::Context;
    let sizes: Vec<String> = b.sizes.iter().map(|s| s.to_string()).collect();
    let out = std::process::Command::new(&b.env.python)
        .arg(b.env.scripts.join("vtk_terrain.py"))
        .args(["--bench", &sizes.join(","), &b.width.to_string(), &b.height.to_string(), &b.runs.to_string()])
        .arg(&b.env.work_dir)
        .output()
        .with_context(|| format!("cannot run {}", b.env.python.display()))?;
    if !out.status.success() {
        bail!("vtk_terrain.py failed: {}", crate::child::last_line(&out.stderr));
    }
    let v: serde_json::Value = serde_json::from_slice(&out.stdout)?;
    let version = v["vtk"].as_str().unwrap_or("").to_string();
    let rows = v["rows"].as_array().context("no VTK rows")?;
    Ok(rows
        .iter()
        .map(|r| {
            Row::timed(
                format!("vtk mesh {version}"),
                r["camera"].as_str().unwrap_or(""),
                r["size"].as_u64().unwrap_or(0) as usize,
                r["build_ms"].as_f64().unwrap_or(f64::NAN),
                r["median_ms"].as_f64().unwrap_or(f64::NAN),
                r["added_rss_mib"].as_f64().unwrap_or(f64::NAN),
            )
        })
        .collect())
}

/// A little-endian f32 array as a .npy file (NPY format 1.0), rows × cols, C order.
fn write_npy(path: &Path, rows: usize, cols: usize, values: &[f32]) -> Result<()> {
    let mut header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({rows}, {cols}), }}");
    // Magic (6) + version (2) + length (2) + header + '\n' is padded to a multiple of 64.
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut bytes = Vec::with_capacity(10 + header.len() + 4 * values.len());
    bytes.extend_from_slice(b"\x93NUMPY\x01\x00");
    bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
    bytes.extend_from_slice(header.as_bytes());
    for v in values {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    volterra_formats::atomic::write_bytes_atomically(path, &bytes)?;
    Ok(())
}
