//! NIfTI-1 and NIfTI-2 volumes: `.nii`, `.nii.gz`, and `.hdr`/`.img` pairs (each optionally
//! gzipped), either byte order, the eight scalar types volterra keeps.
//!
//! Why not the `nifti` crate: it does not read NIfTI-2 (open upstream issue), leaves the
//! qform/sform choice to the caller, and sizes its buffers from the header before we could
//! check them against the memory guard. The header is a fixed C struct, so we parse it here.

use crate::atomic::write_atomically;
use crate::error::{FormatError, Result};
use crate::memory::Limits;
use crate::volume::{spacing_of, Affine, Rescale, ScalarType, Volume, VoxelData};
use flate2::read::MultiGzDecoder;
use std::fs::File;
use std::io::{BufReader, Read, Write};
use std::path::{Path, PathBuf};

#[derive(Debug, Clone, Default)]
pub struct NiftiOptions {
    /// Which volume of a 4-D (or higher) file to read.
    pub volume_index: usize,
}

/// The header fields volterra uses, from either NIfTI version.
#[derive(Debug, Clone)]
pub struct NiftiHeader {
    pub version: u8,
    pub big_endian: bool,
    /// true for a single `.nii` file ("n+1"/"n+2"), false for a `.hdr`/`.img` pair.
    pub single_file: bool,
    pub dim: [i64; 8],
    pub datatype: i16,
    pub bitpix: i16,
    pub pixdim: [f64; 8],
    pub vox_offset: f64,
    pub scl_slope: f64,
    pub scl_inter: f64,
    pub xyzt_units: u8,
    pub qform_code: i32,
    pub sform_code: i32,
    pub quatern: [f64; 3],
    pub qoffset: [f64; 3],
    pub srow: [[f64; 4]; 3],
    pub descrip: String,
    pub intent_code: i32,
}

fn is_gz(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("gz"))
}

/// Opens `path`, inflating it when it starts with gzip's magic, and says whether it did.
/// Decided by the bytes, not the name: a gzip stream named `.nii` is read (it was refused as
/// a bad header), and so is a plain file named `.gz`.
fn open_maybe_gz(path: &Path) -> Result<(Box<dyn Read>, bool)> {
    use std::io::BufRead;
    let f = File::open(path).map_err(|e| FormatError::io(path, e))?;
    // A megabyte of buffer for large files; no more than the file for small ones (a pair's
    // header is 348 bytes).
    let len = f.metadata().map_err(|e| FormatError::io(path, e))?.len();
    let mut r = BufReader::with_capacity(len.clamp(8 << 10, 1 << 20) as usize, f);
    let gz = r.fill_buf().map_err(|e| FormatError::io(path, e))?.starts_with(&[0x1f, 0x8b]);
    Ok(if gz { (Box::new(MultiGzDecoder::new(r)), true) } else { (Box::new(r), false) })
}

/// `x.hdr[.gz]` → `x.img[.gz]` (same gz state, falling back to the other).
fn image_path_for_header(path: &Path) -> Result<PathBuf> {
    let s = path.to_string_lossy();
    let candidates: Vec<String> = if let Some(stem) = s.strip_suffix(".hdr.gz") {
        vec![format!("{stem}.img.gz"), format!("{stem}.img")]
    } else if let Some(stem) = s.strip_suffix(".hdr") {
        vec![format!("{stem}.img"), format!("{stem}.img.gz")]
    } else {
        return Err(FormatError::invalid(path, "header says the image is in a separate .img file, but this is not a .hdr file"));
    };
    candidates
        .iter()
        .map(PathBuf::from)
        .find(|p| p.exists())
        .ok_or_else(|| FormatError::invalid(path, format!("image file {} not found", candidates[0])))
}

struct Fields<'a> {
    b: &'a [u8],
    be: bool,
}

