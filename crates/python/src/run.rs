//! `simulate`: one run or a batch, with events and checkpoints, through the core's run driver.
use std::cell::RefCell;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use multipendulum_core as core;
use numpy::PyReadonlyArray1;
use pyo3::prelude::*;
use pyo3::types::PyBytes;

use core::{Error, Form, Method, Settings, Watch};

use crate::base::{PyAxis, PyCartForce};
use crate::chain::PyChain;
use crate::torque::{torque_error, AnyTorque, PyTorque};
use crate::{interruptible, slice, to_py, vec_out, InputError};

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(simulate, m)?)?;
    m.add_function(wrap_pyfunction!(checkpoint_time, m)?)?;
    m.add_class::<PyEventSpec>()?;
    Ok(())
}

struct Trajectories(Vec<core::Trajectory>);

/// The run's outputs as a dict of flat arrays (Python reshapes): t, theta, omega, p, energy,
/// work, and the stats.
fn trajectories_out<'py>(py: Python<'py>, trs: Trajectories, sizes: Vec<usize>) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
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
    d.set_item("energy_error", vec_out(py, take(&mut trs, |t| std::mem::take(&mut t.energy_error))))?;
    // The general model's terms (empty arrays when the run has none).
    d.set_item("work_pivot", vec_out(py, take(&mut trs, |t| std::mem::take(&mut t.work_pivot))))?;
    d.set_item("work_cart", vec_out(py, take(&mut trs, |t| std::mem::take(&mut t.work_cart))))?;
    d.set_item("dissipated", vec_out(py, take(&mut trs, |t| std::mem::take(&mut t.dissipated))))?;
    d.set_item("cart_x", vec_out(py, take(&mut trs, |t| std::mem::take(&mut t.cart_x))))?;
    d.set_item("cart_v", vec_out(py, take(&mut trs, |t| std::mem::take(&mut t.cart_v))))?;
    d.set_item("pivot", vec_out(py, take(&mut trs, |t| std::mem::take(&mut t.pivot))))?;
    // Sensitivities: (T, S, K) per trajectory, flat (empty without them).
    d.set_item("directions", trs[0].directions)?;
    // Each input's number of directions, in the order asked (the core's Input::len).
    d.set_item("sensitivity_sizes", sizes)?;
    d.set_item("sensitivities", vec_out(py, take(&mut trs, |t| std::mem::take(&mut t.sensitivities))))?;
    d.set_item("canonical", vec_out(py, take(&mut trs, |t| std::mem::take(&mut t.canonical))))?;
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
            let r = self.f.call1(py, (t, vec_out(py, theta.to_vec()), vec_out(py, omega.to_vec()))).and_then(|v| {
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

/// An event condition as the Python layer hands it to the core.
#[pyclass(module = "multipendulum._core", frozen, name = "Event")]
pub(crate) struct PyEventSpec {
    condition: Cond,
    direction: i8,
    terminal: bool,
}

enum Cond {
    Flip(Option<usize>),
    Linear { theta: Vec<f64>, omega: Vec<f64>, constant: f64 },
    Function(Py<PyAny>),
}

#[pymethods]
impl PyEventSpec {
    /// Link `link` (None: any) goes over the top, `|theta| = pi`.
    #[staticmethod]
    #[pyo3(signature = (link, *, direction, terminal))]
    fn flip(link: Option<usize>, direction: i8, terminal: bool) -> Self {
        PyEventSpec { condition: Cond::Flip(link), direction, terminal }
    }

    /// `theta . a + omega . b + constant` crosses zero.
    #[staticmethod]
    #[pyo3(signature = (theta, omega, constant, *, direction, terminal))]
    fn linear(theta: Vec<f64>, omega: Vec<f64>, constant: f64, direction: i8, terminal: bool) -> Self {
        PyEventSpec { condition: Cond::Linear { theta, omega, constant }, direction, terminal }
    }

    /// A Python function `g(t, theta, omega) -> float` crosses zero.
    #[staticmethod]
    #[pyo3(signature = (g, *, direction, terminal))]
    fn function(g: Py<PyAny>, direction: i8, terminal: bool) -> Self {
        PyEventSpec { condition: Cond::Function(g), direction, terminal }
    }

    fn __repr__(&self) -> String {
        let kind = match self.condition {
            Cond::Flip(_) => "flip",
            Cond::Linear { .. } => "linear",
            Cond::Function(_) => "function",
        };
        format!("Event.{kind}(direction={}, terminal={})", self.direction, if self.terminal { "True" } else { "False" })
    }
}

fn event_spec(py: Python<'_>, spec: &PyEventSpec, errors: &EventErrors) -> core::EventSpec {
    let condition = match &spec.condition {
        Cond::Flip(k) => core::Condition::Flip(*k),
        Cond::Linear { theta, omega, constant } => core::Condition::Linear { theta: theta.clone(), omega: omega.clone(), constant: *constant },
        Cond::Function(g) => core::Condition::Custom(std::sync::Arc::new(PyEvent { f: g.clone_ref(py), error: errors.clone() })),
    };
    core::EventSpec { condition, direction: spec.direction, terminal: spec.terminal }
}

/// Integrate B >= 1 initial states (rows of flat `theta0`, `omega0`). Built-in torques run
/// without the GIL (a batch on all cores, in SIMD lanes where it fits: `core::run::lanes`),
/// interruptible by Ctrl-C; a Python torque function runs the rows in turn on this thread,
/// holding it. `batch`: the rows run as a batch even when there is one (an input with a batch
/// axis), so that a row's bits do not depend on the batch's size. `checkpoint`:
/// `(every_steps, every_seconds, save)`, `save(state: bytes, t, steps)` called with the run's
/// serialised state; `resume`: such bytes.
#[pyfunction]
#[pyo3(signature = (chain, theta0, omega0, t_end, *, method, rtol, atol, max_steps, form=None, dt=None, adaptive=true, t_eval=None, torque=None, progress=None, events=None, checkpoint=None, resume=None, pivot=None, cart_force=None, cart0=(0.0, 0.0), sensitivities=None, batch=false))]
#[allow(clippy::too_many_arguments)]
fn simulate<'py>(
    py: Python<'py>,
    chain: &PyChain,
    theta0: PyReadonlyArray1<'py, f64>,
    omega0: PyReadonlyArray1<'py, f64>,
    t_end: f64,
    method: &str,
    rtol: f64,
    atol: f64,
    max_steps: u64,
    form: Option<&str>,
    dt: Option<f64>,
    adaptive: bool,
    t_eval: Option<PyReadonlyArray1<'py, f64>>,
    torque: Option<PyRef<'py, PyTorque>>,
    progress: Option<Py<PyAny>>,
    events: Option<Vec<PyRef<'py, PyEventSpec>>>,
    checkpoint: Option<(u64, Option<f64>, Py<PyAny>)>,
    resume: Option<Vec<u8>>,
    pivot: Option<(PyRef<'py, PyAxis>, PyRef<'py, PyAxis>)>,
    cart_force: Option<PyRef<'py, PyCartForce>>,
    cart0: (f64, f64),
    sensitivities: Option<Vec<String>>,
    batch: bool,
) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
    let c = &chain.inner;
    let n = c.n();
    let err = |e| to_py(py, e);
    let event_errors: EventErrors = Default::default();
    let settings = Settings {
        method: Method::parse(method).map_err(err)?,
        form: form.map(Form::parse).transpose().map_err(err)?,
        dt,
        rtol,
        atol,
        adaptive,
        t_eval: t_eval.as_ref().map(|a| slice("t_eval", a).map(<[f64]>::to_vec)).transpose()?,
        max_steps,
        events: events.unwrap_or_default().iter().map(|e| event_spec(py, e, &event_errors)).collect(),
        drive: core::Drive { pivot: crate::base::pivot(py, pivot, &event_errors)?, force: crate::base::force(py, cart_force, &event_errors)? },
        cart0: [cart0.0, cart0.1],
        sensitivities: sensitivities.unwrap_or_default().iter().map(|s| core::Input::parse(s)).collect::<core::Result<_>>().map_err(err)?,
    };
    let base_callbacks = settings.drive.pivot.as_ref().is_some_and(|p| matches!(p.x, core::Axis::Function(_)) || matches!(p.y, core::Axis::Function(_)))
        || settings.drive.force.as_ref().is_some_and(core::Force::is_feedback);
    let (theta0, omega0) = (slice("theta0", &theta0)?, slice("omega0", &omega0)?);
    let b = core::dynamics::rows::count("theta0", theta0.len(), n).map_err(err)?;
    let slot = RefCell::new(None);
    let src = crate::torque::torque(py, n, torque.as_deref(), &slot)?;
    let resume = resume.as_deref().map(core::Checkpoint::from_bytes).transpose().map_err(err)?;
    let callable = matches!(src, AnyTorque::Call(_) | AnyTorque::JointCall(_));
    if (checkpoint.is_some() || resume.is_some()) && (b > 1 || callable || base_callbacks) {
        return Err(InputError::new_err("checkpoints need a single run with built-in inputs (not a batch, not a Python torque, pivot or cart force function)"));
    }
    let save_error: Mutex<Option<PyErr>> = Default::default();
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
        Python::attach(|py| cb.call1(py, (PyBytes::new(py, &cp.to_bytes()), cp.t(), cp.run.steps)).map(drop)).map_err(|e| {
            *save_error.lock().unwrap_or_else(|p| p.into_inner()) = Some(e);
            Error::Torque { t: cp.t() }
        })
    };
    let start = match &resume {
        Some(cp) => core::Start::Resume(cp),
        None => core::Start::Initial { theta0, omega0 },
    };
    // A failed checkpoint write matters more than the interrupt that asked for it; then a Python
    // callback's own exception; then the core's error.
    let fail = |e: Error| -> PyErr {
        if let Some(p) = save_error.lock().unwrap_or_else(|p| p.into_inner()).take() {
            return p;
        }
        if let Some(p) = event_errors.lock().unwrap_or_else(|p| p.into_inner()).take() {
            return p;
        }
        torque_error(py, e, &slot)
    };
    let progress = progress.as_ref();
    let short = settings.is_short(t_end, b);
    macro_rules! native {
        ($s:expr) => {{
            let s = $s;
            if b > 1 || batch {
                let watch = Watch::units(b as u64);
                interruptible(py, &watch, progress, short, || core::simulate_batch(c, theta0, omega0, t_end, &settings, &s, &watch))?.map(Trajectories)
            } else {
                let watch = Watch::new();
                let mut monitor = |t: f64| {
                    watch.set_fraction(t / t_end);
                    watch.check(t)
                };
                interruptible(py, &watch, progress, short, || {
                    let mut cps = checkpoint.as_ref().map(|_| core::Checkpoints { every_steps, due: &mut due, save: &mut save });
                    core::simulate_from(c, start, t_end, &settings, s, &mut monitor, cps.as_mut())
                })?
                .map(|t| Trajectories(vec![t]))
            }
        }};
    }
    let result = match src {
        // The built-ins of both conventions run alike, without the GIL: a batch on all cores,
        // a single run with its checkpoints.
        AnyTorque::Builtin(s) => native!(s),
        AnyTorque::JointBuiltin(s) => native!(s),
        mut src => {
            // The torque function needs the GIL: the rows in turn, here, with Ctrl-C and
            // progress checked now and then (at most ten times a second).
            let mut last = Instant::now();
            let mut pending: Option<PyErr> = None;
            let mut monitor = |fraction: f64, t: f64| {
                if last.elapsed() < Duration::from_millis(100) {
                    return Ok(());
                }
                last = Instant::now();
                py.check_signals().and_then(|()| progress.map_or(Ok(()), |cb| cb.call1(py, (fraction,)).map(drop))).map_err(|e| {
                    pending = Some(e);
                    Error::Interrupted { t }
                })
            };
            let r = core::simulate_each(c, theta0, omega0, t_end, &settings, &mut src, &mut monitor);
            if let Some(p) = pending {
                return Err(p);
            }
            r.map(Trajectories)
        }
    };
    let trs = result.map_err(fail)?;
    trajectories_out(py, trs, settings.sensitivities.iter().map(|i| i.len(n)).collect())
}

/// `(t, steps)` of serialised checkpoint bytes, or an InputError saying why they cannot be read.
#[pyfunction]
fn checkpoint_time(py: Python<'_>, state: Vec<u8>) -> PyResult<(f64, u64)> {
    let cp = core::Checkpoint::from_bytes(&state).map_err(|e| to_py(py, e))?;
    Ok((cp.t(), cp.run.steps))
}
