//! `Heightfield`: a regular grid of elevations in metres with its georeferencing.
//!
//! Layout: `elevations[row * width + col]`, row 0 is the northern (top) edge as in every
//! raster format; columns go east. Sample (col, row) lies at map coordinates
//! `origin + (col · cell_size_native[0], −row · cell_size_native[1])` in the CRS's units.

use serde::Serialize;

#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Crs {
    /// EPSG code where the file names one.
    pub epsg: Option<u32>,
    /// true for a geographic CRS (coordinates in degrees).
    pub geographic: bool,
    /// Human-readable description ("EPSG:4326 (geographic)", "local (no georeferencing)").
    pub description: String,
    /// Metres in one unit of a projected CRS's coordinates (0.3048 for feet; 1 for metres,
    /// and for a geographic CRS, whose degrees are converted at the raster's latitude).
    pub metres_per_unit: f64,
}

impl Crs {
    pub fn local() -> Crs {
        Crs { epsg: None, geographic: false, description: "local (no georeferencing)".into(), metres_per_unit: 1.0 }
    }
}

#[derive(Debug, Clone)]
pub struct Heightfield {
    /// Samples per row (east-west).
    pub width: usize,
    /// Rows (north-south).
    pub height: usize,
    /// Distance between samples in metres, (east, north), both positive. For a geographic
    /// CRS this is converted from degrees at the raster's centre latitude.
    pub cell_size: [f64; 2],
    /// Distance between samples in the CRS's own units (degrees for a geographic CRS).
    pub cell_size_native: [f64; 2],
    /// Map coordinates (CRS units) of the centre of sample (0, 0), the north-west one.
    pub origin: [f64; 2],
    pub crs: Crs,
    /// Elevations in metres; NoData samples hold NaN and are flagged in `nodata`.
    pub elevations: Vec<f32>,
    /// Which samples are NoData. Empty when the raster has no NoData samples.
    pub nodata: NodataMask,
    /// The file's NoData value, where it declares one.
    pub nodata_value: Option<f64>,
    pub notes: Vec<String>,
    /// What the file says about itself, for `info`, in the order shown: data type,
    /// compression, codes, patient, study and series (name, value as people read it).
    pub attributes: Vec<(String, String)>,
    /// Whether the cell size and the elevations are metres, or only sample steps and
    /// stored levels (a PNG heightmap given no cell size or vertical scale).
    pub units: GridUnits,
}

/// Whether a raster's numbers carry units. A GeoTIFF's do (its CRS and metres); a PNG
/// heightmap holds grey levels a sample apart, and has metres only where the scene or the
/// command line gives a vertical scale and a cell size — until then `info` and the scalar
/// bar say "grey level" and "sample", not "m".
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GridUnits {
    /// The cell size is in metres (else one sample step, unitless).
    pub cell_size_in_metres: bool,
    /// The elevations are in metres (else stored levels, unitless).
    pub elevation_in_metres: bool,
}

impl GridUnits {
    pub const METRES: GridUnits = GridUnits { cell_size_in_metres: true, elevation_in_metres: true };
    /// The unit of the cell size, as printed: "m" or "sample".
    pub fn cell_size_unit(&self) -> &'static str {
        if self.cell_size_in_metres {
            "m"
        } else {
            "sample"
        }
    }
    /// The unit of the elevations, as printed: "m" or "grey level".
    pub fn elevation_unit(&self) -> &'static str {
        if self.elevation_in_metres {
            "m"
        } else {
            "grey level"
        }
    }
}

impl Heightfield {
    pub fn nodata_count(&self) -> usize {
        self.nodata.count()
    }
    pub fn is_nodata(&self, col: usize, row: usize) -> bool {
        self.nodata.get(row * self.width + col)
    }
    /// The elevation (metres) at a point of the heightfield's local frame — x east, y north
    /// in metres from the south-west sample's centre — bilinear between the four samples
    /// around it. None outside the samples or where one of the four is NoData.
    pub fn surface_height(&self, x: f64, y: f64) -> Option<f64> {
        bilinear_height([self.width, self.height], self.cell_size, x, y, |col, row| {
            let e = self.elevations[row * self.width + col];
            (!self.is_nodata(col, row) && e.is_finite()).then_some(e as f64)
        })
    }

    /// Where the samples lie, without them.
    pub fn georef(&self) -> GridGeoref {
        GridGeoref {
            width: self.width,
            height: self.height,
            cell_size: self.cell_size,
            cell_size_native: self.cell_size_native,
            origin: self.origin,
            crs: self.crs.clone(),
            units: self.units,
        }
    }

    /// (min, max) elevation over valid samples.
    pub fn range(&self) -> Option<(f32, f32)> {
        let mut lo = f32::INFINITY;
        let mut hi = f32::NEG_INFINITY;
        for (i, &z) in self.elevations.iter().enumerate() {
            if !self.nodata.get(i) && z.is_finite() {
                lo = lo.min(z);
                hi = hi.max(z);
            }
        }
        (lo <= hi).then_some((lo, hi))
    }
}