impl Fields<'_> {
    fn i16(&self, o: usize) -> i16 {
        let a = [self.b[o], self.b[o + 1]];
        if self.be {
            i16::from_be_bytes(a)
        } else {
            i16::from_le_bytes(a)
        }
    }
    fn i32(&self, o: usize) -> i32 {
        let a: [u8; 4] = self.b[o..o + 4].try_into().unwrap();
        if self.be {
            i32::from_be_bytes(a)
        } else {
            i32::from_le_bytes(a)
        }
    }
    fn i64(&self, o: usize) -> i64 {
        let a: [u8; 8] = self.b[o..o + 8].try_into().unwrap();
        if self.be {
            i64::from_be_bytes(a)
        } else {
            i64::from_le_bytes(a)
        }
    }
    fn f32(&self, o: usize) -> f64 {
        let a: [u8; 4] = self.b[o..o + 4].try_into().unwrap();
        (if self.be { f32::from_be_bytes(a) } else { f32::from_le_bytes(a) }) as f64
    }
    fn f64(&self, o: usize) -> f64 {
        let a: [u8; 8] = self.b[o..o + 8].try_into().unwrap();
        if self.be {
            f64::from_be_bytes(a)
        } else {
            f64::from_le_bytes(a)
        }
    }
    fn text(&self, o: usize, n: usize) -> String {
        let s = &self.b[o..o + n];
        let end = s.iter().position(|&c| c == 0).unwrap_or(n);
        String::from_utf8_lossy(&s[..end]).trim().to_string()
    }
}

/// Reads and validates the header (348 bytes for NIfTI-1, 540 for NIfTI-2).
pub fn read_header(path: &Path, r: &mut dyn Read) -> Result<NiftiHeader> {
    let mut b = vec![0u8; 540];
    read_exact_or(path, r, &mut b[..4], "header")?;
    let le = i32::from_le_bytes(b[..4].try_into().unwrap());
    let be = i32::from_be_bytes(b[..4].try_into().unwrap());
    let (version, big_endian, size) = match (le, be) {
        (348, _) => (1u8, false, 348),
        (_, 348) => (1, true, 348),
        (540, _) => (2, false, 540),
        (_, 540) => (2, true, 540),
        _ => return Err(FormatError::invalid(path, "not a NIfTI file (sizeof_hdr is neither 348 nor 540)")),
    };
    read_exact_or(path, r, &mut b[4..size], "header")?;
    let f = Fields { b: &b, be: big_endian };
    let h = if version == 1 {
        let magic = &b[344..348];
        let single_file = match magic {
            b"n+1\0" => true,
            b"ni1\0" => false,
            _ => return Err(FormatError::invalid(path, "NIfTI-1 magic is neither \"n+1\" nor \"ni1\" (an Analyze 7.5 file?)")),
        };
        let mut dim = [0i64; 8];
        let mut pixdim = [0f64; 8];
        for i in 0..8 {
            dim[i] = f.i16(40 + 2 * i) as i64;
            pixdim[i] = f.f32(76 + 4 * i);
        }
        let mut srow = [[0f64; 4]; 3];
        for (r, row) in srow.iter_mut().enumerate() {
            for (c, v) in row.iter_mut().enumerate() {
                *v = f.f32(280 + 16 * r + 4 * c);
            }
        }
        NiftiHeader {
            version,
            big_endian,
            single_file,
            dim,
            datatype: f.i16(70),
            bitpix: f.i16(72),
            pixdim,
            vox_offset: f.f32(108),
            scl_slope: f.f32(112),
            scl_inter: f.f32(116),
            xyzt_units: b[123],
            qform_code: f.i16(252) as i32,
            sform_code: f.i16(254) as i32,
            quatern: [f.f32(256), f.f32(260), f.f32(264)],
            qoffset: [f.f32(268), f.f32(272), f.f32(276)],
            srow,
            descrip: f.text(148, 80),
            intent_code: f.i16(68) as i32,
        }
    } else {
        let magic = &b[4..12];
        let single_file = match &magic[..4] {
            b"n+2\0" => true,
            b"ni2\0" => false,
            _ => return Err(FormatError::invalid(path, "NIfTI-2 magic is neither \"n+2\" nor \"ni2\"")),
        };
        let mut dim = [0i64; 8];
        let mut pixdim = [0f64; 8];
        for i in 0..8 {
            dim[i] = f.i64(16 + 8 * i);
            pixdim[i] = f.f64(104 + 8 * i);
        }
        let mut srow = [[0f64; 4]; 3];
        for (r, row) in srow.iter_mut().enumerate() {
            for (c, v) in row.iter_mut().enumerate() {
                *v = f.f64(400 + 32 * r + 8 * c);
            }
        }
        NiftiHeader {
            version,
            big_endian,
            single_file,
            dim,
            datatype: f.i16(12),
            bitpix: f.i16(14),
            pixdim,
            vox_offset: f.i64(168) as f64,
            scl_slope: f.f64(176),
            scl_inter: f.f64(184),
            xyzt_units: f.i32(500) as u8,
            qform_code: f.i32(344),
            sform_code: f.i32(348),
            quatern: [f.f64(352), f.f64(360), f.f64(368)],
            qoffset: [f.f64(376), f.f64(384), f.f64(392)],
            srow,
            descrip: f.text(240, 80),
            intent_code: f.i32(504),
        }
    };
    Ok(h)
}

