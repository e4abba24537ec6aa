//! Python bindings: convert arrays, call the core, map its errors. No physics here.
//!
//! Arrays cross as flat, C-contiguous float64 (the Python layer reshapes); results are moved
//! into NumPy without copying. The GIL is released while Rust integrates, except when a Python
//! torque function must be called back.
use std::cell::RefCell;
use std::time::{Duration, Instant};

use multipendulum_core as core;
use numpy::{PyArray1, PyReadonlyArray1};
use pyo3::create_exception;
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyTuple;

use core::{reference, Builtin, Chain as CoreChain, Error, Form, Interp, Joint, Method, Settings, TorqueSource, Workspace};

create_exception!(multipendulum, InputError, PyValueError, "Bad input: the message names the field, the index, the value and what was expected.");
create_exception!(multipendulum, IntegrationError, PyRuntimeError, "An integration could not continue; `.t` is the time it failed.");

/// The one place where core errors become Python exceptions.
fn to_py(py: Python<'_>, e: Error) -> PyErr {
    match e {
        Error::Input(m) => InputError::new_err(m),
        Error::Integration { t, .. } | Error::Torque { t } => {
            let err = IntegrationError::new_err(e.to_string());
            let _ = err.value(py).setattr("t", t);
            err
        }
    }
}

fn slice<'a>(name: &str, a: &'a PyReadonlyArray1<'_, f64>) -> PyResult<&'a [f64]> {
    a.as_slice().map_err(|_| InputError::new_err(format!("{name} must be a C-contiguous float64 array")))
}

