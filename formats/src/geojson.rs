//! GeoJSON features, as GDAL's GeoJSON driver writes them for `gdal_contour`: a
//! FeatureCollection whose features carry an `ID` and numeric attributes — LineString
//! contour lines with their level, or MultiPolygon bands between levels (`-p`) with their
//! bounds — coordinates in the raster's own CRS (x, y: longitude first for a geographic
//! one), named by the (2008 GeoJSON) `crs` member where its EPSG code is known, as GDAL
//! does, so that GIS tools place them without being told. Numbers are written in Rust's
//! shortest round-trip form, so a reader gets back the exact f64. Written atomically; a
//! feature with a value or coordinate that is not finite is refused (JSON has no such
//! numbers) and nothing is written.

use std::io::Write;
use std::path::Path;

use crate::atomic::write_atomically;
use crate::heightfield::Crs;
use crate::{FormatError, Result};

/// One line feature: its vertices (x, y) and its attribute's value.
pub struct LineFeature<'a> {
    pub points: &'a [[f64; 2]],
    pub value: f64,
}

/// Writes `features` to `path`. `attribute` names the value (gdal_contour -a); with
/// `three_d` each vertex gets the value as its z (gdal_contour -3d).
pub fn write_lines<'a>(
    path: &Path,
    layer: &str,
    crs: &Crs,
    attribute: &str,
    three_d: bool,
    features: impl IntoIterator<Item = LineFeature<'a>>,
) -> Result<()> {
    write_lines_from(path, layer, crs, attribute, three_d, |emit| features.into_iter().try_for_each(emit))
}

/// As `write_lines`, the features handed over one at a time by `produce` as it makes them
/// (a DEM's contours as its rows are read), each written at once: nothing is held but the
/// feature being written. An error from `produce` stops the write (no file is left) and
/// is returned as it is.
pub fn write_lines_from<E: From<FormatError>>(
    path: &Path,
    layer: &str,
    crs: &Crs,
    attribute: &str,
    three_d: bool,
    produce: impl FnOnce(&mut dyn FnMut(LineFeature) -> Result<()>) -> std::result::Result<(), E>,
) -> std::result::Result<(), E> {
    let line = |w: &mut dyn Write, id: usize, f: &LineFeature| -> std::io::Result<()> {
        let finite = f.points.iter().flatten().all(|c| c.is_finite());
        feature_start(w, id, &[(attribute, f.value)], "LineString", finite)?;
        for (i, p) in f.points.iter().enumerate() {
            let sep = if i > 0 { "," } else { "" };
            if three_d {
                write!(w, "{sep}[{},{},{}]", p[0], p[1], f.value)?;
            } else {
                write!(w, "{sep}[{},{}]", p[0], p[1])?;
            }
        }
        Ok(())
    };
    write_collection_from(path, layer, crs, |emit| produce(&mut |f: LineFeature| emit(&|w, id| line(w, id, &f))))
}

/// One polygon band (gdal_contour -p): its polygons (outer ring first, then holes; each
/// ring closed) and its bounds.
pub struct PolygonFeature<'a> {
    pub polygons: &'a [Vec<Vec<[f64; 2]>>],
    pub min: f64,
    pub max: f64,
}

/// Writes polygon bands to `path` as MultiPolygon features carrying an `ID` and the
/// attributes `min_name` and `max_name` (gdal_contour -amin, -amax).
pub fn write_polygons<'a>(
    path: &Path,
    layer: &str,
    crs: &Crs,
    (min_name, max_name): (&str, &str),
    features: impl IntoIterator<Item = PolygonFeature<'a>>,
) -> Result<()> {
    write_collection(path, layer, crs, features, |w, id, f| {
        let finite = f.polygons.iter().flatten().flatten().flatten().all(|c| c.is_finite());
        feature_start(w, id, &[(min_name, f.min), (max_name, f.max)], "MultiPolygon", finite)?;
        for (pi, poly) in f.polygons.iter().enumerate() {
            w.write_all(if pi > 0 { b",[" } else { b"[" })?;
            for (ri, ring) in poly.iter().enumerate() {
                w.write_all(if ri > 0 { b",[" } else { b"[" })?;
                for (i, p) in ring.iter().enumerate() {
                    write!(w, "{}[{},{}]", if i > 0 { "," } else { "" }, p[0], p[1])?;
                }
                w.write_all(b"]")?;
            }
            w.write_all(b"]")?;
        }
        Ok(())
    })
}

