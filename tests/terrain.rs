//! The GPU terrain ray-caster against the f64 CPU reference on hard synthetic cases, and
//! on the real DEMs in ../shared/data. Runs on whatever adapter wgpu finds — lavapipe
//! (software Vulkan) in CI, where a missing adapter fails the test.

mod common;

use glam::DMat4;
use volterra::formats::{Crs, Heightfield};
use volterra::render::terrain::{self, depth_agreement, grid::TerrainGrid, Settings, TerrainInput, Traversal};
use volterra::render::Frame;
use volterra::scene::camera::Camera;

/// A heightfield of w×h samples, `cell` metres apart, elevation f(col, row) (row 0 north);
/// NaN marks NoData.
fn field(w: usize, h: usize, cell: f64, f: impl Fn(usize, usize) -> f32) -> Heightfield {
    let mut elevations = Vec::with_capacity(w * h);
    let mut nodata = Vec::with_capacity(w * h);
    for row in 0..h {
        for col in 0..w {
            let z = f(col, row);
            elevations.push(z);
            nodata.push(!z.is_finite());
        }
    }
    Heightfield {
        width: w,
        height: h,
        cell_size: [cell; 2],
        cell_size_native: [cell; 2],
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

fn perspective(position: [f64; 3], focal_point: [f64; 3], view_up: [f64; 3], view_angle: f64) -> Camera {
    Camera { position, focal_point, view_up, view_angle, parallel_projection: false, parallel_scale: 1.0 }
}

fn parallel(position: [f64; 3], focal_point: [f64; 3], view_up: [f64; 3], scale: f64) -> Camera {
    Camera { position, focal_point, view_up, view_angle: 30.0, parallel_projection: true, parallel_scale: scale }
}

fn counter(f: &Frame, name: &str) -> f64 {
    f.stats.counter(name).unwrap_or_else(|| panic!("no counter '{name}'"))
}

/// The GPU ray-caster's shading for tests that call it directly: the sun from `to_sun`
/// (none: no lights), shadows with a sun, smooth normals, one ray per pixel.
fn sun_shading(to_sun: Option<[f64; 3]>) -> volterra::render::terrain::shading::Shading {
    let lights: Vec<_> = to_sun.map(common::sun).into_iter().collect();
    volterra::render::terrain::shading::Shading {
        lights: volterra::render::terrain::shading::sun_lights(&lights).unwrap(),
        ambient: 0.25,
        shadows: to_sun.is_some(),
        smooth: true,
        rays_per_side: 1,
        colormap: volterra::colormap::Colormap::Hypsometric,
        colour_range: None,
    }
}

/// GPU and reference renders of one view, or None where the GPU is missing (local runs).
fn render_both(hf: &Heightfield, cam: &Camera, size: (usize, usize), settings: &Settings) -> Option<(Frame, Frame)> {
    common::gpu()?;
    let input = TerrainInput { heightfield: hf, texture: None, node_to_world: DMat4::IDENTITY, lights: &[] };
    let rays = cam.rays(size.0, size.1);
    let gpu = terrain::render(&input, &rays, settings).unwrap();
    let reference = terrain::render_reference(&input, &rays, settings).unwrap();
    Some((gpu, reference))
}

/// The bar: hit masks agree away from silhouettes, relative depth error below
/// 1e-4 in the median and 1e-2 at the 99.9th percentile, no ray at the step cap.
fn assert_agree(label: &str, gpu: &Frame, reference: &Frame) {
    let a = depth_agreement(gpu, reference);
    println!("{label}: {a:?}, mean steps {:.1}", counter(gpu, "mean steps"));
    assert_eq!(a.mismatched_off_silhouette, 0, "{label}: hit/miss disagreements away from silhouettes");
    assert!(a.median_rel < 1e-4, "{label}: median relative depth error {}", a.median_rel);
    assert!(a.p999_rel < 1e-2, "{label}: 99.9th percentile relative depth error {}", a.p999_rel);
    assert_eq!(counter(gpu, "rays at the step cap"), 0.0, "{label}: rays stopped by the step cap");
}

#[test]
fn flat_terrain_seen_straight_down_is_at_exactly_the_eye_height() {
    // A = B = C = 0 in every cell; parallel rays straight down (d = (0, 0, −1)).
    let hf = field(65, 65, 10.0, |_, _| 100.0);
    let cam = parallel([320.0, 320.0, 500.0], [320.0, 320.0, 0.0], [0.0, 1.0, 0.0], 400.0);
    let Some((gpu, reference)) = render_both(&hf, &cam, (64, 64), &Settings::default()) else { return };
    assert_agree("flat, straight down", &gpu, &reference);
    let rays = cam.rays(64, 64);
    for y in 0..64 {
        for x in 0..64 {
            let o = rays.ray(x as f64 + 0.5, y as f64 + 0.5).origin;
            let inside = (0.0..=640.0).contains(&o.x) && (0.0..=640.0).contains(&o.y);
            let z = gpu.depth[y * 64 + x];
            assert_eq!(z.is_finite(), inside, "pixel ({x}, {y}) at ({}, {})", o.x, o.y);
            if inside {
                assert!((z - 400.0).abs() < 1e-3, "pixel ({x}, {y}): depth {z}, expected 400");
            }
        }
    }
    // And obliquely, from outside the footprint.
    let cam = perspective([-200.0, -300.0, 400.0], [320.0, 320.0, 100.0], [0.0, 0.0, 1.0], 50.0);
    let Some((gpu, reference)) = render_both(&hf, &cam, (96, 64), &Settings::default()) else { return };
    assert_agree("flat, oblique", &gpu, &reference);
}

#[test]
fn a_single_spike_is_found_and_its_apex_is_exact() {
    let hf = field(33, 33, 10.0, |c, r| if (c, r) == (16, 16) { 1000.0 } else { 0.0 });
    let cam = perspective([-150.0, -250.0, 700.0], [160.0, 160.0, 300.0], [0.0, 0.0, 1.0], 40.0);
    let Some((gpu, reference)) = render_both(&hf, &cam, (120, 90), &Settings::default()) else { return };
    assert_agree("spike", &gpu, &reference);
    // Straight down onto the apex (sample (16, 16) is at x = 160, y = 160).
    let cam = parallel([160.0, 160.0, 1500.0], [160.0, 160.0, 0.0], [0.0, 1.0, 0.0], 0.5);
    let Some((gpu, reference)) = render_both(&hf, &cam, (1, 1), &Settings::default()) else { return };
    assert!((gpu.depth[0] - 500.0).abs() < 1e-2, "apex depth {}", gpu.depth[0]);
    assert!((reference.depth[0] - 500.0).abs() < 1e-9);
}

#[test]
fn rays_exactly_along_x_and_along_y_meet_a_ridge_where_the_bilinear_patch_says() {
    // A ridge 100 m high along column 20 (x = 200 m): between columns 19 and 20 the
    // surface rises linearly, so a horizontal ray at 50 m meets it half-way, x = 195 m.
    let hf = field(41, 41, 10.0, |c, _| if c == 20 { 100.0 } else { 0.0 });
    let cam = parallel([-100.0, 200.0, 50.0], [0.0, 200.0, 50.0], [0.0, 0.0, 1.0], 0.25);
    let Some((gpu, reference)) = render_both(&hf, &cam, (1, 1), &Settings::default()) else { return };
    assert!((reference.depth[0] as f64 - 295.0).abs() < 1e-6, "reference {}", reference.depth[0]);
    assert!((gpu.depth[0] - 295.0).abs() < 1e-3, "gpu {}", gpu.depth[0]);
    // The same ridge turned 90°: rays along +y.
    let hf = field(41, 41, 10.0, |_, r| if r == 20 { 100.0 } else { 0.0 });
    let cam = parallel([200.0, -100.0, 50.0], [200.0, 0.0, 50.0], [0.0, 0.0, 1.0], 0.25);
    let Some((gpu, _)) = render_both(&hf, &cam, (1, 1), &Settings::default()) else { return };
    assert!((gpu.depth[0] - 295.0).abs() < 1e-3, "gpu {}", gpu.depth[0]);
    // A whole image of axis-parallel rays against the reference.
    let cam = parallel([-100.0, 200.0, 60.0], [0.0, 200.0, 60.0], [0.0, 0.0, 1.0], 60.0);
    let Some((gpu, reference)) = render_both(&hf, &cam, (80, 80), &Settings::default()) else { return };
    assert_agree("axis-parallel rays", &gpu, &reference);
}

#[test]
fn a_vertical_cliff_and_a_saddle() {
    let cliff = field(33, 33, 10.0, |c, _| if c >= 16 { 500.0 } else { 0.0 });
    let cam = perspective([-200.0, 40.0, 120.0], [200.0, 200.0, 200.0], [0.0, 0.0, 1.0], 60.0);
    let Some((gpu, reference)) = render_both(&cliff, &cam, (96, 96), &Settings::default()) else { return };
    assert_agree("cliff", &gpu, &reference);
    // Alternating 0 / 200 m samples: every cell a saddle with |A| = 400.
    let saddle = field(33, 33, 10.0, |c, r| if (c + r) % 2 == 0 { 0.0 } else { 200.0 });
    let cam = perspective([-100.0, -150.0, 400.0], [160.0, 160.0, 50.0], [0.0, 0.0, 1.0], 45.0);
    let Some((gpu, reference)) = render_both(&saddle, &cam, (96, 96), &Settings::default()) else { return };
    assert_agree("saddle", &gpu, &reference);
}

#[test]
fn straight_up_rays_miss_unless_the_eye_is_under_the_ground() {
    let hf = field(33, 33, 10.0, |c, r| (20.0 * ((c as f32) * 0.3).sin() * ((r as f32) * 0.2).cos()) + 50.0);
    let cam = parallel([160.0, 160.0, 200.0], [160.0, 160.0, 300.0], [0.0, 1.0, 0.0], 50.0);
    let Some((gpu, reference)) = render_both(&hf, &cam, (16, 16), &Settings::default()) else { return };
    assert!(gpu.depth.iter().all(|z| z.is_infinite()), "rays straight up from above the ground hit nothing");
    assert!(reference.depth.iter().all(|z| z.is_infinite()));
    // The terrain is a solid down to its lowest sample (30 m): an eye inside it, under
    // the surface, sees the ground at distance 0.
    let cam = parallel([160.0, 160.0, 31.0], [160.0, 160.0, 300.0], [0.0, 1.0, 0.0], 50.0);
    let Some((gpu, reference)) = render_both(&hf, &cam, (16, 16), &Settings::default()) else { return };
    assert!(gpu.depth.iter().all(|&z| z == 0.0), "an eye under the ground sees the ground at distance 0");
    assert!(reference.depth.iter().all(|&z| z == 0.0));
}

#[test]
fn an_eye_on_a_cell_corner_at_exactly_ground_height() {
    let hf = field(33, 33, 10.0, |c, r| (c as f32 * 3.0) + (r as f32 * 2.0));
    // Sample (10, 22) (row 22 from the north = j 10 from the south) lies at (100, 100, 74).
    let ground = 10.0 * 3.0 + 22.0 * 2.0;
    let cam = perspective([100.0, 100.0, ground], [300.0, 250.0, ground], [0.0, 0.0, 1.0], 90.0);
    let Some((gpu, reference)) = render_both(&hf, &cam, (64, 64), &Settings::default()) else { return };
    assert_agree("eye on a corner at ground height", &gpu, &reference);
    // Rays that leave the eye downward into the slope meet it at once.
    assert_eq!(gpu.depth[63 * 64 + 32], 0.0);
    assert_eq!(reference.depth[63 * 64 + 32], 0.0);
}

#[test]
fn grazing_rays_at_the_horizon_and_nodata_holes() {
    let rolling = |c: usize, r: usize| 30.0 * ((c as f32) * 0.05).sin() * ((r as f32) * 0.07).cos() + 100.0;
    let hf = field(257, 257, 10.0, rolling);
    let ground = hf.surface_height(300.0, 400.0).unwrap();
    let cam = perspective([300.0, 400.0, ground + 2.0], [2000.0, 2400.0, ground + 2.0], [0.0, 0.0, 1.0], 30.0);
    let Some((gpu, reference)) = render_both(&hf, &cam, (128, 64), &Settings::default()) else { return };
    assert_agree("grazing", &gpu, &reference);

    // A NoData disc: rays through it pass, and see what lies beyond (here: nothing).
    let holed =
        field(65, 65, 10.0, |c, r| if (c as f32 - 32.0).powi(2) + (r as f32 - 32.0).powi(2) < 64.0 { f32::NAN } else { rolling(c, r) });
    let cam = parallel([320.0, 320.0, 1000.0], [320.0, 320.0, 0.0], [0.0, 1.0, 0.0], 100.0);
    let Some((gpu, reference)) = render_both(&holed, &cam, (64, 64), &Settings::default()) else { return };
    assert_agree("holes, straight down", &gpu, &reference);
    assert!(gpu.depth[32 * 64 + 32].is_infinite(), "the centre of the hole is see-through");
    assert!(gpu.depth[2 * 64 + 2].is_finite());
    let cam = perspective([-100.0, -200.0, 500.0], [320.0, 320.0, 100.0], [0.0, 0.0, 1.0], 40.0);
    let Some((gpu, reference)) = render_both(&holed, &cam, (96, 64), &Settings::default()) else { return };
    assert_agree("holes, oblique", &gpu, &reference);
}

/// The big case: 4096² samples, 30 m cells, 4000 m of relief, from above (fly)
/// and from 2 m above the ground (walk).
#[test]
fn a_4096_squared_terrain_with_4000_m_of_relief() {
    if common::gpu().is_none() {
        return;
    }
    let dem = volterra::samples::fractal_dem(12, 30.0, 7);
    let n = 4096;
    let hf = field(n, n, 30.0, |c, r| {
        let z = dem.elevations[r * dem.width + c];
        if z.is_finite() {
            z * 1.6
        } else {
            f32::NAN
        }
    });
    let extent = 30.0 * (n - 1) as f64;
    let fly = perspective([-0.1 * extent, -0.1 * extent, 9000.0], [0.5 * extent, 0.5 * extent, 1000.0], [0.0, 0.0, 1.0], 50.0);
    let Some((gpu, reference)) = render_both(&hf, &fly, (96, 64), &Settings::default()) else { return };
    assert_agree("4096² fly", &gpu, &reference);
    let (x, y) = (0.6 * extent, 0.4 * extent);
    let ground = hf.surface_height(x, y).unwrap();
    let walk = perspective([x, y, ground + 2.0], [x - 5000.0, y + 8000.0, ground + 300.0], [0.0, 0.0, 1.0], 60.0);
    let Some((gpu, reference)) = render_both(&hf, &walk, (96, 64), &Settings::default()) else { return };
    assert_agree("4096² walk", &gpu, &reference);
}

#[test]
fn traversals_agree_and_the_quadtree_takes_fewer_steps_than_the_linear_march() {
    let dem = volterra::samples::fractal_dem(8, 30.0, 3);
    let cam = perspective([-1000.0, -1500.0, 5000.0], [3840.0, 3840.0, 500.0], [0.0, 0.0, 1.0], 45.0);
    let mut frames = Vec::new();
    for traversal in [Traversal::Quadtree, Traversal::NoRaise, Traversal::Linear] {
        let s = Settings { traversal, ..Default::default() };
        let Some((gpu, reference)) = render_both(&dem, &cam, (128, 96), &s) else { return };
        assert_agree(&format!("{traversal:?}"), &gpu, &reference);
        frames.push(gpu);
    }
    let steps: Vec<f64> = frames.iter().map(|f| counter(f, "mean steps")).collect();
    println!("mean steps quadtree / no-raise / linear: {steps:?}");
    assert!(steps[0] < 0.5 * steps[2], "the quadtree should need well under half the linear march's steps: {steps:?}");
}

#[test]
fn a_step_cap_that_is_hit_is_counted_and_reported() {
    if common::gpu().is_none() {
        return;
    }
    let dem = volterra::samples::fractal_dem(7, 30.0, 3);
    let cam = perspective([-1000.0, -1500.0, 3000.0], [1920.0, 1920.0, 500.0], [0.0, 0.0, 1.0], 45.0);
    let input = TerrainInput { heightfield: &dem, texture: None, node_to_world: DMat4::IDENTITY, lights: &[] };
    let s = Settings { traversal: Traversal::Linear, max_steps: 3, ..Default::default() };
    let f = terrain::render(&input, &cam.rays(32, 32), &s).unwrap();
    assert!(counter(&f, "rays at the step cap") > 0.0);
    assert!(f.stats.notes.iter().any(|n| n.contains("step cap")), "{:?}", f.stats.notes);
}

#[test]
fn shading_matches_the_reference_with_shadows_and_a_texture() {
    if common::gpu().is_none() {
        return;
    }
    let dem = volterra::samples::fractal_dem(7, 30.0, 5);
    let tex = volterra::scene::drape::Drape::stretched(&volterra::samples::dem_texture(&dem));
    let lights = [volterra::scene::Light {
        kind: volterra::scene::LightKind::Directional,
        direction: Some([1.0, 0.5, -0.4]),
        position: None,
        color: [1.0, 0.95, 0.9],
        intensity: 1.2,
        cone_angle: None,
    }];
    let cam = perspective([-500.0, -800.0, 3000.0], [1920.0, 1920.0, 300.0], [0.0, 0.0, 1.0], 45.0);
    let rays = cam.rays(96, 64);
    for texture in [None, Some(&tex)] {
        let input = TerrainInput { heightfield: &dem, texture, node_to_world: DMat4::IDENTITY, lights: &lights };
        let s = Settings { shadows: true, ..Default::default() };
        let gpu = terrain::render(&input, &rays, &s).unwrap();
        let reference = terrain::render_reference(&input, &rays, &s).unwrap();
        assert_agree("shaded", &gpu, &reference);
        let err = volterra::compare::rgba_rel_rmse(&gpu.rgba, &reference.rgba);
        println!("texture {}: colour relative RMSE {err:.5}", texture.is_some());
        assert!(err < 0.02, "colour differs from the reference by {err}");
        // Shadows are really cast: with them, some lit-facing pixels go dark.
        let unshadowed = terrain::render(&input, &rays, &Settings::default()).unwrap();
        let darker = gpu.rgba.iter().zip(&unshadowed.rgba).filter(|(a, b)| a[0] < 0.8 * b[0]).count();
        assert!(darker > 20, "only {darker} pixels in shadow");
    }
}

/// The proof on real data: the Puget Sound heightmap and the pysheds GeoTIFF,
/// from above (fly-through) and from 2 m above the ground (walk-through).
#[test]
fn real_dems_fly_and_walk_agree_with_the_reference() {
    let Some(data) = common::shared_data() else { return };
    if common::gpu().is_none() {
        return;
    }
    let opts = volterra::formats::png_height::PngHeightOptions { vertical_scale: Some(0.1), cell_size: Some(160.0), ..Default::default() };
    let puget =
        volterra::formats::png_height::read_png_heightmap(&data.join("terrain/ps_height_1k.png"), &opts, &Default::default()).unwrap();
    let pysheds = volterra::formats::geotiff::read_geotiff(&data.join("terrain/pysheds_dem.tif"), &Default::default()).unwrap();
    for (name, hf) in [("puget sound", &puget), ("pysheds", &pysheds)] {
        let grid = TerrainGrid::new(hf, DMat4::IDENTITY).unwrap();
        let ex = grid.cell[0] * (hf.width - 1) as f64;
        let ey = grid.cell[1] * (hf.height - 1) as f64;
        let top = grid.z_ref + grid.z_hi;
        let fly = perspective([-0.1 * ex, -0.2 * ey, top + 0.4 * ex.max(ey)], [0.55 * ex, 0.5 * ey, grid.z_ref], [0.0, 0.0, 1.0], 45.0);
        let Some((gpu, reference)) = render_both(hf, &fly, (160, 100), &Settings::default()) else { return };
        assert_agree(&format!("{name} fly"), &gpu, &reference);
        let (x, y) = (0.45 * ex, 0.3 * ey);
        let ground = hf.surface_height(x, y).unwrap();
        let walk = perspective([x, y, ground + 2.0], [x + 0.2 * ex, y + 0.5 * ey, ground + 2.0], [0.0, 0.0, 1.0], 60.0);
        let Some((gpu, reference)) = render_both(hf, &walk, (160, 100), &Settings::default()) else { return };
        assert_agree(&format!("{name} walk"), &gpu, &reference);
    }
}

/// Seams in a terrain image: luminance steps between neighbouring pixels in two edge-
/// adjacent patches that exceed 1.5 × (the largest step between neighbouring pixels inside
/// either patch, in the same direction: across or down) + 1e-4. Only patches large enough
/// on screen to hold 8 such inside steps count. Returns (seams, border steps compared). Patches are those the reference's rays hit.
fn seams(frame: &Frame, grid: &TerrainGrid, rays: &volterra::scene::camera::RayGenerator) -> (usize, usize) {
    use std::collections::HashMap;
    let (w, h) = (frame.width, frame.height);
    let cells: Vec<Option<[usize; 2]>> = (0..w * h)
        .map(|p| {
            let ray = rays.ray((p % w) as f64 + 0.5, (p / w) as f64 + 0.5);
            terrain::reference::trace_world(grid, &ray, terrain::reference::Surface::Bilinear).0.map(|hit| hit.cell)
        })
        .collect();
    let lum = |p: usize| (frame.rgba[p][0] + frame.rgba[p][1] + frame.rgba[p][2]) as f64 / 3.0;
    // Per patch and pair direction (0 across, 1 down): the largest inside step, and how many.
    let mut inside: HashMap<([usize; 2], usize), (f64, usize)> = HashMap::new();
    let mut borders = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let p = y * w + x;
            for (dir, q) in [(x + 1 < w).then(|| (0, p + 1)), (y + 1 < h).then(|| (1, p + w))].into_iter().flatten() {
                let (Some(a), Some(b)) = (cells[p], cells[q]) else { continue };
                if !(frame.depth[p].is_finite() && frame.depth[q].is_finite()) {
                    continue;
                }
                let jump = (lum(p) - lum(q)).abs();
                if a == b {
                    let e = inside.entry((a, dir)).or_default();
                    *e = (e.0.max(jump), e.1 + 1);
                } else if a[0].abs_diff(b[0]) + a[1].abs_diff(b[1]) == 1 {
                    borders.push((a, b, dir, jump));
                }
            }
        }
    }
    let (mut found, mut compared) = (0, 0);
    for (a, b, dir, jump) in borders {
        let (Some(&(ja, na)), Some(&(jb, nb))) = (inside.get(&(a, dir)), inside.get(&(b, dir))) else { continue };
        if na < 8 || nb < 8 {
            continue;
        }
        compared += 1;
        if jump > 1.5 * ja.max(jb) + 1e-4 {
            if found < 6 {
                println!("  seam {a:?} {b:?} jump {jump:.6} inside {ja:.6} ({na}) {jb:.6} ({nb})");
            }
            found += 1;
        }
    }
    (found, compared)
}