fn vec_out(py: Python<'_>, v: Vec<f64>) -> Bound<'_, PyArray1<f64>> {
    PyArray1::from_vec(py, v)
}

/// A Python torque function `f(t)` or `f(t, theta, omega)`; its exception is kept to re-raise.
struct Callback<'py> {
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
fn builtin(n: usize, spec: &Bound<'_, PyTuple>) -> PyResult<Builtin> {
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
enum AnyTorque<'py> {
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
fn torque<'py>(
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
fn torque_error(py: Python<'_>, e: Error, slot: &RefCell<Option<PyErr>>) -> PyErr {
    match (&e, slot.borrow_mut().take()) {
        (Error::Torque { .. }, Some(err)) => err,
        _ => to_py(py, e),
    }
}

#[pyclass(module = "multipendulum._core", frozen, name = "Chain")]
struct PyChain {
    inner: CoreChain,
}

fn rows(name: &str, len: usize, n: usize) -> PyResult<usize> {
    if len % n != 0 || len == 0 {
        return Err(InputError::new_err(format!("{name} must have shape (..., {n}), got {len} numbers")));
    }
    Ok(len / n)
}

#[pymethods]
impl PyChain {
    #[new]
    #[pyo3(signature = (lengths, masses, com=None, inertia=None, g=9.81))]
    fn new(
        py: Python<'_>,
        lengths: Vec<f64>,
        masses: Vec<f64>,
        com: Option<Vec<f64>>,
        inertia: Option<Vec<f64>>,
        g: f64,
    ) -> PyResult<Self> {
        CoreChain::new(&lengths, &masses, com.as_deref(), inertia.as_deref(), g)
            .map(|inner| PyChain { inner })
            .map_err(|e| to_py(py, e))
    }

    #[staticmethod]
    #[pyo3(signature = (lengths, masses, g=9.81))]
    fn rods(py: Python<'_>, lengths: Vec<f64>, masses: Vec<f64>, g: f64) -> PyResult<Self> {
        CoreChain::rods(&lengths, &masses, g).map(|inner| PyChain { inner }).map_err(|e| to_py(py, e))
    }

    #[getter]
    fn n(&self) -> usize {
        self.inner.n()
    }
    #[getter]
    fn lengths<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec_out(py, self.inner.lengths().to_vec())
    }
    #[getter]
    fn masses<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec_out(py, self.inner.masses().to_vec())
    }
    #[getter]
    fn com<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec_out(py, self.inner.com().to_vec())
    }
    #[getter]
    fn inertia<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec_out(py, self.inner.inertia().to_vec())
    }
    #[getter]
    fn g(&self) -> f64 {
        self.inner.g()
    }

    /// Rows of flat `theta` -> rows of row-major N x N mass matrices.
    fn mass_matrix<'py>(&self, py: Python<'py>, theta: PyReadonlyArray1<'py, f64>) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let (c, theta) = (&self.inner, slice("theta", &theta)?);
        let n = c.n();
        let b = rows("theta", theta.len(), n)?;
        let mut out = vec![0.0; b * n * n];
        for (row, o) in theta.chunks(n).zip(out.chunks_mut(n * n)) {
            c.mass_matrix_into(row, o);
        }
        Ok(vec_out(py, out))
    }

    /// Accelerations of each row; `algorithm` is "recursive" (O(N)), "cholesky" or "cramer".
    #[pyo3(signature = (theta, omega, t, torque_spec, joint, algorithm))]
    fn accelerations<'py>(
        &self,
        py: Python<'py>,
        theta: PyReadonlyArray1<'py, f64>,
        omega: PyReadonlyArray1<'py, f64>,
        t: f64,
        torque_spec: Option<Bound<'py, PyTuple>>,
        joint: bool,
        algorithm: &str,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let c = &self.inner;
        let n = c.n();
        let (theta, omega) = (slice("theta", &theta)?, slice("omega", &omega)?);
        core::error::check_finite("theta", theta).map_err(|e| to_py(py, e))?;
        core::error::check_finite("omega", omega).map_err(|e| to_py(py, e))?;
        let b = rows("theta", theta.len(), n)?;
        let slot = RefCell::new(None);
        let mut src = torque(n, torque_spec.as_ref(), joint, &slot)?;
        let mut ws = Workspace::new(n);
        let (mut tau, mut out) = (vec![0.0; n], vec![0.0; b * n]);
        for i in 0..b {
            let (th, om) = (&theta[i * n..(i + 1) * n], &omega[i * n..(i + 1) * n]);
            if src.active() {
                src.eval(t, th, om, &mut tau).map_err(|e| torque_error(py, e, &slot))?;
            }
            let o = &mut out[i * n..(i + 1) * n];
            let singular = |s: core::Singular| to_py(py, Error::integration(t, s.reason()));
            match algorithm {
                "recursive" => c.accelerations_into(th, om, &tau, o, &mut ws).map_err(singular)?,
                "cholesky" => o.copy_from_slice(&reference::accelerations_cholesky(c, th, om, &tau).map_err(singular)?),
                "cramer" => o.copy_from_slice(&reference::accelerations_cramer(c, th, om, &tau).map_err(singular)?),
                other => {
                    return Err(InputError::new_err(format!(
                        "algorithm must be one of recursive, cholesky, cramer, got {other:?}"
                    )))
                }
            }
        }
        Ok(vec_out(py, out))
    }

    /// The exact Jacobian of the Lagrangian right-hand side `(omega, theta_ddot)` with respect to
    /// `(theta, omega)` (row-major 2N x 2N), from the variational equations; torques are taken as
    /// depending on time only.
    #[pyo3(signature = (theta, omega, t, torque_spec, joint))]
    fn jacobian<'py>(
        &self,
        py: Python<'py>,
        theta: Vec<f64>,
        omega: Vec<f64>,
        t: f64,
        torque_spec: Option<Bound<'py, PyTuple>>,
        joint: bool,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let c = &self.inner;
        let n = c.n();
        let err = |e| to_py(py, e);
        c.check_state("theta", &theta).map_err(err)?;
        c.check_state("omega", &omega).map_err(err)?;
        let slot = RefCell::new(None);
        let mut src = torque(n, torque_spec.as_ref(), joint, &slot)?;
        let mut ws = Workspace::new(n);
        let (mut tau, mut acc) = (vec![0.0; n], vec![0.0; n]);
        if src.active() {
            src.eval(t, &theta, &omega, &mut tau).map_err(|e| torque_error(py, e, &slot))?;
        }
        let singular = |s: core::Singular| to_py(py, Error::integration(t, s.reason()));
        c.accelerations_into(&theta, &omega, &tau, &mut acc, &mut ws).map_err(singular)?;
        let m = 2 * n;
        let mut jac = vec![0.0; m * m];
        let (mut dir, mut col, mut scratch) = (vec![0.0; m], vec![0.0; n], vec![0.0; 6 * n]);
        for j in 0..m {
            dir.fill(0.0);
            dir[j] = 1.0;
            c.tangent_accelerations_into(&theta, &omega, &acc, &dir[..n], &dir[n..], &mut col, &mut scratch, &mut ws)
                .map_err(singular)?;
            for i in 0..n {
                jac[i * m + j] = dir[n + i]; // d theta_dot / d(.) = d omega / d(.)
                jac[(n + i) * m + j] = col[i];
            }
        }
        Ok(vec_out(py, jac))
    }

    /// `(theta_dot, p_dot)` of Hamilton's equations for each row.
    #[pyo3(signature = (theta, p, t, torque_spec, joint))]
    fn hamilton<'py>(
        &self,
        py: Python<'py>,
        theta: PyReadonlyArray1<'py, f64>,
        p: PyReadonlyArray1<'py, f64>,
        t: f64,
        torque_spec: Option<Bound<'py, PyTuple>>,
        joint: bool,
    ) -> PyResult<(Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<f64>>)> {
        let c = &self.inner;
        let n = c.n();
        let (theta, p) = (slice("theta", &theta)?, slice("p", &p)?);
        let b = rows("theta", theta.len(), n)?;
        let slot = RefCell::new(None);
        let mut src = torque(n, torque_spec.as_ref(), joint, &slot)?;
        let mut ws = Workspace::new(n);
        let (mut td, mut pd) = (vec![0.0; b * n], vec![0.0; b * n]);
        for i in 0..b {
            let r = i * n..(i + 1) * n;
            let th = &theta[r.clone()];
            let active = src.active();
            c.hamilton_into(th, &p[r.clone()], &mut td[r.clone()], &mut pd[r], &mut ws, |om, out| {
                if active {
                    src.eval(t, th, om, out)
                } else {
                    out.fill(0.0);
                    Ok(())
                }
            })
            .map_err(|s| to_py(py, Error::integration(t, s.reason())))?
            .map_err(|e| torque_error(py, e, &slot))?;
        }
        Ok((vec_out(py, td), vec_out(py, pd)))
    }

    fn momenta<'py>(&self, py: Python<'py>, theta: PyReadonlyArray1<'py, f64>, omega: PyReadonlyArray1<'py, f64>) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let c = &self.inner;
        let n = c.n();
        let (theta, omega) = (slice("theta", &theta)?, slice("omega", &omega)?);
        rows("theta", theta.len(), n)?;
        let mut ws = Workspace::new(n);
        let mut out = vec![0.0; theta.len()];
        for ((th, om), o) in theta.chunks(n).zip(omega.chunks(n)).zip(out.chunks_mut(n)) {
            c.momenta_into(th, om, o, &mut ws);
        }
        Ok(vec_out(py, out))
    }

    fn velocities<'py>(&self, py: Python<'py>, theta: PyReadonlyArray1<'py, f64>, p: PyReadonlyArray1<'py, f64>) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let c = &self.inner;
        let n = c.n();
        let (theta, p) = (slice("theta", &theta)?, slice("p", &p)?);
        rows("theta", theta.len(), n)?;
        let mut ws = Workspace::new(n);
        let mut out = vec![0.0; theta.len()];
        for ((th, pp), o) in theta.chunks(n).zip(p.chunks(n)).zip(out.chunks_mut(n)) {
            c.velocities_into(th, pp, o, &mut ws).map_err(|s| to_py(py, Error::integration(0.0, s.reason())))?;
        }
        Ok(vec_out(py, out))
    }

    /// `(kinetic, potential)` energies of each row.
    fn energies<'py>(&self, py: Python<'py>, theta: PyReadonlyArray1<'py, f64>, omega: PyReadonlyArray1<'py, f64>) -> PyResult<(Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<f64>>)> {
        let c = &self.inner;
        let n = c.n();
        let (theta, omega) = (slice("theta", &theta)?, slice("omega", &omega)?);
        let b = rows("theta", theta.len(), n)?;
        let mut ws = Workspace::new(n);
        let mut scratch = vec![0.0; n];
        let (mut kin, mut pot) = (Vec::with_capacity(b), Vec::with_capacity(b));
        for (th, om) in theta.chunks(n).zip(omega.chunks(n)) {
            kin.push(c.kinetic_energy(th, om, &mut scratch, &mut ws));
            pot.push(c.potential_energy(th));
        }
        Ok((vec_out(py, kin), vec_out(py, pot)))
    }

    /// Joint positions (`com=False`) or centres of mass (`com=True`), 2N numbers per row.
    fn positions<'py>(&self, py: Python<'py>, theta: PyReadonlyArray1<'py, f64>, com: bool) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let c = &self.inner;
        let n = c.n();
        let theta = slice("theta", &theta)?;
        rows("theta", theta.len(), n)?;
        let mut out = vec![0.0; 2 * theta.len()];
        for (th, o) in theta.chunks(n).zip(out.chunks_mut(2 * n)) {
            if com {
                c.com_positions_into(th, o);
            } else {
                c.positions_into(th, o);
            }
        }
        Ok(vec_out(py, out))
    }

    fn __repr__(&self) -> String {
        let c = &self.inner;
        format!(
            "Chain(lengths={:?}, masses={:?}, com={:?}, inertia={:?}, g={})",
            c.lengths(),
            c.masses(),
            c.com(),
            c.inertia(),
            c.g()
        )
    }
}

