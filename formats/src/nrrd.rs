//! NRRD (`.nrrd`: header and data in one file; `.nhdr`: a detached header naming its data
//! files), teem's format. Geometry: with `space directions`, index axis i steps along its
//! vector from `space origin` (the first sample), in the header's `space`, converted to RAS
//! (left-posterior-superior negates x and y, left-anterior-superior x); `scanner-xyz` and
//! `3D-right-handed` spaces are taken as world coordinates as they are, `3D-left-handed`
//! likewise (with a note: no anatomical frame says which axis to mirror). Without space
//! directions, axis-aligned steps of `spacings` (1 when absent) from the world origin.
//!
//! Read: 2-D and 3-D scalar data of every integer and float type that fits a volume, both
//! endians, encodings raw, gzip and ascii, `byte skip` (−1: the data ends its file) and
//! `line skip`, data in the header's file or in one or several detached files (a list, or
//! a `printf` pattern with min, max and step — one file per slice). Refused with the
//! reason: bzip2 and hex encodings, non-scalar kinds (a vector or colour axis), more than 3
//! domain axes, 64-bit integers, time-varying spaces.

use crate::error::{FormatError, Result};
use crate::memory::Limits;
use crate::raw::{self, Compression, Start};
use crate::volume::{ScalarType, Volume, VoxelData};
use std::io::Read;
use std::path::{Path, PathBuf};

const MAX_HEADER: u64 = 1 << 20;
/// The most data files a `printf` pattern may name.
const MAX_DATA_FILES: usize = 1 << 16;

struct Header {
    fields: Vec<(String, String)>,
    /// Lines after `data file: LIST` (the data files, one per line).
    list: Vec<String>,
    /// Where the header ends (the blank line) in its file: attached data starts here.
    end: u64,
}

impl Header {
    fn get(&self, key: &str) -> Option<&str> {
        self.fields.iter().find(|(k, _)| *k == key).map(|(_, v)| v.as_str())
    }
}

fn parse_header(path: &Path) -> Result<Header> {
    let f = std::fs::File::open(path).map_err(|e| FormatError::io(path, e))?;
    let mut head = Vec::new();
    f.take(MAX_HEADER).read_to_end(&mut head).map_err(|e| FormatError::io(path, e))?;
    if !head.starts_with(b"NRRD000") {
        return Err(FormatError::invalid(path, "not a NRRD file (no NRRD000x magic)"));
    }
    let mut fields = Vec::new();
    let mut list = Vec::new();
    let mut in_list = false;
    let mut pos = head.iter().position(|&b| b == b'\n').map_or(head.len(), |i| i + 1);
    loop {
        if pos >= head.len() {
            // A detached header may end without a blank line; an attached one may not.
            break;
        }
        let end = head[pos..].iter().position(|&b| b == b'\n').map_or(head.len(), |i| pos + i);
        let line = String::from_utf8_lossy(&head[pos..end]).trim_end_matches('\r').to_string();
        pos = end + 1;
        if line.is_empty() {
            break;
        }
        if in_list {
            list.push(line.trim().to_string());
            continue;
        }
        if line.starts_with('#') || line.contains(":=") {
            continue; // comments, key/value pairs
        }
        let (k, v) = line.split_once(": ").ok_or_else(|| {
            FormatError::invalid(path, format!("header line '{}' is not 'field: value'", line.chars().take(60).collect::<String>()))
        })?;
        let key = k
            .trim()
            .to_ascii_lowercase()
            .replace("datafile", "data file")
            .replace("byteskip", "byte skip")
            .replace("lineskip", "line skip");
        let value = v.trim().to_string();
        if key == "data file" && value.to_ascii_uppercase().starts_with("LIST") {
            in_list = true;
        }
        fields.push((key, value));
    }
    Ok(Header { fields, list, end: pos.min(head.len()) as u64 })
}

