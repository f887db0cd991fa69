//! GeoTIFF overviews (issue 20, "DEMs larger than memory allows"): a DEM whose full raster
//! needs more memory than the limit is read from its largest overview that fits. GDAL
//! makes the files (a tiled GeoTIFF with `gdaladdo` overviews, and a Cloud-Optimised
//! GeoTIFF) and is the reference for what an overview holds and where it lies:
//! `gdal_translate -oo OVERVIEW_LEVEL=k` writes overview k as a plain GeoTIFF with the
//! georeferencing GDAL gives it, which must read equal — size, origin, cell size, every
//! elevation and NoData cell — to what `read_geotiff` makes of the overview in place.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;
use volterra_formats::geotiff::read_geotiff;
use volterra_formats::memory::{human_bytes, in_use, Limits};
use volterra_formats::Heightfield;

fn gdal() -> Option<PathBuf> {
    common::gdal_tool("gdal_translate")
}

/// The limits below are the heap in use plus a margin of a few hundred kB: tests of this
/// file run one at a time, so one's allocations never eat another's margin.
fn serial() -> std::sync::MutexGuard<'static, ()> {
    static SERIAL: std::sync::Mutex<()> = std::sync::Mutex::new(());
    SERIAL.lock().unwrap_or_else(|e| e.into_inner())
}

fn run(cmd: &mut Command) {
    let out = cmd.output().unwrap();
    assert!(out.status.success(), "{cmd:?}: {}", String::from_utf8_lossy(&out.stderr));
}

/// 1001 × 703 cells of 30 m in UTM 10N (odd sizes: overviews round up), hills, two NoData
/// holes.
fn dem(path: &Path) -> Heightfield {
    let hf = common::utm_heightfield(1001, 703, |c, r| {
        let (x, y) = (c as f64 * 30.0, r as f64 * 30.0);
        let hole = ((c as f64 - 300.0).powi(2) + (r as f64 - 200.0).powi(2)) < 400.0 || (c > 600 && c < 640 && r > 400 && r < 470);
        (!hole).then(|| (300.0 + 80.0 * (x / 4000.0).sin() * (y / 3000.0).cos() + 0.005 * x) as f32)
    });
    volterra_formats::geotiff::write_geotiff(path, &hf).unwrap();
    hf
}

/// The same grid, cell for cell: size, where it lies, every elevation (bit for bit) and
/// NoData cell.
fn assert_same_grid(ours: &Heightfield, gdal: &Heightfield, what: &str) {
    assert_eq!((ours.width, ours.height), (gdal.width, gdal.height), "{what}: size");
    for k in 0..2 {
        let tol = 1e-9 * gdal.origin[k].abs();
        assert!((ours.origin[k] - gdal.origin[k]).abs() <= tol, "{what}: origin {:?} vs GDAL's {:?}", ours.origin, gdal.origin);
        let tol = 1e-12 * gdal.cell_size_native[k];
        assert!(
            (ours.cell_size_native[k] - gdal.cell_size_native[k]).abs() <= tol,
            "{what}: cells {:?} vs GDAL's {:?}",
            ours.cell_size_native,
            gdal.cell_size_native
        );
    }
    assert_eq!(ours.crs.epsg, gdal.crs.epsg, "{what}: CRS");
    let nodata = |hf: &Heightfield, i: usize| hf.nodata.get(i);
    let mut differ = 0;
    for i in 0..gdal.elevations.len() {
        let same = match (nodata(ours, i), nodata(gdal, i)) {
            (true, true) => true,
            (false, false) => ours.elevations[i].to_bits() == gdal.elevations[i].to_bits(),
            _ => false,
        };
        differ += usize::from(!same);
    }
    assert_eq!(differ, 0, "{what}: {differ} of {} cells differ from GDAL's", gdal.elevations.len());
    assert!(gdal.nodata_count() > 0, "{what}: the holes survive in the overview");
}

