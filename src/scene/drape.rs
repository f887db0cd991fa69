//! A colour image draped over a terrain node (`texture`): a PNG stretched over the
//! heightfield's extent, or a GeoTIFF placed by its own georeferencing — RGB or RGBA bytes,
//! or one band of values shown through a colour map (`texture_colormap`, between
//! `texture_range` or the band's own range). Pixels a single-band drape holds no data for
//! (GDAL_NODATA, NaN) are transparent: the terrain's elevation colours show there, as they
//! do beyond the drape's edges.

use crate::colormap::Colormap;
use anyhow::{bail, Context, Result};
use std::path::Path;
use volterra_formats::geotiff::{read_geotiff_image, GeoPixels};
use volterra_formats::image::{linear_to_srgb, read_rgb_png};
use volterra_formats::{Crs, Limits, RgbImage};

/// Where a georeferenced drape lies, in its CRS.
#[derive(Debug, Clone, PartialEq)]
pub struct DrapeGeoref {
    pub crs: Crs,
    /// Map coordinates of the centre of pixel (0, 0), the north-west one.
    pub origin: [f64; 2],
    /// Pixel size in CRS units (east, north), both positive.
    pub cell_size_native: [f64; 2],
}

/// The drape's pixels as sRGB RGBA bytes, row by row from the north, with colour
/// premultiplied by alpha (0 where there is no data), and its placement.
#[derive(Debug, Clone, PartialEq)]
pub struct Drape {
    pub width: usize,
    pub height: usize,
    pub rgba: Vec<u8>,
    /// None: stretched over the heightfield's extent (a PNG).
    pub georef: Option<DrapeGeoref>,
    /// What a colour-mapped band shows, for the legend: the map and its end values.
    pub scale: Option<(Colormap, [f64; 2])>,
}

/// How a single-band drape is coloured.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BandColours {
    pub colormap: Colormap,
    /// Values at the map's ends; None: the band's own range.
    pub range: Option<[f64; 2]>,
}

/// Whether the drape at `path` is stretched over the heightfield read (a PNG), rather than
/// placed by its own georeferencing (a `.tif`/`.tiff` GeoTIFF).
pub fn is_stretched(path: &Path) -> bool {
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or_default().to_ascii_lowercase();
    ext != "tif" && ext != "tiff"
}

impl Drape {
    /// An RGB image stretched over the heightfield's extent.
    pub fn stretched(img: &RgbImage) -> Drape {
        let rgba = img.data.chunks_exact(3).flat_map(|p| [p[0], p[1], p[2], 255]).collect();
        Drape { width: img.width, height: img.height, rgba, georef: None, scale: None }
    }

    /// Reads a drape (see `is_stretched`): a `.tif`/`.tiff` GeoTIFF (placed by its georeferencing), else a PNG
    /// (stretched). `band` colours a single-band GeoTIFF, and is refused for anything else.
    pub fn load(path: &Path, band: Option<BandColours>, limits: &Limits) -> Result<Drape> {
        if is_stretched(path) {
            if band.is_some() {
                bail!("{}: texture_colormap and texture_range colour a single-band GeoTIFF, not a PNG", path.display());
            }
            return Ok(Drape::stretched(&read_rgb_png(path, limits)?));
        }
        let img = read_geotiff_image(path, limits)?;
        if band.is_some() && !matches!(img.pixels, GeoPixels::Values(_)) {
            bail!("{}: texture_colormap and texture_range colour a single-band GeoTIFF; this one is RGB(A)", path.display());
        }
        let georef = DrapeGeoref { crs: img.crs.clone(), origin: img.origin, cell_size_native: img.cell_size_native };
        let (rgba, scale) = match img.pixels {
            GeoPixels::Rgb8(v) => (v.chunks_exact(3).flat_map(|p| [p[0], p[1], p[2], 255]).collect(), None),
            GeoPixels::Rgba8(v) => {
                // Premultiplied (in sRGB bytes: exact for the usual alpha of 0 or 255).
                let pre = |c: u8, a: u8| ((c as u32 * a as u32 + 127) / 255) as u8;
                (v.chunks_exact(4).flat_map(|p| [pre(p[0], p[3]), pre(p[1], p[3]), pre(p[2], p[3]), p[3]]).collect(), None)
            }
            GeoPixels::Values(values) => {
                let band = band.unwrap_or(BandColours { colormap: Colormap::Grey, range: None });
                let range = match band.range {
                    Some(r) => r,
                    None => values
                        .iter()
                        .filter(|v| v.is_finite())
                        .fold(None, |r: Option<[f64; 2]>, &v| Some(r.map_or([v, v], |[lo, hi]| [lo.min(v), hi.max(v)])))
                        .with_context(|| format!("{}: every pixel of the drape is NoData", path.display()))?,
                };
                if !(range[0].is_finite() && range[1].is_finite() && range[0] < range[1]) && band.range.is_some() {
                    bail!("{}: texture_range {range:?} must be two finite values, low < high", path.display());
                }
                let span = (range[1] - range[0]).max(f64::MIN_POSITIVE);
                let byte = |c: f32| (linear_to_srgb(c) * 255.0).round().clamp(0.0, 255.0) as u8;
                let rgba = values
                    .iter()
                    .flat_map(|&v| {
                        if v.is_finite() {
                            let [r, g, b] = band.colormap.at((v - range[0]) / span);
                            [byte(r), byte(g), byte(b), 255]
                        } else {
                            [0; 4]
                        }
                    })
                    .collect();
                (rgba, Some((band.colormap, range)))
            }
        };
        Ok(Drape { width: img.width, height: img.height, rgba, georef: Some(georef), scale })
    }
}
