//! The files GDAL reads beside a raster for what the raster itself does not say: the PAM
//! file (`NAME.tif.aux.xml`: georeferencing, CRS as WKT, a band's NoData), the world file
//! (`NAME.tfw`, `NAME.tifw`, `NAME.wld`: the affine transform to map coordinates) and the
//! ESRI projection file (`NAME.prj`: a CRS as WKT).
//!
//! `gdal_translate -co PROFILE=BASELINE -co TFW=YES` writes a plain TIFF with a `.tfw` and
//! an `.aux.xml`; ESRI tools write a `.tfw` and a `.prj`. GDAL's GeoTIFF driver takes each
//! item from the first of its sources that has it, in the order of its GEOREF_SOURCES
//! default `PAM,INTERNAL,TABFILE,WORLDFILE` (GDAL 3.6, checked with gdalinfo): the PAM
//! file before the GeoTIFF tags, the tags before a world file; a band's NoData from the PAM
//! file before the GDAL_NODATA tag. GDAL's GeoTIFF driver does not read a `.prj`; we take a
//! CRS from it only where nothing else gives one, and say so in a note.

use crate::error::{FormatError, Result};
use crate::heightfield::Crs;
use std::path::{Path, PathBuf};

/// The largest sidecar read: a PAM file holds metadata and perhaps histograms, a world file
/// six numbers. A larger one is refused rather than read into memory.
const MAX_SIDECAR_BYTES: u64 = 16 << 20;

/// A GDAL geotransform: map x = g0 + col·g1 + row·g2, map y = g3 + col·g4 + row·g5, for
/// (col, row) = (0, 0) at the outer corner of the first pixel.
pub type GeoTransform = [f64; 6];

/// What a raster's PAM file (`NAME.aux.xml`) says.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Pam {
    pub path: PathBuf,
    pub geotransform: Option<GeoTransform>,
    /// The CRS as WKT (GDAL writes WKT1; WKT2 is read as well).
    pub srs: Option<String>,
    /// Band 1's NoData value.
    pub nodata: Option<f64>,
}

/// A sidecar's contents, or None where there is no such file.
fn read_sidecar(path: &Path) -> Result<Option<String>> {
    let meta = match std::fs::metadata(path) {
        Ok(m) if m.is_file() => m,
        _ => return Ok(None),
    };
    if meta.len() > MAX_SIDECAR_BYTES {
        return Err(FormatError::invalid(
            path,
            format!("sidecar of {} bytes, more than the {} MiB a sidecar may have", meta.len(), MAX_SIDECAR_BYTES >> 20),
        ));
    }
    let bytes = std::fs::read(path).map_err(|e| FormatError::io(path, e))?;
    String::from_utf8(bytes).map(Some).map_err(|_| FormatError::invalid(path, "sidecar is not UTF-8 text"))
}

/// `raster` with `suffix` appended to its whole name (`a.tif` → `a.tif.aux.xml`).
fn appended(raster: &Path, suffix: &str) -> PathBuf {
    let mut s = raster.as_os_str().to_owned();
    s.push(suffix);
    PathBuf::from(s)
}

/// The first existing file among `raster` with each extension, trying each in lower then
/// upper case (as GDAL does on case-sensitive file systems).
fn with_extension(raster: &Path, extensions: &[String]) -> Option<PathBuf> {
    extensions.iter().flat_map(|e| [e.to_lowercase(), e.to_uppercase()]).map(|e| raster.with_extension(e)).find(|p| p.is_file())
}

/// The raster's PAM file, where it has one.
pub fn read_pam(raster: &Path) -> Result<Option<Pam>> {
    let path = appended(raster, ".aux.xml");
    let Some(text) = read_sidecar(&path)? else { return Ok(None) };
    parse_pam(&path, &text).map(Some)
}