/// A feature whose coordinates or attribute values are not finite numbers (JSON has none).
#[derive(Debug)]
struct NotFinite;

impl std::fmt::Display for NotFinite {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("a coordinate or value is not finite")
    }
}

impl std::error::Error for NotFinite {}

/// Opens feature `id`: its properties (`ID` first) and its geometry up to the first
/// coordinate; refuses one whose values or coordinates (`finite`) are not finite.
fn feature_start(w: &mut dyn Write, id: usize, properties: &[(&str, f64)], geometry: &str, finite: bool) -> std::io::Result<()> {
    if !finite || properties.iter().any(|(_, v)| !v.is_finite()) {
        return Err(std::io::Error::new(std::io::ErrorKind::InvalidData, NotFinite));
    }
    let quoted = |s: &str| serde_json::to_string(s).expect("a string serialises");
    write!(w, "{{\"type\":\"Feature\",\"properties\":{{\"ID\":{id}")?;
    for (name, value) in properties {
        write!(w, ",{}:{value}", quoted(name))?;
    }
    write!(w, "}},\"geometry\":{{\"type\":{},\"coordinates\":[", quoted(geometry))
}

/// Writes a FeatureCollection atomically: its header, then each feature through `feature`
/// (which writes it from `feature_start` up to its last coordinate), then the end.
fn write_collection<T>(
    path: &Path,
    layer: &str,
    crs: &Crs,
    features: impl IntoIterator<Item = T>,
    feature: impl Fn(&mut dyn Write, usize, &T) -> std::io::Result<()>,
) -> Result<()> {
    write_collection_from(path, layer, crs, |emit| features.into_iter().try_for_each(|f| emit(&|w, id| feature(w, id, &f))))
}

/// One feature for the collection writer: writes feature `id` from `feature_start` up to
/// its last coordinate.
type FeatureBody<'f> = &'f dyn Fn(&mut dyn Write, usize) -> std::io::Result<()>;

/// As `write_collection`, the features handed to the writer by `produce` one at a time,
/// each written at once. An error from `produce` stops the write (no file is left) and is
/// returned as it is.
fn write_collection_from<E: From<FormatError>>(
    path: &Path,
    layer: &str,
    crs: &Crs,
    produce: impl FnOnce(&mut dyn FnMut(FeatureBody) -> Result<()>) -> std::result::Result<(), E>,
) -> std::result::Result<(), E> {
    let io = |e: std::io::Error| FormatError::io(path, e);
    // The error `produce` returned, kept while the writer's own error unwinds the write.
    let mut failed: Option<E> = None;
    let written = write_atomically(path, |w| {
        write_header(w, layer, crs).map_err(io)?;
        let mut id = 0;
        let mut emit = |body: FeatureBody| -> Result<()> {
            if id > 0 {
                w.write_all(b",\n").map_err(io)?;
            }
            match body(w, id) {
                Err(e) if e.get_ref().is_some_and(|inner| inner.is::<NotFinite>()) => {
                    return Err(FormatError::invalid(path, format!("feature {id}: {NotFinite}")));
                }
                r => r.map_err(io)?,
            }
            w.write_all(b"]}}").map_err(io)?;
            id += 1;
            Ok(())
        };
        if let Err(e) = produce(&mut emit) {
            failed = Some(e);
            return Err(FormatError::invalid(path, "the write was stopped"));
        }
        w.write_all(b"\n]}\n").map_err(io)?;
        Ok(())
    });
    match failed {
        Some(e) => Err(e),
        None => written.map_err(E::from),
    }
}

