//! VTK XML PolyData / UnstructuredGrid reader (see `vtk.rs` for why it is our own).
//! Reads the Piece's Points and PointData arrays in every encoding VTK writes: ascii,
//! base64 `binary`, and `appended` (raw or base64), each optionally zlib-compressed, with
//! UInt32 or UInt64 headers in either byte order.

use crate::error::{FormatError, Result};
use crate::memory::Limits;
use crate::particles::{ParticleArrayNames, ParticleSet, PointArray};
use base64::Engine;
use quick_xml::events::{BytesStart, Event};
use std::io::Read;
use std::path::Path;

#[derive(Debug, Default, Clone)]
struct ArrayDecl {
    name: String,
    ty: String,
    components: usize,
    format: String,
    offset: Option<usize>,
    text: String,
}

#[derive(Debug, Default)]
struct FileDecl {
    dataset: String,
    big_endian: bool,
    header64: bool,
    zlib: bool,
    points: usize,
    point_arrays: Vec<ArrayDecl>,
    positions: Option<ArrayDecl>,
    appended_base64: bool,
    /// ImageData: WholeExtent (or the Piece's Extent), Origin, Spacing, Direction
    /// (row-major), and the PointData's active scalars.
    extent: Option<[i64; 6]>,
    origin: [f64; 3],
    spacing: [f64; 3],
    direction: [f64; 9],
    active_scalars: Option<String>,
}

fn attr(e: &BytesStart, key: &str) -> Option<String> {
    e.attributes().flatten().find(|a| a.key.as_ref() == key.as_bytes()).map(|a| String::from_utf8_lossy(&a.value).into_owned())
}

fn type_size(ty: &str) -> Option<usize> {
    Some(match ty {
        "Int8" | "UInt8" => 1,
        "Int16" | "UInt16" => 2,
        "Int32" | "UInt32" | "Float32" => 4,
        "Int64" | "UInt64" | "Float64" => 8,
        _ => return None,
    })
}

/// The file's bytes, held while its arrays are decoded: counted against the limit first.
fn read_file(path: &Path, limits: &Limits) -> Result<Vec<u8>> {
    let len = std::fs::metadata(path).map_err(|e| FormatError::io(path, e))?.len();
    limits.check(path, "the file", &[len])?;
    std::fs::read(path).map_err(|e| FormatError::io(path, e))
}

pub fn read_vtk_xml(path: &Path, names: &ParticleArrayNames, limits: &Limits) -> Result<ParticleSet> {
    let bytes = read_file(path, limits)?;
    let (decl, data_start) = parse_file(path, &bytes)?;
    let appended: &[u8] = data_start.map_or(&[], |s| &bytes[s..]);
    if decl.dataset != "PolyData" && decl.dataset != "UnstructuredGrid" {
        return Err(FormatError::unsupported(
            path,
            format!("VTK XML type '{}': particles come from PolyData (.vtp) or UnstructuredGrid (.vtu)", decl.dataset),
        ));
    }
    let n = decl.points;
    let pos_decl = decl.positions.clone().ok_or_else(|| FormatError::invalid(path, "Piece has no Points array"))?;
    if pos_decl.components != 3 {
        return Err(FormatError::invalid(path, format!("Points have {} components, not 3", pos_decl.components)));
    }
    let coords = decode_array(path, &decl, &pos_decl, appended, n, limits)?;
    let positions: Vec<[f64; 3]> = coords.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    let mut arrays = Vec::new();
    for a in &decl.point_arrays {
        let values = decode_array(path, &decl, a, appended, n, limits)?;
        arrays.push(PointArray { name: a.name.clone(), components: a.components, values });
    }
    let notes = vec![format!("VTK XML {}, {} points, {}", decl.dataset, n, decl.encoding(data_start.is_some()))];
    ParticleSet::from_arrays(positions, arrays, names, notes).map_err(|m| FormatError::invalid(path, m))
}

