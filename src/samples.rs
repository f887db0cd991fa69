//! `volterra samples DIR`: deterministic built-in sample data, made by our own code (no
//! network, no ../shared), and a scene for each:
//! - `angio_phantom.nii.gz`: a vessel-tree angiography phantom with an aneurysm bulge;
//! - `fractal_dem.tif` (float32 GeoTIFF, UTM 10N), `fractal_dem.png` (16-bit) and
//!   `fractal_dem_texture.png`: a fractal DEM with a colour texture;
//! - `smoke_plume.vtp`: a rising smoke plume as SPH particles (and, written by
//!   `volterra bench smoke` only, `smoke_plume_400k.vtp`: 400k particles, denser at the core
//!   and thinner at the edge, h spread about 10×).

use anyhow::{Context, Result};
use std::path::Path;
use volterra_formats::heightfield::{Crs, Heightfield};
use volterra_formats::{image, ParticleArrayNames, ParticleSet, PointArray, RgbImage, Volume, VoxelData};

pub use volterra_formats::rng::SplitMix64;

/// The scene files `samples` writes, by file name. Kept identical to `samples/*.toml` in
/// the repository (a test checks it).
pub const SCENES: &[(&str, &str)] = &[
    ("angio.toml", include_str!("../samples/angio.toml")),
    ("angio_mip.toml", include_str!("../samples/angio_mip.toml")),
    ("angio_shear_warp.toml", include_str!("../samples/angio_shear_warp.toml")),
    ("angio_shaded.toml", include_str!("../samples/angio_shaded.toml")),
    ("angio_preset.toml", include_str!("../samples/angio_preset.toml")),
    ("angio_cropped.toml", include_str!("../samples/angio_cropped.toml")),
    ("angio_gpu.toml", include_str!("../samples/angio_gpu.toml")),
    ("terrain.toml", include_str!("../samples/terrain.toml")),
    ("terrain_png.toml", include_str!("../samples/terrain_png.toml")),
    ("terrain_walk.toml", include_str!("../samples/terrain_walk.toml")),
    ("smoke.toml", include_str!("../samples/smoke.toml")),
    ("smoke_series.toml", include_str!("../samples/smoke_series.toml")),
    ("plume_points.toml", include_str!("../samples/plume_points.toml")),
    ("pet_ct.toml", include_str!("../samples/pet_ct.toml")),
];

pub fn write_samples(dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create directory", dir.display()))?;
    let vol = angio_phantom(128);
    volterra_formats::nifti::write_nifti(&dir.join("angio_phantom.nii.gz"), &vol)?;
    let dem = fractal_dem(9, 30.0, 7);
    volterra_formats::geotiff::write_geotiff(&dir.join("fractal_dem.tif"), &dem)?;
    let grey: Vec<u16> = dem.elevations.iter().map(|&z| (z as f64 / DEM_PNG_SCALE).round().clamp(0.0, 65535.0) as u16).collect();
    image::write_png_grey16(&dir.join("fractal_dem.png"), dem.width, dem.height, &grey)?;
    image::write_png_rgb8(&dir.join("fractal_dem_texture.png"), &dem_texture(&dem))?;
    write_smoke_plume(dir)?;
    write_plume_series(&dir.join("plume_series"), 8, 12_000)?;
    let (ct, pet) = pet_ct_pair();
    volterra_formats::nifti::write_nifti(&dir.join("pet_ct_ct.nii.gz"), &ct)?;
    volterra_formats::nifti::write_nifti(&dir.join("pet_ct_pet.nii.gz"), &pet)?;
    for (name, text) in SCENES {
        volterra_formats::atomic::write_bytes_atomically(&dir.join(name), text.as_bytes())?;
    }
    Ok(())
}

