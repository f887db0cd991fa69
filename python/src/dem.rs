//! DEM products and image comparison from Python: the functions `volterra dem` and
//! `volterra compare` run, on a DEM given as a path, a `Heightfield` or an array with its
//! geotransform, and on frames, EXR files or arrays. python/volterra/dem.py gives them
//! their documented signatures.

use crate::frame::PyFrame;
use crate::{input, limits_of, py_error, scene_error, shaped, to_python};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyList;
use std::path::PathBuf;
use volterra::dem::{self, ColorMode, Options, Product, Raster, Shading};
use volterra_formats::{Dataset, FloatImage, Heightfield, LoadOptions};

/// The DEM a function works on: a file read whole (within `max_memory`), a `Heightfield`,
/// or an array of elevations with its geotransform.
fn dem_of(
    py: Python<'_>,
    dem: &Bound<'_, PyAny>,
    transform: Option<&Bound<'_, PyAny>>,
    epsg: Option<u32>,
    max_memory: Option<&Bound<'_, PyAny>>,
) -> PyResult<Heightfield> {
    if let Ok(path) = dem.extract::<PathBuf>() {
        let opts = LoadOptions { limits: limits_of(max_memory)?, ..Default::default() };
        return match py.detach(|| volterra_formats::load(&path, &opts)).map_err(py_error)? {
            Dataset::Heightfield(h) => Ok(h),
            _ => Err(crate::FormatError::new_err(format!("{}: not a DEM (a GeoTIFF or PNG heightmap)", path.display()))),
        };
    }
    input::heightfield(dem, transform, epsg)
}

/// A product's cells as a (rows, columns) array: float32 with NaN where gdaldem writes its
/// NoData value (as `read` gives the CLI's output file), hillshade's uint8 as written
/// (0 is its NoData).
fn raster_to_python(py: Python<'_>, hf: &Heightfield, raster: Raster, nodata: Option<f64>) -> PyResult<Py<PyAny>> {
    let shape = vec![hf.height, hf.width];
    match raster {
        Raster::U8(v) => shaped(py, v, shape, false),
        Raster::F32(mut v) => {
            if let Some(nd) = nodata {
                v.iter_mut().filter(|x| **x as f64 == nd).for_each(|x| *x = f32::NAN);
            }
            shaped(py, v, shape, false)
        }
    }
}

/// gdaldem's slope, aspect, hillshade, TRI, TPI or roughness of a DEM, with its options.
#[pyfunction]
#[pyo3(signature = (dem, product, transform=None, *, epsg=None, z=1.0, scale=1.0, azimuth=315.0, altitude=45.0,
    percent=false, zero_for_flat=false, compute_edges=false, alg=None, multidirectional=false, combined=false, max_memory=None))]
#[allow(clippy::too_many_arguments)]
pub fn dem_product(
    py: Python<'_>,
    dem: &Bound<'_, PyAny>,
    product: &str,
    transform: Option<&Bound<'_, PyAny>>,
    epsg: Option<u32>,
    z: f64,
    scale: f64,
    azimuth: f64,
    altitude: f64,
    percent: bool,
    zero_for_flat: bool,
    compute_edges: bool,
    alg: Option<&str>,
    multidirectional: bool,
    combined: bool,
    max_memory: Option<&Bound<'_, PyAny>>,
) -> PyResult<Py<PyAny>> {
    let product = match product {
        "hillshade" => Product::Hillshade,
        "slope" => Product::Slope,
        "aspect" => Product::Aspect,
        "tri" => Product::Tri,
        "tpi" => Product::Tpi,
        "roughness" => Product::Roughness,
        other => return Err(PyValueError::new_err(format!("unknown DEM product '{other}'"))),
    };
    let gradient = matches!(product, Product::Slope | Product::Aspect | Product::Hillshade);
    let (gradient_alg, tri) = dem::algorithms(alg, gradient, product == Product::Tri)
        .map_err(|m| PyValueError::new_err(format!("alg '{}': {m}", alg.unwrap_or_default())))?;
    if (multidirectional || combined) && product != Product::Hillshade {
        return Err(PyValueError::new_err("multidirectional and combined are for hillshade"));
    }
    let shading = match (multidirectional, combined) {
        (true, true) => return Err(PyValueError::new_err("give multidirectional or combined, not both")),
        (true, _) => Shading::MultiDirectional,
        (_, true) => Shading::Combined,
        _ => Shading::Single,
    };
    let options = Options { z, scale, azimuth, altitude, percent, zero_for_flat, compute_edges, gradient: gradient_alg, tri, shading };
    let hf = dem_of(py, dem, transform, epsg, max_memory)?;
    let raster = py.detach(|| dem::compute(&hf, product, &options)).map_err(scene_error)?;
    raster_to_python(py, &hf, raster, dem::nodata_value(product, &options))
}

