//! The base's drive from the Python layer: a pivot axis (`Axis`) and a cart force
//! (`CartForce`), each a built-in evaluated in Rust or a Python function called back with the
//! GIL (from any thread: a batch may call it from its workers). A Python function's own
//! exception is kept in the run's error slot, to re-raise.
use std::sync::{Arc, Mutex};

use multipendulum_core as core;
use pyo3::prelude::*;

use core::{Builtin, Error, Interp};

use crate::{to_py, vec_out, InputError};

/// Where a callback's exception waits to be re-raised (shared with the events').
pub(crate) type Errors = Arc<Mutex<Option<PyErr>>>;

fn keep(errors: &Errors, e: PyErr, t: f64) -> Error {
    *errors.lock().unwrap_or_else(|p| p.into_inner()) = Some(e);
    Error::Torque { t }
}

/// The kept exception, if a callback raised one.
pub(crate) fn take(errors: &Errors) -> Option<PyErr> {
    errors.lock().unwrap_or_else(|p| p.into_inner()).take()
}

/// A user function's own exception as an `mp.InputError` naming the function and the time, the
/// original kept as its cause; Ctrl-C and other exceptions outside `Exception` pass unchanged.
fn raised(py: Python<'_>, e: PyErr, what: &str, t: f64) -> PyErr {
    if !e.is_instance_of::<pyo3::exceptions::PyException>(py) {
        return e;
    }
    let value = e.value(py).repr().map(|r| r.to_string()).unwrap_or_default();
    let wrapped = InputError::new_err(format!("{what} raised {value} at t = {t}"));
    wrapped.set_cause(py, Some(e));
    wrapped
}

struct AxisCall {
    f: Py<PyAny>,
    name: &'static str,
    errors: Errors,
}

impl core::AxisFn for AxisCall {
    fn eval(&self, t: f64) -> core::Result<[f64; 3]> {
        Python::attach(|py| {
            let r = self.f.call1(py, (t,)).map_err(|e| raised(py, e, &format!("the pivot {} function", self.name), t)).and_then(|v| {
                let bad = || {
                    InputError::new_err(format!(
                        "the pivot {} function must return (position, velocity, acceleration), 3 finite numbers, got {} at t = {t}",
                        self.name,
                        v.bind(py).repr().map(|r| r.to_string()).unwrap_or_default()
                    ))
                };
                let a: Vec<f64> = v.extract(py).map_err(|_| bad())?;
                if a.len() != 3 || !a.iter().all(|x| x.is_finite()) {
                    return Err(bad());
                }
                Ok([a[0], a[1], a[2]])
            });
            r.map_err(|e| keep(&self.errors, e, t))
        })
    }
}

struct ForceCall {
    f: Py<PyAny>,
    errors: Errors,
}

impl core::ForceFn for ForceCall {
    fn eval(&self, t: f64, state: &[f64]) -> core::Result<f64> {
        Python::attach(|py| {
            let r = self.f.call1(py, (t, vec_out(py, state.to_vec()))).and_then(|v| match v.extract::<f64>(py) {
                Ok(x) if x.is_finite() => Ok(x),
                _ => Err(InputError::new_err(format!(
                    "the cart force function must return one finite number, got {} at t = {t}",
                    v.bind(py).repr().map(|r| r.to_string()).unwrap_or_default()
                ))),
            });
            r.map_err(|e| keep(&self.errors, e, t))
        })
    }
}

enum AxisKind {
    Fixed(f64),
    Sinusoid(f64, f64, f64, f64),
    Spline(Vec<f64>, Vec<f64>),
    Function(Py<PyAny>),
}

/// One coordinate of a prescribed pivot motion, as the Python layer hands it to the core.
#[pyclass(module = "multipendulum._core", frozen, name = "Axis")]
pub(crate) struct PyAxis {
    kind: AxisKind,
}

#[pymethods]
impl PyAxis {
    #[staticmethod]
    fn fixed(x: f64) -> Self {
        PyAxis { kind: AxisKind::Fixed(x) }
    }
    /// `offset + amplitude sin(frequency t + phase)`.
    #[staticmethod]
    fn sinusoid(amplitude: f64, frequency: f64, phase: f64, offset: f64) -> Self {
        PyAxis { kind: AxisKind::Sinusoid(amplitude, frequency, phase, offset) }
    }
    /// The natural cubic spline through `(t, x)`.
    #[staticmethod]
    fn spline(t: Vec<f64>, x: Vec<f64>) -> Self {
        PyAxis { kind: AxisKind::Spline(t, x) }
    }
    /// `f(t) -> (position, velocity, acceleration)`.
    #[staticmethod]
    fn function(f: Py<PyAny>) -> Self {
        PyAxis { kind: AxisKind::Function(f) }
    }
    fn __repr__(&self) -> &'static str {
        match self.kind {
            AxisKind::Fixed(_) => "Axis.fixed",
            AxisKind::Sinusoid(..) => "Axis.sinusoid",
            AxisKind::Spline(..) => "Axis.spline",
            AxisKind::Function(_) => "Axis.function",
        }
    }
}