/// A PET/CT pair as a scanner gives it: the CT phantom of `ct_phantom` (the whole body,
/// 192 × 160 × 64 voxels of 1.75 × 1.75 × 2.5 mm) and a PET on its own coarser grid (80 ×
/// 64 × 36 voxels of 4 mm, inside the CT's box) in SUV: 1 in soft tissue, 1.8 in the
/// aorta's blood, 2 in the spine's marrow, 2.5 in a liver on the right, and two lesions
/// (8 mm radius, SUV 9, in front of the spine; 5 mm, SUV 6, in the left lung region),
/// edges blurred as a PET's resolution blurs them (≈ 6 mm). Deterministic.
pub fn pet_ct_pair() -> (Volume, Volume) {
    let ct = ct_phantom_spaced([192, 160, 64], 1.75, 2.5);
    let (n, s) = ([80usize, 64, 36], 4.0);
    let origin = [-0.5 * (n[0] - 1) as f64 * s, -0.5 * (n[1] - 1) as f64 * s, -0.5 * (n[2] - 1) as f64 * s];
    // Soft inside-ness: 1 well inside, ½ on the edge, 0 well outside (edge width ≈ 6 mm).
    let soft = |signed_distance: f64| 0.5 * (1.0 - (signed_distance / 2.5).tanh());
    let ball = |p: [f64; 3], c: [f64; 3], r: f64| soft(((p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) + (p[2] - c[2]).powi(2)).sqrt() - r);
    let mut data = Vec::with_capacity(n[0] * n[1] * n[2]);
    for k in 0..n[2] {
        for j in 0..n[1] {
            for i in 0..n[0] {
                let p = [origin[0] + s * i as f64, origin[1] + s * j as f64, origin[2] + s * k as f64];
                // The body (the CT's ellipse, 150 × 110 mm) scaled to a signed distance in mm.
                let body = soft((((p[0] / 150.0).powi(2) + (p[1] / 110.0).powi(2)).sqrt() - 1.0) * 120.0);
                let aorta = soft((p[0].powi(2) + (p[1] + 35.0).powi(2)).sqrt() - 12.0);
                let spine = soft((p[0].powi(2) + (p[1] + 70.0).powi(2)).sqrt() - 15.0);
                let liver = ball(p, [-70.0, 20.0, -10.0], 45.0);
                let suv = body * (1.0 + 0.8 * aorta + 1.0 * spine + 1.5 * liver)
                    + 8.0 * ball(p, [15.0, -5.0, 10.0], 8.0)
                    + 5.0 * ball(p, [75.0, 30.0, -25.0], 5.0);
                data.push(suv as f32);
            }
        }
    }
    let affine = [[s, 0.0, 0.0, origin[0]], [0.0, s, 0.0, origin[1]], [0.0, 0.0, s, origin[2]], [0.0, 0.0, 0.0, 1.0]];
    let pet = Volume { modality: Some("PT".into()), ..Volume::new(n, affine, VoxelData::F32(data)) };
    (ct, pet)
}

/// Metres per grey level of `fractal_dem.png` (its scene sets the same).
pub const DEM_PNG_SCALE: f64 = 0.05;

