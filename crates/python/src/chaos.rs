//! Chaos tools of the core: Lyapunov exponents, chaos indicators (MEGNO, FLI, SALI, GALI) and
//! first-flip times, interruptible.
use multipendulum_core as core;
use numpy::{PyArray1, PyReadonlyArray1};
use pyo3::prelude::*;

use core::Watch;

use crate::base::{take, Errors, PyAxis, PyCartForce};
use crate::chain::PyChain;
use crate::torque::{builtin_only, timed, PyTorque};
use crate::{interruptible, slice, to_py, vec_out, Array};

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(lyapunov, m)?)?;
    m.add_function(wrap_pyfunction!(first_flips, m)?)?;
    m.add_function(wrap_pyfunction!(certified_flips, m)?)?;
    m.add_function(wrap_pyfunction!(ensemble, m)?)?;
    m.add_function(wrap_pyfunction!(flip_energy_threshold, m)?)?;
    m.add_function(wrap_pyfunction!(indicator, m)?)?;
    m.add_function(wrap_pyfunction!(indicators, m)?)?;
    m.add_function(wrap_pyfunction!(certified_indicators, m)?)?;
    use core::chaos::indicators::Indicator;
    m.add("INDICATORS", Indicator::NAMES.to_vec())?;
    // name -> (chaotic above the threshold?, the threshold or None), the core's rule of thumb.
    let rules = pyo3::types::PyDict::new(m.py());
    for name in Indicator::NAMES {
        let which = Indicator::parse(name, Some(2)).expect("the core's own names parse");
        rules.set_item(name, which.chaos_rule())?;
    }
    m.add("CHAOS_RULES", rules)?;
    Ok(())
}

/// A chaos indicator of one run with its history; see `multipendulum_core::chaos::indicators`.
#[pyfunction]
#[pyo3(signature = (chain, theta0, omega0, t_end, *, dt, name, k=None, torque=None, pivot=None, deviations=None, record_every=1, progress=None))]
#[allow(clippy::too_many_arguments)]
fn indicator<'py>(
    py: Python<'py>,
    chain: &PyChain,
    theta0: Vec<f64>,
    omega0: Vec<f64>,
    t_end: f64,
    dt: f64,
    name: &str,
    k: Option<usize>,
    torque: Option<PyRef<'py, PyTorque>>,
    pivot: Option<(PyRef<'py, PyAxis>, PyRef<'py, PyAxis>)>,
    deviations: Option<Vec<f64>>,
    record_every: u64,
    progress: Option<Py<PyAny>>,
) -> PyResult<(f64, Array<'py>, Array<'py>)> {
    use core::chaos::indicators::{indicator, Indicator};
    let c = &chain.inner;
    let which = Indicator::parse(name, k).map_err(|e| to_py(py, e))?;
    let torque = builtin_only(py, c.n(), torque.as_deref(), "chaos indicators")?;
    let errors: Errors = Default::default();
    let pivot = crate::base::pivot(py, pivot, &errors)?;
    let watch = Watch::new();
    let out = interruptible(py, &watch, progress.as_ref(), false, || {
        indicator(c, &theta0, &omega0, t_end, dt, which, (&torque, pivot.as_ref()), deviations.as_deref(), record_every, &watch)
    })?
    .map_err(|e| take(&errors).unwrap_or_else(|| to_py(py, e)))?;
    Ok((out.value, vec_out(py, out.times), vec_out(py, out.values)))
}

