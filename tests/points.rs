//! The points renderer on the GPU (lavapipe where there is no hardware) against its
//! brute-force f64 CPU version: coverage, colour and the distance along every pixel's ray,
//! in perspective and in parallel, with overlapping spheres; colours from the colour map at
//! the data's range; depth compositing with another node.

mod common;

use glam::DMat4;
use volterra::colormap::ColourScale;
use volterra::render::points::{self, Colormap, PointsInput, Settings};
use volterra::scene::camera::Camera;
use volterra_formats::rng::SplitMix64;
use volterra_formats::{ParticleSet, PointArray};

fn cloud(n: usize) -> ParticleSet {
    let mut rng = SplitMix64(11);
    let mut positions = vec![];
    let (mut h, mut temperature) = (vec![], vec![]);
    for _ in 0..n {
        positions.push([rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), rng.range(-1.0, 1.0)]);
        h.push(rng.range(0.08, 0.3) as f32);
        temperature.push(rng.range(250.0, 400.0));
    }
    ParticleSet {
        positions,
        mass: Some(vec![1.0; n]),
        density: None,
        smoothing_length: Some(h),
        arrays: vec![PointArray { name: "temperature".into(), components: 1, values: temperature }],
        notes: vec![],
    }
}

fn camera(parallel: bool) -> Camera {
    Camera {
        position: [3.0, -6.0, 2.5],
        focal_point: [0.0, 0.0, 0.0],
        view_up: [0.0, 0.0, 1.0],
        view_angle: 30.0,
        parallel_projection: parallel,
        parallel_scale: 1.6,
    }
}

#[test]
fn spheres_on_the_gpu_match_the_f64_reference_in_colour_coverage_and_distance() {
    if common::gpu().is_none() {
        return;
    }
    let set = cloud(60);
    let input = PointsInput { particles: &set, node_to_world: DMat4::IDENTITY, color_by: Some("temperature"), range: None, spacing: None };
    let s = Settings { colormap: Colormap::Magma, ..Default::default() };
    let (spheres, range) = points::spheres(&input, &s).unwrap();
    let (name, [lo, hi]) = range.unwrap();
    assert_eq!(name, "temperature");
    let t = &set.arrays[0].values;
    assert_eq!((lo, hi), (t.iter().cloned().fold(f64::INFINITY, f64::min), t.iter().cloned().fold(f64::NEG_INFINITY, f64::max)));
    for parallel in [false, true] {
        let rays = camera(parallel).rays(96, 72);
        let gpu = points::render(&input, &rays, &s).unwrap();
        let cpu = points::render_reference(&spheres, &rays);
        // The PNG preview gets a scalar bar for what colours the spheres.
        assert_eq!(gpu.scales, [ColourScale { title: "temperature".into(), colormap: Colormap::Magma, range: [lo, hi] }]);
        let (mut both, mut mismatched, mut worst_colour, mut worst_depth) = (0, 0, 0.0f32, 0.0f64);
        for i in 0..96 * 72 {
            let (g, c) = (gpu.rgba[i], cpu.rgba[i]);
            if (g[3] > 0.0) != (c[3] > 0.0) {
                mismatched += 1;
                continue;
            }
            if c[3] == 0.0 {
                assert!(gpu.depth[i].is_infinite());
                continue;
            }
            both += 1;
            // Where two spheres meet within f32's reach, either may be nearest.
            let rel = ((gpu.depth[i] - cpu.depth[i]) / cpu.depth[i]).abs() as f64;
            if rel > 1e-4 {
                mismatched += 1;
                continue;
            }
            worst_depth = worst_depth.max(rel);
            worst_colour = worst_colour.max((0..3).map(|k| (g[k] - c[k]).abs()).fold(0.0, f32::max));
        }
        eprintln!("parallel {parallel}: {both} pixels agree, {mismatched} differ; worst colour {worst_colour:e}, depth {worst_depth:e}");
        assert!(both > 1000, "the cloud covers much of the view: {both}");
        // The quads bound each projection exactly (a fiftieth of a pixel to spare): at most a
        // ray grazing a sphere within f32's reach may differ.
        assert!(mismatched <= 2, "{mismatched} of {both} pixels differ");
        assert!(worst_depth < 2e-6, "distance along the ray: relative error {worst_depth:e}");
        assert!(worst_colour < 1e-4, "colour error {worst_colour:e}");
    }
}