/// Walking in a smooth bowl (a sphere cap, 30 m cells, seen from 2 m above it): with
/// smooth normals no patch border shows a seam (see `seams` for the bound), on the GPU and
/// in the reference; with faceted normals more than a tenth of the borders do.
#[test]
fn a_walk_in_a_smooth_bowl_shows_no_seams_between_patches() {
    let (n, cell, radius) = (129usize, 30.0, 4000.0);
    let c = (n - 1) as f64 / 2.0;
    let hf = field(n, n, cell, |col, row| {
        let (dx, dy) = ((col as f64 - c) * cell, (row as f64 - c) * cell);
        (radius - (radius * radius - dx * dx - dy * dy).sqrt()) as f32
    });
    let grid = TerrainGrid::new(&hf, DMat4::IDENTITY).unwrap();
    // Near the bowl's bottom, looking across at its far side.
    let (x, y) = (0.4 * (n - 1) as f64 * cell, 0.35 * (n - 1) as f64 * cell);
    let ground = hf.surface_height(x, y).unwrap();
    let walk = perspective(
        [x, y, ground + 2.0],
        [0.8 * (n - 1) as f64 * cell, 0.9 * (n - 1) as f64 * cell, ground + 150.0],
        [0.0, 0.0, 1.0],
        60.0,
    );
    let rays = walk.rays(240, 160);
    let input = TerrainInput { heightfield: &hf, texture: None, node_to_world: DMat4::IDENTITY, lights: &[] };
    for normals in [terrain::Normals::Smooth, terrain::Normals::Faceted] {
        // One ray per pixel: each pixel's colour is that of the patch its centre ray meets.
        let s = Settings { normals, rays_per_pixel: 1, ..Default::default() };
        let mut frames = vec![("reference", terrain::render_reference(&input, &rays, &s).unwrap())];
        if common::gpu().is_some() {
            frames.push(("gpu", terrain::render(&input, &rays, &s).unwrap()));
        }
        for (name, frame) in &frames {
            let (found, compared) = seams(frame, &grid, &rays);
            println!("{normals:?} {name}: {found} seams in {compared} border steps compared");
            assert!(compared > 500, "{name}: only {compared} border steps compared");
            if normals == terrain::Normals::Smooth {
                assert_eq!(found, 0, "{name}: seams with smooth normals");
            } else {
                assert!(found * 10 > compared, "{name}: faceted normals should show seams ({found} of {compared})");
            }
        }
    }
}

