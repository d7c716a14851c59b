//! psneus from Python (`import psneus`): the scene loaders, the probability-guided estimator
//! for any backbone (its SDF a Python callable), the trainer and the DTU-protocol evaluation.
//!
//! The Python layer (`python/psneus/__init__.py`) re-exports this module, `_psneus`; the type
//! stubs are `python/psneus/_psneus.pyi`. Values are typed here, once: Python objects become
//! the library's types (keyword options become typed TOML values of the configuration's keys,
//! never text to parse). Library errors become `OSError` when an I/O error caused them, else
//! `ValueError`, with the library's message (file and problem named). No `unsafe` is written
//! here; what PyO3's macros generate is theirs.

mod convert;
mod estimator;
mod evaluate;
mod field;
mod scene;
mod train;

use pyo3::prelude::*;

/// The extension module `psneus._psneus`.
#[pymodule]
fn _psneus(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_class::<scene::Scene>()?;
    m.add_class::<estimator::Estimator>()?;
    m.add_class::<field::Sphere>()?;
    m.add_function(wrap_pyfunction!(scene::load_scene, m)?)?;
    m.add_function(wrap_pyfunction!(train::train, m)?)?;
    m.add_function(wrap_pyfunction!(evaluate::evaluate_mesh, m)?)?;
    m.add_function(wrap_pyfunction!(field::extract_mesh, m)?)?;
    m.add_function(wrap_pyfunction!(train::default_config, m)?)?;
    Ok(())
}
