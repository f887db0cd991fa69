//! `Volume`: a 3-D scalar field on a regular grid with its geometry in world space.
//!
//! World space is RAS+ millimetres, as NIfTI and 3D Slicer use it: +x points to the
//! patient's Right, +y Anterior, +z Superior. DICOM's LPS (+x Left, +y Posterior) is
//! converted by negating x and y.

use serde::Serialize;

/// The scalar type the file stores. Kept as is: nothing is widened on load.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ScalarType {
    U8,
    I8,
    U16,
    I16,
    U32,
    I32,
    F32,
    F64,
}

impl ScalarType {
    pub fn size(self) -> usize {
        match self {
            ScalarType::U8 | ScalarType::I8 => 1,
            ScalarType::U16 | ScalarType::I16 => 2,
            ScalarType::U32 | ScalarType::I32 | ScalarType::F32 => 4,
            ScalarType::F64 => 8,
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            ScalarType::U8 => "u8",
            ScalarType::I8 => "i8",
            ScalarType::U16 => "u16",
            ScalarType::I16 => "i16",
            ScalarType::U32 => "u32",
            ScalarType::I32 => "i32",
            ScalarType::F32 => "f32",
            ScalarType::F64 => "f64",
        }
    }
}

/// Voxel values in their stored type, x fastest, then y, then z.
#[derive(Debug, Clone, PartialEq)]
pub enum VoxelData {
    U8(Vec<u8>),
    I8(Vec<i8>),
    U16(Vec<u16>),
    I16(Vec<i16>),
    U32(Vec<u32>),
    I32(Vec<i32>),
    F32(Vec<f32>),
    F64(Vec<f64>),
}

macro_rules! each_variant {
    ($self:expr, $v:ident => $body:expr) => {
        match $self {
            VoxelData::U8($v) => $body,
            VoxelData::I8($v) => $body,
            VoxelData::U16($v) => $body,
            VoxelData::I16($v) => $body,
            VoxelData::U32($v) => $body,
            VoxelData::I32($v) => $body,
            VoxelData::F32($v) => $body,
            VoxelData::F64($v) => $body,
        }
    };
}

