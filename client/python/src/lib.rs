//! The Python package `cbdam` (docs/PYTHON.md): the extension module `cbdam._cbdam`. Readers of
//! local and remote repositories ([`reader`], over [`source`]), builds and verification
//! ([`build`]), and the exceptions ([`errors`]); the pure-Python face (`read_masked`,
//! `to_xarray`) is in `python/cbdam/`.

mod build;
mod cache;
mod errors;
mod planet;
mod reader;
mod source;

use pyo3::prelude::*;

/// The extension module.
#[pymodule]
fn _cbdam(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("Error", py.get_type::<errors::Error>())?;
    m.add("CorruptError", py.get_type::<errors::CorruptError>())?;
    m.add("InputError", py.get_type::<errors::InputError>())?;
    m.add(
        "UnsupportedError",
        py.get_type::<errors::UnsupportedError>(),
    )?;
    m.add("NetworkError", py.get_type::<errors::NetworkError>())?;
    m.add("IoError", py.get_type::<errors::IoError>())?;
    m.add_class::<reader::Reader>()?;
    m.add_function(wrap_pyfunction!(reader::open, m)?)?;
    m.add_function(wrap_pyfunction!(build::build, m)?)?;
    m.add_function(wrap_pyfunction!(build::verify, m)?)?;
    Ok(())
}