/// Pixels darker than 0.7 × the darkest of their 8 neighbours, all of which hit: the
/// isolated black dots shadow acne leaves (and a pit or a lone steep cell facing away from
/// the sun, which the reference shows too).
fn isolated_dark_pixels(frame: &Frame) -> Vec<usize> {
    let (w, h) = (frame.width, frame.height);
    let lum = |p: usize| (frame.rgba[p][0] + frame.rgba[p][1] + frame.rgba[p][2]) / 3.0;
    let mut found = Vec::new();
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            let p = y * w + x;
            if !frame.depth[p].is_finite() {
                continue;
            }
            let mut darkest = f32::INFINITY;
            for (dx, dy) in [(-1i64, -1i64), (0, -1), (1, -1), (-1, 0), (1, 0), (-1, 1), (0, 1), (1, 1)] {
                let q = (y as i64 + dy) as usize * w + (x as i64 + dx) as usize;
                darkest = if frame.depth[q].is_finite() { darkest.min(lum(q)) } else { -1.0 };
            }
            if lum(p) < 0.7 * darkest {
                found.push(p);
            }
        }
    }
    found
}

/// Shadow acne: a 15361 × 1025 fractal DEM (30 m cells, 4000 m of relief; positions up to
/// 15360 cells from the eye, where f32 loses most) lit by a low sun with shadows, seen from
/// far above its western end and from 2 m above the ground near its eastern end. Acne is
/// an isolated dark pixel of the GPU's image that the f64 reference does not darken: none.
#[test]
fn shadows_leave_no_acne_on_a_large_dem() {
    if common::gpu().is_none() {
        return;
    }
    // The fractal tile mirrored eastward.
    let base = volterra::samples::fractal_dem(10, 30.0, 11);
    let period = 2 * (base.width - 1);
    let hf = field(15 * (base.width - 1) + 1, base.height, 30.0, |c, r| {
        let m = c % period;
        let c = if m < base.width { m } else { period - m };
        base.elevations[r * base.width + c] * 1.6
    });
    let grid = TerrainGrid::new(&hf, DMat4::IDENTITY).unwrap();
    let (ex, ey) = (grid.cell[0] * grid.cells()[0] as f64, grid.cell[1] * grid.cells()[1] as f64);
    let top = grid.z_ref + grid.z_hi;
    let lights = [common::sun([-0.8, -0.5, -0.35])];
    let fly = perspective([-0.02 * ex, 0.5 * ey, top + 2000.0], [0.9 * ex, 0.5 * ey, grid.z_ref], [0.0, 0.0, 1.0], 30.0);
    let (x, y) = (0.93 * ex, 0.45 * ey);
    let ground = hf.surface_height(x, y).unwrap();
    let walk = perspective([x, y, ground + 2.0], [x + 3000.0, y + 500.0, ground + 100.0], [0.0, 0.0, 1.0], 60.0);
    let input = TerrainInput { heightfield: &hf, texture: None, node_to_world: DMat4::IDENTITY, lights: &lights };
    let lum = |c: &[f32; 4]| c[0] + c[1] + c[2];
    for (name, cam) in [("fly", fly), ("walk", walk)] {
        let rays = cam.rays(320, 200);
        for shadows in [false, true] {
            // One ray per pixel: anti-aliasing would dilute a dark dot, not remove its cause.
            let s = Settings { shadows, rays_per_pixel: 1, ..Default::default() };
            let gpu = terrain::render(&input, &rays, &s).unwrap();
            let reference = terrain::render_reference(&input, &rays, &s).unwrap();
            let (dots, truth) = (isolated_dark_pixels(&gpu), isolated_dark_pixels(&reference));
            let acne = dots.iter().filter(|&&p| lum(&gpu.rgba[p]) < 0.7 * lum(&reference.rgba[p])).count();
            let flipped = gpu
                .rgba
                .iter()
                .zip(&reference.rgba)
                .filter(|(g, r)| g[3] > 0.0 && r[3] > 0.0 && (lum(g) < 0.7 * lum(r) || lum(r) < 0.7 * lum(g)))
                .count();
            println!(
                "{name}, shadows {shadows}: isolated dark pixels: GPU {}, reference {}; acne {acne}; pixels lit on one side only {flipped}",
                dots.len(),
                truth.len(),
            );
            assert_eq!(acne, 0, "{name}, shadows {shadows}: shadow acne");
            // A shadow edge may fall either side of a pixel; wholesale self-shadowing (a
            // shadow ray starting under its own surface everywhere) may not.
            assert!(flipped <= 64, "{name}, shadows {shadows}: {flipped} pixels lit in one image and shadowed in the other");
        }
    }
}

