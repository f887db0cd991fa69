//! GeoTIFFs as GDAL compresses them read as their uncompressed copies do: every sample
//! type a DEM comes in, tiled and in strips, LZW, Deflate and ZSTD, with each predictor
//! GDAL offers for the type, little- and big-endian — whole, by window and row by row.
//! The tiff crate fails some valid LZW tiles ("no lzw end code found", image-tiff#395:
//! int16 DEMs tiled with PREDICTOR=2, byte rasters' tiles); `formats::tiff_lzw` decodes
//! those, and this test is where a file it decodes wrongly would show.

mod common;

use std::path::Path;
use std::process::Command;
use volterra_formats::geotiff::{read_geotiff, read_geotiff_with, GeoTiffOptions};
use volterra_formats::geotiff_rows::GeoTiffRows;
use volterra_formats::memory::Limits;
use volterra_formats::Heightfield;

fn translate(gdal: &Path, args: &[&str], from: &Path, to: &Path) {
    let out = Command::new(gdal).arg("-q").args(args).arg(from).arg(to).output().unwrap();
    assert!(out.status.success(), "gdal_translate {args:?}: {}", String::from_utf8_lossy(&out.stderr));
}

/// Bit for bit, or both NoData.
fn same(a: f32, b: f32) -> bool {
    a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan())
}

fn differing(a: &Heightfield, b: &Heightfield) -> usize {
    assert_eq!((a.width, a.height, a.origin, a.nodata_count()), (b.width, b.height, b.origin, b.nodata_count()));
    a.elevations.iter().zip(&b.elevations).filter(|(x, y)| !same(**x, **y)).count()
}

#[test]
fn compressed_geotiffs_read_as_their_uncompressed_copies() {
    let Some(gdal) = common::gdal_tool("gdal_translate") else { return };
    let dir = tempfile::tempdir().unwrap();
    // 1001 × 703 cells of 30 m: hills from 150 to 450 m (beyond a byte's range, clipped by
    // GDAL alike in both copies), a NoData hole, and a flat corner (tiles that compress to
    // almost nothing are the ones the tiff crate's LZW fails).
    let hf = common::utm_heightfield(1001, 703, |c, r| {
        let (x, y) = (c as f64 * 30.0, r as f64 * 30.0);
        let hole = (c as f64 - 300.0).powi(2) + (r as f64 - 200.0).powi(2) < 400.0;
        let flat = c > 800 && r > 500;
        (!hole).then(|| if flat { 200.0 } else { (300.0 + 150.0 * (x / 4000.0).sin() * (y / 3000.0).cos()) as f32 })
    });
    let source = dir.path().join("source.tif");
    volterra_formats::geotiff::write_geotiff(&source, &hf).unwrap();
    let window = GeoTiffOptions {
        extent: Some([
            500_015.0 + 250.0 * 30.0 - 10.0,
            4_200_015.0 - 650.0 * 30.0 - 10.0,
            500_015.0 + 950.0 * 30.0,
            4_200_015.0 - 100.0 * 30.0,
        ]),
        ..GeoTiffOptions::default()
    };
    let (mut files, mut lzw_failures_mended) = (0, 0);
    for ty in ["Byte", "Int16", "UInt16", "Int32", "Float32", "Float64"] {
        let float = ty.starts_with("Float");
        let reference = dir.path().join(format!("{ty}.none.tif"));
        translate(&gdal, &["-ot", ty, "-co", "COMPRESS=NONE"], &source, &reference);
        let expected = read_geotiff(&reference, &Limits::default()).unwrap();
        let expected_window = read_geotiff_with(&reference, &window, &Limits::default()).unwrap();
        for compress in ["LZW", "DEFLATE", "ZSTD"] {
            for predictor in ["1", "2", "3"] {
                // GDAL offers the floating-point predictor for floats only; GDAL itself
                // reads its big-endian floating-point-predicted files as garbage (checked:
                // gdalinfo -stats gives ±3.4e38), so those are not a reference.
                if predictor == "3" && !float {
                    continue;
                }
                for (layout, endian) in [("TILED=YES", "LITTLE"), ("BLOCKYSIZE=16", "LITTLE"), ("TILED=YES", "BIG")] {
                    if predictor == "3" && endian == "BIG" {
                        continue;
                    }
                    let what = format!("{ty} {compress} predictor {predictor} {layout} {endian}");
                    let file = dir.path().join(format!("{ty}.{compress}.{predictor}.{}.{endian}.tif", layout.len()));
                    let (c, p, e) = (format!("COMPRESS={compress}"), format!("PREDICTOR={predictor}"), format!("ENDIANNESS={endian}"));
                    translate(&gdal, &["-ot", ty, "-co", &c, "-co", &p, "-co", layout, "-co", &e], &source, &file);
                    files += 1;
                    // Whether the tiff crate alone decodes it (what `tiff_lzw` mends).
                    let crate_alone = tiff::decoder::Decoder::new(std::fs::File::open(&file).unwrap()).unwrap().read_image().is_ok();
                    lzw_failures_mended += usize::from(!crate_alone);
                    assert!(crate_alone || compress == "LZW", "{what}: the tiff crate fails it");
                    let whole = read_geotiff(&file, &Limits::default()).unwrap_or_else(|e| panic!("{what}: {e}"));
                    assert_eq!(differing(&whole, &expected), 0, "{what}: whole");
                    let part = read_geotiff_with(&file, &window, &Limits::default()).unwrap();
                    assert_eq!(differing(&part, &expected_window), 0, "{what}: window");
                    let rows = GeoTiffRows::open(&file, &GeoTiffOptions::default(), &Limits::default(), 5).unwrap();
                    let mut row = vec![0f32; 1001];
                    let mut differ = 0;
                    for r in (0..703).rev() {
                        rows.read_row(r, 0, &mut row);
                        differ += (0..1001).filter(|&c| !same(row[c], expected.elevations[r * 1001 + c])).count();
                    }
                    assert_eq!((differ, rows.failure()), (0, None), "{what}: rows");
                }
            }
        }
    }
    eprintln!("{files} files read as their uncompressed copies; {lzw_failures_mended} of them the tiff crate fails alone");
    // One the crate fails, with a tile's bytes overwritten: a one-line error naming the
    // file, whole or by rows, never a panic.
    let file = dir.path().join("Int16.LZW.2.9.LITTLE.tif");
    let broken = dir.path().join("broken.tif");
    let mut bytes = std::fs::read(&file).unwrap();
    let (offset, count) = {
        let mut d = tiff::decoder::Decoder::new(std::fs::File::open(&file).unwrap()).unwrap();
        (d.get_tag_u64_vec(tiff::tags::Tag::TileOffsets).unwrap()[5], d.get_tag_u64_vec(tiff::tags::Tag::TileByteCounts).unwrap()[5])
    };
    bytes[offset as usize..(offset + count) as usize].fill(0xFF);
    std::fs::write(&broken, &bytes).unwrap();
    let e = read_geotiff(&broken, &Limits::default()).expect_err("a broken tile").to_string();
    assert!(e.contains("broken.tif") && !e.contains('\n'), "{e}");
    let rows = GeoTiffRows::open(&broken, &GeoTiffOptions::default(), &Limits::default(), 5).unwrap();
    let mut row = vec![0f32; 1001];
    (0..703).for_each(|r| rows.read_row(r, 0, &mut row));
    assert!(rows.failure().is_some_and(|e| e.contains("broken.tif")));
    // The workaround is exercised: were the crate mended, this would say so.
    assert!(lzw_failures_mended > 0, "the tiff crate now decodes every LZW file: tiff_lzw may be retired");
}