/// Calls `progress(fraction)` and checks for Ctrl-C at most ten times a second.
struct Progress<'a> {
    every: Duration,
    last: Instant,
    t_end: f64,
    callback: Option<&'a Py<PyAny>>,
}

impl Progress<'_> {
    fn tick(&mut self, py: Option<Python<'_>>, t: f64) -> core::Result<()> {
        if self.last.elapsed() < self.every {
            return Ok(());
        }
        self.last = Instant::now();
        let report = |py: Python<'_>| -> PyResult<()> {
            py.check_signals()?;
            if let Some(cb) = self.callback {
                cb.call1(py, (t / self.t_end,))?;
            }
            Ok(())
        };
        let r = match py {
            Some(py) => report(py),
            None => Python::attach(report),
        };
        r.map_err(|e| {
            PENDING.with(|p| *p.borrow_mut() = Some(e));
            Error::Torque { t }
        })
    }
}

thread_local! {
    /// A Python exception raised in a progress callback or by a signal handler during a run.
    static PENDING: RefCell<Option<PyErr>> = const { RefCell::new(None) };
}

struct Trajectories(Vec<core::Trajectory>);

/// The run's outputs as a dict of flat arrays (Python reshapes): t, theta, omega, p, energy,
/// work, and the stats.
fn trajectories_out<'py>(py: Python<'py>, trs: Trajectories) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
    use pyo3::types::PyDict;
    let d = PyDict::new(py);
    let mut trs = trs.0;
    let first = &trs[0];
    d.set_item("t", vec_out(py, first.t.clone()))?;
    d.set_item("form", first.form.name())?;
    let stats = PyDict::new(py);
    for (k, f) in [
        ("steps", (|s: &core::Stats| s.steps as f64) as fn(&core::Stats) -> f64),
        ("rejected", |s| s.rejected as f64),
        ("evaluations", |s| s.evaluations as f64),
        ("iterations", |s| s.iterations as f64),
        ("energy_error", |s| s.energy_error),
    ] {
        stats.set_item(k, vec_out(py, trs.iter().map(|t| f(&t.stats)).collect()))?;
    }
    d.set_item("stats", stats)?;
    let take = |trs: &mut Vec<core::Trajectory>, f: fn(&mut core::Trajectory) -> Vec<f64>| -> Vec<f64> {
        if trs.len() == 1 {
            return f(&mut trs[0]);
        }
        trs.iter_mut().flat_map(f).collect()
    };
    d.set_item("theta", vec_out(py, take(&mut trs, |t| std::mem::take(&mut t.theta))))?;
    d.set_item("omega", vec_out(py, take(&mut trs, |t| std::mem::take(&mut t.omega))))?;
    d.set_item("p", vec_out(py, take(&mut trs, |t| std::mem::take(&mut t.p))))?;
    d.set_item("energy", vec_out(py, take(&mut trs, |t| std::mem::take(&mut t.energy))))?;
    d.set_item("work", vec_out(py, take(&mut trs, |t| std::mem::take(&mut t.work))))?;
    let events = pyo3::types::PyList::empty(py);
    let stopped = pyo3::types::PyList::empty(py);
    for tr in trs.iter_mut() {
        let hits = pyo3::types::PyList::empty(py);
        for (i, t, theta, omega, p) in std::mem::take(&mut tr.events) {
            hits.append((i, t, vec_out(py, theta), vec_out(py, omega), vec_out(py, p)))?;
        }
        events.append(hits)?;
        stopped.append(tr.stopped_at)?;
    }
    d.set_item("events", events)?;
    d.set_item("stopped_at", stopped)?;
    Ok(d)
}