#[test]
fn a_dem_beyond_the_memory_limit_is_read_from_its_largest_overview_that_fits_where_gdal_puts_it() {
    let Some(gdal_translate) = gdal() else { return };
    let _serial = serial();
    let dir = tempfile::tempdir().unwrap();
    let plain = dir.path().join("hills.tif");
    let original = dem(&plain);
    // A tiled GeoTIFF with internal overviews at 2 and 4 (averaged, NoData-aware), and a
    // COG (its overviews made by the COG driver, down to one 256-pixel block).
    let tiled = dir.path().join("tiled.tif");
    run(Command::new(&gdal_translate).args(["-q", "-co", "TILED=YES", "-co", "COMPRESS=DEFLATE"]).arg(&plain).arg(&tiled));
    run(Command::new("gdaladdo").args(["-q", "-r", "average"]).arg(&tiled).args(["2", "4"]));
    let cog = dir.path().join("cog.tif");
    run(Command::new(&gdal_translate)
        .args(["-q", "-of", "COG", "-co", "BLOCKSIZE=256", "-co", "RESAMPLING=AVERAGE", "-co", "COMPRESS=LZW"])
        .arg(&plain)
        .arg(&cog));

    // gdaladdo rounds an overview's size up, the COG driver down.
    for (file, overviews, first) in [(&tiled, "501×352, 251×176", "501×352"), (&cog, "500×351, 250×175", "500×351")] {
        let name = file.file_name().unwrap().to_string_lossy().into_owned();
        // Without a limit: the full raster, as written, and its overviews listed for `info`.
        let full = read_geotiff(file, &Limits::default()).unwrap();
        assert_same_grid(&full, &original, &format!("{name}, full"));
        let listed = full.attributes.iter().find(|(k, _)| k == "overviews").map(|(_, v)| v.as_str());
        assert_eq!(listed, Some(overviews), "{name}: overviews listed");
        assert!(!full.notes.iter().any(|n| n.contains("overview")), "{name}: {:?}", full.notes);

        // Room for the first overview (501 × 352 × 4 bytes = 0.7 MB) but not the full
        // raster (2.8 MB): overview 0, where and as GDAL reads it.
        let limit = Limits::max(in_use() + 1_600_000);
        let ov = read_geotiff(file, &limit).unwrap();
        let gdal_ov = dir.path().join(format!("{name}.ov0.tif"));
        run(Command::new(&gdal_translate).args(["-q", "-oo", "OVERVIEW_LEVEL=0"]).arg(file).arg(&gdal_ov));
        let reference = read_geotiff(&gdal_ov, &Limits::default()).unwrap();
        assert_same_grid(&ov, &reference, &format!("{name}, overview 0"));
        // Stated with what the full raster needed (1001 × 703 float32) and the limit.
        let stated = format!(
            "{first} overview ({}) of the 1001×703 raster: the full elevation raster needs {}, more than the memory limit of {}",
            human_bytes(ov.width as u64 * ov.height as u64 * 4),
            human_bytes(1001 * 703 * 4),
            human_bytes(limit.bytes())
        );
        assert!(ov.notes.iter().any(|n| n.contains(&stated)), "{name}: the overview read is stated ({stated}): {:?}", ov.notes);
        // The overview covers the full raster's extent: the same outer corner.
        let corner = |hf: &Heightfield| [hf.origin[0] - 0.5 * hf.cell_size_native[0], hf.origin[1] + 0.5 * hf.cell_size_native[1]];
        assert_eq!(corner(&ov), corner(&original), "{name}: north-west corner");

        // Room for the second overview only (0.18 MB).
        let limit = Limits::max(in_use() + 400_000);
        let ov1 = read_geotiff(file, &limit).unwrap();
        let gdal_ov1 = dir.path().join(format!("{name}.ov1.tif"));
        run(Command::new(&gdal_translate).args(["-q", "-oo", "OVERVIEW_LEVEL=1"]).arg(file).arg(&gdal_ov1));
        assert_same_grid(&ov1, &read_geotiff(&gdal_ov1, &Limits::default()).unwrap(), &format!("{name}, overview 1"));
        // A level asked for is read whatever room there is (the scene's view windows fix
        // the level they placed); one the file lacks, and one that does not fit, refused.
        let level = |k: usize, limits: &Limits| {
            volterra_formats::geotiff::read_geotiff_with(
                file,
                &volterra_formats::geotiff::GeoTiffOptions { level: Some(k), ..Default::default() },
                limits,
            )
        };
        assert_same_grid(&level(2, &Limits::default()).unwrap(), &ov1, &format!("{name}, level 2"));
        assert_same_grid(&level(0, &Limits::default()).unwrap(), &original, &format!("{name}, level 0"));
        let msg = level(3, &Limits::default()).expect_err("no level 3").to_string();
        assert!(msg.contains("level 3") && msg.contains("has 3"), "{msg}");
        let msg = level(1, &limit).expect_err("level 1 does not fit").to_string();
        assert!(msg.contains("memory limit"), "{msg}");

        // Room for none: the full raster's refusal, naming the file.
        let err = read_geotiff(file, &Limits::max(in_use() + 50_000)).expect_err("refused");
        let msg = err.to_string();
        assert!(msg.contains(&name) && msg.contains("elevation raster needs") && msg.contains("memory limit"), "{msg}");
    }
}