/// Anti-aliasing: against 256 rays per pixel, 4 rays per pixel at least halve the colour
/// error of 1 along the silhouettes and ridges of a fractal DEM; the GPU's anti-aliased
/// colour agrees with the reference's; depth stays the centre ray's (equal to the 1-ray
/// depth).
#[test]
fn more_rays_per_pixel_converge_to_the_supersampled_image() {
    if common::gpu().is_none() {
        return;
    }
    let dem = volterra::samples::fractal_dem(8, 30.0, 5);
    let grid = TerrainGrid::new(&dem, DMat4::IDENTITY).unwrap();
    let ext = grid.cell[0] * grid.cells()[0] as f64;
    let cam = perspective(
        [-0.1 * ext, -0.2 * ext, grid.z_ref + grid.z_hi + 0.3 * ext],
        [0.5 * ext, 0.5 * ext, grid.z_ref],
        [0.0, 0.0, 1.0],
        45.0,
    );
    let rays = cam.rays(120, 80);
    let input = TerrainInput { heightfield: &dem, texture: None, node_to_world: DMat4::IDENTITY, lights: &[] };
    let with = |n: u32| Settings { rays_per_pixel: n, ..Default::default() };
    let truth = terrain::render(&input, &rays, &with(256)).unwrap();
    let one = terrain::render(&input, &rays, &with(1)).unwrap();
    let mut errors = Vec::new();
    for n in [1, 4, 9, 16] {
        let f = terrain::render(&input, &rays, &with(n)).unwrap();
        let err = volterra::compare::rgba_rel_rmse(&f.rgba, &truth.rgba);
        println!("{n} rays per pixel: colour relative RMSE from 256 rays {err:.5}");
        assert_eq!(f.depth, one.depth, "{n} rays per pixel: depth is the centre ray's");
        errors.push(err);
    }
    assert!(errors[1] < 0.5 * errors[0], "4 rays per pixel: {} against {} for 1", errors[1], errors[0]);
    assert!(errors.windows(2).all(|w| w[1] < w[0]), "errors fall with more rays: {errors:?}");
    let s = with(4);
    let (gpu, reference) = (terrain::render(&input, &rays, &s).unwrap(), terrain::render_reference(&input, &rays, &s).unwrap());
    let err = volterra::compare::rgba_rel_rmse(&gpu.rgba, &reference.rgba);
    println!("4 rays per pixel: GPU against the reference {err:.2e}");
    assert!(err < 0.01, "4 rays per pixel: GPU {err} from the reference");
    assert!(terrain::render(&input, &rays, &with(3)).is_err(), "3 is not a square");
}