// The f64 variant makes `as f64` a same-type cast inside the shared macro.
#[allow(clippy::unnecessary_cast)]
impl VoxelData {
    pub fn scalar_type(&self) -> ScalarType {
        match self {
            VoxelData::U8(_) => ScalarType::U8,
            VoxelData::I8(_) => ScalarType::I8,
            VoxelData::U16(_) => ScalarType::U16,
            VoxelData::I16(_) => ScalarType::I16,
            VoxelData::U32(_) => ScalarType::U32,
            VoxelData::I32(_) => ScalarType::I32,
            VoxelData::F32(_) => ScalarType::F32,
            VoxelData::F64(_) => ScalarType::F64,
        }
    }
    pub fn len(&self) -> usize {
        each_variant!(self, v => v.len())
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// The stored value at linear index `i`, widened to f64 (exact for every stored type).
    #[inline]
    pub fn stored(&self, i: usize) -> f64 {
        each_variant!(self, v => v[i] as f64)
    }
    /// Decodes `bytes` (little- or big-endian) into typed data of `ty`.
    /// `bytes.len()` must be a multiple of the type size.
    pub fn from_bytes(ty: ScalarType, bytes: &[u8], big_endian: bool) -> VoxelData {
        macro_rules! conv {
            ($t:ty, $n:expr) => {{
                bytes
                    .chunks_exact($n)
                    .map(|c| {
                        let a: [u8; $n] = c.try_into().unwrap();
                        if big_endian {
                            <$t>::from_be_bytes(a)
                        } else {
                            <$t>::from_le_bytes(a)
                        }
                    })
                    .collect()
            }};
        }
        match ty {
            ScalarType::U8 => VoxelData::U8(bytes.to_vec()),
            ScalarType::I8 => VoxelData::I8(bytes.iter().map(|&b| b as i8).collect()),
            ScalarType::U16 => VoxelData::U16(conv!(u16, 2)),
            ScalarType::I16 => VoxelData::I16(conv!(i16, 2)),
            ScalarType::U32 => VoxelData::U32(conv!(u32, 4)),
            ScalarType::I32 => VoxelData::I32(conv!(i32, 4)),
            ScalarType::F32 => VoxelData::F32(conv!(f32, 4)),
            ScalarType::F64 => VoxelData::F64(conv!(f64, 8)),
        }
    }
    /// A zeroed buffer of `n` values of type `ty`.
    pub fn zeroed(ty: ScalarType, n: usize) -> VoxelData {
        match ty {
            ScalarType::U8 => VoxelData::U8(vec![0; n]),
            ScalarType::I8 => VoxelData::I8(vec![0; n]),
            ScalarType::U16 => VoxelData::U16(vec![0; n]),
            ScalarType::I16 => VoxelData::I16(vec![0; n]),
            ScalarType::U32 => VoxelData::U32(vec![0; n]),
            ScalarType::I32 => VoxelData::I32(vec![0; n]),
            ScalarType::F32 => VoxelData::F32(vec![0.0; n]),
            ScalarType::F64 => VoxelData::F64(vec![0.0; n]),
        }
    }
    /// The values' memory as bytes (native byte order), for reading files straight into it.
    pub fn as_bytes_mut(&mut self) -> &mut [u8] {
        each_variant!(self, v => bytemuck::cast_slice_mut(v.as_mut_slice()))
    }
    /// Converts values read in the file's byte order to native order, in place.
    pub fn fix_byte_order(&mut self, file_big_endian: bool) {
        if file_big_endian == cfg!(target_endian = "big") {
            return;
        }
        macro_rules! swap {
            ($v:expr) => {
                $v.iter_mut().for_each(|x| *x = x.swap_bytes())
            };
        }
        match self {
            VoxelData::U8(_) | VoxelData::I8(_) => {}
            VoxelData::U16(v) => swap!(v),
            VoxelData::I16(v) => swap!(v),
            VoxelData::U32(v) => swap!(v),
            VoxelData::I32(v) => swap!(v),
            VoxelData::F32(v) => v.iter_mut().for_each(|x| *x = f32::from_bits(x.to_bits().swap_bytes())),
            VoxelData::F64(v) => v.iter_mut().for_each(|x| *x = f64::from_bits(x.to_bits().swap_bytes())),
        }
    }
    /// Little-endian bytes of the stored values.
    pub fn to_le_bytes(&self) -> Vec<u8> {
        each_variant!(self, v => v.iter().flat_map(|x| x.to_le_bytes()).collect())
    }
    /// Writes the values as little-endian bytes without a copy of the whole volume (a
    /// 300 MB CT written to NIfTI held twice its size when it was converted first).
    pub fn write_le(&self, w: &mut impl std::io::Write) -> std::io::Result<()> {
        // Values per piece: 1 Mi, a few MB at most.
        const PIECE: usize = 1 << 20;
        each_variant!(self, v => {
            for piece in v.chunks(PIECE) {
                if cfg!(target_endian = "little") {
                    w.write_all(bytemuck::cast_slice(piece))?;
                } else {
                    let bytes: Vec<u8> = piece.iter().flat_map(|x| x.to_le_bytes()).collect();
                    w.write_all(&bytes)?;
                }
            }
            Ok(())
        })
    }
    /// (min, max) of the stored values, ignoring NaN; None when empty or all NaN.
    pub fn stored_range(&self) -> Option<(f64, f64)> {
        let mut lo = f64::INFINITY;
        let mut hi = f64::NEG_INFINITY;
        each_variant!(self, v => for &x in v.iter() {
            let x = x as f64;
            if x < lo { lo = x; }
            if x > hi { hi = x; }
        });
        (lo <= hi).then_some((lo, hi))
    }
}

/// Real-world value = slope · stored + intercept.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Rescale {
    pub slope: f64,
    pub intercept: f64,
}

impl Rescale {
    pub const IDENTITY: Rescale = Rescale { slope: 1.0, intercept: 0.0 };
    pub fn is_identity(&self) -> bool {
        self.slope == 1.0 && self.intercept == 0.0
    }
    #[inline]
    pub fn apply(&self, stored: f64) -> f64 {
        self.slope * stored + self.intercept
    }
}

/// A 4x4 row-major affine, voxel index (i, j, k, 1) → world RAS+ mm.
pub type Affine = [[f64; 4]; 4];

