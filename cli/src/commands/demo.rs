//! `demo`: the main job on the built-in samples (every scene rendered into one folder, with a
//! summary), and the README's gallery: small pictures of the built-in samples, made by
//! `volterra demo --gallery docs/images` (tests/gallery.rs makes them again and compares
//! them with the committed ones, so a picture cannot drift from the code).

use anyhow::{Context, Result};
use std::path::Path;
use volterra_formats::{self as formats, Limits};

/// Width of every picture; each keeps its scene's aspect.
pub const WIDTH: usize = 320;

/// What the gallery shows: (picture, the sample scene it renders; None: the hillshade of
/// the sample DEM, as `volterra dem hillshade` makes it).
pub const PICTURES: &[(&str, Option<&str>)] = &[
    ("angio_shaded.png", Some("angio_shaded.toml")),
    ("pet_ct.png", Some("pet_ct.toml")),
    ("terrain_drape.png", Some("terrain_png.toml")),
    ("hillshade.png", None),
    ("smoke.png", Some("smoke.toml")),
    ("plume_points.png", Some("plume_points.toml")),
];

/// Writes every picture into `dir` (the samples into a temporary directory beside it).
pub fn gallery(dir: &Path, limits: Limits) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create the directory", dir.display()))?;
    let samples = tempfile::Builder::new()
        .prefix(".volterra-gallery-")
        .tempdir_in(dir)
        .with_context(|| format!("{}: cannot write into it", dir.display()))?;
    volterra::samples::write_samples(samples.path())?;
    for (picture, scene) in PICTURES {
        let out = dir.join(picture);
        let t = std::time::Instant::now();
        match scene {
            Some(scene) => {
                let path = samples.path().join(scene);
                let file = volterra::scene::Scene::load(&path, &[])?.file;
                let height = (WIDTH * file.image.height).div_ceil(file.image.width);
                let sets = [format!("image.width={WIDTH}"), format!("image.height={height}")];
                super::render::cmd_render(&path, &out, None, &sets, limits)?;
            }
            None => hillshade(&samples.path().join("fractal_dem.tif"), &out, &limits)?,
        }
        say!("{}: {:.1} s", out.display(), t.elapsed().as_secs_f64());
    }
    Ok(())
}

/// gdaldem hillshade's defaults (azimuth 315°, altitude 45°, Horn) on the sample DEM,
/// written as a PNG of every n-th cell along each axis, n the least that makes it at most
/// WIDTH wide (each pixel a cell's own grey level, none averaged).
fn hillshade(dem: &Path, out: &Path, limits: &Limits) -> Result<()> {
    let hf = formats::geotiff::read_geotiff(dem, limits)?;
    let volterra::dem::Raster::U8(shade) = volterra::dem::compute(&hf, volterra::dem::Product::Hillshade, &Default::default())? else {
        unreachable!("hillshade is a byte raster")
    };
    let step = hf.width.div_ceil(WIDTH);
    let (w, h) = (hf.width.div_ceil(step), hf.height.div_ceil(step));
    let rgba: Vec<u8> = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .flat_map(|(x, y)| {
            let v = shade[y * step * hf.width + x * step];
            [v, v, v, 255]
        })
        .collect();
    Ok(formats::image::write_png_rgba8(out, w, h, &rgba)?)
}

/// `json`: the summary as one JSON array (scene, renderer, width, height, seconds, the
/// EXR and PNG written) instead of a table.
pub fn run(out: &Path, json: bool, limits: Limits) -> Result<()> {
    let samples = out.join("samples");
    volterra::samples::write_samples(&samples)?;
    say!("wrote built-in samples into {}", samples.display());
    if !json {
        println!("{:<18} {:<12} {:>9} {:>9}  result", "scene", "renderer", "size", "seconds");
    }
    let mut rows = Vec::new();
    for (name, _) in volterra::samples::SCENES {
        let stem = name.trim_end_matches(".toml");
        let scene = volterra::scene::Scene::load(&samples.join(name), &[])?.with_limits(limits);
        let renderer = (0..scene.nodes().len()).filter_map(|i| scene.renderer(i)).map(|r| r.name).collect::<Vec<_>>().join("+");
        let (width, height) = (scene.file.image.width, scene.file.image.height);
        let exr = out.join(format!("{stem}.exr"));
        let png = out.join(format!("{stem}.png"));
        let t = std::time::Instant::now();
        super::render::cmd_render(&samples.join(name), &exr, Some(&png), &[], limits)?;
        let seconds = t.elapsed().as_secs_f64();
        if json {
            rows.push(serde_json::json!({"scene": stem, "renderer": renderer, "width": width, "height": height,
                "seconds": seconds, "exr": exr.display().to_string(), "png": png.display().to_string()}));
        } else {
            let size = format!("{width}×{height}");
            println!("{stem:<18} {renderer:<12} {size:>9} {seconds:>9.2}  {} + {}", exr.display(), png.display());
        }
    }
    if json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
    }
    Ok(())
}
