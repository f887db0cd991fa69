//! Data handed in from Python (numpy arrays, or what `read` returned) turned into the
//! readers' types, checked as a reader checks a file: a dtype the renderers take, a shape
//! that holds data, an affine or geotransform that places it. Arrays of any memory layout
//! are taken (a nibabel slice is a strided view): they are copied in the order the
//! renderers store, so a view and its contiguous copy give the same data.

use crate::data::{PyHeightfield, PyParticles, PyVolume};
use numpy::ndarray::{ArrayView2, ArrayView3};
use numpy::{PyArray2, PyArray3, PyArrayMethods};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList, PyTuple};
use volterra_formats::heightfield::{GridGeoref, GridUnits, NodataMask};
use volterra_formats::particles::PointArray;
use volterra_formats::volume::Rescale;
use volterra_formats::{Crs, Heightfield, ParticleArrayNames, ParticleSet, RgbImage, Volume, VoxelData};

/// `obj` as a numpy array (lists and other array-likes through `numpy.asarray`).
fn as_ndarray<'py>(obj: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyAny>> {
    obj.py().import("numpy")?.call_method1("asarray", (obj,))
}

fn dtype_name(array: &Bound<'_, PyAny>) -> String {
    array.getattr("dtype").and_then(|d| d.str().map(|s| s.to_string())).unwrap_or_else(|_| "?".into())
}

fn shape_of(array: &Bound<'_, PyAny>) -> PyResult<Vec<usize>> {
    array.getattr("shape")?.extract()
}

/// A volume's voxels from a 3-D array indexed (i, j, k), as `Volume.array` and nibabel's
/// `get_fdata()` are: copied with i fastest, in their own type.
fn voxels(what: &str, array: &Bound<'_, PyAny>) -> PyResult<([usize; 3], VoxelData)> {
    // Big-endian values (nibabel's view of a big-endian file) in this machine's order.
    let native;
    let array = if array.getattr("dtype")?.getattr("isnative")?.extract::<bool>()? {
        array
    } else {
        let dtype = array.getattr("dtype")?.call_method1("newbyteorder", ("=",))?;
        native = array.call_method1("astype", (dtype,))?;
        &native
    };
    let shape = shape_of(array)?;
    let [ni, nj, nk] = shape[..] else {
        return Err(PyValueError::new_err(format!("{what}: a volume's array has 3 dimensions (i, j, k), this one has shape {shape:?}")));
    };
    if ni * nj * nk == 0 {
        return Err(PyValueError::new_err(format!("{what}: the array is empty (shape {shape:?})")));
    }
    fn fortran<T: numpy::Element + Copy>(a: ArrayView3<'_, T>) -> Vec<T> {
        // The transpose iterated in logical order runs i fastest.
        a.t().iter().copied().collect()
    }
    macro_rules! try_types {
        ($($t:ty => $v:ident),*) => {
            $(if let Ok(a) = array.cast::<PyArray3<$t>>() {
                return Ok(([ni, nj, nk], VoxelData::$v(fortran(a.readonly().as_array()))));
            })*
        };
    }
    try_types!(u8 => U8, i8 => I8, u16 => U16, i16 => I16, u32 => U32, i32 => I32, f32 => F32, f64 => F64);
    Err(PyTypeError::new_err(format!(
        "{what}: arrays of {} are not volumes volterra renders (uint8, int8, uint16, int16, uint32, int32, float32, float64; \
         convert with .astype(np.float32) or np.int32)",
        dtype_name(array)
    )))
}

