//! The voxel block of formats whose text header points at raw data (MetaImage, NRRD):
//! read from the header's own file or a separate one, after a byte skip or from the end,
//! raw or compressed, checked against the memory limit and the size the header declares —
//! a lying header gets an error, never an allocation it asked for.

use crate::error::{FormatError, Result};
use crate::memory::Limits;
use crate::volume::{ScalarType, VoxelData};
use std::io::{Read, Seek, SeekFrom};
use std::path::Path;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Compression {
    None,
    /// A zlib stream (MetaImage's `CompressedData = True`).
    Zlib,
    /// A gzip stream (NRRD's `encoding: gzip`).
    Gzip,
}

/// Where the voxel block starts in its file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Start {
    At(u64),
    /// The block ends the file (MetaImage `HeaderSize = -1`, NRRD `byte skip: -1`).
    FromEnd,
}

/// Reads `want` bytes of voxel data from `file` (named in errors as `path`, the header).
/// The bytes and the voxels converted from them are held at once: both count against the
/// limit.
pub fn read_block(path: &Path, file: &Path, start: Start, compression: Compression, want: u64, limits: &Limits) -> Result<Vec<u8>> {
    limits.check(path, "voxel data and the voxels converted from it", &[want, 2])?;
    // Errors are the header's: a separate data file is named by its name beside it.
    let which =
        if file == path { "file".to_string() } else { format!("data file {}", file.file_name().unwrap_or_default().to_string_lossy()) };
    let io = |e: std::io::Error| FormatError::invalid(path, format!("{which}: {}", crate::error::io_reason(&e)));
    let mut f = std::fs::File::open(file).map_err(io)?;
    let len = f.metadata().map_err(io)?.len();
    let at = match (start, compression) {
        (Start::At(n), _) => n,
        (Start::FromEnd, Compression::None) => len
            .checked_sub(want)
            .ok_or_else(|| FormatError::invalid(path, format!("{which} holds {len} bytes, fewer than the {want} the header declares")))?,
        (Start::FromEnd, _) => return Err(FormatError::invalid(path, "a compressed block cannot be found from the end of its file")),
    };
    if at > len {
        return Err(FormatError::invalid(path, format!("the data would start at byte {at} of {which}, which holds {len}")));
    }
    f.seek(SeekFrom::Start(at)).map_err(io)?;
    // Sized once (a byte over, for the check that a stream holds no more): a vector grown by
    // doubling would hold up to twice the data, and three times while it moves.
    let mut out = Vec::with_capacity(want as usize + 1);
    let got = match compression {
        Compression::None => {
            if len - at < want {
                return Err(FormatError::invalid(
                    path,
                    format!("{which} is truncated: it holds {} bytes of voxel data, the header declares {want}", len - at),
                ));
            }
            f.take(want).read_to_end(&mut out)
        }
        // One byte more than declared: a stream that holds more is an error, not truncated.
        Compression::Zlib => flate2::read::ZlibDecoder::new(std::io::BufReader::new(f)).take(want + 1).read_to_end(&mut out),
        Compression::Gzip => flate2::read::MultiGzDecoder::new(std::io::BufReader::new(f)).take(want + 1).read_to_end(&mut out),
    };
    got.map_err(|e| FormatError::invalid(path, format!("voxel data does not decompress: {e}")))?;
    if out.len() as u64 != want {
        let how = if (out.len() as u64) < want { "truncated: it holds" } else { "longer than declared: it holds at least" };
        return Err(FormatError::invalid(path, format!("voxel data is {how} {} bytes, the header declares {want}", out.len())));
    }
    Ok(out)
}

/// Voxel values from whitespace-separated text (NRRD `encoding: ascii`), `count` of them.
pub fn parse_text(path: &Path, text: &str, ty: ScalarType, count: usize) -> Result<VoxelData> {
    let mut values = Vec::with_capacity(count.min(1 << 24));
    for word in text.split(|c: char| c.is_ascii_whitespace() || c == ',').filter(|w| !w.is_empty()) {
        if values.len() == count {
            break;
        }
        values.push(word.parse::<f64>().map_err(|_| FormatError::invalid(path, format!("ascii data holds '{word}', not a number")))?);
    }
    if values.len() < count {
        return Err(FormatError::invalid(path, format!("ascii data holds {} values, the header declares {count}", values.len())));
    }
    Ok(from_f64s(ty, values))
}