/// Distance from p to the segment a–b, and the parameter of the closest point.
fn segment_distance(p: [f64; 3], a: [f64; 3], b: [f64; 3]) -> (f64, f64) {
    let ab = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
    let ap = [p[0] - a[0], p[1] - a[1], p[2] - a[2]];
    let len2 = ab[0] * ab[0] + ab[1] * ab[1] + ab[2] * ab[2];
    let t = if len2 > 0.0 { ((ap[0] * ab[0] + ap[1] * ab[1] + ap[2] * ab[2]) / len2).clamp(0.0, 1.0) } else { 0.0 };
    let d = [ap[0] - t * ab[0], ap[1] - t * ab[1], ap[2] - t * ab[2]];
    ((d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt(), t)
}

/// A vessel tree (tapered tubes that branch in two, four levels deep, from a trunk
/// entering at the bottom) with a saccular aneurysm at one bifurcation, in an n³ u8
/// volume with 0.6 mm voxels (RAS+, centred on the origin). Contrast-filled vessels are
/// bright (≈ 220), the aneurysm brighter (≈ 250), soft tissue faint (≈ 15-30).
pub fn angio_phantom(n: usize) -> Volume {
    let mut rng = SplitMix64(0xA11C_E5ED);
    let nf = n as f64;
    // (start, end, radius) in voxel units.
    let mut segments: Vec<([f64; 3], [f64; 3], f64)> = Vec::new();
    let mut stack = vec![([0.5 * nf, 0.5 * nf, 0.04 * nf], [0.0, 0.0, 1.0], 0.04 * nf, 0.32 * nf, 0usize)];
    let mut bifurcations = Vec::new();
    while let Some((start, dir, radius, length, depth)) = stack.pop() {
        let end = [start[0] + dir[0] * length, start[1] + dir[1] * length, start[2] + dir[2] * length];
        segments.push((start, end, radius));
        if depth < 4 {
            bifurcations.push((end, radius));
            for side in [-1.0, 1.0] {
                let angle = rng.range(0.5, 0.9) * side;
                let twist = rng.range(0.0, std::f64::consts::TAU);
                let (s, c) = angle.sin_cos();
                let nd = [dir[0] * c + s * twist.cos(), dir[1] * c + s * twist.sin(), dir[2] * c];
                let norm = (nd[0] * nd[0] + nd[1] * nd[1] + nd[2] * nd[2]).sqrt();
                let nd = [nd[0] / norm, nd[1] / norm, nd[2] / norm];
                stack.push((end, nd, radius * 0.75, length * rng.range(0.62, 0.8), depth + 1));
            }
        }
    }
    let (bulge_at, bulge_r) = {
        let (p, r) = bifurcations[2];
        (p, 1.7 * r)
    };
    let mut data = vec![0u8; n * n * n];
    // Soft tissue: a faint ellipsoid with smooth noise.
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                let (x, y, z) = ((i as f64 / nf - 0.5) * 2.0, (j as f64 / nf - 0.5) * 2.0, (k as f64 / nf - 0.5) * 2.0);
                let r2 = x * x / 0.8 + y * y / 0.9 + z * z;
                if r2 < 1.0 {
                    let wobble = 4.0 * ((7.0 * x).sin() * (5.0 * y).cos() + (6.0 * z).sin());
                    data[i + n * (j + n * k)] = (20.0 + wobble).clamp(0.0, 255.0) as u8;
                }
            }
        }
    }
    let mut paint = |centre: [f64; 3], reach: f64, value: &dyn Fn([f64; 3]) -> f64| {
        let lo: Vec<usize> = centre.iter().map(|c| (c - reach).floor().max(0.0) as usize).collect();
        let hi: Vec<usize> = centre.iter().map(|c| ((c + reach).ceil() as usize).min(n - 1)).collect();
        for k in lo[2]..=hi[2] {
            for j in lo[1]..=hi[1] {
                for i in lo[0]..=hi[0] {
                    let v = value([i as f64, j as f64, k as f64]);
                    let cell = &mut data[i + n * (j + n * k)];
                    *cell = (*cell).max(v.clamp(0.0, 255.0) as u8);
                }
            }
        }
    };
    for (a, b, r) in &segments {
        let mid = [(a[0] + b[0]) / 2.0, (a[1] + b[1]) / 2.0, (a[2] + b[2]) / 2.0];
        let half = ((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2) + (b[2] - a[2]).powi(2)).sqrt() / 2.0;
        let (a, b, r) = (*a, *b, *r);
        paint(mid, half + 2.0 * r + 2.0, &|p| {
            let (d, t) = segment_distance(p, a, b);
            let radius = r * (1.0 - 0.25 * t);
            // A smooth tube wall: full contrast inside, a 1.5-voxel ramp at the wall.
            220.0 * (0.5 - (d - radius) / 1.5).clamp(0.0, 1.0)
        });
    }
    paint(bulge_at, bulge_r + 2.0, &|p| {
        let d = ((p[0] - bulge_at[0]).powi(2) + (p[1] - bulge_at[1]).powi(2) + (p[2] - bulge_at[2]).powi(2)).sqrt();
        250.0 * (0.5 - (d - bulge_r) / 1.5).clamp(0.0, 1.0)
    });
    Volume { notes: vec!["volterra angiography phantom".into()], ..Volume::centred([n, n, n], [0.6; 3], VoxelData::U8(data)) }
}