#[test]
fn the_nearer_sphere_wins_and_the_colour_map_spans_the_values() {
    if common::gpu().is_none() {
        return;
    }
    // Two spheres on the line of sight, the far one larger; values 0 and 10.
    let set = ParticleSet {
        positions: vec![[0.0, 2.0, 0.0], [0.0, 0.0, 0.0]],
        mass: None,
        density: None,
        smoothing_length: Some(vec![0.5, 0.2]),
        arrays: vec![PointArray { name: "v".into(), components: 1, values: vec![0.0, 10.0] }],
        notes: vec![],
    };
    let cam = Camera {
        position: [0.0, -5.0, 0.0],
        focal_point: [0.0; 3],
        view_up: [0.0, 0.0, 1.0],
        view_angle: 30.0,
        parallel_projection: false,
        parallel_scale: 1.0,
    };
    let rays = cam.rays(33, 33);
    let input = PointsInput { particles: &set, node_to_world: DMat4::IDENTITY, color_by: Some("v"), range: None, spacing: None };
    let s = Settings::default();
    let f = points::render(&input, &rays, &s).unwrap();
    let centre = 16 * 33 + 16;
    // The near sphere (value 10: the map's top) faces the eye: shade 1.
    let top = Colormap::Viridis.at(1.0);
    for k in 0..3 {
        assert!((f.rgba[centre][k] - top[k]).abs() < 1e-5, "{:?} vs {top:?}", f.rgba[centre]);
    }
    assert!((f.depth[centre] as f64 - 4.8).abs() < 1e-5, "{}", f.depth[centre]);
    // Beside the near sphere the far one shows, with the map's bottom colour.
    let ring = 16 * 33 + 16 + 4;
    let bottom = Colormap::Viridis.at(0.0);
    let ratio = f.rgba[ring][1] / bottom[1];
    for (got, want) in f.rgba[ring].iter().zip(bottom) {
        assert!((got - want * ratio).abs() < 1e-5, "{:?}", f.rgba[ring]);
    }
    assert!(f.depth[ring] > 6.0);
    // An array that is not there: one line naming what there is.
    let bad = PointsInput { color_by: Some("pressure"), ..input };
    let e = points::render(&bad, &rays, &s).unwrap_err().to_string();
    assert!(e.contains("no point array 'pressure'") && e.contains("v, h"), "{e}");
}

#[test]
fn colour_maps_are_matplotlibs_in_linear_rgb() {
    // viridis(0) is #440154 and magma(1) #fcfdbf in sRGB (matplotlib's ends).
    let lin = |c: u8| {
        let c = c as f32 / 255.0;
        if c <= 0.04045 {
            c / 12.92
        } else {
            ((c + 0.055) / 1.055).powf(2.4)
        }
    };
    // Within the hex codes' rounding (half a step of 255 in sRGB, up to 0.005 in linear).
    let close = |a: [f32; 3], b: [u8; 3]| (0..3).all(|k| (a[k] - lin(b[k])).abs() < 5e-3);
    assert!(close(Colormap::Viridis.at(0.0), [0x44, 0x01, 0x54]), "{:?}", Colormap::Viridis.at(0.0));
    assert!(close(Colormap::Magma.at(1.0), [0xfc, 0xfd, 0xbf]), "{:?}", Colormap::Magma.at(1.0));
    // hot ends in white; rainbow starts at #8000ff (matplotlib's).
    assert!(close(Colormap::Hot.at(1.0), [0xff, 0xff, 0xff]), "{:?}", Colormap::Hot.at(1.0));
    assert!(close(Colormap::Rainbow.at(0.0), [0x80, 0x00, 0xff]), "{:?}", Colormap::Rainbow.at(0.0));
    // Grey is even in sRGB: 0.5 is sRGB 0.5.
    assert!((Colormap::Grey.at(0.5)[0] - 0.214_041_14).abs() < 1e-6);
}

