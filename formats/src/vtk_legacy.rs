//! Legacy VTK files (`.vtk`), read here: the tokenizer both legacy readers use, and the
//! point sets (POLYDATA, UNSTRUCTURED_GRID, STRUCTURED_GRID, POLYDATA without cells) read
//! as particles with every point array.
//!
//! Why not vtkio: vtkio 0.7 (a release candidate) does not read legacy files as VTK 9 and
//! pyvista write them today (`# vtk DataFile Version 5.1`): an ASCII file's `OFFSETS` /
//! `CONNECTIVITY` cell lists fail with "Parse error: Digit", and in a binary one the point
//! arrays after a dataset-level `FIELD FieldData` block were dropped without a word. The
//! format is small and line-based; read here, every version (2.0 … 5.1), both encodings
//! (ASCII; BINARY, big-endian by the format's definition) and every attribute kind (SCALARS
//! with any component count, COLOR_SCALARS, VECTORS, NORMALS, TEXTURE_COORDINATES, TENSORS,
//! TENSORS6, GLOBAL_IDS, PEDIGREE_IDS, EDGE_FLAGS, FIELD arrays) read as pyvista reads them:
//! each point array by its name (VTK's %xx escapes decoded), in file order. Cells, cell data,
//! lookup tables, METADATA blocks and dataset-level field data are skipped by their declared
//! sizes, which are checked against what the file holds before anything is allocated.

use crate::error::{FormatError, Result};
use crate::memory::Limits;
use crate::particles::{ParticleArrayNames, ParticleSet, PointArray};
use std::path::Path;

/// A cursor over a legacy file: header lines, then data (binary or ASCII words).
pub(crate) struct Cursor<'a> {
    pub(crate) path: &'a Path,
    pub(crate) b: &'a [u8],
    pub(crate) pos: usize,
}

/// Bytes of one binary value of a legacy type name (None: not a numeric type).
pub(crate) fn type_size(ty: &str) -> Option<usize> {
    Some(match ty.to_ascii_lowercase().as_str() {
        "bit" | "char" | "unsigned_char" | "signed_char" | "vtktypeint8" | "vtktypeuint8" => 1,
        "short" | "unsigned_short" | "vtktypeint16" | "vtktypeuint16" => 2,
        "int" | "unsigned_int" | "float" | "vtkidtype" | "vtktypeint32" | "vtktypeuint32" | "vtktypefloat32" => 4,
        "long" | "unsigned_long" | "double" | "vtktypeint64" | "vtktypeuint64" | "vtktypefloat64" => 8,
        _ => return None,
    })
}

impl<'a> Cursor<'a> {
    /// The next non-empty line, trimmed; a METADATA block (VTK 5: component names and
    /// information keys after an array, ended by an empty line) is passed over.
    pub(crate) fn line(&mut self) -> Option<String> {
        while let Some(l) = self.raw_line() {
            let l = l.trim();
            if l.eq_ignore_ascii_case("METADATA") {
                while self.raw_line().is_some_and(|m| !m.trim().is_empty()) {}
                continue;
            }
            if !l.is_empty() {
                return Some(l.to_string());
            }
        }
        None
    }

    /// The next line as it is (None at the end).
    fn raw_line(&mut self) -> Option<String> {
        if self.pos >= self.b.len() {
            return None;
        }
        let end = self.b[self.pos..].iter().position(|&c| c == b'\n').map_or(self.b.len(), |i| self.pos + i);
        let l = String::from_utf8_lossy(&self.b[self.pos..end]).into_owned();
        // Past the newline; at the end where the last line has none.
        self.pos = (end + 1).min(self.b.len());
        Some(l)
    }

    pub(crate) fn expect_line(&mut self, what: &str) -> Result<String> {
        self.line().ok_or_else(|| FormatError::invalid(self.path, format!("file is truncated: no {what}")))
    }

    /// The bytes after the cursor.
    fn remaining(&self) -> usize {
        self.b.len().saturating_sub(self.pos)
    }

