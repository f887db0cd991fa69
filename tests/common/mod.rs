//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

pub mod volumes;

/// `../shared/data` beside the repository (or $VOLTERRA_SHARED_DATA). Under CI (CI=true) a
/// missing directory is a failure; locally the test is skipped with a printed reason.
pub fn shared_data() -> Option<PathBuf> {
    let dir = std::env::var_os("VOLTERRA_SHARED_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data"));
    if dir.join("SOURCES.md").exists() {
        return Some(dir);
    }
    if std::env::var("CI").is_ok_and(|v| v == "true" || v == "1") {
        panic!("shared data not found at {} (CI=true: tests that need it must not skip)", dir.display());
    }
    eprintln!("SKIPPED: shared data not found at {}", dir.display());
    None
}

/// A volume on the grid `affine` gives (spacing from its columns), for tests that write one.
pub fn volume(
    dims: [usize; 3],
    affine: volterra_formats::Affine,
    data: volterra_formats::VoxelData,
    rescale: volterra_formats::Rescale,
) -> volterra_formats::Volume {
    volterra_formats::Volume { rescale, ..volterra_formats::Volume::new(dims, affine, data) }
}

pub fn repo_path(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(rel)
}

/// The sample positions and weights of tests/reference/make_references.py.
pub fn weight(i: usize) -> f64 {
    ((i as u64 * 7919) % 1009) as f64
}
pub fn sample_index(k: usize, n: usize) -> usize {
    (k * 104729 + 17) % n
}

pub struct Fingerprint {
    pub count: usize,
    pub sum: f64,
    pub wsum: f64,
}

pub fn fingerprint(values: impl Iterator<Item = f64>) -> Fingerprint {
    let mut f = Fingerprint { count: 0, sum: 0.0, wsum: 0.0 };
    for (i, v) in values.enumerate() {
        let v = if v.is_finite() { v } else { 0.0 };
        f.sum += v;
        f.wsum += v * weight(i);
        f.count += 1;
    }
    f
}

pub fn close(a: f64, b: f64, rel: f64) -> bool {
    (a - b).abs() <= rel * a.abs().max(b.abs()).max(1e-300) || (a.is_nan() && b.is_nan())
}

/// true under CI (CI=true), where nothing may skip.
pub fn under_ci() -> bool {
    std::env::var("CI").is_ok_and(|v| v == "true" || v == "1")
}

/// The shared GPU device (lavapipe where there is no hardware). Under CI a missing adapter
/// is a failure; locally the test is skipped with a printed reason.
pub fn gpu() -> Option<&'static volterra::gpu::Device> {
    match volterra::gpu::device() {
        Ok(g) => Some(g),
        Err(e) if under_ci() => panic!("CI=true and no GPU adapter: {e}"),
        Err(e) => {
            eprintln!("SKIPPED: {e}");
            None
        }
    }
}

/// The `volterra` binary, which the volterra-cli package builds into the same target
/// directory as the tests (target/<profile>/volterra; the tests' own executables sit in
/// target/<profile>/deps). `cargo test` builds only the binary's test harness, so build it
/// first: `cargo build --workspace --bins` (tests/run.sh does).
pub fn volterra_bin() -> PathBuf {
    let exe = std::env::current_exe().expect("the test executable's path");
    let profile_dir = exe.parent().and_then(|deps| deps.parent()).expect("target/<profile>/deps/<test>");
    let bin = profile_dir.join(format!("volterra{}", std::env::consts::EXE_SUFFIX));
    assert!(
        bin.is_file(),
        "{} is not built: build it with `cargo build --workspace --bins` before `cargo test` (tests/run.sh does)",
        bin.display()
    );
    bin
}

/// A white directional light of intensity 1 travelling along `direction`.
pub fn sun(direction: [f64; 3]) -> volterra::scene::Light {
    volterra::scene::Light {
        kind: volterra::scene::LightKind::Directional,
        direction: Some(direction),
        position: None,
        color: [1.0; 3],
        intensity: 1.0,
        cone_angle: None,
    }
}