/// A (2^levels + 1)² fractal DEM by the diamond-square algorithm, with `cell` metres per
/// sample, georeferenced in UTM zone 10N (EPSG:32610), elevations 0..≈2500 m, with a lake
/// of NoData in one corner so renderers meet holes.
pub fn fractal_dem(levels: u32, cell: f64, seed: u64) -> Heightfield {
    let n = (1usize << levels) + 1;
    let mut rng = SplitMix64(seed);
    let mut h = vec![0f64; n * n];
    let mut amp = 1.0;
    for &(x, y) in &[(0, 0), (n - 1, 0), (0, n - 1), (n - 1, n - 1)] {
        h[y * n + x] = rng.range(-0.5, 0.5);
    }
    let mut step = n - 1;
    while step > 1 {
        let half = step / 2;
        for y in (half..n).step_by(step) {
            for x in (half..n).step_by(step) {
                let avg = (h[(y - half) * n + x - half]
                    + h[(y - half) * n + x + half]
                    + h[(y + half) * n + x - half]
                    + h[(y + half) * n + x + half])
                    / 4.0;
                h[y * n + x] = avg + amp * rng.range(-0.5, 0.5);
            }
        }
        for y in (0..n).step_by(half) {
            let x0 = if (y / half).is_multiple_of(2) { half } else { 0 };
            for x in (x0..n).step_by(step) {
                let mut sum = 0.0;
                let mut cnt = 0.0;
                if y >= half {
                    sum += h[(y - half) * n + x];
                    cnt += 1.0;
                }
                if y + half < n {
                    sum += h[(y + half) * n + x];
                    cnt += 1.0;
                }
                if x >= half {
                    sum += h[y * n + x - half];
                    cnt += 1.0;
                }
                if x + half < n {
                    sum += h[y * n + x + half];
                    cnt += 1.0;
                }
                h[y * n + x] = sum / cnt + amp * rng.range(-0.5, 0.5);
            }
        }
        amp *= 0.55;
        step = half;
    }
    let (lo, hi) = h.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| (a.min(v), b.max(v)));
    let mut nodata = volterra_formats::NodataMask::new(n * n);
    let elevations: Vec<f32> = h
        .iter()
        .enumerate()
        .map(|(i, &v)| {
            let t = (v - lo) / (hi - lo);
            // Sharpen peaks, flatten valleys, like eroded terrain.
            let z = 2500.0 * t.powf(1.8);
            let (x, y) = ((i % n) as f64 / n as f64, (i / n) as f64 / n as f64);
            if (x - 0.12).powi(2) + (y - 0.85).powi(2) < 0.004 {
                nodata.set(i, true);
                f32::NAN
            } else {
                z as f32
            }
        })
        .collect();
    Heightfield {
        width: n,
        height: n,
        cell_size: [cell; 2],
        cell_size_native: [cell; 2],
        origin: [500_000.0 + 0.5 * cell, 5_200_000.0 - 0.5 * cell],
        crs: Crs { epsg: Some(32610), geographic: false, description: "EPSG:32610 (projected)".into(), metres_per_unit: 1.0 },
        elevations,
        nodata,
        nodata_value: Some(-32768.0),
        notes: vec!["volterra fractal DEM".into()],
        attributes: Vec::new(),
        units: volterra_formats::heightfield::GridUnits::METRES,
    }
}

