//! Georeferenced drapes (issue 20): a GeoTIFF texture lies where its own georeferencing
//! says, in the heightfield's CRS, not stretched over the extent. Checked against GDAL: at
//! points of a flat DEM seen straight down, the colour drawn is the drape's pixel that
//! `gdallocationinfo -geoloc` finds at the same map coordinates (GPU and f64 reference);
//! beyond the drape and where a single-band drape is NoData the elevation colour shows; a
//! colour-mapped band gets its scalar bar; a drape in another CRS, or off the DEM, is
//! refused with a clear line.

mod common;

use glam::DMat4;
use std::path::Path;
use std::process::Command;
use volterra::render::terrain::{self, Settings, TerrainInput};
use volterra::render::Frame;
use volterra::scene::camera::Camera;
use volterra::scene::drape::{BandColours, Drape};
use volterra_formats::{Crs, Heightfield};

const CELL: f64 = 30.0;
const N: usize = 65;

fn utm(epsg: u32) -> Crs {
    Crs { epsg: Some(epsg), geographic: false, description: format!("EPSG:{epsg}"), metres_per_unit: 1.0 }
}

/// A flat DEM (100 m) of N × N samples, 30 m apart, in UTM 10N.
fn dem() -> Heightfield {
    Heightfield { elevations: vec![100.0; N * N], ..drape_grid(N, N, CELL, [500_015.0, 4_200_015.0], utm(32610)) }
}

/// A grid of w × h pixels of `pixel` m (elevations 0), its north-west pixel centred at
/// `origin`: a drape's, or the DEM's.
fn drape_grid(w: usize, h: usize, pixel: f64, origin: [f64; 2], crs: Crs) -> Heightfield {
    Heightfield {
        width: w,
        height: h,
        cell_size: [pixel; 2],
        cell_size_native: [pixel; 2],
        origin,
        crs,
        elevations: vec![0.0; w * h],
        nodata: Default::default(),
        nodata_value: None,
        notes: vec![],
        attributes: vec![],
        units: volterra_formats::heightfield::GridUnits::METRES,
    }
}

/// Straight down on the whole DEM, parallel, one image pixel per DEM cell; a sun straight
/// overhead and no ambient light, so a pixel's colour is its base colour.
fn top_down(hf: &Heightfield, drape: Option<&Drape>) -> Option<(Frame, Frame, volterra::scene::camera::RayGenerator)> {
    let ext = (N - 1) as f64 * CELL;
    let cam = Camera {
        position: [0.5 * ext, 0.5 * ext, 5000.0],
        focal_point: [0.5 * ext, 0.5 * ext, 0.0],
        view_up: [0.0, 1.0, 0.0],
        view_angle: 30.0,
        parallel_projection: true,
        parallel_scale: 0.5 * ext,
    };
    let lights = [common::sun([0.0, 0.0, -1.0])];
    let rays = cam.rays(N - 1, N - 1);
    let input = TerrainInput { heightfield: hf, texture: drape, node_to_world: DMat4::IDENTITY, lights: &lights };
    let s = Settings { ambient: 0.0, rays_per_pixel: 1, ..Default::default() };
    let reference = terrain::render_reference(&input, &rays, &s).unwrap();
    let gpu = common::gpu().map(|_| terrain::render(&input, &rays, &s).unwrap());
    Some((gpu.unwrap_or_else(|| reference.clone()), reference, rays))
}

/// The map coordinates a pixel's centre ray hits (straight down).
fn map_xy(hf: &Heightfield, rays: &volterra::scene::camera::RayGenerator, px: usize, py: usize) -> [f64; 2] {
    let o = rays.ray(px as f64 + 0.5, py as f64 + 0.5).origin;
    [o.x + hf.origin[0], o.y + hf.origin[1] - (hf.height - 1) as f64 * CELL]
}

/// What GDAL reads at map point (x, y) of `path`: each band's value, or None off the image.
fn gdal_at(path: &Path, xy: [f64; 2]) -> Option<Vec<f64>> {
    let out = Command::new("gdallocationinfo")
        .args(["-valonly", "-geoloc"])
        .arg(path)
        .args([xy[0].to_string(), xy[1].to_string()])
        .output()
        .expect("gdallocationinfo runs");
    let text = String::from_utf8_lossy(&out.stdout);
    let values: Vec<f64> = text.lines().filter_map(|l| l.trim().parse().ok()).collect();
    (!values.is_empty()).then_some(values)
}

