//! GeoTIFFs georeferenced by the files GDAL reads beside them: `gdal_translate -co
//! PROFILE=BASELINE -co TFW=YES` (a plain TIFF, a `.tfw`, an `.aux.xml` with the CRS and
//! NoData), a world file under each of its names, a PAM file overriding the GeoTIFF's own
//! tags, a world file that does not (GDAL's order: PAM, the tags, the world file), and an
//! ESRI `.prj` (which GDAL does not read beside a GeoTIFF: read, with a note). What
//! `volterra info` says of the grid — size, geotransform, CRS, NoData — must be what
//! gdalinfo says, on the real geographic DEM in `../shared/data` and a projected one
//! written here; and the DEM products of the BASELINE copy equal gdaldem's (before, its
//! cells were taken as 1 m: slope's median was 85° where gdaldem's is 22°).

mod common;

use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::process::Command;

/// What gdalinfo says of the grid: size, geotransform, EPSG code (None without a CRS) and
/// band 1's NoData value.
fn gdalinfo(path: &Path) -> Value {
    let info: Value = serde_json::from_str(&common::run_ok(Command::new("gdalinfo").arg("-json").arg(path))).unwrap();
    let epsg = info["coordinateSystem"]["wkt"].as_str().and_then(common::wkt_epsg);
    json!({
        "size": info["size"],
        "geoTransform": info["geoTransform"],
        "epsg": epsg,
        "noDataValue": info["bands"][0]["noDataValue"],
    })
}

/// `volterra info --json`, or its one-line error.
fn volterra_info(path: &Path) -> Result<Value, String> {
    let out = Command::new(common::volterra_bin()).args(["info", "--json"]).arg(path).output().unwrap();
    if !out.status.success() {
        return Err(String::from_utf8_lossy(&out.stderr).trim().to_string());
    }
    Ok(serde_json::from_slice(&out.stdout).unwrap())
}

/// Ours in gdalinfo's terms: the geotransform from the centre of the north-west sample and
/// the cells; the EPSG code as GDAL's WKT names it.
fn as_gdal(info: &Value) -> Value {
    let (o, c) = (&info["origin"], &info["cell_size_native"]);
    let (ox, oy, sx, sy) = (o[0].as_f64().unwrap(), o[1].as_f64().unwrap(), c[0].as_f64().unwrap(), c[1].as_f64().unwrap());
    json!({
        "size": info["dims"],
        "geoTransform": [ox - 0.5 * sx, sx, 0.0, oy + 0.5 * sy, 0.0, -sy],
        "epsg": info["epsg"].as_u64().map(|e| format!("ID[\"EPSG\",{e}")),
        "noDataValue": info["nodata_value"],
    })
}

/// The geotransforms within rounding (ours is the centre's, half a cell from the corner),
/// everything else equal.
fn assert_same_grid(tag: &str, ours: &Value, gdal: &Value) {
    let (a, b) = (ours["geoTransform"].as_array().unwrap(), gdal["geoTransform"].as_array().unwrap());
    for (k, (x, y)) in a.iter().zip(b).enumerate() {
        let (x, y) = (x.as_f64().unwrap(), y.as_f64().unwrap());
        assert!((x - y).abs() <= 1e-12 * y.abs().max(1.0), "{tag}: geotransform[{k}] {x} where gdalinfo has {y}");
    }
    for key in ["size", "epsg", "noDataValue"] {
        assert_eq!(ours[key], gdal[key], "{tag}: {key}");
    }
}

/// A copy of `dem` in `dir` under `name` written by gdal_translate with `args`.
fn translate(dem: &Path, dir: &Path, name: &str, args: &[&str]) -> PathBuf {
    let out = dir.join(name);
    common::run_ok(Command::new("gdal_translate").arg("-q").args(args).arg(dem).arg(&out));
    out
}

/// The WKT GDAL writes for an EPSG code, in `form` (gdalsrsinfo -o: wkt1, wkt_esri, wkt2).
fn srs_wkt(epsg: u32, form: &str) -> String {
    common::run_ok(Command::new("gdalsrsinfo").args(["-o", form, &format!("EPSG:{epsg}")])).trim().to_string()
}

