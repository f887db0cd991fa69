//! MetaImage (`.mha`: header and data in one file; `.mhd`: header naming a raw file), ITK's
//! plain format. Geometry as ITK reads it: world = Offset + D · (spacing ⊙ index), where
//! row i of `TransformMatrix` (as written) is the direction of index axis i — D's columns —
//! in ITK's LPS frame, converted to RAS by negating x and y. `AnatomicalOrientation` is a
//! label ITK does not apply; neither do we.
//!
//! Read: 2-D and 3-D scalar images of every MET_ integer and float type that fits a
//! volume (64-bit integers refused), either byte order (`BinaryDataByteOrderMSB` or
//! `ElementByteOrderMSB`), raw or zlib (`CompressedData`), `ElementDataFile` LOCAL or one
//! file beside the header, `HeaderSize` including −1 (the data ends the file). Refused with
//! the reason: several channels, more than 3 dimensions, data split over a LIST or pattern
//! of files, ASCII data.

use crate::error::{FormatError, Result};
use crate::memory::Limits;
use crate::raw::{self, Compression, Start};
use crate::volume::{ScalarType, Volume, VoxelData};
use std::io::Read;
use std::path::Path;

/// The longest header read before `ElementDataFile` must have come.
const MAX_HEADER: u64 = 1 << 20;