/// Elevation colour maps: seen straight down under an overhead sun with no ambient light,
/// a gentle ramp's every pixel is the colour map at its elevation's place in the range
/// (the elevation from the pixel's depth) times the slope's cosine, on the GPU and in the
/// reference; the frame carries the map's scalar bar with the elevation range in metres.
#[test]
fn elevation_colour_maps_colour_by_elevation_with_a_legend() {
    let (n, cell) = (33usize, 30.0);
    // 200 m at the western edge, rising 0.1 m per metre eastward.
    let hf = field(n, n, cell, |col, _| (200.0 + 0.1 * cell * col as f64) as f32);
    let ext = (n - 1) as f64 * cell;
    let cam = parallel([0.5 * ext, 0.5 * ext, 1000.0], [0.5 * ext, 0.5 * ext, 0.0], [0.0, 1.0, 0.0], 0.5 * ext);
    let lights = [common::sun([0.0, 0.0, -1.0])];
    let input = TerrainInput { heightfield: &hf, texture: None, node_to_world: DMat4::IDENTITY, lights: &lights };
    let rays = cam.rays(64, 64);
    let cosine = 1.0 / (1.0f64 + 0.1 * 0.1).sqrt();
    let (lo, hi) = (200.0, 200.0 + 0.1 * ext);
    for colormap in [volterra::colormap::Colormap::Viridis, volterra::colormap::Colormap::Hypsometric] {
        let s = Settings { colormap, ambient: 0.0, rays_per_pixel: 1, ..Default::default() };
        let mut frames = vec![("reference", terrain::render_reference(&input, &rays, &s).unwrap())];
        if common::gpu().is_some() {
            frames.push(("gpu", terrain::render(&input, &rays, &s).unwrap()));
        }
        for (name, f) in &frames {
            assert_eq!(f.scales.len(), 1, "{name}: one scalar bar");
            assert_eq!((f.scales[0].colormap, f.scales[0].title.as_str()), (colormap, "elevation (m)"));
            assert!((f.scales[0].range[0] - lo).abs() < 1e-3 && (f.scales[0].range[1] - hi).abs() < 1e-3, "{:?}", f.scales[0].range);
            let mut worst = 0.0f64;
            for (p, c) in f.rgba.iter().enumerate() {
                let elevation = 1000.0 - f.depth[p] as f64;
                let want = colormap.at((elevation - lo) / (hi - lo)).map(|v| v as f64 * cosine);
                worst = worst.max((0..3).map(|k| (c[k] as f64 - want[k]).abs()).fold(0.0, f64::max));
            }
            println!("{colormap:?} {name}: largest difference from the map at the pixel's elevation {worst:.2e}");
            // The 256-entry table's linear steps against the map itself: well under a byte.
            assert!(worst < 2e-3, "{name}: {worst}");
        }
    }
}

