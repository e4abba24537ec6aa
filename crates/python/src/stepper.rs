//! `Steppers`: copies of one chain advanced together with their inputs held over each call (the
//! environments' engine, [`core::Steppers`]). Arrays cross flat; the GIL is released while the
//! copies step.
use multipendulum_core as core;
use numpy::{PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray1, PyReadwriteArray1};
use pyo3::prelude::*;
use pyo3::types::PyTuple;

use core::{Form, Method, Settings};

use crate::chain::PyChain;
use crate::{slice, to_py, Array, InputError};

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PySteppers>()?;
    m.add_class::<PyTask>()
}

/// Observation columns from flat `(kind, index)` pairs: kind 0 a state row's value, 1 its
/// cosine, 2 its sine.
fn columns_of(columns: &PyReadonlyArray1<'_, i64>) -> PyResult<Vec<core::Column>> {
    let pairs = columns.as_slice().map_err(|_| InputError::new_err("columns must be a C-contiguous int64 array"))?;
    if pairs.len() % 2 != 0 {
        return Err(InputError::new_err("columns must hold (kind, index) pairs"));
    }
    pairs
        .chunks(2)
        .map(|p| match (p[0], usize::try_from(p[1])) {
            (0, Ok(i)) => Ok(core::Column::Value(i)),
            (1, Ok(i)) => Ok(core::Column::Cos(i)),
            (2, Ok(i)) => Ok(core::Column::Sin(i)),
            _ => Err(InputError::new_err(format!("an observation column is (kind 0, 1 or 2, index >= 0), got ({}, {})", p[0], p[1]))),
        })
        .collect()
}

/// An environment's actions, observation and outcome over copies of one chain
/// ([`core::Task`]): what `Steppers.act` applies around a step.
#[pyclass(module = "multipendulum._core", name = "Task", frozen)]
pub(crate) struct PyTask {
    inner: core::Task,
}

#[pymethods]
impl PyTask {
    /// `targets`: each action component's input, a joint's index or None for the cart's force;
    /// `scale`: each component's largest input; `discrete`: actions 0, 1, 2 are `-scale, 0,
    /// +scale`, else numbers clipped to [-1, 1] and scaled; `columns` as for
    /// `Steppers.observe`; `goal`: "height" (`above`: the tip's rise above the pivot that ends
    /// the episode), "balance" (`x_limit`, `angle_limit`) or "swingup" (`x_limit`).
    #[new]
    #[pyo3(signature = (chain, *, discrete, targets, scale, columns, goal, above=None, x_limit=None, angle_limit=None))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        chain: &PyChain,
        discrete: bool,
        targets: Vec<Option<usize>>,
        scale: Vec<f64>,
        columns: PyReadonlyArray1<'_, i64>,
        goal: &str,
        above: Option<f64>,
        x_limit: Option<f64>,
        angle_limit: Option<f64>,
    ) -> PyResult<Self> {
        let need = |v: Option<f64>, name: &str| v.ok_or_else(|| InputError::new_err(format!("goal {goal:?} needs {name}")));
        let goal = match goal {
            "height" => core::Goal::Height { above: need(above, "above")? },
            "balance" => core::Goal::Balance { x_limit: need(x_limit, "x_limit")?, angle_limit: need(angle_limit, "angle_limit")? },
            "swingup" => core::Goal::SwingUp { x_limit: need(x_limit, "x_limit")? },
            _ => return Err(InputError::new_err(format!("goal must be 'height', 'balance' or 'swingup', got {goal:?}"))),
        };
        let targets = targets.into_iter().map(|t| t.map_or(core::Target::Cart, core::Target::Joint)).collect();
        let inner = core::Task::new(&chain.inner, discrete, targets, scale, columns_of(&columns)?, goal).map_err(|e| to_py(py, e))?;
        Ok(PyTask { inner })
    }

    /// Components of one action.
    #[getter]
    fn width(&self) -> usize {
        self.inner.width()
    }

    /// One action's shape: `()` for a discrete task of one component (gymnasium's
    /// `Discrete`), else `(width,)`.
    #[getter]
    fn action_shape<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyTuple>> {
        PyTuple::new(py, self.inner.action_shape())
    }

    /// The number of values a discrete action takes (`0..levels`), or None for continuous actions.
    #[getter]
    fn action_levels(&self) -> Option<usize> {
        self.inner.discrete.then_some(core::Task::LEVELS)
    }

    /// `(low, high)`: the range of a continuous action's components (beyond it, clipped).
    #[getter]
    fn action_bounds(&self) -> (f64, f64) {
        core::Task::BOUNDS
    }
}

#[pyclass(module = "multipendulum._core", name = "Steppers")]
pub(crate) struct PySteppers {
    inner: core::Steppers,
}

