//! `volterra dem hillshade|slope|aspect|TRI|TPI|roughness|color-relief` (with -alg,
//! -multidirectional, -combined) against GDAL's `gdaldem`, and `volterra dem
//! contours` against `gdal_contour` (Debian's gdal-bin, which
//! tests/setup-system.sh installs): on the real geographic DEM in `../shared/data`
//! (pysheds_dem.tif, with -s 111120) and on a projected DEM with NoData holes written
//! here, with and without -compute_edges. The outputs must agree cell for cell (values,
//! NoData) and in everything `gdalinfo -json` says of the grid: size, geotransform, CRS,
//! band type and NoData value. Contours must give the same lines per level (count, closed
//! or open, every vertex to 1e-12 of its magnitude) in the same CRS.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

fn gdaldem() -> Option<PathBuf> {
    common::gdal_tool("gdaldem")
}

use common::{gdal_grid as grid_of, run_ok as run};

/// The cells of a raster as f32 (through gdal_translate, so GDAL reads ours too) and
/// which are NoData.
fn cells(path: &Path, dir: &Path) -> (Vec<f32>, Vec<bool>) {
    band_cells(path, dir, 1)
}

/// As `cells`, of band `band` (1-based).
fn band_cells(path: &Path, dir: &Path, band: usize) -> (Vec<f32>, Vec<bool>) {
    let f32_path = dir.join(format!("{}.b{band}.f32.tif", path.file_stem().unwrap().to_string_lossy()));
    run(Command::new("gdal_translate").args(["-q", "-ot", "Float32", "-b", &band.to_string()]).arg(path).arg(&f32_path));
    let hf = volterra_formats::geotiff::read_geotiff(&f32_path, &Default::default()).unwrap();
    let n = hf.elevations.len();
    let nodata: Vec<bool> = (0..n).map(|i| hf.nodata.get(i)).collect();
    (hf.elevations, nodata)
}

/// A palette with every kind of entry: NoData, absolute values (space- and comma-separated),
/// percentages of the range, named colours, alpha.
const PALETTE: &str = "# elevations\nnv 0 0 0 0\n150 0 90 30\n180,60,140,60\n0% blue\n40% 200 200 80 200\n250 brown\n100% white\n";

/// color-relief both ways (interpolated and nearest, RGB and RGBA): every band equal.
fn compare_color_relief(dem: &Path, dir: &Path) {
    compare_color_relief_with(dem, dir, PALETTE);
}

/// As `compare_color_relief`, with the palette `palette_text`.
fn compare_color_relief_with(dem: &Path, dir: &Path, palette_text: &str) {
    let gdaldem = gdaldem().unwrap();
    let palette = dir.join("palette.txt");
    std::fs::write(&palette, palette_text).unwrap();
    for (mode, our_mode) in [(None, None), (Some("-nearest_color_entry"), Some("--nearest-color-entry"))] {
        for alpha in [false, true] {
            let tag = format!("relief{}{}", if mode.is_some() { "_nearest" } else { "" }, if alpha { "_alpha" } else { "" });
            let (reference, ours) = (dir.join(format!("gdal_{tag}.tif")), dir.join(format!("ours_{tag}.tif")));
            let mut g = Command::new(&gdaldem);
            g.arg("color-relief").arg(dem).arg(&palette).arg(&reference).arg("-q").args(mode).args(alpha.then_some("-alpha"));
            run(&mut g);
            let mut v = Command::new(common::volterra_bin());
            v.args(["dem", "color-relief"]).arg(dem).arg(&ours).arg("--palette").arg(&palette).args(our_mode);
            v.args(alpha.then_some("--alpha"));
            run(&mut v);
            assert_eq!(grid_of(&ours), grid_of(&reference), "{tag}: the grid as gdalinfo reads it");
            let mut differing = 0;
            for band in 1..=if alpha { 4 } else { 3 } {
                let ((a, _), (b, _)) = (band_cells(&ours, dir, band), band_cells(&reference, dir, band));
                differing += a.iter().zip(&b).filter(|(p, q)| p != q).count();
            }
            eprintln!("{} {tag}: {differing} band values differ", dem.display());
            assert_eq!(differing, 0, "{tag}");
        }
    }
}

/// A GeoJSON file's CRS name and its lines per level (elevation bits → lines).
type LinesByLevel = std::collections::BTreeMap<u64, Vec<Vec<[f64; 2]>>>;

fn contour_lines(path: &Path, attribute: &str) -> (String, LinesByLevel) {
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    let crs = v["crs"]["properties"]["name"].as_str().unwrap_or_default().to_string();
    let mut lines = LinesByLevel::new();
    for f in v["features"].as_array().unwrap() {
        let level = f["properties"][attribute].as_f64().unwrap();
        let coords = f["geometry"]["coordinates"].as_array().unwrap();
        let points = coords.iter().map(|c| [c[0].as_f64().unwrap(), c[1].as_f64().unwrap()]).collect();
        lines.entry(level.to_bits()).or_default().push(points);
    }
    (crs, lines)
}