#[test]
fn an_extent_reads_the_samples_inside_it_as_gdal_translate_srcwin_does_decoding_only_their_tiles() {
    let Some(gdal_translate) = gdal() else { return };
    let _serial = serial();
    let dir = tempfile::tempdir().unwrap();
    let plain = dir.path().join("hills.tif");
    dem(&plain);
    let tiled = dir.path().join("tiled.tif");
    run(Command::new(&gdal_translate)
        .args(["-q", "-co", "TILED=YES", "-co", "BLOCKXSIZE=128", "-co", "BLOCKYSIZE=64", "-co", "COMPRESS=DEFLATE"])
        .arg(&plain)
        .arg(&tiled));
    let strips = dir.path().join("strips.tif");
    run(Command::new(&gdal_translate).args(["-q", "-co", "BLOCKYSIZE=7"]).arg(&plain).arg(&strips));
    // Sample centres lie at 500015 + 30·c east and 4200015 − 30·r north: this extent holds
    // columns 250..=612 and rows 100..=377 (10 m beyond their centres), the first NoData
    // hole among them, across tile and strip borders.
    let extent = [
        500_015.0 + 250.0 * 30.0 - 10.0,
        4_200_015.0 - 377.0 * 30.0 - 10.0,
        500_015.0 + 612.0 * 30.0 + 10.0,
        4_200_015.0 - 100.0 * 30.0 + 10.0,
    ];
    let opts = volterra_formats::geotiff::GeoTiffOptions { extent: Some(extent), level: None };
    for file in [&plain, &tiled, &strips] {
        let name = file.file_name().unwrap().to_string_lossy().into_owned();
        let ours = volterra_formats::geotiff::read_geotiff_with(file, &opts, &Limits::default()).unwrap();
        let reference = dir.path().join(format!("{name}.srcwin.tif"));
        run(Command::new(&gdal_translate).args(["-q", "-srcwin", "250", "100", "363", "278"]).arg(file).arg(&reference));
        assert_same_grid(&ours, &read_geotiff(&reference, &Limits::default()).unwrap(), &format!("{name}, window"));
        let window = ours.attributes.iter().find(|(k, _)| k == "window").map(|(_, v)| v.as_str());
        assert_eq!(window, Some("columns 250..=612, rows 100..=377"), "{name}");
    }
    // Only the window counts against the limit: 363 × 278 × 4 bytes = 0.4 MB of a 2.8 MB
    // raster.
    let small = Limits::max(in_use() + 600_000);
    let ours = volterra_formats::geotiff::read_geotiff_with(&tiled, &opts, &small).unwrap();
    assert_eq!((ours.width, ours.height), (363, 278));
    assert!(!ours.notes.iter().any(|n| n.contains("overview")), "{:?}", ours.notes);
    // An extent beside the raster: refused, naming the file and the raster's bounds.
    let beside = volterra_formats::geotiff::GeoTiffOptions { extent: Some([0.0, 0.0, 10.0, 10.0]), level: None };
    let msg = volterra_formats::geotiff::read_geotiff_with(&tiled, &beside, &Limits::default()).expect_err("beside").to_string();
    assert!(msg.contains("tiled.tif") && msg.contains("holds no sample") && msg.contains("500000"), "{msg}");

    // The scene key: a heightfield node's `extent`, through the loader.
    let scene = dir.path().join("scene.toml");
    std::fs::write(
        &scene,
        format!(
            "[camera]\nposition = [0.0, -10.0, 10.0]\nfocal_point = [0.0, 0.0, 0.0]\n\n[[node]]\nname = \"dem\"\nkind = \"heightfield\"\nfile = \"tiled.tif\"\nextent = [{}, {}, {}, {}]\n",
            extent[0], extent[1], extent[2], extent[3]
        ),
    )
    .unwrap();
    let scene = volterra::scene::Scene::load(&scene, &[]).unwrap();
    let hf = scene.heightfield(0).unwrap();
    assert_eq!((hf.width, hf.height, hf.origin), (363, 278, [500_015.0 + 250.0 * 30.0, 4_200_015.0 - 100.0 * 30.0]));
}