/// An elevation colour ramp with hillshading, one texel per DEM sample.
pub fn dem_texture(dem: &Heightfield) -> RgbImage {
    let (w, h) = (dem.width, dem.height);
    let z = |x: usize, y: usize| {
        let v = dem.elevations[y.min(h - 1) * w + x.min(w - 1)];
        if v.is_nan() {
            0.0
        } else {
            v as f64
        }
    };
    let ramp = [
        (0.0, [70.0, 120.0, 60.0]),
        (600.0, [120.0, 150.0, 80.0]),
        (1400.0, [150.0, 120.0, 90.0]),
        (2000.0, [130.0, 125.0, 120.0]),
        (2300.0, [245.0, 245.0, 250.0]),
    ];
    let mut data = Vec::with_capacity(w * h * 3);
    for y in 0..h {
        for x in 0..w {
            if dem.is_nodata(x, y) {
                data.extend_from_slice(&[40, 80, 160]);
                continue;
            }
            let e = z(x, y);
            let k = ramp.iter().rposition(|(v, _)| e >= *v).unwrap_or(0);
            let col = if k + 1 < ramp.len() {
                let t = (e - ramp[k].0) / (ramp[k + 1].0 - ramp[k].0);
                [0, 1, 2].map(|c| ramp[k].1[c] + t * (ramp[k + 1].1[c] - ramp[k].1[c]))
            } else {
                ramp[k].1
            };
            let dzdx = (z(x + 1, y) - z(x.saturating_sub(1), y)) / (2.0 * dem.cell_size[0]);
            let dzdy = (z(x, y.saturating_sub(1)) - z(x, y + 1)) / (2.0 * dem.cell_size[1]);
            let nrm = (1.0 + dzdx * dzdx + dzdy * dzdy).sqrt();
            let sun = [-0.5f64, 0.5, 0.707];
            let shade = ((-dzdx * sun[0] - dzdy * sun[1] + sun[2]) / nrm).clamp(0.0, 1.0);
            let f = 0.35 + 0.65 * shade;
            data.extend(col.iter().map(|c| (c * f).clamp(0.0, 255.0) as u8));
        }
    }
    RgbImage { width: w, height: h, data }
}

/// The built-in plume, `smoke_plume.vtp` in `dir`: the particles `volterra demo` renders
/// (tests/smoke_mitsuba.rs compares them with Mitsuba).
pub fn write_smoke_plume(dir: &Path) -> Result<()> {
    let plume = smoke_plume(20_000, 3);
    volterra_formats::vtk::write_vtp(&dir.join("smoke_plume.vtp"), &plume, &ParticleArrayNames::default())?;
    Ok(())
}

/// Particles in the large built-in plume: the size of a simulation's output that one view
/// of smoke must still render quickly (`volterra bench smoke` times it against Mitsuba).
pub const LARGE_PLUME: usize = 400_000;

/// The large built-in plume, `smoke_plume_400k.vtp` in `dir`: the plume of
/// [`write_smoke_plume`] with 400,000 particles, thinning from a dense core to its edge as
/// a simulation's does (a Gaussian across it, cut at 2.13 σ: a tenth of the core's density
/// at the edge), so h spreads about 10× (tested), as in the simulation outputs issue 18 names (the
/// uniform cross-section of the small plume spreads 4.7×).
pub fn write_large_plume(dir: &Path) -> Result<()> {
    let plume = large_plume();
    volterra_formats::vtk::write_vtp(&dir.join("smoke_plume_400k.vtp"), &plume, &ParticleArrayNames::default())?;
    Ok(())
}

/// The particles of [`write_large_plume`].
pub fn large_plume() -> ParticleSet {
    plume_with(LARGE_PLUME, 5, CrossSection::Gaussian { cut: 2.13 })
}

/// A built-in time series: the plume as it rises, `steps` timesteps half a second apart,
/// written as `plume_0000.vtp` … in `dir` with a ParaView collection `plume.pvd` listing
/// them. Step k holds the particles emitted so far (those below the front, which climbs
/// from a fifth of the plume's height to all of it), so counts and ranges change with time.
pub fn write_plume_series(dir: &Path, steps: usize, count: usize) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create directory", dir.display()))?;
    let plume = smoke_plume(count, 3);
    let mut pvd = String::from("<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\">\n<Collection>\n");
    for k in 0..steps {
        let front = 0.05 + 0.85 * (0.2 + 0.8 * (k + 1) as f64 / steps as f64);
        let keep: Vec<usize> = (0..plume.len()).filter(|&i| plume.positions[i][2] <= front).collect();
        let pick = |v: &Option<Vec<f32>>| v.as_ref().map(|v| keep.iter().map(|&i| v[i]).collect());
        let step = ParticleSet {
            positions: keep.iter().map(|&i| plume.positions[i]).collect(),
            mass: pick(&plume.mass),
            density: pick(&plume.density),
            smoothing_length: pick(&plume.smoothing_length),
            arrays: plume
                .arrays
                .iter()
                .map(|a| volterra_formats::PointArray {
                    name: a.name.clone(),
                    components: a.components,
                    values: keep.iter().flat_map(|&i| a.values[i * a.components..(i + 1) * a.components].iter().copied()).collect(),
                })
                .collect(),
            notes: vec![],
        };
        let name = format!("plume_{k:04}.vtp");
        volterra_formats::vtk::write_vtp(&dir.join(&name), &step, &ParticleArrayNames::default())?;
        pvd += &format!("  <DataSet timestep=\"{}\" group=\"\" part=\"0\" file=\"{name}\"/>\n", 0.5 * k as f64);
    }
    pvd += "</Collection>\n</VTKFile>\n";
    volterra_formats::atomic::write_bytes_atomically(&dir.join("plume.pvd"), pvd.as_bytes())?;
    Ok(())
}