/// The PAM file's georeferencing, CRS and band 1's NoData. Other elements (metadata,
/// statistics, histograms, other bands) are skipped.
fn parse_pam(path: &Path, text: &str) -> Result<Pam> {
    use quick_xml::events::Event;
    let bad = |what: String| FormatError::invalid(path, format!("PAM sidecar is not valid XML: {what}"));
    let mut reader = quick_xml::Reader::from_str(text);
    let mut pam = Pam { path: path.to_path_buf(), ..Default::default() };
    // Element names from the root down, and whether the band open is band 1.
    let mut stack: Vec<String> = Vec::new();
    let mut band_one = Vec::new();
    let mut seen_root = false;
    loop {
        match reader.read_event().map_err(|e| bad(e.to_string()))? {
            Event::Start(e) => {
                let name = String::from_utf8_lossy(e.name().as_ref()).into_owned();
                if stack.is_empty() {
                    if name != "PAMDataset" {
                        return Err(FormatError::invalid(path, format!("PAM sidecar's root is <{name}>, not <PAMDataset>")));
                    }
                    seen_root = true;
                }
                let is_band_one =
                    name == "PAMRasterBand" && e.attributes().flatten().any(|a| a.key.as_ref() == b"band" && a.value.as_ref() == b"1");
                band_one.push(is_band_one);
                stack.push(name);
            }
            Event::Empty(e) if stack.is_empty() => {
                let name = String::from_utf8_lossy(e.name().as_ref()).into_owned();
                if name != "PAMDataset" {
                    return Err(FormatError::invalid(path, format!("PAM sidecar's root is <{name}>, not <PAMDataset>")));
                }
                seen_root = true;
            }
            Event::End(_) => {
                stack.pop();
                band_one.pop();
            }
            Event::Text(t) => {
                let value = t.unescape().map_err(|e| bad(e.to_string()))?;
                let value = value.trim();
                match stack.iter().map(String::as_str).collect::<Vec<_>>().as_slice() {
                    ["PAMDataset", "SRS"] => pam.srs = Some(value.to_string()),
                    ["PAMDataset", "GeoTransform"] => {
                        let numbers: Vec<f64> = value
                            .split(',')
                            .map(|s| s.trim().parse::<f64>())
                            .collect::<std::result::Result<_, _>>()
                            .map_err(|_| FormatError::invalid(path, format!("PAM GeoTransform '{value}' is not six numbers")))?;
                        let gt: GeoTransform = numbers
                            .try_into()
                            .map_err(|_| FormatError::invalid(path, format!("PAM GeoTransform '{value}' is not six numbers")))?;
                        pam.geotransform = Some(gt);
                    }
                    ["PAMDataset", "PAMRasterBand", "NoDataValue"] if band_one.get(1) == Some(&true) => {
                        // GDAL writes "nan" / "inf" as well as numbers.
                        let v = parse_gdal_number(value)
                            .ok_or_else(|| FormatError::invalid(path, format!("PAM NoDataValue '{value}' is not a number")))?;
                        pam.nodata = Some(v);
                    }
                    _ => {}
                }
            }
            Event::Eof => break,
            _ => {}
        }
    }
    if !seen_root {
        return Err(FormatError::invalid(path, "PAM sidecar has no <PAMDataset> element"));
    }
    Ok(pam)
}

/// A number as GDAL writes it in text (also `nan`, `inf`, `-inf`, any case).
fn parse_gdal_number(s: &str) -> Option<f64> {
    let t = s.trim();
    match t.to_ascii_lowercase().as_str() {
        "nan" | "-nan" | "1.#qnan" => Some(f64::NAN),
        "inf" | "+inf" | "infinity" => Some(f64::INFINITY),
        "-inf" | "-infinity" => Some(f64::NEG_INFINITY),
        _ => t.parse().ok(),
    }
}

/// The raster's world file, where it has one, as a geotransform: `NAME.tfw`, `NAME.tifw`,
/// `NAME.wld` for `NAME.tif` (GDAL's names: the extension's first and last letters and a
/// `w`, the extension and a `w`, then `wld`).
pub fn read_world_file(raster: &Path) -> Result<Option<(PathBuf, GeoTransform)>> {
    let ext = raster.extension().map(|e| e.to_string_lossy().into_owned()).unwrap_or_default();
    let mut candidates = Vec::new();
    let mut chars = ext.chars();
    if let (Some(first), Some(last)) = (chars.next(), ext.chars().last()) {
        if ext.chars().count() >= 2 {
            candidates.push(format!("{first}{last}w"));
        }
        candidates.push(format!("{ext}w"));
    }
    candidates.push("wld".to_string());
    let Some(path) = with_extension(raster, &candidates) else { return Ok(None) };
    let Some(text) = read_sidecar(&path)? else { return Ok(None) };
    parse_world_file(&path, &text).map(|gt| Some((path, gt)))
}