fn read_exact_or(path: &Path, r: &mut dyn Read, buf: &mut [u8], what: &str) -> Result<()> {
    r.read_exact(buf).map_err(|e| {
        if e.kind() == std::io::ErrorKind::UnexpectedEof {
            FormatError::invalid(path, format!("file is truncated in the {what}"))
        } else {
            FormatError::io(path, e)
        }
    })
}

pub fn scalar_type_of(path: &Path, datatype: i16) -> Result<ScalarType> {
    Ok(match datatype {
        2 => ScalarType::U8,
        4 => ScalarType::I16,
        8 => ScalarType::I32,
        16 => ScalarType::F32,
        64 => ScalarType::F64,
        256 => ScalarType::I8,
        512 => ScalarType::U16,
        768 => ScalarType::U32,
        other => {
            let name = match other {
                1 => "binary",
                32 => "complex64",
                128 => "rgb24",
                1024 => "int64",
                1280 => "uint64",
                1536 => "float128",
                1792 => "complex128",
                2048 => "complex256",
                2304 => "rgba32",
                _ => "unknown",
            };
            return Err(FormatError::unsupported(path, format!("unsupported NIfTI datatype {other} ({name})")));
        }
    })
}

fn datatype_code(t: ScalarType) -> i16 {
    match t {
        ScalarType::U8 => 2,
        ScalarType::I16 => 4,
        ScalarType::I32 => 8,
        ScalarType::F32 => 16,
        ScalarType::F64 => 64,
        ScalarType::I8 => 256,
        ScalarType::U16 => 512,
        ScalarType::U32 => 768,
    }
}

/// Millimetres per unit of the header's spatial unit (xyzt_units bits 0-2).
fn spatial_unit_to_mm(units: u8) -> (f64, Option<&'static str>) {
    match units & 0x07 {
        1 => (1000.0, Some("m")),
        3 => (0.001, Some("µm")),
        _ => (1.0, None), // 2 = mm; 0 = unknown, taken as mm as every reader does
    }
}

/// The qform affine from the quaternion, pixdim and qoffset (NIfTI-1 "method 2").
pub fn qform_affine(h: &NiftiHeader) -> Affine {
    let [b, c, d] = h.quatern;
    // a is derived; rounding can make 1 - b²-c²-d² slightly negative: then the rotation is
    // 180° about (b,c,d) and a = 0, as the NIfTI reference code does.
    let a2 = 1.0 - (b * b + c * c + d * d);
    let (a, b, c, d) = if a2 < 1e-7 {
        let n = (b * b + c * c + d * d).sqrt();
        (0.0, b / n, c / n, d / n)
    } else {
        (a2.sqrt(), b, c, d)
    };
    let r = [
        [a * a + b * b - c * c - d * d, 2.0 * (b * c - a * d), 2.0 * (b * d + a * c)],
        [2.0 * (b * c + a * d), a * a + c * c - b * b - d * d, 2.0 * (c * d - a * b)],
        [2.0 * (b * d - a * c), 2.0 * (c * d + a * b), a * a + d * d - c * c - b * b],
    ];
    let qfac = if h.pixdim[0] < 0.0 { -1.0 } else { 1.0 };
    let dx = if h.pixdim[1] > 0.0 { h.pixdim[1] } else { 1.0 };
    let dy = if h.pixdim[2] > 0.0 { h.pixdim[2] } else { 1.0 };
    let dz = if h.pixdim[3] > 0.0 { h.pixdim[3] } else { 1.0 } * qfac;
    let s = [dx, dy, dz];
    let mut m = [[0.0; 4]; 4];
    for i in 0..3 {
        for j in 0..3 {
            m[i][j] = r[i][j] * s[j];
        }
        m[i][3] = h.qoffset[i];
    }
    m[3][3] = 1.0;
    m
}