fn scalar_type(path: &Path, t: &str) -> Result<ScalarType> {
    let t = t.trim().to_ascii_lowercase();
    Ok(match t.as_str() {
        "signed char" | "int8" | "int8_t" => ScalarType::I8,
        "uchar" | "unsigned char" | "uint8" | "uint8_t" => ScalarType::U8,
        "short" | "short int" | "signed short" | "signed short int" | "int16" | "int16_t" => ScalarType::I16,
        "ushort" | "unsigned short" | "unsigned short int" | "uint16" | "uint16_t" => ScalarType::U16,
        "int" | "signed int" | "int32" | "int32_t" => ScalarType::I32,
        "uint" | "unsigned int" | "uint32" | "uint32_t" => ScalarType::U32,
        "float" => ScalarType::F32,
        "double" => ScalarType::F64,
        _ => return Err(FormatError::unsupported(path, format!("type '{t}': not a scalar type volumes keep"))),
    })
}

/// The vectors of `space directions` ("(1,0,0) (0,1,0) none …"), None for "none".
fn directions(path: &Path, value: &str) -> Result<Vec<Option<[f64; 3]>>> {
    let mut out = Vec::new();
    let mut rest = value.trim();
    while !rest.is_empty() {
        if let Some(r) = rest.strip_prefix("none") {
            out.push(None);
            rest = r.trim_start();
            continue;
        }
        let close = rest
            .find(')')
            .filter(|_| rest.starts_with('('))
            .ok_or_else(|| FormatError::invalid(path, format!("space directions '{value}' is malformed")))?;
        let v = raw::numbers(path, "space directions", &rest[1..close], 3)?;
        if v.len() != 3 {
            return Err(FormatError::unsupported(path, format!("space directions '{value}': only 3-D spaces are read")));
        }
        out.push(Some([v[0], v[1], v[2]]));
        rest = rest[close + 1..].trim_start();
    }
    Ok(out)
}

/// Signs that take the header's space to RAS, and a note where the space has no anatomy.
fn space_to_ras(path: &Path, space: Option<&str>) -> Result<([f64; 3], Option<&'static str>)> {
    let Some(s) = space else { return Ok(([1.0; 3], None)) };
    Ok(match s.trim().to_ascii_lowercase().as_str() {
        "right-anterior-superior" | "ras" => ([1.0, 1.0, 1.0], None),
        "left-anterior-superior" | "las" => ([-1.0, 1.0, 1.0], None),
        "left-posterior-superior" | "lps" => ([-1.0, -1.0, 1.0], None),
        "scanner-xyz" | "3d-right-handed" => ([1.0; 3], None),
        "3d-left-handed" => {
            ([1.0; 3], Some("space 3D-left-handed: its coordinates taken as world x, y, z (no anatomical frame says which axis to mirror)"))
        }
        other => return Err(FormatError::unsupported(path, format!("space '{other}': not a 3-D space volumes are placed in"))),
    })
}