/// A drape (an orthophoto, a classified band) larger than the memory limit allows is read
/// from its largest overview that fits, where GDAL puts it: an RGB GeoTIFF with `gdaladdo`
/// overviews and a float32 band in a COG, each equal — size, corner, pixel size, every
/// byte or value and NoData — to what `gdal_translate -oo OVERVIEW_LEVEL=0` writes.
#[test]
fn a_drape_beyond_the_memory_limit_is_read_from_its_largest_overview_that_fits() {
    use volterra_formats::geotiff::{read_geotiff_image, GeoImage, GeoPixels};
    let Some(gdal_translate) = gdal() else { return };
    let _serial = serial();
    let dir = tempfile::tempdir().unwrap();
    let plain = dir.path().join("hills.tif");
    dem(&plain);
    // RGB bytes: the elevations scaled to 0..255 in three bands (NoData 0), tiled, with
    // overviews at 2 and 4.
    let rgb = dir.path().join("rgb.tif");
    run(Command::new(&gdal_translate)
        .args(["-q", "-ot", "Byte", "-scale", "250", "420", "1", "255", "-a_nodata", "none", "-b", "1", "-b", "1", "-b", "1"])
        .args(["-co", "TILED=YES", "-co", "PHOTOMETRIC=RGB", "-co", "INTERLEAVE=PIXEL"])
        .arg(&plain)
        .arg(&rgb));
    // GDAL's band-interleaved layout (its choice here without INTERLEAVE=PIXEL) is refused
    // by name, not read as its first plane.
    let planes = dir.path().join("rgb_planes.tif");
    run(Command::new(&gdal_translate).args(["-q", "-co", "INTERLEAVE=BAND"]).arg(&rgb).arg(&planes));
    let err = read_geotiff_image(&planes, &Limits::default()).map(|_| ()).expect_err("band-interleaved RGB refused");
    assert!(err.to_string().contains("rgb_planes.tif") && err.to_string().contains("INTERLEAVE=PIXEL"), "{err}");
    run(Command::new("gdaladdo").args(["-q", "-r", "nearest"]).arg(&rgb).args(["2", "4"]));
    let band = dir.path().join("band_cog.tif");
    run(Command::new(&gdal_translate)
        .args(["-q", "-of", "COG", "-co", "BLOCKSIZE=256", "-co", "RESAMPLING=AVERAGE", "-co", "COMPRESS=LZW"])
        .arg(&plain)
        .arg(&band));
    let same = |ours: &GeoImage, gdal: &GeoImage, what: &str| {
        assert_eq!((ours.width, ours.height), (gdal.width, gdal.height), "{what}: size");
        for k in 0..2 {
            assert!(
                (ours.origin[k] - gdal.origin[k]).abs() <= 1e-9 * gdal.origin[k].abs(),
                "{what}: origin {:?} vs {:?}",
                ours.origin,
                gdal.origin
            );
            let cells = (ours.cell_size_native[k], gdal.cell_size_native[k]);
            assert!((cells.0 - cells.1).abs() <= 1e-12 * cells.1, "{what}: pixel size {cells:?}");
        }
        match (&ours.pixels, &gdal.pixels) {
            (GeoPixels::Rgb8(a), GeoPixels::Rgb8(b)) => assert!(a == b, "{what}: bytes differ"),
            (GeoPixels::Values(a), GeoPixels::Values(b)) => {
                let differ = a.iter().zip(b).filter(|(p, q)| !(p.to_bits() == q.to_bits() || p.is_nan() && q.is_nan())).count();
                assert_eq!(differ, 0, "{what}: {differ} values differ");
                assert!(b.iter().any(|v| v.is_nan()), "{what}: NoData survives");
            }
            _ => panic!("{what}: different pixel kinds"),
        }
    };
    // RGB: 1001 × 703 × 3 bytes (2.1 MB) full, 501 × 352 × 3 (0.53 MB) at overview 0.
    // Band: 12 bytes a pixel (float32 decoded, f64 kept): 8.4 MB full, 2.1 MB at 500 × 351.
    for (file, margin, first) in [(&rgb, 1_000_000, "501×352"), (&band, 3_000_000, "500×351")] {
        let name = file.file_name().unwrap().to_string_lossy().into_owned();
        let full = read_geotiff_image(file, &Limits::default()).unwrap();
        assert_eq!((full.width, full.height), (1001, 703), "{name}: full image without a limit");
        let ov = read_geotiff_image(file, &Limits::max(in_use() + margin)).unwrap();
        let gdal_ov = dir.path().join(format!("{name}.ov0.tif"));
        run(Command::new(&gdal_translate).args(["-q", "-oo", "OVERVIEW_LEVEL=0"]).arg(file).arg(&gdal_ov));
        same(&ov, &read_geotiff_image(&gdal_ov, &Limits::default()).unwrap(), &format!("{name}, overview 0"));
        assert!(
            ov.notes.iter().any(|n| n.contains(&format!("{first} overview (")) && n.contains("the full draped image needs")),
            "{name}: {:?}",
            ov.notes
        );
        let err = read_geotiff_image(file, &Limits::max(in_use() + 20_000)).map(|_| ()).expect_err("no level fits");
        assert!(err.to_string().contains("draped image needs"), "{err}");
    }
}

