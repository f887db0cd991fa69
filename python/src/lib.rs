//! volterra._volterra: the Rust side of the Python package (python/volterra/). Reading:
//! `read` opens any file the CLI reads into a `Volume`, `Heightfield` or `Particles` whose
//! arrays are numpy arrays over the reader's own buffers (no copy where the values are the
//! stored ones); `list_series` lists a DICOM directory's series. The GIL is released while
//! a file is read. Errors are the CLI's one-line messages, raised as exceptions that
//! subclass ValueError, OSError or MemoryError (by what went wrong).

use numpy::npyffi::NPY_ORDER;
use numpy::{PyArray1, PyArrayMethods};
use pyo3::create_exception;
use pyo3::exceptions::{PyMemoryError, PyOSError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use std::path::PathBuf;
use volterra_formats::dicom;
use volterra_formats::{Dataset, ErrorKind, FormatError as ReaderError, Heightfield, Limits, LoadOptions, ParticleSet, Volume, VoxelData};

create_exception!(volterra, FormatError, PyValueError, "A file volterra cannot read: malformed, truncated or self-contradicting.");
create_exception!(volterra, UnsupportedError, FormatError, "A well-formed file that uses a feature volterra does not read.");
create_exception!(
    volterra,
    AmbiguousError,
    PyValueError,
    "A request that names no one thing, such as a directory of several DICOM series."
);
create_exception!(volterra, ReadError, PyOSError, "A file that could not be opened or read.");
create_exception!(volterra, MemoryLimitError, PyMemoryError, "A file that declares more data than the memory limit allows.");

/// A reader's error as the exception of its kind, with the CLI's one-line message.
fn py_error(e: ReaderError) -> PyErr {
    let message = e.to_string();
    match e.kind {
        ErrorKind::Io => ReadError::new_err(message),
        ErrorKind::Invalid => FormatError::new_err(message),
        ErrorKind::Unsupported => UnsupportedError::new_err(message),
        ErrorKind::TooLarge => MemoryLimitError::new_err(message),
        ErrorKind::Ambiguous => AmbiguousError::new_err(message),
    }
}

/// `max_memory` as bytes: an int, or a size as `--max-memory` takes it ("2G", "512M").
fn limits_of(max_memory: Option<&Bound<'_, PyAny>>) -> PyResult<Limits> {
    let Some(m) = max_memory else { return Ok(Limits::default()) };
    let bytes = if let Ok(n) = m.extract::<u64>() {
        n
    } else if let Ok(s) = m.extract::<String>() {
        volterra_formats::memory::parse_size(&s)
            .ok_or_else(|| PyValueError::new_err(format!("max_memory {s:?}: not a size (bytes, or a number with K, M, G or T)")))?
    } else {
        return Err(PyValueError::new_err("max_memory: give bytes as an int, or a size such as \"2G\""));
    };
    Ok(Limits::max(bytes))
}

/// A JSON value (what `volterra info --json` prints) as Python objects.
fn to_python(py: Python<'_>, v: &serde_json::Value) -> PyResult<Py<PyAny>> {
    use serde_json::Value;
    Ok(match v {
        Value::Null => py.None(),
        Value::Bool(b) => b.into_pyobject(py)?.to_owned().into_any().unbind(),
        Value::Number(n) => match (n.as_i64(), n.as_u64()) {
            (Some(i), _) => i.into_pyobject(py)?.into_any().unbind(),
            (None, Some(u)) => u.into_pyobject(py)?.into_any().unbind(),
            _ => n.as_f64().unwrap_or(f64::NAN).into_pyobject(py)?.into_any().unbind(),
        },
        Value::String(s) => s.into_pyobject(py)?.into_any().unbind(),
        Value::Array(a) => {
            let items: Vec<Py<PyAny>> = a.iter().map(|x| to_python(py, x)).collect::<PyResult<_>>()?;
            PyList::new(py, items)?.into_any().unbind()
        }
        Value::Object(o) => {
            let d = PyDict::new(py);
            for (k, x) in o {
                d.set_item(k, to_python(py, x)?)?;
            }
            d.into_any().unbind()
        }
    })
}

/// `values` as an array of `shape` over the same buffer (no copy), in Fortran order where
/// `fortran` (the first index fastest, as volumes are stored and nibabel hands them out).
fn shaped<T: numpy::Element>(py: Python<'_>, values: Vec<T>, shape: Vec<usize>, fortran: bool) -> PyResult<Py<PyAny>> {
    let flat = PyArray1::from_vec(py, values);
    let order = if fortran { NPY_ORDER::NPY_FORTRANORDER } else { NPY_ORDER::NPY_CORDER };
    Ok(flat.reshape_with_order(shape, order)?.into_any().unbind())
}

/// A volume: voxel values on a grid placed in the world (RAS+ millimetres).
#[pyclass(module = "volterra", name = "Volume", frozen)]
struct PyVolume {
    /// Stored values, shape (i, j, k), Fortran order: over the reader's buffer.
    raw: Py<PyAny>,
    /// Real-world values (`raw` where the rescale is the identity, else raw × slope + intercept as float64).
    array: Py<PyAny>,
    affine: [[f64; 4]; 4],
    spacing: [f64; 3],
    slope: f64,
    intercept: f64,
    modality: Option<String>,
    units: Option<String>,
    suv_bw: Option<f64>,
    meta: serde_json::Value,
}

fn volume_to_python(py: Python<'_>, mut v: Volume) -> PyResult<PyVolume> {
    let meta = volterra::info::volume_json(&v);
    let shape = v.dims.to_vec();
    let real: Option<Vec<f64>> = (!v.rescale.is_identity()).then(|| (0..v.voxel_count()).map(|i| v.value(i)).collect());
    let raw = match std::mem::replace(&mut v.data, VoxelData::U8(Vec::new())) {
        VoxelData::U8(d) => shaped(py, d, shape.clone(), true)?,
        VoxelData::I8(d) => shaped(py, d, shape.clone(), true)?,
        VoxelData::U16(d) => shaped(py, d, shape.clone(), true)?,
        VoxelData::I16(d) => shaped(py, d, shape.clone(), true)?,
        VoxelData::U32(d) => shaped(py, d, shape.clone(), true)?,
        VoxelData::I32(d) => shaped(py, d, shape.clone(), true)?,
        VoxelData::F32(d) => shaped(py, d, shape.clone(), true)?,
        VoxelData::F64(d) => shaped(py, d, shape.clone(), true)?,
    };
    let array = match real {
        Some(values) => shaped(py, values, shape, true)?,
        None => raw.clone_ref(py),
    };
    Ok(PyVolume {
        raw,
        array,
        affine: v.affine,
        spacing: v.spacing,
        slope: v.rescale.slope,
        intercept: v.rescale.intercept,
        modality: v.modality,
        units: v.units,
        suv_bw: v.suv_bw,
        meta,
    })
}

#[pymethods]
impl PyVolume {
    /// Real-world values (Hounsfield units, Bq/ml, …), shape (i, j, k) as nibabel's
    /// `get_fdata()` gives them: the stored values themselves, without a copy, where the
    /// file gives no rescale; else float64 (stored × slope + intercept).
    #[getter]
    fn array(&self, py: Python<'_>) -> Py<PyAny> {
        self.array.clone_ref(py)
    }
    /// The stored values in their own type, shape (i, j, k), over the reader's buffer.
    #[getter]
    fn raw(&self, py: Python<'_>) -> Py<PyAny> {
        self.raw.clone_ref(py)
    }
    /// Voxel index (i, j, k, 1) → world RAS+ millimetres: nibabel's `affine` for NIfTI.
    #[getter]
    fn affine<'py>(&self, py: Python<'py>) -> PyResult<Py<PyAny>> {
        shaped(py, self.affine.iter().flatten().copied().collect::<Vec<f64>>(), vec![4, 4], false)
    }
    /// Voxel spacing in mm along i, j, k.
    #[getter]
    fn spacing(&self) -> (f64, f64, f64) {
        (self.spacing[0], self.spacing[1], self.spacing[2])
    }
    /// Stored → real values: real = stored × slope + intercept.
    #[getter]
    fn slope(&self) -> f64 {
        self.slope
    }
    #[getter]
    fn intercept(&self) -> f64 {
        self.intercept
    }
    /// The DICOM modality ("CT", "MR", "PT", …) where the file says.
    #[getter]
    fn modality(&self) -> Option<String> {
        self.modality.clone()
    }
    /// Units of the real values ("HU", "Bq/ml", …) where the file says.
    #[getter]
    fn units(&self) -> Option<String> {
        self.units.clone()
    }
    /// For a PET in Bq/ml with what SUV needs: the factor from real values to SUVbw (g/ml).
    #[getter]
    fn suv_bw(&self) -> Option<f64> {
        self.suv_bw
    }
    /// What `volterra info --json` prints for the file.
    #[getter]
    fn meta(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        to_python(py, &self.meta)
    }
    fn __repr__(&self) -> String {
        let dims = &self.meta["dims"];
        format!(
            "<volterra.Volume {} {} {}, spacing {:?} mm, {}>",
            dims,
            self.meta["dtype"].as_str().unwrap_or("?"),
            self.modality.as_deref().unwrap_or("-"),
            self.spacing,
            self.meta["orientation"].as_str().unwrap_or("")
        )
    }
}