pub fn read_nrrd(path: &Path, limits: &Limits) -> Result<Volume> {
    let h = parse_header(path)?;
    let dimension: usize = h
        .get("dimension")
        .ok_or_else(|| FormatError::invalid(path, "no dimension field"))?
        .parse()
        .map_err(|_| FormatError::invalid(path, "dimension is not a count"))?;
    if !(2..=3).contains(&dimension) {
        return Err(FormatError::unsupported(
            path,
            format!("dimension {dimension}: volumes have 2 or 3 axes (a vector or time axis is not read)"),
        ));
    }
    if let Some(kinds) = h.get("kinds") {
        let scalar = kinds.split_whitespace().all(|k| matches!(k.to_ascii_lowercase().as_str(), "domain" | "space" | "none" | "???"));
        if !scalar {
            return Err(FormatError::unsupported(
                path,
                format!("kinds '{kinds}': a non-spatial axis (vector, colour, time, list) is not a scalar volume"),
            ));
        }
    }
    let ty = scalar_type(path, h.get("type").ok_or_else(|| FormatError::invalid(path, "no type field"))?)?;
    let sizes = raw::numbers(path, "sizes", h.get("sizes").ok_or_else(|| FormatError::invalid(path, "no sizes field"))?, dimension)?;
    let mut dims = [1usize; 3];
    for i in 0..dimension {
        if sizes[i] < 1.0 || sizes[i].fract() != 0.0 || sizes[i] > u32::MAX as f64 {
            return Err(FormatError::invalid(path, format!("size {} is not a positive count", sizes[i])));
        }
        dims[i] = sizes[i] as usize;
    }
    let n = raw::voxel_count(path, dims, ty, limits)?;
    let (signs, space_note) = space_to_ras(path, h.get("space"))?;
    let mut axes = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let mut origin = [0.0; 3];
    if let Some(d) = h.get("space directions") {
        let dirs = directions(path, d)?;
        if dirs.len() != dimension || dirs.iter().any(Option::is_none) {
            return Err(FormatError::unsupported(path, format!("space directions '{d}': each of the {dimension} axes needs a vector")));
        }
        for (i, v) in dirs.iter().enumerate() {
            axes[i] = v.unwrap();
        }
        if let Some(o) = h.get("space origin") {
            let o = raw::numbers(path, "space origin", o.trim_matches(|c| c == '(' || c == ')'), 3)?;
            origin = [o[0], o[1], o[2]];
        }
    } else if let Some(s) = h.get("spacings") {
        let words: Vec<&str> = s.split_whitespace().collect();
        for (i, w) in words.iter().take(dimension).enumerate() {
            let step = if w.eq_ignore_ascii_case("nan") {
                1.0
            } else {
                w.parse::<f64>().map_err(|_| FormatError::invalid(path, format!("spacings '{s}' is not numbers")))?
            };
            axes[i] = [0.0; 3];
            axes[i][i] = step;
        }
    }
    for i in 0..3 {
        for r in 0..3 {
            axes[i][r] *= signs[r];
        }
        origin[i] *= signs[i];
    }
    let affine = raw::affine_from_axes(axes, origin);
    raw::check_affine(path, &affine)?;
    let encoding = h.get("encoding").ok_or_else(|| FormatError::invalid(path, "no encoding field"))?.to_ascii_lowercase();
    let compression = match encoding.as_str() {
        "raw" => Compression::None,
        "gzip" | "gz" => Compression::Gzip,
        "ascii" | "text" | "txt" => Compression::None,
        other => return Err(FormatError::unsupported(path, format!("encoding '{other}' (raw, gzip and ascii are read)"))),
    };
    let ascii = matches!(encoding.as_str(), "ascii" | "text" | "txt");
    let big_endian = h.get("endian").is_some_and(|e| e.eq_ignore_ascii_case("big"));
    if ty.size() > 1 && !ascii && h.get("endian").is_none() {
        return Err(FormatError::invalid(path, "no endian field for multi-byte data"));
    }
    let dir = path.parent().unwrap_or(Path::new(".")).to_path_buf();
    let files = data_files(path, &h, &dir, dims[dimension - 1])?;
    let line_skip: usize =
        h.get("line skip").map_or(Ok(0), |s| s.trim().parse()).map_err(|_| FormatError::invalid(path, "line skip is not a count"))?;
    let byte_skip: i64 =
        h.get("byte skip").map_or(Ok(0), |s| s.trim().parse()).map_err(|_| FormatError::invalid(path, "byte skip is not a count"))?;
    // Each file holds an equal share of the samples (one slice each for a pattern).
    let per_file = n / files.len();
    if per_file * files.len() != n {
        return Err(FormatError::invalid(path, format!("{} data files cannot share {n} samples equally", files.len())));
    }
    if !ascii {
        // The voxel data read (from every data file) and the voxels converted from it are
        // held at once.
        limits.check(path, "voxel data and the voxels converted from it", &[n as u64, ty.size() as u64, 2])?;
    }
    let mut bytes = Vec::new();
    let mut text_values = Vec::new();
    for (file, attached) in &files {
        let skip_lines = |f: &Path, from: u64| -> Result<u64> {
            let mut at = from;
            if line_skip > 0 {
                let mut r = std::io::BufReader::new(open_data(path, f)?);
                std::io::Seek::seek(&mut r, std::io::SeekFrom::Start(from)).map_err(|e| data_error(path, f, e))?;
                let mut line = Vec::new();
                for k in 0..line_skip {
                    line.clear();
                    let read = std::io::BufRead::read_until(&mut r, b'\n', &mut line).map_err(|e| data_error(path, f, e))?;
                    if read == 0 {
                        // A lying count must not spin at the end of the file.
                        return Err(FormatError::invalid(path, format!("line skip {line_skip}: the data ends after {k} lines")));
                    }
                    at += read as u64;
                }
            }
            Ok(at)
        };
        let from = skip_lines(file, if *attached { h.end } else { 0 })?;
        if ascii {
            let mut f = open_data(path, file)?;
            std::io::Seek::seek(&mut f, std::io::SeekFrom::Start(from)).map_err(|e| data_error(path, file, e))?;
            let mut text = String::new();
            // Text numbers take at least two bytes each: read no more than the limit allows.
            limits.check(path, "ascii data", &[per_file as u64, 2])?;
            f.take(limits.bytes().saturating_add(1))
                .read_to_string(&mut text)
                .map_err(|_| FormatError::invalid(path, "ascii data is not text"))?;
            text_values.push(text);
            continue;
        }
        let start = match byte_skip {
            -1 => Start::FromEnd,
            s if s >= 0 => Start::At(from + s as u64),
            s => return Err(FormatError::invalid(path, format!("byte skip {s} is neither a count nor -1"))),
        };
        let block = raw::read_block(path, file, start, compression, (per_file * ty.size()) as u64, limits)?;
        if bytes.is_empty() {
            // One data file (or the first): its block is the voxel data, not copied.
            bytes = block;
            bytes.reserve_exact((n - per_file) * ty.size());
        } else {
            bytes.extend(block);
        }
    }
    let data = if ascii { raw::parse_text(path, &text_values.join("\n"), ty, n)? } else { VoxelData::from_bytes(ty, &bytes, big_endian) };
    let mut v = Volume::new(dims, affine, data);
    v.notes.push(format!(
        "NRRD {}D {}, {}{}{}",
        dimension,
        ty.name(),
        encoding,
        if ty.size() > 1 && !ascii {
            if big_endian {
                ", big-endian"
            } else {
                ", little-endian"
            }
        } else {
            ""
        },
        if files.len() > 1 { format!(", {} data files", files.len()) } else { String::new() }
    ));
    if let Some(note) = space_note {
        v.notes.push(note.to_string());
    }
    for key in ["type", "encoding", "space", "data file"] {
        if let Some(value) = h.get(key) {
            v.attributes.push((key.to_string(), value.to_string()));
        }
    }
    Ok(v)
}