/// gdal_contour and ours at `levels` (gdal_contour's arguments, ours): the same lines.
/// Returns the vertices compared.
fn compare_contours(dem: &Path, dir: &Path, tag: &str, gdal_levels: &[&str], our_levels: &[&str]) -> usize {
    let (reference, ours) = (dir.join(format!("gdal_{tag}.geojson")), dir.join(format!("ours_{tag}.geojson")));
    run(Command::new("gdal_contour").args(["-q", "-a", "height", "-f", "GeoJSON"]).args(gdal_levels).arg(dem).arg(&reference));
    let mut v = Command::new(common::volterra_bin());
    v.args(["dem", "contours"]).arg(dem).arg(&ours).args(["--attribute", "height"]).args(our_levels);
    run(&mut v);
    let ((crs_a, a), (crs_b, b)) = (contour_lines(&ours, "height"), contour_lines(&reference, "height"));
    assert_eq!(crs_a, crs_b, "{tag}: the CRS");
    assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>(), "{tag}: the levels drawn");
    let (mut compared, mut worst) = (0, 0.0f64);
    for (level, ours) in &a {
        let theirs = &b[level];
        let level = f64::from_bits(*level);
        assert_eq!(ours.len(), theirs.len(), "{tag}: lines at level {level}");
        let closed = |ls: &Vec<Vec<[f64; 2]>>| ls.iter().filter(|l| l.len() > 2 && l.first() == l.last()).count();
        assert_eq!(closed(ours), closed(theirs), "{tag}: closed lines at level {level}");
        // Every vertex, in a canonical order (the lines' directions and starts may differ).
        let vertices = |ls: &Vec<Vec<[f64; 2]>>| {
            let mut v: Vec<[f64; 2]> = ls.iter().flat_map(|l| l.iter().copied()).collect();
            v.sort_by(|p, q| p[0].total_cmp(&q[0]).then(p[1].total_cmp(&q[1])));
            v.dedup();
            v
        };
        let (va, vb) = (vertices(ours), vertices(theirs));
        assert_eq!(va.len(), vb.len(), "{tag}: vertices at level {level}");
        for (p, q) in va.iter().zip(&vb) {
            for k in 0..2 {
                worst = worst.max((p[k] - q[k]).abs() / p[k].abs().max(1.0));
            }
        }
        compared += va.len();
    }
    eprintln!("{} contours {tag}: {} levels, {compared} vertices, largest relative difference {worst:e}", dem.display(), a.len());
    assert!(worst <= 1e-12, "{tag}: a vertex {worst:e} from gdal_contour's");
    compared
}

/// Twice a ring's signed area (positive: counter-clockwise), about its first vertex (about
/// the origin, rounding would drown the rings round single cell centres).
fn ring_area2(r: &[[f64; 2]]) -> f64 {
    let o = r[0];
    r.windows(2).map(|w| (w[0][0] - o[0]) * (w[1][1] - o[1]) - (w[1][0] - o[0]) * (w[0][1] - o[1])).sum()
}

/// A polygon file's bands in order: (ELEV_MIN, ELEV_MAX, polygons as rings of points).
type PolygonBands = Vec<(f64, f64, Vec<Vec<Vec<[f64; 2]>>>)>;

fn contour_polygons(path: &Path) -> (String, PolygonBands) {
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    let crs = v["crs"]["properties"]["name"].as_str().unwrap_or_default().to_string();
    let point = |c: &serde_json::Value| [c[0].as_f64().unwrap(), c[1].as_f64().unwrap()];
    let bands = v["features"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| {
            assert_eq!(f["geometry"]["type"], "MultiPolygon");
            let polys = f["geometry"]["coordinates"].as_array().unwrap();
            let polys = polys
                .iter()
                .map(|p| p.as_array().unwrap().iter().map(|r| r.as_array().unwrap().iter().map(point).collect()).collect())
                .collect();
            (f["properties"]["ELEV_MIN"].as_f64().unwrap(), f["properties"]["ELEV_MAX"].as_f64().unwrap(), polys)
        })
        .collect();
    (crs, bands)
}