/// NoData voids are holes through the solid terrain: a ray that goes under the surface in a
/// void meets the void's wall where it reaches valid ground (before, it carried on under the
/// ground and missed). A terrain at 100 m (one corner sample at 0 m: the solid reaches down
/// to 0) with a square void (cells 11–20 each way); a ray going down eastward (slope 0.3)
/// passes 100 m inside the void and meets its eastern wall (x = 21 cells, 630 m) 51 m up,
/// at 344.5 m: a wall of soil facing west, on the GPU and in the reference.
#[test]
fn a_ray_through_a_nodata_void_meets_the_void_s_wall() {
    let hf = field(33, 33, 30.0, |c, r| {
        if (12..=20).contains(&c) && (12..=20).contains(&r) {
            f32::NAN
        } else if (c, r) == (0, 0) {
            0.0
        } else {
            100.0
        }
    });
    let cam = perspective([300.0, 480.0, 150.0], [400.0, 480.0, 120.0], [0.0, 0.0, 1.0], 30.0);
    let rays = cam.rays(33, 33);
    let input = TerrainInput { heightfield: &hf, texture: None, node_to_world: DMat4::IDENTITY, lights: &[] };
    let s = Settings { rays_per_pixel: 1, ..Default::default() };
    let mut frames = vec![("reference", terrain::render_reference(&input, &rays, &s).unwrap())];
    if common::gpu().is_some() {
        frames.push(("gpu", terrain::render(&input, &rays, &s).unwrap()));
    }
    let centre = 16 * 33 + 16;
    let want = 330.0 * 1.09f64.sqrt();
    // The default sun (north-west, 45° up) on a west-facing wall: ambient 0.25 + 0.5.
    let colour = terrain::reference::WALL_COLOUR.map(|c| c * 0.75);
    for (name, f) in &frames {
        let depth = f.depth[centre] as f64;
        println!("{name}: depth {depth}, colour {:?}", f.rgba[centre]);
        assert!((depth - want).abs() < 1e-4 * want, "{name}: depth {depth}, the wall is at {want}");
        assert!((0..3).all(|k| (f.rgba[centre][k] as f64 - colour[k]).abs() < 1e-4), "{name}: {:?} vs {colour:?}", f.rgba[centre]);
    }
    let walls = frames[0].1.extra.iter().find(|e| e.0 == "wall").unwrap();
    assert_eq!(walls.1[centre], 1.0, "the reference flags the hit as a wall");
}