fn gdal_present() -> bool {
    if Path::new("/usr/bin/gdallocationinfo").exists() {
        return true;
    }
    if common::under_ci() {
        panic!("gdallocationinfo missing under CI (tests/setup-system.sh installs gdal-bin)");
    }
    eprintln!("SKIPPED: gdal-bin not installed");
    false
}

fn srgb(v: f64) -> f64 {
    volterra::render::terrain::shading::srgb_to_linear(v.round() as u8)
}

#[test]
fn an_rgb_geotiff_drape_lies_where_its_georeferencing_says() {
    if !gdal_present() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let hf = dem();
    // 48 × 40 pixels of 20 m, its corner 200 m east and 300 m south of the DEM's north-west
    // corner: it covers part of the DEM only. Blocks of 8 × 8 pixels in distinct colours.
    let (w, h, px) = (48, 40, 20.0);
    let corner = [hf.origin[0] - 0.5 * CELL + 200.0, hf.origin[1] + 0.5 * CELL - 300.0];
    let grid = drape_grid(w, h, px, [corner[0] + 0.5 * px, corner[1] - 0.5 * px], utm(32610));
    let rgb: Vec<u8> = (0..w * h)
        .flat_map(|i| {
            let (bx, by) = ((i % w) / 8, (i / w) / 8);
            [(40 * bx + 20) as u8, (50 * by + 10) as u8, ((bx * 7 + by * 13) % 5 * 50) as u8]
        })
        .collect();
    let path = dir.path().join("drape.tif");
    volterra_formats::geotiff::write_band(&path, &grid.georef(), volterra_formats::geotiff::Band::Rgb8(&rgb), None, false).unwrap();
    let drape = Drape::load(&path, None, &Default::default()).unwrap();
    let Some((gpu, reference, rays)) = top_down(&hf, Some(&drape)) else { return };
    let (plain, ..) = top_down(&hf, None).unwrap();
    let (iw, ih) = (rays.size().0, rays.size().1);
    let (mut inside, mut outside) = (0, 0);
    for py in (2..ih).step_by(4) {
        for pxl in (2..iw).step_by(4) {
            let xy = map_xy(&hf, &rays, pxl, py);
            // Only points well inside a block (its colour the same ±1.5 drape pixels away).
            let (fx, fy) = ((xy[0] - corner[0]) / px, (corner[1] - xy[1]) / px);
            let p = py * iw + pxl;
            match gdal_at(&path, xy) {
                Some(v) => {
                    if (fx % 8.0 - 4.0).abs() > 2.5 || (fy % 8.0 - 4.0).abs() > 2.5 || fx > w as f64 - 2.0 || fy > h as f64 - 2.0 {
                        continue;
                    }
                    let want = [srgb(v[0]), srgb(v[1]), srgb(v[2])];
                    for (name, f) in [("gpu", &gpu), ("reference", &reference)] {
                        assert!(
                            want.iter().zip(&f.rgba[p]).all(|(w, &c)| (c as f64 - w).abs() < 2e-3),
                            "{name} pixel ({pxl}, {py}) at {xy:?}: {:?}, GDAL's drape pixel {v:?}",
                            f.rgba[p]
                        );
                    }
                    inside += 1;
                }
                None => {
                    if fx > -1.0 && fy > -1.0 && fx < w as f64 + 1.0 && fy < h as f64 + 1.0 {
                        continue;
                    }
                    // Beyond the drape: the elevation colour, as without one.
                    for f in [&gpu, &reference] {
                        assert!((0..3).all(|k| (f.rgba[p][k] - plain.rgba[p][k]).abs() < 1e-4), "pixel ({pxl}, {py})");
                    }
                    outside += 1;
                }
            }
        }
    }
    println!("{inside} points checked on the drape against gdallocationinfo, {outside} beyond it");
    assert!(inside > 15 && outside > 100, "{inside} inside, {outside} outside");
}