/// Numbers read from text, stored as `ty` (integers from text are whole).
pub fn from_f64s(ty: ScalarType, values: Vec<f64>) -> VoxelData {
    match ty {
        ScalarType::U8 => VoxelData::U8(values.iter().map(|&v| v as u8).collect()),
        ScalarType::I8 => VoxelData::I8(values.iter().map(|&v| v as i8).collect()),
        ScalarType::U16 => VoxelData::U16(values.iter().map(|&v| v as u16).collect()),
        ScalarType::I16 => VoxelData::I16(values.iter().map(|&v| v as i16).collect()),
        ScalarType::U32 => VoxelData::U32(values.iter().map(|&v| v as u32).collect()),
        ScalarType::I32 => VoxelData::I32(values.iter().map(|&v| v as i32).collect()),
        ScalarType::F32 => VoxelData::F32(values.iter().map(|&v| v as f32).collect()),
        ScalarType::F64 => VoxelData::F64(values),
    }
}

/// The voxel count of `dims`, checked for overflow and against the memory limit for
/// values of `ty`.
pub fn voxel_count(path: &Path, dims: [usize; 3], ty: ScalarType, limits: &Limits) -> Result<usize> {
    let n = dims.iter().try_fold(1usize, |n, &d| n.checked_mul(d)).ok_or_else(|| FormatError::invalid(path, "voxel count overflows"))?;
    limits.check(path, "volume", &[dims[0] as u64, dims[1] as u64, dims[2] as u64, ty.size() as u64])?;
    Ok(n)
}

/// Parses `n` numbers from a header value ("1.5 1.5 2"), naming `key` in errors.
pub fn numbers(path: &Path, key: &str, value: &str, n: usize) -> Result<Vec<f64>> {
    let v: Vec<f64> = value
        .split(|c: char| c.is_ascii_whitespace() || c == ',')
        .filter(|w| !w.is_empty())
        .map(|w| w.parse::<f64>().ok().filter(|x| x.is_finite()))
        .collect::<Option<_>>()
        .ok_or_else(|| FormatError::invalid(path, format!("{key} '{value}' is not a list of numbers")))?;
    if v.len() < n {
        return Err(FormatError::invalid(path, format!("{key} '{value}' has {} numbers, {n} needed", v.len())));
    }
    Ok(v)
}

/// The affine (index → world) of a grid whose axis i steps along `axes[i]` (world vectors,
/// spacing included) from `origin`.
pub fn affine_from_axes(axes: [[f64; 3]; 3], origin: [f64; 3]) -> crate::Affine {
    let mut a = [[0.0; 4]; 4];
    for r in 0..3 {
        for c in 0..3 {
            a[r][c] = axes[c][r];
        }
        a[r][3] = origin[r];
    }
    a[3][3] = 1.0;
    a
}

/// The affine with world x and y negated (LPS, ITK's and DICOM's frame, to RAS).
pub fn lps_to_ras(mut a: crate::Affine) -> crate::Affine {
    for r in 0..2 {
        for c in 0..4 {
            a[r][c] = -a[r][c];
        }
    }
    a
}

/// Refuses a grid that is not one: an axis of zero (or non-finite) length, or axes that do
/// not span space (a singular affine: every voxel of a slab on one plane).
pub fn check_affine(path: &Path, a: &crate::Affine) -> Result<()> {
    for c in 0..3 {
        let len = (a[0][c] * a[0][c] + a[1][c] * a[1][c] + a[2][c] * a[2][c]).sqrt();
        if !(len.is_finite() && len > 0.0) {
            return Err(FormatError::invalid(path, format!("voxel axis {c} has length {len}: not a grid (a zero or non-finite spacing)")));
        }
    }
    if !a.iter().flatten().all(|x| x.is_finite()) {
        return Err(FormatError::invalid(path, "the origin is not finite"));
    }
    let det = a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1]) - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
        + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0]);
    let scale = (0..3).map(|c| (a[0][c] * a[0][c] + a[1][c] * a[1][c] + a[2][c] * a[2][c]).sqrt()).product::<f64>();
    if det.abs() <= 1e-12 * scale {
        return Err(FormatError::invalid(path, "the voxel axes do not span space (a singular direction matrix)"));
    }
    Ok(())
}