/// A Python event function `g(t, theta, omega) -> float`; its exception is kept to re-raise.
struct PyEvent {
    f: Py<PyAny>,
    error: std::sync::Arc<std::sync::Mutex<Option<PyErr>>>,
}

impl core::EventFn for PyEvent {
    fn value(&self, t: f64, theta: &[f64], omega: &[f64]) -> core::Result<f64> {
        Python::attach(|py| {
            let r = self
                .f
                .call1(py, (t, vec_out(py, theta.to_vec()), vec_out(py, omega.to_vec())))
                .and_then(|v| {
                    v.extract::<f64>(py).map_err(|_| {
                        InputError::new_err(format!(
                            "the event function must return a number, got {}",
                            v.bind(py).repr().map(|r| r.to_string()).unwrap_or_default()
                        ))
                    })
                });
            r.map_err(|e| {
                *self.error.lock().unwrap_or_else(|p| p.into_inner()) = Some(e);
                Error::Torque { t }
            })
        })
    }
}

type EventErrors = std::sync::Arc<std::sync::Mutex<Option<PyErr>>>;

/// An event from the Python layer's normalised spec: `("flip", link | None, direction, terminal)`,
/// `("linear", theta_coefficients, omega_coefficients, constant, direction, terminal)` or
/// `("callable", g, direction, terminal)`.
fn event_spec(spec: &Bound<'_, PyTuple>, errors: &EventErrors) -> PyResult<core::EventSpec> {
    let kind: String = spec.get_item(0)?.extract()?;
    let (condition, rest) = match kind.as_str() {
        "callable" => (
            core::Condition::Custom(std::sync::Arc::new(PyEvent { f: spec.get_item(1)?.unbind(), error: errors.clone() })),
            2,
        ),
        "flip" => (core::Condition::Flip(spec.get_item(1)?.extract()?), 2),
        "linear" => (
            core::Condition::Linear {
                theta: spec.get_item(1)?.extract()?,
                omega: spec.get_item(2)?.extract()?,
                constant: spec.get_item(3)?.extract()?,
            },
            4,
        ),
        other => return Err(InputError::new_err(format!("unknown event kind {other:?}"))),
    };
    Ok(core::EventSpec { condition, direction: spec.get_item(rest)?.extract()?, terminal: spec.get_item(rest + 1)?.extract()? })
}

