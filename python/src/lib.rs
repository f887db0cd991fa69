//! volterra._volterra: the Rust side of the Python package (python/volterra/). Reading:
//! `read` opens any file the CLI reads into a `Volume`, `Heightfield` or `Particles` whose
//! arrays are numpy arrays over the reader's own buffers (no copy where the values are the
//! stored ones); `list_series` lists a DICOM directory's series. The GIL is released while
//! a file is read. Errors are the CLI's one-line messages, raised as exceptions that
//! subclass ValueError, OSError or MemoryError (by what went wrong).

mod data;
mod dem;
mod frame;
mod input;
mod scene;

use numpy::npyffi::NPY_ORDER;
use numpy::{PyArray1, PyArrayMethods};
use pyo3::create_exception;
use pyo3::exceptions::{PyKeyboardInterrupt, PyMemoryError, PyOSError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use volterra_formats::{ErrorKind, FormatError as ReaderError, Limits};

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
create_exception!(
    volterra,
    SceneError,
    PyValueError,
    "A scene that does not check: an unknown key, a value out of range, a node or file that is not there."
);

/// The exception a reader's error of `kind` raises, with `message`.
fn exception_of(kind: ErrorKind, message: String) -> PyErr {
    match kind {
        ErrorKind::Io => ReadError::new_err(message),
        ErrorKind::Invalid => FormatError::new_err(message),
        ErrorKind::Unsupported => UnsupportedError::new_err(message),
        ErrorKind::TooLarge => MemoryLimitError::new_err(message),
        ErrorKind::Ambiguous => AmbiguousError::new_err(message),
    }
}

/// A reader's error as the exception of its kind, with the CLI's one-line message.
fn py_error(e: ReaderError) -> PyErr {
    exception_of(e.kind, e.to_string())
}

/// A scene's or a render's error: a reader's as the exception of its kind, a cancelled
/// render as KeyboardInterrupt, others as SceneError; the message is the whole chain on
/// one line, as the CLI prints it.
fn scene_error(e: anyhow::Error) -> PyErr {
    let message = format!("{e:#}");
    if e.chain().any(|c| c.is::<volterra::render::driver::Cancelled>()) {
        return PyKeyboardInterrupt::new_err(message);
    }
    match e.chain().find_map(|c| c.downcast_ref::<ReaderError>()) {
        Some(r) => exception_of(r.kind, message),
        None => SceneError::new_err(message),
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

#[pymodule]
fn _volterra(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add_function(wrap_pyfunction!(data::read, m)?)?;
    m.add_function(wrap_pyfunction!(data::list_series, m)?)?;
    m.add_class::<data::PyVolume>()?;
    m.add_class::<data::PyHeightfield>()?;
    m.add_class::<data::PyParticles>()?;
    m.add_function(wrap_pyfunction!(dem::dem_product, m)?)?;
    m.add_function(wrap_pyfunction!(dem::dem_color_relief, m)?)?;
    m.add_function(wrap_pyfunction!(dem::dem_contours, m)?)?;
    m.add_function(wrap_pyfunction!(dem::compare, m)?)?;
    m.add_class::<scene::PyScene>()?;
    m.add_class::<scene::PyCamera>()?;
    m.add_class::<scene::PyFrames>()?;
    m.add_class::<frame::PyFrame>()?;
    m.add("FormatError", py.get_type::<FormatError>())?;
    m.add("UnsupportedError", py.get_type::<UnsupportedError>())?;
    m.add("AmbiguousError", py.get_type::<AmbiguousError>())?;
    m.add("ReadError", py.get_type::<ReadError>())?;
    m.add("MemoryLimitError", py.get_type::<MemoryLimitError>())?;
    m.add("SceneError", py.get_type::<SceneError>())?;
    Ok(())
}