/// Six numbers, one a line: x size of a pixel, rotation terms, y size (negative for
/// north-up), and the map coordinates of the *centre* of the first pixel. Returned as
/// GDAL's geotransform (the first pixel's outer corner).
fn parse_world_file(path: &Path, text: &str) -> Result<GeoTransform> {
    let lines: Vec<&str> = text.lines().map(str::trim).filter(|l| !l.is_empty()).take(6).collect();
    let numbers: Vec<f64> = lines.iter().filter_map(|l| l.split_whitespace().next()?.parse::<f64>().ok()).collect();
    if lines.len() < 6 || numbers.len() < 6 || numbers.iter().any(|v| !v.is_finite()) {
        return Err(FormatError::invalid(path, "world file must hold six finite numbers, one a line"));
    }
    let [a, d, b, e, c, f] = [numbers[0], numbers[1], numbers[2], numbers[3], numbers[4], numbers[5]];
    if a == 0.0 && b == 0.0 || d == 0.0 && e == 0.0 {
        return Err(FormatError::invalid(path, "world file gives a pixel size of 0"));
    }
    Ok([c - 0.5 * a - 0.5 * b, a, b, f - 0.5 * d - 0.5 * e, d, e])
}

/// The raster's ESRI projection file (`NAME.prj`), where it has one: its WKT.
pub fn read_prj(raster: &Path) -> Result<Option<(PathBuf, String)>> {
    let Some(path) = with_extension(raster, &["prj".to_string()]) else { return Ok(None) };
    Ok(read_sidecar(&path)?.map(|t| (path, t.trim().to_string())))
}

/// A WKT node: its keyword and its values (quoted strings, numbers, bare words, nodes).
#[derive(Debug, Clone, PartialEq)]
enum Wkt {
    Node(String, Vec<Wkt>),
    Text(String),
    Word(String),
}

impl Wkt {
    fn children(&self) -> &[Wkt] {
        match self {
            Wkt::Node(_, c) => c,
            _ => &[],
        }
    }
    fn child(&self, keywords: &[&str]) -> Option<&Wkt> {
        self.children().iter().find(|c| matches!(c, Wkt::Node(k, _) if keywords.iter().any(|w| k.eq_ignore_ascii_case(w))))
    }
    fn keyword(&self) -> &str {
        match self {
            Wkt::Node(k, _) => k,
            _ => "",
        }
    }
    fn text(&self, i: usize) -> Option<&str> {
        match self.children().get(i)? {
            Wkt::Text(s) | Wkt::Word(s) => Some(s),
            _ => None,
        }
    }
}

/// Parses WKT (1 or 2; brackets or parentheses) into a tree, at most 64 levels deep.
fn parse_wkt(s: &str) -> std::result::Result<Wkt, String> {
    fn skip_ws(b: &[u8], i: &mut usize) {
        while *i < b.len() && b[*i].is_ascii_whitespace() {
            *i += 1;
        }
    }
    fn node(b: &[u8], i: &mut usize, depth: usize) -> std::result::Result<Wkt, String> {
        if depth > 64 {
            return Err("nested more than 64 levels".into());
        }
        skip_ws(b, i);
        let start = *i;
        while *i < b.len() && (b[*i].is_ascii_alphanumeric() || b[*i] == b'_') {
            *i += 1;
        }
        let keyword = String::from_utf8_lossy(&b[start..*i]).into_owned();
        if keyword.is_empty() {
            return Err(format!("a keyword expected at byte {start}"));
        }
        skip_ws(b, i);
        let close = match b.get(*i) {
            Some(b'[') => b']',
            Some(b'(') => b')',
            _ => return Ok(Wkt::Word(keyword)),
        };
        *i += 1;
        let mut values = Vec::new();
        loop {
            skip_ws(b, i);
            match b.get(*i) {
                None => return Err(format!("{keyword}[ is not closed")),
                Some(&c) if c == close => {
                    *i += 1;
                    return Ok(Wkt::Node(keyword, values));
                }
                Some(b',') => *i += 1,
                Some(b'"') => {
                    // A quoted string; "" is a quote inside it.
                    *i += 1;
                    let mut text = Vec::new();
                    loop {
                        match b.get(*i) {
                            None => return Err("a quoted string is not closed".into()),
                            Some(b'"') if b.get(*i + 1) == Some(&b'"') => {
                                text.push(b'"');
                                *i += 2;
                            }
                            Some(b'"') => {
                                *i += 1;
                                break;
                            }
                            Some(&c) => {
                                text.push(c);
                                *i += 1;
                            }
                        }
                    }
                    values.push(Wkt::Text(String::from_utf8_lossy(&text).into_owned()));
                }
                Some(c) if c.is_ascii_digit() || matches!(c, b'-' | b'+' | b'.') => {
                    let start = *i;
                    while *i < b.len() && (b[*i].is_ascii_alphanumeric() || matches!(b[*i], b'-' | b'+' | b'.')) {
                        *i += 1;
                    }
                    values.push(Wkt::Word(String::from_utf8_lossy(&b[start..*i]).into_owned()));
                }
                Some(_) => values.push(node(b, i, depth + 1)?),
            }
        }
    }
    let b = s.as_bytes();
    let mut i = 0;
    let tree = node(b, &mut i, 0)?;
    skip_ws(b, &mut i);
    if i != b.len() {
        return Err(format!("text after the CRS at byte {i}"));
    }
    Ok(tree)
}