/// Integrate B >= 1 initial states (rows of flat `theta0`, `omega0`). Built-in torques run on
/// all cores with the GIL released; a Python torque function runs the rows in turn, holding it.
#[pyfunction]
#[pyo3(signature = (chain, theta0, omega0, t_end, method, form, dt, rtol, atol, adaptive, t_eval, max_steps, torque_spec, joint, progress, events=None, checkpoint=None, resume=None))]
#[allow(clippy::too_many_arguments)]
fn simulate<'py>(
    py: Python<'py>,
    chain: &PyChain,
    theta0: PyReadonlyArray1<'py, f64>,
    omega0: PyReadonlyArray1<'py, f64>,
    t_end: f64,
    method: &str,
    form: Option<&str>,
    dt: Option<f64>,
    rtol: f64,
    atol: f64,
    adaptive: bool,
    t_eval: Option<PyReadonlyArray1<'py, f64>>,
    max_steps: u64,
    torque_spec: Option<Bound<'py, PyTuple>>,
    joint: bool,
    progress: Option<Py<PyAny>>,
    events: Option<Vec<Bound<'py, PyTuple>>>,
    checkpoint: Option<(u64, Option<f64>, Py<PyAny>)>,
    resume: Option<Bound<'py, pyo3::types::PyDict>>,
) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
    let c = &chain.inner;
    let n = c.n();
    let err = |e| to_py(py, e);
    let form = match form {
        None => None,
        Some("lagrangian") => Some(Form::Lagrangian),
        Some("hamiltonian") => Some(Form::Hamiltonian),
        Some(other) => return Err(InputError::new_err(format!("form must be \"lagrangian\" or \"hamiltonian\", got {other:?}"))),
    };
    let event_errors: EventErrors = Default::default();
    let settings = Settings {
        method: Method::parse(method).map_err(err)?,
        form,
        dt,
        rtol,
        atol,
        adaptive,
        t_eval: t_eval.as_ref().map(|a| slice("t_eval", a).map(<[f64]>::to_vec)).transpose()?,
        max_steps,
        events: events.unwrap_or_default().iter().map(|e| event_spec(e, &event_errors)).collect::<PyResult<_>>()?,
    };
    let (theta0, omega0) = (slice("theta0", &theta0)?, slice("omega0", &omega0)?);
    let b = rows("theta0", theta0.len(), n)?;
    let slot = RefCell::new(None);
    let src = torque(n, torque_spec.as_ref(), joint, &slot)?;
    let mut prog = Progress { every: Duration::from_millis(100), last: Instant::now(), t_end, callback: progress.as_ref() };
    let resume = resume.as_ref().map(checkpoint_in).transpose()?;
    if (checkpoint.is_some() || resume.is_some()) && (b > 1 || matches!(src, AnyTorque::Call(_) | AnyTorque::JointCall(_))) {
        return Err(InputError::new_err(
            "checkpoints need a single run with a built-in torque (not a batch, not a Python torque function)",
        ));
    }
    let save_error: std::sync::Mutex<Option<PyErr>> = Default::default();
    let mut last_save = Instant::now();
    let (every_steps, every_seconds) = checkpoint.as_ref().map_or((0, None), |c| (c.0, c.1));
    let mut due = || {
        let due = every_seconds.is_some_and(|s| last_save.elapsed().as_secs_f64() >= s);
        if due {
            last_save = Instant::now();
        }
        due
    };
    let mut save = |cp: &core::Checkpoint| -> core::Result<()> {
        let Some((_, _, cb)) = checkpoint.as_ref() else { return Ok(()) };
        Python::attach(|py| checkpoint_out(py, cp).and_then(|d| cb.call1(py, (d,)).map(drop))).map_err(|e| {
            *save_error.lock().unwrap_or_else(|p| p.into_inner()) = Some(e);
            Error::Torque { t: cp.t }
        })
    };
    let start = match &resume {
        Some(cp) => core::Start::Resume(cp),
        None => core::Start::Initial { theta0, omega0 },
    };
    let fail = |e: Error| -> PyErr {
        // A checkpoint that could not be written matters more than the interrupt that asked for it.
        if let Some(p) = save_error.lock().unwrap_or_else(|p| p.into_inner()).take() {
            PENDING.with(|p| p.borrow_mut().take());
            return p;
        }
        if let Some(p) = PENDING.with(|p| p.borrow_mut().take()) {
            return p;
        }
        if let Some(p) = event_errors.lock().unwrap_or_else(|p| p.into_inner()).take() {
            return p;
        }
        torque_error(py, e, &slot)
    };
    let result = match src {
        AnyTorque::Builtin(_) | AnyTorque::JointBuiltin(_) if b > 1 => {
            let run = |src: AnyTorque<'_>| match src {
                AnyTorque::Builtin(s) => py.detach(|| core::simulate_batch(c, theta0, omega0, t_end, &settings, &s)),
                AnyTorque::JointBuiltin(s) => py.detach(|| core::simulate_batch(c, theta0, omega0, t_end, &settings, &s)),
                _ => unreachable!(),
            };
            run(src).map(Trajectories)
        }
        AnyTorque::Builtin(s) => py
            .detach(|| {
                let mut cps = checkpoint.as_ref().map(|_| core::Checkpoints { every_steps, due: &mut due, save: &mut save });
                core::simulate_from(c, start, t_end, &settings, s, &mut |t| prog.tick(None, t), cps.as_mut())
            })
            .map(|t| Trajectories(vec![t])),
        AnyTorque::JointBuiltin(s) => py
            .detach(|| {
                let mut cps = checkpoint.as_ref().map(|_| core::Checkpoints { every_steps, due: &mut due, save: &mut save });
                core::simulate_from(c, start, t_end, &settings, s, &mut |t| prog.tick(None, t), cps.as_mut())
            })
            .map(|t| Trajectories(vec![t])),
        mut src => {
            let mut out = Vec::with_capacity(b);
            let mut res = Ok(());
            for i in 0..b {
                let r = i * n..(i + 1) * n;
                match core::simulate(c, &theta0[r.clone()], &omega0[r], t_end, &settings, &mut src, &mut |t| prog.tick(Some(py), t)) {
                    Ok(t) => out.push(t),
                    Err(e) => {
                        res = Err(e);
                        break;
                    }
                }
            }
            res.map(|_| Trajectories(out))
        }
    };
    let trs = result.map_err(fail)?;
    trajectories_out(py, trs)
}