/// gdal_contour -p and ours --polygons at `levels`: the same bands (bounds as GDAL writes
/// them, except its placeholders 0 and 2³²−1 for the lowest band's minimum and a fixed
/// list's highest band's maximum, where ours gives the data's extremes), the same polygons
/// per band (each's outer ring's vertex count and area to 1e-9 of it, its holes' count and
/// areas), every vertex of GDAL's among ours. Returns the polygons compared.
fn compare_contour_polygons(dem: &Path, dir: &Path, tag: &str, gdal_levels: &[&str], our_levels: &[&str]) -> usize {
    let (reference, ours) = (dir.join(format!("gdal_{tag}_p.geojson")), dir.join(format!("ours_{tag}_p.geojson")));
    let mut g = Command::new("gdal_contour");
    g.args(["-q", "-p", "-amin", "ELEV_MIN", "-amax", "ELEV_MAX", "-f", "GeoJSON"]).args(gdal_levels).arg(dem).arg(&reference);
    run(&mut g);
    let mut v = Command::new(common::volterra_bin());
    v.args(["dem", "contours", "--polygons"]).arg(dem).arg(&ours).args(our_levels);
    run(&mut v);
    let ((crs_a, a), (crs_b, b)) = (contour_polygons(&ours), contour_polygons(&reference));
    assert_eq!(crs_a, crs_b, "{tag}: the CRS");
    assert_eq!(a.len(), b.len(), "{tag}: bands");
    let (data_lo, data_hi) = (a[0].0, a[a.len() - 1].1);
    let (mut polygons, mut worst) = (0, 0.0f64);
    for (i, ((min_a, max_a, pa), (min_b, max_b, pb))) in a.iter().zip(&b).enumerate() {
        let min_b = if i == 0 && *min_b == 0.0 { data_lo } else { *min_b };
        let max_b = if i == b.len() - 1 && *max_b == 4294967295.0 { data_hi } else { *max_b };
        assert_eq!((*min_a, *max_a), (min_b, max_b), "{tag}: band {i}'s bounds");
        assert_eq!(pa.len(), pb.len(), "{tag}: polygons in band {min_b}…{max_b}");
        // Each polygon by its outer ring's least vertex: (outer vertices, outer area, sorted
        // hole areas), orientation aside (ours follows RFC 7946, GDAL 3.6 does not).
        let summary = |ps: &Vec<Vec<Vec<[f64; 2]>>>| {
            ps.iter()
                .map(|p| {
                    let mut holes: Vec<f64> = p[1..].iter().map(|r| ring_area2(r).abs() / 2.0).collect();
                    holes.sort_by(f64::total_cmp);
                    let least = p[0].iter().map(|q| (q[0].to_bits(), q[1].to_bits())).min().unwrap();
                    (least, (ring_area2(&p[0]).abs() / 2.0, p[0].len(), holes))
                })
                .collect::<std::collections::BTreeMap<_, _>>()
        };
        let (sa, sb) = (summary(pa), summary(pb));
        assert_eq!(sa.keys().collect::<Vec<_>>(), sb.keys().collect::<Vec<_>>(), "{tag}: polygons in band {min_b}…{max_b}");
        for ((area_a, n_a, holes_a), (area_b, n_b, holes_b)) in sa.values().zip(sb.values()) {
            assert_eq!(n_a, n_b, "{tag}: vertices of an outer ring of area {area_b} in band {min_b}…{max_b}");
            assert_eq!(holes_a.len(), holes_b.len(), "{tag}: holes of the polygon of area {area_b}");
            for (x, y) in std::iter::once((area_a, area_b)).chain(holes_a.iter().zip(holes_b)) {
                worst = worst.max((x - y).abs() / y.abs().max(1e-300));
            }
        }
        // Every vertex of GDAL's is one of ours, bit for bit.
        let ours: std::collections::HashSet<(u64, u64)> = pa.iter().flatten().flatten().map(|p| (p[0].to_bits(), p[1].to_bits())).collect();
        let missing = pb.iter().flatten().flatten().filter(|p| !ours.contains(&(p[0].to_bits(), p[1].to_bits()))).count();
        assert_eq!(missing, 0, "{tag}: vertices of GDAL's band {min_b}…{max_b} not among ours");
        polygons += pa.len();
    }
    eprintln!(
        "{} contour polygons {tag}: {} bands, {polygons} polygons, largest relative area difference {worst:e}",
        dem.display(),
        a.len()
    );
    assert!(worst <= 1e-9, "{tag}: an area {worst:e} from gdal_contour's");
    polygons
}

/// Runs every product on `dem` both ways and compares; returns the cells compared: the
/// rest of gdaldem too — TRI (Riley's and Wilson's), TPI, roughness, slope, aspect and
/// hillshade by Zevenbergen–Thorne, multidirectional and combined hillshade.
fn compare_products(dem: &Path, dir: &Path, gdal_args: &[&str], our_args: &[&str]) -> usize {
    compare_products_of(dem, dir, gdal_args, our_args, true)
}

