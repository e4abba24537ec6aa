//! Torques from the Python layer's normalised specs (built-ins evaluated in Rust), and Python
//! torque functions called back with the GIL.
use std::cell::RefCell;

use multipendulum_core as core;
use pyo3::prelude::*;

use core::{Builtin, Error, Interp, Joint, Timed, TorqueSource};

use crate::{to_py, vec_out, InputError};

/// A Python torque function `f(t)` or `f(t, theta, omega)`; its exception is kept to re-raise.
pub(crate) struct Callback<'py> {
    f: Bound<'py, PyAny>,
    with_state: bool,
    error: &'py RefCell<Option<PyErr>>,
}

impl TorqueSource for Callback<'_> {
    fn uses_state(&self) -> bool {
        self.with_state
    }
    fn eval(&mut self, t: f64, theta: &[f64], omega: &[f64], out: &mut [f64]) -> core::Result<()> {
        let py = self.f.py();
        let result = if self.with_state { self.f.call1((t, vec_out(py, theta.to_vec()), vec_out(py, omega.to_vec()))) } else { self.f.call1((t,)) };
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

/// A torque as the Python layer hands it to the core: a built-in (evaluated in Rust) or a Python
/// function, in the generalized (`joint = False`) or the joint-motor convention. Checked against
/// the chain (its number of links) where it is used.
#[pyclass(module = "multipendulum._core", frozen, name = "Torque")]
pub(crate) struct PyTorque {
    kind: Kind,
    joint: bool,
}

enum Kind {
    Constant(Vec<f64>),
    Sinusoid { amplitude: Vec<f64>, frequency: Vec<f64>, phase: Vec<f64>, offset: Vec<f64> },
    Table { t: Vec<f64>, values: Vec<f64>, interp: Interp },
    Function { f: Py<PyAny>, with_state: bool },
}

#[pymethods]
impl PyTorque {
    /// Constant generalized (or joint) torques, one per link.
    #[staticmethod]
    #[pyo3(signature = (values, *, joint=false))]
    fn constant(values: Vec<f64>, joint: bool) -> Self {
        PyTorque { kind: Kind::Constant(values), joint }
    }

    /// `offset + amplitude sin(frequency t + phase)`, each one value per link.
    #[staticmethod]
    #[pyo3(signature = (amplitude, frequency, phase, offset, *, joint=false))]
    fn sinusoid(amplitude: Vec<f64>, frequency: Vec<f64>, phase: Vec<f64>, offset: Vec<f64>, joint: bool) -> Self {
        PyTorque { kind: Kind::Sinusoid { amplitude, frequency, phase, offset }, joint }
    }

    /// Tabulated torques: `values` row-major `(len(t), N)`, interpolated `"linear"` or `"cubic"`.
    #[staticmethod]
    #[pyo3(signature = (t, values, kind, *, joint=false))]
    fn table(t: Vec<f64>, values: Vec<f64>, kind: &str, joint: bool) -> PyResult<Self> {
        let interp = match kind {
            "linear" => Interp::Linear,
            "cubic" => Interp::Cubic,
            other => return Err(InputError::new_err(format!("kind must be \"linear\" or \"cubic\", got {other:?}"))),
        };
        Ok(PyTorque { kind: Kind::Table { t, values, interp }, joint })
    }

    /// A Python function `f(t)` (`with_state = False`) or `f(t, theta, omega)` returning N values.
    #[staticmethod]
    #[pyo3(signature = (f, *, with_state, joint=false))]
    fn function(f: Py<PyAny>, with_state: bool, joint: bool) -> Self {
        PyTorque { kind: Kind::Function { f, with_state }, joint }
    }

    #[getter]
    fn joint(&self) -> bool {
        self.joint
    }

    /// `"constant"`, `"sinusoid"`, `"table"` or `"function"`.
    #[getter]
    fn kind(&self) -> &'static str {
        match self.kind {
            Kind::Constant(_) => "constant",
            Kind::Sinusoid { .. } => "sinusoid",
            Kind::Table { .. } => "table",
            Kind::Function { .. } => "function",
        }
    }

    fn __repr__(&self) -> String {
        format!("Torque.{}(joint={})", self.kind(), if self.joint { "True" } else { "False" })
    }
}

impl PyTorque {
    /// The core's built-in for an `n`-link chain; `None` for a Python function.
    fn builtin(&self, py: Python<'_>, n: usize) -> PyResult<Option<Builtin>> {
        let b = match &self.kind {
            Kind::Constant(v) => Builtin::constant(n, v.clone()),
            Kind::Sinusoid { amplitude, frequency, phase, offset } => Builtin::sinusoid(n, amplitude.clone(), frequency.clone(), phase.clone(), offset.clone()),
            Kind::Table { t, values, interp } => Builtin::table(n, t.clone(), values.clone(), *interp),
            Kind::Function { .. } => return Ok(None),
        };
        b.map(Some).map_err(|e| to_py(py, e))
    }
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyTorque>()
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
    fn uses_state(&self) -> bool {
        match self {
            AnyTorque::Call(c) => c.uses_state(),
            AnyTorque::JointCall(c) => c.uses_state(),
            _ => false,
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

/// The torque a run or an evaluation uses; `error` keeps a Python function's own exception.
pub(crate) fn torque<'py>(py: Python<'py>, n: usize, spec: Option<&PyTorque>, error: &'py RefCell<Option<PyErr>>) -> PyResult<AnyTorque<'py>> {
    let Some(spec) = spec else { return Ok(AnyTorque::Builtin(Builtin::None)) };
    if let Kind::Function { f, with_state } = &spec.kind {
        let cb = Callback { f: f.bind(py).clone(), with_state: *with_state, error };
        return Ok(if spec.joint { AnyTorque::JointCall(Joint(cb)) } else { AnyTorque::Call(cb) });
    }
    let b = spec.builtin(py, n)?.unwrap_or(Builtin::None);
    Ok(if spec.joint { AnyTorque::JointBuiltin(Joint(b)) } else { AnyTorque::Builtin(b) })
}

/// Re-raise a torque function's own exception where the core reported it.
pub(crate) fn torque_error(py: Python<'_>, e: Error, slot: &RefCell<Option<PyErr>>) -> PyErr {
    match (&e, slot.borrow_mut().take()) {
        (Error::Torque { .. }, Some(err)) => err,
        _ => to_py(py, e),
    }
}

/// A torque of time alone for the SIMD lanes (no torque: a zero one); `None` for a Python
/// function, which they cannot call.
pub(crate) fn timed(py: Python<'_>, n: usize, spec: Option<&PyTorque>) -> PyResult<Option<Timed>> {
    let Some(spec) = spec else { return Ok(Some(Timed { builtin: Builtin::None, joint: false })) };
    Ok(spec.builtin(py, n)?.map(|builtin| Timed { builtin, joint: spec.joint }))
}

/// A built-in generalized torque for the chaos kernels (which run without the GIL).
pub(crate) fn builtin_only(py: Python<'_>, n: usize, spec: Option<&PyTorque>, what: &str) -> PyResult<Builtin> {
    match spec {
        None => Ok(Builtin::None),
        Some(PyTorque { joint: true, .. }) => Err(InputError::new_err(format!("{what} takes generalized torques (torque=), not joint torques"))),
        Some(spec) => spec
            .builtin(py, n)?
            .ok_or_else(|| InputError::new_err(format!("{what} takes built-in torques only (constant, Sinusoid, Table), not a Python function"))),
    }
}
