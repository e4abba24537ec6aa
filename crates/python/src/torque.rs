//! Torques from the Python layer's normalised specs (built-ins evaluated in Rust), and Python
//! torque functions called back with the GIL.
use std::cell::RefCell;

use multipendulum_core as core;
use pyo3::prelude::*;
use pyo3::types::PyTuple;

use core::{Builtin, Error, Interp, Joint, TorqueSource};

use crate::{to_py, vec_out, InputError};

/// A Python torque function `f(t)` or `f(t, theta, omega)`; its exception is kept to re-raise.
pub(crate) struct Callback<'py> {
    f: Bound<'py, PyAny>,
    with_state: bool,
    error: &'py RefCell<Option<PyErr>>,
}

impl TorqueSource for Callback<'_> {
    fn eval(&mut self, t: f64, theta: &[f64], omega: &[f64], out: &mut [f64]) -> core::Result<()> {
        let py = self.f.py();
        let result = if self.with_state {
            self.f.call1((t, vec_out(py, theta.to_vec()), vec_out(py, omega.to_vec())))
        } else {
            self.f.call1((t,))
        };
        let fail = |err: PyErr| {
            *self.error.borrow_mut() = Some(err);
            Error::Torque { t }
        };
        let value = result.map_err(fail)?;
        let arr: Vec<f64> = match value.extract::<Vec<f64>>() {
            Ok(v) => v,
            Err(_) => match value.extract::<f64>() {
                Ok(x) if out.len() == 1 => vec![x],
                _ => {
                    return Err(fail(InputError::new_err(format!(
                        "the torque function must return {} numbers (one per link), got {}",
                        out.len(),
                        value.repr().map(|r| r.to_string()).unwrap_or_default()
                    ))))
                }
            },
        };
        if arr.len() != out.len() {
            return Err(fail(InputError::new_err(format!(
                "the torque function must return {} numbers (one per link), got {} at t = {t}",
                out.len(),
                arr.len()
            ))));
        }
        if let Some(i) = arr.iter().position(|v| !v.is_finite()) {
            return Err(fail(InputError::new_err(format!("the torque function returned torque[{i}] = {} at t = {t}", arr[i]))));
        }
        out.copy_from_slice(&arr);
        Ok(())
    }
}

/// Build a built-in torque from the Python layer's normalised spec:
/// `("constant", values)`, `("sinusoid", amplitude, frequency, phase, offset)`,
/// `("table", times, values, "linear"|"cubic")`.
pub(crate) fn builtin(n: usize, spec: &Bound<'_, PyTuple>) -> PyResult<Builtin> {
    let kind: String = spec.get_item(0)?.extract()?;
    let arr = |i: usize| -> PyResult<Vec<f64>> { spec.get_item(i)?.extract() };
    let py = spec.py();
    match kind.as_str() {
        "constant" => Builtin::constant(n, arr(1)?),
        "sinusoid" => Builtin::sinusoid(n, arr(1)?, arr(2)?, arr(3)?, arr(4)?),
        "table" => {
            let interp = match spec.get_item(3)?.extract::<String>()?.as_str() {
                "linear" => Interp::Linear,
                "cubic" => Interp::Cubic,
                other => return Err(InputError::new_err(format!("kind must be \"linear\" or \"cubic\", got {other:?}"))),
            };
            Builtin::table(n, arr(1)?, arr(2)?, interp)
        }
        other => return Err(InputError::new_err(format!("unknown torque kind {other:?}"))),
    }
    .map_err(|e| to_py(py, e))
}

/// Any torque the Python layer can pass, in either convention.
pub(crate) enum AnyTorque<'py> {
    Builtin(Builtin),
    JointBuiltin(Joint<Builtin>),
    Call(Callback<'py>),
    JointCall(Joint<Callback<'py>>),
}

impl TorqueSource for AnyTorque<'_> {
    fn active(&self) -> bool {
        match self {
            AnyTorque::Builtin(b) => b.active(),
            AnyTorque::JointBuiltin(b) => b.active(),
            _ => true,
        }
    }
    fn eval(&mut self, t: f64, theta: &[f64], omega: &[f64], out: &mut [f64]) -> core::Result<()> {
        match self {
            AnyTorque::Builtin(b) => b.eval(t, theta, omega, out),
            AnyTorque::JointBuiltin(b) => b.eval(t, theta, omega, out),
            AnyTorque::Call(c) => c.eval(t, theta, omega, out),
            AnyTorque::JointCall(c) => c.eval(t, theta, omega, out),
        }
    }
}

/// `spec`: None, a built-in tuple, or `("callable", f, with_state)`; `joint` selects the
/// joint-motor convention.
pub(crate) fn torque<'py>(
    n: usize,
    spec: Option<&Bound<'py, PyTuple>>,
    joint: bool,
    error: &'py RefCell<Option<PyErr>>,
) -> PyResult<AnyTorque<'py>> {
    let Some(spec) = spec else { return Ok(AnyTorque::Builtin(Builtin::None)) };
    if spec.get_item(0)?.extract::<String>()? == "callable" {
        let cb = Callback { f: spec.get_item(1)?, with_state: spec.get_item(2)?.extract()?, error };
        return Ok(if joint { AnyTorque::JointCall(Joint(cb)) } else { AnyTorque::Call(cb) });
    }
    let b = builtin(n, spec)?;
    Ok(if joint { AnyTorque::JointBuiltin(Joint(b)) } else { AnyTorque::Builtin(b) })
}

/// Re-raise a torque function's own exception where the core reported it.
pub(crate) fn torque_error(py: Python<'_>, e: Error, slot: &RefCell<Option<PyErr>>) -> PyErr {
    match (&e, slot.borrow_mut().take()) {
        (Error::Torque { .. }, Some(err)) => err,
        _ => to_py(py, e),
    }
}

/// A built-in generalized torque for the chaos kernels (which run without the GIL).
pub(crate) fn builtin_only(py: Python<'_>, n: usize, spec: Option<&Bound<'_, PyTuple>>, what: &str) -> PyResult<Builtin> {
    let _ = py;
    match spec {
        None => Ok(Builtin::None),
        Some(spec) if spec.get_item(0)?.extract::<String>()? == "callable" => Err(InputError::new_err(format!(
            "{what} takes built-in torques only (constant, Sinusoid, Table), not a Python function"
        ))),
        Some(spec) => builtin(n, spec),
    }
}