/// A points node composites with a volume by depth: a sphere in front of the volume hides
/// it; beside the sphere the volume shows as it does alone.
#[test]
fn points_composite_with_a_volume_by_depth() {
    if common::gpu().is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    volterra_formats::nifti::write_nifti(&dir.path().join("v.nii"), &volterra::samples::angio_phantom(32)).unwrap();
    let one = ParticleSet {
        positions: vec![[0.0, -12.0, 0.0]],
        mass: Some(vec![1.0]),
        density: Some(vec![1.0]),
        smoothing_length: Some(vec![2.0]),
        arrays: vec![],
        notes: vec![],
    };
    volterra_formats::vtk::write_vtp(&dir.path().join("p.vtp"), &one, &Default::default()).unwrap();
    let head = "[image]\nwidth = 48\nheight = 48\n[camera]\nposition = [0.0, -80.0, 0.0]\nfocal_point = [0.0, 0.0, 0.0]\nview_angle = 20.0\n\
                [[node]]\nname = \"v\"\nkind = \"volume\"\nfile = \"v.nii\"\nrenderer = \"shear-warp\"\n\
                [node.transfer_function]\nscalar_opacity = [[0.0, 0.0], [255.0, 1.0]]\ncolor = [[0.0, 1.0, 0.2, 0.2], [255.0, 1.0, 0.2, 0.2]]\n";
    let both = format!("{head}[[node]]\nname = \"p\"\nkind = \"particles\"\nfile = \"p.vtp\"\nrenderer = \"points\"\nsettings = {{ colormap = \"grey\" }}\n");
    let load = |text: &str, name: &str| {
        std::fs::write(dir.path().join(name), text).unwrap();
        volterra::scene::Scene::load(&dir.path().join(name), &[]).unwrap()
    };
    let (alone, with) = (load(head, "alone.toml"), load(&both, "both.toml"));
    let render = |s: &volterra::scene::Scene| {
        volterra::render::render_view(s, &s.camera(None).unwrap(), (48, 48), &volterra::render::RenderCache::default()).unwrap()
    };
    let (a, b) = (render(&alone), render(&with));
    let centre = 24 * 48 + 24;
    // One particle, one value: the grey map's middle, nearly facing the eye (the pixel's
    // centre lies half a pixel off the sphere's axis: shade just under 1).
    let grey = Colormap::Grey.at(0.5);
    let shade = b.rgba[centre][0] / grey[0];
    assert!((0.97..=1.0).contains(&shade) && b.rgba[centre][3] == 1.0, "{:?}", b.rgba[centre]);
    assert!((b.depth[centre] - 66.0).abs() < 0.1, "{}", b.depth[centre]);
    // Off the sphere, where the volume is drawn, the composite is the volume's pixel.
    let off: Vec<usize> = (0..48 * 48).filter(|&i| a.rgba[i][3] > 0.05 && (b.depth[i] - 66.0).abs() > 5.0).collect();
    assert!(off.len() > 50, "{}", off.len());
    for i in off {
        assert_eq!(a.rgba[i], b.rgba[i], "pixel {i}");
    }
}

