//! The core's facts as module attributes: `METHODS`, `METHOD_INFO`, `DEFAULTS`, `LIMITS`,
//! `FORMS`, and the one memory check (`check_memory`). Published as the core states them.
use multipendulum_core as core;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use core::facts;

use crate::to_py;

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    let methods = facts::methods();
    m.add("METHODS", methods.iter().map(|f| f.name).collect::<Vec<_>>())?;
    let info = PyDict::new(py);
    for f in &methods {
        let d = PyDict::new(py);
        d.set_item("order", f.order)?;
        d.set_item("symplectic", f.symplectic)?;
        d.set_item("symplectic_when", f.symplectic_when)?;
        d.set_item("implicit", f.implicit)?;
        d.set_item("adaptive", f.adaptive)?;
        d.set_item("needs_dt", f.needs_dt)?;
        d.set_item("forms", f.forms.clone())?;
        info.set_item(f.name, d)?;
    }
    m.add("METHOD_INFO", info)?;
    let defaults = PyDict::new(py);
    for (name, value, _) in facts::defaults() {
        defaults.set_item(name, value)?;
    }
    defaults.set_item("method", facts::default_method())?;
    m.add("DEFAULTS", defaults)?;
    let limits = PyDict::new(py);
    for (name, value, _) in facts::limits() {
        limits.set_item(name, value)?;
    }
    m.add("LIMITS", limits)?;
    m.add("FORMS", facts::forms())?;
    m.add("SENSITIVITIES", core::Input::NAMES.to_vec())?;
    let algorithms = PyDict::new(py);
    for (name, max_links) in facts::algorithms() {
        algorithms.set_item(name, max_links)?;
    }
    m.add("ALGORITHMS", algorithms)?;
    m.add_function(wrap_pyfunction!(check_memory, m)?)?;
    Ok(())
}

/// Refuse a request needing `bytes` that would not fit in memory; see
/// `multipendulum_core::memory::check` (the one place the limit lives).
#[pyfunction]
fn check_memory(py: Python<'_>, bytes: f64, what: &str, advice: &str) -> PyResult<()> {
    core::memory::check(bytes, what, advice).map_err(|e| to_py(py, e))
}
