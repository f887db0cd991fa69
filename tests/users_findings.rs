//! What three new users hit on unseen data (issue 44), each reproduced: results that were
//! wrong or misleading without a word, and the conventions of the tools they came from.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

fn volterra(args: &[&str]) -> std::process::Output {
    Command::new(common::volterra_bin()).args(args).output().unwrap()
}

/// `volterra render SCENE -o OUT` in `dir`: its stderr (it must succeed).
fn render(scene: &Path, out: &Path) -> String {
    let o = volterra(&["render", scene.to_str().unwrap(), "-o", out.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(o.status.success(), "{}: {err}", scene.display());
    err
}

fn exr_pixels(path: &Path) -> Vec<f32> {
    let img = volterra_formats::exr_io::read_exr(path, &Default::default()).unwrap();
    img.channels.into_iter().flat_map(|(_, values)| values).collect()
}

/// A small plume scene over `file`, drawn by `renderer`.
fn particle_scene(dir: &Path, name: &str, file: &str, renderer: &str) -> PathBuf {
    let settings = if renderer == "smoke" {
        "medium = { c_ext = 10.0, albedo = 0.9, g = 0.3 }\nsettings = { photons = 3000, samples = 1 }"
    } else {
        "color_by = \"density\""
    };
    let scene = dir.join(name);
    std::fs::write(
        &scene,
        format!(
            "[image]\nwidth = 40\nheight = 32\n[camera]\nposition = [0.5, -1.6, 0.5]\nfocal_point = [0.5, 0.5, 0.45]\n\
             [[light]]\nkind = \"directional\"\ndirection = [-1.0, 0.6, -0.5]\nintensity = 3.0\n\
             [[node]]\nname = \"plume\"\nkind = \"particles\"\nfile = \"{file}\"\nrenderer = \"{renderer}\"\n{settings}\n"
        ),
    )
    .unwrap();
    scene
}

/// Particles at NaN or infinite positions: one rule for both particle renderers — left
/// out, counted by `info` (bounds of the finite ones) and said in the frame's notes. Each
/// renderer's image is the image of the file without them, bit for bit. (Before, the points
/// renderer drew them silently and smoke refused them.)
#[test]
fn particles_at_positions_that_are_not_finite_are_counted_left_out_and_said() {
    let dir = tempfile::tempdir().unwrap();
    let clean = volterra::samples::smoke_plume(2000, 5);
    let mut broken = clean.clone();
    let bad = [(17, [f64::NAN, 0.5, 0.5]), (400, [0.5, f64::INFINITY, 0.5]), (1999, [0.2, 0.3, f64::NEG_INFINITY])];
    // Insert the bad particles (each with every array's values) among the clean ones.
    for (at, p) in bad {
        broken.positions.insert(at, p);
        for v in [&mut broken.mass, &mut broken.density, &mut broken.smoothing_length].into_iter().flatten() {
            v.insert(at, v[0]);
        }
        for a in &mut broken.arrays {
            let first: Vec<f64> = a.values[..a.components].to_vec();
            a.values.splice(at * a.components..at * a.components, first);
        }
    }
    let names = Default::default();
    volterra_formats::vtk::write_vtp(&dir.path().join("clean.vtp"), &clean, &names).unwrap();
    volterra_formats::vtk::write_vtp(&dir.path().join("broken.vtp"), &broken, &names).unwrap();

    let o = volterra(&["info", "--json", dir.path().join("broken.vtp").to_str().unwrap()]);
    assert!(o.status.success());
    let info: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(info["count"], 2003);
    assert_eq!(info["non_finite_positions"], 3);
    let (lo, hi) = clean.bounds().unwrap();
    assert_eq!(info["bounds"], serde_json::json!([lo, hi]), "bounds of the finite positions");
    assert!(info["notes"].to_string().contains("3 of 2003 particles are at positions that are not finite"), "{info}");
    let text = String::from_utf8_lossy(&volterra(&["info", dir.path().join("broken.vtp").to_str().unwrap()]).stdout).into_owned();
    assert!(text.contains("2003 (3 at positions that are not finite)") && text.contains("particle 17, at (NaN, 0.5, 0.5)"), "{text}");

    let renderers: &[&str] = if common::gpu().is_some() { &["smoke", "points"] } else { &["smoke"] };
    for renderer in renderers {
        let (a, b) = (dir.path().join(format!("{renderer}_clean.exr")), dir.path().join(format!("{renderer}_broken.exr")));
        render(&particle_scene(dir.path(), &format!("{renderer}_clean.toml"), "clean.vtp", renderer), &a);
        let err = render(&particle_scene(dir.path(), &format!("{renderer}_broken.toml"), "broken.vtp", renderer), &b);
        assert!(err.contains("3 of 2003 particles are at positions that are not finite"), "{renderer}: {err}");
        assert!(exr_pixels(&a) == exr_pixels(&b), "{renderer}: the image differs from the image without those particles");
    }
}

/// A DICOM folder of two series: `view --screenshot` ends at once with the one-line error
/// that says to choose one (it waited for ever for a click in the series browser), and
/// `view` takes `--series`; a scene node on such a folder names the node's own key
/// (`series = N`), not a CLI flag, and lists the series by number, description and size
/// before their UIDs.
#[test]
fn a_folder_of_several_series_says_how_to_choose_one_wherever_it_is_opened() {
    let folder = common::repo_path("tests/fixtures/dicom/two_series");
    let dir = tempfile::tempdir().unwrap();
    let shot = dir.path().join("never.png");
    let mut child = Command::new(common::volterra_bin())
        .args(["view", folder.to_str().unwrap(), "--screenshot", shot.to_str().unwrap()])
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let start = std::time::Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if start.elapsed() > std::time::Duration::from_secs(60) {
            let _ = child.kill();
            panic!("view --screenshot still waits after 60 s for a series to be chosen");
        }
        std::thread::sleep(std::time::Duration::from_millis(100));
    };
    let mut err = String::new();
    std::io::Read::read_to_string(child.stderr.as_mut().unwrap(), &mut err).unwrap();
    assert_eq!(status.code(), Some(1), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.contains("holds 2 series, choose one with --series: 1: '"), "{err}");
    assert!(!shot.exists());
    let help = String::from_utf8_lossy(&volterra(&["view", "--help"]).stdout).into_owned();
    assert!(help.contains("--series"), "{help}");
    // A scene node on the folder.
    let scene = dir.path().join("s.toml");
    std::fs::write(
        &scene,
        format!(
            "[image]\nwidth = 16\nheight = 16\n[camera]\nposition = [0.0, -300.0, 0.0]\nfocal_point = [0.0, 0.0, 0.0]\n\
             [[node]]\nname = \"mr\"\nkind = \"volume\"\nfile = {:?}\nrenderer = \"reference\"\n",
            folder.display().to_string()
        ),
    )
    .unwrap();
    let o = volterra(&["render", scene.to_str().unwrap(), "-o", dir.path().join("x.exr").to_str().unwrap()]);
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("node 'mr'") && err.contains("give series = N") && !err.contains("--series"), "{err}");
    let listing = err.split("UID: ").nth(1).unwrap_or(&err);
    assert!(listing.starts_with("1: '") && listing.contains(" files of ") && listing.contains("(UID "), "{err}");
}