/// Large DEMs are tiled into GPU textures when a side exceeds what one texture holds. With
/// the texture size lowered so that small grids are tiled (129 texels: tiles of 128 patches;
/// 40: tiles of 32), every view — fly and walk, shadows and smooth normals reading across
/// tile borders, NoData voids, a grid whose sides are not multiples of the tile — renders
/// exactly as from one texture (depth and colour bit for bit), and agrees with the f64
/// reference as the untiled ray-caster does. With the bytes of a texture lowered too, the
/// 150 tiles of 32 patches are split over four texture arrays (as a 40000² DEM's tiles
/// are on lavapipe, whose allocations stop at 2 GiB), and still render bit for bit the
/// same.
#[test]
fn tiled_terrains_render_exactly_as_one_texture() {
    use volterra::render::terrain::gpu::{self, GpuTerrain, View};
    if common::gpu().is_none() {
        return;
    }
    let gpu = gpu::gpu().unwrap();
    let base = volterra::samples::fractal_dem(9, 30.0, 7);
    // 450 × 301 samples with a NoData void: sides not multiples of any tile.
    let hf = field(450, 301, 30.0, |c, r| {
        if (200..230).contains(&c) && (100..120).contains(&r) {
            f32::NAN
        } else {
            base.elevations[r * base.width + c] * 1.6
        }
    });
    let grid = TerrainGrid::new(&hf, DMat4::IDENTITY).unwrap();
    let (ex, ey) = (grid.cell[0] * grid.cells()[0] as f64, grid.cell[1] * grid.cells()[1] as f64);
    let top = grid.z_ref + grid.z_hi;
    let fly = perspective([-0.1 * ex, -0.2 * ey, top + 0.4 * ex], [0.55 * ex, 0.5 * ey, grid.z_ref], [0.0, 0.0, 1.0], 45.0);
    let (x, y) = (0.3 * ex, 0.3 * ey);
    let ground = hf.surface_height(x, y).unwrap();
    let walk = perspective([x, y, ground + 2.0], [x + 0.5 * ex, y + 0.4 * ey, ground + 40.0], [0.0, 0.0, 1.0], 60.0);
    let to_sun = [-0.8, -0.5, -0.45];
    let lights = [common::sun(to_sun)];
    let shading = sun_shading(Some(to_sun));
    let whole = GpuTerrain::new(gpu, &grid, None).unwrap();
    let cap = Settings::default().step_cap(&grid);
    // Tiles of 32 patches: 33² heights (4356 bytes) a layer; 40 layers an array.
    for (limit, array_bytes) in [(129, u64::MAX), (40, u64::MAX), (40, 40 * 4356)] {
        if array_bytes < u64::MAX {
            // More arrays than the ray-caster binds: refused with the reason.
            let err = GpuTerrain::with_limits(gpu, &grid, None, limit, 30 * 4356).err().expect("refused").to_string();
            assert!(err.contains("more than the 4 the ray-caster binds"), "{err}");
        }
        let tiled = GpuTerrain::with_limits(gpu, &grid, None, limit, array_bytes).unwrap();
        let arrays = tiled.texture_arrays();
        assert_eq!(arrays, if array_bytes == u64::MAX { 1 } else { 4 }, "tiles ≤ {limit} texels, ≤ {array_bytes} bytes");
        let limit = format!("{limit} texels in {arrays} arrays");
        for (name, cam) in [("fly", &fly), ("walk", &walk)] {
            let rays = cam.rays(160, 100);
            let view = View { grid: &grid, rays: &rays, shading: &shading, traversal: Traversal::Quadtree, max_steps: cap };
            let (a, b) = (whole.render(gpu, &view).unwrap(), tiled.render(gpu, &view).unwrap());
            let same_depth = a.depth.iter().zip(&b.depth).filter(|(p, q)| p.to_bits() == q.to_bits()).count();
            let same_colour = a.rgba.iter().zip(&b.rgba).filter(|(p, q)| p == q).count();
            println!("textures ≤ {limit}, {name}: {same_depth} depths and {same_colour} colours of {} equal", a.depth.len());
            assert_eq!(same_depth, a.depth.len(), "tiles ≤ {limit}, {name}: depth");
            assert_eq!(same_colour, a.rgba.len(), "tiles ≤ {limit}, {name}: colour");
            let input = TerrainInput { heightfield: &hf, texture: None, node_to_world: DMat4::IDENTITY, lights: &lights };
            let s = Settings { shadows: true, rays_per_pixel: 1, ..Default::default() };
            let reference = terrain::render_reference(&input, &rays, &s).unwrap();
            assert_agree(&format!("tiles ≤ {limit}, {name}"), &b, &reference);
        }
    }
}

/// The smallest pyramids: the lid map (level 0) is read from the heights, so a grid of
/// one patch has no stored level at all, a row of patches a pyramid one texel high, and
/// tiles of 2 patches one stored level each. Each is drawn as the f64 reference draws it,
/// and the tiles exactly as one texture.
#[test]
fn the_smallest_pyramids_and_tiles_of_two_patches() {
    use volterra::render::terrain::gpu::{self, GpuTerrain, View};
    let settings = Settings { rays_per_pixel: 1, ..Default::default() };
    for (w, h) in [(2, 2), (2, 6), (7, 2), (3, 3), (9, 7)] {
        // A tilted, bumpy surface with one NoData sample where there is room for it.
        let hf = field(w, h, 10.0, |c, r| {
            if w * h > 20 && (c, r) == (w / 2, h / 2) {
                f32::NAN
            } else {
                5.0 * c as f32 - 3.0 * r as f32 + if (c + r) % 2 == 0 { 4.0 } else { 0.0 }
            }
        });
        let (ex, ey) = (10.0 * (w - 1) as f64, 10.0 * (h - 1) as f64);
        let cam = perspective([-0.6 * ex - 10.0, -0.7 * ey - 10.0, 60.0], [0.5 * ex, 0.5 * ey, 0.0], [0.0, 0.0, 1.0], 50.0);
        let Some((g, reference)) = render_both(&hf, &cam, (96, 64), &settings) else { return };
        assert!(g.depth.iter().any(|d| d.is_finite()), "{w}×{h}: the terrain is in view");
        assert_agree(&format!("{w}×{h} samples"), &g, &reference);
        if (w, h) == (9, 7) {
            // Tiles of 2 patches (3 samples a side): 4 × 3 tiles, each pyramid one level.
            let gpu = gpu::gpu().unwrap();
            let grid = TerrainGrid::new(&hf, DMat4::IDENTITY).unwrap();
            let shading = sun_shading(Some([-0.8, -0.5, -0.45]));
            let (whole, tiled) = (GpuTerrain::new(gpu, &grid, None).unwrap(), GpuTerrain::with_texture_limit(gpu, &grid, None, 3).unwrap());
            assert!(tiled.tiled());
            let rays = cam.rays(96, 64);
            let view =
                View { grid: &grid, rays: &rays, shading: &shading, traversal: Traversal::Quadtree, max_steps: settings.step_cap(&grid) };
            let (a, b) = (whole.render(gpu, &view).unwrap(), tiled.render(gpu, &view).unwrap());
            assert!(a.depth.iter().zip(&b.depth).all(|(p, q)| p.to_bits() == q.to_bits()), "tiles of 2 patches: depth");
            assert_eq!(a.rgba, b.rgba, "tiles of 2 patches: colour");
        }
    }
}