#[pymethods]
impl PySteppers {
    /// `count` copies of `chain`, hanging at rest until `reset`.
    #[new]
    #[pyo3(signature = (chain, count, *, method, rtol, atol, max_steps, dt=None, form=None))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        chain: &PyChain,
        count: usize,
        method: &str,
        rtol: f64,
        atol: f64,
        max_steps: u64,
        dt: Option<f64>,
        form: Option<&str>,
    ) -> PyResult<Self> {
        let err = |e| to_py(py, e);
        let settings = Settings {
            method: Method::parse(method).map_err(err)?,
            form: form.map(Form::parse).transpose().map_err(err)?,
            dt,
            rtol,
            atol,
            max_steps,
            ..Settings::default()
        };
        let inner = core::Steppers::new(&chain.inner, count, &settings).map_err(err)?;
        Ok(PySteppers { inner })
    }

    #[getter]
    fn count(&self) -> usize {
        self.inner.len()
    }

    /// The route the copies take: `"each"` (a stepper per copy) or `"lanes:<path>"` (SIMD lanes).
    #[getter]
    fn route(&self) -> String {
        self.inner.route()
    }

    /// Values per copy in `states()`: theta (N), omega (N), then the cart's x, v.
    #[getter]
    fn state_len(&self) -> usize {
        self.inner.state_len()
    }

    /// Start copy `index` anew at t = 0 (a new episode).
    #[pyo3(signature = (index, theta0, omega0, cart0=(0.0, 0.0)))]
    fn reset(&mut self, py: Python<'_>, index: usize, theta0: PyReadonlyArray1<'_, f64>, omega0: PyReadonlyArray1<'_, f64>, cart0: (f64, f64)) -> PyResult<()> {
        let (theta0, omega0) = (slice("theta0", &theta0)?, slice("omega0", &omega0)?);
        self.inner.reset(index, theta0, omega0, [cart0.0, cart0.1]).map_err(|e| to_py(py, e))
    }

    /// Start every copy anew at t = 0 from the rows of flat `theta0`, `omega0` (count x N each).
    fn reset_all(&mut self, py: Python<'_>, theta0: PyReadonlyArray1<'_, f64>, omega0: PyReadonlyArray1<'_, f64>) -> PyResult<()> {
        let (theta0, omega0) = (slice("theta0", &theta0)?, slice("omega0", &omega0)?);
        let (count, n) = (self.inner.len(), self.inner.chain().n());
        if theta0.len() != count * n || omega0.len() != count * n {
            return Err(InputError::new_err(format!("theta0 and omega0 must both have count x N = {} values", count * n)));
        }
        for i in 0..count {
            self.inner.reset(i, &theta0[i * n..(i + 1) * n], &omega0[i * n..(i + 1) * n], [0.0, 0.0]).map_err(|e| to_py(py, e))?;
        }
        Ok(())
    }

    /// Start the copies `indices` anew at t = 0, copy `indices[r]` from row r of `rows`
    /// (len(indices) x state_len, flat: theta (N), omega (N), then the cart's x, v).
    fn reset_rows(&mut self, py: Python<'_>, indices: PyReadonlyArray1<'_, i64>, rows: PyReadonlyArray1<'_, f64>) -> PyResult<()> {
        let indices = indices.as_slice().map_err(|_| InputError::new_err("indices must be a C-contiguous int64 array"))?;
        let rows = slice("rows", &rows)?;
        let (k, n) = (self.inner.state_len(), self.inner.chain().n());
        if rows.len() != indices.len() * k {
            return Err(InputError::new_err(format!("rows must have len(indices) x {k} = {} values, got {}", indices.len() * k, rows.len())));
        }
        for (&i, row) in indices.iter().zip(rows.chunks(k)) {
            let i = usize::try_from(i).map_err(|_| InputError::new_err(format!("index {i} out of range for {} copies", self.inner.len())))?;
            let cart = if k > 2 * n { [row[2 * n], row[2 * n + 1]] } else { [0.0, 0.0] };
            self.inner.reset(i, &row[..n], &row[n..2 * n], cart).map_err(|e| to_py(py, e))?;
        }
        Ok(())
    }

    /// Hold joint torques (count x N, flat) and cart forces (count, or empty without a cart),
    /// then advance every copy by `span` (whole steps of a fixed-step method's grid), without
    /// the GIL.
    /// `active`: one flag per copy, the copies that move (None: all). Returns the new states
    /// and balances, as `report()` does.
    #[pyo3(signature = (torques, forces, span, active=None))]
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        torques: PyReadonlyArray1<'_, f64>,
        forces: PyReadonlyArray1<'_, f64>,
        span: f64,
        active: Option<PyReadonlyArray1<'_, bool>>,
    ) -> PyResult<(Array<'py>, Array<'py>)> {
        let (torques, forces) = (slice("torques", &torques)?, slice("forces", &forces)?);
        let active = match &active {
            Some(a) => a.as_slice().map_err(|_| InputError::new_err("active must be a C-contiguous bool array"))?,
            None => &[],
        };
        let count = self.inner.len();
        let (mut states, mut balance) = (vec![0.0; count * self.inner.state_len()], vec![0.0; count * 3]);
        let inner = &mut self.inner;
        py.detach(|| inner.step(torques, forces, span, active, &mut states, &mut balance)).map_err(|e| to_py(py, e))?;
        Ok((PyArray1::from_vec(py, states), PyArray1::from_vec(py, balance)))
    }

    /// An observation of every copy from `states` (count x state_len, flat, as `step` returns
    /// them): `columns` flat pairs `(kind, index)`, kind 0 the row's value at `index`, 1 its
    /// cosine, 2 its sine. Returns count x (number of pairs) values, flat.
    fn observe<'py>(&self, py: Python<'py>, states: PyReadonlyArray1<'_, f64>, columns: PyReadonlyArray1<'_, i64>) -> PyResult<Array<'py>> {
        let states = slice("states", &states)?;
        let columns = columns_of(&columns)?;
        let mut out = vec![0.0; self.inner.len() * columns.len()];
        self.inner.observe_into(states, &columns, &mut out).map_err(|e| to_py(py, e))?;
        Ok(PyArray1::from_vec(py, out))
    }

    /// One environment step of every copy under `task` (`Task`): `actions` (count x the task's
    /// width, flat) become the inputs held over `span`, the active copies step (`active` as for
    /// `step`; a copy that does not move earns 0 and does not end), and every copy reports.
    /// `steps` (uint64, one per copy) counts each copy's steps in its episode, in place;
    /// `limit` truncates an episode at that count (None: never). Returns the states
    /// (count x state_len) and balances (count x 3) as `step`, the observations (count x the
    /// task's columns), the rewards, the ends, the truncations, and how many copies ended.
    /// `batched`: a refused action is named by (copy, component), else by (component,). Without
    /// the GIL.
    #[pyo3(signature = (task, actions, span, batched, steps, limit=None, active=None))]
    #[allow(clippy::type_complexity, clippy::too_many_arguments)]
    fn act<'py>(
        &mut self,
        py: Python<'py>,
        task: &PyTask,
        actions: PyReadonlyArray1<'_, f64>,
        span: f64,
        batched: bool,
        mut steps: PyReadwriteArray1<'_, u64>,
        limit: Option<u64>,
        active: Option<PyReadonlyArray1<'_, bool>>,
    ) -> PyResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<f64>>, Array<'py>, Array<'py, bool>, Array<'py, bool>, usize)>
    {
        let actions = slice("actions", &actions)?;
        let active = match &active {
            Some(a) => a.as_slice().map_err(|_| InputError::new_err("active must be a C-contiguous bool array"))?,
            None => &[],
        };
        let steps = steps.as_slice_mut().map_err(|_| InputError::new_err("steps must be a C-contiguous uint64 array"))?;
        let (count, k, task) = (self.inner.len(), self.inner.state_len(), &task.inner);
        let width = task.columns.len();
        let (mut states, mut balance, mut obs) = (vec![0.0; count * k], vec![0.0; count * 3], vec![0.0; count * width]);
        let (mut reward, mut terminated, mut truncated) = (vec![0.0; count], vec![false; count], vec![false; count]);
        let inner = &mut self.inner;
        let out = core::Acted {
            states: &mut states,
            balance: &mut balance,
            obs: &mut obs,
            reward: &mut reward,
            terminated: &mut terminated,
            truncated: &mut truncated,
        };
        let ended = py.detach(|| inner.act(task, actions, batched, span, active, (steps, limit), out)).map_err(|e| to_py(py, e))?;
        Ok((
            PyArray1::from_vec(py, states).reshape([count, k])?,
            PyArray1::from_vec(py, balance).reshape([count, 3])?,
            PyArray1::from_vec(py, obs).reshape([count, width])?,
            PyArray1::from_vec(py, reward),
            PyArray1::from_vec(py, terminated),
            PyArray1::from_vec(py, truncated),
            ended,
        ))
    }

    /// Every copy's state (count x state_len, flat) and its time, energy (lab frame) and
    /// energy-balance residual (count x 3, flat), as `step` returns them.
    fn report<'py>(&mut self, py: Python<'py>) -> (Array<'py>, Array<'py>) {
        let count = self.inner.len();
        let (mut states, mut balance) = (vec![0.0; count * self.inner.state_len()], vec![0.0; count * 3]);
        self.inner.report_into(&mut states, &mut balance);
        (PyArray1::from_vec(py, states), PyArray1::from_vec(py, balance))
    }
}