/// A chaos indicator at `t_end` of each row of flat `theta0`/`omega0`, in parallel.
#[pyfunction]
#[pyo3(signature = (chain, theta0, omega0, t_end, *, dt, name, k=None, torque=None, pivot=None, deviations=None, progress=None))]
#[allow(clippy::too_many_arguments)]
fn indicators<'py>(
    py: Python<'py>,
    chain: &PyChain,
    theta0: PyReadonlyArray1<'py, f64>,
    omega0: PyReadonlyArray1<'py, f64>,
    t_end: f64,
    dt: f64,
    name: &str,
    k: Option<usize>,
    torque: Option<PyRef<'py, PyTorque>>,
    pivot: Option<(PyRef<'py, PyAxis>, PyRef<'py, PyAxis>)>,
    deviations: Option<Vec<f64>>,
    progress: Option<Py<PyAny>>,
) -> PyResult<Array<'py>> {
    use core::chaos::indicators::{indicators, Indicator};
    let c = &chain.inner;
    let which = Indicator::parse(name, k).map_err(|e| to_py(py, e))?;
    let torque = builtin_only(py, c.n(), torque.as_deref(), "chaos indicators")?;
    let errors: Errors = Default::default();
    let pivot = crate::base::pivot(py, pivot, &errors)?;
    let (theta0, omega0) = (slice("theta0", &theta0)?, slice("omega0", &omega0)?);
    let watch = Watch::units((theta0.len() / c.n().max(1)) as u64);
    let out = interruptible(py, &watch, progress.as_ref(), false, || {
        indicators(c, theta0, omega0, t_end, dt, which, (&torque, pivot.as_ref()), deviations.as_deref(), &watch)
    })?
    .map_err(|e| take(&errors).unwrap_or_else(|| to_py(py, e)))?;
    Ok(vec_out(py, out))
}

/// [`indicators`] certified: the values at `dt`, whether each row is uncertain (it falls on
/// the other side of the threshold at `dt / 2`; `core::chaos::indicators::certified_indicators`)
/// and the threshold used.
#[pyfunction]
#[pyo3(signature = (chain, theta0, omega0, t_end, *, dt, name, k=None, torque=None, pivot=None, deviations=None, threshold=None, progress=None))]
#[allow(clippy::too_many_arguments)]
fn certified_indicators<'py>(
    py: Python<'py>,
    chain: &PyChain,
    theta0: PyReadonlyArray1<'py, f64>,
    omega0: PyReadonlyArray1<'py, f64>,
    t_end: f64,
    dt: f64,
    name: &str,
    k: Option<usize>,
    torque: Option<PyRef<'py, PyTorque>>,
    pivot: Option<(PyRef<'py, PyAxis>, PyRef<'py, PyAxis>)>,
    deviations: Option<Vec<f64>>,
    threshold: Option<f64>,
    progress: Option<Py<PyAny>>,
) -> PyResult<(Array<'py>, Array<'py, bool>, f64)> {
    use core::chaos::indicators::{certified_indicators, Indicator};
    let c = &chain.inner;
    let which = Indicator::parse(name, k).map_err(|e| to_py(py, e))?;
    let torque = builtin_only(py, c.n(), torque.as_deref(), "chaos indicators")?;
    let errors: Errors = Default::default();
    let pivot = crate::base::pivot(py, pivot, &errors)?;
    let (theta0, omega0) = (slice("theta0", &theta0)?, slice("omega0", &omega0)?);
    let watch = Watch::units(2 * (theta0.len() / c.n().max(1)) as u64);
    let out = interruptible(py, &watch, progress.as_ref(), false, || {
        certified_indicators(c, theta0, omega0, t_end, dt, which, (&torque, pivot.as_ref()), deviations.as_deref(), threshold, &watch)
    })?
    .map_err(|e| take(&errors).unwrap_or_else(|| to_py(py, e)))?;
    Ok((vec_out(py, out.values), PyArray1::from_vec(py, out.uncertain), out.threshold))
}