    /// `count` values of `ty` as f64: big-endian binary, or ASCII words (`nan`, `inf`
    /// read as VTK writes them). What they would take is checked against `limits` and,
    /// binary, against the bytes left, before anything is allocated.
    fn f64s(&mut self, binary: bool, ty: &str, count: usize, what: &str, limits: &Limits) -> Result<Vec<f64>> {
        let size = type_size(ty)
            .ok_or_else(|| FormatError::unsupported(self.path, format!("{what} has data type '{ty}', which is not numeric")))?;
        if ty.eq_ignore_ascii_case("bit") {
            return Err(FormatError::unsupported(self.path, format!("{what} holds bits: bit arrays are not read")));
        }
        limits.check(self.path, what, &[count as u64, 8])?;
        if binary {
            let want = count.checked_mul(size).filter(|&w| w <= self.remaining()).ok_or_else(|| {
                FormatError::invalid(
                    self.path,
                    format!("file is truncated: {what} needs {count} {ty} values, {} bytes remain", self.remaining()),
                )
            })?;
            let bytes = &self.b[self.pos..self.pos + want];
            self.pos += want;
            let lower = ty.to_ascii_lowercase();
            let v = bytes.chunks_exact(size).map(|c| binary_value(&lower, c)).collect();
            return Ok(v);
        }
        // ASCII: at least two bytes a value (a digit and a separator), so a lying count
        // reserves no more than the file could hold.
        let mut v = Vec::with_capacity(count.min(self.remaining() / 2 + 1));
        while v.len() < count {
            let w = self.word().ok_or_else(|| shortfall(self.path, what, count, v.len()))?;
            match parse_number(&w) {
                Some(x) => v.push(x),
                // The next section's keyword: the data ended early.
                None if w.starts_with(|c: char| c.is_ascii_alphabetic()) => return Err(shortfall(self.path, what, count, v.len())),
                None => return Err(FormatError::invalid(self.path, format!("{what}: '{w}' is not a number"))),
            }
        }
        // VTK stores the numbers in an array of the declared type: a float array holds
        // them rounded to f32, as pyvista reads them.
        if size == 4 && (ty.eq_ignore_ascii_case("float") || ty.eq_ignore_ascii_case("vtktypefloat32")) {
            v.iter_mut().for_each(|x| *x = *x as f32 as f64);
        }
        Ok(v)
    }

    /// The next whitespace-separated word (None at the end).
    fn word(&mut self) -> Option<String> {
        self.pos = self.pos.min(self.b.len());
        while self.pos < self.b.len() && self.b[self.pos].is_ascii_whitespace() {
            self.pos += 1;
        }
        let end = self.b[self.pos..].iter().position(|c| c.is_ascii_whitespace()).map_or(self.b.len(), |i| self.pos + i);
        if end == self.pos {
            return None;
        }
        let w = String::from_utf8_lossy(&self.b[self.pos..end]).into_owned();
        self.pos = end;
        Some(w)
    }

    /// Skips `count` values of `ty` (binary: by size, refused past the end; ASCII: by
    /// words, refused where fewer remain).
    pub(crate) fn skip(&mut self, binary: bool, ty: &str, count: usize, what: &str) -> Result<()> {
        if ty.eq_ignore_ascii_case("string") || ty.eq_ignore_ascii_case("utf8_string") {
            if binary {
                return Err(FormatError::unsupported(
                    self.path,
                    format!("{what} is a string array, which binary legacy files are not read with"),
                ));
            }
            // One string a line.
            for k in 0..count {
                self.raw_line()
                    .ok_or_else(|| FormatError::invalid(self.path, format!("file is truncated: {what} holds {k} of {count} strings")))?;
            }
            return Ok(());
        }
        if binary {
            let size = type_size(ty).ok_or_else(|| FormatError::unsupported(self.path, format!("{what} has data type '{ty}'")))?;
            let bytes = if ty.eq_ignore_ascii_case("bit") { count.div_ceil(8) } else { count.saturating_mul(size) };
            if bytes > self.remaining() {
                return Err(FormatError::invalid(
                    self.path,
                    format!("file is truncated: {what} needs {bytes} bytes, {} remain", self.remaining()),
                ));
            }
            self.pos += bytes;
            return Ok(());
        }
        for k in 0..count {
            if self.word().is_none() {
                return Err(shortfall(self.path, what, count, k));
            }
        }
        Ok(())
    }
}

/// The error for ASCII data that ends after `found` of the `count` values `what` declares.
fn shortfall(path: &Path, what: &str, count: usize, found: usize) -> FormatError {
    if what == "POINTS" {
        let n = count / 3;
        return FormatError::invalid(path, format!("POINTS declares {n} points but only {found} coordinates follow ({count} needed)"));
    }
    FormatError::invalid(path, format!("{what} declares {count} values but only {found} follow"))
}