#[test]
fn a_single_band_drape_is_colour_mapped_with_nodata_transparent_and_a_legend() {
    if !gdal_present() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let hf = dem();
    // Covers the whole DEM at 60 m: values = column × 10 (0…330), a NoData square.
    let (w, h, px) = (34, 34, 60.0);
    let corner = [hf.origin[0] - 0.5 * CELL - 30.0, hf.origin[1] + 0.5 * CELL + 30.0];
    let mut grid = drape_grid(w, h, px, [corner[0] + 0.5 * px, corner[1] - 0.5 * px], utm(32610));
    grid.elevations = (0..w * h).map(|i| ((i % w) * 10) as f32).collect();
    grid.nodata = (0..w * h).map(|i| (10..20).contains(&(i % w)) && (10..20).contains(&(i / w))).collect();
    grid.nodata_value = Some(-9999.0);
    let path = dir.path().join("band.tif");
    volterra_formats::geotiff::write_geotiff(&path, &grid).unwrap();
    let colours = BandColours { colormap: volterra::colormap::Colormap::Viridis, range: Some([0.0, 330.0]) };
    let drape = Drape::load(&path, Some(colours), &Default::default()).unwrap();
    assert_eq!(drape.scale, Some((colours.colormap, [0.0, 330.0])), "the legend's map and range");
    let Some((gpu, reference, rays)) = top_down(&hf, Some(&drape)) else { return };
    let (plain, ..) = top_down(&hf, None).unwrap();
    let iw = rays.size().0;
    let (mut mapped, mut holes) = (0, 0);
    for py in (1..rays.size().1).step_by(3) {
        for pxl in (1..iw).step_by(4) {
            let xy = map_xy(&hf, &rays, pxl, py);
            let (fx, fy) = ((xy[0] - corner[0]) / px, (corner[1] - xy[1]) / px);
            let (col, row) = (fx.floor() as usize, fy.floor() as usize);
            let near = |lo: f64, hi: f64, f: f64| f > lo - 1.5 && f < hi + 1.5;
            let p = py * iw + pxl;
            if near(10.0, 20.0, fx) && near(10.0, 20.0, fy) {
                if fx > 11.5 && fx < 18.5 && fy > 11.5 && fy < 18.5 {
                    for f in [&gpu, &reference] {
                        assert!((0..3).all(|k| (f.rgba[p][k] - plain.rgba[p][k]).abs() < 1e-4), "NoData at ({pxl}, {py})");
                    }
                    holes += 1;
                }
                continue;
            }
            // Inside a drape pixel, away from its edges (the band is linear across columns,
            // so bilinear filtering gives the value at the point itself).
            let Some(v) = gdal_at(&path, xy) else { continue };
            assert_eq!(v[0], (col * 10) as f64, "GDAL's value at ({col}, {row})");
            let value = (fx - 0.5) * 10.0;
            if !(0.0..=330.0).contains(&value) {
                continue;
            }
            // The colour map's sRGB bytes, decoded as the GPU does.
            let c = colours.colormap.at(value / 330.0);
            let byte = |x: f32| (volterra_formats::image::linear_to_srgb(x) * 255.0).round();
            let want = c.map(|x| srgb(byte(x) as f64));
            for (name, f) in [("gpu", &gpu), ("reference", &reference)] {
                for k in 0..3 {
                    // Neighbouring drape pixels' bytes are interpolated: within a byte step.
                    assert!((f.rgba[p][k] as f64 - want[k]).abs() < 0.02, "{name} ({pxl}, {py}): {:?} vs {want:?}", f.rgba[p]);
                }
            }
            mapped += 1;
        }
    }
    println!("{mapped} colour-mapped points, {holes} in the NoData hole");
    assert!(mapped > 150 && holes > 4, "{mapped} mapped, {holes} holes");
}

#[test]
fn a_drape_in_another_crs_or_off_the_dem_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let hf = dem();
    let rgb = vec![128u8; 3 * 16];
    let other = drape_grid(4, 4, 30.0, hf.origin, utm(32611));
    let path = dir.path().join("other.tif");
    volterra_formats::geotiff::write_band(&path, &other.georef(), volterra_formats::geotiff::Band::Rgb8(&rgb), None, false).unwrap();
    let drape = Drape::load(&path, None, &Default::default()).unwrap();
    let e = terrain::drape_placement(&hf.georef(), &drape).unwrap_err().to_string();
    assert!(e.contains("EPSG:32611") && e.contains("EPSG:32610") && e.contains("CRS"), "{e}");
    let away = drape_grid(4, 4, 30.0, [hf.origin[0] + 1e5, hf.origin[1]], utm(32610));
    let path = dir.path().join("away.tif");
    volterra_formats::geotiff::write_band(&path, &away.georef(), volterra_formats::geotiff::Band::Rgb8(&rgb), None, false).unwrap();
    let drape = Drape::load(&path, None, &Default::default()).unwrap();
    let e = terrain::drape_placement(&hf.georef(), &drape).unwrap_err().to_string();
    assert!(e.contains("outside the heightfield"), "{e}");
    // A colour map for an RGB drape is a mistake, said so.
    let colours = BandColours { colormap: volterra::colormap::Colormap::Grey, range: None };
    let e = Drape::load(&path, Some(colours), &Default::default()).unwrap_err().to_string();
    assert!(e.contains("single-band"), "{e}");
}

