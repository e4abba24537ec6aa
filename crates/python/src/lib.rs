//! Python bindings of multipendulum-core: convert arguments, call the core, map its errors. No
//! physics and no orchestration here; split by domain:
//! - [`chain`]: the `Chain` class (mass matrix, accelerations, energies, the Jacobian);
//! - [`torque`]: torques from the Python layer's specs, and Python torque functions;
//! - [`run`]: `simulate` (single runs, batches, events, checkpoints);
//! - [`stepper`]: `Steppers`, copies of a chain stepped with held inputs (the environments');
//! - [`chaos`]: Lyapunov exponents and flip times;
//! - [`facts`]: the core's methods, defaults and limits, published as they are.
//!
//! Arrays cross as flat, C-contiguous float64 (the Python layer reshapes); results are moved
//! into NumPy without copying. The GIL is released while Rust integrates, except when a Python
//! function (a torque, an event) must be called back; long work runs under [`interruptible`],
//! so Ctrl-C reaches it.
// The crate's documentation is for its developers (`cargo doc --document-private-items`, as
// `make lint` builds it): its links to private items are meant, and resolve there.
#![allow(rustdoc::private_intra_doc_links)]
use std::time::Duration;

use multipendulum_core as core;
use numpy::{PyArray1, PyReadonlyArray1};
use pyo3::create_exception;
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;

use core::watch::{supervise, Watch};
use core::Error;

mod base;
mod chain;
mod chaos;
mod facts;
mod run;
mod stepper;
mod torque;

create_exception!(multipendulum, InputError, PyValueError, "Bad input: the message names the field, the index, the value and what was expected.");
create_exception!(multipendulum, IntegrationError, PyRuntimeError, "An integration could not continue; `.t` is the time it failed.");

/// The one place where core errors become Python exceptions.
pub(crate) fn to_py(py: Python<'_>, e: Error) -> PyErr {
    match e {
        Error::Input(m) => InputError::new_err(m),
        Error::Interrupted { .. } => pyo3::exceptions::PyKeyboardInterrupt::new_err(e.to_string()),
        Error::Integration { t, .. } | Error::Torque { t } => {
            let err = IntegrationError::new_err(e.to_string());
            let _ = err.value(py).setattr("t", t);
            err
        }
    }
}

/// A one-dimensional NumPy array returned to Python.
pub(crate) type Array<'py, T = f64> = Bound<'py, PyArray1<T>>;

pub(crate) fn slice<'a>(name: &str, a: &'a PyReadonlyArray1<'_, f64>) -> PyResult<&'a [f64]> {
    a.as_slice().map_err(|_| InputError::new_err(format!("{name} must be a C-contiguous float64 array")))
}

pub(crate) fn vec_out(py: Python<'_>, v: Vec<f64>) -> Bound<'_, PyArray1<f64>> {
    PyArray1::from_vec(py, v)
}

/// Run `work` without the GIL on another thread, while this one checks for Ctrl-C and calls
/// `progress(fraction)` about ten times a second. A signal (or an exception from `progress`)
/// stops the work through `watch` and is raised here once the work has wound down. Work the
/// core calls `short` runs here, without the watcher thread.
pub(crate) fn interruptible<R: Send>(py: Python<'_>, watch: &Watch, progress: Option<&Py<PyAny>>, short: bool, work: impl FnOnce() -> R + Send) -> PyResult<R> {
    if short {
        return Ok(py.detach(work));
    }
    let mut raised: Option<PyErr> = None;
    let out = py.detach(|| {
        supervise(watch, Duration::from_millis(100), work, |fraction| {
            Python::attach(|py| {
                let r = py.check_signals().and_then(|()| match progress {
                    Some(cb) => cb.call1(py, (fraction,)).map(drop),
                    None => Ok(()),
                });
                match r {
                    Ok(()) => false,
                    Err(e) => {
                        raised = Some(e);
                        true
                    }
                }
            })
        })
    });
    match raised {
        Some(e) => Err(e),
        None => Ok(out),
    }
}

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    // The version of the compiled core: what checkpoint archives and benchmarks record.
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("InputError", m.py().get_type::<InputError>())?;
    m.add("IntegrationError", m.py().get_type::<IntegrationError>())?;
    torque::register(m)?;
    base::register(m)?;
    chain::register(m)?;
    run::register(m)?;
    stepper::register(m)?;
    chaos::register(m)?;
    facts::register(m)?;
    Ok(())
}