/// One big-endian binary value of legacy type `ty` (lower case), as f64.
fn binary_value(ty: &str, c: &[u8]) -> f64 {
    match (ty, c.len()) {
        ("char" | "signed_char" | "vtktypeint8", _) => c[0] as i8 as f64,
        (_, 1) => c[0] as f64,
        ("short" | "vtktypeint16", _) => i16::from_be_bytes([c[0], c[1]]) as f64,
        (_, 2) => u16::from_be_bytes([c[0], c[1]]) as f64,
        ("float" | "vtktypefloat32", _) => f32::from_be_bytes([c[0], c[1], c[2], c[3]]) as f64,
        ("unsigned_int" | "vtktypeuint32", _) => u32::from_be_bytes([c[0], c[1], c[2], c[3]]) as f64,
        (_, 4) => i32::from_be_bytes([c[0], c[1], c[2], c[3]]) as f64,
        ("double" | "vtktypefloat64", _) => f64::from_be_bytes(c.try_into().expect("8 bytes")),
        ("unsigned_long" | "vtktypeuint64", _) => u64::from_be_bytes(c.try_into().expect("8 bytes")) as f64,
        _ => i64::from_be_bytes(c.try_into().expect("8 bytes")) as f64,
    }
}

/// A number as VTK writes it in ASCII (also `nan`, `-nan`, `inf`, `-inf`, any case).
fn parse_number(w: &str) -> Option<f64> {
    w.parse::<f64>().ok().or_else(|| match w.to_ascii_lowercase().as_str() {
        "-nan" | "+nan" | "nan(ind)" | "-nan(ind)" => Some(f64::NAN),
        "1.#inf" => Some(f64::INFINITY),
        "-1.#inf" => Some(f64::NEG_INFINITY),
        _ => None,
    })
}

