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
}

impl Crs {
    pub fn local() -> Crs {
        Crs { epsg: None, geographic: false, description: "local (no georeferencing)".into() }
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
    /// true where the sample is NoData. Empty when the raster has no NoData samples.
    pub nodata: Vec<bool>,
    /// The file's NoData value, where it declares one.
    pub nodata_value: Option<f64>,
    pub notes: Vec<String>,
}

impl Heightfield {
    pub fn nodata_count(&self) -> usize {
        self.nodata.iter().filter(|&&b| b).count()
    }
    pub fn is_nodata(&self, col: usize, row: usize) -> bool {
        !self.nodata.is_empty() && self.nodata[row * self.width + col]
    }
    /// (min, max) elevation over valid samples.
    pub fn range(&self) -> Option<(f32, f32)> {
        let mut lo = f32::INFINITY;
        let mut hi = f32::NEG_INFINITY;
        for (i, &z) in self.elevations.iter().enumerate() {
            if (self.nodata.is_empty() || !self.nodata[i]) && z.is_finite() {
                lo = lo.min(z);
                hi = hi.max(z);
            }
        }
        (lo <= hi).then_some((lo, hi))
    }
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
