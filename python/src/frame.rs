//! `Frame`: what a render returns — colour, depth and statistics as numpy arrays and
//! dicts, saved as the CLI saves it (EXR or PNG) and shown inline in Jupyter.

use crate::{py_error, shaped, to_python};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyBytes;
use std::path::PathBuf;
use volterra::render::Frame;

/// A rendered image: `rgba` premultiplied linear RGBA over a transparent background,
/// `depth` the distance along each pixel's ray to what its renderer calls the surface,
/// `stats` what the CLI prints about the render.
#[pyclass(module = "volterra", name = "Frame", frozen)]
pub struct PyFrame {
    frame: Frame,
    background: [f64; 3],
    exposure: f64,
}

impl PyFrame {
    pub fn new(frame: Frame, background: [f64; 3], exposure: f64) -> PyFrame {
        PyFrame { frame, background, exposure }
    }

    /// The image `save` writes as EXR.
    pub fn to_image(&self) -> volterra_formats::FloatImage {
        self.frame.to_image(self.background)
    }
}

#[pymethods]
impl PyFrame {
    #[getter]
    fn width(&self) -> usize {
        self.frame.width
    }
    #[getter]
    fn height(&self) -> usize {
        self.frame.height
    }
    /// Premultiplied linear RGBA, float32, shape (height, width, 4), the top row first;
    /// transparent where nothing was drawn (the background is not in it).
    #[getter]
    fn rgba(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        let values: Vec<f32> = self.frame.rgba.iter().flatten().copied().collect();
        shaped(py, values, vec![self.frame.height, self.frame.width, 4], false)
    }
    /// Linear RGB over the scene's background, float32, shape (height, width, 3): what the
    /// EXR's R, G, B channels hold.
    #[getter]
    fn rgb(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        let bg = self.background.map(|c| c as f32);
        let values: Vec<f32> =
            self.frame.rgba.iter().flat_map(|p| std::array::from_fn::<f32, 3, _>(|k| p[k] + (1.0 - p[3]) * bg[k])).collect();
        shaped(py, values, vec![self.frame.height, self.frame.width, 3], false)
    }
    /// Distance along each pixel's ray, float32, shape (height, width); inf where nothing.
    #[getter]
    fn depth(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        shaped(py, self.frame.depth.clone(), vec![self.frame.height, self.frame.width], false)
    }
    /// The renderer(s), seconds, counters, notes, and each node's load, preparation and
    /// render seconds (`volterra render` prints the same).
    #[getter]
    fn stats(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        let s = &self.frame.stats;
        let counters: serde_json::Map<String, serde_json::Value> =
            s.counters.iter().map(|(k, v)| (k.clone(), serde_json::json!(v))).collect();
        let nodes: Vec<serde_json::Value> = s
            .nodes
            .iter()
            .map(|t| serde_json::json!({"node": t.node, "renderer": t.renderer, "load": t.load, "prepare": t.prepare, "render": t.render}))
            .collect();
        let v = serde_json::json!({
            "renderer": s.renderer, "seconds": s.seconds, "counters": counters, "notes": s.notes, "nodes": nodes,
        });
        to_python(py, &v)
    }
    /// Writes the frame as `volterra render` does: `.exr` (R, G, B over the background, A,
    /// Z and any extra channels, linear) or `.png` (sRGB preview with the exposure and a
    /// scalar bar per colour map); written to a temporary file and renamed.
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        let lower = path.to_string_lossy().to_ascii_lowercase();
        let f = &self.frame;
        py.detach(|| {
            if lower.ends_with(".exr") {
                Ok(volterra_formats::exr_io::write_exr(&path, &self.to_image()))
            } else if lower.ends_with(".png") {
                Ok(volterra_formats::image::write_png_preview(&path, f.width, f.height, &f.preview_rgba(self.background, self.exposure)))
            } else {
                Err(format!("{}: unsupported output format (a frame saves as .exr or .png)", path.display()))
            }
        })
        .map_err(PyValueError::new_err)?
        .map_err(py_error)
    }
    /// The PNG preview's bytes (Jupyter shows a frame inline through this).
    fn _repr_png_<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyBytes>> {
        let f = &self.frame;
        let bytes = volterra_formats::image::png_preview_bytes(f.width, f.height, &f.preview_rgba(self.background, self.exposure))
            .map_err(PyValueError::new_err)?;
        Ok(PyBytes::new(py, &bytes))
    }
    fn __repr__(&self) -> String {
        format!(
            "<volterra.Frame {}×{} by {} in {:.3} s>",
            self.frame.width, self.frame.height, self.frame.stats.renderer, self.frame.stats.seconds
        )
    }
}