/// A PNG drape of the DEM's own size has its texel centres on the sample centres (issue 44:
/// its outer texel edges were stretched to the first and last sample centres, up to half a
/// cell off): it draws bit for bit as the same pixels written as a GeoTIFF on the DEM's own
/// grid, GPU and reference; a PNG one texel shorter than the samples (1024² over 1025²)
/// draws as a GeoTIFF whose pixel edges lie on the sample centres. And a drape that
/// covers the whole terrain, GeoTIFF or PNG, leaves no elevation scalar bar (its tints show
/// nowhere); one that covers part of it keeps it.
#[test]
fn a_png_drape_of_the_dems_size_lies_texel_on_sample_as_the_same_geotiff() {
    let dir = tempfile::tempdir().unwrap();
    let hf = dem();
    let pattern = |w: usize, h: usize| -> Vec<u8> {
        (0..w * h)
            .flat_map(|i| [((i % w) * 255 / w) as u8, ((i / w) * 255 / h) as u8, ((i % w * 7 + i / w * 13) % 17 * 15) as u8])
            .collect()
    };
    let [x0, y0] = hf.origin;
    // (texels, the GeoTIFF's north-west pixel centre): the DEM's own grid, and pixels
    // whose edges lie on the sample centres.
    let cases = [(N, [x0, y0]), (N - 1, [x0 + 0.5 * CELL, y0 - 0.5 * CELL])];
    for (texels, origin) in cases {
        let rgb = pattern(texels, texels);
        let png = dir.path().join(format!("drape{texels}.png"));
        volterra_formats::image::write_png_rgb8(&png, &volterra_formats::RgbImage { width: texels, height: texels, data: rgb.clone() })
            .unwrap();
        let tif = dir.path().join(format!("drape{texels}.tif"));
        let grid = drape_grid(texels, texels, CELL, origin, utm(32610));
        volterra_formats::geotiff::write_band(&tif, &grid.georef(), volterra_formats::geotiff::Band::Rgb8(&rgb), None, false).unwrap();
        let (png_drape, tif_drape) =
            (Drape::load(&png, None, &Default::default()).unwrap(), Drape::load(&tif, None, &Default::default()).unwrap());
        let (a, b) =
            (terrain::drape_placement(&hf.georef(), &png_drape).unwrap(), terrain::drape_placement(&hf.georef(), &tif_drape).unwrap());
        for k in 0..4 {
            assert!((a[k] - b[k]).abs() < 1e-12, "{texels} texels: placement {a:?}, the GeoTIFF's {b:?}");
        }
        let (gpu_png, ref_png, _) = top_down(&hf, Some(&png_drape)).unwrap();
        let (gpu_tif, ref_tif, _) = top_down(&hf, Some(&tif_drape)).unwrap();
        assert!(ref_png.rgba == ref_tif.rgba, "{texels} texels: the reference's pictures differ");
        assert!(gpu_png.rgba == gpu_tif.rgba, "{texels} texels: the GPU's pictures differ");
        // Both cover the whole terrain: no elevation scalar bar.
        assert!(ref_png.scales.is_empty() && ref_tif.scales.is_empty(), "{:?} {:?}", ref_png.scales, ref_tif.scales);
    }
    // The DEM's own size, in texel units: sample c lies at texel coordinate c (centres).
    let png_drape = Drape::stretched(&volterra_formats::RgbImage { width: N, height: N, data: pattern(N, N) });
    let [s0, s1, t0, t1] = terrain::drape_placement(&hf.georef(), &png_drape).unwrap();
    for c in [0, 10, N - 1] {
        assert!(((s0 + s1 * c as f64) * N as f64 - 0.5 - c as f64).abs() < 1e-9, "column {c}");
        // Grid row gy counts from the south; texel rows from the north.
        assert!(((t0 + t1 * c as f64) * N as f64 - 0.5 - (N - 1 - c) as f64).abs() < 1e-9, "row {c}");
    }
    // A GeoTIFF drape over part of the DEM: the elevation colours show, with their bar.
    let part = drape_grid(20, 20, CELL, hf.origin, utm(32610));
    let tif = dir.path().join("part.tif");
    volterra_formats::geotiff::write_band(&tif, &part.georef(), volterra_formats::geotiff::Band::Rgb8(&pattern(20, 20)), None, false)
        .unwrap();
    let (_, reference, _) = top_down(&hf, Some(&Drape::load(&tif, None, &Default::default()).unwrap())).unwrap();
    assert_eq!(reference.scales.len(), 1, "part of the terrain shows its elevation colours");
}