/// The affine the NIfTI rules choose: sform when sform_code > 0, else qform when
/// qform_code > 0, else the spec's "method 1" (pixdim scaling, no rotation, origin 0).
/// Returns the affine and which one was used.
pub fn best_affine(h: &NiftiHeader) -> (Affine, &'static str) {
    if h.sform_code > 0 {
        let mut m = [[0.0; 4]; 4];
        m[..3].copy_from_slice(&h.srow);
        m[3][3] = 1.0;
        (m, "sform")
    } else if h.qform_code > 0 {
        (qform_affine(h), "qform")
    } else {
        let mut m = [[0.0; 4]; 4];
        for i in 0..3 {
            m[i][i] = if h.pixdim[i + 1] > 0.0 { h.pixdim[i + 1] } else { 1.0 };
        }
        m[3][3] = 1.0;
        (m, "pixdim (no qform/sform)")
    }
}

/// Reads the header only: cheap, for `info` on big files.
pub fn read_nifti_header(path: &Path) -> Result<NiftiHeader> {
    let (mut r, _) = open_maybe_gz(path)?;
    read_header(path, &mut *r)
}

/// A NIfTI file opened and checked, its stream positioned at the first voxel of volume 0.
struct OpenedNifti {
    h: NiftiHeader,
    ty: ScalarType,
    dims: [usize; 3],
    /// dim[4..=dim[0]]: the extents beyond the three spatial ones (time, then others).
    extra_dims: Vec<usize>,
    volume_count: u64,
    vol_bytes: usize,
    data_path: PathBuf,
    data: Box<dyn Read>,
    /// The voxel data's stream is inflated (its CRC is checked at the end).
    data_gzipped: bool,
    affine: Affine,
    spacing: [f64; 3],
    rescale: Rescale,
    notes: Vec<String>,
}

fn open_nifti(path: &Path, limits: &Limits) -> Result<OpenedNifti> {
    let (mut r, header_gzipped) = open_maybe_gz(path)?;
    let h = read_header(path, &mut *r)?;
    let ty = scalar_type_of(path, h.datatype)?;
    if h.bitpix as usize != ty.size() * 8 {
        return Err(FormatError::invalid(path, format!("bitpix {} does not match datatype {} ({})", h.bitpix, h.datatype, ty.name())));
    }
    let ndim = h.dim[0];
    if !(1..=7).contains(&ndim) {
        return Err(FormatError::invalid(path, format!("dim[0] = {ndim} is outside 1..7")));
    }
    let mut dims = [1usize; 3];
    for i in 0..3 {
        if (i as i64) < ndim {
            let d = h.dim[i + 1];
            if d < 1 {
                return Err(FormatError::invalid(path, format!("dim[{}] = {d} is not positive", i + 1)));
            }
            dims[i] = d as usize;
        }
    }
    let mut volume_count: u64 = 1;
    let mut extra_dims = Vec::new();
    for i in 4..=ndim as usize {
        let d = h.dim[i];
        if d < 1 {
            return Err(FormatError::invalid(path, format!("dim[{i}] = {d} is not positive")));
        }
        volume_count = volume_count.checked_mul(d as u64).ok_or_else(|| FormatError::invalid(path, "volume count overflows"))?;
        extra_dims.push(d as usize);
    }
    let (unit_mm, unit_name) = spatial_unit_to_mm(h.xyzt_units);
    for i in 1..=3 {
        let p = h.pixdim[i];
        if !p.is_finite() {
            return Err(FormatError::invalid(path, format!("pixdim[{i}] = {p} is not finite")));
        }
    }
    let vol_bytes = limits.check(path, "volume", &[dims[0] as u64, dims[1] as u64, dims[2] as u64, ty.size() as u64])?;

    // Skip to the data: in a single file it starts at vox_offset; in a pair, at 0 of .img.
    let data_path = if h.single_file { path.to_path_buf() } else { image_path_for_header(path)? };
    let (data, data_gzipped): (Box<dyn Read>, bool) = if h.single_file {
        let header_size = if h.version == 1 { 348 } else { 540 };
        let off = h.vox_offset;
        if !(off.is_finite() && off >= header_size as f64) {
            return Err(FormatError::invalid(path, format!("vox_offset {off} lies inside the header")));
        }
        let skip = off as u64 - header_size as u64;
        std::io::copy(&mut (&mut r).take(skip), &mut std::io::sink()).map_err(|e| FormatError::io(path, e))?;
        (r, header_gzipped)
    } else {
        let (mut ir, gz) = open_maybe_gz(&data_path)?;
        let off = if h.vox_offset.is_finite() && h.vox_offset > 0.0 { h.vox_offset as u64 } else { 0 };
        std::io::copy(&mut (&mut ir).take(off), &mut std::io::sink()).map_err(|e| FormatError::io(&data_path, e))?;
        (ir, gz)
    };

    let (mut affine, which) = best_affine(&h);
    if which != "sform" {
        // The qform and the no-transform rule scale by pixdim: a voxel size of 0 or below is
        // a broken header (nibabel refuses negative ones too), not something to guess around.
        for i in 1..=3 {
            let p = h.pixdim[i];
            if p <= 0.0 {
                return Err(FormatError::invalid(path, format!("pixdim[{i}] = {p} is not a positive voxel size (the {which} needs it)")));
            }
        }
    }
    if unit_mm != 1.0 {
        for row in affine.iter_mut().take(3) {
            for v in row.iter_mut() {
                *v *= unit_mm;
            }
        }
    }
    for row in &affine[..3] {
        if row.iter().any(|v| !v.is_finite()) {
            return Err(FormatError::invalid(path, format!("the {which} affine is not finite")));
        }
    }
    let spacing = spacing_of(&affine);
    if spacing.contains(&0.0) {
        return Err(FormatError::invalid(path, format!("the {which} affine is singular (a zero voxel spacing)")));
    }
    if spacing.iter().any(|s| !s.is_finite()) {
        return Err(FormatError::invalid(path, format!("the {which} affine's voxel spacing {spacing:?} overflows")));
    }
    // scl_slope 0 (or not finite) means "no scaling" by the standard.
    let rescale = if h.scl_slope != 0.0 && h.scl_slope.is_finite() {
        Rescale { slope: h.scl_slope, intercept: if h.scl_inter.is_finite() { h.scl_inter } else { 0.0 } }
    } else {
        Rescale::IDENTITY
    };
    let mut notes = vec![format!(
        "NIfTI-{} {}, {}, affine from {which}",
        h.version,
        if h.single_file { "single file" } else { "header/image pair" },
        if h.big_endian { "big-endian" } else { "little-endian" }
    )];
    if let Some(u) = unit_name {
        notes.push(format!("spatial unit {u} converted to mm"));
    }
    Ok(OpenedNifti { h, ty, dims, extra_dims, volume_count, vol_bytes, data_path, data, data_gzipped, affine, spacing, rescale, notes })
}