pub fn read_metaimage(path: &Path, limits: &Limits) -> Result<Volume> {
    let f = std::fs::File::open(path).map_err(|e| FormatError::io(path, e))?;
    let mut head = Vec::new();
    f.take(MAX_HEADER).read_to_end(&mut head).map_err(|e| FormatError::io(path, e))?;
    // Key = value lines up to and including ElementDataFile; the data follows its line.
    let mut fields: Vec<(String, String)> = Vec::new();
    let mut data_at = None;
    let mut pos = 0;
    while pos < head.len() {
        let end = head[pos..].iter().position(|&b| b == b'\n').map_or(head.len(), |i| pos + i);
        let line = String::from_utf8_lossy(&head[pos..end]).trim().to_string();
        pos = end + 1;
        if line.is_empty() {
            continue;
        }
        let (k, v) = line
            .split_once('=')
            .ok_or_else(|| FormatError::invalid(path, format!("header line '{}' is not 'Key = Value'", short(&line))))?;
        let (k, v) = (k.trim().to_string(), v.trim().to_string());
        let last = k.eq_ignore_ascii_case("ElementDataFile");
        fields.push((k, v));
        if last {
            data_at = Some(pos.min(head.len()) as u64);
            break;
        }
    }
    let get = |key: &str| fields.iter().find(|(k, _)| k.eq_ignore_ascii_case(key)).map(|(_, v)| v.as_str());
    if fields.first().is_none_or(|(k, _)| !k.eq_ignore_ascii_case("ObjectType") && !k.eq_ignore_ascii_case("NDims")) {
        return Err(FormatError::invalid(path, "not a MetaImage (no 'ObjectType =' or 'NDims =' first)"));
    }
    let data_at = data_at.ok_or_else(|| FormatError::invalid(path, "header has no ElementDataFile (or is longer than 1 MiB)"))?;
    if let Some(t) = get("ObjectType") {
        if !t.eq_ignore_ascii_case("Image") {
            return Err(FormatError::unsupported(path, format!("ObjectType {t}: only Image objects are volumes")));
        }
    }
    let ndims: usize = get("NDims")
        .ok_or_else(|| FormatError::invalid(path, "no NDims"))?
        .parse()
        .map_err(|_| FormatError::invalid(path, format!("NDims '{}' is not a count", get("NDims").unwrap_or(""))))?;
    if !(2..=3).contains(&ndims) {
        return Err(FormatError::unsupported(path, format!("NDims {ndims}: volumes have 2 or 3 dimensions")));
    }
    if let Some(c) = get("ElementNumberOfChannels") {
        if c.trim() != "1" {
            return Err(FormatError::unsupported(path, format!("ElementNumberOfChannels {c}: a volume holds one value per voxel")));
        }
    }
    let sizes = raw::numbers(path, "DimSize", get("DimSize").ok_or_else(|| FormatError::invalid(path, "no DimSize"))?, ndims)?;
    let mut dims = [1usize; 3];
    for i in 0..ndims {
        let s = sizes[i];
        if s < 1.0 || s.fract() != 0.0 || s > u32::MAX as f64 {
            return Err(FormatError::invalid(path, format!("DimSize {s} is not a positive count")));
        }
        dims[i] = s as usize;
    }
    let ty_name = get("ElementType").ok_or_else(|| FormatError::invalid(path, "no ElementType"))?;
    let ty = match ty_name.to_ascii_uppercase().as_str() {
        "MET_UCHAR" => ScalarType::U8,
        "MET_CHAR" => ScalarType::I8,
        "MET_USHORT" => ScalarType::U16,
        "MET_SHORT" => ScalarType::I16,
        "MET_UINT" => ScalarType::U32,
        "MET_INT" => ScalarType::I32,
        "MET_FLOAT" => ScalarType::F32,
        "MET_DOUBLE" => ScalarType::F64,
        other => return Err(FormatError::unsupported(path, format!("ElementType {other}: not a scalar type volumes keep"))),
    };
    let n = raw::voxel_count(path, dims, ty, limits)?;
    let spacing = match get("ElementSpacing").or(get("ElementSize")) {
        Some(v) => raw::numbers(path, "ElementSpacing", v, ndims)?,
        None => vec![1.0; ndims],
    };
    let offset = match get("Offset").or(get("Position")).or(get("Origin")) {
        Some(v) => raw::numbers(path, "Offset", v, ndims)?,
        None => vec![0.0; ndims],
    };
    let matrix = match get("TransformMatrix").or(get("Rotation")).or(get("Orientation")) {
        Some(v) => raw::numbers(path, "TransformMatrix", v, ndims * ndims)?,
        None => (0..ndims * ndims).map(|k| if k % (ndims + 1) == 0 { 1.0 } else { 0.0 }).collect(),
    };
    // Row i of the matrix as written: the direction of index axis i (ITK's SetDirection(i, …)).
    let mut axes = [[0.0; 3]; 3];
    for i in 0..3 {
        for r in 0..3 {
            axes[i][r] = if i < ndims && r < ndims {
                matrix[i * ndims + r] * spacing[i]
            } else if i == r {
                1.0
            } else {
                0.0
            };
        }
    }
    let origin = [offset[0], offset[1], if ndims == 3 { offset[2] } else { 0.0 }];
    let affine = raw::lps_to_ras(raw::affine_from_axes(axes, origin));
    raw::check_affine(path, &affine)?;
    let yes = |key: &str| get(key).is_some_and(|v| v.eq_ignore_ascii_case("true"));
    let big_endian = yes("BinaryDataByteOrderMSB") || yes("ElementByteOrderMSB");
    if get("BinaryData").is_some_and(|v| v.eq_ignore_ascii_case("false")) {
        return Err(FormatError::unsupported(path, "BinaryData = False (ASCII voxel data)"));
    }
    let compression = if yes("CompressedData") { Compression::Zlib } else { Compression::None };
    let file = get("ElementDataFile").unwrap_or("LOCAL");
    let (data_file, start) = if file.eq_ignore_ascii_case("LOCAL") {
        (path.to_path_buf(), Start::At(data_at))
    } else if file.to_ascii_uppercase().starts_with("LIST") || file.contains('%') || file.split_whitespace().count() > 1 {
        return Err(FormatError::unsupported(path, format!("ElementDataFile '{}': data split over several files", short(file))));
    } else {
        let skip = get("HeaderSize").map(str::trim).unwrap_or("0");
        let start = match skip.parse::<i64>() {
            Ok(-1) => Start::FromEnd,
            Ok(s) if s >= 0 => Start::At(s as u64),
            _ => return Err(FormatError::invalid(path, format!("HeaderSize '{skip}' is not a byte count or -1"))),
        };
        (path.parent().unwrap_or(Path::new(".")).join(file), start)
    };
    let bytes = raw::read_block(path, &data_file, start, compression, (n * ty.size()) as u64, limits)?;
    let mut v = Volume::new(dims, affine, VoxelData::from_bytes(ty, &bytes, big_endian));
    v.notes.push(format!(
        "MetaImage {}D {}, {}{}",
        ndims,
        ty_name,
        if big_endian { "big-endian" } else { "little-endian" },
        if compression == Compression::Zlib { ", zlib" } else { "" }
    ));
    for key in ["ElementType", "AnatomicalOrientation", "CompressedData", "ElementDataFile"] {
        if let Some(value) = get(key) {
            v.attributes.push((key.to_string(), value.to_string()));
        }
    }
    if let Some(m) = get("Modality") {
        // MET_MOD_CT, MET_MOD_MR, …
        v.modality = Some(m.trim_start_matches("MET_MOD_").to_string());
    }
    Ok(v)
}

fn short(s: &str) -> String {
    s.chars().take(60).collect()
}