/// Drapes likewise: RGB, RGBA and one-band byte GeoTIFFs, tiled with LZW (with and without
/// PREDICTOR=2), read as their uncompressed copies — every byte, where they lie.
#[test]
fn compressed_drapes_read_as_their_uncompressed_copies() {
    use volterra_formats::geotiff::{read_geotiff_image, GeoPixels};
    let Some(gdal) = common::gdal_tool("gdal_translate") else { return };
    let dir = tempfile::tempdir().unwrap();
    // Elevations of 150..450 m scaled to bytes, the flat corner included.
    let hf = common::utm_heightfield(1001, 703, |c, r| {
        let (x, y) = (c as f64 * 30.0, r as f64 * 30.0);
        Some(if c > 800 && r > 500 { 200.0 } else { (300.0 + 150.0 * (x / 4000.0).sin() * (y / 3000.0).cos()) as f32 })
    });
    let source = dir.path().join("source.tif");
    volterra_formats::geotiff::write_geotiff(&source, &hf).unwrap();
    let bytes = |img: &volterra_formats::geotiff::GeoImage| match &img.pixels {
        GeoPixels::Rgb8(v) | GeoPixels::Rgba8(v) => v.clone(),
        GeoPixels::Values(v) => v.iter().map(|x| *x as u8).collect(),
    };
    let mut crate_fails = 0;
    for (bands, photometric) in [
        (vec!["-b", "1", "-b", "1", "-b", "1"], "RGB"),
        (vec!["-b", "1", "-b", "1", "-b", "1", "-b", "1"], "RGB"),
        (vec!["-b", "1"], "MINISBLACK"),
    ] {
        let mut common_args: Vec<&str> = ["-ot", "Byte", "-scale", "150", "450", "0", "255", "-co", "INTERLEAVE=PIXEL"]
            .into_iter()
            .chain(bands.iter().copied())
            .collect();
        if bands.len() / 2 == 4 {
            common_args.extend(["-co", "ALPHA=YES"]);
        }
        let plain = dir.path().join(format!("{}.none.tif", bands.len() / 2));
        translate(&gdal, &[common_args.clone(), vec!["-co", "COMPRESS=NONE"]].concat(), &source, &plain);
        let expected = read_geotiff_image(&plain, &Limits::default()).unwrap();
        for predictor in ["PREDICTOR=1", "PREDICTOR=2"] {
            let file = dir.path().join(format!("{}.{predictor}.tif", bands.len() / 2));
            let ph = format!("PHOTOMETRIC={photometric}");
            let args = [common_args.clone(), vec!["-co", "TILED=YES", "-co", "COMPRESS=LZW", "-co", predictor, "-co", &ph]].concat();
            translate(&gdal, &args, &source, &file);
            crate_fails += usize::from(tiff::decoder::Decoder::new(std::fs::File::open(&file).unwrap()).unwrap().read_image().is_err());
            let got =
                read_geotiff_image(&file, &Limits::default()).unwrap_or_else(|e| panic!("{} bands, {predictor}: {e}", bands.len() / 2));
            assert_eq!(
                (got.width, got.height, got.origin, got.cell_size_native),
                (expected.width, expected.height, expected.origin, expected.cell_size_native)
            );
            assert!(bytes(&got) == bytes(&expected), "{} bands, {predictor}: pixels differ", bands.len() / 2);
        }
    }
    assert!(crate_fails > 0, "the tiff crate now decodes every drape here: tiff_lzw may be retired");
}