/// A rising, widening, swirling plume of `count` SPH particles in a 1 m box (z up), with
/// mass, density and smoothing length h set consistently: h from the local particle
/// spacing, density from mass / h³ scaled to the emitted density of 1 kg/m³.
pub fn smoke_plume(count: usize, seed: u64) -> ParticleSet {
    plume_with(count, seed, CrossSection::Uniform)
}

/// How particles spread across the plume at each height.
#[derive(Clone, Copy)]
enum CrossSection {
    /// Evenly over the disc.
    Uniform,
    /// A Gaussian about the axis cut at `cut` σ, the cut at the disc's edge.
    Gaussian { cut: f64 },
}

fn plume_with(count: usize, seed: u64, section: CrossSection) -> ParticleSet {
    let mut rng = SplitMix64(seed);
    let total_mass = 0.01;
    let m = total_mass / count as f64;
    let mut positions = Vec::with_capacity(count);
    let mut h = Vec::with_capacity(count);
    let mut density = Vec::with_capacity(count);
    let mut temperature = Vec::with_capacity(count);
    for _ in 0..count {
        let s = rng.next_f64().powf(0.8); // more particles near the source
        let z = 0.05 + 0.85 * s;
        let radius = 0.04 + 0.16 * s * s;
        // A mushroom cap: wider near the top.
        let cap = if s > 0.8 { 1.0 + 2.5 * (s - 0.8) } else { 1.0 };
        let disc = radius * cap;
        let u = rng.next_f64();
        // The radius, and the disc's area per particle there over its mean (1: uniform).
        let (r, area_ratio) = match section {
            CrossSection::Uniform => (disc * u.sqrt(), 1.0),
            CrossSection::Gaussian { cut } => {
                let sigma = disc / cut;
                let kept = 1.0 - (-0.5 * cut * cut).exp();
                let r = sigma * (-2.0 * (1.0 - u * kept).ln()).sqrt();
                // Areal density exp(−r²/2σ²) / (2πσ² · kept) against the mean 1 / (π disc²).
                (r, 2.0 * sigma * sigma * kept / (disc * disc) * (0.5 * (r / sigma).powi(2)).exp())
            }
        };
        let swirl = 6.0 * s + rng.range(0.0, std::f64::consts::TAU);
        let x = 0.5 + r * swirl.cos() + 0.03 * (9.0 * z).sin();
        let y = 0.5 + r * swirl.sin();
        positions.push([x, y, z]);
        let vol_per_particle = area_ratio * std::f64::consts::PI * disc.powi(2) * 0.85 / (count as f64 * (0.8 * s.max(0.05).powf(-0.2)));
        let spacing = vol_per_particle.cbrt();
        h.push((1.3 * spacing) as f32);
        density.push((m / vol_per_particle).min(5.0) as f32);
        temperature.push((1.0 - s) as f32);
    }
    ParticleSet {
        positions,
        mass: Some(vec![m as f32; count]),
        density: Some(density),
        smoothing_length: Some(h),
        arrays: vec![PointArray { name: "temperature".into(), components: 1, values: temperature.iter().map(|&t| t as f64).collect() }],
        notes: vec!["volterra smoke plume".into()],
    }
}