/// `volterra info` in gdalinfo's terms (a geoscientist's checks): the geotransform, the
/// corners to the millimetre (1e-7° in degrees; 6 significant digits were 25 m off in
/// degrees) followed by their longitude and latitude in gdalinfo's own words, the mean and
/// standard deviation of `gdalinfo -stats`, and "no valid samples" for a raster that has
/// none — on the real geographic DEM and on copies of it in UTM north and south and Web
/// Mercator made by gdal_translate.
#[test]
fn info_reports_a_raster_as_gdalinfo_does() {
    let Some(shared) = common::shared_data() else { return };
    if common::gdal_tool("gdal_translate").is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let dem = shared.join("terrain/pysheds_dem.tif");
    let mut files = vec![dir.path().join("geographic.tif")];
    std::fs::copy(&dem, &files[0]).unwrap();
    for (name, srs, ullr) in [
        ("utm10n.tif", "EPSG:32610", ["500000", "4200030", "501800", "4198830"]),
        ("utm33s.tif", "EPSG:32733", ["612345.5", "7350000.25", "622345.5", "7340000.25"]),
        ("web_mercator.tif", "EPSG:3857", ["-10852000", "3870000", "-10818000", "3836000"]),
    ] {
        let out = dir.path().join(name);
        common::run_ok(Command::new("gdal_translate").args(["-q", "-a_srs", srs, "-a_ullr"]).args(ullr).arg(&dem).arg(&out));
        files.push(out);
    }
    for f in &files {
        let gdal_text = common::run_ok(Command::new("gdalinfo").arg(f));
        // gdalinfo -stats (it keeps them in a .aux.xml, which volterra reads as GDAL does).
        let gdal: serde_json::Value =
            serde_json::from_str(&common::run_ok(Command::new("gdalinfo").args(["-json", "-stats"]).arg(f))).unwrap();
        let o = volterra(&["info", "--json", f.to_str().unwrap()]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let ours: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        let name = f.file_name().unwrap().to_string_lossy();
        for (k, (a, b)) in ours["geotransform"].as_array().unwrap().iter().zip(gdal["geoTransform"].as_array().unwrap()).enumerate() {
            let (a, b) = (a.as_f64().unwrap(), b.as_f64().unwrap());
            assert!((a - b).abs() <= 1e-12 * b.abs().max(1.0), "{name}: geotransform[{k}] {a} vs {b}");
        }
        // wgs84Extent: upper left, lower left, lower right, upper right (7 decimals).
        let extent = &gdal["wgs84Extent"]["coordinates"][0];
        for (k, corner) in ["upper_left", "lower_left", "lower_right", "upper_right"].iter().enumerate() {
            for axis in 0..2 {
                let (a, b) = (ours["corners_lonlat"][corner][axis].as_f64().unwrap(), extent[k][axis].as_f64().unwrap());
                assert!((a - b).abs() <= 6e-8, "{name}: {corner} {a} vs gdalinfo's {b}");
            }
        }
        let md = &gdal["bands"][0]["metadata"][""];
        for (key, gkey) in [("mean", "STATISTICS_MEAN"), ("std_dev", "STATISTICS_STDDEV")] {
            let want: f64 = md[gkey].as_str().unwrap().parse().unwrap();
            let got = ours[key].as_f64().unwrap();
            assert!((got - want).abs() <= 1e-9 * want.abs(), "{name}: {key} {got} vs gdalinfo's {want}");
        }
        // The corner lines as gdalinfo prints them, word for word after the label.
        let text = String::from_utf8_lossy(&volterra(&["info", "--stats", f.to_str().unwrap()]).stdout).into_owned();
        for (gdal_label, our_label) in [("Upper Left", "upper left"), ("Lower Right", "lower right"), ("Center", "centre")] {
            let g = gdal_text.lines().find(|l| l.starts_with(gdal_label)).unwrap()[gdal_label.len()..].trim().to_string();
            let ours = text.lines().find(|l| l.starts_with(our_label)).unwrap()[our_label.len()..].trim().to_string();
            assert_eq!(ours, g, "{name}: {gdal_label}");
        }
        assert!(text.contains("statistics  mean 206.919 m, standard deviation 27.799 m over 131753 valid samples"), "{text}");
    }
    // A raster with no valid sample says so.
    let void = dir.path().join("void.tif");
    volterra_formats::geotiff::write_geotiff(&void, &common::utm_heightfield(8, 6, |_, _| None)).unwrap();
    let text = String::from_utf8_lossy(&volterra(&["info", void.to_str().unwrap()]).stdout).into_owned();
    assert!(text.contains("elevation   no valid samples") && !text.contains("NaN"), "{text}");
    let o = volterra(&["info", "--json", void.to_str().unwrap()]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!((v["valid_count"].as_u64(), v["min"].is_null()), (Some(0), true), "{v}");
}

/// A raster refused for the memory limit says how it would fit: the gdaladdo overviews to
/// add, after which the largest that fits is read (with a note).
#[test]
fn a_raster_too_large_for_the_limit_suggests_the_overviews_that_would_fit() {
    let Some(gdaladdo) = common::gdal_tool("gdaladdo") else { return };
    let dir = tempfile::tempdir().unwrap();
    let dem = dir.path().join("dem.tif");
    common::view_window_dem(&dem); // 1200 × 900 float32: 4.1 MiB
    let limit = volterra_formats::Limits::max(400 << 10);
    let e = volterra_formats::geotiff::read_geotiff(&dem, &limit).unwrap_err().to_string();
    assert!(e.contains("or add overviews — gdaladdo -r average dem.tif 2 4 — and the largest that fits is read"), "{e}");
    common::run_ok(Command::new(gdaladdo).args(["-q", "-r", "average"]).arg(&dem).args(["2", "4"]));
    let hf = volterra_formats::geotiff::read_geotiff(&dem, &limit).unwrap();
    assert_eq!((hf.width, hf.height), (300, 225), "{:?}", hf.notes);
    assert!(hf.notes.iter().any(|n| n.contains("overview")), "{:?}", hf.notes);
}

/// `info` on a DICOM data set that holds no image (an RT plan, a structure set) says so
/// ("no data set at byte 0" and "missing or malformed Rows" before), naming its modality;
/// `--resample` names every gap off the usual and the spacing chosen.
#[test]
fn dicom_without_an_image_and_resampled_gaps_are_said_plainly() {
    let lib = common::repo_path("tests/reference/.venv/lib");
    let plan = std::fs::read_dir(&lib)
        .ok()
        .and_then(|d| d.flatten().map(|e| e.path().join("site-packages/pydicom/data/test_files/rtplan.dcm")).find(|p| p.exists()));
    match plan {
        Some(plan) => {
            let o = volterra(&["info", plan.to_str().unwrap()]);
            let err = String::from_utf8_lossy(&o.stderr);
            assert!(!o.status.success() && err.contains("the data set holds no image") && err.contains("(modality RTPLAN)"), "{err}");
        }
        None if common::under_ci() => panic!("pydicom's rtplan.dcm not found under {} (run tests/setup_venv.py)", lib.display()),
        None => eprintln!("SKIPPED: no reference venv"),
    }
    let o = volterra(&["info", common::repo_path("tests/fixtures/dicom/missing_slice").to_str().unwrap(), "--resample"]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("1 gap off the usual (2.000 mm); resampled to uniform 1.0000 mm spacing (the median gap) over"), "{text}");
}

/// `--max-memory` counts what a GPU whose memory is the host's holds (lavapipe's textures
/// live in the process's memory, allocated by Mesa): a terrain whose textures do not fit is
/// refused before they are made, and one that fits reports a peak that includes them and
/// stays within the limit (before, the report said 27 MiB for a render whose resident
/// memory was 192 MiB, 1.1–1.7× the limit).
#[test]
fn max_memory_counts_the_gpus_textures_where_they_live_in_host_memory() {
    let Some(gpu) = common::gpu() else { return };
    let host = matches!(gpu.info.device_type, wgpu::DeviceType::Cpu | wgpu::DeviceType::IntegratedGpu);
    let dir = tempfile::tempdir().unwrap();
    let n = 2400usize;
    let hf = common::utm_heightfield(n, n, |c, r| Some((300.0 + 50.0 * ((c as f64) / 97.0).sin() * ((r as f64) / 83.0).cos()) as f32));
    volterra_formats::geotiff::write_geotiff(&dir.path().join("dem.tif"), &hf).unwrap();
    let scene = dir.path().join("dem.toml");
    std::fs::write(
        &scene,
        "[image]\nwidth = 160\nheight = 120\n[camera]\nposition = [536000.0, 4100000.0, 40000.0]\nfocal_point = [536000.0, 4164000.0, 300.0]\n\
         [[node]]\nname = \"dem\"\nkind = \"heightfield\"\nfile = \"dem.tif\"\nrenderer = \"terrain\"\n",
    )
    .unwrap();
    let render = |limit: &str| {
        let o = Command::new(common::volterra_bin())
            .args(["--max-memory", limit, "render", scene.to_str().unwrap(), "-o", dir.path().join("t.exr").to_str().unwrap()])
            .output()
            .unwrap();
        (o.status.success(), String::from_utf8_lossy(&o.stderr).into_owned())
    };
    let textures = (n * n * 4) as f64 / (1 << 20) as f64;
    let (ok, err) = render("40M");
    // Refused where the raster's level is chosen, counting all the GPU takes for it.
    assert!(!ok && err.contains("elevation raster, as its renderer holds it, needs"), "{err}");
    let (ok, err) = render("400M");
    assert!(ok, "{err}");
    let line = err.lines().find(|l| l.starts_with("memory: peak")).unwrap().to_string();
    let peak: f64 = line.split_whitespace().nth(2).unwrap().parse().unwrap();
    eprintln!("{line} (heights texture {textures:.1} MiB)");
    assert!(!line.contains("over the limit"), "{line}");
    if host {
        assert!(line.contains("with the GPU"), "{line}");
        assert!(peak > textures, "the peak {peak} MiB leaves out the GPU's {textures:.1} MiB of heights");
    }
}

/// A PNG heightmap has units only where they are given: without a vertical scale its
/// elevations are grey levels, without a cell size its samples are 1 apart without a unit
/// (`info` claimed metres for both); a slope or hillshade of it says its angles mean nothing.
#[test]
fn a_png_heightmap_has_metres_only_where_they_are_given() {
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("dem.png");
    let levels: Vec<u16> = (0..12 * 8).map(|i| (i * 100) as u16).collect();
    volterra_formats::image::write_png_grey16(&png, 12, 8, &levels).unwrap();
    let p = png.to_str().unwrap();
    let text = String::from_utf8_lossy(&volterra(&["info", p]).stdout).into_owned();
    assert!(text.contains("cell size   1 sample × 1 sample\n") && text.contains("elevation   0 .. 9500 grey level\n"), "{text}");
    assert!(!text.contains(" m\n") && !text.contains(" m ×"), "{text}");
    let bare: serde_json::Value = serde_json::from_slice(&volterra(&["info", "--json", p]).stdout).unwrap();
    assert_eq!((bare["cell_size_unit"].as_str(), bare["elevation_unit"].as_str()), (Some("sample"), Some("grey level")));
    // Given both, metres: 0.5 m per level, 25 m cells.
    let o = volterra(&["info", "--json", "--vertical-scale", "0.5", "--cell-size", "25", p]);
    let given: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!((given["cell_size_unit"].as_str(), given["elevation_unit"].as_str()), (Some("m"), Some("m")), "{given}");
    assert_eq!((given["max"].as_f64(), given["cell_size"][0].as_f64()), (Some(4750.0), Some(25.0)));
    // Terrarium is metres by definition; its cells still have no size.
    let rgb = dir.path().join("terrarium.png");
    // R·256 + G + B/256 − 32768: 128, 10, 0 is 10 m.
    let img = volterra_formats::image::RgbImage { width: 3, height: 2, data: [128, 10, 0].repeat(6) };
    volterra_formats::image::write_png_rgb8(&rgb, &img).unwrap();
    let o = volterra(&["info", "--json", "--encoding", "terrarium", rgb.to_str().unwrap()]);
    let t: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(
        (t["cell_size_unit"].as_str(), t["elevation_unit"].as_str(), t["max"].as_f64()),
        (Some("sample"), Some("m"), Some(10.0)),
        "{t}"
    );
    // Slope of unitless numbers: written, with a warning naming what is missing.
    let out = dir.path().join("slope.tif");
    let o = volterra(&["dem", "slope", p, out.to_str().unwrap(), "--cell-size", "25"]);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success() && e.contains("angles mean nothing: its elevations are grey levels (give --vertical-scale"), "{e}");
    let o = volterra(&["dem", "slope", p, out.to_str().unwrap(), "--cell-size", "25", "--vertical-scale", "0.5"]);
    assert!(o.status.success() && !String::from_utf8_lossy(&o.stderr).contains("warning"), "{}", String::from_utf8_lossy(&o.stderr));
}