impl OpenedNifti {
    /// Skips `n` whole volumes.
    fn skip_volumes(&mut self, path: &Path, n: u64) -> Result<()> {
        let skip = n * self.vol_bytes as u64;
        if skip > 0 {
            let got = std::io::copy(&mut (&mut self.data).take(skip), &mut std::io::sink()).map_err(|e| FormatError::io(path, e))?;
            if got < skip {
                return Err(FormatError::invalid(path, "file is truncated before the requested volume"));
            }
        }
        Ok(())
    }

    /// Reads the next volume's voxels, in the host's byte order.
    fn read_volume(&mut self, path: &Path) -> Result<VoxelData> {
        // Read straight into the typed buffer: no second copy of a large volume.
        let mut data = VoxelData::zeroed(self.ty, self.dims[0] * self.dims[1] * self.dims[2]);
        let bytes = data.as_bytes_mut();
        let mut got = 0;
        while got < self.vol_bytes {
            match self.data.read(&mut bytes[got..]) {
                Ok(0) => {
                    return Err(FormatError::invalid(
                        path,
                        format!("file is truncated: voxel data holds {got} of {} bytes", self.vol_bytes),
                    ))
                }
                Ok(n) => got += n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(FormatError::invalid(path, format!("cannot read voxel data: {e}"))),
            }
        }
        data.fix_byte_order(self.h.big_endian);
        Ok(data)
    }

    /// gzip checks its CRC only at the end of the stream: after the last volume, read on to
    /// the end (little is left there), so a corrupt .nii.gz is refused rather than shown.
    fn check_gzip_tail(&mut self) -> Result<()> {
        if self.data_gzipped {
            std::io::copy(&mut (&mut self.data).take(64 << 20), &mut std::io::sink())
                .map_err(|e| FormatError::invalid(&self.data_path, format!("gzip stream is corrupt: {e}")))?;
        }
        Ok(())
    }