/// A 4×4 voxel-to-world affine that places a grid: finite, its last row (0, 0, 0, 1), its
/// 3×3 part invertible.
fn affine_of(what: &str, affine: &Bound<'_, PyAny>) -> PyResult<[[f64; 4]; 4]> {
    let a = as_ndarray(affine)?.call_method1("astype", ("float64",))?;
    let shape = shape_of(&a)?;
    if shape != [4, 4] {
        return Err(PyValueError::new_err(format!("{what}: the affine must be 4×4, it has shape {shape:?}")));
    }
    let held = a.cast::<PyArray2<f64>>()?.readonly();
    let a: ArrayView2<'_, f64> = held.as_array();
    let m: [[f64; 4]; 4] = std::array::from_fn(|r| std::array::from_fn(|c| a[[r, c]]));
    if m.iter().flatten().any(|v| !v.is_finite()) {
        return Err(PyValueError::new_err(format!("{what}: the affine holds NaN or infinite values: {m:?}")));
    }
    if m[3] != [0.0, 0.0, 0.0, 1.0] {
        return Err(PyValueError::new_err(format!("{what}: the affine's last row must be (0, 0, 0, 1), it is {:?}", m[3])));
    }
    let det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
    if det == 0.0 || !det.is_finite() {
        return Err(PyValueError::new_err(format!("{what}: the affine's 3×3 part is singular (a voxel axis of length 0): {m:?}")));
    }
    Ok(m)
}

/// A volume from a `Volume` (its stored values, affine, rescale, modality and units) or
/// from an array and an affine (identity: 1 mm voxels at the origin).
pub fn volume(what: &str, data: &Bound<'_, PyAny>, affine: Option<&Bound<'_, PyAny>>) -> PyResult<Volume> {
    if let Ok(v) = data.cast::<PyVolume>() {
        let v = v.get();
        let py = data.py();
        let (dims, values) = voxels(what, v.raw.bind(py))?;
        let affine = match affine {
            Some(a) => affine_of(what, a)?,
            None => v.affine,
        };
        let mut out = Volume::new(dims, affine, values);
        out.rescale = Rescale { slope: v.slope, intercept: v.intercept };
        out.modality = v.modality.clone();
        out.units = v.units.clone();
        out.suv_bw = v.suv_bw;
        return Ok(out);
    }
    let array = as_ndarray(data)?;
    let (dims, values) = voxels(what, &array)?;
    let affine = match affine {
        Some(a) => affine_of(what, a)?,
        None => volterra_formats::volume::identity_affine(),
    };
    Ok(Volume::new(dims, affine, values))
}

/// A heightfield from a `Heightfield` (its elevations and georeferencing) or from a 2-D
/// array (rows from the north, NaN for NoData) and GDAL's geotransform in metres of a
/// projected CRS (`epsg`, or local coordinates).
pub fn heightfield(data: &Bound<'_, PyAny>, transform: Option<&Bound<'_, PyAny>>, epsg: Option<u32>) -> PyResult<Heightfield> {
    let what = "add_heightfield";
    let (array, georef, nodata_value) = match data.cast::<PyHeightfield>() {
        Ok(h) if transform.is_none() && epsg.is_none() => {
            let h = h.get();
            (h.array.bind(data.py()).clone(), Some(h.georef.clone()), h.nodata)
        }
        Ok(h) => (h.get().array.bind(data.py()).clone(), None, h.get().nodata),
        Err(_) => (as_ndarray(data)?, None, None),
    };
    let kind = array.getattr("dtype")?.getattr("kind")?.extract::<String>()?;
    if !matches!(kind.as_str(), "f" | "i" | "u") {
        return Err(PyTypeError::new_err(format!("{what}: arrays of {} are not elevations (give real numbers)", dtype_name(&array))));
    }
    let shape = shape_of(&array)?;
    let [rows, cols] = shape[..] else {
        return Err(PyValueError::new_err(format!("{what}: elevations are a 2-D array (rows, columns), this one has shape {shape:?}")));
    };
    if rows < 2 || cols < 2 {
        return Err(PyValueError::new_err(format!("{what}: a heightfield needs at least 2×2 samples, the array has shape {shape:?}")));
    }
    let georef = match georef {
        Some(g) => g,
        None => {
            let Some(t) = transform else {
                return Err(PyValueError::new_err(format!("{what}: give the geotransform (GDAL's order) of an array of elevations")));
            };
            grid(what, t, rows, cols, epsg)?
        }
    };
    let as_f32 = array.call_method1("astype", ("float32",))?;
    let elevations: Vec<f32> = as_f32.cast::<PyArray2<f32>>()?.readonly().as_array().iter().copied().collect();
    let mut nodata = NodataMask::default();
    if elevations.iter().any(|z| z.is_nan()) {
        nodata = NodataMask::new(elevations.len());
        for (i, z) in elevations.iter().enumerate() {
            nodata.set(i, z.is_nan());
        }
    }
    if elevations.iter().any(|z| z.is_infinite()) {
        return Err(PyValueError::new_err(format!("{what}: the elevations hold infinite values (NaN marks NoData)")));
    }
    Ok(Heightfield {
        width: georef.width,
        height: georef.height,
        cell_size: georef.cell_size,
        cell_size_native: georef.cell_size_native,
        origin: georef.origin,
        crs: georef.crs,
        elevations,
        nodata,
        nodata_value,
        notes: Vec::new(),
        attributes: Vec::new(),
        units: georef.units,
    })
}