/// Gaussian splats on the GPU against their f64 CPU version: the same coverage, colours
/// (weighted blended: α-weighted mean colour over 1 − Π (1 − α)) and depth, in perspective
/// and in parallel; the result does not depend on the particles' order.
#[test]
fn splats_on_the_gpu_match_the_f64_reference_in_any_order() {
    if common::gpu().is_none() {
        return;
    }
    let mut set = cloud(80);
    let s = Settings { style: points::PointStyle::Splats, opacity: 0.4, colormap: Colormap::Viridis, ..Default::default() };
    for parallel in [false, true] {
        let input =
            PointsInput { particles: &set, node_to_world: DMat4::IDENTITY, color_by: Some("temperature"), range: None, spacing: None };
        let (spheres, _) = points::spheres(&input, &s).unwrap();
        let rays = camera(parallel).rays(96, 72);
        let gpu = points::render(&input, &rays, &s).unwrap();
        let cpu = points::render_splats_reference(&spheres, &rays, s.opacity);
        let (mut covered, mut worst, mut worst_depth, mut depth_mismatch) = (0, 0.0f32, 0.0f32, 0);
        for i in 0..96 * 72 {
            let (g, c) = (gpu.rgba[i], cpu.rgba[i]);
            worst = worst.max((0..4).map(|k| (g[k] - c[k]).abs()).fold(0.0, f32::max));
            covered += (c[3] > 0.01) as usize;
            if cpu.depth[i].is_finite() != gpu.depth[i].is_finite() {
                depth_mismatch += 1; // a ray passing exactly σ from a centre, within f32
            } else if cpu.depth[i].is_finite() {
                worst_depth = worst_depth.max((gpu.depth[i] - cpu.depth[i]).abs() / cpu.depth[i]);
            }
        }
        eprintln!("splats, parallel {parallel}: {covered} pixels covered; worst RGBA difference {worst:e}, depth {worst_depth:e}, {depth_mismatch} depth mismatches");
        assert!(covered > 1000, "{covered}");
        assert!(worst < 2e-5, "RGBA differs by {worst:e}");
        assert!(worst_depth < 2e-6 && depth_mismatch <= 3, "depth {worst_depth:e}, {depth_mismatch} mismatches");
        // Translucent where few splats overlap: coverage spans (0, 1).
        assert!(gpu.rgba.iter().any(|p| p[3] > 0.01 && p[3] < 0.5) && gpu.rgba.iter().any(|p| p[3] > 0.6));
        // In passes of at most 300 tile records (several passes, each carrying on the
        // sums the one before left): the same picture, bit for bit.
        let passes = points::render_in_batches(&input, &rays, &s, 300).unwrap();
        assert!(passes.rgba == gpu.rgba && passes.depth == gpu.depth, "drawn in passes, the splats differ");
        // Reversed order: the same picture up to the float sums' rounding.
        set.positions.reverse();
        set.smoothing_length.as_mut().unwrap().reverse();
        set.arrays[0].values.reverse();
        let input =
            PointsInput { particles: &set, node_to_world: DMat4::IDENTITY, color_by: Some("temperature"), range: None, spacing: None };
        let reversed = points::render(&input, &rays, &s).unwrap();
        let order =
            (0..96 * 72).map(|i| (0..4).map(|k| (reversed.rgba[i][k] - gpu.rgba[i][k]).abs()).fold(0.0, f32::max)).fold(0.0, f32::max);
        assert!(order < 1e-5, "order changes the picture by {order:e}");
    }
}

/// Where the adapter maps storage buffers in place (lavapipe), the splats' records and sums
/// are kept from frame to frame: a frame drawn after others of other sizes, with more and
/// with fewer records, is the same bit for bit as when drawn first.
#[test]
fn splats_drawn_after_other_frames_are_the_same() {
    if common::gpu().is_none() {
        return;
    }
    let s = Settings { style: points::PointStyle::Splats, opacity: 0.4, colormap: Colormap::Viridis, ..Default::default() };
    let (small, large) = (cloud(40), cloud(400));
    let input =
        |set| PointsInput { particles: set, node_to_world: DMat4::IDENTITY, color_by: Some("temperature"), range: None, spacing: None };
    let first = points::render(&input(&small), &camera(false).rays(96, 72), &s).unwrap();
    assert!(first.rgba.iter().any(|p| p[3] > 0.5));
    points::render(&input(&large), &camera(true).rays(120, 90), &s).unwrap();
    points::render(&input(&large), &camera(false).rays(96, 72), &s).unwrap();
    let again = points::render(&input(&small), &camera(false).rays(96, 72), &s).unwrap();
    assert!(again.rgba == first.rgba && again.depth == first.depth, "a frame drawn after others differs");
}

/// `opacity` belongs to splats: a spheres node that gives it is refused before any drawing.
#[test]
fn opacity_is_refused_for_spheres() {
    let decl = volterra::catalog::find("points").unwrap();
    let table = |s: &str| s.parse::<toml::Table>().unwrap();
    let e = (decl.parse)(&table("opacity = 0.5")).err().unwrap();
    assert!(e.to_string().contains("opacity") && e.to_string().contains("splats"), "{e}");
    assert!((decl.parse)(&table("style = \"splats\"\nopacity = 0.5")).is_ok());
    assert!((decl.parse)(&table("style = \"splats\"\nopacity = 0.0")).is_err(), "opacity in (0, 1]");
}