impl FileDecl {
    /// How the arrays are stored, for notes: "inline", "appended raw" or "appended
    /// base64", and ", zlib" when compressed.
    fn encoding(&self, appended: bool) -> String {
        let how = match (appended, self.appended_base64) {
            (false, _) => "inline",
            (true, true) => "appended base64",
            (true, false) => "appended raw",
        };
        format!("{how}{}", if self.zlib { ", zlib" } else { "" })
    }
}

/// The declarations of a VTK XML file's bytes, and where its appended data starts (after
/// the '_' marker) if it has any. A cut file can still parse up to where it stops (and
/// appended raw data can still cover the arrays): it is refused by its missing end. The
/// appended block may hold raw bytes that are not XML: only what precedes it is parsed.
fn parse_file(path: &Path, bytes: &[u8]) -> Result<(FileDecl, Option<usize>)> {
    let tail = &bytes[bytes.len().saturating_sub(4096)..];
    if find(tail, b"</VTKFile>").is_none() {
        if find(&bytes[..bytes.len().min(4096)], b"<VTKFile").is_none() {
            return Err(FormatError::invalid(path, "not a VTK XML file (no VTKFile element)"));
        }
        return Err(FormatError::invalid(path, "file is truncated: no closing </VTKFile>"));
    }
    let Some(start) = find(bytes, b"<AppendedData") else { return Ok((parse_decl(path, bytes)?, None)) };
    let us =
        find(&bytes[start..], b"_").map(|i| start + i + 1).ok_or_else(|| FormatError::invalid(path, "AppendedData has no '_' marker"))?;
    let mut decl = parse_decl(path, &bytes[..start])?;
    let head_end = find(&bytes[start..], b">").map(|i| start + i + 1).unwrap_or(start);
    decl.appended_base64 = String::from_utf8_lossy(&bytes[start..head_end]).contains("base64");
    Ok((decl, Some(us)))
}

