//! GeoJSON line features, as GDAL's GeoJSON driver writes them for `gdal_contour`: a
//! FeatureCollection whose LineString features carry an `ID` and one numeric attribute,
//! coordinates in the raster's own CRS (x, y: longitude first for a geographic one), named
//! by the (2008 GeoJSON) `crs` member where its EPSG code is known — as GDAL does, so that GIS tools place the lines without being told.
//! Numbers are written in Rust's shortest round-trip form, so a reader gets back the exact
//! f64. Written atomically.

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
    let io = |e: std::io::Error| FormatError::io(path, e);
    let quoted = |s: &str| serde_json::to_string(s).expect("a string serialises");
    write_atomically(path, |w| {
        write_header(w, layer, crs).map_err(io)?;
        for (id, f) in features.into_iter().enumerate() {
            if !f.value.is_finite() || f.points.iter().flatten().any(|c| !c.is_finite()) {
                return Err(FormatError::invalid(path, format!("feature {id}: a coordinate or value is not finite")));
            }
            if id > 0 {
                w.write_all(b",\n").map_err(io)?;
            }
            write!(
                w,
                "{{\"type\":\"Feature\",\"properties\":{{\"ID\":{id},{}:{}}},\"geometry\":{{\"type\":\"LineString\",\"coordinates\":[",
                quoted(attribute),
                f.value
            )
            .map_err(io)?;
            for (i, p) in f.points.iter().enumerate() {
                let sep = if i > 0 { "," } else { "" };
                if three_d {
                    write!(w, "{sep}[{},{},{}]", p[0], p[1], f.value).map_err(io)?;
                } else {
                    write!(w, "{sep}[{},{}]", p[0], p[1]).map_err(io)?;
                }
            }
            w.write_all(b"]}}").map_err(io)?;
        }
        w.write_all(b"\n]}\n").map_err(io)?;
        Ok(())
    })
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
    let io = |e: std::io::Error| FormatError::io(path, e);
    let quoted = |s: &str| serde_json::to_string(s).expect("a string serialises");
    write_atomically(path, |w| {
        write_header(w, layer, crs).map_err(io)?;
        for (id, f) in features.into_iter().enumerate() {
            let finite = f.polygons.iter().flatten().flatten().flatten().all(|c| c.is_finite());
            if !f.min.is_finite() || !f.max.is_finite() || !finite {
                return Err(FormatError::invalid(path, format!("feature {id}: a coordinate or value is not finite")));
            }
            if id > 0 {
                w.write_all(b",\n").map_err(io)?;
            }
            write!(
                w,
                "{{\"type\":\"Feature\",\"properties\":{{\"ID\":{id},{}:{},{}:{}}},\"geometry\":{{\"type\":\"MultiPolygon\",\"coordinates\":[",
                quoted(min_name),
                f.min,
                quoted(max_name),
                f.max
            )
            .map_err(io)?;
            for (pi, poly) in f.polygons.iter().enumerate() {
                w.write_all(if pi > 0 { b",[" } else { b"[" }).map_err(io)?;
                for (ri, ring) in poly.iter().enumerate() {
                    w.write_all(if ri > 0 { b",[" } else { b"[" }).map_err(io)?;
                    for (i, p) in ring.iter().enumerate() {
                        write!(w, "{}[{},{}]", if i > 0 { "," } else { "" }, p[0], p[1]).map_err(io)?;
                    }
                    w.write_all(b"]").map_err(io)?;
                }
                w.write_all(b"]").map_err(io)?;
            }
            w.write_all(b"]}}").map_err(io)?;
        }
        w.write_all(b"\n]}\n").map_err(io)?;
        Ok(())
    })
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
        let crs = Crs { epsg: Some(32610), geographic: false, description: String::new() };
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
}