/// As `compare_products`; without `all`, only hillshade, slope and aspect (with and without
/// -zero_for_flat) and color-relief.
fn compare_products_of(dem: &Path, dir: &Path, gdal_args: &[&str], our_args: &[&str], all: bool) -> usize {
    let gdaldem = gdaldem().unwrap();
    compare_color_relief(dem, dir);
    let mut compared = 0;
    // aspect -zero_for_flat too: 0 for flat, edge and void cells, and no NoData value.
    type Variant<'a> = (&'a str, &'a [&'a str], &'a [&'a str]);
    let mut variants: Vec<Variant> =
        vec![("hillshade", &[], &[]), ("slope", &[], &[]), ("aspect", &[], &[]), ("aspect", &["-zero_for_flat"], &["--zero-for-flat"])];
    if all {
        let zt: (&[&str], &[&str]) = (&["-alg", "ZevenbergenThorne"], &["--alg", "ZevenbergenThorne"]);
        variants.extend([
            ("TRI", &[][..], &[][..]),
            ("TRI", &["-alg", "Wilson"][..], &["--alg", "Wilson"][..]),
            ("TPI", &[], &[]),
            ("roughness", &[], &[]),
            ("slope", zt.0, zt.1),
            ("aspect", zt.0, zt.1),
            ("hillshade", zt.0, zt.1),
            ("hillshade", &["-multidirectional"], &["--multidirectional"]),
            ("hillshade", &["-combined"], &["--combined"]),
        ]);
    }
    for (product, gdal_extra, our_extra) in variants {
        for edges in [false, true] {
            let tag = format!("{product}{}{}", gdal_extra.join("").replace('-', "_"), if edges { "_edges" } else { "" });
            let (reference, ours) = (dir.join(format!("gdal_{tag}.tif")), dir.join(format!("ours_{tag}.tif")));
            let mut g = Command::new(&gdaldem);
            g.arg(product).arg(dem).arg(&reference).arg("-q").args(gdal_args).args(gdal_extra);
            if edges {
                g.arg("-compute_edges");
            }
            run(&mut g);
            let mut v = Command::new(common::volterra_bin());
            v.args(["dem", product]).arg(dem).arg(&ours).args(our_args).args(our_extra);
            if edges {
                v.arg("--compute-edges");
            }
            run(&mut v);
            assert_eq!(grid_of(&ours), grid_of(&reference), "{tag}: the grid as gdalinfo reads it");
            let ((a, na), (b, nb)) = (cells(&ours, dir), cells(&reference, dir));
            let nodata_mismatch = na.iter().zip(&nb).filter(|(x, y)| x != y).count();
            let worst = a
                .iter()
                .zip(&b)
                .zip(na.iter().zip(&nb))
                .filter(|(_, (x, y))| !**x && !**y)
                .map(|((p, q), _)| (p - q).abs())
                .fold(0.0f32, f32::max);
            let valid = na.iter().filter(|x| !**x).count();
            let differing = a.iter().zip(&b).zip(na.iter().zip(&nb)).filter(|((p, q), (x, y))| !**x && !**y && p != q).count();
            eprintln!(
                "{} {tag}: {valid} cells, NoData mismatches {nodata_mismatch}, {differing} differ, largest difference {worst}",
                dem.display()
            );
            assert_eq!(nodata_mismatch, 0, "{tag}: NoData where gdaldem has it");
            if product == "hillshade" {
                // GDAL divides by an approximate square root (SSE rsqrt and one Newton step)
                // and sums a float window in its own order: a byte may round the other way.
                assert!(worst <= 1.0 && differing * 1000 <= valid, "{tag}: {differing} bytes differ, by up to {worst}");
            } else {
                assert!(worst <= 1e-4, "{tag}: {worst} from gdaldem");
            }
            compared += valid;
        }
    }
    compared
}

#[test]
fn dem_products_equal_gdaldem_on_a_real_geographic_dem() {
    let Some(shared) = common::shared_data() else { return };
    if gdaldem().is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let dem = shared.join("terrain/pysheds_dem.tif");
    let n = compare_products(&dem, dir.path(), &["-s", "111120"], &["--scale", "111120"]);
    assert!(n > 700_000, "{n} cells compared");
    let v = compare_contours(&dem, dir.path(), "i10", &["-i", "10"], &["--interval", "10"]);
    let v = v + compare_contours(&dem, dir.path(), "i7o3", &["-i", "7", "-off", "3"], &["--interval", "7", "--offset", "3"]);
    // Fixed levels, one of them an elevation the DEM holds exactly (nudged, as GDAL does).
    let (lo, _) = volterra_formats::geotiff::read_geotiff(&dem, &Default::default())
        .unwrap()
        .elevations
        .iter()
        .filter(|v| v.is_finite())
        .fold((f32::INFINITY, 0.0f32), |(lo, hi), &v| (lo.min(v), hi.max(v)));
    let exact = format!("{}", lo + 20.0);
    assert!(lo + 20.0 < 180.0);
    // gdal_contour 3.6 silently drops fixed levels given out of order: ascending here. Ours
    // sorts them, so our list is given shuffled.
    let fl = ["-fl", &exact, "180", "200.5"];
    let v = v + compare_contours(&dem, dir.path(), "fl", &fl, &["--levels", &format!("180,200.5,{exact}")]);
    assert!(v > 20_000, "{v} vertices compared");
    let p = compare_contour_polygons(&dem, dir.path(), "i10", &["-i", "10"], &["--interval", "10"]);
    let p = p + compare_contour_polygons(&dem, dir.path(), "fl", &fl, &["--levels", &format!("180,200.5,{exact}")]);
    assert!(p > 20, "{p} polygons compared");
}