/// Every sidecar arrangement on `dem` (in CRS `epsg`): ours as gdalinfo, or refused where
/// GDAL finds no CRS. Returns the cases compared with gdalinfo.
fn compare_sidecars(dem: &Path, epsg: u32, dir: &Path) -> usize {
    let mut compared = 0;
    let mut check = |tag: &str, path: &Path| {
        let ours = volterra_info(path).unwrap_or_else(|e| panic!("{tag}: {e}"));
        let gdal = gdalinfo(path);
        eprintln!("{tag}: ours {} gdalinfo {gdal}", as_gdal(&ours));
        assert_same_grid(tag, &as_gdal(&ours), &gdal);
        compared += 1;
        ours
    };
    // The BASELINE profile: the geotransform in the .tfw and the .aux.xml, CRS and NoData in
    // the .aux.xml alone.
    let baseline = translate(dem, dir, "baseline.tif", &["-co", "PROFILE=BASELINE", "-co", "TFW=YES"]);
    assert!(dir.join("baseline.tfw").exists() && dir.join("baseline.tif.aux.xml").exists());
    let info = check("baseline", &baseline);
    assert!(info["attributes"]["crs from"].as_str().unwrap().contains("baseline.tif.aux.xml"), "{info}");
    // A world file alone, under each name GDAL looks for (and in upper case), with the CRS
    // from a PAM file that holds only the CRS: the world file's geotransform.
    let pam_srs_only = format!("<PAMDataset>\n  <SRS>{}</SRS>\n</PAMDataset>\n", srs_wkt(epsg, "wkt1").replace('"', "&quot;"));
    let plain = translate(dem, dir, "plain.tif", &["-co", "PROFILE=BASELINE"]);
    let tfw = std::fs::read_to_string(baseline.with_extension("tfw")).unwrap();
    for world in ["tfw", "tifw", "wld", "TFW"] {
        let sub = dir.join(world);
        std::fs::create_dir_all(&sub).unwrap();
        let raster = sub.join("dem.tif");
        std::fs::copy(&plain, &raster).unwrap();
        std::fs::write(raster.with_extension(world), &tfw).unwrap();
        std::fs::write(sub.join("dem.tif.aux.xml"), &pam_srs_only).unwrap();
        let info = check(&format!("world file .{world}"), &raster);
        assert!(info["attributes"]["georef from"].as_str().unwrap().contains(&format!("dem.{world}")), "{info}");
        // Without any CRS, GDAL reports the geotransform and no CRS: refused, since the
        // cells' units are unknown — never taken as metres silently.
        std::fs::remove_file(sub.join("dem.tif.aux.xml")).unwrap();
        assert_eq!(gdalinfo(&raster)["epsg"], Value::Null);
        let err = volterra_info(&raster).unwrap_err();
        assert!(err.contains(&format!("dem.{world}")) && err.contains("no CRS"), "{world}: {err}");
        // An ESRI .prj: GDAL ignores it beside a GeoTIFF; ours reads it, with a note.
        std::fs::write(raster.with_extension("prj"), srs_wkt(epsg, "wkt1")).unwrap();
        assert_eq!(gdalinfo(&raster)["epsg"], Value::Null);
        let info = volterra_info(&raster).unwrap();
        assert_eq!(info["epsg"].as_u64(), Some(epsg as u64), "{info}");
        assert!(info["notes"].to_string().contains("GDAL does not read a .prj"), "{info}");
        let mut gdal = gdalinfo(&raster);
        gdal["epsg"] = json!(format!("ID[\"EPSG\",{epsg}"));
        assert_same_grid(&format!("world file .{world} + .prj"), &as_gdal(&info), &gdal);
        std::fs::remove_file(raster.with_extension(world)).unwrap();
    }
    // The ESRI flavour of a .prj names no EPSG code: the CRS's kind still read.
    let esri = dir.join("esri");
    std::fs::create_dir_all(&esri).unwrap();
    std::fs::copy(&plain, esri.join("dem.tif")).unwrap();
    std::fs::write(esri.join("dem.tfw"), &tfw).unwrap();
    std::fs::write(esri.join("dem.prj"), srs_wkt(epsg, "wkt_esri")).unwrap();
    let info = volterra_info(&esri.join("dem.tif")).unwrap();
    assert_eq!(info["geographic"].as_bool(), Some(epsg == 4326), "{info}");
    // The GeoTIFF's own tags come before a world file: a contradicting one is not read.
    let internal = dir.join("internal");
    std::fs::create_dir_all(&internal).unwrap();
    let tagged = internal.join("dem.tif");
    std::fs::copy(dem, &tagged).unwrap();
    std::fs::write(tagged.with_extension("tfw"), "2\n0\n0\n-2\n1001\n4999\n").unwrap();
    check("tags before a world file", &tagged);
    // A PAM file comes before the tags: its geotransform and NoData are read.
    let gt = if epsg == 4326 { [-97.0, 0.001, 0.0, 33.0, 0.0, -0.001] } else { [1000.0, 2.0, 0.0, 5000.0, 0.0, -2.0] };
    let gt_text: Vec<String> = gt.iter().map(|v| v.to_string()).collect();
    std::fs::write(
        internal.join("dem.tif.aux.xml"),
        format!(
            "<PAMDataset><GeoTransform>{}</GeoTransform>\
             <PAMRasterBand band=\"1\"><NoDataValue>147</NoDataValue></PAMRasterBand></PAMDataset>",
            gt_text.join(", ")
        ),
    )
    .unwrap();
    let info = check("PAM before the tags", &tagged);
    assert_eq!(info["origin"], json!([gt[0] + 0.5 * gt[1], gt[3] + 0.5 * gt[5]]));
    assert_eq!(info["nodata_value"], json!(147.0));
    compared
}

