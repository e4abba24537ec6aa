//! The `Chain` class: construction, and the dynamics of rows of states (each row a state; the
//! Python layer reshapes).
use std::cell::RefCell;

use multipendulum_core as core;
use numpy::{PyArray1, PyReadonlyArray1};
use pyo3::prelude::*;

use core::dynamics::rows;
use core::reference::Algorithm;
use core::Chain as CoreChain;

use crate::torque::{torque_error, PyTorque};
use crate::{slice, to_py, vec_out};

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyChain>()
}

#[pyclass(module = "multipendulum._core", frozen, name = "Chain")]
pub(crate) struct PyChain {
    pub(crate) inner: CoreChain,
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
        let out = rows::mass_matrices(&self.inner, slice("theta", &theta)?).map_err(|e| to_py(py, e))?;
        Ok(vec_out(py, out))
    }

    /// Accelerations of each row; `algorithm` is "recursive" (O(N)), "cholesky" or "cramer".
    #[pyo3(signature = (theta, omega, *, t=0.0, torque=None, algorithm="recursive"))]
    fn accelerations<'py>(
        &self,
        py: Python<'py>,
        theta: PyReadonlyArray1<'py, f64>,
        omega: PyReadonlyArray1<'py, f64>,
        t: f64,
        torque: Option<PyRef<'py, PyTorque>>,
        algorithm: &str,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let (theta, omega) = (slice("theta", &theta)?, slice("omega", &omega)?);
        let algorithm = Algorithm::parse(algorithm).map_err(|e| to_py(py, e))?;
        let slot = RefCell::new(None);
        let mut src = crate::torque::torque(py, self.inner.n(), torque.as_deref(), &slot)?;
        let out = rows::accelerations(&self.inner, theta, omega, t, &mut src, algorithm).map_err(|e| torque_error(py, e, &slot))?;
        Ok(vec_out(py, out))
    }

    /// The exact Jacobian of the Lagrangian right-hand side `(omega, theta_ddot)` with respect to
    /// `(theta, omega)` (row-major 2N x 2N), from the variational equations; torques are taken as
    /// depending on time only.
    #[pyo3(signature = (theta, omega, *, t=0.0, torque=None))]
    fn jacobian<'py>(
        &self,
        py: Python<'py>,
        theta: Vec<f64>,
        omega: Vec<f64>,
        t: f64,
        torque: Option<PyRef<'py, PyTorque>>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let slot = RefCell::new(None);
        let mut src = crate::torque::torque(py, self.inner.n(), torque.as_deref(), &slot)?;
        let out = rows::jacobian(&self.inner, &theta, &omega, t, &mut src).map_err(|e| torque_error(py, e, &slot))?;
        Ok(vec_out(py, out))
    }

    /// `(theta_dot, p_dot)` of Hamilton's equations for each row.
    #[pyo3(signature = (theta, p, *, t=0.0, torque=None))]
    fn hamilton<'py>(
        &self,
        py: Python<'py>,
        theta: PyReadonlyArray1<'py, f64>,
        p: PyReadonlyArray1<'py, f64>,
        t: f64,
        torque: Option<PyRef<'py, PyTorque>>,
    ) -> PyResult<(Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<f64>>)> {
        let slot = RefCell::new(None);
        let mut src = crate::torque::torque(py, self.inner.n(), torque.as_deref(), &slot)?;
        let (td, pd) = rows::hamilton(&self.inner, slice("theta", &theta)?, slice("p", &p)?, t, &mut src)
            .map_err(|e| torque_error(py, e, &slot))?;
        Ok((vec_out(py, td), vec_out(py, pd)))
    }

    fn momenta<'py>(&self, py: Python<'py>, theta: PyReadonlyArray1<'py, f64>, omega: PyReadonlyArray1<'py, f64>) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let out = rows::momenta(&self.inner, slice("theta", &theta)?, slice("omega", &omega)?).map_err(|e| to_py(py, e))?;
        Ok(vec_out(py, out))
    }

    fn velocities<'py>(&self, py: Python<'py>, theta: PyReadonlyArray1<'py, f64>, p: PyReadonlyArray1<'py, f64>) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let out = rows::velocities(&self.inner, slice("theta", &theta)?, slice("p", &p)?).map_err(|e| to_py(py, e))?;
        Ok(vec_out(py, out))
    }

    /// `(kinetic, potential)` energies of each row.
    fn energies<'py>(&self, py: Python<'py>, theta: PyReadonlyArray1<'py, f64>, omega: PyReadonlyArray1<'py, f64>) -> PyResult<(Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<f64>>)> {
        let (kin, pot) = rows::energies(&self.inner, slice("theta", &theta)?, slice("omega", &omega)?).map_err(|e| to_py(py, e))?;
        Ok((vec_out(py, kin), vec_out(py, pot)))
    }

    /// Joint positions (`com=False`) or centres of mass (`com=True`), 2N numbers per row.
    #[pyo3(signature = (theta, *, com=false))]
    fn positions<'py>(&self, py: Python<'py>, theta: PyReadonlyArray1<'py, f64>, com: bool) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let out = rows::positions(&self.inner, slice("theta", &theta)?, com).map_err(|e| to_py(py, e))?;
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