#[test]
fn dem_products_equal_gdaldem_on_a_projected_dem_with_nodata() {
    if gdaldem().is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    // 90 × 70 cells of 30 m in UTM 10N: smooth hills, two NoData holes and a NoData edge run.
    let hf = common::utm_heightfield(90, 70, |c, r| {
        let (x, y) = (c as f64 * 30.0, r as f64 * 30.0);
        let hole = ((c as f64 - 30.0).powi(2) + (r as f64 - 20.0).powi(2)) < 25.0 || (c > 60 && c < 66 && r > 40 && r < 50);
        (!(hole || (r == 0 && c < 10))).then(|| (300.0 + 80.0 * (x / 400.0).sin() * (y / 300.0).cos() + 0.05 * x) as f32)
    });
    let dem = dir.path().join("hills.tif");
    volterra_formats::geotiff::write_geotiff(&dem, &hf).unwrap();
    let n = compare_products(&dem, dir.path(), &[], &[]);
    assert!(n > 30_000, "{n} cells compared");
    // Lines round the holes stop half-way to the NoData centres, as GDAL's do.
    let v = compare_contours(&dem, dir.path(), "i5", &["-i", "5"], &["--interval", "5"]);
    assert!(v > 5_000, "{v} vertices compared");
    // Band polygons: their edges run round the holes half-way to the NoData centres too.
    let p = compare_contour_polygons(&dem, dir.path(), "i5", &["-i", "5"], &["--interval", "5"]);
    let p = p + compare_contour_polygons(&dem, dir.path(), "i20o7", &["-i", "20", "-off", "7"], &["--interval", "20", "--offset", "7"]);
    assert!(p > 20, "{p} polygons compared");
}

/// A GeoTIFF larger than the memory limit: its products are made at full resolution, a
/// band of rows at a time (read whole, the raster would be its largest overview that fits,
/// and the products that overview's), equal to gdaldem's and gdal_contour's, within the
/// limit.
#[test]
fn dem_products_of_a_tiled_dem_larger_than_the_memory_limit_equal_gdaldem_at_full_resolution() {
    if gdaldem().is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    // 2048 × 1536 float32 cells (12 MiB), tiled 256², with overviews; NoData holes across
    // tile borders.
    let hf = common::utm_heightfield(2048, 1536, |c, r| {
        let (x, y) = (c as f64 * 30.0, r as f64 * 30.0);
        let hole = ((c as f64 - 256.0).powi(2) + (r as f64 - 700.0).powi(2)) < 60.0 || (c > 1500 && c < 1530 && r > 250 && r < 260);
        (!hole).then(|| (300.0 + 80.0 * (x / 4000.0).sin() * (y / 3000.0).cos() + 0.005 * x + 3.0 * (x / 97.0).sin()) as f32)
    });
    let strips = dir.path().join("strips.tif");
    volterra_formats::geotiff::write_geotiff(&strips, &hf).unwrap();
    let dem = dir.path().join("tiled.tif");
    run(Command::new("gdal_translate").args(["-q", "-co", "TILED=YES", "-co", "COMPRESS=DEFLATE"]).arg(&strips).arg(&dem));
    run(Command::new("gdaladdo").args(["-q"]).arg(&dem).args(["2", "4", "8"]));
    let limit = ["--max-memory", "8M"];
    // Read whole within the limit, the raster would be an overview.
    let whole = volterra_formats::geotiff::read_geotiff(&dem, &volterra_formats::Limits::max(8 << 20)).unwrap();
    assert_eq!(whole.width, 1024, "{:?}", whole.notes);
    let n = compare_products_of(&dem, dir.path(), &[], &limit, false);
    assert!(n > 18_000_000, "{n} cells compared");
    // Contours too: read by rows, lines and band polygons as gdal_contour draws them.
    let v = compare_contours(&dem, dir.path(), "tiled_i20", &["-i", "20"], &["--interval", "20", limit[0], limit[1]]);
    assert!(v > 50_000, "{v} vertices compared");
    let p = compare_contour_polygons(&dem, dir.path(), "tiled_i40", &["-i", "40"], &["--interval", "40", limit[0], limit[1]]);
    assert!(p > 5, "{p} polygons compared");
    let out =
        Command::new(common::volterra_bin()).args(limit).args(["dem", "slope"]).arg(&dem).arg(dir.path().join("s.tif")).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success() && stderr.contains("memory: peak") && !stderr.contains("over the limit"), "{stderr}");
    // `info` reads it by rows too: the full raster described (not the overview), its range
    // and NoData count those of the raster held, within the limit.
    let out = Command::new(common::volterra_bin()).args(limit).args(["info", "--json"]).arg(&dem).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success() && !stderr.contains("over the limit"), "{stderr}");
    let info: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let (lo, hi) = hf.range().unwrap();
    assert_eq!(info["dims"], serde_json::json!([2048, 1536]));
    assert_eq!((info["min"].as_f64(), info["max"].as_f64()), (Some(lo as f64), Some(hi as f64)));
    assert_eq!(info["nodata_count"].as_u64(), Some(hf.nodata_count() as u64));
    // `convert` likewise: the full raster, strip by strip, the file the raster held gives.
    let converted = dir.path().join("converted.tif");
    let out = Command::new(common::volterra_bin()).args(limit).arg("convert").arg(&dem).arg(&converted).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success() && !stderr.contains("over the limit"), "{stderr}");
    let held = dir.path().join("held.tif");
    volterra_formats::geotiff::write_geotiff(&held, &hf).unwrap();
    assert!(std::fs::read(&converted).unwrap() == std::fs::read(&held).unwrap(), "converted by rows: not the file the raster held gives");
}