/// A name as VTK writes it in a legacy file: spaces and other bytes as `%xx`.
fn decode_name(s: &str) -> String {
    let b = s.as_bytes();
    let hex = |c: u8| (c as char).to_digit(16).map(|d| d as u8);
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if let (b'%', Some(Some(hi)), Some(Some(lo))) = (b[i], b.get(i + 1).map(|&c| hex(c)), b.get(i + 2).map(|&c| hex(c))) {
            out.push(hi * 16 + lo);
            i += 3;
            continue;
        }
        out.push(b[i]);
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// The count (and size) words of a header line `KEYWORD n [size]`, as usize.
fn counts(path: &Path, line: &str, at: usize) -> Result<usize> {
    let w = line.split_whitespace().nth(at).unwrap_or("");
    w.parse::<usize>()
        .map_err(|_| FormatError::invalid(path, format!("'{}': '{w}' is not a count", line.chars().take(60).collect::<String>())))
}

/// A cell list (`VERTICES`, `LINES`, `POLYGONS`, `TRIANGLE_STRIPS`, `CELLS`) skipped: the
/// VTK 4 form (`n size`, then `size` integers) or the VTK 5 form (`offsets connectivity`,
/// then `OFFSETS type` and `CONNECTIVITY type` lists).
fn skip_cells(c: &mut Cursor, binary: bool, line: &str) -> Result<()> {
    let keyword = line.split_whitespace().next().unwrap_or("");
    let (n, size) = (counts(c.path, line, 1)?, counts(c.path, line, 2)?);
    let save = c.pos;
    match c.line() {
        Some(l) if l.to_ascii_uppercase().starts_with("OFFSETS") => {
            let ty = l.split_whitespace().nth(1).unwrap_or("vtktypeint64").to_string();
            c.skip(binary, &ty, n, &format!("{keyword} OFFSETS"))?;
            let l = c.expect_line(&format!("{keyword} CONNECTIVITY"))?;
            if !l.to_ascii_uppercase().starts_with("CONNECTIVITY") {
                return Err(FormatError::invalid(
                    c.path,
                    format!("{keyword}: CONNECTIVITY expected after OFFSETS, found '{}'", l.chars().take(60).collect::<String>()),
                ));
            }
            let ty = l.split_whitespace().nth(1).unwrap_or("vtktypeint64").to_string();
            c.skip(binary, &ty, size, &format!("{keyword} CONNECTIVITY"))
        }
        _ => {
            c.pos = save;
            c.skip(binary, "int", size, keyword)
        }
    }
}

/// Reads (`keep`) or skips the attributes of a POINT_DATA or CELL_DATA section of `n`
/// tuples, up to the next section keyword, which is returned (None at the end).
fn attributes(c: &mut Cursor, binary: bool, n: usize, keep: Option<&mut Vec<PointArray>>, limits: &Limits) -> Result<Option<String>> {
    let mut keep = keep;
    loop {
        let Some(l) = c.line() else { return Ok(None) };
        let w: Vec<&str> = l.split_whitespace().collect();
        let key = w[0].to_ascii_uppercase();
        let name = || decode_name(w.get(1).copied().unwrap_or(""));
        // (name, components, data type) of the array this line declares.
        let array = match key.as_str() {
            "POINT_DATA" | "CELL_DATA" => return Ok(Some(l)),
            "SCALARS" => {
                let comps: usize = match w.get(3) {
                    Some(x) => x.parse().map_err(|_| FormatError::invalid(c.path, format!("'{l}': '{x}' is not a component count")))?,
                    None => 1,
                };
                // The LOOKUP_TABLE line is optional in files VTK reads.
                let save = c.pos;
                if !c.line().is_some_and(|t| t.to_ascii_uppercase().starts_with("LOOKUP_TABLE")) {
                    c.pos = save;
                }
                Some((name(), comps, w.get(2).unwrap_or(&"float").to_string()))
            }
            "VECTORS" | "NORMALS" => Some((name(), 3, w.get(2).unwrap_or(&"float").to_string())),
            "TENSORS" => Some((name(), 9, w.get(2).unwrap_or(&"float").to_string())),
            "TENSORS6" => Some((name(), 6, w.get(2).unwrap_or(&"float").to_string())),
            "GLOBAL_IDS" | "PEDIGREE_IDS" | "EDGE_FLAGS" => Some((name(), 1, w.get(2).unwrap_or(&"int").to_string())),
            "TEXTURE_COORDINATES" => {
                let dim: usize = w.get(2).and_then(|x| x.parse().ok()).unwrap_or(2);
                Some((name(), dim, w.get(3).unwrap_or(&"float").to_string()))
            }
            "COLOR_SCALARS" => {
                // Bytes in a binary file; floats in [0, 1] in an ASCII one (VTK reads both as
                // unsigned char, the floats scaled by 255).
                let comps: usize = w.get(2).and_then(|x| x.parse().ok()).unwrap_or(4);
                let count = n.saturating_mul(comps);
                let what = format!("COLOR_SCALARS '{}'", name());
                let values = if binary {
                    c.f64s(true, "unsigned_char", count, &what, limits)?
                } else {
                    c.f64s(false, "float", count, &what, limits)?.into_iter().map(|v| (v * 255.0 + 0.5).floor().clamp(0.0, 255.0)).collect()
                };
                if let Some(k) = keep.as_deref_mut() {
                    k.push(PointArray { name: name(), components: comps, values });
                }
                None
            }
            "LOOKUP_TABLE" => {
                let size = counts(c.path, &l, 2)?;
                c.skip(binary, if binary { "unsigned_char" } else { "float" }, size.saturating_mul(4), "LOOKUP_TABLE")?;
                None
            }
            "FIELD" => {
                field(c, binary, &l, n, keep.as_deref_mut(), limits)?;
                None
            }
            other => {
                return Err(FormatError::invalid(
                    c.path,
                    format!("unexpected '{}' among the point or cell data", other.chars().take(40).collect::<String>()),
                ))
            }
        };
        if let Some((name, comps, ty)) = array {
            let what = format!("{key} '{name}'");
            match keep.as_deref_mut() {
                Some(k) => {
                    let values = c.f64s(binary, &ty, n.saturating_mul(comps), &what, limits)?;
                    k.push(PointArray { name, components: comps, values });
                }
                None => c.skip(binary, &ty, n.saturating_mul(comps), &what)?,
            }
        }
    }
}

/// A legacy VTK point set as particles: its points and every point array.
pub fn read_points(path: &Path, names: &ParticleArrayNames, limits: &Limits) -> Result<ParticleSet> {
    let len = std::fs::metadata(path).map_err(|e| FormatError::io(path, e))?.len();
    limits.check(path, "VTK file", &[len])?;
    let bytes = std::fs::read(path).map_err(|e| FormatError::io(path, e))?;
    let mut c = Cursor { path, b: &bytes, pos: 0 };
    let header = c.expect_line("header")?;
    if !header.starts_with("# vtk DataFile") {
        return Err(FormatError::invalid(path, "not a legacy VTK file (no '# vtk DataFile' header)"));
    }
    let version = header.rsplit(' ').next().unwrap_or("?").to_string();
    let _title = c.expect_line("title")?;
    let binary = match c.expect_line("ASCII or BINARY")?.to_ascii_uppercase().as_str() {
        "BINARY" => true,
        "ASCII" => false,
        other => {
            return Err(FormatError::invalid(path, format!("'{}' is neither ASCII nor BINARY", other.chars().take(40).collect::<String>())))
        }
    };
    let dataset = c.expect_line("DATASET")?;
    let kind = dataset.to_ascii_uppercase().split_whitespace().nth(1).unwrap_or("").to_string();
    if !matches!(kind.as_str(), "POLYDATA" | "UNSTRUCTURED_GRID" | "STRUCTURED_GRID") {
        return Err(FormatError::unsupported(
            path,
            format!("DATASET {kind} holds no points (only POLYDATA, UNSTRUCTURED_GRID and STRUCTURED_GRID carry particles)"),
        ));
    }
    let (mut positions, mut arrays) = (None::<Vec<[f64; 3]>>, Vec::new());
    let mut next = c.line();
    while let Some(l) = next.take() {
        let key = l.split_whitespace().next().unwrap_or("").to_ascii_uppercase();
        match key.as_str() {
            "POINTS" => {
                let n = counts(path, &l, 1)?;
                let ty = l.split_whitespace().nth(2).unwrap_or("float").to_string();
                limits.check(path, "POINTS", &[n as u64, 3, 8])?;
                if binary && n.saturating_mul(3).saturating_mul(type_size(&ty).unwrap_or(4)) > c.remaining() {
                    return Err(FormatError::invalid(
                        path,
                        format!(
                            "POINTS declares {n} points ({} bytes of {ty}) but only {} bytes follow",
                            n * 3 * type_size(&ty).unwrap_or(4),
                            c.remaining()
                        ),
                    ));
                }
                let coords = c.f64s(binary, &ty, n.saturating_mul(3), "POINTS", limits)?;
                positions = Some(coords.chunks_exact(3).map(|p| [p[0], p[1], p[2]]).collect());
                next = c.line();
            }
            "VERTICES" | "LINES" | "POLYGONS" | "TRIANGLE_STRIPS" | "CELLS" => {
                skip_cells(&mut c, binary, &l)?;
                next = c.line();
            }
            "CELL_TYPES" => {
                c.skip(binary, "int", counts(path, &l, 1)?, "CELL_TYPES")?;
                next = c.line();
            }
            "DIMENSIONS" => next = c.line(),
            "FIELD" => {
                // Field data of the whole dataset (a time value, a title): not per point.
                field(&mut c, binary, &l, 0, None, limits)?;
                next = c.line();
            }
            "POINT_DATA" => {
                let n = counts(path, &l, 1)?;
                let have = positions.as_ref().map_or(0, Vec::len);
                if n != have {
                    return Err(FormatError::invalid(path, format!("POINT_DATA {n} does not match the {have} POINTS")));
                }
                next = attributes(&mut c, binary, n, Some(&mut arrays), limits)?;
            }
            "CELL_DATA" => {
                let n = counts(path, &l, 1)?;
                next = attributes(&mut c, binary, n, None, limits)?;
            }
            _ => {
                return Err(FormatError::invalid(
                    path,
                    format!("unexpected line '{}' in the {kind} dataset", l.chars().take(60).collect::<String>()),
                ))
            }
        }
    }
    let positions = positions.ok_or_else(|| FormatError::invalid(path, "no POINTS"))?;
    let notes = vec![format!("legacy VTK {version} ({}), {} points", if binary { "binary" } else { "ASCII" }, positions.len())];
    ParticleSet::from_arrays(positions, arrays, names, notes).map_err(|m| FormatError::invalid(path, m))
}

/// A `FIELD name arrays` block (its header line `line`): each array of `n` tuples read into
/// `keep` (where given), every other array skipped.
fn field(c: &mut Cursor, binary: bool, line: &str, n: usize, mut keep: Option<&mut Vec<PointArray>>, limits: &Limits) -> Result<()> {
    let arrays = counts(c.path, line, 2)?;
    for _ in 0..arrays {
        let a = c.expect_line("FIELD array")?;
        let f: Vec<&str> = a.split_whitespace().collect();
        if f[0].eq_ignore_ascii_case("NULL_ARRAY") {
            continue;
        }
        let (comps, tuples) = (counts(c.path, &a, 1)?, counts(c.path, &a, 2)?);
        let ty = f.get(3).copied().unwrap_or("float");
        let (name, count) = (decode_name(f[0]), comps.saturating_mul(tuples));
        let what = format!("FIELD array '{name}'");
        match keep.as_deref_mut() {
            Some(k) if tuples == n && type_size(ty).is_some() => {
                let values = c.f64s(binary, ty, count, &what, limits)?;
                k.push(PointArray { name, components: comps, values });
            }
            _ => c.skip(binary, ty, count, &what)?,
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read(text: &[u8]) -> Result<ParticleSet> {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("x.vtk");
        std::fs::write(&p, text).unwrap();
        read_points(&p, &Default::default(), &Limits::default())
    }

    #[test]
    fn vtk_5_ascii_as_pyvista_writes_it() {
        let text = b"# vtk DataFile Version 5.1\nvtk output\nASCII\nDATASET POLYDATA\nFIELD FieldData 1\ntime 1 1 double\n1.5 \n\
            POINTS 3 float\n0 1 2 nan 4 5\n6 7 -inf\nVERTICES 4 3\nOFFSETS vtktypeint64\n0 1 2 3\nCONNECTIVITY vtktypeint64\n0 1 2\n\
            POINT_DATA 3\nSCALARS mass float\nLOOKUP_TABLE default\n1 2 3\nMETADATA\nINFORMATION 0\n\n\
            FIELD FieldData 2\nh 1 3 double\n0.1 0.2 0.3\nmy%20vel 3 3 float\n1 2 3 4 5 6 7 8 9\n";
        let p = read(text).unwrap();
        assert_eq!(p.len(), 3);
        assert!(p.positions[1][0].is_nan() && p.positions[2][2] == f64::NEG_INFINITY);
        assert_eq!(p.mass, Some(vec![1.0, 2.0, 3.0]));
        assert_eq!(p.smoothing_length, Some(vec![0.1, 0.2, 0.3]));
        assert_eq!(p.arrays[0].name, "my vel");
        assert_eq!((p.arrays[0].components, p.arrays[0].values[8]), (3, 9.0));
    }

    #[test]
    fn vtk_4_cells_and_cell_data_are_skipped() {
        let text = b"# vtk DataFile Version 4.2\nt\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 2 double\n0 0 0 1 1 1\n\
            CELLS 2 4\n1 0\n1 1\nCELL_TYPES 2\n1 1\nCELL_DATA 2\nSCALARS c int 1\n7 8\nPOINT_DATA 2\nVECTORS v float\n1 2 3 4 5 6\n\
            COLOR_SCALARS rgb 3\n0 0.5 1 1 1 1\n";
        let p = read(text).unwrap();
        assert_eq!(p.arrays.iter().map(|a| a.name.as_str()).collect::<Vec<_>>(), ["v", "rgb"]);
        assert_eq!(p.arrays[1].values[..3], [0.0, 128.0, 255.0]);
    }

    #[test]
    fn lying_counts_are_refused_before_allocating() {
        let e = read(b"# vtk DataFile Version 5.1\nt\nBINARY\nDATASET POLYDATA\nPOINTS 1000000000 float\n\0\0").unwrap_err();
        assert!(e.message.contains("POINTS declares 1000000000 points"), "{e}");
        let e = read(b"# vtk DataFile Version 5.1\nt\nASCII\nDATASET POLYDATA\nPOINTS 1 float\n0 0 0\nPOINT_DATA 1\nFIELD f 1\na 1 99999999999 float\n1\n").unwrap_err();
        assert!(e.message.contains("declares 99999999999 values but only 1 follow"), "{e}");
    }
}