/// gdaldem color-relief: each cell's colour from a palette (a gdaldem colour file's text),
/// (rows, columns, 3 or 4) uint8.
#[pyfunction]
#[pyo3(signature = (dem, palette, transform=None, *, epsg=None, alpha=false, mode="interpolate", max_memory=None))]
#[allow(clippy::too_many_arguments)]
pub fn dem_color_relief(
    py: Python<'_>,
    dem: &Bound<'_, PyAny>,
    palette: &str,
    transform: Option<&Bound<'_, PyAny>>,
    epsg: Option<u32>,
    alpha: bool,
    mode: &str,
    max_memory: Option<&Bound<'_, PyAny>>,
) -> PyResult<Py<PyAny>> {
    let mode = match mode {
        "interpolate" => ColorMode::Interpolate,
        "nearest" => ColorMode::Nearest,
        "exact" => ColorMode::Exact,
        other => return Err(PyValueError::new_err(format!("mode '{other}': interpolate, nearest or exact"))),
    };
    let hf = dem_of(py, dem, transform, epsg, max_memory)?;
    let entries = dem::parse_palette(palette, hf.nodata_value, || hf.range().map(|(lo, hi)| (lo as f64, hi as f64)))
        .map_err(|e| PyValueError::new_err(format!("palette: {e:#}")))?;
    let bytes = py.detach(|| dem::color_relief(&hf, &entries, mode, alpha));
    shaped(py, bytes, vec![hf.height, hf.width, if alpha { 4 } else { 3 }], false)
}

/// gdal_contour's lines of a DEM at `interval` (from `offset`) or at `levels`: a list of
/// (level, (n, 2) array of map coordinates); a closed line repeats its first vertex.
#[pyfunction]
#[pyo3(signature = (dem, transform=None, *, epsg=None, interval=None, offset=0.0, levels=None, max_memory=None))]
#[allow(clippy::too_many_arguments)]
pub fn dem_contours(
    py: Python<'_>,
    dem: &Bound<'_, PyAny>,
    transform: Option<&Bound<'_, PyAny>>,
    epsg: Option<u32>,
    interval: Option<f64>,
    offset: f64,
    levels: Option<Vec<f64>>,
    max_memory: Option<&Bound<'_, PyAny>>,
) -> PyResult<Py<PyAny>> {
    let levels = match (interval, levels) {
        (Some(interval), None) => dem::contours::Levels::Interval { interval, offset },
        (None, Some(l)) => dem::contours::Levels::Fixed(l),
        _ => return Err(PyValueError::new_err("contours: give interval or levels, one of them")),
    };
    let hf = dem_of(py, dem, transform, epsg, max_memory)?;
    let grid = hf.georef();
    let lines = py.detach(|| dem::contours::contours(&hf, &grid, &levels)).map_err(scene_error)?;
    let out = PyList::empty(py);
    for line in lines {
        let n = line.points.len();
        let points = shaped(py, line.points.into_iter().flatten().collect::<Vec<f64>>(), vec![n, 2], false)?;
        out.append((line.level, points))?;
    }
    Ok(out.into_any().unbind())
}

/// An image to compare: a Frame (its EXR's channels), an EXR file, or an array (H, W, 3
/// or 4: R, G, B[, A]; H, W: one channel "Y").
fn image_of(py: Python<'_>, obj: &Bound<'_, PyAny>, max_memory: Option<&Bound<'_, PyAny>>) -> PyResult<FloatImage> {
    if let Ok(f) = obj.cast::<PyFrame>() {
        // In the order its EXR file holds them (sorted by name), so the sums run as for
        // the file and a frame compares exactly as its saved EXR.
        let mut img = f.get().to_image();
        img.channels.sort_by(|a, b| a.0.cmp(&b.0));
        return Ok(img);
    }
    if let Ok(path) = obj.extract::<PathBuf>() {
        let limits = limits_of(max_memory)?;
        return py.detach(|| volterra_formats::exr_io::read_exr(&path, &limits)).map_err(py_error);
    }
    let array = py.import("numpy")?.call_method1("asarray", (obj, "float32"))?;
    let shape: Vec<usize> = array.getattr("shape")?.extract()?;
    let names: &[&str] = match shape[..] {
        [_, _] => &["Y"],
        [_, _, 3] => &["R", "G", "B"],
        [_, _, 4] => &["R", "G", "B", "A"],
        _ => return Err(PyTypeError::new_err(format!("compare: an image array is (H, W), (H, W, 3) or (H, W, 4), not {shape:?}"))),
    };
    let flat: Vec<f32> = array.call_method0("ravel")?.extract()?;
    let mut img = FloatImage::new(shape[1], shape[0]);
    for (k, name) in names.iter().enumerate() {
        img.add_channel(name, flat.iter().skip(k).step_by(names.len()).copied().collect());
    }
    Ok(img)
}

/// What `volterra compare A B --json` prints: per channel and overall RMSE, PSNR, largest
/// error and relative RMSE (B the reference), and the pixels covered in one only.
#[pyfunction]
#[pyo3(signature = (a, b, *, max_memory=None))]
pub fn compare(py: Python<'_>, a: &Bound<'_, PyAny>, b: &Bound<'_, PyAny>, max_memory: Option<&Bound<'_, PyAny>>) -> PyResult<Py<PyAny>> {
    let (ia, ib) = (image_of(py, a, max_memory)?, image_of(py, b, max_memory)?);
    let c = volterra::compare::compare(&ia, &ib).map_err(|e| PyValueError::new_err(format!("compare: {e:#}")))?;
    to_python(py, &serde_json::to_value(&c).map_err(|e| PyValueError::new_err(e.to_string()))?)
}