/// Which samples of a raster are NoData, a bit each (a byte each was a quarter of the
/// float32 elevations' memory). Empty — no bits at all — where none is.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct NodataMask {
    len: usize,
    words: Vec<u64>,
}

impl NodataMask {
    /// `len` samples, none NoData.
    pub fn new(len: usize) -> NodataMask {
        NodataMask { len, words: vec![0; len.div_ceil(64)] }
    }
    /// Samples it holds a bit for (0: an empty mask, no sample NoData).
    pub fn len(&self) -> usize {
        self.len
    }
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
    /// Whether sample `i` is NoData (false beyond the mask: an empty mask flags none).
    #[inline]
    pub fn get(&self, i: usize) -> bool {
        i < self.len && self.words[i / 64] >> (i % 64) & 1 == 1
    }
    /// Flags sample `i` (`i` < `len`) NoData or not.
    pub fn set(&mut self, i: usize, nodata: bool) {
        let bit = 1u64 << (i % 64);
        if nodata {
            self.words[i / 64] |= bit;
        } else {
            self.words[i / 64] &= !bit;
        }
    }
    /// NoData samples.
    pub fn count(&self) -> usize {
        self.words.iter().map(|w| w.count_ones() as usize).sum()
    }
    /// Every sample's flag in order.
    pub fn iter(&self) -> impl Iterator<Item = bool> + '_ {
        (0..self.len).map(|i| self.get(i))
    }
}

impl FromIterator<bool> for NodataMask {
    fn from_iter<I: IntoIterator<Item = bool>>(flags: I) -> NodataMask {
        let mut mask = NodataMask::default();
        for (i, nodata) in flags.into_iter().enumerate() {
            if i % 64 == 0 {
                mask.words.push(0);
            }
            mask.len = i + 1;
            mask.set(i, nodata);
        }
        mask
    }
}

/// Heights read a row at a time, for a heightfield that is not held in memory as a whole
/// (`GeoTiffRows`) or one that is: the GPU ray-caster reads each sample once (the samples
/// tiles share, twice), a tile at a time in bands of rows, into its textures, so a DEM near
/// the size of the host's memory is held only there (on a software adapter the textures
/// are host memory: `volterra bench terrain --large` measures a 40000² DEM so); the DEM
/// products (`volterra dem`) read the rows of a band of output rows and write it, so a
/// hillshade of a DEM larger than memory is made in the memory of a few rows.
pub trait HeightRows: Send + Sync {
    /// Samples east-west and north-south.
    fn size(&self) -> [usize; 2];
    /// Metres between samples east-west and north-south.
    fn cell_size(&self) -> [f64; 2];
    /// Elevations (metres) of `out.len()` samples of row `row` (row 0 the northernmost, as
    /// in the file) from column `col`; NaN for NoData.
    fn read_row(&self, row: usize, col: usize, out: &mut [f32]);
    /// Why rows could not be read (one line naming the source), once they have been: a
    /// reader of a file reads a chunk that fails to decode as NoData and says so here.
    fn failure(&self) -> Option<String> {
        None
    }
    /// (min, max) elevation over valid samples, reading every row once in order.
    fn elevation_range(&self) -> Option<(f32, f32)> {
        summarise(self).range
    }
}

/// What one pass over a raster's rows finds: its elevation range, mean and standard
/// deviation, and its NoData samples.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RowsSummary {
    /// (min, max) elevation in metres over valid samples; None where every one is NoData.
    pub range: Option<(f32, f32)>,
    /// Samples that are NoData (the file's NoData value, or not a finite number).
    pub nodata: usize,
    /// Mean and population standard deviation (gdalinfo -stats') of the valid samples, in
    /// metres; None where there is none.
    pub mean_std: Option<(f64, f64)>,
}

/// One pass over every row of `rows`, in order: the elevation range, mean, standard
/// deviation and the NoData count. Stops at the first row that could not be read
/// (`failure`): what it returns then covers the rows before, and the caller reports the
/// failure.
pub fn summarise<R: HeightRows + ?Sized>(rows: &R) -> RowsSummary {
    let [w, h] = rows.size();
    let mut row = vec![0f32; w];
    let (mut lo, mut hi, mut nodata) = (f32::INFINITY, f32::NEG_INFINITY, 0);
    // Count, mean and sum of squared deviations, each row's merged in (Chan et al.): no
    // cancellation where the spread is small against the mean.
    let (mut n, mut mean, mut m2) = (0f64, 0f64, 0f64);
    for r in 0..h {
        rows.read_row(r, 0, &mut row);
        if rows.failure().is_some() {
            break;
        }
        let (mut rn, mut rsum) = (0f64, 0f64);
        for &z in &row {
            if z.is_finite() {
                lo = lo.min(z);
                hi = hi.max(z);
                rn += 1.0;
                rsum += z as f64;
            } else {
                nodata += 1;
            }
        }
        if rn > 0.0 {
            let rmean = rsum / rn;
            let rm2: f64 = row.iter().filter(|z| z.is_finite()).map(|&z| (z as f64 - rmean).powi(2)).sum();
            let d = rmean - mean;
            let total = n + rn;
            mean += d * rn / total;
            m2 += rm2 + d * d * n * rn / total;
            n = total;
        }
    }
    let mean_std = (n > 0.0).then(|| (mean, (m2 / n).sqrt()));
    RowsSummary { range: (lo <= hi).then_some((lo, hi)), nodata, mean_std }
}