    fn volume(&self, data: VoxelData, index: usize) -> Volume {
        let h = &self.h;
        let mut attributes = vec![
            ("format".to_string(), format!("NIfTI-{} {}", h.version, if h.single_file { "single file" } else { "header/image pair" })),
            ("data type".to_string(), format!("{} ({}-endian)", self.ty.name(), if h.big_endian { "big" } else { "little" })),
            ("sform_code".to_string(), xform_code_name(h.sform_code)),
            ("qform_code".to_string(), xform_code_name(h.qform_code)),
        ];
        if h.scl_slope != 0.0 && h.scl_slope.is_finite() {
            // As stored: f32 (shortest f32 text, not the f64 widening's digits).
            attributes.push(("scl_slope".into(), format!("{}", h.scl_slope as f32)));
            attributes.push(("scl_inter".into(), format!("{}", h.scl_inter as f32)));
        }
        if !self.extra_dims.is_empty() {
            attributes.push(("dim[4..]".into(), format!("{:?}, pixdim[4] {}", self.extra_dims, h.pixdim[4])));
        }
        if h.intent_code != 0 {
            attributes.push(("intent_code".into(), h.intent_code.to_string()));
        }
        if !h.descrip.is_empty() {
            attributes.push(("descrip".into(), h.descrip.clone()));
        }
        let mut notes = self.notes.clone();
        if self.volume_count > 1 {
            notes.push(format!("4-D file: volume {index} of {}", self.volume_count));
        }
        Volume {
            dims: self.dims,
            spacing: self.spacing,
            affine: self.affine,
            data,
            rescale: self.rescale,
            modality: None,
            units: None,
            suv_bw: None,
            volume_count: self.volume_count as usize,
            volume_index: index,
            notes,
            attributes,
        }
    }
}

/// sform_code / qform_code as NIfTI names them.
fn xform_code_name(code: i32) -> String {
    let name = match code {
        0 => "unknown",
        1 => "scanner",
        2 => "aligned",
        3 => "talairach",
        4 => "mni_152",
        5 => "template",
        _ => "non-standard",
    };
    format!("{code} ({name})")
}

pub fn read_nifti(path: &Path, opts: &NiftiOptions, limits: &Limits) -> Result<Volume> {
    let mut f = open_nifti(path, limits)?;
    if opts.volume_index as u64 >= f.volume_count {
        return Err(FormatError::invalid(
            path,
            format!("volume index {} requested but the file holds {} volume(s)", opts.volume_index, f.volume_count),
        ));
    }
    f.skip_volumes(path, opts.volume_index as u64)?;
    let data = f.read_volume(path)?;
    if opts.volume_index as u64 + 1 == f.volume_count {
        f.check_gzip_tail()?;
    }
    Ok(f.volume(data, opts.volume_index))
}

/// Every volume of a 4-D (or higher) file, with what is needed to write them back as one.
#[derive(Debug)]
pub struct NiftiVolumes {
    pub volumes: Vec<Volume>,
    /// dim[4..]: the extents beyond the spatial ones (their product is `volumes.len()`).
    pub extra_dims: Vec<usize>,
    /// pixdim[4]: the time between volumes, in `time_unit`.
    pub time_step: f64,
    /// xyzt_units' time bits (8 s, 16 ms, 24 µs, …), kept as the file has them.
    pub time_unit: u8,
}

/// Reads all volumes of a file in one pass (the whole 4-D data set is checked against the
/// memory limit first).
pub fn read_nifti_volumes(path: &Path, limits: &Limits) -> Result<NiftiVolumes> {
    let mut f = open_nifti(path, limits)?;
    limits.check(path, "4-D data set", &[f.vol_bytes as u64, f.volume_count])?;
    let mut volumes = Vec::with_capacity(f.volume_count as usize);
    for k in 0..f.volume_count as usize {
        let data = f.read_volume(path)?;
        volumes.push(f.volume(data, k));
    }
    f.check_gzip_tail()?;
    let time_step = if f.h.pixdim[4].is_finite() { f.h.pixdim[4] } else { 0.0 };
    Ok(NiftiVolumes { volumes, extra_dims: f.extra_dims, time_step, time_unit: f.h.xyzt_units & 0x38 })
}