/// A drape: an sRGB image, uint8 (rows, columns, 3), the first row the northern one.
pub fn drape(obj: &Bound<'_, PyAny>) -> PyResult<RgbImage> {
    let array = as_ndarray(obj)?;
    let shape = shape_of(&array)?;
    let (rows, cols) = match shape[..] {
        [r, c, 3] if r > 0 && c > 0 => (r, c),
        _ => return Err(PyValueError::new_err(format!("drape: an RGB image is (rows, columns, 3), this one has shape {shape:?}"))),
    };
    let Ok(bytes) = array.cast::<PyArray3<u8>>() else {
        return Err(PyTypeError::new_err(format!(
            "drape: sRGB bytes (uint8) are taken, not {} (for colours in [0, 1]: (np.clip(c, 0, 1) * 255).round().astype(np.uint8))",
            dtype_name(&array)
        )));
    };
    let data: Vec<u8> = bytes.readonly().as_array().iter().copied().collect();
    Ok(RgbImage { width: cols, height: rows, data })
}

/// The grid GDAL's geotransform `t` gives `rows` × `cols` samples: north up, metres.
fn grid(what: &str, t: &Bound<'_, PyAny>, rows: usize, cols: usize, epsg: Option<u32>) -> PyResult<GridGeoref> {
    let t: Vec<f64> = t.extract().map_err(|_| PyTypeError::new_err(format!("{what}: the geotransform is six numbers")))?;
    let [x0, dx, rx, y0, ry, dy] = t[..] else {
        return Err(PyValueError::new_err(format!("{what}: the geotransform is six numbers, not {}", t.len())));
    };
    if t.iter().any(|v| !v.is_finite()) {
        return Err(PyValueError::new_err(format!("{what}: the geotransform holds NaN or infinite values: {t:?}")));
    }
    if rx != 0.0 || ry != 0.0 {
        return Err(PyValueError::new_err(format!("{what}: a rotated geotransform {t:?} is not read (north up only)")));
    }
    if !(dx > 0.0 && dy < 0.0) {
        return Err(PyValueError::new_err(format!(
            "{what}: the geotransform's column step must be positive and its row step negative (north up), they are {dx} and {dy}"
        )));
    }
    let crs = match epsg {
        Some(code) => Crs { epsg: Some(code), geographic: false, description: format!("EPSG:{code} (projected)"), metres_per_unit: 1.0 },
        None => Crs::local(),
    };
    Ok(GridGeoref {
        width: cols,
        height: rows,
        cell_size: [dx, -dy],
        cell_size_native: [dx, -dy],
        origin: [x0 + 0.5 * dx, y0 + 0.5 * dy],
        crs,
        units: GridUnits::METRES,
    })
}

/// A real-valued array as float64 values and its shape (refusing others with `what`).
fn reals(what: &str, obj: &Bound<'_, PyAny>) -> PyResult<(Vec<usize>, Vec<f64>)> {
    let array = as_ndarray(obj)?;
    let kind = array.getattr("dtype")?.getattr("kind")?.extract::<String>()?;
    if !matches!(kind.as_str(), "f" | "i" | "u") {
        return Err(PyTypeError::new_err(format!("{what}: arrays of {} are not real numbers", dtype_name(&array))));
    }
    let shape = shape_of(&array)?;
    // C order: a point's components together.
    let flat = array.call_method1("astype", ("float64",))?.call_method1("ravel", ())?;
    let values: Vec<f64> = flat.cast::<numpy::PyArray1<f64>>()?.readonly().as_array().iter().copied().collect();
    Ok((shape, values))
}