pub fn identity_affine() -> Affine {
    [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
}

#[derive(Debug, Clone)]
pub struct Volume {
    /// Voxel counts along i (fastest), j, k.
    pub dims: [usize; 3],
    /// Voxel spacing in mm along i, j, k: the lengths of the affine's columns.
    pub spacing: [f64; 3],
    /// Voxel index → world RAS+ mm.
    pub affine: Affine,
    pub data: VoxelData,
    pub rescale: Rescale,
    /// DICOM modality ("CT", "MR", "PT", …) where the file says.
    pub modality: Option<String>,
    /// Units of the real-world values ("HU", "Bq/ml", …) where the file says.
    pub units: Option<String>,
    /// A PET in Bq/ml whose file gives what SUV needs (patient weight, injected dose, its
    /// half-life, injection and series times): the factor taking its real values to the
    /// body-weight standardised uptake value SUVbw (g/ml).
    pub suv_bw: Option<f64>,
    /// For 4-D inputs: how many volumes the file holds and which one this is.
    pub volume_count: usize,
    pub volume_index: usize,
    /// Human-readable notes about what the reader did (conversions, fallbacks).
    pub notes: Vec<String>,
    /// What the file says about itself, for `info`, in the order shown: data type,
    /// compression, codes, patient, study and series (name, value as people read it).
    pub attributes: Vec<(String, String)>,
}

impl Volume {
    /// A volume of `data` on the grid `affine` gives (spacing from its columns), its
    /// stored values taken as real-world values and nothing else said about it: set the
    /// other fields with struct-update syntax (`Volume { rescale, ..Volume::new(…) }`).
    pub fn new(dims: [usize; 3], affine: Affine, data: VoxelData) -> Volume {
        assert_eq!(data.len(), dims[0] * dims[1] * dims[2], "voxel data does not fill {dims:?}");
        Volume {
            dims,
            spacing: spacing_of(&affine),
            affine,
            data,
            rescale: Rescale::IDENTITY,
            modality: None,
            units: None,
            suv_bw: None,
            volume_count: 1,
            volume_index: 0,
            notes: Vec::new(),
            attributes: Vec::new(),
        }
    }

    /// As [`Volume::new`], axis-aligned with `spacing` (mm) and centred on the world origin.
    pub fn centred(dims: [usize; 3], spacing: [f64; 3], data: VoxelData) -> Volume {
        let c = |a: usize| -0.5 * (dims[a] as f64 - 1.0) * spacing[a];
        let affine = [[spacing[0], 0.0, 0.0, c(0)], [0.0, spacing[1], 0.0, c(1)], [0.0, 0.0, spacing[2], c(2)], [0.0, 0.0, 0.0, 1.0]];
        Volume::new(dims, affine, data)
    }

    pub fn voxel_count(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }
    #[inline]
    pub fn index(&self, i: usize, j: usize, k: usize) -> usize {
        i + self.dims[0] * (j + self.dims[1] * k)
    }
    /// The real-world value (rescale applied) at linear index `i`.
    #[inline]
    pub fn value(&self, i: usize) -> f64 {
        self.rescale.apply(self.data.stored(i))
    }
    /// Every voxel's real-world value in storage order: one pass per stored type (not a
    /// match per voxel), on every core — numpy's multiply converts with the CPU's widest
    /// vectors, which this build's baseline x86-64 target does not assume.
    #[allow(clippy::unnecessary_cast)]
    pub fn real_values(&self) -> Vec<f64> {
        use rayon::prelude::*;
        let r = self.rescale;
        each_variant!(&self.data, v => v.par_iter().with_min_len(1 << 16).map(|&x| r.apply(x as f64)).collect())
    }
    /// (min, max) of the real-world values.
    pub fn value_range(&self) -> Option<(f64, f64)> {
        let (a, b) = self.data.stored_range()?;
        let (a, b) = (self.rescale.apply(a), self.rescale.apply(b));
        Some((a.min(b), a.max(b)))
    }
    /// World position (RAS+ mm) of the centre of voxel (i, j, k), fractional indices allowed.
    pub fn index_to_world(&self, ijk: [f64; 3]) -> [f64; 3] {
        let a = &self.affine;
        let mut out = [0.0; 3];
        for (r, o) in out.iter_mut().enumerate() {
            *o = a[r][0] * ijk[0] + a[r][1] * ijk[1] + a[r][2] * ijk[2] + a[r][3];
        }
        out
    }
}

/// Column lengths of the affine's 3x3 part: the voxel spacing it implies.
pub fn spacing_of(affine: &Affine) -> [f64; 3] {
    let mut s = [0.0; 3];
    for (c, sc) in s.iter_mut().enumerate() {
        *sc = (0..3).map(|r| affine[r][c] * affine[r][c]).sum::<f64>().sqrt();
    }
    s
}