/// A DEM: elevations in metres on a north-up grid.
#[pyclass(module = "volterra", name = "Heightfield", frozen)]
struct PyHeightfield {
    array: Py<PyAny>,
    transform: [f64; 6],
    crs: String,
    epsg: Option<u32>,
    nodata: Option<f64>,
    meta: serde_json::Value,
}

fn heightfield_to_python(py: Python<'_>, mut h: Heightfield) -> PyResult<PyHeightfield> {
    let meta = volterra::info::heightfield_json(&h);
    let transform = volterra::info::geotransform(&h.georef());
    let elevations = std::mem::take(&mut h.elevations);
    Ok(PyHeightfield {
        array: shaped(py, elevations, vec![h.height, h.width], false)?,
        transform,
        crs: h.crs.description.clone(),
        epsg: h.crs.epsg,
        nodata: h.nodata_value,
        meta,
    })
}

#[pymethods]
impl PyHeightfield {
    /// Elevations in metres, float32, shape (rows, columns), the first row the northern
    /// one (as GDAL's `ReadAsArray` and rasterio's `read(1)`); NoData samples are NaN.
    #[getter]
    fn array(&self, py: Python<'_>) -> Py<PyAny> {
        self.array.clone_ref(py)
    }
    /// GDAL's geotransform: (x of the west edge, column step, 0, y of the north edge, 0, −row step).
    #[getter]
    fn transform(&self) -> (f64, f64, f64, f64, f64, f64) {
        let t = self.transform;
        (t[0], t[1], t[2], t[3], t[4], t[5])
    }
    /// The coordinate reference system, as `volterra info` names it.
    #[getter]
    fn crs(&self) -> String {
        self.crs.clone()
    }
    #[getter]
    fn epsg(&self) -> Option<u32> {
        self.epsg
    }
    /// The file's NoData value, where it declares one (such samples are NaN in `array`).
    #[getter]
    fn nodata(&self) -> Option<f64> {
        self.nodata
    }
    #[getter]
    fn meta(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        to_python(py, &self.meta)
    }
    fn __repr__(&self) -> String {
        format!("<volterra.Heightfield {} × {}, {}>", self.meta["dims"][0], self.meta["dims"][1], self.crs)
    }
}