/// The collection's opening, its name and CRS, up to the features' first.
fn write_header(w: &mut impl Write, layer: &str, crs: &Crs) -> std::io::Result<()> {
    let quoted = |s: &str| serde_json::to_string(s).expect("a string serialises");
    write!(w, "{{\"type\":\"FeatureCollection\",\"name\":{}", quoted(layer))?;
    // WGS 84 in longitude, latitude order is OGC's CRS84 (EPSG:4326 proper is latitude
    // first), as GDAL names it.
    let name = match crs.epsg {
        Some(4326) => Some("urn:ogc:def:crs:OGC:1.3:CRS84".to_string()),
        Some(code) => Some(format!("urn:ogc:def:crs:EPSG::{code}")),
        None => None,
    };
    if let Some(name) = name {
        write!(w, ",\"crs\":{{\"type\":\"name\",\"properties\":{{\"name\":{}}}}}", quoted(&name))?;
    }
    w.write_all(b",\"features\":[\n")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What we write parses as GeoJSON with the exact numbers and the CRS's name.
    #[test]
    fn lines_round_trip_through_a_json_parser() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.geojson");
        let pts = [[500_015.123456789, 4_200_015.0], [0.1 + 0.2, -1e-7]];
        let crs = Crs { epsg: Some(32610), geographic: false, description: String::new(), metres_per_unit: 1.0 };
        write_lines(&path, "contour", &crs, "elev\"m", true, [LineFeature { points: &pts, value: 12.5 }]).unwrap();
        let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
        assert_eq!(v["crs"]["properties"]["name"], "urn:ogc:def:crs:EPSG::32610");
        let f = &v["features"][0];
        assert_eq!(f["properties"]["ID"], 0);
        assert_eq!(f["properties"]["elev\"m"], 12.5);
        let c = &f["geometry"]["coordinates"];
        assert_eq!(c[0][0].as_f64(), Some(500_015.123456789));
        assert_eq!(c[1][0].as_f64(), Some(0.1 + 0.2));
        assert_eq!(c[1][1].as_f64(), Some(-1e-7));
        assert_eq!(c[1][2].as_f64(), Some(12.5));
        let nan = [[f64::NAN, 0.0]];
        assert!(write_lines(&path, "c", &crs, "e", false, [LineFeature { points: &nan, value: 1.0 }]).is_err());
    }

    /// Polygon bands parse back as MultiPolygons with their rings and bounds; a NaN is
    /// refused naming the feature, and the file it would replace is left as it was.
    #[test]
    fn polygons_round_trip_and_nan_is_refused_whole() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("p.geojson");
        let outer = vec![[0.0, 0.0], [4.0, 0.0], [4.0, 4.0], [0.0, 4.0], [0.0, 0.0]];
        let hole = vec![[1.0, 1.0], [1.0, 2.0], [2.0, 2.0], [1.0, 1.0]];
        let polys = vec![vec![outer.clone(), hole.clone()], vec![outer.clone()]];
        let crs = Crs { epsg: Some(4326), geographic: true, description: String::new(), metres_per_unit: 1.0 };
        let band = |min, max| PolygonFeature { polygons: &polys, min, max };
        write_polygons(&path, "contour", &crs, ("lo", "hi"), [band(0.5, 10.0), band(10.0, 20.25)]).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        let v: serde_json::Value = serde_json::from_str(&text).unwrap();
        assert_eq!(v["crs"]["properties"]["name"], "urn:ogc:def:crs:OGC:1.3:CRS84");
        let f = &v["features"][1];
        assert_eq!(
            (f["properties"]["ID"].as_u64(), f["properties"]["lo"].as_f64(), f["properties"]["hi"].as_f64()),
            (Some(1), Some(10.0), Some(20.25))
        );
        assert_eq!(f["geometry"]["type"], "MultiPolygon");
        let c = &f["geometry"]["coordinates"];
        assert_eq!((c.as_array().unwrap().len(), c[0].as_array().unwrap().len()), (2, 2));
        assert_eq!(c[0][1][1][1].as_f64(), Some(2.0));
        let bad = PolygonFeature { polygons: &polys, min: f64::NAN, max: 1.0 };
        let e = write_polygons(&path, "contour", &crs, ("lo", "hi"), [band(0.5, 10.0), bad]).unwrap_err().to_string();
        assert!(e.contains("feature 1") && e.contains("not finite"), "{e}");
        assert_eq!(std::fs::read_to_string(&path).unwrap(), text);
    }
}
