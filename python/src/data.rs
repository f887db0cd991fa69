//! What `read` returns: `Volume`, `Heightfield` and `Particles`, their arrays numpy arrays
//! over the readers' own buffers (no copy where the values are the stored ones), and
//! `list_series`.

use crate::{limits_of, py_error, shaped, to_python};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::PathBuf;
use volterra_formats::dicom;
use volterra_formats::heightfield::GridGeoref;
use volterra_formats::{Dataset, Heightfield, LoadOptions, ParticleSet, Volume, VoxelData};

/// A volume: voxel values on a grid placed in the world (RAS+ millimetres).
#[pyclass(module = "volterra", name = "Volume", frozen)]
pub(crate) struct PyVolume {
    /// Stored values, shape (i, j, k), Fortran order: over the reader's buffer.
    pub(crate) raw: Py<PyAny>,
    /// Real-world values (`raw` where the rescale is the identity, else raw × slope + intercept as float64).
    array: Py<PyAny>,
    pub(crate) affine: [[f64; 4]; 4],
    spacing: [f64; 3],
    pub(crate) slope: f64,
    pub(crate) intercept: f64,
    pub(crate) modality: Option<String>,
    pub(crate) units: Option<String>,
    pub(crate) suv_bw: Option<f64>,
    meta: serde_json::Value,
}

fn volume_to_python(py: Python<'_>, mut v: Volume) -> PyResult<PyVolume> {
    // The passes over the voxels (the metadata's range, the rescaled values) without the GIL.
    let (meta, real) = py.detach(|| (volterra::info::volume_json(&v), (!v.rescale.is_identity()).then(|| v.real_values())));
    let shape = v.dims.to_vec();
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
    /// A volume from an array indexed (i, j, k) of stored values and its 4×4 affine (voxel
    /// index → RAS+ mm; identity where None); real values are stored × `slope` +
    /// `intercept`. `from_nibabel` builds one from a nibabel image.
    #[new]
    #[pyo3(signature = (array, affine=None, *, slope=1.0, intercept=0.0, modality=None, units=None))]
    fn new(
        py: Python<'_>,
        array: &Bound<'_, PyAny>,
        affine: Option<&Bound<'_, PyAny>>,
        slope: f64,
        intercept: f64,
        modality: Option<String>,
        units: Option<String>,
    ) -> PyResult<PyVolume> {
        if !(slope.is_finite() && intercept.is_finite() && slope != 0.0) {
            return Err(PyValueError::new_err(format!("Volume: slope {slope} and intercept {intercept} must be finite, the slope not 0")));
        }
        let mut v = crate::input::volume("Volume", array, affine)?;
        v.rescale = volterra_formats::volume::Rescale { slope, intercept };
        v.modality = modality;
        v.units = units;
        volume_to_python(py, v)
    }

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
pub(crate) struct PyHeightfield {
    pub(crate) array: Py<PyAny>,
    /// Where the samples lie, as read (a scene built from this heightfield places it so).
    pub(crate) georef: GridGeoref,
    transform: [f64; 6],
    crs: String,
    epsg: Option<u32>,
    pub(crate) nodata: Option<f64>,
    meta: serde_json::Value,
}

fn heightfield_to_python(py: Python<'_>, mut h: Heightfield) -> PyResult<PyHeightfield> {
    let meta = volterra::info::heightfield_json(&h);
    let transform = volterra::info::geotransform(&h.georef());
    let elevations = std::mem::take(&mut h.elevations);
    Ok(PyHeightfield {
        array: shaped(py, elevations, vec![h.height, h.width], false)?,
        georef: h.georef(),
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
pub(crate) struct PyParticles {
    pub(crate) positions: Py<PyAny>,
    pub(crate) arrays: Vec<(String, Py<PyAny>)>,
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
pub(crate) fn read(
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
pub(crate) fn list_series(py: Python<'_>, directory: PathBuf, max_memory: Option<&Bound<'_, PyAny>>) -> PyResult<Py<PyAny>> {
    let limits = limits_of(max_memory)?;
    let found = py.detach(|| dicom::list_series(&directory, &limits)).map_err(py_error)?;
    let json = serde_json::to_value(&found).map_err(|e| PyValueError::new_err(e.to_string()))?;
    to_python(py, &json)
}