/// Particles: positions and per-particle arrays.
#[pyclass(module = "volterra", name = "Particles", frozen)]
struct PyParticles {
    positions: Py<PyAny>,
    arrays: Vec<(String, Py<PyAny>)>,
    meta: serde_json::Value,
}

fn particles_to_python(py: Python<'_>, p: ParticleSet, names: &volterra_formats::ParticleArrayNames) -> PyResult<PyParticles> {
    let meta = volterra::info::particles_json(&p, names);
    let n = p.positions.len();
    let positions = shaped(py, p.positions.iter().flatten().copied().collect::<Vec<f64>>(), vec![n, 3], false)?;
    let mut arrays = Vec::new();
    for (name, values) in [(&names.mass, p.mass), (&names.density, p.density), (&names.smoothing_length, p.smoothing_length)] {
        if let Some(v) = values {
            arrays.push((name.clone(), shaped(py, v, vec![n], false)?));
        }
    }
    for a in p.arrays {
        let shape = if a.components == 1 { vec![n] } else { vec![n, a.components] };
        arrays.push((a.name, shaped(py, a.values, shape, false)?));
    }
    Ok(PyParticles { positions, arrays, meta })
}

#[pymethods]
impl PyParticles {
    /// Positions, float64, shape (N, 3), in the file's units.
    #[getter]
    fn positions(&self, py: Python<'_>) -> Py<PyAny> {
        self.positions.clone_ref(py)
    }
    /// Every point array by name: shape (N,) or (N, components).
    #[getter]
    fn arrays<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        for (name, a) in &self.arrays {
            d.set_item(name, a.clone_ref(py))?;
        }
        Ok(d)
    }
    #[getter]
    fn meta(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        to_python(py, &self.meta)
    }
    fn __len__(&self) -> usize {
        self.meta["count"].as_u64().unwrap_or(0) as usize
    }
    fn __repr__(&self) -> String {
        format!("<volterra.Particles {} points, arrays {:?}>", self.meta["count"], self.arrays.iter().map(|a| &a.0).collect::<Vec<_>>())
    }
}