/// A clinical-size CT-like phantom for benchmarks and tests: nx × ny × nz int16 voxels
/// of 0.7 × 0.7 × 1 mm (RAS+, centred), stored as HU + 1024 with the rescale intercept
/// −1024 as scanners write them. Air (−1000 HU) round an elliptic body of soft tissue
/// (40 HU) with a fat rim (−100 HU), a skin of 60 HU, a spine column and a rib ring of
/// bone (700–1200 HU), a contrast-filled aorta (320 HU) along z with two branches, and
/// ±20 HU of noise; a table (200 HU) under the patient touches nothing. Deterministic.
pub fn ct_phantom(nx: usize, ny: usize, nz: usize) -> Volume {
    ct_phantom_spaced([nx, ny, nz], 0.7, 1.0)
}

/// `ct_phantom` on voxels of `sx` × `sx` × `sz` mm.
pub fn ct_phantom_spaced([nx, ny, nz]: [usize; 3], sx: f64, sz: f64) -> Volume {
    use rayon::prelude::*;
    let mut data = vec![0i16; nx * ny * nz];
    data.par_chunks_mut(nx * ny).enumerate().for_each(|(z, slice)| {
        let mut rng = SplitMix64(0xC7_0000 + z as u64);
        let zmm = (z as f64 - 0.5 * (nz - 1) as f64) * sz;
        for y in 0..ny {
            for x in 0..nx {
                let (px, py) = ((x as f64 - 0.5 * (nx - 1) as f64) * sx, (y as f64 - 0.5 * (ny - 1) as f64) * sx);
                // The body: an ellipse 150 × 110 mm (semi-axes), front at +y.
                let r = ((px / 150.0).powi(2) + (py / 110.0).powi(2)).sqrt();
                let mut hu = if r < 0.97 {
                    40.0
                } else if r < 1.0 {
                    -100.0
                } else if r < 1.01 {
                    60.0
                } else {
                    -1000.0
                };
                if r < 1.0 {
                    // Ribs: a thin ring at 0.8 with gaps every 25 mm of z.
                    if (0.78..0.82).contains(&r) && (zmm.rem_euclid(25.0) < 12.0) && py > -60.0 {
                        hu = 700.0 + 300.0 * (1.0 - ((r - 0.8) / 0.02).abs());
                    }
                    // The spine: a vertebral body behind the aorta, 18 mm radius, denser rim.
                    let d_spine = (px.powi(2) + (py + 70.0).powi(2)).sqrt();
                    if d_spine < 18.0 {
                        hu = if d_spine > 15.0 { 1200.0 } else { 350.0 + 5.0 * (zmm.rem_euclid(30.0) - 15.0).abs() };
                    }
                    // The aorta in front of the spine, and two branches leaving it sideways.
                    let d_aorta = (px.powi(2) + (py + 35.0).powi(2)).sqrt();
                    let branch = |side: f64| {
                        let along = side * px;
                        let centre_y = -35.0 + 0.25 * along;
                        let centre_z = 20.0 * side;
                        if along > 0.0 && along < 90.0 {
                            ((py - centre_y).powi(2) + (zmm - centre_z).powi(2)).sqrt() < 4.0
                        } else {
                            false
                        }
                    };
                    if d_aorta < 12.0 || branch(1.0) || branch(-1.0) {
                        hu = 320.0;
                    }
                }
                // The table under the patient, clear of the body.
                if (py + 130.0).abs() < 3.0 && px.abs() < 200.0 {
                    hu = 200.0;
                }
                let noise = if hu > -900.0 { rng.range(-20.0, 20.0) } else { rng.range(-5.0, 5.0) };
                slice[y * nx + x] = (hu + noise + 1024.0).round() as i16;
            }
        }
    });
    let affine = [
        [sx, 0.0, 0.0, -0.5 * (nx - 1) as f64 * sx],
        [0.0, sx, 0.0, -0.5 * (ny - 1) as f64 * sx],
        [0.0, 0.0, sz, -0.5 * (nz - 1) as f64 * sz],
        [0.0, 0.0, 0.0, 1.0],
    ];
    let v = Volume::new([nx, ny, nz], affine, VoxelData::I16(data));
    Volume { rescale: volterra_formats::Rescale { slope: 1.0, intercept: -1024.0 }, modality: Some("CT".into()), ..v }
}