/// The CRS a WKT string describes: its EPSG code where it names one, whether it is
/// geographic, and for a projected CRS the metres in one unit of its coordinates. A
/// compound CRS is its horizontal part; a bound CRS (WKT2's BOUNDCRS) its source.
pub fn crs_from_wkt(source: &Path, wkt: &str) -> Result<Crs> {
    let tree = parse_wkt(wkt).map_err(|e| FormatError::invalid(source, format!("CRS is not valid WKT: {e}")))?;
    let mut crs = &tree;
    for _ in 0..4 {
        let next = match crs.keyword().to_ascii_uppercase().as_str() {
            "COMPD_CS" | "COMPOUNDCRS" => crs.children().iter().find(|c| matches!(c, Wkt::Node(..))),
            "BOUNDCRS" => crs.child(&["SOURCECRS"]).and_then(|s| s.children().iter().find(|c| matches!(c, Wkt::Node(..)))),
            _ => None,
        };
        match next {
            Some(n) => crs = n,
            None => break,
        }
    }
    let keyword = crs.keyword().to_ascii_uppercase();
    let geographic = match keyword.as_str() {
        "PROJCS" | "PROJCRS" | "PROJECTEDCRS" => false,
        "GEOGCS" | "GEOGCRS" | "GEOGRAPHICCRS" => true,
        // WKT2's geodetic CRS is geographic with an ellipsoidal coordinate system.
        "GEODCRS" | "GEODETICCRS" => match crs.child(&["CS"]).and_then(|cs| cs.text(0)) {
            Some(t) if t.eq_ignore_ascii_case("ellipsoidal") => true,
            _ => return Err(FormatError::unsupported(source, "CRS is geocentric: a raster needs a geographic or projected CRS")),
        },
        "LOCAL_CS" | "ENGCRS" | "ENGINEERINGCRS" => false,
        "GEOCCS" => return Err(FormatError::unsupported(source, "CRS is geocentric: a raster needs a geographic or projected CRS")),
        other => return Err(FormatError::unsupported(source, format!("CRS of kind {other} is not a geographic or projected CRS"))),
    };
    let name = crs.text(0).unwrap_or("").to_string();
    // The CRS's own identifier: WKT1's AUTHORITY["EPSG","4326"], WKT2's ID["EPSG",4326].
    let epsg = crs
        .children()
        .iter()
        .rev()
        .find(|c| {
            matches!(c, Wkt::Node(k, _) if k.eq_ignore_ascii_case("AUTHORITY") || k.eq_ignore_ascii_case("ID"))
                && c.text(0).is_some_and(|a| a.eq_ignore_ascii_case("EPSG"))
        })
        .and_then(|c| c.text(1)?.parse::<u32>().ok());
    // A projected CRS's linear unit: WKT1's UNIT at the CRS's own level, WKT2's LENGTHUNIT
    // there or on its coordinate system's first axis.
    let metres_per_unit = if geographic {
        1.0
    } else {
        let unit = crs.child(&["UNIT", "LENGTHUNIT"]).or_else(|| {
            crs.children().iter().find(|c| c.keyword().eq_ignore_ascii_case("AXIS")).and_then(|a| a.child(&["LENGTHUNIT", "UNIT"]))
        });
        match unit.and_then(|u| u.text(1)).map(|f| f.parse::<f64>()) {
            None => 1.0,
            Some(Ok(f)) if f.is_finite() && f > 0.0 => f,
            Some(_) => return Err(FormatError::invalid(source, "CRS's linear unit is not a positive number of metres")),
        }
    };
    let mut description = match epsg {
        Some(c) => format!("EPSG:{c}"),
        None => "user-defined CRS".to_string(),
    };
    description.push_str(if geographic { " (geographic)" } else { " (projected)" });
    if !name.is_empty() {
        description.push(' ');
        description.push_str(&name);
    }
    Ok(Crs { epsg, geographic, description, metres_per_unit })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn world_file_centre_to_corner() {
        let gt = parse_world_file(Path::new("a.tfw"), "30\n0\n0\n-30\n500015\n4200015\n").unwrap();
        assert_eq!(gt, [500000.0, 30.0, 0.0, 4200030.0, 0.0, -30.0]);
        assert!(parse_world_file(Path::new("a.tfw"), "30\n0\n0\n-30\n500015\n").is_err());
        assert!(parse_world_file(Path::new("a.tfw"), "0\n0\n0\n0\n1\n1\n").is_err());
    }

    #[test]
    fn wkt1_and_wkt2() {
        let utm = r#"PROJCS["WGS 84 / UTM zone 10N",GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563,AUTHORITY["EPSG","7030"]],AUTHORITY["EPSG","6326"]],PRIMEM["Greenwich",0],UNIT["degree",0.0174532925199433],AUTHORITY["EPSG","4326"]],PROJECTION["Transverse_Mercator"],PARAMETER["central_meridian",-123],UNIT["metre",1,AUTHORITY["EPSG","9001"]],AXIS["Easting",EAST],AXIS["Northing",NORTH],AUTHORITY["EPSG","32610"]]"#;
        let c = crs_from_wkt(Path::new("x"), utm).unwrap();
        assert_eq!((c.epsg, c.geographic, c.metres_per_unit), (Some(32610), false, 1.0));
        let ft = r#"PROJCS["NAD83(HARN) / Washington North (ftUS)",GEOGCS["NAD83(HARN)",DATUM["x",SPHEROID["GRS 1980",6378137,298.257222101]]],UNIT["US survey foot",0.304800609601219,AUTHORITY["EPSG","9003"]],AUTHORITY["EPSG","2926"]]"#;
        let c = crs_from_wkt(Path::new("x"), ft).unwrap();
        assert_eq!((c.epsg, c.metres_per_unit), (Some(2926), 0.304800609601219));
        let wkt2 = r#"GEOGCRS["WGS 84",DATUM["World Geodetic System 1984",ELLIPSOID["WGS 84",6378137,298.257223563,LENGTHUNIT["metre",1]]],CS[ellipsoidal,2],AXIS["latitude",north,ANGLEUNIT["degree",0.0174532925199433]],ID["EPSG",4326]]"#;
        let c = crs_from_wkt(Path::new("x"), wkt2).unwrap();
        assert_eq!((c.epsg, c.geographic), (Some(4326), true));
        let esri = r#"PROJCS["NAD_1983_UTM_Zone_10N",GEOGCS["GCS_North_American_1983",DATUM["D_North_American_1983",SPHEROID["GRS_1980",6378137.0,298.257222101]],PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]],PROJECTION["Transverse_Mercator"],UNIT["Meter",1.0]]"#;
        let c = crs_from_wkt(Path::new("x"), esri).unwrap();
        assert_eq!((c.epsg, c.geographic, c.metres_per_unit), (None, false, 1.0));
        assert!(crs_from_wkt(Path::new("x"), "PROJCS[\"x\"").is_err());
        assert!(crs_from_wkt(Path::new("x"), &"A[".repeat(100)).is_err());
    }

    #[test]
    fn pam_band_one_only() {
        let xml = r#"<PAMDataset><SRS dataAxisToSRSAxisMapping="2,1">GEOGCS["WGS 84",AUTHORITY["EPSG","4326"]]</SRS>
            <GeoTransform> -9.7e+01, 8.3e-04, 0, 3.2e+01, 0, -8.3e-04</GeoTransform>
            <PAMRasterBand band="2"><NoDataValue>7</NoDataValue></PAMRasterBand>
            <PAMRasterBand band="1"><NoDataValue>-3.27680000000000E+04</NoDataValue></PAMRasterBand></PAMDataset>"#;
        let pam = parse_pam(Path::new("a.tif.aux.xml"), xml).unwrap();
        assert_eq!(pam.geotransform, Some([-97.0, 8.3e-4, 0.0, 32.0, 0.0, -8.3e-4]));
        assert_eq!(pam.nodata, Some(-32768.0));
        assert!(pam.srs.unwrap().starts_with("GEOGCS"));
        assert!(parse_pam(Path::new("a"), "<Other/>").is_err());
        assert!(parse_pam(Path::new("a"), "<PAMDataset><GeoTransform>1,2</GeoTransform></PAMDataset>").is_err());
    }
}