/// Particles from a `Particles` or from positions (N × 3) and a dict of point arrays
/// ((N,) or (N, components)); `names` says which arrays are mass, density and h.
pub fn particles(data: &Bound<'_, PyAny>, arrays: Option<&Bound<'_, PyDict>>, names: &ParticleArrayNames) -> PyResult<ParticleSet> {
    let what = "add_particles";
    let py = data.py();
    let (positions, arrays): (Bound<'_, PyAny>, Bound<'_, PyDict>) = match data.cast::<PyParticles>() {
        Ok(p) => {
            let d = PyDict::new(py);
            for (name, a) in &p.get().arrays {
                d.set_item(name, a.bind(py))?;
            }
            if let Some(extra) = arrays {
                d.update(extra.as_mapping())?;
            }
            (p.get().positions.bind(py).clone(), d)
        }
        Err(_) => (data.clone(), arrays.cloned().unwrap_or_else(|| PyDict::new(py))),
    };
    let (shape, flat) = reals(&format!("{what}: positions"), &positions)?;
    let n = match shape[..] {
        [n, 3] if n > 0 => n,
        _ => return Err(PyValueError::new_err(format!("{what}: positions are an (N, 3) array with N > 0, this one has shape {shape:?}"))),
    };
    let positions: Vec<[f64; 3]> = flat.chunks_exact(3).map(|p| [p[0], p[1], p[2]]).collect();
    let mut point_arrays = Vec::new();
    for (name, values) in arrays.iter() {
        let name: String = name.extract().map_err(|_| PyTypeError::new_err(format!("{what}: array names are strings")))?;
        let (shape, values) = reals(&format!("{what}: array '{name}'"), &values)?;
        let components = match shape[..] {
            [m] if m == n => 1,
            [m, c] if m == n && c > 0 => c,
            _ => {
                return Err(PyValueError::new_err(format!(
                    "{what}: array '{name}' has shape {shape:?}; point arrays are ({n},) or ({n}, components)"
                )))
            }
        };
        point_arrays.push(PointArray { name, components, values });
    }
    ParticleSet::from_arrays(positions, point_arrays, names, Vec::new()).map_err(|m| PyValueError::new_err(format!("{what}: {m}")))
}

/// A Python value (dicts, lists, tuples, numbers, strings, numpy arrays and scalars) as
/// JSON, to be read as a scene file's keys are.
pub fn to_json(obj: &Bound<'_, PyAny>) -> PyResult<serde_json::Value> {
    use serde_json::Value;
    if obj.is_none() {
        return Ok(Value::Null);
    }
    if let Ok(b) = obj.cast::<pyo3::types::PyBool>() {
        return Ok(Value::Bool(b.is_true()));
    }
    if let Ok(d) = obj.cast::<PyDict>() {
        let mut m = serde_json::Map::new();
        for (k, v) in d.iter() {
            m.insert(k.extract::<String>().map_err(|_| PyTypeError::new_err("keys are strings"))?, to_json(&v)?);
        }
        return Ok(Value::Object(m));
    }
    if let Ok(s) = obj.extract::<String>() {
        return Ok(Value::String(s));
    }
    if obj.cast::<PyList>().is_ok() || obj.cast::<PyTuple>().is_ok() || obj.hasattr("tolist")? {
        // numpy arrays and scalars through tolist(): plain Python values.
        let plain = if obj.hasattr("tolist")? { obj.call_method0("tolist")? } else { obj.clone() };
        if plain.cast::<PyList>().is_err() && plain.cast::<PyTuple>().is_err() {
            return to_json(&plain);
        }
        return plain.try_iter()?.map(|x| to_json(&x?)).collect::<PyResult<Vec<_>>>().map(Value::Array);
    }
    if let Ok(i) = obj.extract::<i64>() {
        return Ok(Value::from(i));
    }
    if let Ok(f) = obj.extract::<f64>() {
        return serde_json::Number::from_f64(f)
            .map(Value::Number)
            .ok_or_else(|| PyValueError::new_err(format!("{f} is not a scene setting (values are finite)")));
    }
    Err(PyTypeError::new_err(format!("a value of type {} is not a scene setting", obj.get_type().name()?)))
}