/// Rotation (unit quaternion b, c, d), voxel sizes and qfac from an affine whose 3x3 part is
/// a rotation times a positive diagonal scale (times a z flip). None when it has shear.
fn affine_to_quatern(m: &Affine) -> Option<([f64; 3], [f64; 3], f64)> {
    let s = spacing_of(m);
    if s.contains(&0.0) {
        return None;
    }
    let mut r = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            r[i][j] = m[i][j] / s[j];
        }
    }
    let det = r[0][0] * (r[1][1] * r[2][2] - r[1][2] * r[2][1]) - r[0][1] * (r[1][0] * r[2][2] - r[1][2] * r[2][0])
        + r[0][2] * (r[1][0] * r[2][1] - r[1][1] * r[2][0]);
    let qfac = if det < 0.0 { -1.0 } else { 1.0 };
    if qfac < 0.0 {
        for row in r.iter_mut() {
            row[2] = -row[2];
        }
    }
    // Must be orthonormal to be representable as a quaternion.
    for i in 0..3 {
        for j in 0..3 {
            let dot: f64 = (0..3).map(|k| r[k][i] * r[k][j]).sum();
            let want = if i == j { 1.0 } else { 0.0 };
            if (dot - want).abs() > 1e-4 {
                return None;
            }
        }
    }
    let trace = r[0][0] + r[1][1] + r[2][2];
    let (a, b, c, d);
    if trace > 0.0 {
        let t = (trace + 1.0).sqrt() * 2.0;
        a = 0.25 * t;
        b = (r[2][1] - r[1][2]) / t;
        c = (r[0][2] - r[2][0]) / t;
        d = (r[1][0] - r[0][1]) / t;
    } else if r[0][0] > r[1][1] && r[0][0] > r[2][2] {
        let t = (1.0 + r[0][0] - r[1][1] - r[2][2]).sqrt() * 2.0;
        a = (r[2][1] - r[1][2]) / t;
        b = 0.25 * t;
        c = (r[0][1] + r[1][0]) / t;
        d = (r[0][2] + r[2][0]) / t;
    } else if r[1][1] > r[2][2] {
        let t = (1.0 + r[1][1] - r[0][0] - r[2][2]).sqrt() * 2.0;
        a = (r[0][2] - r[2][0]) / t;
        b = (r[0][1] + r[1][0]) / t;
        c = 0.25 * t;
        d = (r[1][2] + r[2][1]) / t;
    } else {
        let t = (1.0 + r[2][2] - r[0][0] - r[1][1]).sqrt() * 2.0;
        a = (r[1][0] - r[0][1]) / t;
        b = (r[0][2] + r[2][0]) / t;
        c = (r[1][2] + r[2][1]) / t;
        d = 0.25 * t;
    }
    // NIfTI stores b, c, d with a >= 0.
    let sign = if a < 0.0 { -1.0 } else { 1.0 };
    Some(([b * sign, c * sign, d * sign], s, qfac))
}

/// Writes a NIfTI-1 single file (`.nii`, or `.nii.gz` when the name ends in `.gz`): the stored
/// type and rescale kept, sform = the affine (code 1, "scanner"), and the same geometry as a
/// qform when the affine has no shear. Written atomically.
pub fn write_nifti(path: &Path, vol: &Volume) -> Result<()> {
    write_nifti_volumes(path, std::slice::from_ref(vol), &[], 0.0, 8)
}