/// A DEM whose every sample is NoData: color-relief with a palette of percentages (whose
/// range is then undefined) paints what gdaldem paints — the nv colour where the palette
/// has one, else its lowest (it painted an opaque palette colour before) — and says that
/// the DEM has no valid sample; the other products are all NoData, said too.
#[test]
fn products_of_an_all_nodata_dem_equal_gdaldem_and_say_so() {
    if gdaldem().is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let hf = common::utm_heightfield(40, 30, |_, _| None);
    let dem = dir.path().join("void.tif");
    volterra_formats::geotiff::write_geotiff(&dem, &hf).unwrap();
    compare_color_relief_with(&dem, dir.path(), PALETTE);
    compare_color_relief_with(&dem, dir.path(), "0% blue\n40% 200 200 80 200\n100% white\n");
    for product in ["slope", "color-relief"] {
        let out = Command::new(common::volterra_bin())
            .args(["dem", product])
            .arg(&dem)
            .arg(dir.path().join(format!("{product}.tif")))
            .args(["--palette", dir.path().join("palette.txt").to_str().unwrap()].iter().filter(|_| product == "color-relief"))
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{stderr}");
        assert!(stderr.contains("no valid samples"), "{product}: {stderr}");
    }
    // Contours and a render say it too, rather than writing an empty result silently.
    let out = Command::new(common::volterra_bin())
        .args(["dem", "contours"])
        .arg(&dem)
        .arg(dir.path().join("c.geojson"))
        .args(["--levels", "100"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success() && stderr.contains("no valid samples (every one NoData): the output holds no contour"), "{stderr}");
    let scene = dir.path().join("void.toml");
    std::fs::write(
        &scene,
        "[image]\nwidth = 16\nheight = 16\n[camera]\nposition = [600.0, -900.0, 900.0]\nfocal_point = [600.0, 450.0, 0.0]\n\
         [[node]]\nname = \"dem\"\nkind = \"heightfield\"\nfile = \"void.tif\"\nrenderer = \"terrain-reference\"\n",
    )
    .unwrap();
    let out = Command::new(common::volterra_bin()).arg("render").arg(&scene).arg("-o").arg(dir.path().join("v.exr")).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success() && stderr.contains("node 'dem': the heightfield has no valid sample"), "{stderr}");
}