#[test]
fn sidecar_georeferencing_reads_as_gdalinfo_reads_it() {
    if common::gdal_tool("gdal_translate").is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    // A projected DEM written here (UTM 10N, 30 m, NoData holes).
    let hf = common::utm_heightfield(60, 40, |c, r| (c + r != 20).then_some(300.0 + c as f32 * 2.0 - r as f32));
    let utm = dir.path().join("utm.tif");
    volterra_formats::geotiff::write_geotiff(&utm, &hf).unwrap();
    let sub = dir.path().join("utm");
    std::fs::create_dir_all(&sub).unwrap();
    let mut n = compare_sidecars(&utm, 32610, &sub);
    // The real geographic DEM.
    if let Some(shared) = common::shared_data() {
        let sub = dir.path().join("pysheds");
        std::fs::create_dir_all(&sub).unwrap();
        n += compare_sidecars(&shared.join("terrain/pysheds_dem.tif"), 4326, &sub);
    }
    assert!(n >= 7, "{n} cases compared with gdalinfo");
}

/// The case: `dem slope` of a DEM georeferenced by its world file and PAM file is
/// gdaldem's, cell for cell (it was computed on 1 m cells).
#[test]
fn slope_of_a_baseline_geotiff_with_a_world_file_equals_gdaldem() {
    let Some(shared) = common::shared_data() else { return };
    let Some(gdaldem) = common::gdal_tool("gdaldem") else { return };
    let dir = tempfile::tempdir().unwrap();
    let dem = translate(&shared.join("terrain/pysheds_dem.tif"), dir.path(), "dem.tif", &["-co", "PROFILE=BASELINE", "-co", "TFW=YES"]);
    let (reference, ours) = (dir.path().join("gdal_slope.tif"), dir.path().join("ours_slope.tif"));
    common::run_ok(Command::new(&gdaldem).args(["slope", "-q", "-s", "111120"]).arg(&dem).arg(&reference));
    common::run_ok(Command::new(common::volterra_bin()).args(["dem", "slope", "--scale", "111120"]).arg(&dem).arg(&ours));
    assert_eq!(common::gdal_grid(&ours), common::gdal_grid(&reference));
    let read = |p: &Path| volterra_formats::geotiff::read_geotiff(p, &Default::default()).unwrap();
    let (a, b) = (read(&ours), read(&reference));
    let mut valid: Vec<f32> = b.elevations.iter().copied().filter(|v| v.is_finite()).collect();
    let worst = a
        .elevations
        .iter()
        .zip(&b.elevations)
        .filter(|(x, y)| x.is_finite() && y.is_finite())
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max);
    let nodata_mismatch = a.elevations.iter().zip(&b.elevations).filter(|(x, y)| x.is_finite() != y.is_finite()).count();
    valid.sort_by(f32::total_cmp);
    eprintln!(
        "slope: {} cells, median {}°, largest difference {worst}, NoData mismatches {nodata_mismatch}",
        valid.len(),
        valid[valid.len() / 2]
    );
    assert_eq!(nodata_mismatch, 0);
    assert!(worst <= 1e-4, "{worst}° from gdaldem");
}