/// The pyramid holds half floats, rounded up (terrain_pyramid.wgsl): a plateau 1000.2 m
/// above the middle of the elevation range is bounded by 1000.5, never by the nearest
/// half, 1000.0 — which would pass level rays between 1000.0 and 1000.2 over it; a shelf
/// 999.8 m below the middle is bounded by −999.5, not −1000.0. Rays exactly there all meet
/// the edge where the f64 reference does, in one texture and in tiles (whose texture over
/// the tiles rounds the same way on the CPU). The shelf's grid is taller than wide, so its
/// pyramid pairs texels east-west where the plateau's square one pairs them north-south.
#[test]
fn lids_rounded_to_half_floats_round_up_and_hide_no_hit() {
    use volterra::render::terrain::gpu::{self, GpuTerrain, View};
    let cases = [
        // Ground at 0 west of column 20, a plateau at 2000.4 m from it: z_ref = 1000.2;
        // level rays from the west at 2000.22 … 2000.38 m, 1000.02 … 1000.18 over z_ref.
        ("a plateau above the middle", field(40, 40, 1.0, |c, _| if c < 20 { 0.0 } else { 2000.4 }), 2000.3),
        // A 4000 m wall in the west, ground at 0, a shelf at 1000.2 m from column 20:
        // z_ref = 2000, the shelf −999.8 below it; rays at −999.98 … −999.82.
        (
            "a shelf below the middle",
            field(40, 100, 1.0, |c, _| match c {
                0..10 => 4000.0,
                10..20 => 0.0,
                _ => 1000.2,
            }),
            1000.1,
        ),
    ];
    for (name, hf, z) in cases {
        let cam = parallel([15.0, 20.0, z], [30.0, 20.0, z], [0.0, 0.0, 1.0], 0.08);
        let settings = Settings { rays_per_pixel: 1, ..Default::default() };
        let Some((one, reference)) = render_both(&hf, &cam, (32, 16), &settings) else { return };
        assert!(reference.depth.iter().all(|d| d.is_finite()), "{name}: every reference ray meets the edge");
        assert_agree(&format!("{name}, one texture"), &one, &reference);
        let gpu = gpu::gpu().unwrap();
        let grid = TerrainGrid::new(&hf, DMat4::IDENTITY).unwrap();
        let tiled = GpuTerrain::with_texture_limit(gpu, &grid, None, 9).unwrap();
        assert!(tiled.tiled());
        let rays = cam.rays(32, 16);
        let shading = sun_shading(None);
        let cap = settings.step_cap(&grid);
        let view = View { grid: &grid, rays: &rays, shading: &shading, traversal: Traversal::Quadtree, max_steps: cap };
        assert_agree(&format!("{name}, tiles of 8 patches"), &tiled.render(gpu, &view).unwrap(), &reference);
    }
}

/// A heightfield read row by row (`HeightRows`: a DEM not held in memory as a whole) is
/// the same terrain as the one held: the GPU's images bit for bit, in one texture and in
/// tiles, the elevation range and a point's surface height alike.
#[test]
fn heights_read_row_by_row_render_as_the_heightfield_held() {
    use std::sync::Arc;
    use volterra::render::terrain::gpu::{self, GpuTerrain, View};
    use volterra::render::terrain::grid::HeightRows;
    struct Rows(Heightfield);
    impl HeightRows for Rows {
        fn size(&self) -> [usize; 2] {
            [self.0.width, self.0.height]
        }
        fn cell_size(&self) -> [f64; 2] {
            self.0.cell_size
        }
        fn read_row(&self, row: usize, col: usize, out: &mut [f32]) {
            for (k, z) in out.iter_mut().enumerate() {
                let c = col + k;
                *z = if self.0.is_nodata(c, row) { f32::NAN } else { self.0.elevations[row * self.0.width + c] };
            }
        }
    }
    if common::gpu().is_none() {
        return;
    }
    let gpu = gpu::gpu().unwrap();
    let base = volterra::samples::fractal_dem(8, 25.0, 3);
    // 200 × 150 samples, a NoData void, 25 m × 40 m cells.
    let mut hf = field(200, 150, 25.0, |c, r| {
        if (80..95).contains(&c) && (60..70).contains(&r) {
            f32::NAN
        } else {
            base.elevations[r * base.width + c] + 300.0
        }
    });
    hf.cell_size[1] = 40.0;
    let held = TerrainGrid::new(&hf, DMat4::IDENTITY).unwrap();
    let rows = TerrainGrid::from_rows(Arc::new(Rows(hf.clone())), DMat4::IDENTITY).unwrap();
    assert_eq!((rows.z_ref, rows.z_lo, rows.z_hi, rows.cell), (held.z_ref, held.z_lo, held.z_hi, held.cell));
    for (x, y) in [(1000.0, 2000.0), (3333.3, 4321.0), (0.0, 0.0)] {
        assert_eq!(rows.surface_height(x, y), held.surface_height(x, y), "at ({x}, {y})");
        let direct = hf.surface_height(x, y).unwrap();
        assert!((held.surface_height(x, y).unwrap() - direct).abs() < 1e-3, "the grid's surface at ({x}, {y}) against the heightfield's");
    }
    let (ex, ey) = (25.0 * 199.0, 40.0 * 149.0);
    let cam =
        perspective([-0.1 * ex, -0.2 * ey, held.z_ref + held.z_hi + 0.4 * ex], [0.5 * ex, 0.5 * ey, held.z_ref], [0.0, 0.0, 1.0], 45.0);
    let rays = cam.rays(120, 80);
    let shading = sun_shading(Some([-0.8, -0.5, -0.45]));
    let cap = Settings::default().step_cap(&held);
    for limit in [4096, 40] {
        let a = GpuTerrain::with_texture_limit(gpu, &held, None, limit).unwrap();
        let b = GpuTerrain::with_texture_limit(gpu, &rows, None, limit).unwrap();
        let view = |grid| View { grid, rays: &rays, shading: &shading, traversal: Traversal::Quadtree, max_steps: cap };
        let (fa, fb) = (a.render(gpu, &view(&held)).unwrap(), b.render(gpu, &view(&rows)).unwrap());
        assert!(fa.depth.iter().filter(|d| d.is_finite()).count() > fa.depth.len() / 2, "the view sees the terrain");
        assert!(fa.depth.iter().zip(&fb.depth).all(|(p, q)| p.to_bits() == q.to_bits()), "textures ≤ {limit}: depth");
        assert_eq!(fa.rgba, fb.rgba, "textures ≤ {limit}: colour");
    }
}