/// `volterra dem` takes gdaldem's output options, spelled as gdaldem spells them (`-co`,
/// `-of`): uncompressed strips by default, as gdaldem writes (it always wrote Deflate
/// strips); COMPRESS=DEFLATE/LZW/ZSTD, PREDICTOR=2/3, TILED=YES with block sizes — each
/// read by GDAL as written (gdalinfo's image structure and block size) and holding
/// gdaldem's cells. What it does not write is refused with a line that says so.
#[test]
fn dem_products_take_gdaldems_creation_options() {
    let Some(gdaldem) = gdaldem() else { return };
    let dir = tempfile::tempdir().unwrap();
    let hf = common::utm_heightfield(300, 200, |c, r| {
        (c + r != 100).then_some((300.0 + 20.0 * (c as f64 / 17.0).sin() + 0.3 * r as f64) as f32)
    });
    let dem = dir.path().join("dem.tif");
    volterra_formats::geotiff::write_geotiff(&dem, &hf).unwrap();
    let reference = dir.path().join("gdal_slope.tif");
    run(Command::new(&gdaldem).args(["slope", "-q"]).arg(&dem).arg(&reference));
    let (want, want_nodata) = cells(&reference, dir.path());
    let structure = |p: &Path| -> (Option<String>, Option<String>, Vec<u64>) {
        let info: serde_json::Value = serde_json::from_str(&run(Command::new("gdalinfo").arg("-json").arg(p))).unwrap();
        let md = &info["metadata"]["IMAGE_STRUCTURE"];
        let block = info["bands"][0]["block"].as_array().unwrap().iter().map(|v| v.as_u64().unwrap()).collect();
        (md["COMPRESSION"].as_str().map(String::from), md["PREDICTOR"].as_str().map(String::from), block)
    };
    // (the options, and what gdalinfo then says: compression, predictor, tile size).
    type Case<'a> = (&'a [&'a str], Option<&'a str>, Option<&'a str>, Option<[u64; 2]>);
    let cases: [Case; 5] = [
        (&[], None, None, None),
        (&["-co", "COMPRESS=DEFLATE"], Some("DEFLATE"), None, None),
        (&["-co", "COMPRESS=LZW", "-co", "PREDICTOR=2"], Some("LZW"), Some("2"), None),
        (&["-co", "COMPRESS=ZSTD", "-co", "PREDICTOR=3", "-co", "TILED=YES"], Some("ZSTD"), Some("3"), Some([256, 256])),
        (&["--co", "TILED=YES", "--co", "BLOCKXSIZE=64", "--co", "BLOCKYSIZE=32", "-of", "GTiff"], None, None, Some([64, 32])),
    ];
    for (k, (args, compression, predictor, block)) in cases.into_iter().enumerate() {
        let out = dir.path().join(format!("ours_{k}.tif"));
        run(Command::new(common::volterra_bin()).args(["dem", "slope"]).arg(&dem).arg(&out).args(args));
        let (c, p, b) = structure(&out);
        assert_eq!((c.as_deref(), p.as_deref()), (compression, predictor), "{args:?}");
        if let Some(block) = block {
            assert_eq!(b, block, "{args:?}: tiles");
        } else {
            assert_eq!(b[0], 300, "{args:?}: strips");
        }
        assert_eq!(grid_of(&out), grid_of(&reference), "{args:?}");
        let (got, got_nodata) = cells(&out, dir.path());
        let same = got.iter().zip(&want).all(|(a, b)| a == b || (a.is_nan() && b.is_nan()));
        assert!(same && got_nodata == want_nodata, "{args:?}: cells differ from gdaldem's");
    }
    for (args, says) in [
        (&["-of", "COG", "-co", "TILED=YES"][..], "TILED is a GTiff option; a COG is always tiled"),
        (&["-of", "COG", "-co", "RESAMPLING=MODE"][..], "RESAMPLING=MODE"),
        (&["-co", "PHOTOMETRIC=RGB"][..], "creation option PHOTOMETRIC is not one this writer takes"),
        (&["-co", "COMPRESS=JPEG"][..], "COMPRESS=JPEG"),
    ] {
        let o = Command::new(common::volterra_bin())
            .args(["dem", "slope"])
            .arg(&dem)
            .arg(dir.path().join("x.tif"))
            .args(args)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && err.contains(says), "{args:?}: {err}");
    }
    let o = Command::new(common::volterra_bin())
        .args(["dem", "hillshade"])
        .arg(&dem)
        .arg(dir.path().join("h.tif"))
        .args(["-co", "COMPRESS=LZW", "-co", "PREDICTOR=3"])
        .output()
        .unwrap();
    assert!(String::from_utf8_lossy(&o.stderr).contains("PREDICTOR=3 is for floating-point samples"));
}

/// The cells of overview `level` (0 the full raster, k its k-th overview) of band `band`,
/// as GDAL reads them (`-oo OVERVIEW_LEVEL`), as f32, and which are NoData.
fn level_cells(path: &Path, dir: &Path, level: usize, band: usize) -> (Vec<f32>, Vec<bool>) {
    let f32_path = dir.join(format!("{}.l{level}.b{band}.f32.tif", path.file_stem().unwrap().to_string_lossy()));
    let mut cmd = Command::new("gdal_translate");
    cmd.args(["-q", "-ot", "Float32", "-b", &band.to_string()]);
    if level > 0 {
        cmd.args(["-oo", &format!("OVERVIEW_LEVEL={}", level - 1)]);
    }
    run(cmd.arg(path).arg(&f32_path));
    let hf = volterra_formats::geotiff::read_geotiff(&f32_path, &Default::default()).unwrap();
    let nodata: Vec<bool> = (0..hf.elevations.len()).map(|i| hf.nodata.get(i)).collect();
    (hf.elevations, nodata)
}

/// GDAL's validator of Cloud-Optimised GeoTIFFs (Debian's python3-gdal), with its full
/// check of the tiles' leaders and trailers: what it says of `path`.
fn validate_cog(path: &Path) -> Option<String> {
    let python = Path::new("/usr/bin/python3");
    let ok = python.exists()
        && Command::new(python)
            .args(["-c", "import osgeo_utils.samples.validate_cloud_optimized_geotiff"])
            .output()
            .is_ok_and(|o| o.status.success());
    if !ok {
        assert!(!common::under_ci(), "python3-gdal missing under CI (tests/setup-system.sh installs it)");
        eprintln!("SKIPPED: GDAL's COG validator (apt install python3-gdal)");
        return None;
    }
    let out = Command::new(python)
        .args(["-m", "osgeo_utils.samples.validate_cloud_optimized_geotiff", "--full-check=yes"])
        .arg(path)
        .output()
        .unwrap();
    Some(format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr)))
}