/// A w × h heightfield of 30 m cells in UTM 10N (the north-west sample's centre at
/// 500015 E, 4200015 N; NoData written as −32768): `elevation(column, row)` in metres, None
/// for NoData.
pub fn utm_heightfield(w: usize, h: usize, elevation: impl Fn(usize, usize) -> Option<f32>) -> volterra_formats::Heightfield {
    let cells: Vec<Option<f32>> = (0..h).flat_map(|r| (0..w).map(move |c| (c, r))).map(|(c, r)| elevation(c, r)).collect();
    volterra_formats::Heightfield {
        width: w,
        height: h,
        cell_size: [30.0, 30.0],
        cell_size_native: [30.0, 30.0],
        origin: [500_015.0, 4_200_015.0],
        crs: volterra_formats::Crs { epsg: Some(32610), geographic: false, description: "EPSG:32610".into(), metres_per_unit: 1.0 },
        elevations: cells.iter().map(|e| e.unwrap_or(f32::NAN)).collect(),
        nodata: cells.iter().map(|e| e.is_none()).collect(),
        nodata_value: Some(-32768.0),
        notes: vec![],
        attributes: vec![],
        units: volterra_formats::heightfield::GridUnits::METRES,
    }
}

/// A GDAL command-line tool (`gdal_translate`, `gdaldem`, …) from Debian's gdal-bin, or a
/// skip: None with a printed reason locally, a failure under CI.
pub fn gdal_tool(name: &str) -> Option<PathBuf> {
    let p = PathBuf::from("/usr/bin").join(name);
    if p.exists() {
        return Some(p);
    }
    if under_ci() {
        panic!("{name} missing under CI (tests/setup-system.sh installs gdal-bin)");
    }
    eprintln!("SKIPPED: {name} not installed (apt install gdal-bin)");
    None
}

/// A view of part of a DEM at `width` × `height` pixels: 1200 × 900 cells of 30 m (UTM
/// 10N, smooth hills), seen from above its south-east quarter.
pub fn view_window_scene(width: u32, height: u32) -> String {
    format!(
        r#"
[image]
width = {width}
height = {height}

[camera]
position = [26000.0, 1500.0, 3000.0]
focal_point = [29000.0, 6000.0, 300.0]
view_up = [0.0, 0.0, 1.0]
view_angle = 30.0

[[node]]
name = "dem"
kind = "heightfield"
file = "dem.tif"
renderer = "terrain-reference"
"#
    )
}

/// The DEM `view_window_scene` draws, written as a float32 GeoTIFF (strips, no overviews).
pub fn view_window_dem(path: &std::path::Path) {
    let hf = utm_heightfield(1200, 900, |c, r| {
        let (x, y) = (c as f64 * 30.0, (899 - r) as f64 * 30.0);
        Some((400.0 + 250.0 * (x / 3100.0).sin() * (y / 2300.0).cos() + 0.004 * x) as f32)
    });
    volterra_formats::geotiff::write_geotiff(path, &hf).unwrap();
}

/// Runs a command that must succeed; its standard output.
pub fn run_ok(cmd: &mut std::process::Command) -> String {
    let out = cmd.output().unwrap();
    assert!(out.status.success(), "{cmd:?}: {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// The EPSG code of the CRS in a WKT (GDAL's WKT2: the last `ID["EPSG",…]`), as text.
pub fn wkt_epsg(wkt: &str) -> Option<String> {
    wkt.rfind("ID[\"EPSG\",").map(|at| wkt[at..].split(']').next().unwrap_or_default().to_string())
}

/// What gdalinfo says of a raster's grid and band: size, geotransform, CRS (by its EPSG
/// code), band type and NoData value.
pub fn gdal_grid(path: &std::path::Path) -> serde_json::Value {
    let info: serde_json::Value = serde_json::from_str(&run_ok(std::process::Command::new("gdalinfo").arg("-json").arg(path))).unwrap();
    let band = &info["bands"][0];
    // The CRS by its EPSG code: GDAL spells the same code out in other words when it wrote
    // the file (a datum ensemble or the datum it resolves to).
    let wkt = info["coordinateSystem"]["wkt"].as_str().unwrap_or_default();
    let epsg = wkt_epsg(wkt);
    assert!(epsg.is_some(), "{}: no EPSG code in {wkt}", path.display());
    serde_json::json!({
        "size": info["size"],
        "geoTransform": info["geoTransform"],
        "crs": epsg,
        "type": band["type"],
        "noDataValue": band["noDataValue"],
    })
}