/// A heightfield held: its rows copied out (NoData samples hold NaN already).
impl HeightRows for Heightfield {
    fn size(&self) -> [usize; 2] {
        [self.width, self.height]
    }
    fn elevation_range(&self) -> Option<(f32, f32)> {
        self.range()
    }
    fn cell_size(&self) -> [f64; 2] {
        self.cell_size
    }
    fn read_row(&self, row: usize, col: usize, out: &mut [f32]) {
        out.fill(f32::NAN);
        if row < self.height && col < self.width {
            let n = out.len().min(self.width - col);
            let at = row * self.width + col;
            out[..n].copy_from_slice(&self.elevations[at..at + n]);
        }
    }
}

/// Where a heightfield's samples lie — their number and georeferencing, as in
/// [`Heightfield`] — for a raster whose samples are read as needed, not held.
#[derive(Debug, Clone, PartialEq)]
pub struct GridGeoref {
    pub width: usize,
    pub height: usize,
    /// Metres between samples (east, north).
    pub cell_size: [f64; 2],
    /// CRS units between samples (east, north).
    pub cell_size_native: [f64; 2],
    /// Map coordinates of the centre of the north-west sample.
    pub origin: [f64; 2],
    pub crs: Crs,
    pub units: GridUnits,
}

/// The elevation at (x, y) metres east and north of the south-west sample's centre of a
/// `size` grid with cells `cell_size`, bilinear between the four samples around it, read by
/// `sample(col, row)` (row 0 the northern one; None for NoData). None outside the samples
/// or where one of the four is NoData.
pub fn bilinear_height(
    [width, height]: [usize; 2],
    cell_size: [f64; 2],
    x: f64,
    y: f64,
    mut sample: impl FnMut(usize, usize) -> Option<f64>,
) -> Option<f64> {
    let gx = x / cell_size[0];
    let gy = y / cell_size[1];
    let (cx, cy) = (width.checked_sub(1)?, height.checked_sub(1)?);
    if !(gx >= 0.0 && gy >= 0.0 && gx <= cx as f64 && gy <= cy as f64) || cx == 0 || cy == 0 {
        return None;
    }
    let i = (gx.floor() as usize).min(cx - 1);
    let j = (gy.floor() as usize).min(cy - 1);
    let (u, v) = (gx - i as f64, gy - j as f64);
    // Row index from the north: j counts from the south.
    let mut z = |col: usize, jj: usize| sample(col, height - 1 - jj);
    let (z00, z10, z01, z11) = (z(i, j)?, z(i + 1, j)?, z(i, j + 1)?, z(i + 1, j + 1)?);
    Some((1.0 - u) * (1.0 - v) * z00 + u * (1.0 - v) * z10 + (1.0 - u) * v * z01 + u * v * z11)
}

/// Metres per degree of longitude and latitude at latitude `lat_deg` on the WGS 84
/// ellipsoid (prime-vertical and meridional radii of curvature).
pub fn metres_per_degree(lat_deg: f64) -> (f64, f64) {
    const A: f64 = 6_378_137.0;
    const F: f64 = 1.0 / 298.257_223_563;
    let e2 = F * (2.0 - F);
    let phi = lat_deg.to_radians();
    let w = 1.0 - e2 * phi.sin().powi(2);
    let n = A / w.sqrt();
    let m = A * (1.0 - e2) / w.powf(1.5);
    (n * phi.cos() * std::f64::consts::PI / 180.0, m * std::f64::consts::PI / 180.0)
}

#[cfg(test)]
mod mask_tests {
    use super::NodataMask;

    #[test]
    fn a_mask_holds_a_bit_per_sample_across_word_borders() {
        let flags: Vec<bool> = (0..200).map(|i| i % 7 == 0 || i == 63 || i == 64 || i == 199).collect();
        let mut mask: NodataMask = flags.iter().copied().collect();
        assert_eq!((mask.len(), mask.count()), (200, flags.iter().filter(|&&b| b).count()));
        assert_eq!(mask.iter().collect::<Vec<_>>(), flags);
        assert!(!mask.get(200) && !mask.get(10_000), "beyond the mask: not NoData");
        mask.set(64, false);
        mask.set(65, true);
        assert!(!mask.get(64) && mask.get(65) && mask.get(63));
        let empty = NodataMask::default();
        assert!(empty.is_empty() && !empty.get(0) && empty.count() == 0);
        assert_eq!(NodataMask::new(130).count(), 0);
    }
}