/// The same elevation bit for bit, or both NoData (NaN).
fn same_sample(a: f32, b: f32) -> bool {
    a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan())
}

/// Every sample of `rows` read row by row — south to north in column bands that cut across
/// tiles, then north to south whole — equals `held`'s, bit for bit, NoData as NaN; where
/// they lie, and what `info` says of the file, too.
fn assert_rows_read_as_held(rows: &volterra_formats::geotiff_rows::GeoTiffRows, held: &Heightfield, what: &str) {
    let g = rows.georef();
    assert_eq!(g, &held.georef(), "{what}: georeferencing");
    assert_eq!(rows.attributes, held.attributes, "{what}: attributes");
    assert_eq!(rows.nodata_value, held.nodata_value, "{what}: NoData value");
    let expected = |r: usize, c: usize| if held.is_nodata(c, r) { f32::NAN } else { held.elevations[r * held.width + c] };
    let (mut differ, mut voids) = (0, 0);
    let band = 100;
    for c0 in (0..g.width).step_by(band) {
        let mut out = vec![0f32; band.min(g.width - c0)];
        for r in (0..g.height).rev() {
            rows.read_row(r, c0, &mut out);
            for (k, z) in out.iter().enumerate() {
                differ += usize::from(!same_sample(*z, expected(r, c0 + k)));
                voids += usize::from(z.is_nan());
            }
        }
    }
    let mut out = vec![0f32; g.width];
    for r in 0..g.height {
        rows.read_row(r, 0, &mut out);
        for (c, z) in out.iter().enumerate() {
            differ += usize::from(!same_sample(*z, expected(r, c)));
        }
    }
    assert_eq!(differ, 0, "{what}: samples read by rows that differ from the raster read whole");
    assert_eq!(voids, held.nodata_count(), "{what}: NoData samples");
    assert_eq!(rows.failure(), None, "{what}");
}