/// A checkpoint as a dict of numbers and flat arrays (the Python layer stores it).
fn checkpoint_out<'py>(py: Python<'py>, cp: &core::Checkpoint) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
    let d = pyo3::types::PyDict::new(py);
    d.set_item("t", cp.t)?;
    d.set_item("y", vec_out(py, cp.y.clone()))?;
    d.set_item("steps", cp.stats.steps)?;
    d.set_item("rejected", cp.stats.rejected)?;
    d.set_item("evaluations", cp.stats.evaluations)?;
    d.set_item("iterations", cp.stats.iterations)?;
    d.set_item("k", vec_out(py, cp.carry.k.clone()))?;
    d.set_item("comp", vec_out(py, cp.carry.comp.clone()))?;
    d.set_item("h", cp.carry.h)?;
    d.set_item("slope", vec_out(py, cp.slope.clone()))?;
    d.set_item("out_t", vec_out(py, cp.out_t.clone()))?;
    d.set_item("out_y", vec_out(py, cp.out_y.clone()))?;
    d.set_item("next_out", cp.next_out)?;
    Ok(d)
}

/// The inverse of [`checkpoint_out`]; a missing or mistyped entry is named.
fn checkpoint_in(d: &Bound<'_, pyo3::types::PyDict>) -> PyResult<core::Checkpoint> {
    fn get<'py, T: for<'a> FromPyObject<'a, 'py>>(d: &Bound<'py, pyo3::types::PyDict>, key: &str) -> PyResult<T> {
        let v = d.get_item(key)?.ok_or_else(|| InputError::new_err(format!("checkpoint: missing {key:?}")))?;
        v.extract().map_err(|_| InputError::new_err(format!("checkpoint: {key:?} has the wrong type")))
    }
    Ok(core::Checkpoint {
        t: get(d, "t")?,
        y: get(d, "y")?,
        stats: core::Stats {
            steps: get(d, "steps")?,
            rejected: get(d, "rejected")?,
            evaluations: get(d, "evaluations")?,
            iterations: get(d, "iterations")?,
            energy_error: 0.0,
        },
        carry: core::Carry { k: get(d, "k")?, comp: get(d, "comp")?, h: get(d, "h")? },
        slope: get(d, "slope")?,
        out_t: get(d, "out_t")?,
        out_y: get(d, "out_y")?,
        next_out: get(d, "next_out")?,
    })
}

