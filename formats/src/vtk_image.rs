//! Legacy VTK `DATASET STRUCTURED_POINTS` (`.vtk`) as a volume, read here (through
//! `vtk_legacy::Cursor`) rather than by vtkio: vtkio keeps origin and spacing as f32 and
//! every array whole, where a volume wants f64 geometry and only its scalars. VTK's
//! coordinates are taken as world coordinates (VTK has no anatomical frame): world =
//! ORIGIN + SPACING ⊙ index.
//!
//! Read: ASCII and BINARY (big-endian, as the format defines), the first `SCALARS` of the
//! POINT_DATA (other attributes before it skipped by their declared sizes; a one-component
//! FIELD array where there are no SCALARS), every scalar type that fits a volume.
//! `STRUCTURED_GRID` and `RECTILINEAR_GRID` are refused as volumes with their reason
//! (points placed one by one, or spacing that varies).

use crate::error::{FormatError, Result};
use crate::memory::Limits;
use crate::volume::{ScalarType, Volume, VoxelData};
use crate::vtk_legacy::Cursor;
use std::path::Path;

/// What DATASET a legacy file declares (None: no DATASET line in its first 4 KiB).
pub fn legacy_dataset(path: &Path) -> Result<Option<String>> {
    use std::io::Read;
    let mut head = Vec::new();
    std::fs::File::open(path)
        .map_err(|e| FormatError::io(path, e))?
        .take(4096)
        .read_to_end(&mut head)
        .map_err(|e| FormatError::io(path, e))?;
    let text = String::from_utf8_lossy(&head);
    Ok(text.lines().find_map(|l| l.trim().strip_prefix("DATASET ").map(|d| d.trim().to_ascii_uppercase())))
}

/// `count` values of `ty` for a volume: binary big-endian bytes, or ASCII numbers.
fn voxel_values(c: &mut Cursor, binary: bool, ty: &str, count: usize, limits: &Limits) -> Result<(ScalarType, VoxelData)> {
    let st = scalar_type(c.path, ty)?;
    limits.check(c.path, "scalars", &[count as u64, st.size() as u64])?;
    if binary {
        let want = count * st.size();
        let bytes = c.b.get(c.pos..c.pos + want).ok_or_else(|| {
            FormatError::invalid(
                c.path,
                format!("file is truncated: {count} {ty} values need {want} bytes, {} remain", c.b.len().saturating_sub(c.pos)),
            )
        })?;
        c.pos += want;
        return Ok((st, VoxelData::from_bytes(st, bytes, true)));
    }
    let mut v = Vec::with_capacity(count.min(1 << 24));
    while v.len() < count {
        while c.pos < c.b.len() && c.b[c.pos].is_ascii_whitespace() {
            c.pos += 1;
        }
        let end = c.b[c.pos..].iter().position(|ch| ch.is_ascii_whitespace()).map_or(c.b.len(), |i| c.pos + i);
        if end == c.pos {
            return Err(FormatError::invalid(c.path, format!("file is truncated: {} of {count} values", v.len())));
        }
        let w = String::from_utf8_lossy(&c.b[c.pos..end]);
        v.push(w.parse::<f64>().map_err(|_| FormatError::invalid(c.path, format!("'{w}' is not a number")))?);
        c.pos = end;
    }
    Ok((st, crate::raw::from_f64s(st, v)))
}

fn scalar_type(path: &Path, ty: &str) -> Result<ScalarType> {
    Ok(match ty.to_ascii_lowercase().as_str() {
        "unsigned_char" | "bit" => ScalarType::U8,
        "char" => ScalarType::I8,
        "unsigned_short" => ScalarType::U16,
        "short" => ScalarType::I16,
        "unsigned_int" => ScalarType::U32,
        "int" => ScalarType::I32,
        "float" => ScalarType::F32,
        "double" => ScalarType::F64,
        other => return Err(FormatError::unsupported(path, format!("data type '{other}': not a scalar type volumes keep"))),
    })
}

fn numbers<const N: usize>(path: &Path, line: &str) -> Result<[f64; N]> {
    let v: Vec<f64> = line.split_whitespace().skip(1).filter_map(|w| w.parse().ok()).filter(|x: &f64| x.is_finite()).collect();
    if v.len() != N {
        return Err(FormatError::invalid(path, format!("'{line}' does not give {N} numbers")));
    }
    Ok(std::array::from_fn(|i| v[i]))
}