/// A VTK XML ImageData file (`.vti`) as a volume: the PointData's active scalars (else its
/// first one-component array), in the stored type. VTK's coordinates are taken as world
/// coordinates (VTK has no anatomical frame): world = Origin + Direction · (Spacing ⊙ index),
/// index counted from the extent's start (a piece may start away from 0).
pub fn read_vti(path: &Path, limits: &Limits) -> Result<crate::Volume> {
    use crate::volume::{ScalarType, VoxelData};
    let bytes = read_file(path, limits)?;
    let (decl, data_start) = parse_file(path, &bytes)?;
    let appended: &[u8] = data_start.map_or(&[], |s| &bytes[s..]);
    if decl.dataset != "ImageData" {
        return Err(FormatError::unsupported(path, format!("VTK XML type '{}': volumes come from ImageData (.vti)", decl.dataset)));
    }
    let e = decl.extent.ok_or_else(|| FormatError::invalid(path, "ImageData has no WholeExtent or Piece Extent"))?;
    let dims = [0, 1, 2].map(|a| (e[2 * a + 1] - e[2 * a] + 1).max(0) as usize);
    if dims.contains(&0) {
        return Err(FormatError::invalid(path, format!("extent {e:?} holds no points")));
    }
    let n = dims.iter().try_fold(1usize, |n, &d| n.checked_mul(d)).ok_or_else(|| FormatError::invalid(path, "point count overflows"))?;
    let chosen = match &decl.active_scalars {
        Some(name) => decl.point_arrays.iter().find(|a| &a.name == name),
        None => decl.point_arrays.iter().find(|a| a.components == 1),
    };
    let a = chosen.cloned().ok_or_else(|| match &decl.active_scalars {
        Some(name) => FormatError::invalid(path, format!("PointData names Scalars '{name}', which it does not hold")),
        None => FormatError::unsupported(path, "PointData holds no one-component array: nothing to draw as a volume"),
    })?;
    if a.components != 1 {
        return Err(FormatError::unsupported(
            path,
            format!("array '{}' has {} components: a volume holds one value per voxel", a.name, a.components),
        ));
    }
    let ty = match a.ty.as_str() {
        "Int8" => ScalarType::I8,
        "UInt8" => ScalarType::U8,
        "Int16" => ScalarType::I16,
        "UInt16" => ScalarType::U16,
        "Int32" => ScalarType::I32,
        "UInt32" => ScalarType::U32,
        "Float32" => ScalarType::F32,
        "Float64" => ScalarType::F64,
        other => {
            return Err(FormatError::unsupported(path, format!("array '{}' is {other}: 64-bit integers are not kept as voxels", a.name)))
        }
    };
    // The decoded bytes and the voxels converted from them are held at once (the array
    // alone first: a lying extent is refused for what it claims).
    limits.check(path, &format!("array '{}'", a.name), &[n as u64, ty.size() as u64])?;
    limits.check(path, &format!("array '{}' decoded and converted to voxels", a.name), &[n as u64, ty.size() as u64, 2])?;
    let data = match decode(path, &decl, &a, appended, n, limits)? {
        Decoded::Bytes(b) => VoxelData::from_bytes(ty, &b, decl.big_endian),
        Decoded::Text(v) => {
            if v.len() != n {
                return Err(FormatError::invalid(path, format!("array '{}' holds {} values; the extent has {n} points", a.name, v.len())));
            }
            match ty {
                ScalarType::F32 => VoxelData::F32(v.iter().map(|&x| x as f32).collect()),
                ScalarType::F64 => VoxelData::F64(v),
                _ => VoxelData::F64(v), // integers read from text, kept exactly
            }
        }
    };
    let d = decl.direction;
    let mut axes = [[0.0; 3]; 3];
    for i in 0..3 {
        for r in 0..3 {
            axes[i][r] = d[3 * r + i] * decl.spacing[i];
        }
    }
    let start = [e[0], e[2], e[4]].map(|x| x as f64);
    let origin = [0, 1, 2].map(|r| decl.origin[r] + (0..3).map(|i| axes[i][r] * start[i]).sum::<f64>());
    let affine = crate::raw::affine_from_axes(axes, origin);
    crate::raw::check_affine(path, &affine)?;
    let mut v = crate::Volume::new(dims, affine, data);
    v.notes.push(format!("VTK XML ImageData, array '{}' ({}), {}", a.name, a.ty, decl.encoding(data_start.is_some())));
    v.attributes.push(("array".into(), a.name.clone()));
    Ok(v)
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

fn parse_decl(path: &Path, xml: &[u8]) -> Result<FileDecl> {
    let mut reader = quick_xml::Reader::from_reader(xml);
    reader.config_mut().check_end_names = false;
    let mut decl = FileDecl::default();
    let mut section: Vec<String> = Vec::new();
    let mut current: Option<ArrayDecl> = None;
    let mut pieces = 0;
    // Elements nested inside a DataArray (InformationKey…): their text is not array data.
    let mut nested = 0usize;
    let mut buf = Vec::new();
    let bad = |e: quick_xml::Error| FormatError::invalid(path, format!("malformed VTK XML: {e}"));
    loop {
        buf.clear();
        let ev = reader.read_event_into(&mut buf).map_err(bad)?;
        let (start, empty) = match &ev {
            Event::Start(e) => (Some(e.clone()), false),
            Event::Empty(e) => (Some(e.clone()), true),
            _ => (None, false),
        };
        if let Some(e) = start {
            let name = String::from_utf8_lossy(e.name().as_ref()).into_owned();
            if current.is_some() {
                if !empty {
                    nested += 1;
                }
                continue;
            }
            match name.as_str() {
                "VTKFile" => {
                    decl.dataset = attr(&e, "type").unwrap_or_default();
                    decl.big_endian = attr(&e, "byte_order").as_deref() == Some("BigEndian");
                    decl.header64 = attr(&e, "header_type").as_deref() == Some("UInt64");
                    match attr(&e, "compressor").as_deref() {
                        None | Some("") => {}
                        Some("vtkZLibDataCompressor") => decl.zlib = true,
                        Some(other) => return Err(FormatError::unsupported(path, format!("compressor {other} (only zlib is supported)"))),
                    }
                }
                "ImageData" => {
                    let nums = |key: &str, n: usize| -> Result<Option<Vec<f64>>> {
                        let Some(v) = attr(&e, key) else { return Ok(None) };
                        let x: Option<Vec<f64>> = v.split_whitespace().map(|w| w.parse::<f64>().ok().filter(|x| x.is_finite())).collect();
                        match x {
                            Some(x) if x.len() == n => Ok(Some(x)),
                            _ => Err(FormatError::invalid(path, format!("ImageData {key} '{v}' is not {n} numbers"))),
                        }
                    };
                    decl.extent = nums("WholeExtent", 6)?.map(|v| [0, 1, 2, 3, 4, 5].map(|i| v[i] as i64));
                    decl.origin = nums("Origin", 3)?.map_or([0.0; 3], |v| [v[0], v[1], v[2]]);
                    decl.spacing = nums("Spacing", 3)?.map_or([1.0; 3], |v| [v[0], v[1], v[2]]);
                    decl.direction =
                        nums("Direction", 9)?.map_or([1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0], |v| std::array::from_fn(|i| v[i]));
                    section.push(name);
                }
                "Piece" => {
                    pieces += 1;
                    if pieces > 1 {
                        return Err(FormatError::unsupported(path, "file holds several pieces; only the first is read"));
                    }
                    if let Some(ext) = attr(&e, "Extent") {
                        let v: Option<Vec<i64>> = ext.split_whitespace().map(|w| w.parse().ok()).collect();
                        let v = v
                            .filter(|v| v.len() == 6 && (0..3).all(|a| v[2 * a] <= v[2 * a + 1]))
                            .ok_or_else(|| FormatError::invalid(path, format!("Piece Extent '{ext}' is not 6 increasing pairs")))?;
                        decl.extent = Some([v[0], v[1], v[2], v[3], v[4], v[5]]);
                    }
                    if let Some(np) = attr(&e, "NumberOfPoints") {
                        decl.points =
                            np.trim().parse().map_err(|_| FormatError::invalid(path, format!("NumberOfPoints '{np}' is not a count")))?;
                    }
                    if !empty {
                        section.push(name);
                    }
                }
                "PointData" => {
                    decl.active_scalars = attr(&e, "Scalars");
                    if !empty {
                        section.push(name);
                    }
                }
                "DataArray" => {
                    let ty = attr(&e, "type").unwrap_or_default();
                    if type_size(&ty).is_none() {
                        return Err(FormatError::unsupported(path, format!("DataArray type '{ty}'")));
                    }
                    let comps = attr(&e, "NumberOfComponents").unwrap_or_else(|| "1".into());
                    let components: usize = comps
                        .trim()
                        .parse()
                        .ok()
                        .filter(|c| (1..=64).contains(c))
                        .ok_or_else(|| FormatError::invalid(path, format!("NumberOfComponents '{comps}' is not valid")))?;
                    let offset = match attr(&e, "offset") {
                        Some(o) => {
                            Some(o.trim().parse().map_err(|_| FormatError::invalid(path, format!("DataArray offset '{o}' is not valid")))?)
                        }
                        None => None,
                    };
                    let a = ArrayDecl {
                        name: attr(&e, "Name").unwrap_or_default(),
                        ty,
                        components,
                        format: attr(&e, "format").unwrap_or_else(|| "ascii".into()),
                        offset,
                        text: String::new(),
                    };
                    if empty {
                        store(&mut decl, &section, a);
                    } else {
                        current = Some(a);
                    }
                }
                _ => {
                    if !empty {
                        section.push(name);
                    }
                }
            }
            continue;
        }
        match ev {
            Event::Text(t) => {
                if let Some(a) = current.as_mut().filter(|_| nested == 0) {
                    a.text.push_str(&String::from_utf8_lossy(t.as_ref()));
                }
            }
            Event::End(e) => {
                let name = String::from_utf8_lossy(e.name().as_ref()).into_owned();
                if nested > 0 {
                    nested -= 1;
                } else if name == "DataArray" {
                    if let Some(a) = current.take() {
                        store(&mut decl, &section, a);
                    }
                } else if section.last() == Some(&name) {
                    section.pop();
                }
            }
            Event::Eof => break,
            _ => {}
        }
    }
    if decl.dataset.is_empty() {
        return Err(FormatError::invalid(path, "not a VTK XML file (no VTKFile element)"));
    }
    if pieces == 0 {
        return Err(FormatError::invalid(path, "VTK XML file has no Piece"));
    }
    Ok(decl)
}

fn store(decl: &mut FileDecl, section: &[String], a: ArrayDecl) {
    match section.last().map(String::as_str) {
        Some("Points") if decl.positions.is_none() => decl.positions = Some(a),
        Some("PointData") => decl.point_arrays.push(a),
        _ => {}
    }
}

/// What a DataArray decodes to: its bytes (in the file's byte order), or numbers from text.
enum Decoded {
    Bytes(Vec<u8>),
    Text(Vec<f64>),
}

/// Decodes one DataArray into f64 values, checking its length against `n` points.
fn decode_array(path: &Path, f: &FileDecl, a: &ArrayDecl, appended: &[u8], n: usize, limits: &Limits) -> Result<Vec<f64>> {
    let size = type_size(&a.ty).unwrap() as u64;
    limits.check(path, &format!("array '{}'", a.name), &[n as u64, a.components as u64, size])?;
    // As stored and as f64, held at once while converting.
    limits.check(path, &format!("array '{}' as f64", a.name), &[n as u64, a.components as u64, size + 8])?;
    let what = if a.name.is_empty() { "Points".to_string() } else { format!("array '{}'", a.name) };
    let values = match decode(path, f, a, appended, n, limits)? {
        Decoded::Bytes(raw) => to_f64(&raw, &a.ty, f.big_endian),
        Decoded::Text(v) => v,
    };
    if values.len() != n * a.components {
        return Err(FormatError::invalid(
            path,
            format!("{what} holds {} values, but {n} points × {} components need {}", values.len(), a.components, n * a.components),
        ));
    }
    Ok(values)
}

/// Decodes one DataArray of `n` tuples as stored (binary: exactly its bytes).
fn decode(path: &Path, f: &FileDecl, a: &ArrayDecl, appended: &[u8], n: usize, limits: &Limits) -> Result<Decoded> {
    let size = type_size(&a.ty).unwrap();
    let want = limits.check(path, &format!("array '{}'", a.name), &[n as u64, a.components as u64, size as u64])?;
    let what = if a.name.is_empty() { "Points".to_string() } else { format!("array '{}'", a.name) };
    let values = match a.format.as_str() {
        "ascii" => {
            // Float32 text is the shortest decimal of an f32: parse it as f32 to get the
            // value VTK stored, then widen.
            let parse = |t: &str| if a.ty == "Float32" { t.parse::<f32>().map(f64::from) } else { t.parse::<f64>() };
            let v: std::result::Result<Vec<f64>, _> = a.text.split_ascii_whitespace().map(parse).collect();
            return Ok(Decoded::Text(v.map_err(|_| FormatError::invalid(path, format!("{what}: ascii data holds a non-number")))?));
        }
        "binary" => {
            let text: String = a.text.chars().filter(|c| !c.is_whitespace()).collect();
            decode_base64_block(path, f, text.as_bytes(), want, &what)?
        }
        "appended" => {
            let off = a.offset.ok_or_else(|| FormatError::invalid(path, format!("{what}: appended array has no offset")))?;
            if off >= appended.len() {
                return Err(FormatError::invalid(
                    path,
                    format!("{what}: offset {off} lies beyond the appended data ({} bytes)", appended.len()),
                ));
            }
            if f.appended_base64 {
                let end =
                    appended[off..].iter().position(|c| c.is_ascii_whitespace() || *c == b'<').map(|e| off + e).unwrap_or(appended.len());
                decode_base64_block(path, f, &appended[off..end], want, &what)?
            } else {
                decode_raw_block(path, f, &appended[off..], want, &what)?
            }
        }
        other => return Err(FormatError::unsupported(path, format!("{what}: DataArray format '{other}'"))),
    };
    if values.len() != want {
        return Err(FormatError::invalid(path, format!("{what} holds {} bytes, but {n} tuples need {want}", values.len())));
    }
    Ok(Decoded::Bytes(values))
}

/// One integer of a block header; None when the bytes run out (a cut or corrupt header).
fn header_int(f: &FileDecl, b: &[u8]) -> Option<u64> {
    Some(if f.header64 {
        let a: [u8; 8] = b.get(..8)?.try_into().ok()?;
        if f.big_endian {
            u64::from_be_bytes(a)
        } else {
            u64::from_le_bytes(a)
        }
    } else {
        let a: [u8; 4] = b.get(..4)?.try_into().ok()?;
        (if f.big_endian { u32::from_be_bytes(a) } else { u32::from_le_bytes(a) }) as u64
    })
}

/// Raw appended block: header then (possibly compressed) data, all bytes.
fn decode_raw_block(path: &Path, f: &FileDecl, block: &[u8], want: usize, what: &str) -> Result<Vec<u8>> {
    let hs = if f.header64 { 8 } else { 4 };
    let short = || FormatError::invalid(path, format!("{what}: appended data is truncated"));
    if f.zlib {
        let nblocks = header_int(f, block).ok_or_else(short)? as usize;
        let hlen = nblocks.checked_add(3).and_then(|c| c.checked_mul(hs)).ok_or_else(short)?;
        let header = block.get(..hlen).ok_or_else(short)?;
        inflate_blocks(path, f, header, &block[hlen..], want, what)
    } else {
        let nbytes = header_int(f, block).ok_or_else(short)? as usize;
        if nbytes != want {
            return Err(FormatError::invalid(path, format!("{what}: block holds {nbytes} bytes, expected {want}")));
        }
        Ok(block.get(hs..hs + nbytes).ok_or_else(short)?.to_vec())
    }
}

/// Base64 block (inline, or one array's run inside an appended base64 block, which may be
/// followed by the next array's run). VTK encodes a compressed array's header and data as
/// two base64 runs; an uncompressed one as one run or two, depending on the writer.
fn decode_base64_block(path: &Path, f: &FileDecl, text: &[u8], want: usize, what: &str) -> Result<Vec<u8>> {
    let b64 = base64::engine::general_purpose::STANDARD;
    let bad = || FormatError::invalid(path, format!("{what}: base64 data is corrupt or truncated"));
    let run = |from: usize, bytes: usize| -> Result<Vec<u8>> {
        let to = from.checked_add(enc_len(bytes)).ok_or_else(bad)?;
        b64.decode(text.get(from..to).ok_or_else(bad)?).map_err(|_| bad())
    };
    let hs = if f.header64 { 8 } else { 4 };
    let first = run(0, hs)?;
    if f.zlib {
        let nblocks = header_int(f, &first).ok_or_else(bad)? as usize;
        let hlen = nblocks.checked_add(3).and_then(|c| c.checked_mul(hs)).ok_or_else(bad)?;
        let header = run(0, hlen)?;
        if header.len() < hlen {
            return Err(bad());
        }
        let sizes: u64 = header.chunks_exact(hs).skip(3).filter_map(|c| header_int(f, c)).fold(0u64, u64::saturating_add);
        let sizes = usize::try_from(sizes).map_err(|_| bad())?;
        let data = run(enc_len(hlen), sizes)?;
        inflate_blocks(path, f, &header, &data, want, what)
    } else {
        let nbytes = header_int(f, &first).ok_or_else(bad)? as usize;
        if nbytes != want {
            return Err(FormatError::invalid(path, format!("{what}: block holds {nbytes} bytes, expected {want}")));
        }
        // A separately encoded header ends in '=' padding; a joint run does not.
        let separate = text[..enc_len(hs).min(text.len())].contains(&b'=');
        if separate {
            check_len(path, run(enc_len(hs), nbytes)?, want, what)
        } else {
            let all = run(0, hs + nbytes)?;
            check_len(path, all[hs..].to_vec(), want, what)
        }
    }
}

fn enc_len(bytes: usize) -> usize {
    bytes.div_ceil(3) * 4
}

fn check_len(path: &Path, data: Vec<u8>, want: usize, what: &str) -> Result<Vec<u8>> {
    if data.len() < want {
        return Err(FormatError::invalid(path, format!("{what}: holds {} bytes, expected {want}", data.len())));
    }
    Ok(data)
}

/// zlib blocks: header = [nblocks, block size, last block size, compressed sizes…].
fn inflate_blocks(path: &Path, f: &FileDecl, header: &[u8], data: &[u8], want: usize, what: &str) -> Result<Vec<u8>> {
    let hs = if f.header64 { 8 } else { 4 };
    let h: Vec<u64> = header.chunks_exact(hs).filter_map(|c| header_int(f, c)).collect();
    let bad_header = || FormatError::invalid(path, format!("{what}: compressed block header is corrupt"));
    if h.len() < 3 || h.len() < 3 + h[0] as usize {
        return Err(bad_header());
    }
    let (nblocks, block, last) = (h[0], h[1], h[2]);
    let total = if nblocks == 0 {
        Some(0)
    } else {
        (nblocks - 1).checked_mul(block).and_then(|t| t.checked_add(if last == 0 { block } else { last }))
    };
    let total = total.ok_or_else(bad_header)?;
    if total != want as u64 {
        return Err(FormatError::invalid(path, format!("{what}: compressed header declares {total} bytes, expected {want}")));
    }
    let mut out = Vec::with_capacity(want);
    let mut pos = 0usize;
    for &csize in &h[3..3 + nblocks as usize] {
        let csize = csize as usize;
        let chunk = data
            .get(pos..pos.saturating_add(csize))
            .ok_or_else(|| FormatError::invalid(path, format!("{what}: compressed data is truncated")))?;
        let mut d = flate2::read::ZlibDecoder::new(chunk).take(block.max(last));
        d.read_to_end(&mut out).map_err(|e| FormatError::invalid(path, format!("{what}: corrupt zlib data: {e}")))?;
        pos += csize;
    }
    check_len(path, out, want, what)
}

fn to_f64(raw: &[u8], ty: &str, be: bool) -> Vec<f64> {
    macro_rules! conv {
        ($t:ty, $n:expr) => {
            raw.chunks_exact($n)
                .map(|c| {
                    let a: [u8; $n] = c.try_into().unwrap();
                    (if be { <$t>::from_be_bytes(a) } else { <$t>::from_le_bytes(a) }) as f64
                })
                .collect()
        };
    }
    match ty {
        "Int8" => raw.iter().map(|&b| b as i8 as f64).collect(),
        "UInt8" => raw.iter().map(|&b| b as f64).collect(),
        "Int16" => conv!(i16, 2),
        "UInt16" => conv!(u16, 2),
        "Int32" => conv!(i32, 4),
        "UInt32" => conv!(u32, 4),
        "Int64" => conv!(i64, 8),
        "UInt64" => conv!(u64, 8),
        "Float32" => conv!(f32, 4),
        _ => conv!(f64, 8),
    }
}