/// A built-in generalized torque for the chaos kernels (which run without the GIL).
fn builtin_only(py: Python<'_>, n: usize, spec: Option<&Bound<'_, PyTuple>>, what: &str) -> PyResult<Builtin> {
    let _ = py;
    match spec {
        None => Ok(Builtin::None),
        Some(spec) if spec.get_item(0)?.extract::<String>()? == "callable" => Err(InputError::new_err(format!(
            "{what} takes built-in torques only (constant, Sinusoid, Table), not a Python function"
        ))),
        Some(spec) => builtin(n, spec),
    }
}

/// Lyapunov exponents by the variational equations; see `multipendulum_core::chaos::lyapunov`.
#[pyfunction]
#[pyo3(signature = (chain, theta0, omega0, t_end, dt, k, renorm_every, torque_spec))]
#[allow(clippy::too_many_arguments)]
fn lyapunov<'py>(
    py: Python<'py>,
    chain: &PyChain,
    theta0: Vec<f64>,
    omega0: Vec<f64>,
    t_end: f64,
    dt: f64,
    k: usize,
    renorm_every: u64,
    torque_spec: Option<Bound<'py, PyTuple>>,
) -> PyResult<(Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<f64>>)> {
    let c = &chain.inner;
    let torque = builtin_only(py, c.n(), torque_spec.as_ref(), "lyapunov")?;
    let out = py
        .detach(|| core::chaos::lyapunov(c, &theta0, &omega0, t_end, dt, k, renorm_every, torque))
        .map_err(|e| to_py(py, e))?;
    Ok((vec_out(py, out.exponents), vec_out(py, out.times), vec_out(py, out.history)))
}

