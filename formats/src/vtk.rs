//! VTK particle files: legacy `.vtk` (ASCII or binary; POLYDATA, UNSTRUCTURED_GRID,
//! STRUCTURED_GRID: `vtk_legacy`) and XML `.vtp` / `.vtu` (ascii, base64 binary, appended
//! raw or base64, zlib-compressed: `vtk_xml`), both read here rather than by vtkio.
//!
//! Why the XML reader is our own: vtkio 0.7 (a release candidate) hands the whole file to an
//! XML parser, and raw appended data is not valid XML — VTK's own writer produces exactly
//! such files. Parsing the few XML elements that matter with quick-xml and decoding the
//! DataArrays (inline or from the appended block) ourselves reads every variant VTK writes.
//! Why the legacy reader is: see `vtk_legacy`.

use crate::atomic::write_atomically;
use crate::error::{FormatError, Result};
use crate::memory::Limits;
use crate::particles::{ParticleArrayNames, ParticleSet};
use std::io::Write;
use std::path::Path;

/// A VTK particle file, legacy or XML by its content (a `.vtp` named `.vtk` is read as what
/// it is, as VTK's readers and pyvista do not).
pub fn read_vtk_particles(path: &Path, names: &ParticleArrayNames, limits: &Limits) -> Result<ParticleSet> {
    let mut head = [0u8; 64];
    let n = {
        use std::io::Read;
        std::fs::File::open(path).and_then(|mut f| f.read(&mut head)).map_err(|e| FormatError::io(path, e))?
    };
    // XML begins with '<' (after any byte-order mark or blank); anything else is legacy.
    let xml = head[..n].iter().find(|b| !b.is_ascii_whitespace() && !matches!(b, 0xEF | 0xBB | 0xBF)) == Some(&b'<');
    if xml {
        crate::vtk_xml::read_vtk_xml(path, names, limits)
    } else {
        crate::vtk_legacy::read_points(path, names, limits)
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