impl PyAxis {
    fn core(&self, py: Python<'_>, name: &'static str, errors: &Errors) -> PyResult<core::Axis> {
        let r = match &self.kind {
            AxisKind::Fixed(x) => core::Axis::fixed(name, *x),
            AxisKind::Sinusoid(a, f, p, o) => core::Axis::sinusoid(name, *a, *f, *p, *o),
            AxisKind::Spline(t, x) => core::Axis::spline(name, t.clone(), x.clone()),
            AxisKind::Function(f) => Ok(core::Axis::Function(Arc::new(AxisCall { f: f.clone_ref(py), name, errors: errors.clone() }))),
        };
        r.map_err(|e| to_py(py, e))
    }
}

/// The core's pivot of two axes.
pub(crate) fn pivot(py: Python<'_>, axes: Option<(PyRef<'_, PyAxis>, PyRef<'_, PyAxis>)>, errors: &Errors) -> PyResult<Option<core::Pivot>> {
    axes.map(|(x, y)| Ok(core::Pivot { x: x.core(py, "x", errors)?, y: y.core(py, "y", errors)? })).transpose()
}

enum ForceKind {
    Constant(f64),
    Sinusoid(f64, f64, f64, f64),
    Table(Vec<f64>, Vec<f64>, Interp),
    Function(Py<PyAny>),
}

/// The horizontal force on a cart, as the Python layer hands it to the core.
#[pyclass(module = "multipendulum._core", frozen, name = "CartForce")]
pub(crate) struct PyCartForce {
    kind: ForceKind,
}

#[pymethods]
impl PyCartForce {
    #[staticmethod]
    fn constant(value: f64) -> Self {
        PyCartForce { kind: ForceKind::Constant(value) }
    }
    #[staticmethod]
    fn sinusoid(amplitude: f64, frequency: f64, phase: f64, offset: f64) -> Self {
        PyCartForce { kind: ForceKind::Sinusoid(amplitude, frequency, phase, offset) }
    }
    /// Samples `values` at `t`, interpolated `"linear"` or `"cubic"`.
    #[staticmethod]
    fn table(t: Vec<f64>, values: Vec<f64>, kind: &str) -> PyResult<Self> {
        let interp = match kind {
            "linear" => Interp::Linear,
            "cubic" => Interp::Cubic,
            other => return Err(InputError::new_err(format!("kind must be \"linear\" or \"cubic\", got {other:?}"))),
        };
        Ok(PyCartForce { kind: ForceKind::Table(t, values, interp) })
    }
    /// `f(t, state) -> float`, `state = (x, theta_1..theta_N, v, omega_1..omega_N)`.
    #[staticmethod]
    fn function(f: Py<PyAny>) -> Self {
        PyCartForce { kind: ForceKind::Function(f) }
    }
    fn __repr__(&self) -> &'static str {
        match self.kind {
            ForceKind::Constant(_) => "CartForce.constant",
            ForceKind::Sinusoid(..) => "CartForce.sinusoid",
            ForceKind::Table(..) => "CartForce.table",
            ForceKind::Function(_) => "CartForce.function",
        }
    }
}

/// The core's cart force.
pub(crate) fn force(py: Python<'_>, spec: Option<PyRef<'_, PyCartForce>>, errors: &Errors) -> PyResult<Option<core::Force>> {
    let Some(spec) = spec else { return Ok(None) };
    let b = match &spec.kind {
        ForceKind::Constant(v) => Builtin::constant(1, vec![*v]),
        ForceKind::Sinusoid(a, f, p, o) => Builtin::sinusoid(1, vec![*a], vec![*f], vec![*p], vec![*o]),
        ForceKind::Table(t, v, interp) => Builtin::table(1, t.clone(), v.clone(), *interp),
        ForceKind::Function(f) => return Ok(Some(core::Force::Function(Arc::new(ForceCall { f: f.clone_ref(py), errors: errors.clone() })))),
    };
    // (The tables are the torques'; the message is about the force.)
    let b = b.map_err(|e| to_py(py, Error::input(format!("cart_force: {}", e.to_string().replace("a torque table", "a table")))))?;
    Ok(Some(core::Force::Builtin(b)))
}

/// `(position, velocity, acceleration)` of an axis at each of `t` (3 numbers per time).
#[pyfunction]
fn axis_eval<'py>(py: Python<'py>, axis: PyRef<'py, PyAxis>, t: Vec<f64>) -> PyResult<Bound<'py, numpy::PyArray1<f64>>> {
    let errors = Errors::default();
    let a = axis.core(py, "axis", &errors)?;
    let mut out = Vec::with_capacity(3 * t.len());
    for &s in &t {
        match a.eval(s) {
            Ok(v) => out.extend_from_slice(&v),
            Err(e) => return Err(take(&errors).unwrap_or_else(|| to_py(py, e))),
        }
    }
    Ok(vec_out(py, out))
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(axis_eval, m)?)?;
    m.add_class::<PyAxis>()?;
    m.add_class::<PyCartForce>()
}