pub fn read_structured_points(path: &Path, limits: &Limits) -> Result<Volume> {
    let len = std::fs::metadata(path).map_err(|e| FormatError::io(path, e))?.len();
    limits.check(path, "VTK file", &[len])?;
    let bytes = std::fs::read(path).map_err(|e| FormatError::io(path, e))?;
    let mut c = Cursor { path, b: &bytes, pos: 0 };
    if !c.expect_line("header")?.starts_with("# vtk DataFile") {
        return Err(FormatError::invalid(path, "not a legacy VTK file (no '# vtk DataFile' header)"));
    }
    let title = c.expect_line("title")?;
    let binary = match c.expect_line("ASCII or BINARY")?.to_ascii_uppercase().as_str() {
        "BINARY" => true,
        "ASCII" => false,
        other => return Err(FormatError::invalid(path, format!("'{other}' is neither ASCII nor BINARY"))),
    };
    let dataset = c.expect_line("DATASET")?;
    match dataset.to_ascii_uppercase().split_whitespace().nth(1).unwrap_or("") {
        "STRUCTURED_POINTS" => {}
        "STRUCTURED_GRID" => {
            return Err(FormatError::unsupported(
                path,
                "a STRUCTURED_GRID places its points one by one (a curvilinear grid), not a regular volume",
            ))
        }
        "RECTILINEAR_GRID" => {
            return Err(FormatError::unsupported(path, "a RECTILINEAR_GRID's spacing varies along its axes: not a regular volume"))
        }
        other => return Err(FormatError::unsupported(path, format!("DATASET {other} is not a volume"))),
    }
    let (mut dims, mut origin, mut spacing) = (None, [0.0; 3], [1.0; 3]);
    let npoints = loop {
        let l = c.expect_line("POINT_DATA")?;
        let key = l.split_whitespace().next().unwrap_or("").to_ascii_uppercase();
        match key.as_str() {
            "DIMENSIONS" => {
                let d = numbers::<3>(path, &l)?;
                if d.iter().any(|&x| x < 1.0 || x.fract() != 0.0 || x > u32::MAX as f64) {
                    return Err(FormatError::invalid(path, format!("'{l}': dimensions must be positive counts")));
                }
                dims = Some(d.map(|x| x as usize));
            }
            "ORIGIN" => origin = numbers::<3>(path, &l)?,
            "SPACING" | "ASPECT_RATIO" => spacing = numbers::<3>(path, &l)?,
            "POINT_DATA" => {
                break l
                    .split_whitespace()
                    .nth(1)
                    .and_then(|w| w.parse::<usize>().ok())
                    .ok_or_else(|| FormatError::invalid(path, format!("'{l}': not a count")))?
            }
            "CELL_DATA" => return Err(FormatError::unsupported(path, "CELL_DATA before POINT_DATA: cell values are not voxels")),
            "FIELD" => return Err(FormatError::unsupported(path, "FIELD data before POINT_DATA is not read")),
            _ => {
                return Err(FormatError::invalid(
                    path,
                    format!("unexpected line '{}' in the STRUCTURED_POINTS header", l.chars().take(60).collect::<String>()),
                ))
            }
        }
    };
    let dims = dims.ok_or_else(|| FormatError::invalid(path, "no DIMENSIONS"))?;
    let n = dims.iter().try_fold(1usize, |n, &d| n.checked_mul(d)).ok_or_else(|| FormatError::invalid(path, "point count overflows"))?;
    if npoints != n {
        return Err(FormatError::invalid(path, format!("POINT_DATA {npoints} does not match DIMENSIONS {dims:?} ({n} points)")));
    }
    let (name, data) = loop {
        let Some(l) = c.line() else {
            return Err(FormatError::unsupported(path, "POINT_DATA holds no SCALARS: nothing to draw as a volume"));
        };
        let w: Vec<&str> = l.split_whitespace().collect();
        match w[0].to_ascii_uppercase().as_str() {
            "SCALARS" => {
                let comps: usize = w.get(3).and_then(|x| x.parse().ok()).unwrap_or(1);
                let ty = w.get(2).copied().unwrap_or("float");
                // The LOOKUP_TABLE line is optional in files VTK reads.
                let save = c.pos;
                if !c.line().is_some_and(|l| l.to_ascii_uppercase().starts_with("LOOKUP_TABLE")) {
                    c.pos = save;
                }
                if comps != 1 {
                    return Err(FormatError::unsupported(
                        path,
                        format!("SCALARS '{}' has {comps} components: a volume holds one value per voxel", w.get(1).unwrap_or(&"")),
                    ));
                }
                let (_, data) = voxel_values(&mut c, binary, ty, n, limits)?;
                break (w.get(1).unwrap_or(&"scalars").to_string(), data);
            }
            "VECTORS" | "NORMALS" => c.skip(binary, w.get(2).copied().unwrap_or("float"), 3 * n, &l)?,
            "TENSORS" => c.skip(binary, w.get(2).copied().unwrap_or("float"), 9 * n, &l)?,
            "TEXTURE_COORDINATES" => {
                let dim: usize = w.get(2).and_then(|x| x.parse().ok()).unwrap_or(2);
                c.skip(binary, w.get(3).copied().unwrap_or("float"), dim * n, &l)?
            }
            "COLOR_SCALARS" => return Err(FormatError::unsupported(path, "COLOR_SCALARS before SCALARS: colours are not a scalar volume")),
            "FIELD" => {
                let arrays: usize = w.get(2).and_then(|x| x.parse().ok()).unwrap_or(0);
                let mut found = None;
                for _ in 0..arrays {
                    let a = c.expect_line("FIELD array")?;
                    let f: Vec<&str> = a.split_whitespace().collect();
                    let (comps, tuples) = (
                        f.get(1).and_then(|x| x.parse::<usize>().ok()).unwrap_or(0),
                        f.get(2).and_then(|x| x.parse::<usize>().ok()).unwrap_or(0),
                    );
                    let ty = f.get(3).copied().unwrap_or("float");
                    if found.is_none() && comps == 1 && tuples == n {
                        found = Some((f[0].to_string(), voxel_values(&mut c, binary, ty, n, limits)?.1));
                    } else {
                        c.skip(binary, ty, comps.saturating_mul(tuples), &a)?;
                    }
                }
                if let Some(f) = found {
                    break f;
                }
            }
            other => return Err(FormatError::invalid(path, format!("unexpected '{other}' in POINT_DATA"))),
        }
    };
    let affine =
        [[spacing[0], 0.0, 0.0, origin[0]], [0.0, spacing[1], 0.0, origin[1]], [0.0, 0.0, spacing[2], origin[2]], [0.0, 0.0, 0.0, 1.0]];
    crate::raw::check_affine(path, &affine)?;
    let mut v = Volume::new(dims, affine, data);
    v.notes.push(format!(
        "legacy VTK STRUCTURED_POINTS ({}), scalars '{name}', title '{}'",
        if binary { "binary" } else { "ASCII" },
        title.chars().take(60).collect::<String>()
    ));
    v.attributes.push(("scalars".into(), name));
    Ok(v)
}