/// As [`write_nifti`], for several volumes of one grid: a 4-D file (or of the dimensions
/// `extra_dims` gives, whose product must be the number of volumes) with pixdim[4] =
/// `time_step` in the xyzt time unit `time_unit`.
pub fn write_nifti_volumes(path: &Path, vols: &[Volume], extra_dims: &[usize], time_step: f64, time_unit: u8) -> Result<()> {
    let vol = &vols[0];
    if vols.iter().any(|v| v.dims != vol.dims || v.data.scalar_type() != vol.data.scalar_type() || v.rescale != vol.rescale) {
        return Err(FormatError::unsupported(path, "volumes of different sizes, types or scalings cannot share one NIfTI file"));
    }
    let extra: Vec<usize> = if extra_dims.is_empty() && vols.len() > 1 { vec![vols.len()] } else { extra_dims.to_vec() };
    if extra.iter().product::<usize>() != vols.len() || extra.len() > 4 {
        return Err(FormatError::invalid(path, format!("dimensions {extra:?} do not hold {} volumes", vols.len())));
    }
    let mut h = vec![0u8; 352];
    let put_i16 = |h: &mut Vec<u8>, o: usize, v: i16| h[o..o + 2].copy_from_slice(&v.to_le_bytes());
    let put_f32 = |h: &mut Vec<u8>, o: usize, v: f64| h[o..o + 4].copy_from_slice(&(v as f32).to_le_bytes());
    h[0..4].copy_from_slice(&348i32.to_le_bytes());
    h[38] = b'r';
    let ty = vol.data.scalar_type();
    put_i16(&mut h, 40, 3 + extra.len() as i16);
    for i in 0..3 {
        put_i16(
            &mut h,
            42 + 2 * i,
            i16::try_from(vol.dims[i])
                .map_err(|_| FormatError::unsupported(path, format!("dimension {} is too large for NIfTI-1", vol.dims[i])))?,
        );
    }
    for i in 3..7 {
        let d = extra.get(i - 3).copied().unwrap_or(1);
        put_i16(
            &mut h,
            42 + 2 * i,
            i16::try_from(d).map_err(|_| FormatError::unsupported(path, format!("dimension {d} is too large for NIfTI-1")))?,
        );
    }
    put_i16(&mut h, 70, datatype_code(ty));
    put_i16(&mut h, 72, (ty.size() * 8) as i16);
    let q = affine_to_quatern(&vol.affine);
    let qfac = q.map(|q| q.2).unwrap_or(1.0);
    put_f32(&mut h, 76, qfac);
    for i in 0..3 {
        put_f32(&mut h, 80 + 4 * i, vol.spacing[i]);
    }
    if vols.len() > 1 {
        put_f32(&mut h, 92, time_step);
    }
    put_f32(&mut h, 108, 352.0);
    if vol.rescale.is_identity() {
        put_f32(&mut h, 112, 0.0);
    } else {
        put_f32(&mut h, 112, vol.rescale.slope);
        put_f32(&mut h, 116, vol.rescale.intercept);
    }
    h[123] = 2 | (time_unit & 0x38); // mm, and the time unit
    let descrip = b"volterra";
    h[148..148 + descrip.len()].copy_from_slice(descrip);
    if let Some((quat, _, _)) = q {
        put_i16(&mut h, 252, 1);
        for i in 0..3 {
            put_f32(&mut h, 256 + 4 * i, quat[i]);
            put_f32(&mut h, 268 + 4 * i, vol.affine[i][3]);
        }
    }
    put_i16(&mut h, 254, 1);
    for r in 0..3 {
        for c in 0..4 {
            put_f32(&mut h, 280 + 16 * r + 4 * c, vol.affine[r][c]);
        }
    }
    h[344..348].copy_from_slice(b"n+1\0");
    // bytes 348..352: the empty extension flag.
    write_atomically(path, |w| {
        let mk = |e| FormatError::io(path, e);
        if is_gz(path) {
            let mut gz = flate2::write::GzEncoder::new(w, flate2::Compression::new(6));
            gz.write_all(&h).map_err(mk)?;
            for v in vols {
                v.data.write_le(&mut gz).map_err(mk)?;
            }
            gz.finish().map_err(mk)?;
        } else {
            w.write_all(&h).map_err(mk)?;
            for v in vols {
                v.data.write_le(w).map_err(mk)?;
            }
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quaternion_round_trip_of_oblique_affine() {
        let (c, s) = (0.3f64.cos(), 0.3f64.sin());
        let m: Affine = [[c * 0.9, -s * 1.1, 0.0, 10.0], [s * 0.9, c * 1.1, 0.0, -5.0], [0.0, 0.0, -2.5, 3.0], [0.0, 0.0, 0.0, 1.0]];
        let (quat, sp, qfac) = affine_to_quatern(&m).unwrap();
        let h = NiftiHeader {
            version: 1,
            big_endian: false,
            single_file: true,
            dim: [3, 1, 1, 1, 1, 1, 1, 1],
            datatype: 2,
            bitpix: 8,
            pixdim: [qfac, sp[0], sp[1], sp[2], 0.0, 0.0, 0.0, 0.0],
            vox_offset: 352.0,
            scl_slope: 0.0,
            scl_inter: 0.0,
            xyzt_units: 2,
            qform_code: 1,
            sform_code: 0,
            quatern: quat,
            qoffset: [10.0, -5.0, 3.0],
            srow: [[0.0; 4]; 3],
            descrip: String::new(),
            intent_code: 0,
        };
        let back = qform_affine(&h);
        for i in 0..3 {
            for j in 0..4 {
                assert!((back[i][j] - m[i][j]).abs() < 1e-12, "{i},{j}: {} vs {}", back[i][j], m[i][j]);
            }
        }
    }

    #[test]
    fn sheared_affine_has_no_quaternion() {
        let m: Affine = [[1.0, 0.5, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]];
        assert!(affine_to_quatern(&m).is_none());
    }
}