/// Each sphere's triangle is drawn round its exact projection, an ellipse stretched toward
/// the image's edge: a wide view (110°) with spheres near the eye, off the axis, beside the
/// eye (more than 90° across) and partly outside the image covers what the f64 reference
/// covers, pixel for pixel, in spheres and in splats. (A triangle round a circle of the
/// minor semi-axis leaves 826 pixels out; the depth range once taken along the view axis
/// instead of along the rays put 327 pixels of spheres at the edges behind the far plane.)
#[test]
fn wide_views_of_spheres_near_the_eye_cover_what_the_reference_covers() {
    if common::gpu().is_none() {
        return;
    }
    let mut rng = SplitMix64(5);
    let mut positions = vec![];
    let mut h = vec![];
    for _ in 0..150 {
        // Camera at the origin looking along +y: spheres 0.3 to 4 ahead, spread far to the
        // sides, some of them with their centre within a radius or two of the eye plane.
        let y = rng.range(0.3, 4.0);
        positions.push([rng.range(-1.6, 1.6) * y, y, rng.range(-1.2, 1.2) * y]);
        h.push(rng.range(0.05, 0.25) as f32);
    }
    let n = positions.len();
    let set = ParticleSet {
        positions,
        mass: Some(vec![1.0; n]),
        density: None,
        smoothing_length: Some(h),
        arrays: vec![PointArray { name: "v".into(), components: 1, values: (0..n).map(|i| i as f64).collect() }],
        notes: vec![],
    };
    let cam = Camera {
        position: [0.0; 3],
        focal_point: [0.0, 1.0, 0.0],
        view_up: [0.0, 0.0, 1.0],
        view_angle: 110.0,
        parallel_projection: false,
        parallel_scale: 1.0,
    };
    let rays = cam.rays(160, 120);
    let input = PointsInput { particles: &set, node_to_world: DMat4::IDENTITY, color_by: Some("v"), range: None, spacing: None };
    for style in [points::PointStyle::Spheres, points::PointStyle::Splats] {
        let s = Settings { style, ..Default::default() };
        let (spheres, _) = points::spheres(&input, &s).unwrap();
        let gpu = points::render(&input, &rays, &s).unwrap();
        let cpu = if style == points::PointStyle::Spheres {
            points::render_reference(&spheres, &rays)
        } else {
            points::render_splats_reference(&spheres, &rays, s.opacity)
        };
        let covered = cpu.rgba.iter().filter(|p| p[3] > 0.0).count();
        let differ = gpu.rgba.iter().zip(&cpu.rgba).filter(|(g, c)| (g[3] > 0.0) != (c[3] > 0.0)).count();
        eprintln!("{style:?}: {covered} pixels covered, {differ} differ");
        assert!(covered > 4000, "{style:?}: the spheres cover much of the view: {covered}");
        assert!(differ <= 3, "{style:?}: {differ} of {covered} pixels covered by one side only");
    }
}

/// The default radius of spheres is half the distance to each particle's nearest
/// neighbour, at most its h (issue 44: spheres of h hid a halo's core behind overlapping
/// balls): no two spheres overlap, where spheres of h (`radius_of = "h"`, VTK's) do; a set
/// without h gets radii all the same.
#[test]
fn default_spheres_do_not_overlap() {
    let set = volterra::samples::smoke_plume(600, 4);
    let input = PointsInput { particles: &set, node_to_world: DMat4::IDENTITY, color_by: None, range: None, spacing: None };
    let overlaps = |spheres: &[points::Sphere]| {
        let mut n = 0;
        for i in 0..spheres.len() {
            for j in i + 1..spheres.len() {
                let d = (spheres[i].centre - spheres[j].centre).length();
                n += usize::from(d < spheres[i].radius + spheres[j].radius);
            }
        }
        n
    };
    let (auto, _) = points::spheres(&input, &Settings::default()).unwrap();
    assert_eq!(overlaps(&auto), 0, "default spheres overlap");
    let (of_h, _) = points::spheres(&input, &Settings { radius_of: points::RadiusOf::H, ..Default::default() }).unwrap();
    let n = overlaps(&of_h);
    assert!(n > 1000, "spheres of h overlap ({n} pairs): the default is the test's point");
    // Radii at most h, and set by the nearest neighbour where that is nearer.
    let h = set.smoothing_length.as_ref().unwrap();
    assert!(auto.iter().zip(h).all(|(s, &h)| s.radius <= h as f64 * (1.0 + 1e-6)));
    assert!(auto.iter().zip(h).filter(|(s, &h)| s.radius < 0.99 * h as f64).count() > 300);
    // Without h: the spacing alone.
    let no_h = ParticleSet { smoothing_length: None, ..set.clone() };
    let input = PointsInput { particles: &no_h, ..input };
    let (spheres, _) = points::spheres(&input, &Settings::default()).unwrap();
    assert_eq!(overlaps(&spheres), 0);
}