/// Lyapunov exponents by the variational equations; see `multipendulum_core::chaos::lyapunov`.
/// A pivot function's own exception is re-raised as it was kept.
#[pyfunction]
#[pyo3(signature = (chain, theta0, omega0, t_end, *, dt, k=None, renorm_every, torque=None, pivot=None, cart_force=None, cart0=(0.0, 0.0), progress=None))]
#[allow(clippy::too_many_arguments)]
fn lyapunov<'py>(
    py: Python<'py>,
    chain: &PyChain,
    theta0: Vec<f64>,
    omega0: Vec<f64>,
    t_end: f64,
    dt: f64,
    k: Option<usize>,
    renorm_every: u64,
    torque: Option<PyRef<'py, PyTorque>>,
    pivot: Option<(PyRef<'py, PyAxis>, PyRef<'py, PyAxis>)>,
    cart_force: Option<PyRef<'py, PyCartForce>>,
    cart0: (f64, f64),
    progress: Option<Py<PyAny>>,
) -> PyResult<(Array<'py>, Array<'py>, Array<'py>)> {
    let c = &chain.inner;
    let torque = builtin_only(py, c.n(), torque.as_deref(), "lyapunov")?;
    let errors: Errors = Default::default();
    let drive = core::Drive { pivot: crate::base::pivot(py, pivot, &errors)?, force: crate::base::force(py, cart_force, &errors)? };
    let watch = Watch::new();
    let out = interruptible(py, &watch, progress.as_ref(), false, || {
        core::chaos::lyapunov(c, (&theta0, &omega0, [cart0.0, cart0.1]), t_end, dt, k, renorm_every, torque, drive, &watch)
    })?
    .map_err(|e| take(&errors).unwrap_or_else(|| to_py(py, e)))?;
    Ok((vec_out(py, out.exponents), vec_out(py, out.times), vec_out(py, out.history)))
}

/// First-flip times of the rows of flat `theta0`/`omega0` (+inf: never), in parallel. A pivot
/// function's own exception is re-raised as it was kept.
#[pyfunction]
#[pyo3(signature = (chain, theta0, omega0, t_max, *, dt, link=None, torque=None, pivot=None, progress=None))]
#[allow(clippy::too_many_arguments)]
fn first_flips<'py>(
    py: Python<'py>,
    chain: &PyChain,
    theta0: PyReadonlyArray1<'py, f64>,
    omega0: PyReadonlyArray1<'py, f64>,
    t_max: f64,
    dt: f64,
    link: Option<usize>,
    torque: Option<PyRef<'py, PyTorque>>,
    pivot: Option<(PyRef<'py, PyAxis>, PyRef<'py, PyAxis>)>,
    progress: Option<Py<PyAny>>,
) -> PyResult<Array<'py>> {
    let c = &chain.inner;
    let torque = builtin_only(py, c.n(), torque.as_deref(), "flip maps")?;
    let errors: Errors = Default::default();
    let pivot = crate::base::pivot(py, pivot, &errors)?;
    let (theta0, omega0) = (slice("theta0", &theta0)?, slice("omega0", &omega0)?);
    let watch = Watch::units((theta0.len() / c.n().max(1)) as u64);
    let out =
        interruptible(py, &watch, progress.as_ref(), false, || core::chaos::first_flips(c, theta0, omega0, t_max, dt, link, &torque, pivot.as_ref(), &watch))?
            .map_err(|e| take(&errors).unwrap_or_else(|| to_py(py, e)))?;
    Ok(vec_out(py, out))
}

/// [`first_flips`] certified: the times at `dt`, whether each row is uncertain (its flip
/// decision or time moves when the step halves; `core::chaos::certified_flips`) and the time
/// tolerance used.
#[pyfunction]
#[pyo3(signature = (chain, theta0, omega0, t_max, *, dt, link=None, torque=None, pivot=None, tolerance=None, progress=None))]
#[allow(clippy::too_many_arguments)]
fn certified_flips<'py>(
    py: Python<'py>,
    chain: &PyChain,
    theta0: PyReadonlyArray1<'py, f64>,
    omega0: PyReadonlyArray1<'py, f64>,
    t_max: f64,
    dt: f64,
    link: Option<usize>,
    torque: Option<PyRef<'py, PyTorque>>,
    pivot: Option<(PyRef<'py, PyAxis>, PyRef<'py, PyAxis>)>,
    tolerance: Option<f64>,
    progress: Option<Py<PyAny>>,
) -> PyResult<(Array<'py>, Array<'py, bool>, f64)> {
    let c = &chain.inner;
    let torque = builtin_only(py, c.n(), torque.as_deref(), "flip maps")?;
    let errors: Errors = Default::default();
    let pivot = crate::base::pivot(py, pivot, &errors)?;
    let (theta0, omega0) = (slice("theta0", &theta0)?, slice("omega0", &omega0)?);
    let watch = Watch::units(2 * (theta0.len() / c.n().max(1)) as u64);
    let out = interruptible(py, &watch, progress.as_ref(), false, || {
        core::chaos::certified_flips(c, theta0, omega0, t_max, dt, link, &torque, pivot.as_ref(), tolerance, &watch)
    })?
    .map_err(|e| take(&errors).unwrap_or_else(|| to_py(py, e)))?;
    Ok((vec_out(py, out.times), PyArray1::from_vec(py, out.uncertain), out.tolerance))
}