/// An I/O error on `file` as the header's error (a data file is named by its name).
fn data_error(path: &Path, file: &Path, e: std::io::Error) -> FormatError {
    let which =
        if file == path { "file".to_string() } else { format!("data file {}", file.file_name().unwrap_or_default().to_string_lossy()) };
    FormatError::invalid(path, format!("{which}: {}", crate::error::io_reason(&e)))
}

fn open_data(path: &Path, file: &Path) -> Result<std::fs::File> {
    std::fs::File::open(file).map_err(|e| data_error(path, file, e))
}

/// The files holding the data, each with whether it is the header's own (attached).
fn data_files(path: &Path, h: &Header, dir: &Path, slices: usize) -> Result<Vec<(PathBuf, bool)>> {
    let Some(spec) = h.get("data file") else { return Ok(vec![(path.to_path_buf(), true)]) };
    if spec.to_ascii_uppercase().starts_with("LIST") {
        if h.list.is_empty() {
            return Err(FormatError::invalid(path, "data file: LIST names no files"));
        }
        return Ok(h.list.iter().map(|f| (dir.join(f), false)).collect());
    }
    let words: Vec<&str> = spec.split_whitespace().collect();
    if words.len() >= 4 && words[0].contains('%') {
        // printf pattern, min, max, step (and an optional sub-dimension, ignored: one slice each).
        let num =
            |w: &str| w.parse::<i64>().map_err(|_| FormatError::invalid(path, format!("data file '{spec}': '{w}' is not an integer")));
        let (lo, hi, step) = (num(words[1])?, num(words[2])?, num(words[3])?);
        let span = hi.checked_sub(lo).and_then(|d| d.checked_div(step)).filter(|&s| s >= 0 && step != 0);
        let Some(span) = span else {
            return Err(FormatError::invalid(path, format!("data file '{spec}': min, max and step do not make a range")));
        };
        let count = usize::try_from(span).unwrap_or(usize::MAX).saturating_add(1);
        // One file per slice at most, and no more files than a real series would split into
        // (the list is built before the first file is opened).
        if count > slices.max(1) || count > MAX_DATA_FILES {
            return Err(FormatError::invalid(path, format!("data file '{spec}' names {count} files for {slices} slices")));
        }
        return (0..count).map(|k| Ok((dir.join(printf_int(path, words[0], lo + k as i64 * step)?), false))).collect();
    }
    Ok(vec![(dir.join(spec), false)])
}