/// `-of COG` writes what GDAL's COG driver writes from the same product (`volterra dem …;
/// gdal_translate -of COG`): the same overview sizes (halvings rounded down until one fits
/// in a block), every level's cells equal to GDAL's — the default CUBIC resampling
/// cascaded from level to level, NoData and the alpha band's mask as GDAL treats them,
/// bytes rounded as GDAL rounds — for a float product with NoData holes (slope), bytes
/// with NoData 0 (hillshade), RGB and RGBA (color-relief); LZW, tiled, the layout
/// GDAL's validator accepts with its full check. Odd sizes, so that no level halves evenly.
#[test]
fn dem_products_as_cogs_equal_gdals_cog_driver() {
    if gdaldem().is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let hf = common::utm_heightfield(701, 533, |c, r| {
        let hole = (c as i64 - 300).pow(2) + (r as i64 - 200).pow(2) < 40 * 40 || (c > 600 && r < 37);
        (!hole).then_some((400.0 + 60.0 * (c as f64 / 37.0).sin() * (r as f64 / 53.0).cos() + 0.4 * r as f64) as f32)
    });
    let dem = dir.path().join("dem.tif");
    volterra_formats::geotiff::write_geotiff(&dem, &hf).unwrap();
    let palette = dir.path().join("palette.txt");
    std::fs::write(&palette, "nv 0 0 0 0\n0% 20 60 200 120\n50% 200 200 80\n100% white\n").unwrap();
    let cases: [(&str, &[&str]); 4] = [("slope", &[]), ("hillshade", &[]), ("color-relief", &[]), ("color-relief", &["--alpha"])];
    for (k, (product, our_args)) in cases.into_iter().enumerate() {
        let (plain, reference, ours) = (
            dir.path().join(format!("g{k}.tif")),
            dir.path().join(format!("gdal_cog{k}.tif")),
            dir.path().join(format!("ours_cog{k}.tif")),
        );
        // GDAL's COG is made from our own GTiff product (equal to gdaldem's, as the tests
        // above show), so that only the COG writing is compared.
        let mut g = Command::new(common::volterra_bin());
        g.args(["dem", product]).arg(&dem).arg(&plain).args(our_args);
        if product == "color-relief" {
            g.arg("--palette").arg(&palette);
        }
        run(&mut g);
        run(Command::new("gdal_translate").args(["-q", "-of", "COG", "-co", "BLOCKSIZE=128"]).arg(&plain).arg(&reference));
        let mut v = Command::new(common::volterra_bin());
        v.args(["dem", product]).arg(&dem).arg(&ours).args(["-of", "COG", "-co", "BLOCKSIZE=128"]).args(our_args);
        if product == "color-relief" {
            v.arg("--palette").arg(&palette);
        }
        run(&mut v);
        let tag = format!("{product} {our_args:?}");
        let info = |p: &Path| -> serde_json::Value {
            let i: serde_json::Value = serde_json::from_str(&run(Command::new("gdalinfo").arg("-json").arg(p))).unwrap();
            let b = &i["bands"][0];
            serde_json::json!({"structure": i["metadata"]["IMAGE_STRUCTURE"], "block": b["block"], "overviews": b["overviews"],
                "bands": i["bands"].as_array().unwrap().len()})
        };
        let (want, got) = (info(&reference), info(&ours));
        assert_eq!(got, want, "{tag}: gdalinfo's layout, compression, blocks, overviews");
        assert_eq!(want["overviews"].as_array().unwrap().len(), 3, "{tag}: 350×266 → 175×133 → 87×66");
        assert_eq!(grid_of(&ours), grid_of(&reference), "{tag}");
        let bands = want["bands"].as_u64().unwrap() as usize;
        for level in 0..=3 {
            for band in 1..=bands {
                let (a, an) = level_cells(&ours, dir.path(), level, band);
                let (b, bn) = level_cells(&reference, dir.path(), level, band);
                // NoData reads as NaN: compared by the masks.
                let differing = a.iter().zip(&b).filter(|(p, q)| p != q && !(p.is_nan() && q.is_nan())).count();
                assert_eq!((differing, an == bn), (0, true), "{tag}: level {level} band {band}: cells (or NoData) differ from GDAL's");
            }
        }
        if let Some(said) = validate_cog(&ours) {
            assert!(said.contains("is a valid cloud optimized GeoTIFF") && !said.contains("arning"), "{tag}: {said}");
        }
    }
}
