//! `Steppers`: copies of one chain advanced together with their inputs held over each call (the
//! environments' engine, [`core::Steppers`]). Arrays cross flat; the GIL is released while the
//! copies step.
use multipendulum_core as core;
use numpy::{PyArray1, PyReadonlyArray1};
use pyo3::prelude::*;

use core::{Form, Method, Settings};

use crate::chain::PyChain;
use crate::{slice, to_py, InputError};

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PySteppers>()
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
    fn new(py: Python<'_>, chain: &PyChain, count: usize, method: &str, rtol: f64, atol: f64, max_steps: u64, dt: Option<f64>, form: Option<&str>) -> PyResult<Self> {
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

    /// The route the copies take: "each" (a stepper per copy) or "lanes:<path>" (SIMD lanes).
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
    ) -> PyResult<(Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<f64>>)> {
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
    fn observe<'py>(&self, py: Python<'py>, states: PyReadonlyArray1<'_, f64>, columns: PyReadonlyArray1<'_, i64>) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let states = slice("states", &states)?;
        let pairs = columns.as_slice().map_err(|_| InputError::new_err("columns must be a C-contiguous int64 array"))?;
        if pairs.len() % 2 != 0 {
            return Err(InputError::new_err("columns must hold (kind, index) pairs"));
        }
        let columns = pairs
            .chunks(2)
            .map(|p| match (p[0], usize::try_from(p[1])) {
                (0, Ok(i)) => Ok(core::Column::Value(i)),
                (1, Ok(i)) => Ok(core::Column::Cos(i)),
                (2, Ok(i)) => Ok(core::Column::Sin(i)),
                _ => Err(InputError::new_err(format!("an observation column is (kind 0, 1 or 2, index >= 0), got ({}, {})", p[0], p[1]))),
            })
            .collect::<PyResult<Vec<_>>>()?;
        let mut out = vec![0.0; self.inner.len() * columns.len()];
        self.inner.observe_into(states, &columns, &mut out).map_err(|e| to_py(py, e))?;
        Ok(PyArray1::from_vec(py, out))
    }

    /// Every copy's state (count x state_len, flat) and its time, energy (lab frame) and
    /// energy-balance residual (count x 3, flat), as `step` returns them.
    fn report<'py>(&mut self, py: Python<'py>) -> (Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<f64>>) {
        let count = self.inner.len();
        let (mut states, mut balance) = (vec![0.0; count * self.inner.state_len()], vec![0.0; count * 3]);
        self.inner.report_into(&mut states, &mut balance);
        (PyArray1::from_vec(py, states), PyArray1::from_vec(py, balance))
    }
}