/// A GeoTIFF read row by row (`GeoTiffRows`, what the GPU ray-caster's textures are filled
/// from, so a DEM is held once) reads as the raster read whole: stripped, tiled and COG
/// files, float32 and int16 with NoData, whole, by extent and from an overview when the
/// full raster's GPU bytes exceed the limit; a tile that fails to decode reads as NoData
/// and is reported, naming the file.
#[test]
fn rows_read_by_windows_of_tiles_equal_the_raster_read_whole() {
    use volterra_formats::geotiff::{read_geotiff_with, GeoTiffOptions};
    use volterra_formats::geotiff_rows::GeoTiffRows;
    let Some(gdal_translate) = gdal() else { return };
    let _serial = serial();
    let dir = tempfile::tempdir().unwrap();
    let plain = dir.path().join("hills.tif");
    dem(&plain);
    let tiled = dir.path().join("tiled.tif");
    run(Command::new(&gdal_translate)
        .args(["-q", "-co", "TILED=YES", "-co", "BLOCKXSIZE=128", "-co", "BLOCKYSIZE=64", "-co", "COMPRESS=DEFLATE"])
        .arg(&plain)
        .arg(&tiled));
    run(Command::new("gdaladdo").args(["-q", "-r", "average"]).arg(&tiled).args(["2", "4"]));
    let strips = dir.path().join("strips.tif");
    run(Command::new(&gdal_translate).args(["-q", "-co", "BLOCKYSIZE=7"]).arg(&plain).arg(&strips));
    let int16 = dir.path().join("int16.tif");
    run(Command::new(&gdal_translate).args(["-q", "-ot", "Int16", "-co", "TILED=YES", "-co", "COMPRESS=LZW"]).arg(&plain).arg(&int16));
    let cog = dir.path().join("cog.tif");
    run(Command::new(&gdal_translate).args(["-q", "-of", "COG", "-co", "BLOCKSIZE=256", "-co", "COMPRESS=ZSTD"]).arg(&plain).arg(&cog));
    let whole = GeoTiffOptions::default();
    // Columns 250..=612, rows 100..=377 (see the extent test).
    let extent = GeoTiffOptions {
        extent: Some([
            500_015.0 + 250.0 * 30.0 - 10.0,
            4_200_015.0 - 377.0 * 30.0 - 10.0,
            500_015.0 + 612.0 * 30.0 + 10.0,
            4_200_015.0 - 100.0 * 30.0 + 10.0,
        ]),
        ..GeoTiffOptions::default()
    };
    for file in [&plain, &tiled, &strips, &int16, &cog] {
        let name = file.file_name().unwrap().to_string_lossy().into_owned();
        for (opts, part) in [(&whole, "whole"), (&extent, "extent")] {
            let rows = GeoTiffRows::open(file, opts, &Limits::default(), 5).unwrap();
            let held = read_geotiff_with(file, opts, &Limits::default()).unwrap();
            assert_rows_read_as_held(&rows, &held, &format!("{name}, {part}"));
        }
    }
    // The limit counts the bytes the caller holds a sample (5 for the GPU's textures):
    // room for the first overview's (501 × 352 × 5 = 0.9 MB) and one row of tiles, not the
    // full raster's (3.5 MB): overview 0, as GDAL writes it.
    let limit = Limits::max(in_use() + 1_500_000);
    let rows = GeoTiffRows::open(&tiled, &whole, &limit, 5).unwrap();
    let gdal_ov = dir.path().join("tiled.ov0.tif");
    run(Command::new(&gdal_translate).args(["-q", "-oo", "OVERVIEW_LEVEL=0"]).arg(&tiled).arg(&gdal_ov));
    let reference = read_geotiff(&gdal_ov, &Limits::default()).unwrap();
    assert_eq!(rows.georef(), &reference.georef(), "overview 0: where it lies");
    assert!(rows.notes.iter().any(|n| n.contains("501×352 overview")), "{:?}", rows.notes);
    let mut out = vec![0f32; 501];
    let mut differ = 0;
    for r in 0..352 {
        rows.read_row(r, 0, &mut out);
        differ += (0..501).filter(|&c| !same_sample(out[c], reference.elevations[r * 501 + c])).count();
    }
    assert_eq!(differ, 0, "overview 0, read by rows");

    // Through a scene: the GPU ray-caster draws the overview the rows come from, and its
    // frame says so. Its level is chosen by all the GPU takes — textures, the upload's
    // staging, the driver's memory — so the limit leaves room for overview 0's, not the
    // full raster's.
    if common::gpu().is_some() {
        let room = volterra::render::terrain::gpu_held_bytes(501 * 352) + 300_000;
        assert!(room < volterra::render::terrain::gpu_held_bytes(1001 * 704));
        let scene = dir.path().join("tiled.toml");
        std::fs::write(
            &scene,
            "[image]\nwidth = 64\nheight = 48\n\n[camera]\nposition = [-3000.0, -3000.0, 9000.0]\nfocal_point = [15000.0, 10500.0, 300.0]\n\n[[node]]\nname = \"dem\"\nkind = \"heightfield\"\nfile = \"tiled.tif\"\nrenderer = \"terrain\"\n",
        )
        .unwrap();
        let scene = volterra::scene::Scene::load(&scene, &[]).unwrap().with_limits(Limits::max(in_use() + room));
        let frame = volterra::render::render_scene(&scene, None).unwrap();
        assert!(frame.depth.iter().any(|d| d.is_finite()), "the terrain is drawn");
        assert!(!scene.is_loaded(0), "read by rows");
        assert!(frame.stats.notes.iter().any(|n| n.contains("node 'dem'") && n.contains("501×352 overview")), "{:?}", frame.stats.notes);
    }

    // One tile's compressed bytes overwritten: opening reads no tile; reading reads its
    // samples as NoData and says which file failed.
    let broken = dir.path().join("broken.tif");
    std::fs::copy(&tiled, &broken).unwrap();
    let (offset, count) = {
        let mut d = tiff::decoder::Decoder::new(std::fs::File::open(&broken).unwrap()).unwrap();
        let offsets = d.get_tag_u64_vec(tiff::tags::Tag::TileOffsets).unwrap();
        let counts = d.get_tag_u64_vec(tiff::tags::Tag::TileByteCounts).unwrap();
        (offsets[9], counts[9])
    };
    let mut bytes = std::fs::read(&broken).unwrap();
    bytes[offset as usize..(offset + count) as usize].fill(0xA5);
    std::fs::write(&broken, &bytes).unwrap();
    let rows = GeoTiffRows::open(&broken, &whole, &Limits::default(), 5).unwrap();
    assert_eq!(rows.failure(), None);
    // Tile 9: columns 128..256 of rows 64..128 (8 tiles of 128 across 1001 columns).
    let mut out = vec![0f32; 1001];
    rows.read_row(70, 0, &mut out);
    assert!(out[128..256].iter().all(|z| z.is_nan()) && out[..128].iter().all(|z| z.is_finite()), "the broken tile reads as NoData");
    let why = rows.failure().expect("the failure is kept");
    assert!(why.contains("broken.tif"), "{why}");

    // The command line on the broken file: each command fails naming it, at the broken
    // tile's row (contours: in the range pass), and leaves no output.
    for args in [
        &["dem", "contours", "--interval", "5"][..],
        &["dem", "contours", "--levels", "100,200", "--polygons"],
        &["dem", "hillshade"],
        &["convert"],
        &["info"],
    ] {
        let out_file = dir.path().join(if args[0] == "dem" && args[1] == "contours" { "broken.geojson" } else { "broken_out.tif" });
        let mut cmd = Command::new(common::volterra_bin());
        cmd.args(args).arg(&broken);
        if args[0] != "info" {
            cmd.arg(&out_file);
        }
        let result = cmd.output().unwrap();
        let stderr = String::from_utf8_lossy(&result.stderr);
        assert!(!result.status.success(), "{args:?} succeeded");
        assert!(stderr.matches("broken.tif").count() == 1 && stderr.lines().count() <= 3, "{args:?}: {stderr}");
        assert!(!out_file.exists(), "{args:?} left {}", out_file.display());
    }
}
