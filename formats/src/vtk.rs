//! VTK particle files: legacy `.vtk` (ASCII or binary; POLYDATA, UNSTRUCTURED_GRID or bare
//! points) through `vtkio`, and XML `.vtp` / `.vtu` (ascii, base64 binary, appended raw or
//! base64, zlib-compressed) read here.
//!
//! Why the XML reader is our own: vtkio 0.7 (a release candidate) hands the whole file to an
//! XML parser, and raw appended data is not valid XML — VTK's own writer produces exactly
//! such files. Parsing the few XML elements that matter with quick-xml and decoding the
//! DataArrays (inline or from the appended block) ourselves reads every variant VTK writes.

use crate::atomic::write_atomically;
use crate::error::{FormatError, Result};
use crate::memory::Limits;
use crate::particles::{ParticleArrayNames, ParticleSet, PointArray};
use std::io::Write;
use std::path::Path;

pub fn read_vtk_particles(path: &Path, names: &ParticleArrayNames, limits: &Limits) -> Result<ParticleSet> {
    let ext = path.extension().map(|e| e.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
    match ext.as_str() {
        "vtp" | "vtu" => crate::vtk_xml::read_vtk_xml(path, names, limits),
        _ => read_legacy(path, names, limits),
    }
}

fn read_legacy(path: &Path, names: &ParticleArrayNames, limits: &Limits) -> Result<ParticleSet> {
    use vtkio::model::{Attribute, DataSet};
    let head = {
        use std::io::Read;
        let mut b = [0u8; 256];
        let mut f = std::fs::File::open(path).map_err(|e| FormatError::io(path, e))?;
        let n = f.read(&mut b).map_err(|e| FormatError::io(path, e))?;
        b[..n].to_vec()
    };
    if !head.starts_with(b"# vtk DataFile") {
        return Err(FormatError::invalid(path, "not a legacy VTK file (no '# vtk DataFile' header)"));
    }
    // Guard before vtkio allocates: the file and the POINTS it declares must fit the memory
    // limit, and the points must be there (vtkio reports a short file as "Parse error: Digit").
    let len = std::fs::metadata(path).map_err(|e| FormatError::io(path, e))?.len();
    // Held at once at the peak: the file, vtkio's arrays, their f64 copies and the
    // positions — measured 4.2× a binary file of f32 points. ASCII numbers take at least
    // two bytes each and become up to 24 bytes (vtkio's f64, ours, the positions).
    let ascii = head.split(|&b| b == b'\n').nth(2).is_some_and(|l| l.trim_ascii().eq_ignore_ascii_case(b"ASCII"));
    limits.check(path, "VTK file as it is read", &[len, if ascii { 12 } else { 5 }])?;
    let mut bytes = std::fs::read(path).map_err(|e| FormatError::io(path, e))?;
    check_legacy_points(path, &bytes, limits)?;
    // Legacy binary is big-endian by the format's definition. vtkio parses the bytes read
    // above (its reader appends nothing from an empty one): the file is read once.
    let vtk = crate::guard::third_party(path, "the legacy VTK parser", || {
        vtkio::Vtk::parse_legacy_buf_be(std::io::empty(), &mut bytes)
            .map_err(|e| FormatError::invalid(path, format!("legacy VTK is malformed or truncated (vtkio: {})", short(&e.to_string()))))
    })?;
    let (points, attributes) = match vtk.data {
        DataSet::PolyData { pieces, .. } => {
            let p = first_piece(path, pieces)?;
            (p.points, p.data)
        }
        DataSet::UnstructuredGrid { pieces, .. } => {
            let p = first_piece(path, pieces)?;
            (p.points, p.data)
        }
        DataSet::StructuredGrid { pieces, .. } => {
            let p = first_piece(path, pieces)?;
            (p.points, p.data)
        }
        _ => {
            return Err(FormatError::unsupported(
                path,
                "dataset holds no points (only POLYDATA, UNSTRUCTURED_GRID and STRUCTURED_GRID carry particles)",
            ))
        }
    };
    let coords: Vec<f64> = points.cast_into::<f64>().ok_or_else(|| FormatError::invalid(path, "POINTS are not numeric"))?;
    if !coords.len().is_multiple_of(3) {
        return Err(FormatError::invalid(path, "POINTS length is not a multiple of 3"));
    }
    let positions: Vec<[f64; 3]> = coords.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    let mut arrays = Vec::new();
    for a in attributes.point {
        match a {
            Attribute::DataArray(d) => {
                let values =
                    d.data.cast_into::<f64>().ok_or_else(|| FormatError::invalid(path, format!("array '{}' is not numeric", d.name)))?;
                arrays.push(PointArray { name: d.name, components: d.elem.num_comp() as usize, values });
            }
            Attribute::Field { data_array, .. } => {
                for f in data_array {
                    let values = f
                        .data
                        .cast_into::<f64>()
                        .ok_or_else(|| FormatError::invalid(path, format!("field array '{}' is not numeric", f.name)))?;
                    arrays.push(PointArray { name: f.name, components: f.elem as usize, values });
                }
            }
        }
    }
    let version = match vtk.version {
        vtkio::model::Version::Legacy { major, minor } => format!("{major}.{minor}"),
        other => format!("{other:?}"),
    };
    let notes = vec![format!("legacy VTK {version}, {} points", positions.len())];
    ParticleSet::from_arrays(positions, arrays, names, notes).map_err(|m| FormatError::invalid(path, m))
}

/// Checks the POINTS line of a legacy file against the memory limit and against what
/// follows it: enough bytes (binary) or numbers (ASCII) for every point.
fn check_legacy_points(path: &Path, bytes: &[u8], limits: &Limits) -> Result<()> {
    let mut lines = bytes.split(|&b| b == b'\n');
    let binary = lines.nth(2).is_some_and(|l| String::from_utf8_lossy(l).trim().eq_ignore_ascii_case("BINARY"));
    let Some(at) = bytes.windows(8).position(|w| w == b"\nPOINTS ") else { return Ok(()) };
    let line_end = bytes[at + 1..].iter().position(|&b| b == b'\n').map_or(bytes.len(), |i| at + 1 + i);
    let line = String::from_utf8_lossy(&bytes[at + 1..line_end]).into_owned();
    let mut words = line.split_whitespace().skip(1);
    let count = words.next().unwrap_or("");
    let n: u64 = count.parse().map_err(|_| FormatError::invalid(path, format!("POINTS count '{count}' is not a number")))?;
    let ty = words.next().unwrap_or("float").to_ascii_lowercase();
    limits.check(path, "POINTS", &[n, 3, 8])?;
    let rest = bytes.get(line_end + 1..).unwrap_or(&[]);
    if binary {
        let size = match ty.as_str() {
            "double" | "long" | "unsigned_long" | "vtkidtype" => 8,
            "short" | "unsigned_short" => 2,
            "char" | "unsigned_char" | "bit" => 1,
            _ => 4,
        };
        let need = n * 3 * size;
        if (rest.len() as u64) < need {
            return Err(FormatError::invalid(
                path,
                format!("POINTS declares {n} points ({need} bytes of {ty}) but only {} bytes follow", rest.len()),
            ));
        }
    } else {
        let need = n * 3;
        let mut found = 0u64;
        for word in rest.split(|b| b.is_ascii_whitespace()).filter(|w| !w.is_empty()) {
            if found == need || (word[0].is_ascii_alphabetic() && !word.eq_ignore_ascii_case(b"nan") && !word.eq_ignore_ascii_case(b"inf"))
            {
                break;
            }
            found += 1;
        }
        if found < need {
            return Err(FormatError::invalid(
                path,
                format!("POINTS declares {n} points but only {found} coordinates follow ({need} needed)"),
            ));
        }
    }
    Ok(())
}

/// Pieces other than inline ones only occur in XML parallel files.
fn first_piece<P>(path: &Path, pieces: Vec<vtkio::model::Piece<P>>) -> Result<P> {
    match pieces.into_iter().next() {
        Some(vtkio::model::Piece::Inline(p)) => Ok(*p),
        Some(_) => Err(FormatError::unsupported(path, "piece references another file")),
        None => Err(FormatError::invalid(path, "dataset has no piece")),
    }
}

fn short(s: &str) -> String {
    let l = s.lines().next().unwrap_or(s);
    if l.len() > 200 {
        format!("{}…", &l[..200])
    } else {
        l.to_string()
    }
}

/// Writes particles as VTK XML PolyData (`.vtp`): one vertex cell per point, every array
/// as a Float64 (positions) or Float32/Float64 DataArray, base64 inline binary with UInt64
/// headers — readable by VTK, ParaView and pyvista. Written atomically.
pub fn write_vtp(path: &Path, set: &ParticleSet, names: &ParticleArrayNames) -> Result<()> {
    use base64::Engine;
    let b64 = |bytes: &[u8]| {
        let mut with_header = (bytes.len() as u64).to_le_bytes().to_vec();
        with_header.extend_from_slice(bytes);
        base64::engine::general_purpose::STANDARD.encode(with_header)
    };
    let n = set.len();
    let f32_bytes = |v: &[f32]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    let mut body = String::new();
    body.push_str(&format!(
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"PolyData\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n<PolyData>\n<Piece NumberOfPoints=\"{n}\" NumberOfVerts=\"{n}\" NumberOfLines=\"0\" NumberOfStrips=\"0\" NumberOfPolys=\"0\">\n<PointData>\n"
    ));
    let sph = [(&names.mass, &set.mass), (&names.density, &set.density), (&names.smoothing_length, &set.smoothing_length)];
    for (name, v) in sph {
        if let Some(v) = v {
            body.push_str(&format!(
                "<DataArray type=\"Float32\" Name=\"{}\" NumberOfComponents=\"1\" format=\"binary\">{}</DataArray>\n",
                xml_escape(name),
                b64(&f32_bytes(v))
            ));
        }
    }
    for a in &set.arrays {
        let bytes: Vec<u8> = a.values.iter().flat_map(|x| x.to_le_bytes()).collect();
        body.push_str(&format!(
            "<DataArray type=\"Float64\" Name=\"{}\" NumberOfComponents=\"{}\" format=\"binary\">{}</DataArray>\n",
            xml_escape(&a.name),
            a.components,
            b64(&bytes)
        ));
    }
    body.push_str("</PointData>\n<Points>\n");
    let pts: Vec<u8> = set.positions.iter().flat_map(|p| p.iter().flat_map(|x| x.to_le_bytes())).collect();
    body.push_str(&format!("<DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"binary\">{}</DataArray>\n", b64(&pts)));
    body.push_str("</Points>\n<Verts>\n");
    let conn: Vec<u8> = (0..n as i64).flat_map(|i| i.to_le_bytes()).collect();
    let offs: Vec<u8> = (1..=n as i64).flat_map(|i| i.to_le_bytes()).collect();
    body.push_str(&format!("<DataArray type=\"Int64\" Name=\"connectivity\" format=\"binary\">{}</DataArray>\n", b64(&conn)));
    body.push_str(&format!("<DataArray type=\"Int64\" Name=\"offsets\" format=\"binary\">{}</DataArray>\n", b64(&offs)));
    body.push_str("</Verts>\n</Piece>\n</PolyData>\n</VTKFile>\n");
    write_atomically(path, |w| w.write_all(body.as_bytes()).map_err(|e| FormatError::io(path, e)))
}

fn xml_escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}