/// Reads any file the `volterra` command reads: DICOM (a file, or a directory of a series:
/// `series` picks one of several, by UID, a unique prefix or the 1-based number
/// `list_series` gives), NIfTI (`volume` picks one of a 4-D file), MetaImage, NRRD, VTK
/// image data, GeoTIFF and PNG DEMs, VTK particles. `max_memory` (bytes, or "2G") refuses
/// a file that would need more before it is read.
#[pyfunction]
#[pyo3(signature = (path, *, series=None, volume=None, max_memory=None))]
fn read(
    py: Python<'_>,
    path: PathBuf,
    series: Option<&Bound<'_, PyAny>>,
    volume: Option<usize>,
    max_memory: Option<&Bound<'_, PyAny>>,
) -> PyResult<Py<PyAny>> {
    let mut opts = LoadOptions { limits: limits_of(max_memory)?, ..Default::default() };
    if let Some(s) = series {
        opts.dicom.series = Some(if let Ok(k) = s.extract::<usize>() { k.to_string() } else { s.extract::<String>()? });
    }
    if let Some(k) = volume {
        opts.nifti.volume_index = k;
    }
    let names = opts.particles.clone();
    let data = py.detach(|| volterra_formats::load(&path, &opts)).map_err(py_error)?;
    Ok(match data {
        Dataset::Volume(v) => Py::new(py, volume_to_python(py, v)?)?.into_any(),
        Dataset::Heightfield(h) => Py::new(py, heightfield_to_python(py, h)?)?.into_any(),
        Dataset::Particles(p) => Py::new(py, particles_to_python(py, p, &names)?)?.into_any(),
    })
}

/// The DICOM series in a directory (searched recursively), one dict each: uid,
/// description, modality, files, rows, columns, patient, study, study_date — numbered
/// from 1 in this order, as `read(..., series=k)` takes them.
#[pyfunction]
#[pyo3(signature = (directory, *, max_memory=None))]
fn list_series(py: Python<'_>, directory: PathBuf, max_memory: Option<&Bound<'_, PyAny>>) -> PyResult<Py<PyAny>> {
    let limits = limits_of(max_memory)?;
    let found = py.detach(|| dicom::list_series(&directory, &limits)).map_err(py_error)?;
    let json = serde_json::to_value(&found).map_err(|e| PyValueError::new_err(e.to_string()))?;
    to_python(py, &json)
}

#[pymodule]
fn _volterra(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add_function(wrap_pyfunction!(read, m)?)?;
    m.add_function(wrap_pyfunction!(list_series, m)?)?;
    m.add_class::<PyVolume>()?;
    m.add_class::<PyHeightfield>()?;
    m.add_class::<PyParticles>()?;
    m.add("FormatError", py.get_type::<FormatError>())?;
    m.add("UnsupportedError", py.get_type::<UnsupportedError>())?;
    m.add("AmbiguousError", py.get_type::<AmbiguousError>())?;
    m.add("ReadError", py.get_type::<ReadError>())?;
    m.add("MemoryLimitError", py.get_type::<MemoryLimitError>())?;
    Ok(())
}