/// The arrays of an ensemble.
type EnsembleOut<'py> = (Array<'py>, Array<'py>, Array<'py>, Array<'py>, Array<'py, u64>, Array<'py>);

/// An ensemble in SIMD lanes (`core::chaos::ensemble`): `(theta, omega, p, energy_error, steps,
/// first_flip)` flat, or None where the core sends it the per-trajectory way (a method other than
/// rk4 and dop853, a torque or a pivot axis that is a Python function, or
/// `MULTIPENDULUM_LANES=scalar`).
#[pyfunction]
#[pyo3(signature = (chain, theta0, omega0, t_end, *, method, dt=None, rtol, atol, torque=None, pivot=None, progress=None))]
#[allow(clippy::too_many_arguments)]
fn ensemble<'py>(
    py: Python<'py>,
    chain: &PyChain,
    theta0: PyReadonlyArray1<'py, f64>,
    omega0: PyReadonlyArray1<'py, f64>,
    t_end: f64,
    method: &str,
    dt: Option<f64>,
    rtol: f64,
    atol: f64,
    torque: Option<PyRef<'py, PyTorque>>,
    pivot: Option<(PyRef<'py, PyAxis>, PyRef<'py, PyAxis>)>,
    progress: Option<Py<PyAny>>,
) -> PyResult<Option<EnsembleOut<'py>>> {
    let c = &chain.inner;
    let method = core::Method::parse(method).map_err(|e| to_py(py, e))?;
    let Some(path) = core::chaos::ensemble::route(method).map_err(|e| to_py(py, e))? else {
        return Ok(None);
    };
    let Some(drive) = timed(py, c.n(), torque.as_deref())? else {
        return Ok(None);
    };
    let pivot = crate::base::pivot(py, pivot, &Errors::default())?;
    if pivot.as_ref().is_some_and(|p| !p.in_lanes()) {
        return Ok(None);
    }
    let base = core::Drive { pivot, force: None };
    let settings = core::Settings { method, dt, rtol, atol, drive: base, ..core::Settings::default() };
    let (theta0, omega0) = (slice("theta0", &theta0)?, slice("omega0", &omega0)?);
    let watch = Watch::units((theta0.len() / c.n().max(1)) as u64);
    let out = interruptible(py, &watch, progress.as_ref(), false, || {
        core::chaos::ensemble::ensemble(c, theta0, omega0, t_end, &settings, Some(&drive), path, &watch)
    })?
    .map_err(|e| to_py(py, e))?;
    Ok(Some((
        vec_out(py, out.theta),
        vec_out(py, out.omega),
        vec_out(py, out.p),
        vec_out(py, out.energy_error),
        PyArray1::from_vec(py, out.steps),
        vec_out(py, out.first_flip),
    )))
}

#[pyfunction]
#[pyo3(signature = (chain, link=None))]
fn flip_energy_threshold(py: Python<'_>, chain: &PyChain, link: Option<usize>) -> PyResult<f64> {
    core::chaos::flip_energy_threshold(&chain.inner, link).map_err(|e| to_py(py, e))
}