/// `pattern` with its one integer conversion (%d, %i, %u, %0Nd, %Nd) replaced by `value`.
fn printf_int(path: &Path, pattern: &str, value: i64) -> Result<String> {
    let at = pattern.find('%').unwrap();
    let rest = &pattern[at + 1..];
    let conv = rest
        .find(|c: char| c.is_ascii_alphabetic())
        .ok_or_else(|| FormatError::invalid(path, format!("data file pattern '{pattern}' has no conversion")))?;
    let (flags, kind) = (&rest[..conv], &rest[conv..conv + 1]);
    if !matches!(kind, "d" | "i" | "u") || rest[conv + 1..].contains('%') {
        return Err(FormatError::unsupported(path, format!("data file pattern '{pattern}': one %d conversion is read")));
    }
    let width: usize = flags.trim_start_matches('0').parse().unwrap_or(0);
    let number = if flags.starts_with('0') { format!("{value:0width$}") } else { format!("{value:width$}") };
    Ok(format!("{}{}{}", &pattern[..at], number, &rest[conv + 1..]))
}

/// Writes `vol` as an attached, gzip-encoded NRRD in RAS space: `space directions` from the
/// affine's columns, `space origin` its translation, the stored type kept where the values
/// are the stored ones; a volume with a rescale (slope, intercept: NRRD has none) is written
/// as its real-world values in float. Atomically (a temporary file renamed).
pub fn write_nrrd(path: &Path, vol: &Volume) -> Result<()> {
    use std::io::Write;
    let identity = vol.rescale.is_identity();
    let ty = if identity { vol.data.scalar_type() } else { ScalarType::F32 };
    let name = match ty {
        ScalarType::U8 => "uint8",
        ScalarType::I8 => "int8",
        ScalarType::U16 => "uint16",
        ScalarType::I16 => "int16",
        ScalarType::U32 => "uint32",
        ScalarType::I32 => "int32",
        ScalarType::F32 => "float",
        ScalarType::F64 => "double",
    };
    let a = &vol.affine;
    let column = |c: usize| format!("({},{},{})", a[0][c], a[1][c], a[2][c]);
    let header = format!(
        "NRRD0004\n# Written by volterra\ntype: {name}\ndimension: 3\nspace: right-anterior-superior\nsizes: {} {} {}\n\
         space directions: {} {} {}\nkinds: domain domain domain\nendian: little\nencoding: gzip\nspace origin: ({},{},{})\n\n",
        vol.dims[0],
        vol.dims[1],
        vol.dims[2],
        column(0),
        column(1),
        column(2),
        a[0][3],
        a[1][3],
        a[2][3]
    );
    crate::atomic::write_atomically(path, |w| {
        w.write_all(header.as_bytes()).map_err(|e| FormatError::io(path, e))?;
        let mut gz = flate2::write::GzEncoder::new(w, flate2::Compression::new(4));
        let io = |e| FormatError::io(path, e);
        if identity {
            gz.write_all(&vol.data.to_le_bytes()).map_err(io)?;
        } else {
            let values: Vec<u8> = (0..vol.voxel_count()).flat_map(|i| (vol.value(i) as f32).to_le_bytes()).collect();
            gz.write_all(&values).map_err(io)?;
        }
        gz.finish().map_err(io)?;
        Ok(())
    })
}