/// First-flip times of the rows of flat `theta0`/`omega0` (+inf: never), in parallel.
#[pyfunction]
#[pyo3(signature = (chain, theta0, omega0, t_max, dt, link, torque_spec))]
#[allow(clippy::too_many_arguments)]
fn first_flips<'py>(
    py: Python<'py>,
    chain: &PyChain,
    theta0: PyReadonlyArray1<'py, f64>,
    omega0: PyReadonlyArray1<'py, f64>,
    t_max: f64,
    dt: f64,
    link: Option<usize>,
    torque_spec: Option<Bound<'py, PyTuple>>,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let c = &chain.inner;
    let torque = builtin_only(py, c.n(), torque_spec.as_ref(), "flip maps")?;
    let (theta0, omega0) = (slice("theta0", &theta0)?, slice("omega0", &omega0)?);
    let out = py
        .detach(|| core::chaos::first_flips(c, theta0, omega0, t_max, dt, link, &torque))
        .map_err(|e| to_py(py, e))?;
    Ok(vec_out(py, out))
}

#[pyfunction]
#[pyo3(signature = (chain, link))]
fn flip_energy_threshold(py: Python<'_>, chain: &PyChain, link: Option<usize>) -> PyResult<f64> {
    core::chaos::flip_energy_threshold(&chain.inner, link).map_err(|e| to_py(py, e))
}

/// Refuse a request needing `bytes` that would not fit in memory; see
/// `multipendulum_core::memory::check` (the one place the limit lives).
#[pyfunction]
fn check_memory(py: Python<'_>, bytes: f64, what: &str, advice: &str) -> PyResult<()> {
    core::memory::check(bytes, what, advice).map_err(|e| to_py(py, e))
}

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    // The version of the compiled core: what checkpoint archives and benchmarks record.
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_class::<PyChain>()?;
    m.add_function(wrap_pyfunction!(simulate, m)?)?;
    m.add_function(wrap_pyfunction!(lyapunov, m)?)?;
    m.add_function(wrap_pyfunction!(first_flips, m)?)?;
    m.add_function(wrap_pyfunction!(flip_energy_threshold, m)?)?;
    m.add_function(wrap_pyfunction!(check_memory, m)?)?;
    m.add("InputError", m.py().get_type::<InputError>())?;
    m.add("IntegrationError", m.py().get_type::<IntegrationError>())?;
    m.add("METHODS", Method::ALL.iter().map(|m| m.name()).collect::<Vec<_>>())?;
    let info = pyo3::types::PyDict::new(m.py());
    for method in Method::ALL {
        let d = pyo3::types::PyDict::new(m.py());
        d.set_item("order", method.order())?;
        d.set_item("symplectic", method.symplectic())?;
        d.set_item("adaptive", method.adaptive())?;
        d.set_item("implicit", method.symplectic())?;
        info.set_item(method.name(), d)?;
    }
    m.add("METHOD_INFO", info)?;
    Ok(())
}
